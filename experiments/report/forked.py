"""A report step in a second process, beside the steps the report runs meanwhile.

The report's sections read the same loaded sweeps and write separate files; on two cores the
"every object" report (its reference, levels and rankings) runs in a process forked once the
sweeps are loaded while the report's own process writes the reference, FP.5, FP.6 and FP.7
sections. The forked process shares the loaded tables with the report's (copy-on-write
pages: the memory of the process tree, its PSS, counts them once) and sends its step's result
back pickled (a few small tables). Where ``fork`` is not available, or the report is asked to
stay in one process (``--one-process``: its peak memory lower, its time longer), the step runs
in the report's own process when its result is asked for: the same step, the same files.

An exception of the step is raised again in the report's process (the same exception where
it can be pickled); a forked process that dies without an answer (killed, out of memory) is
named with its exit code: a report never goes on with a step's files half written.
"""

from __future__ import annotations

import multiprocessing as mp
import pickle
import traceback
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any, Generic, TypeVar

T = TypeVar("T")


class StepDied(RuntimeError):
    """The forked process of a report step ended without sending its result."""


def _child(step: Callable[[], Any], send: Connection) -> None:
    """The forked process: run ``step``, send ``("ok", result)`` or ``("error", exception,
    traceback text)``."""
    try:
        answer: tuple = ("ok", step())
    except BaseException as exc:  # noqa: BLE001 - every failure goes back to the report
        text = traceback.format_exc()
        try:
            pickle.dumps(exc)
            answer = ("error", exc, text)
        except Exception:  # noqa: BLE001 - an exception that cannot travel: its text does
            answer = ("error", RuntimeError(f"{type(exc).__name__}: {exc}"), text)
    send.send(answer)
    send.close()


class Forked(Generic[T]):
    """A step started in a forked process (:func:`start`); :meth:`result` waits for it."""

    def __init__(self, step: Callable[[], T], name: str, fork: bool = True) -> None:
        self.name = name
        self._step: Callable[[], T] | None = None
        self._process = None
        if not fork or "fork" not in mp.get_all_start_methods():
            self._step = step  # run by result(), in this process
            return
        context = mp.get_context("fork")
        self._receive, send = context.Pipe(duplex=False)
        self._process = context.Process(target=_child, args=(step, send), name=name)
        self._process.start()
        send.close()  # this process's copy: the pipe ends when the child's closes

    def result(self) -> T:
        """The step's result: waited for; its exception raised again here."""
        if self._process is None:
            assert self._step is not None
            return self._step()
        try:
            answer = self._receive.recv()
        except EOFError:
            answer = None
        self._process.join()
        if answer is None:
            raise StepDied(
                f"the report step {self.name!r} (a forked process) ended without a result, "
                f"exit code {self._process.exitcode}"
            )
        if answer[0] == "error":
            _, exc, text = answer
            exc.add_note(f"in the report step {self.name!r} (a forked process):\n{text}")
            raise exc
        return answer[1]


def start(step: Callable[[], T], name: str, fork: bool = True) -> Forked[T]:
    """``step()`` started in a forked process (where the platform has ``fork``; not with
    ``fork`` false: then run by :meth:`Forked.result`, in this process)."""
    return Forked(step, name, fork)
