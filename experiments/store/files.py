"""The files of a sweep folder: their names, the atomic writers of rows and records, and the
checked readers (:class:`StoreError` names a damaged file)."""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import pickle
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from ttc.atomic import write_bytes_atomic, write_bytes_identified

try:
    import fcntl
except ImportError:  # pragma: no cover - non-POSIX systems: no cross-process locking
    fcntl = None

RUNS_DIR = "runs"
#: The merged files earlier versions wrote beside ``runs/`` (stale now: nothing reads them;
#: ``ttc-bench compact`` removes them).
LEGACY_MERGED_FILES = ("frames.parquet", "runs.parquet")
#: Held shared while a process stores runs, exclusive while a compaction repoints records.
STORE_LOCK = ".store.lock"
COMPLETE_STATUSES = ("ok", "skipped")
#: Folder of the run records' index files, under the sweep folder
#: (:mod:`experiments.store.record_index`).
INDEX_DIR = ".records"
#: A record file's identity: (inode, size, mtime in ns).
Identity = tuple[int, int, int]
#: A record as an index file keeps it: file name → (its file's identity, the record).
IndexEntries = dict[str, tuple[Identity, dict[str, Any]]]
#: :func:`incomplete_reason` of a run never computed in this sweep folder.
NO_RECORD = "no record"


