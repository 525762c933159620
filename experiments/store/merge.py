"""The merged files of a sweep (``frames.parquet``, ``runs.parquet``): written from the run
files, partitioned by detector × descriptor, stamped with the digest of the records merged."""

from __future__ import annotations

import hashlib
import itertools
import json
from collections import deque
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from experiments.store.completeness import Checks, rows_problem
from experiments.store.files import (
    DIGEST_KEY,
    FRAMES_FILE,
    RUNS_DIR,
    RUNS_FILE,
    StoreError,
    list_records,
    read_checked_table,
    rows_path,
    write_parquet_atomic,
)
from ttc.atomic import atomic_write


def merge_digest(records: list[dict[str, Any]]) -> str:
    """Digest of what a merge of ``records`` contains (run ids, statuses, rows checksums)."""
    keys = sorted(
        (str(r.get("run_id")), str(r.get("status")), str(r.get("rows_sha256")), str(r.get("end")))
        for r in records
    )
    return hashlib.sha256(json.dumps(keys).encode()).hexdigest()


def _stored_digest(path: Path) -> str | None:
    try:
        metadata = pq.read_schema(path).metadata or {}
    except (OSError, pa.ArrowException):
        return None
    value = metadata.get(DIGEST_KEY)
    return value.decode() if value else None


#: Columns of a partition of the merged rows: a row group holds rows of one detector ×
#: descriptor, so a query on these columns reads only the row groups it needs.
PARTITION_COLUMNS = ("detector", "descriptor")
#: Consecutive rows of one partition are written as one row group up to this many rows.
ROW_GROUP_ROWS = 200_000
#: Rows files (and rows) read ahead of the writer, and the threads reading them
#: (:func:`_read_ahead`): ~0.2 GB of tables at most beside the one being written.
READ_AHEAD = 8
READ_AHEAD_ROWS = 200_000
READ_THREADS = 2


