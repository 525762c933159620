"""Results store: one folder per sweep, append-only: rows fragments and run records.

Layout of a sweep folder::

    <sweep>/runs/<run_id>.parquet       rows of a run computed alone (a fragment)
    <sweep>/runs/<batch>-<sha>.parquet  rows of the ok runs of one batch (a fragment)
    <sweep>/runs/compact-<sha>.parquet  rows of fragments merged by ``ttc-bench compact``
    <sweep>/runs/<run_id>.json          the run record (written after its rows: marks the run
                                        complete); ``rows_file`` names its fragment, if not its
                                        own, ``rows_sha256`` and ``n_rows`` check it
    <sweep>/runs/<id>.lock              held (flock) while a process computes the run / batch
    <sweep>/runs/.store.lock            held shared while a process stores runs, exclusive
                                        while a compaction repoints records
    <sweep>/.plan/<batch>.json          the settings of a batch (written by the sweeper)

An invocation only adds files: each job writes its fragment and its records (each file to a
temporary name in the same folder, renamed into place, so a killed job leaves whole files or
none); nothing is merged at the end of a sweep and nothing already there is rewritten, so the
end of an invocation costs what its own runs cost, and invocations on many nodes (Slurm array
tasks, ``submitit``, two commands at once) write into one folder without a central step. Only
these names are read; Hydra's job folders and logs beside them are ignored.

Readers see the folder as one dataset: :func:`load_sweep` (pandas, ``columns=`` to read only
some), :func:`read_table` (Arrow) and :func:`rows_dataset` (a ``pyarrow.dataset`` to query
lazily) read the fragments the ``ok`` records name, each checked against its records' SHA-256
and row counts (:class:`StoreError` names a missing or corrupt one; it is never read as good),
without the rows of runs recomputed since into another fragment. DuckDB or pyarrow users may
read the glob ``<sweep>/runs/*.parquet`` (``union_by_name=true``: batches may lack a column):
it holds exactly the live rows once ``ttc-bench compact`` (:func:`compact`) has run, or when no
run was recomputed (``force=true``, changed input) or killed between its rows and its records,
and while no compaction runs (it writes a merged file before it removes the old ones).

A run is *complete* when its record says ``ok`` or ``skipped``, its rows file has the
SHA-256 and row count the record names, and the input files it read still have the identity
(size, mtime) the record names (:func:`incomplete_reason`).
"""

from experiments.store.compact import compact
from experiments.store.completeness import (
    Checks,
    changed_inputs,
    incomplete_reason,
    input_identities,
    is_complete,
    record_problem,
    run_lock,
)
from experiments.store.dataset import (
    UNREAD_RECORD_FIELDS,
    fragments,
    load_runs,
    load_sweep,
    read_table,
    row_count,
    rows_dataset,
    runs_table,
    sweep_records,
)
from experiments.store.files import (
    COMPLETE_STATUSES,
    LEGACY_MERGED_FILES,
    NO_RECORD,
    RUNS_DIR,
    StoreError,
    keep_index,
    parquet_bytes,
    read_record,
    read_rows,
    rows_path,
    run_paths,
    save_batch,
    save_run,
    store_lock,
    write_json_atomic,
    write_parquet_atomic,
    write_record,
)
from experiments.store.record_index import list_records

#: The glob of a sweep's rows fragments, relative to the sweep folder (module docstring).
ROWS_GLOB = f"{RUNS_DIR}/*.parquet"
#: The glob of a sweep's run records, relative to the sweep folder.
RECORDS_GLOB = f"{RUNS_DIR}/*.json"

__all__ = [
    "sweep_records",
    "UNREAD_RECORD_FIELDS",
    "RUNS_DIR",
    "ROWS_GLOB",
    "RECORDS_GLOB",
    "LEGACY_MERGED_FILES",
    "COMPLETE_STATUSES",
    "NO_RECORD",
    "StoreError",
    "parquet_bytes",
    "write_parquet_atomic",
    "write_json_atomic",
    "write_record",
    "keep_index",
    "run_paths",
    "rows_path",
    "read_record",
    "read_rows",
    "save_run",
    "save_batch",
    "store_lock",
    "list_records",
    "input_identities",
    "changed_inputs",
    "Checks",
    "incomplete_reason",
    "record_problem",
    "is_complete",
    "run_lock",
    "fragments",
    "read_table",
    "rows_dataset",
    "load_sweep",
    "load_runs",
    "runs_table",
    "row_count",
    "compact",
]