class StoreError(RuntimeError):
    """A file of the results store is unreadable or inconsistent; ``path`` names it."""

    def __init__(self, path: Path | str, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


def parquet_bytes(df: pd.DataFrame | pa.Table, metadata: dict[bytes, bytes] | None = None) -> bytes:
    """``df`` (a frame or an Arrow table) as parquet file bytes (no index), with extra
    schema ``metadata``."""
    table = df if isinstance(df, pa.Table) else pa.Table.from_pandas(df, preserve_index=False)
    if metadata:
        table = table.replace_schema_metadata({**(table.schema.metadata or {}), **metadata})
    sink = io.BytesIO()
    pq.write_table(table, sink)
    return sink.getvalue()


def write_parquet_atomic(
    df: pd.DataFrame | pa.Table, path: Path, metadata: dict | None = None
) -> str:
    """Write ``df`` (a frame or an Arrow table) to ``path`` as parquet, atomically; return
    the file's SHA-256."""
    data = parquet_bytes(df, metadata)
    write_bytes_atomic(data, path)
    return hashlib.sha256(data).hexdigest()


def write_json_atomic(obj: Any, path: Path, indent: int | None = 1) -> None:
    """Write ``obj`` to ``path`` as JSON, atomically (``indent=None``: one line, written
    several times faster: records of batches and plans)."""
    write_bytes_atomic(json.dumps(obj, indent=indent, default=str).encode(), path)


def write_record(sweep_dir: Path, record: dict[str, Any]) -> IndexEntries:
    """Write a run's record (``runs/<run_id>.json``, one line, atomically); its index entry:
    the identity of the file written (:func:`ttc.atomic.write_bytes_identified`: taken
    before the rename) and the record as the file reads back (a JSON round trip: what a
    listing would parse)."""
    text = json.dumps(record, default=str)
    path = run_paths(sweep_dir, record["run_id"])[1]
    st = write_bytes_identified(text.encode(), path)
    return {path.name: ((st.st_ino, st.st_size, st.st_mtime_ns), json.loads(text))}


def write_index(sweep_dir: Path, entries: IndexEntries) -> Path:
    """Write ``entries`` as a new index file of records
    (``<sweep>/.records/index-<sha>.pkl``, never rewritten); its path."""
    data = pickle.dumps(_texts_shared(entries), protocol=pickle.HIGHEST_PROTOCOL)
    name = f"index-{hashlib.sha256(data).hexdigest()[:16]}.pkl"
    return write_bytes_atomic(data, Path(sweep_dir) / INDEX_DIR / name)


#: Record texts at least this long are stored once per index file when records share them.
SHARED_TEXT_CHARS = 64


def _texts_shared(entries: IndexEntries) -> IndexEntries:
    """``entries`` with equal long text values (a batch's ``inputs``: 3.7 kB of a 7 kB
    record, the same for each of its runs) and equal field names made one object each, which
    pickle then stores once (and loads as one): ``grand`` 0–18's index 233 MB before; a
    record's ~40 field names, new strings in each record parsed, took a quarter of loading
    an index (5,600 records: 39 → 28 ms)."""
    seen: dict[str, str] = {}
    out: IndexEntries = {}
    for name, (identity, record) in entries.items():
        out[name] = (identity, {
            seen.setdefault(k, k): (
                seen.setdefault(v, v) if isinstance(v, str) and len(v) >= SHARED_TEXT_CHARS else v
            )
            for k, v in record.items()
        })  # fmt: skip
    return out


def save_records(sweep_dir: Path, records: Iterable[dict[str, Any]]) -> None:
    """Write each record (:func:`write_record`), then one index file of them, so that the
    next listing parses none of these files (an index that cannot be written is left out:
    the files are the authority)."""
    entries: IndexEntries = {}
    for record in records:
        entries.update(write_record(sweep_dir, record))
    keep_index(sweep_dir, entries)


def keep_index(sweep_dir: Path, entries: IndexEntries) -> None:
    """:func:`write_index` of ``entries`` when there are any, nothing where it cannot be
    written (a read-only or full disk: the listing reads the record files)."""
    if entries:
        with contextlib.suppress(OSError):
            write_index(sweep_dir, entries)


def run_paths(sweep_dir: Path, run_id: str) -> tuple[Path, Path]:
    """(rows parquet of a run computed alone, record json) of one run."""
    base = Path(sweep_dir) / RUNS_DIR
    return base / f"{run_id}.parquet", base / f"{run_id}.json"


def rows_path(sweep_dir: Path, record: dict[str, Any]) -> Path:
    """The rows file a record points to: its batch's (``rows_file``) or its own."""
    name = record.get("rows_file") or f"{record['run_id']}.parquet"
    return Path(sweep_dir) / RUNS_DIR / name


def read_record(sweep_dir: Path, run_id: str) -> dict[str, Any] | None:
    """The record of a run, or None when absent or unreadable."""
    _, record_path = run_paths(sweep_dir, run_id)
    try:
        return json.loads(record_path.read_text())
    except (OSError, ValueError):
        return None


def read_rows(sweep_dir: Path, record: dict[str, Any]) -> pd.DataFrame:
    """The rows of an ``ok`` run, checked against its record (SHA-256 of its rows file when
    recorded, row count); :class:`StoreError` naming the file when missing, corrupt or
    inconsistent. A batch's rows file is read whole and cut to the run's rows."""
    path = rows_path(sweep_dir, record)
    rows = read_checked(path, record.get("rows_sha256"))
    if record.get("rows_file"):
        rows = rows[rows["run_id"] == record["run_id"]].reset_index(drop=True)
    if len(rows) != record.get("n_rows", len(rows)):
        raise StoreError(path, f"{len(rows)} rows, its record says {record['n_rows']}")
    return rows


def read_checked(path: Path, sha256: str | None) -> pd.DataFrame:
    """A rows file, its SHA-256 checked when given; :class:`StoreError` naming it."""
    return read_checked_table(path, sha256).to_pandas()


def read_checked_table(
    path: Path, sha256: str | None, columns: list[str] | None = None
) -> pa.Table:
    """:func:`read_checked` as an Arrow table (as stored: no pandas round trip); ``columns``:
    only those of them the file has decoded (the whole file is checked all the same)."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise StoreError(path, f"rows file unreadable ({exc.strerror})") from None
    if sha256 and hashlib.sha256(data).hexdigest() != sha256:
        raise StoreError(path, "rows file corrupt (SHA-256 differs from its record)")
    try:
        if columns is None:
            return pq.read_table(pa.BufferReader(data))
        file = pq.ParquetFile(pa.BufferReader(data))
        stored = set(file.schema_arrow.names)
        return file.read(columns=[c for c in columns if c in stored])
    except Exception as exc:  # pyarrow raises many types for damaged files
        raise StoreError(path, f"rows file corrupt ({type(exc).__name__}: {exc})") from None


@contextlib.contextmanager
def store_lock(sweep_dir: Path, exclusive: bool = False) -> Iterator[None]:
    """Hold ``runs/.store.lock`` (``flock``): shared while a process writes rows files and
    records (many at once), exclusive while a compaction checks and repoints records and
    removes the files no record names any more (no writer between its check and its
    change)."""
    lock_path = Path(sweep_dir) / RUNS_DIR / STORE_LOCK
    lock_path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
        yield
    finally:
        os.close(fd)  # releases the lock


def save_run(sweep_dir: Path, record: dict[str, Any], rows: pd.DataFrame | None) -> None:
    """Store a run: rows first (their SHA-256 goes into the record), then the record that
    marks it complete."""
    own_rows, record_path = run_paths(sweep_dir, record["run_id"])
    with store_lock(sweep_dir):
        if rows is not None:
            record["rows_sha256"] = write_parquet_atomic(rows, own_rows)
        write_json_atomic(record, record_path)


def save_batch(
    sweep_dir: Path, batch_id: str, records: list[dict[str, Any]], rows: pd.DataFrame
) -> None:
    """Store the runs of a batch: the rows of its ``ok`` runs in one file first, named
    ``<batch_id>-<first 12 hex digits of its SHA-256>.parquet`` (a later re-run of some of the
    batch's runs writes a new file and never touches the one other records point to), then
    each run's record with ``rows_file``, ``rows_sha256`` and ``n_rows``. Rows are stored in
    run id order (a stable sort: each run's rows keep theirs)."""
    if len(rows):  # encoded before the lock is taken
        data = parquet_bytes(rows.sort_values("run_id", kind="stable", ignore_index=True))
        sha = hashlib.sha256(data).hexdigest()
        name = f"{batch_id}-{sha[:12]}.parquet"
    with store_lock(sweep_dir):
        if len(rows):
            write_bytes_atomic(data, Path(sweep_dir) / RUNS_DIR / name)
            for record in records:
                if record.get("status") == "ok":
                    record.update(rows_file=name, rows_sha256=sha)
        save_records(sweep_dir, records)
