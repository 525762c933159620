"""The one way this project writes a file: to a temporary name in the same folder, renamed
into place, so a reader (or a killed process) never sees half a file."""

from __future__ import annotations

import contextlib
import functools
import os
import socket
import tempfile
import time
from collections.abc import Callable
from pathlib import Path


def atomic_write(path: Path | str, write: Callable[[Path], None], mode: int = 0o644) -> Path:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it to ``path``.

    The folder is created when missing; the temporary file (``.<name>.<host>-<pid>.<random>
    .tmp``: :func:`remove_stale_temporaries` tells a dead writer's) is removed when ``write``
    raises (the exception propagates). ``mode``: permissions of the result (``mkstemp`` makes files
    private; results are for everyone to read).
    """
    path = Path(path)
    prefix = temporary_prefix(path.name)
    try:  # the folder made only when missing (a sweep writes thousands of records into one)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=prefix, suffix=".tmp")
    except FileNotFoundError:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=prefix, suffix=".tmp")
    os.close(fd)
    try:
        write(Path(tmp))
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    return path


def write_bytes_atomic(data: bytes, path: Path | str) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_write`)."""
    return atomic_write(path, lambda tmp: tmp.write_bytes(data))


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
