"""A sweep's rows as one dataset: the live rows fragments under ``runs/``, found from the run
records, checked against them and read in one order (no merged file is written)."""

from __future__ import annotations

from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from experiments.store.completeness import Checks, rows_problem
from experiments.store.files import (
    RUNS_DIR,
    StoreError,
    read_checked_table,
)
from experiments.store.record_index import list_records

#: Threads reading fragments (Arrow releases the GIL while it decodes).
READ_THREADS = 2
#: Times a read starts again when a fragment vanished under it (``ttc-bench compact`` moved
#: its rows to a larger file and repointed their records meanwhile).
RETRIES = 3


@dataclass
class Fragment:
    """One rows file and the runs whose record points to it (``n_rows``: by run id)."""

    path: Path
    sha256: str | None
    n_rows: dict[str, int] = field(default_factory=dict)
    own: bool = False  #: a run's own file (``<run_id>.parquet``), not a batch's

    @property
    def rows(self) -> int:
        """Rows of this fragment's live runs (as their records count them)."""
        return sum(self.n_rows.values())


def fragments(sweep_dir: Path, records: list[dict[str, Any]] | None = None) -> list[Fragment]:
    """The live fragments of a sweep (each named by an ``ok`` record), in the order of their
    smallest run id: the order of the rows of :func:`read_table` (``records``: the sweep's
    :func:`list_records`, when already read)."""
    records = list_records(sweep_dir) if records is None else records
    runs_dir = Path(sweep_dir) / RUNS_DIR
    by_name: dict[str, Fragment] = {}  # by file name: one Path per fragment, not per run
    for record in records:
        if record.get("status") != "ok":
            continue
        run_id, shared = record["run_id"], record.get("rows_file")
        name = shared or f"{run_id}.parquet"
        frag = by_name.get(name)
        if frag is None:
            frag = by_name[name] = Fragment(runs_dir / name, record.get("rows_sha256"))
        if record.get("rows_sha256") != frag.sha256:
            raise StoreError(frag.path, "records disagree on the rows file's SHA-256")
        frag.n_rows[run_id] = int(record.get("n_rows") or 0)
        frag.own = frag.own or not shared
    return sorted(by_name.values(), key=lambda f: min(f.n_rows))


def check_fragments(frags: list[Fragment], checks: Checks | None = None) -> None:
    """:class:`StoreError` naming the first fragment that is missing or whose SHA-256
    differs from its records'."""
    checks = checks or Checks()
    for frag in frags:
        if (problem := rows_problem(frag.path, frag.sha256, checks)) is not None:
            raise StoreError(frag.path, f"rows file {problem}")


def fragment_table(frag: Fragment, columns: list[str] | None = None) -> pa.Table:
    """The checked rows of a fragment's live runs (other runs' rows, superseded by a later
    computation, left out), ``columns`` only when given; :class:`StoreError` names a missing,
    corrupt or inconsistent file."""
    wanted = None if columns is None else list(dict.fromkeys(["run_id", *columns]))
    table = read_checked_table(frag.path, frag.sha256, wanted)
    if frag.own:
        if table.num_rows != frag.rows:
            raise StoreError(frag.path, f"{table.num_rows} rows, its record says {frag.rows}")
    else:
        ids = table.column("run_id").to_pandas()
        counts = ids.value_counts()
        for run_id, n in frag.n_rows.items():
            if int(counts.get(run_id, 0)) != n:
                raise StoreError(frag.path, f"{counts.get(run_id, 0)} rows of {run_id}, "
                                 f"its record says {n}")  # fmt: skip
        # in Arrow: pandas' isin on the ids took 10-25 ms a fragment
        wanted = pc.is_in(
            table.column("run_id"), value_set=pa.array(list(frag.n_rows), pa.string())
        )
        table = table if pc.all(wanted).as_py() else table.filter(wanted)
    return (
        table if columns is None else table.select([c for c in columns if c in table.schema.names])
    )


