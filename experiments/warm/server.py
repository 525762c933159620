"""The warm server: one per key (:mod:`.identity`), started by the client on first use.

It computes its key *before* importing anything of the stack, imports the stack once
(:data:`PRELOAD`, Hydra's plugins discovered), and then serves commands until it has been
idle for the idle timeout: for each one it forks a process (:func:`.command.run_command`)
that takes the client's file descriptors, folder, environment and argv and runs
``ttc-bench``'s subcommand as a fresh process would, without importing anything again. It
refuses a command whose key is not its own (and then ends: its code is stale), reports each
command's exit status to its client, passes the client's Ctrl-C on as SIGINT, and sends
SIGINT when the client goes away (the command stops as on Ctrl-C: one line, what is done is
kept). A lock file makes it the only server of its key.
"""

from __future__ import annotations

import contextlib
import fcntl
import importlib
import json
import os
import selectors
import signal
import socket
import struct
import sys
import threading
import time
from pathlib import Path

from experiments.cli import SUBCOMMANDS
from experiments.host.heap import freeze_alive
from experiments.warm.client import REFUSED, STATUS, TAKEN
from experiments.warm.server_key import idle_seconds, server_key

#: Modules imported once by the server (what a sweep imports in its main process and in its
#: workers): every command forked from it starts with them.
PRELOAD = (
    "experiments.cli",
    "experiments.run",
    "experiments.sweep.job",
    "experiments.summary.collect",
    "experiments.sweep.callbacks",
    "experiments.summary.references",
    "experiments.sweep.plan",
    "experiments.sweep.sweeper",
    "experiments.sweep.launcher",
    "experiments.sweep.warm_up",
    "experiments.warm.command",
    "ttc.engine.runner",
    "scipy.optimize",
    "scipy.signal",
)
#: Signal bytes from the client -> the signal the command gets.
SIGNALS = {b"I": signal.SIGINT, b"T": signal.SIGTERM}
#: Largest request accepted (bytes).
MAX_REQUEST = 1 << 22


def say(message: str) -> None:
    """One line in the server's log (its stderr)."""
    print(f"{time.strftime('%Y-%m-%d %H:%M:%S')} [{os.getpid()}] {message}", flush=True,
          file=sys.stderr)  # fmt: skip


def preload() -> None:
    """Import :data:`PRELOAD` and discover Hydra's plugins; start the resource trackers the
    sweep workers share (so no command starts its own). The subcommands' own modules are
    forgotten again (their imports stay): ``runpy`` runs each as ``__main__``, and warns
    about one already imported."""
    for name in PRELOAD:
        importlib.import_module(name)
    from multiprocessing import resource_tracker  # noqa: PLC0415

    from hydra.core.plugins import Plugins  # noqa: PLC0415
    from joblib.externals.loky.backend import resource_tracker as loky_tracker  # noqa: PLC0415

    Plugins.instance()
    loky_tracker.ensure_running()
    resource_tracker.ensure_running()
    for sub in SUBCOMMANDS.values():  # run as ``__main__`` by each command, as with python -m
        sys.modules.pop(sub.module, None)
    # the preloaded stack (≈ 185,000 objects) out of the garbage collector's passes, here and
    # in every process forked from here: a full collection walked it in each command and
    # worker (70 ms each, 7-10 a grand re-run per process) and wrote to every page of it
    # (pages shared with this server, copied into each process then)
    freeze_alive()


def native_threads() -> int:
    """Threads of this process, native ones included (OpenBLAS's of NumPy and of OpenCV,
    jemalloc's of pyarrow: libraries that prepare for a fork with ``pthread_atfork``, as
    every ``multiprocessing`` fork of a NumPy process relies on)."""
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        return threading.active_count()


def read_request(conn: socket.socket) -> tuple[dict, list[int]]:
    """The client's request (JSON) and its three file descriptors."""
    data, fds, _, _ = socket.recv_fds(conn, 1 << 16, 3)
    while len(data) < STATUS.size or len(data) < STATUS.size + STATUS.unpack(data[:4])[0]:
        if len(data) > MAX_REQUEST or not (chunk := conn.recv(1 << 16)):
            raise OSError("incomplete request")
        data += chunk
    return json.loads(data[STATUS.size :]), list(fds)


