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

from __future__ import annotations

import contextlib
import hashlib
import io
import itertools
import json
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from ttc.atomic import atomic_write, write_bytes_atomic

try:
    import fcntl
except ImportError:  # pragma: no cover - non-POSIX systems: no cross-process locking
    fcntl = None

RUNS_DIR = "runs"
FRAMES_FILE = "frames.parquet"
RUNS_FILE = "runs.parquet"
COMPLETE_STATUSES = ("ok", "skipped")
#: :func:`incomplete_reason` of a run never computed in this sweep folder.
NO_RECORD = "no record"
#: Parquet schema-metadata key of the merged files: the digest of the records merged.
DIGEST_KEY = b"ttc_merge_digest"


class StoreError(RuntimeError):
    """A file of the results store is unreadable or inconsistent; ``path`` names it."""

    def __init__(self, path: Path | str, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


def parquet_bytes(df: pd.DataFrame, metadata: dict[bytes, bytes] | None = None) -> bytes:
    """``df`` as parquet file bytes (no index), with extra schema ``metadata``."""
    table = pa.Table.from_pandas(df, preserve_index=False)
    if metadata:
        table = table.replace_schema_metadata({**(table.schema.metadata or {}), **metadata})
    sink = io.BytesIO()
    pq.write_table(table, sink)
    return sink.getvalue()


def write_parquet_atomic(df: pd.DataFrame, path: Path, metadata: dict | None = None) -> str:
    """Write ``df`` to ``path`` as parquet, atomically; return the file's SHA-256."""
    data = parquet_bytes(df, metadata)
    write_bytes_atomic(data, path)
    return hashlib.sha256(data).hexdigest()


def write_json_atomic(obj: Any, path: Path, indent: int | None = 1) -> None:
    """Write ``obj`` to ``path`` as JSON, atomically (``indent=None``: one line, written
    several times faster: records of batches and plans)."""
    text = json.dumps(obj, indent=indent, default=str)
    atomic_write(path, lambda tmp: tmp.write_text(text))


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


# -- input identities ----------------------------------------------------------------------
def input_identities(paths: Iterable[Path | str]) -> str:
    """JSON list of ``[path, size in bytes, mtime in ns]`` of each file (``null``s when the
    file does not exist): what a run read, stored in its record."""
    out = []
    for path in paths:
        try:
            stat = os.stat(path)
            out.append([str(path), stat.st_size, stat.st_mtime_ns])
        except OSError:
            out.append([str(path), None, None])
    return json.dumps(out, separators=(",", ":"))


def changed_inputs(recorded: str, memo: dict[str, list[str]] | None = None) -> list[str]:
    """Paths of :func:`input_identities` whose identity differs today (``memo``: answers
    already found, by recorded text: runs of one sweep mostly read the same files)."""
    if memo is not None and recorded in memo:
        return memo[recorded]
    old = json.loads(recorded)
    new = json.loads(input_identities(path for path, _, _ in old))
    changed = [a[0] for a, b in zip(old, new, strict=True) if a != b]
    if memo is not None:
        memo[recorded] = changed
    return changed


# -- completeness --------------------------------------------------------------------------
def read_rows(sweep_dir: Path, record: dict[str, Any]) -> pd.DataFrame:
    """The rows of an ``ok`` run, checked against its record (SHA-256 of its rows file when
    recorded, row count); :class:`StoreError` naming the file when missing, corrupt or
    inconsistent. A batch's rows file is read whole and cut to the run's rows."""
    path = rows_path(sweep_dir, record)
    rows = _read_checked(path, record.get("rows_sha256"))
    if record.get("rows_file"):
        rows = rows[rows["run_id"] == record["run_id"]].reset_index(drop=True)
    if len(rows) != record.get("n_rows", len(rows)):
        raise StoreError(path, f"{len(rows)} rows, its record says {record['n_rows']}")
    return rows


def _read_checked(path: Path, sha256: str | None) -> pd.DataFrame:
    """A rows file, its SHA-256 checked when given; :class:`StoreError` naming it."""
    return _read_checked_table(path, sha256).to_pandas()


def _read_checked_table(path: Path, sha256: str | None) -> pa.Table:
    """:func:`_read_checked` as an Arrow table (as stored: no pandas round trip)."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise StoreError(path, f"rows file unreadable ({exc.strerror})") from None
    if sha256 and hashlib.sha256(data).hexdigest() != sha256:
        raise StoreError(path, "rows file corrupt (SHA-256 differs from its record)")
    try:
        return pq.read_table(pa.BufferReader(data))
    except Exception as exc:  # pyarrow raises many types for damaged files
        raise StoreError(path, f"rows file corrupt ({type(exc).__name__}: {exc})") from None


class Checks:
    """Memory of the checks made while deciding many runs' completeness: a rows file's
    digest is computed once (a batch's file serves many runs), input identities once per
    distinct list."""

    def __init__(self) -> None:
        self.digests: dict[Path, str | OSError] = {}
        self.inputs: dict[str, list[str]] = {}

    def digest(self, path: Path) -> str | OSError:
        """SHA-256 of a file, or the OSError reading it raised."""
        if path not in self.digests:
            try:
                with path.open("rb") as handle:
                    self.digests[path] = hashlib.file_digest(handle, "sha256").hexdigest()
            except OSError as exc:
                self.digests[path] = exc
        return self.digests[path]


def incomplete_reason(sweep_dir: Path, run_id: str, checks: Checks | None = None) -> str | None:
    """None when the run is complete (see the module docstring), else why not, in words.
    ``checks``: share file digests and input checks across calls (one planning pass)."""
    record = read_record(sweep_dir, run_id)
    if record is None:
        _, record_path = run_paths(sweep_dir, run_id)
        return "its record is unreadable" if record_path.exists() else NO_RECORD
    return record_problem(sweep_dir, record, checks)


def record_problem(
    sweep_dir: Path, record: dict[str, Any], checks: Checks | None = None
) -> str | None:
    """:func:`incomplete_reason` of a record already read."""
    status = record.get("status")
    if status not in COMPLETE_STATUSES:
        return f"its record says {status}"
    if status == "skipped":
        return None
    path = rows_path(sweep_dir, record)
    if not record.get("rows_sha256") or "inputs" not in record:
        return "its record predates rows checksums and input identities"
    if (problem := _rows_problem(path, record["rows_sha256"], checks)) is not None:
        return f"rows file {path.name} {problem}"
    changed = changed_inputs(record["inputs"], checks.inputs if checks else None)
    if changed:
        more = f" and {len(changed) - 1} more" if len(changed) > 1 else ""
        return f"input changed since it ran: {changed[0]}{more}"
    return None


def _rows_problem(path: Path, sha256: str | None, checks: Checks | None = None) -> str | None:
    """Why a rows file does not match the checksum of its record (None: it does)."""
    digest = (checks or Checks()).digest(path)
    if isinstance(digest, OSError):
        return f"unreadable ({digest.strerror})"
    if sha256 and digest != sha256:
        return "corrupt (SHA-256 differs from its record)"
    return None


def is_complete(sweep_dir: Path, run_id: str) -> bool:
    """True when the run finished as ok (rows and inputs as recorded) or skipped."""
    return incomplete_reason(sweep_dir, run_id) is None


@contextlib.contextmanager
def run_lock(sweep_dir: Path, run_id: str, holder: str = "") -> Iterator[None]:
    """Hold ``runs/<run_id>.lock`` (blocking ``flock``): one process computes a run at a time,
    across sweeps started into one folder. The file names the holder while held: JSON with
    ``pid`` and ``holder`` (e.g. the setting)."""
    lock_path = Path(sweep_dir) / RUNS_DIR / f"{run_id}.lock"
    lock_path.parent.mkdir(parents=True, exist_ok=True)
    with open(lock_path, "a+") as handle:
        if fcntl is not None:
            fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            handle.truncate(0)
            handle.write(json.dumps({"pid": os.getpid(), "holder": holder}))
            handle.flush()
            yield
        finally:
            handle.truncate(0)
            if fcntl is not None:
                fcntl.flock(handle, fcntl.LOCK_UN)


def save_run(sweep_dir: Path, record: dict[str, Any], rows: pd.DataFrame | None) -> None:
    """Store a run: rows first (their SHA-256 goes into the record), then the record that
    marks it complete."""
    own_rows, record_path = run_paths(sweep_dir, record["run_id"])
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
    run id order (a stable sort: each run's rows keep theirs), the merged file's order."""
    if len(rows):
        data = parquet_bytes(rows.sort_values("run_id", kind="stable", ignore_index=True))
        sha = hashlib.sha256(data).hexdigest()
        name = f"{batch_id}-{sha[:12]}.parquet"
        write_bytes_atomic(data, Path(sweep_dir) / RUNS_DIR / name)
        for record in records:
            if record.get("status") == "ok":
                record.update(rows_file=name, rows_sha256=sha)
    for record in records:
        write_json_atomic(record, run_paths(sweep_dir, record["run_id"])[1], indent=None)


def list_records(sweep_dir: Path) -> list[dict[str, Any]]:
    """Every readable run record of a sweep, sorted by run id."""
    records = []
    for path in sorted((Path(sweep_dir) / RUNS_DIR).glob("*.json"), key=lambda p: p.name):
        with contextlib.suppress(ValueError, OSError):
            records.append(json.loads(path.read_text()))
    return records


# -- merged files --------------------------------------------------------------------------
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
    table = _read_checked_table(path, sha)
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
    """``table`` with ``schema``'s columns in its order (missing ones null) and types."""
    columns = [
        table.column(f.name).cast(f.type)
        if f.name in table.column_names
        else pa.nulls(table.num_rows, f.type)
        for f in schema
    ]
    return pa.Table.from_arrays(columns, schema=schema)


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

        for rows_file, records in files:
            table = _conform(_file_table(rows_file, records), schema)
            if len({r["run_id"] for r in records}) > 1 and not _sorted(table["run_id"]):
                table = table.take(pc.sort_indices(table, [("run_id", "ascending")]))
            for key, piece in _partitions(table):
                if key != buffered_key or sum(t.num_rows for t in buffer) >= ROW_GROUP_ROWS:
                    flush()
                buffer.append(piece)
                buffered_key = key
        flush()


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


def load_sweep(sweep_dir: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(frames, runs)`` of a sweep, re-merged from ``runs/`` first when the merged files
    are missing, unreadable or stale (a run was added, recomputed or removed since).

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
            if (problem := _rows_problem(path, record.get("rows_sha256"), checks)) is not None:
                raise StoreError(path, f"rows file {problem}")
    if merge_is_current(sweep_dir, records):
        try:
            return pd.read_parquet(sweep_dir / FRAMES_FILE), pd.read_parquet(sweep_dir / RUNS_FILE)
        except Exception:  # damaged between the check and the read: merge again
            pass
    return collect(sweep_dir)
