"""Results store: one folder per sweep, one record + parquet file per run, merged datasets.

Layout of a sweep folder::

    <sweep>/runs/<run_id>.parquet     frame-pair rows of one run (written first)
    <sweep>/runs/<run_id>.json        the run record (written last: marks the run complete)
    <sweep>/runs/<run_id>.lock        held (flock) while a process computes the run
    <sweep>/frames.parquet            every run's rows, merged (collect)
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
import json
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from ttc.atomic import atomic_write, write_bytes_atomic

try:
    import fcntl
except ImportError:  # pragma: no cover - non-POSIX systems: no cross-process locking
    fcntl = None

RUNS_DIR = "runs"
FRAMES_FILE = "frames.parquet"
RUNS_FILE = "runs.parquet"
#: Progress markers of a sweep (one file per finished job), read by the progress bar and the
#: summary: ``.progress/<id of the sweep invocation>/``, named to the jobs by the variable
#: :data:`PROGRESS_ENV`, so two sweeps into one folder count their own jobs.
PROGRESS_DIR = ".progress"
PROGRESS_ENV = "TTC_PROGRESS_DIR"
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


def write_json_atomic(obj: Any, path: Path) -> None:
    """Write ``obj`` to ``path`` as JSON, atomically."""
    atomic_write(path, lambda tmp: tmp.write_text(json.dumps(obj, indent=1, default=str)))


def run_paths(sweep_dir: Path, run_id: str) -> tuple[Path, Path]:
    """(rows parquet, record json) of one run."""
    base = Path(sweep_dir) / RUNS_DIR
    return base / f"{run_id}.parquet", base / f"{run_id}.json"


def read_record(sweep_dir: Path, run_id: str) -> dict[str, Any] | None:
    """The record of a run, or None when absent or unreadable."""
    _, record_path = run_paths(sweep_dir, run_id)
    try:
        return json.loads(record_path.read_text())
    except (OSError, ValueError):
        return None


def progress_dir(sweep_dir: Path) -> Path:
    """This sweep invocation's progress folder (``$TTC_PROGRESS_DIR`` when a sweep set it)."""
    return Path(os.environ.get(PROGRESS_ENV) or Path(sweep_dir) / PROGRESS_DIR / "last")


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


def changed_inputs(recorded: str) -> list[str]:
    """Paths of :func:`input_identities` whose identity differs today."""
    old = json.loads(recorded)
    new = json.loads(input_identities(path for path, _, _ in old))
    return [a[0] for a, b in zip(old, new, strict=True) if a != b]


# -- completeness --------------------------------------------------------------------------
def read_rows(sweep_dir: Path, record: dict[str, Any]) -> pd.DataFrame:
    """The rows of an ``ok`` run, checked against its record (SHA-256 when recorded, row
    count); :class:`StoreError` naming the file when missing, corrupt or inconsistent."""
    rows_path, _ = run_paths(sweep_dir, record["run_id"])
    try:
        data = rows_path.read_bytes()
    except OSError as exc:
        raise StoreError(rows_path, f"rows file unreadable ({exc.strerror})") from None
    expected = record.get("rows_sha256")
    if expected and hashlib.sha256(data).hexdigest() != expected:
        raise StoreError(rows_path, "rows file corrupt (SHA-256 differs from its record)")
    try:
        rows = pd.read_parquet(io.BytesIO(data))
    except Exception as exc:  # pyarrow raises many types for damaged files
        raise StoreError(rows_path, f"rows file corrupt ({type(exc).__name__}: {exc})") from None
    if len(rows) != record.get("n_rows", len(rows)):
        raise StoreError(rows_path, f"{len(rows)} rows, its record says {record['n_rows']}")
    return rows


def incomplete_reason(sweep_dir: Path, run_id: str) -> str | None:
    """None when the run is complete (see the module docstring), else why not, in words."""
    record = read_record(sweep_dir, run_id)
    if record is None:
        _, record_path = run_paths(sweep_dir, run_id)
        return "its record is unreadable" if record_path.exists() else NO_RECORD
    status = record.get("status")
    if status not in COMPLETE_STATUSES:
        return f"its record says {status}"
    if status == "skipped":
        return None
    rows_path, _ = run_paths(sweep_dir, run_id)
    if not record.get("rows_sha256") or "inputs" not in record:
        return "its record predates rows checksums and input identities"
    if (problem := _rows_problem(rows_path, record["rows_sha256"])) is not None:
        return f"rows file {rows_path.name} {problem}"
    changed = changed_inputs(record["inputs"])
    if changed:
        more = f" and {len(changed) - 1} more" if len(changed) > 1 else ""
        return f"input changed since it ran: {changed[0]}{more}"
    return None


def _rows_problem(rows_path: Path, sha256: str | None) -> str | None:
    """Why a rows file does not match the checksum of its record (None: it does)."""
    try:
        with rows_path.open("rb") as handle:
            digest = hashlib.file_digest(handle, "sha256").hexdigest()
    except OSError as exc:
        return f"unreadable ({exc.strerror})"
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
    rows_path, record_path = run_paths(sweep_dir, record["run_id"])
    if rows is not None:
        record["rows_sha256"] = write_parquet_atomic(rows, rows_path)
    write_json_atomic(record, record_path)


def list_records(sweep_dir: Path) -> list[dict[str, Any]]:
    """Every readable run record of a sweep, sorted by run id."""
    records = []
    for path in sorted((Path(sweep_dir) / RUNS_DIR).glob("*.json")):
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


def collect(sweep_dir: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Merge every run's rows and records into ``frames.parquet`` and ``runs.parquet``.

    Every ok run's rows are checked against its record; a missing or corrupt rows file raises
    :class:`StoreError` naming it (re-run the sweep to recompute it) and nothing is written.
    Call it when no job of the sweep is running (end of a multirun, or after a kill): it also
    deletes temporary files that killed jobs left behind.
    """
    sweep_dir = Path(sweep_dir)
    for stale in (sweep_dir / RUNS_DIR).glob(".*.tmp"):  # left by a killed job
        stale.unlink(missing_ok=True)
    records = list_records(sweep_dir)
    runs = pd.DataFrame.from_records(records)
    parts = [read_rows(sweep_dir, r) for r in records if r.get("status") == "ok"]
    frames = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()
    if not runs.empty:
        runs = runs.sort_values("run_id", ignore_index=True)
    metadata = {DIGEST_KEY: merge_digest(records).encode()}
    write_parquet_atomic(runs, sweep_dir / RUNS_FILE, metadata)
    write_parquet_atomic(frames, sweep_dir / FRAMES_FILE, metadata)
    return frames, runs


def merge_is_current(sweep_dir: Path) -> bool:
    """True when both merged files exist and were merged from today's run records."""
    sweep_dir = Path(sweep_dir)
    digest = merge_digest(list_records(sweep_dir))
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
    for record in list_records(sweep_dir):
        if record.get("status") == "ok":
            rows_path, _ = run_paths(sweep_dir, record["run_id"])
            if (problem := _rows_problem(rows_path, record.get("rows_sha256"))) is not None:
                raise StoreError(rows_path, f"rows file {problem}")
    if merge_is_current(sweep_dir):
        try:
            return pd.read_parquet(sweep_dir / FRAMES_FILE), pd.read_parquet(sweep_dir / RUNS_FILE)
        except Exception:  # damaged between the check and the read: merge again
            pass
    return collect(sweep_dir)
