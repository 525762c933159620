"""A command in the warm server's forked process: it becomes the client's stand-in (file
descriptors 0-2, folder, environment, umask, Python's standard streams made again for them,
default signal handlers), forks its sweep workers' source (:mod:`.forks`), runs
``ttc-bench``'s subcommand (:func:`experiments.cli.run_subcommand`, the same code as
without a server), runs the exit handlers a normal exit runs, and exits with the
subcommand's status. It never returns into the server.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import signal
import sys
import traceback
from typing import Any

from experiments.warm.forks import start_fork_source, stop_fork_source


def take_streams(fds: list[int]) -> None:
    """Make ``fds`` (the client's stdin, stdout, stderr) this process's 0, 1, 2 and
    ``sys.stdin``/``sys.stdout``/``sys.stderr`` over them as Python makes them at start-up
    (line-buffered on a terminal; stderr always)."""
    for target, fd in enumerate(fds):
        os.dup2(fd, target)
        os.close(fd)
    encoding = os.environ.get("PYTHONIOENCODING", "utf-8").split(":")[0] or "utf-8"
    for fd, name in ((0, "stdin"), (1, "stdout"), (2, "stderr")):
        tty = os.isatty(fd)
        stream = open(  # noqa: SIM115 (the process's standard stream)
            fd, "r" if fd == 0 else "w", buffering=-1, encoding=encoding,
            errors="backslashreplace" if fd == 2 else "strict", closefd=False,
            newline=None if fd == 0 else "\n",
        )  # fmt: skip
        if fd:
            stream.reconfigure(line_buffering=tty or fd == 2)
        setattr(sys, name, stream)
        setattr(sys, f"__{name}__", stream)


def become_client(request: dict[str, Any], fds: list[int], server_fds: list[int]) -> None:
    """Close the server's own descriptors (``server_fds``: its socket, its clients, its
    lock), take the client's streams, folder, environment and umask; a process group of
    its own; Python's default signal handling."""
    for fd in server_fds:
        with contextlib.suppress(OSError):
            os.close(fd)
    os.setpgid(0, 0)
    take_streams(fds)
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    os.umask(int(request["umask"]))
    signal.signal(signal.SIGINT, signal.default_int_handler)
    for signum in (signal.SIGTERM, signal.SIGHUP, signal.SIGCHLD):
        signal.signal(signum, signal.SIG_DFL)


def run_command(request: dict[str, Any], fds: list[int], server_fds: list[int]) -> None:
    """Run the client's command here and exit with its status (module docstring)."""
    code = 1
    try:
        become_client(request, fds, server_fds)
        from experiments.cli import SUBCOMMANDS, run_subcommand  # noqa: PLC0415 (preloaded)

        argv = list(request["argv"])
        sub = SUBCOMMANDS.get(argv[0]) if argv else None
        start_fork_source(sub.module if sub else None)
        code = run_subcommand(argv)
    except SystemExit as exc:
        code = exit_code(exc.code)
    except BaseException:  # noqa: BLE001 (printed as Python would, then the exit status)
        traceback.print_exc()
    finally:
        with contextlib.suppress(BaseException):
            atexit._run_exitfuncs()
        with contextlib.suppress(BaseException):
            stop_fork_source()
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(BaseException):
                stream.flush()
        os._exit(code)


def exit_code(code: object) -> int:
    """The exit status of ``SystemExit(code)``, as Python's own exit gives it."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code & 0xFF
    print(code, file=sys.stderr)
    return 1
