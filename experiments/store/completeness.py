"""When a stored run is complete: its record's status, its rows file's checksum, the identities
of the input files it read; and the lock one process holds while it computes a run."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from experiments.store.files import (
    COMPLETE_STATUSES,
    NO_RECORD,
    RUNS_DIR,
    read_record,
    rows_path,
    run_paths,
)

try:
    import fcntl
except ImportError:  # pragma: no cover - non-POSIX systems: no cross-process locking
    fcntl = None


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
    if (problem := rows_problem(path, record["rows_sha256"], checks)) is not None:
        return f"rows file {path.name} {problem}"
    changed = changed_inputs(record["inputs"], checks.inputs if checks else None)
    if changed:
        more = f" and {len(changed) - 1} more" if len(changed) > 1 else ""
        return f"input changed since it ran: {changed[0]}{more}"
    return None


def rows_problem(path: Path, sha256: str | None, checks: Checks | None = None) -> str | None:
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