class Server:
    """The serving loop (module docstring)."""

    def __init__(
        self, listener: socket.socket, key: str, idle_s: float, lock_fd: int, added: dict
    ) -> None:
        """``listener``: the bound, listening socket; ``key``: this server's key;
        ``lock_fd``: the descriptor of its lock file; ``added``: the environment variables
        the imports set (a command gets them on top of its own, as after its own imports)."""
        self.listener, self.key, self.idle_s, self.lock_fd = listener, key, idle_s, lock_fd
        self.added = added
        self.path = list(sys.path)
        self.selector = selectors.DefaultSelector()
        self.selector.register(listener, selectors.EVENT_READ, "accept")
        self.running: dict[int, tuple[socket.socket, int]] = {}  # pid -> (conn, pidfd)
        self.stale = False

    def serve(self) -> None:
        """Serve until idle for ``idle_s`` with no command running, or stale."""
        last = time.monotonic()
        while self.running or (not self.stale and time.monotonic() - last < self.idle_s):
            for key, _ in self.selector.select(timeout=1.0):
                kind, pid = key.data if isinstance(key.data, tuple) else (key.data, 0)
                if kind == "accept":
                    self.accept()
                elif kind == "client":
                    self.client_says(pid)
                else:
                    self.ended(pid)
                last = time.monotonic()
            if self.stale:
                self.selector.unregister(self.listener)
                self.listener.close()
                self.stale = False
                self.idle_s = 0.0

    def accept(self) -> None:
        """Take one command: check the peer and the key, fork its process."""
        conn, _ = self.listener.accept()
        fds: list[int] = []
        try:
            creds = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
            if struct.unpack("3i", creds)[1] != os.getuid():
                raise OSError("another user")
            request, fds = read_request(conn)
            if len(fds) != 3 or server_key(request["env"], self.path) != self.key:
                self.stale = len(fds) == 3  # the code or the libraries changed under it
                raise OSError("stale server or bad request")
            conn.sendall(TAKEN)
        except (OSError, ValueError, KeyError) as exc:
            say(f"refused a command: {exc}")
            with contextlib.suppress(OSError):
                conn.sendall(REFUSED)
            conn.close()
            for fd in fds:
                os.close(fd)
            return
        pid = os.fork()
        if pid == 0:  # the command's process: never returns
            from experiments.warm.command import run_command  # noqa: PLC0415 (preloaded)

            request["env"].update(self.added)
            run_command(request, fds, self.own_fds(conn))
        for fd in fds:
            os.close(fd)
        pidfd = os.pidfd_open(pid)
        self.running[pid] = (conn, pidfd)
        self.selector.register(conn, selectors.EVENT_READ, ("client", pid))
        self.selector.register(pidfd, selectors.EVENT_READ, ("ended", pid))
        say(f"command {pid}: {' '.join(request['argv'])}")

    def own_fds(self, conn: socket.socket) -> list[int]:
        """The server's descriptors a command's process closes (listener, selector, lock,
        the clients and process handles of the other commands, ``conn``)."""
        others = [fd for c, p in self.running.values() for fd in (c.fileno(), p)]
        return [self.listener.fileno(), self.selector.fileno(), self.lock_fd, conn.fileno(),
                *others]  # fmt: skip

    def client_says(self, pid: int) -> None:
        """A signal byte from the client, or its end (then the command gets SIGINT)."""
        conn, _ = self.running[pid]
        try:
            data = conn.recv(64)
        except OSError:
            data = b""
        if not data:
            self.selector.unregister(conn)
        for byte in [data[i : i + 1] for i in range(len(data))] or [b"I"]:
            with contextlib.suppress(ProcessLookupError, KeyError):
                os.kill(pid, SIGNALS[byte])

    def ended(self, pid: int) -> None:
        """The command's process ended: its exit status to the client."""
        conn, pidfd = self.running.pop(pid)
        _, status = os.waitpid(pid, 0)
        code = os.waitstatus_to_exitcode(status)
        code = 128 - code if code < 0 else code  # killed by a signal: the shell's number
        with contextlib.suppress(KeyError, ValueError):
            self.selector.unregister(conn)
        self.selector.unregister(pidfd)
        os.close(pidfd)
        with contextlib.suppress(OSError):
            conn.sendall(STATUS.pack(code))
        conn.close()
        say(f"command {pid}: exit {code}")


def listen(path: Path) -> socket.socket:
    """A listening socket at ``path`` (bound under another name, then renamed into place)."""
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    temporary = path.with_name(f"{path.name}.{os.getpid()}")
    temporary.unlink(missing_ok=True)
    listener.bind(str(temporary))
    os.chmod(temporary, 0o600)
    listener.listen(16)
    os.replace(temporary, path)
    return listener


def main(path_text: str, key: str) -> None:
    """Serve commands of ``key`` on ``path_text`` (module docstring)."""
    path = Path(path_text)
    if server_key(os.environ) != key:
        return say("not started: the code changed since the client computed its key")
    lock = open(f"{path}.lock", "w")  # noqa: SIM115 (held for the server's life)
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return say("not started: another server holds this key")
    started, environ, search = time.perf_counter(), dict(os.environ), list(sys.path)
    preload()
    if server_key(environ, search) != key:  # changed while importing: it may hold stale code
        return say("not started: the code changed while it imported")
    if threading.active_count() != 1:
        return say(f"not started: Python threads after the imports {threading.enumerate()}")
    added = {k: v for k, v in os.environ.items() if environ.get(k) != v}
    sys.path[:] = search
    listener = listen(path)
    mine = path.stat().st_ino
    say(f"serving {path} (imports {time.perf_counter() - started:.2f} s, "
        f"{native_threads()} native threads, environment added {added})")  # fmt: skip
    try:
        Server(listener, key, idle_seconds(os.environ), lock.fileno(), added).serve()
    finally:
        with contextlib.suppress(OSError):
            if path.stat().st_ino == mine:  # not replaced by a newer server's
                path.unlink()
        say("ended")
