"""Results store: one folder per sweep, one record + parquet file per run, merged datasets.

Layout of a sweep folder::

    <sweep>/runs/<run_id>.parquet     frame-pair rows of one run (written first)
    <sweep>/runs/<batch>-<sha>.parquet  rows of the runs of one batch (written first)
    <sweep>/runs/<run_id>.json        the run record (written last: marks the run complete);
                                      ``rows_file`` names its batch's rows file, if any
    <sweep>/runs/<id>.lock            held (flock) while a process computes the run / batch
    <sweep>/.plan/<batch>.json        the settings of a batch (written by the sweeper)
    <sweep>/frames.parquet            every run's rows, merged (collect), one row group per
                                      detector × descriptor (× rows file), sorted by axes
    <sweep>/runs.parquet              every run record, merged (collect)

Every file is written to a temporary name in the same folder and renamed into place, so a
killed sweep leaves whole files or none. Only these names are read; Hydra's job folders and
logs beside them are ignored.

A run is *complete* when its record says ``ok`` or ``skipped``, its rows file has the
SHA-256 and row count the record names, and the input files it read still have the identity
(size, mtime) the record names (:func:`incomplete_reason`). The merged files carry a digest of
the records they were merged from, so a reader can tell a stale merge (:func:`load_sweep`).
"""

from experiments.store.completeness import (
    Checks,
    changed_inputs,
    incomplete_reason,
    input_identities,
    is_complete,
    record_problem,
    run_lock,
)
from experiments.store.files import (
    COMPLETE_STATUSES,
    DIGEST_KEY,
    FRAMES_FILE,
    NO_RECORD,
    RUNS_DIR,
    RUNS_FILE,
    StoreError,
    list_records,
    parquet_bytes,
    read_record,
    read_rows,
    rows_path,
    run_paths,
    save_batch,
    save_run,
    write_json_atomic,
    write_parquet_atomic,
)
from experiments.store.merge import (
    PARTITION_COLUMNS,
    ROW_GROUP_ROWS,
    collect,
    load_sweep,
    merge,
    merge_digest,
    merge_is_current,
    merged_row_count,
)

__all__ = [
    "RUNS_DIR",
    "FRAMES_FILE",
    "RUNS_FILE",
    "COMPLETE_STATUSES",
    "NO_RECORD",
    "DIGEST_KEY",
    "StoreError",
    "parquet_bytes",
    "write_parquet_atomic",
    "write_json_atomic",
    "run_paths",
    "rows_path",
    "read_record",
    "read_rows",
    "save_run",
    "save_batch",
    "list_records",
    "input_identities",
    "changed_inputs",
    "Checks",
    "incomplete_reason",
    "record_problem",
    "is_complete",
    "run_lock",
    "merge_digest",
    "PARTITION_COLUMNS",
    "ROW_GROUP_ROWS",
    "collect",
    "merge",
    "merged_row_count",
    "merge_is_current",
    "load_sweep",
]