def unified_schema(
    frags: list[Fragment], known: dict[str, pa.Schema] | None = None
) -> pa.Schema | None:
    """One schema for every fragment (types promoted where files differ), or None.
    ``known``: schemas already read, by the fragment's SHA-256 (a fragment never changes);
    those read here are added to it."""
    schemas = []
    for frag in frags:
        if known is not None and frag.sha256 in known:
            schemas.append(known[frag.sha256])
            continue
        try:
            schema = pq.read_schema(frag.path).remove_metadata()
        except (OSError, pa.ArrowException) as exc:
            raise StoreError(
                frag.path, f"rows file corrupt ({type(exc).__name__}: {exc})"
            ) from None
        schemas.append(schema)
        if known is not None and frag.sha256:
            known[frag.sha256] = schema
    return pa.unify_schemas(schemas, promote_options="permissive") if schemas else None


def conform(table: pa.Table, schema: pa.Schema) -> pa.Table:
    """``table`` with ``schema``'s columns in its order (missing ones null) and types."""
    if table.schema.remove_metadata().equals(schema.remove_metadata()):
        return table.replace_schema_metadata(schema.metadata)
    columns = [
        (table.column(f.name) if table.column(f.name).type == f.type
         else table.column(f.name).cast(f.type))
        if f.name in table.column_names
        else pa.nulls(table.num_rows, f.type)
        for f in schema
    ]  # fmt: skip
    return pa.Table.from_arrays(columns, schema=schema)


def iter_tables(
    frags: list[Fragment], schema: pa.Schema, columns: list[str] | None = None
) -> Iterator[pa.Table]:
    """Each fragment's checked live rows with ``schema`` (``columns`` of it), in order, read
    by :data:`READ_THREADS` threads a few fragments ahead."""
    wanted = schema if columns is None else pa.schema([schema.field(c) for c in columns])

    def read(frag: Fragment) -> pa.Table:
        return conform(fragment_table(frag, columns), wanted)

    ahead = READ_THREADS * 2
    with ThreadPoolExecutor(max_workers=READ_THREADS) as pool:
        futures = [pool.submit(read, f) for f in frags[:ahead]]
        for i in range(len(frags)):
            if i + ahead < len(frags):
                futures.append(pool.submit(read, frags[i + ahead]))
            yield futures[i].result()
            futures[i] = None


def read_table(sweep_dir: Path, columns: list[str] | None = None) -> pa.Table:
    """Every live row of a sweep as one Arrow table (``columns``: only those the sweep has),
    fragments in :func:`fragments` order (:func:`read_with_records`)."""
    return read_with_records(sweep_dir, columns)[0]


def read_with_records(
    sweep_dir: Path, columns: list[str] | None = None
) -> tuple[pa.Table, list[dict[str, Any]]]:
    """(:func:`read_table`, the records it was read by). Starts again (:data:`RETRIES`
    times) when a fragment vanished while read and the records have changed meanwhile (a
    compaction moved its rows)."""
    for attempt in range(RETRIES + 1):
        records = list_records(sweep_dir)
        frags = fragments(sweep_dir, records)
        try:
            schema = unified_schema(frags)
            if schema is None:
                return pa.table({}), records
            present = None if columns is None else [c for c in columns if c in schema.names]
            wanted = schema if present is None else pa.schema([schema.field(c) for c in present])
            tables = list(iter_tables(frags, schema, present))
            return (pa.concat_tables(tables) if tables else wanted.empty_table()), records
        except StoreError as exc:
            if attempt == RETRIES or exc.path.exists() or list_records(sweep_dir) == records:
                raise
    raise AssertionError("unreachable")


