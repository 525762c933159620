"""The thin client: ``ttc-bench`` hands a command to the warm server of its key
(:mod:`.identity`) and becomes a stand-in for it: the server's process for the command gets
this process's argv, working folder, environment, umask and its stdin/stdout/stderr file
descriptors themselves (``SCM_RIGHTS``: a terminal stays a terminal, a pipe a pipe); Ctrl-C
(SIGINT) and SIGTERM are passed on; the command's exit status is this process's.

When no server answers (none yet, switched off, another platform, a folder that is not
private), :func:`forward` says so before anything ran, and ``ttc-bench`` runs the command
itself exactly as without a server; afterwards :func:`start_server` starts one in the
background for the next command (after, so that its imports do not compete with this one).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import struct
import sys
from dataclasses import dataclass
from pathlib import Path

from experiments.warm.server_key import enabled, runtime_dir, server_key, socket_path

#: Reply bytes of the server: the command is taken, or refused (run it here).
TAKEN, REFUSED = b"A", b"R"
#: What the client sends while the command runs: SIGINT, SIGTERM.
SIGNAL_BYTES = {signal.SIGINT: b"I", signal.SIGTERM: b"T"}
#: Status struct: the command's exit status, network order.
STATUS = struct.Struct("!i")
#: Seconds to wait for a server to take the command before running it here.
CONNECT_TIMEOUT_S = 2.0


@dataclass(frozen=True)
class Forwarded:
    """What :func:`forward` did: ``status`` the command's exit status when a server ran it
    (None: run it here); ``start``: the socket a server should be started on afterwards,
    for ``key``, with the environment and ``sys.path`` the key was computed from (the
    command run here may change both)."""

    status: int | None
    start: Path | None = None
    key: str = ""
    environ: tuple[tuple[str, str], ...] = ()
    path: tuple[str, ...] = ()


def request(argv: list[str]) -> bytes:
    """The command as the server reads it: a length-prefixed JSON object."""
    umask = os.umask(0)
    os.umask(umask)
    body = json.dumps(
        {"argv": argv, "cwd": os.getcwd(), "env": dict(os.environ), "umask": umask}
    ).encode()
    return STATUS.pack(len(body)) + body


def receive_exactly(conn: socket.socket, size: int) -> bytes:
    """``size`` bytes from ``conn``, fewer only at end of stream."""
    data = b""
    while len(data) < size and (chunk := conn.recv(size - len(data))):
        data += chunk
    return data


def this_server() -> tuple[str, Path] | None:
    """(key, socket) of the server for this process's interpreter, ``sys.path`` and
    environment; None when switched off or the socket folder is not private."""
    if not enabled(os.environ):
        return None
    try:
        key = server_key(os.environ)
        return key, socket_path(runtime_dir(os.environ), key)
    except OSError:
        return None


def forward(argv: list[str]) -> Forwarded:
    """Run ``argv`` (``ttc-bench``'s arguments) on the warm server (module docstring)."""
    if (found := this_server()) is None:
        return Forwarded(None)
    key, path = found
    conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        conn.settimeout(CONNECT_TIMEOUT_S)
        conn.connect(str(path))
        socket.send_fds(conn, [request(argv)], [0, 1, 2])
        taken = receive_exactly(conn, 1) == TAKEN
    except OSError:
        taken = False
    if not taken:
        conn.close()
        return Forwarded(None, path, key, tuple(os.environ.items()), tuple(sys.path))
    conn.settimeout(None)
    return Forwarded(wait_for_status(conn))


def wait_for_status(conn: socket.socket) -> int:
    """Pass SIGINT and SIGTERM on to the command until its exit status arrives."""

    def pass_on(signum: int, _frame: object) -> None:
        with contextlib.suppress(OSError):
            conn.sendall(SIGNAL_BYTES[signum])

    for signum in SIGNAL_BYTES:
        signal.signal(signum, pass_on)
    data = receive_exactly(conn, STATUS.size)
    conn.close()
    if len(data) < STATUS.size:
        print("ttc-bench: the warm server ended before the command did", file=sys.stderr)
        return 1
    return STATUS.unpack(data)[0]


def start_server(forwarded: Forwarded) -> None:
    """Start the server :func:`forward` asked for in the background, in its own session,
    with this interpreter and the environment and ``sys.path`` of its key; its log is
    ``<socket>.log``."""
    import subprocess  # noqa: PLC0415 (only when a server is started)

    boot = (
        "import sys, json; sys.path[:] = json.loads(sys.argv[1]); "
        "from experiments.warm.server import main; main(sys.argv[2], sys.argv[3])"
    )
    path, key = forwarded.start, forwarded.key
    with open(f"{path}.log", "ab") as log:
        subprocess.Popen(
            [sys.executable, "-c", boot, json.dumps(forwarded.path), str(path), key],
            env=dict(forwarded.environ), stdin=subprocess.DEVNULL, stdout=log, stderr=log, cwd="/",
            start_new_session=True, close_fds=True,
        )  # fmt: skip


def ensure_server() -> Path | None:
    """Start a server for this interpreter, ``sys.path`` and environment unless one answers
    (``python -m experiments.warm.client``, e.g. at login); its socket, None when switched
    off or not private."""
    if (found := this_server()) is None:
        return None
    key, path = found
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        try:
            probe.connect(str(path))
            return path
        except OSError:
            pass
    start_server(Forwarded(None, path, key, tuple(os.environ.items()), tuple(sys.path)))
    return path


if __name__ == "__main__":
    print(ensure_server())