def collect(sweep_dir: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Merge every run's rows and records into ``frames.parquet`` and ``runs.parquet``
    (:func:`merge`) and return both as frames (for a sweep of millions of rows, call
    :func:`merge` and query ``frames.parquet`` instead)."""
    runs = merge(sweep_dir)
    return pd.read_parquet(Path(sweep_dir) / FRAMES_FILE), runs


def merge(sweep_dir: Path) -> pd.DataFrame:
    """Merge every run's rows and records into ``frames.parquet`` and ``runs.parquet``;
    return the runs.

    ``frames.parquet`` is written a rows file at a time (memory: one rows file and one row
    group), one row group per :data:`PARTITION_COLUMNS` value of each rows file, files in
    :data:`SORT_COLUMNS` order. Every ok run's rows are checked against its record; a
    missing or corrupt rows file raises :class:`StoreError` naming it (re-run the sweep to
    recompute it) and nothing is written. Call it when no job of the sweep is running (end
    of a multirun, or after a kill): it also deletes temporary files that killed jobs left.
    """
    sweep_dir = Path(sweep_dir)
    for stale in (sweep_dir / RUNS_DIR).glob(".*.tmp"):  # left by a killed job
        stale.unlink(missing_ok=True)
    records = list_records(sweep_dir)
    runs = pd.DataFrame.from_records(records)
    if not runs.empty:
        runs = runs.sort_values("run_id", ignore_index=True)
    files = _rows_files(sweep_dir, [r for r in records if r.get("status") == "ok"])
    metadata = {DIGEST_KEY: merge_digest(records).encode()}
    schema = _merged_schema(files)
    frames_path = sweep_dir / FRAMES_FILE
    if schema is None:
        write_parquet_atomic(pd.DataFrame(), frames_path, metadata)
    else:
        schema = schema.with_metadata({**(schema.metadata or {}), **metadata})
        atomic_write(frames_path, lambda tmp: _write_frames(tmp, files, schema))
    write_parquet_atomic(runs, sweep_dir / RUNS_FILE, metadata)
    return runs


def _rows_files(sweep_dir: Path, records: list[dict[str, Any]]) -> list[tuple[Path, list]]:
    """``[(rows file, its records)]``, files in the order of their smallest run id (a sweep of
    runs computed alone is merged in run id order, as it always was)."""
    by_file: dict[Path, list[dict[str, Any]]] = {}
    for record in records:
        by_file.setdefault(rows_path(sweep_dir, record), []).append(record)
    return sorted(by_file.items(), key=lambda item: min(r["run_id"] for r in item[1]))


def _file_table(path: Path, records: list[dict[str, Any]]) -> pa.Table:
    """The checked rows of ``records`` from their rows file (see :func:`read_rows`)."""
    sha = records[0].get("rows_sha256")
    if any(r.get("rows_sha256") != sha for r in records):
        raise StoreError(path, "records disagree on the rows file's SHA-256")
    table = read_checked_table(path, sha)
    if not any(r.get("rows_file") for r in records):  # a run's own file
        if table.num_rows != records[0].get("n_rows", table.num_rows):
            raise StoreError(path, f"{table.num_rows} rows, its record says {records[0]['n_rows']}")
        return table
    ids = table.column("run_id").to_pandas()
    counts = ids.value_counts()
    for r in records:
        if int(counts.get(r["run_id"], 0)) != r.get("n_rows"):
            raise StoreError(path, f"{counts.get(r['run_id'], 0)} rows of {r['run_id']}, "
                             f"its record says {r.get('n_rows')}")  # fmt: skip
    wanted = ids.isin([r["run_id"] for r in records]).to_numpy()
    return table if wanted.all() else table.filter(pa.array(wanted))


def _merged_schema(files: list[tuple[Path, list]]) -> pa.Schema | None:
    """One schema for every rows file (types promoted where files differ), or None."""
    schemas = []
    for path, _ in files:
        try:
            schemas.append(pq.read_schema(path).remove_metadata())
        except (OSError, pa.ArrowException) as exc:
            raise StoreError(path, f"rows file corrupt ({type(exc).__name__}: {exc})") from None
    if not schemas:
        return None
    return pa.unify_schemas(schemas, promote_options="permissive")


def _conform(table: pa.Table, schema: pa.Schema) -> pa.Table:
    """``table`` with ``schema``'s columns in its order (missing ones null) and types (a
    column already of its type is not cast: 76 casts per rows file cost a sweep of 175 rows
    files 0.5 s)."""
    if table.schema.remove_metadata().equals(schema.remove_metadata()):
        return table.replace_schema_metadata(schema.metadata)
    columns = [
        _cast(table.column(f.name), f.type)
        if f.name in table.column_names
        else pa.nulls(table.num_rows, f.type)
        for f in schema
    ]
    return pa.Table.from_arrays(columns, schema=schema)


def _cast(column: pa.ChunkedArray, kind: pa.DataType) -> pa.ChunkedArray:
    """``column`` as type ``kind`` (itself when it already is)."""
    return column if column.type == kind else column.cast(kind)


def _write_frames(path: Path, files: list[tuple[Path, list]], schema: pa.Schema) -> None:
    """Stream every rows file into one parquet file (rows of a file in run id order), a row
    group per run of consecutive rows of one partition (:data:`PARTITION_COLUMNS`)."""
    buffer: list[pa.Table] = []
    buffered_key: tuple | None = None
    with pq.ParquetWriter(path, schema) as writer:

        def flush() -> None:
            if buffer:
                writer.write_table(pa.concat_tables(buffer), row_group_size=ROW_GROUP_ROWS)
                buffer.clear()

        for (_, records), table in zip(files, _read_ahead(files, schema), strict=True):
            if len({r["run_id"] for r in records}) > 1 and not _sorted(table["run_id"]):
                table = table.take(pc.sort_indices(table, [("run_id", "ascending")]))
            for key, piece in _partitions(table):
                if key != buffered_key or sum(t.num_rows for t in buffer) >= ROW_GROUP_ROWS:
                    flush()
                buffer.append(piece)
                buffered_key = key
        flush()


def _read_ahead(files: list[tuple[Path, list]], schema: pa.Schema) -> Iterator[pa.Table]:
    """The checked, conformed table of each rows file, in order, read by threads ahead of the
    writer (Arrow releases the GIL while it decodes: reading 175 small files one after the
    other was 0.65 s of a merge): at most :data:`READ_AHEAD` files and, beyond the next one,
    :data:`READ_AHEAD_ROWS` rows (as their records count them) are waiting. A corrupt file's
    :class:`StoreError` is raised in its turn."""
    with ThreadPoolExecutor(max_workers=READ_THREADS) as pool:
        pending: deque = deque()
        waiting_rows = 0
        queued = deque(files)
        while queued or pending:
            while queued and (
                not pending or (len(pending) < READ_AHEAD and waiting_rows < READ_AHEAD_ROWS)
            ):
                path, records = queued.popleft()
                rows = sum(int(r.get("n_rows") or 0) for r in records)
                pending.append((rows, pool.submit(_read_one, path, records, schema)))
                waiting_rows += rows
            rows, future = pending.popleft()
            waiting_rows -= rows
            yield future.result()


def _read_one(path: Path, records: list[dict[str, Any]], schema: pa.Schema) -> pa.Table:
    """One rows file's checked rows of ``records`` with the merged ``schema``."""
    return _conform(_file_table(path, records), schema)


