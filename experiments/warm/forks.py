"""A command's sweep workers, forked instead of started afresh.

loky starts each worker as a new interpreter (fork + exec) that imports the stack again
(≈ 1.1 s each on 2 cores). A command run by the warm server already holds the stack, so
:func:`start_fork_source` forks ``multiprocessing``'s fork server from it at the command's
start, while the process has one thread, and sets loky's start method to ``forkserver``:
each worker is then forked from that single-threaded process (milliseconds, nothing to
import), with the command's stdout/stderr, folder and environment, and SIGINT blocked (as
the launcher blocks it in loky's workers: Ctrl-C reaches the main process, which ends them).

The fork server also runs the command's main module once, as ``multiprocessing`` runs it in
each new worker (``__mp_main__``: ``experiments.run``'s top level registers the config
schemas): the workers inherit it instead of each running it again (0.1-0.3 s per worker on the
way to the first job, measured on 2 cores).

Why ``multiprocessing``'s fork server and not loky's ``fork`` context: loky refuses ``fork``
for its reusable executor (forking a process that runs threads, as the planning main
process does, can deadlock a child on a lock another thread held). The fork server is the
standard library's answer (forks only from a process with one thread) and loky supports it;
started as the library does it (a fresh ``python -c``) it would import the stack again, so
here it is forked from the preloaded process instead. Worker deaths, the jobs re-run alone
and Ctrl-C then work as with loky's own workers (:mod:`experiments.sweep.launcher`).
"""

from __future__ import annotations

import os
import signal
import socket
from multiprocessing import connection, forkserver, spawn


def start_fork_source(main_module: str | None = None) -> int:
    """Fork the fork server from this process and make loky use it (module docstring); its
    process id. ``main_module``: the module the command runs as ``__main__``, run there
    once as each worker would run it. Call while this process has a single thread."""
    from joblib.externals.loky.backend.context import set_start_method  # noqa: PLC0415

    address = connection.arbitrary_address("AF_UNIX")
    listener = socket.socket(socket.AF_UNIX)
    listener.bind(address)
    os.chmod(address, 0o600)
    listener.listen()
    alive_r, alive_w = os.pipe()
    pid = os.fork()
    if pid == 0:
        code = 0
        try:
            os.close(alive_w)
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            if main_module:
                spawn.prepare({"init_main_from_name": main_module})
            forkserver.main(listener.fileno(), alive_r, [])
        except SystemExit:  # every holder of the "alive" pipe is gone
            pass
        except BaseException:  # noqa: BLE001 (a fork child must not return)
            code = 1
        finally:
            os._exit(code)
    os.close(alive_r)
    listener.close()
    server = forkserver._forkserver
    server._forkserver_address, server._forkserver_alive_fd = address, alive_w
    server._forkserver_pid = pid
    set_start_method("forkserver", force=True)
    return pid


def stop_fork_source() -> None:
    """End the fork server once its workers have ended (the library's own stop: close the
    "alive" pipe, wait for the process, remove its socket)."""
    forkserver._forkserver._stop()
