"""The one way this project writes a file: to a temporary name in the same folder, renamed
into place, so a reader (or a killed process) never sees half a file."""

from __future__ import annotations

import contextlib
import functools
import os
import socket
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path


def atomic_write(path: Path | str, write: Callable[[Path], None], mode: int = 0o644) -> Path:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it to ``path``.

    The folder is created when missing; the temporary file (``.<name>.<host>-<pid>.<random>
    .tmp``: :func:`remove_stale_temporaries` tells a dead writer's) is removed when ``write``
    raises (the exception propagates). ``mode``: permissions of the result (``mkstemp`` makes files
    private; results are for everyone to read).
    """
    path = Path(path)
    fd, tmp = _temporary(path)
    os.close(fd)
    with _renamed_or_removed(tmp, path):
        write(Path(tmp))
        os.chmod(tmp, mode)
    return path


def write_bytes_atomic(data: bytes, path: Path | str) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`write_bytes_identified`); ``path``."""
    write_bytes_identified(data, path)
    return Path(path)


def write_bytes_identified(data: bytes, path: Path | str, mode: int = 0o644) -> os.stat_result:
    """Write ``data`` to ``path`` as :func:`atomic_write` does, through the temporary file's
    own descriptor (no second open by name: 485 µs instead of 835 µs a record-sized file, on
    this machine's disk); the file's stat as written, taken before the rename (which keeps
    inode, size and mtime: a writer that replaces it after that gives another identity)."""
    path = Path(path)
    fd, tmp = _temporary(path)
    with _renamed_or_removed(tmp, path):
        try:
            view = memoryview(data)
            while view:  # os.write may write less than asked
                view = view[os.write(fd, view) :]
            os.fchmod(fd, mode)
            written = os.fstat(fd)
        finally:
            os.close(fd)
    return written


def _temporary(path: Path) -> tuple[int, str]:
    """(descriptor, name) of a new temporary file beside ``path`` (the folder made only when
    missing: a sweep writes thousands of records into one)."""
    prefix = temporary_prefix(path.name)
    try:
        return tempfile.mkstemp(dir=path.parent, prefix=prefix, suffix=".tmp")
    except FileNotFoundError:
        path.parent.mkdir(parents=True, exist_ok=True)
        return tempfile.mkstemp(dir=path.parent, prefix=prefix, suffix=".tmp")


@contextlib.contextmanager
def _renamed_or_removed(tmp: str, path: Path) -> Iterator[None]:
    """Rename ``tmp`` to ``path`` after the block; remove it when the block raises."""
    try:
        yield
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


#: A temporary file whose writer cannot be told dead is stale after this many seconds.
STALE_AFTER_S = 3600.0


@functools.cache
def _host() -> str:
    return socket.gethostname().replace(".", "_").replace("-", "_")


def temporary_prefix(name: str, pid: int | None = None) -> str:
    """Prefix of the temporary files of ``name`` written by process ``pid`` (default: this
    one) on this host."""
    return f".{name}.{_host()}-{os.getpid() if pid is None else pid}."


def _writer_dead(tmp: Path) -> bool:
    """True when ``tmp`` was written by a process of this host that no longer runs."""
    try:
        host, pid = tmp.name[: -len(".tmp")].rsplit(".", 2)[1].rsplit("-", 1)
        if host != _host():
            return False
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return True
    except (ValueError, IndexError, OSError):
        return False
    return False


def remove_stale_temporaries(folder: Path | str) -> int:
    """Remove the temporary files of :func:`atomic_write` in ``folder`` left by killed
    writers (of this host, their process gone; else older than :data:`STALE_AFTER_S`); a
    live writer's are kept. Returns how many were removed."""
    removed = 0
    for tmp in Path(folder).glob(".*.tmp"):
        with contextlib.suppress(OSError):
            if _writer_dead(tmp) or time.time() - tmp.stat().st_mtime > STALE_AFTER_S:
                tmp.unlink()
                removed += 1
    return removed