def _sorted(column: pa.ChunkedArray) -> bool:
    """True when ``column`` is in ascending order (batches store their rows so)."""
    values = column.combine_chunks()
    return len(values) < 2 or pc.all(pc.less_equal(values[:-1], values[1:])).as_py()


def _partitions(table: pa.Table) -> Iterator[tuple[tuple, pa.Table]]:
    """``(partition key, rows)`` of each run of consecutive rows with one key."""
    keys = table.select(list(PARTITION_COLUMNS)).to_pandas()
    change = (keys != keys.shift()).any(axis=1).to_numpy()
    starts = [*change.nonzero()[0].tolist(), len(keys)]
    for begin, end in itertools.pairwise(starts):
        yield tuple(keys.iloc[begin]), table.slice(begin, end - begin)


def merged_row_count(sweep_dir: Path) -> int:
    """Rows of the merged ``frames.parquet`` (from its footer: nothing loaded)."""
    return pq.ParquetFile(Path(sweep_dir) / FRAMES_FILE).metadata.num_rows


def merge_is_current(sweep_dir: Path, records: list[dict[str, Any]] | None = None) -> bool:
    """True when both merged files exist and were merged from today's run records
    (``records``: :func:`list_records` of the sweep, when already read)."""
    sweep_dir = Path(sweep_dir)
    digest = merge_digest(list_records(sweep_dir) if records is None else records)
    return all(_stored_digest(sweep_dir / name) == digest for name in (FRAMES_FILE, RUNS_FILE))


def load_sweep(
    sweep_dir: Path, columns: list[str] | None = None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(frames, runs)`` of a sweep, re-merged from ``runs/`` first when the merged files
    are missing, unreadable or stale (a run was added, recomputed or removed since).
    ``columns``: only these columns of the rows (those the sweep has; None: all).

    Raises :class:`StoreError` naming the file when an ok run's rows file is missing or
    corrupt (checked against its record's SHA-256 every time) or the sweep folder has no
    ``runs/``.
    """
    sweep_dir = Path(sweep_dir)
    if not (sweep_dir / RUNS_DIR).is_dir():
        raise StoreError(sweep_dir, f"no {RUNS_DIR}/ folder: not a sweep folder")
    checks, records = Checks(), list_records(sweep_dir)
    for record in records:
        if record.get("status") == "ok":
            path = rows_path(sweep_dir, record)
            if (problem := rows_problem(path, record.get("rows_sha256"), checks)) is not None:
                raise StoreError(path, f"rows file {problem}")
    if not merge_is_current(sweep_dir, records):
        merge(sweep_dir)
    frames_path = sweep_dir / FRAMES_FILE
    if columns is not None:
        present = set(pq.read_schema(frames_path).names)
        columns = [c for c in columns if c in present]
    try:
        return pd.read_parquet(frames_path, columns=columns), pd.read_parquet(sweep_dir / RUNS_FILE)
    except Exception:  # damaged between the check and the read: merge again
        runs = merge(sweep_dir)
        return pd.read_parquet(frames_path, columns=columns), runs