def rows_dataset(sweep_dir: Path, checks: Checks | None = None) -> ds.Dataset:
    """The live rows of a sweep as a ``pyarrow.dataset`` (every fragment's SHA-256 checked
    first: :class:`StoreError` names a corrupt one): a file dataset over the fragments that
    hold only live rows, united with the live rows of any fragment that also holds rows a
    later computation superseded (read now). A snapshot: a compaction that runs meanwhile
    may remove its files (open it again)."""
    sweep_dir = Path(sweep_dir)
    if not (sweep_dir / RUNS_DIR).is_dir():
        raise StoreError(sweep_dir, f"no {RUNS_DIR}/ folder: not a sweep folder")
    frags = fragments(sweep_dir)
    check_fragments(frags, checks)
    schema = unified_schema(frags) or pa.schema([])
    clean, mixed = [], []
    for frag in frags:
        total = pq.ParquetFile(frag.path).metadata.num_rows
        (clean if total == frag.rows else mixed).append(frag)
    parts: list[ds.Dataset] = [ds.dataset([str(f.path) for f in clean], schema=schema)]
    if mixed:
        parts.append(ds.dataset([conform(fragment_table(f), schema) for f in mixed]))
    return parts[0] if len(parts) == 1 else ds.dataset(parts)


#: Run record fields only the completeness check reads (the identities of a run's input
#: files, 3.7 kB of a record's 6.6 kB): a reader of the runs table leaves them out
#: (``runs_table(records, exclude=UNREAD_RECORD_FIELDS)``), 28,000 records' long texts cost
#: seconds to convert and to filter.
UNREAD_RECORD_FIELDS: tuple[str, ...] = ("inputs",)


def runs_table(
    records: list[dict[str, Any]], exclude: tuple[str, ...] = (), texts: tuple[str, ...] = ()
) -> pd.DataFrame:
    """The run records as one table, sorted by run id (types as a parquet round trip gives
    them: the table ``runs.parquet`` held), the fields ``exclude`` left out. ``texts``: fields
    kept as the records' own Python strings (object dtype, last columns), for a reader that
    only parses them (``config``: 2 kB a run; as Arrow strings each of the summary's filters
    of 47,040 runs copied them, 0.3 s a filter)."""
    full, left_out = records, {*exclude, *texts}
    if left_out:  # left out before the table is made: converting them costs (0.7 s of 1.5 s)
        records = [{k: v for k, v in r.items() if k not in left_out} for r in records]
    order = sorted(range(len(records)), key=lambda i: records[i].get("run_id", ""))
    runs = pd.DataFrame.from_records([records[i] for i in order])
    if runs.empty:
        return runs
    runs = runs.sort_values("run_id", ignore_index=True)  # (sorted already: stable)
    runs = pa.Table.from_pandas(runs, preserve_index=False).to_pandas()
    for name in texts:
        runs[name] = pd.Series([full[i].get(name) for i in order], dtype=object)
    return runs


def load_runs(sweep_dir: Path) -> pd.DataFrame:
    """Every run record of a sweep (:func:`runs_table`)."""
    return runs_table(list_records(sweep_dir))


def row_count(records: list[dict[str, Any]]) -> int:
    """Rows of the sweep's dataset, as its ``ok`` records count them."""
    return sum(int(r.get("n_rows") or 0) for r in records if r.get("status") == "ok")


def sweep_records(sweep_dir: Path) -> list[dict[str, Any]]:
    """Every run record of a sweep (:func:`list_records`); :class:`StoreError` when the
    folder has no ``runs/``."""
    sweep_dir = Path(sweep_dir)
    if not (sweep_dir / RUNS_DIR).is_dir():
        raise StoreError(sweep_dir, f"no {RUNS_DIR}/ folder: not a sweep folder")
    return list_records(sweep_dir)


def load_sweep(
    sweep_dir: Path, columns: list[str] | None = None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(frames, runs)`` of a sweep: every live row (``columns``: only these columns, those
    the sweep has; None: all) and every run record.

    Raises :class:`StoreError` naming the file when an ok run's rows file is missing or
    corrupt (checked against its record's SHA-256 every time) or the sweep folder has no
    ``runs/``.
    """
    sweep_dir = Path(sweep_dir)
    if not (sweep_dir / RUNS_DIR).is_dir():
        raise StoreError(sweep_dir, f"no {RUNS_DIR}/ folder: not a sweep folder")
    table, records = read_with_records(sweep_dir, columns)
    return table.to_pandas(), runs_table(records)
