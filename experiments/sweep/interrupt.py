"""What Ctrl-C says: a sweep interrupted (SIGINT to its process group) ends at once with one
line, how many of its settings are done and that a re-run resumes the rest, and exit status
130 (128 + SIGINT, the shell's convention), instead of a ``KeyboardInterrupt`` traceback from
inside joblib. The settings finished before it keep their records; a re-run of the same
command resumes them (the planner launches no job for a complete run)."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import FrameType
from typing import NoReturn

from experiments.store import RUNS_DIR
from experiments.sweep.callbacks import INTERRUPTED_STATUS, stop_progress


def done_count(sweep_dir: Path, run_ids: Sequence[str]) -> int:
    """How many of ``run_ids`` have a run record in the sweep folder (a record is written
    last, when the run is complete)."""
    try:
        recorded = set(os.listdir(Path(sweep_dir) / RUNS_DIR))
    except OSError:
        return 0
    return sum(f"{rid}.json" in recorded for rid in set(run_ids))


def interrupted_line(sweep_dir: Path, run_ids: Sequence[str]) -> str:
    """The one line an interrupted sweep prints."""
    total = len(set(run_ids))
    if not total:
        return f"interrupted before the sweep was planned: nothing launched in {sweep_dir}"
    done = done_count(sweep_dir, run_ids)
    return (
        f"interrupted: {done} of {total} settings done (kept in {sweep_dir}); "
        f"re-running the same command resumes the other {total - done}"
    )


def exit_interrupted(sweep_dir: Path, run_ids: Sequence[str]) -> NoReturn:
    """End the progress bar, print :func:`interrupted_line` and exit with status 130."""
    stop_progress()
    sys.stdout.flush()
    print(interrupted_line(sweep_dir, run_ids), file=sys.stderr, flush=True)
    raise SystemExit(INTERRUPTED_STATUS)


class SigintSeen:
    """Whether SIGINT arrived while :func:`watch_sigint` was active."""

    def __init__(self) -> None:
        self.seen = False


@contextlib.contextmanager
def watch_sigint(state: SigintSeen) -> Iterator[SigintSeen]:
    """Record that SIGINT arrived, then raise ``KeyboardInterrupt`` as Python does.

    A ``KeyboardInterrupt`` raised inside a library can come out as another exception (one
    raised inside OmegaConf while Hydra composes a config leaves it half-set and surfaces as
    an ``AttributeError``): the caller asks ``seen`` instead of matching the exception type.
    Outside the main thread (no signal handlers there) it only yields."""
    try:
        previous = signal.getsignal(signal.SIGINT)
    except ValueError:  # pragma: no cover - not the main thread
        yield state
        return

    def handler(signum: int, frame: FrameType | None) -> None:
        state.seen = True
        signal.default_int_handler(signum, frame)

    try:
        signal.signal(signal.SIGINT, handler)
    except ValueError:  # pragma: no cover - not the main thread
        yield state
        return
    try:
        yield state
    finally:
        signal.signal(signal.SIGINT, previous)
