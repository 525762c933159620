"""When a warm server may serve a command, and where it listens. Standard library only: the
client computes this before it imports anything else.

A server serves only commands whose :func:`server_key` equals the key it computed *before*
importing the stack: the key covers every ``.py`` file of ``ttc``, ``experiments`` and the
Hydra plugins (path, size, modification time), the interpreter, ``sys.path`` and each of its
folders' modification time (``pip install`` changes them), and the environment (all of it
but a few variables a shell changes by itself). Any change gives another key, hence another
socket: stale code is never reused, and the old server ends after its idle timeout.

The socket is in a folder only this user can enter (``$XDG_RUNTIME_DIR/ttc-bench``, else
``<tmp>/ttc-bench-<uid>``, mode 0700, checked).
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path

#: Environment variable that turns the server off (``0``, ``off``, ``false``, ``no``).
SWITCH = "TTC_BENCH_SERVER"
#: Environment variable: seconds a server waits for a command before it ends.
IDLE_VARIABLE = "TTC_BENCH_SERVER_IDLE_S"
#: Default idle timeout (s).
IDLE_S = 600.0
#: Variables a shell changes by itself: left out of the key (the command still gets them).
IGNORED_VARIABLES = frozenset({"PWD", "OLDPWD", "SHLVL", "_"})
#: Folders (relative to the project's packages' parent) whose ``.py`` files are the code.
CODE_ROOTS = ("ttc", "experiments", "hydra_plugins/ttc_launcher", "hydra_plugins/ttc_sweeper")


def enabled(environ: Mapping[str, str]) -> bool:
    """Whether commands go to a warm server: on unless :data:`SWITCH` says off; Linux only
    (``os.pidfd_open`` and ``fork``)."""
    off = environ.get(SWITCH, "").strip().lower() in ("0", "off", "false", "no")
    return not off and sys.platform.startswith("linux") and hasattr(os, "pidfd_open")


def idle_seconds(environ: Mapping[str, str]) -> float:
    """The idle timeout (s): :data:`IDLE_VARIABLE`, else :data:`IDLE_S`."""
    try:
        return float(environ.get(IDLE_VARIABLE, IDLE_S))
    except ValueError:
        return IDLE_S


def runtime_dir(environ: Mapping[str, str]) -> Path:
    """The private folder of the sockets, made if missing; ``OSError`` when it is not this
    user's or others may enter it."""
    xdg = environ.get("XDG_RUNTIME_DIR", "")
    base = Path(xdg) / "ttc-bench" if xdg and os.path.isdir(xdg) else None
    folder = base or Path(tempfile.gettempdir()) / f"ttc-bench-{os.getuid()}"
    folder.mkdir(mode=0o700, exist_ok=True)
    info = folder.lstat()
    if info.st_uid != os.getuid() or info.st_mode & 0o077 or not folder.is_dir():
        raise OSError(f"{folder}: not a private folder of this user (mode, owner)")
    return folder


def code_files() -> list[tuple[str, int, int]]:
    """(path, size, mtime_ns) of every ``.py`` file of the project's packages, sorted."""
    top = project_top()
    found = []
    for root in CODE_ROOTS:
        for folder, dirs, files in os.walk(top / root):
            dirs[:] = [d for d in dirs if d != "__pycache__"]
            for name in files:
                if name.endswith(".py"):
                    path = os.path.join(folder, name)
                    info = os.stat(path)
                    found.append((path, info.st_size, info.st_mtime_ns))
    return sorted(found)


def library_marks(search: Sequence[str]) -> list[tuple[str, int]]:
    """(folder, mtime_ns) of each folder of ``search`` (``sys.path``): installing or
    removing a package changes its folder's modification time. The project's own folder (the
    working folder, ``''``, or the folder holding ``ttc`` and ``experiments``) is marked 0: its
    code is in :func:`code_files`, and its modification time changes whenever a sweep or a
    test creates a file beside the code (a new key for every command, or a server that never
    starts because the key changed while it imported)."""
    top = project_top()
    marks = []
    for entry in search:
        try:
            own = entry == "" or os.path.samefile(entry, top)
            marks.append((entry, 0 if own else os.stat(entry).st_mtime_ns))
        except OSError:
            marks.append((entry, -1))
    return marks


def project_top() -> Path:
    """The folder holding the project's packages (``ttc``, ``experiments``)."""
    return Path(__file__).resolve().parents[2]


def server_key(environ: Mapping[str, str], search: Sequence[str] | None = None) -> str:
    """The key of the server that may serve a command run with ``environ`` and ``search``
    as ``sys.path`` (default: this one) (module docstring): SHA-256, hex."""
    digest = hashlib.sha256()
    env = sorted((k, v) for k, v in environ.items() if k not in IGNORED_VARIABLES)
    marks = library_marks(sys.path if search is None else search)
    for part in (sys.executable, sys.version, sys.flags, marks, env, code_files()):
        digest.update(repr(part).encode())
        digest.update(b"\0")
    return digest.hexdigest()


def socket_path(folder: Path, key: str) -> Path:
    """The socket of the server with ``key`` (short: a Unix socket path has ≤ 107 bytes)."""
    return folder / f"{key[:32]}.sock"
