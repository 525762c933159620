"""Progress markers of a sweep: one small file per finished job, read by the progress bar and
the end-of-sweep summary. They live in ``<sweep>/.progress/<id of the sweep invocation>/``,
named to the jobs by the environment variable :data:`PROGRESS_ENV`, so two sweeps into one
folder count their own jobs. Light on purpose (no pandas): the remembered-command check
(:mod:`experiments.sweep.finished`) imports it before anything else."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from ttc.atomic import atomic_write

PROGRESS_DIR = ".progress"
PROGRESS_ENV = "TTC_PROGRESS_DIR"


def progress_dir(sweep_dir: Path) -> Path:
    """This sweep invocation's progress folder (``$TTC_PROGRESS_DIR`` when a sweep set it)."""
    return Path(os.environ.get(PROGRESS_ENV) or Path(sweep_dir) / PROGRESS_DIR / "last")


def mark_progress(sweep_dir: Path, name: str, outcomes: list[str]) -> None:
    """Tell the sweep's progress bar and summary that settings are finished: one marker file
    (``name``: a run id, a batch id) holding one outcome per setting (``ok``, ``skipped``,
    ``failed``, ``resumed``), separated by spaces."""
    marker = progress_dir(sweep_dir) / name
    marker.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(marker, lambda tmp: tmp.write_text(" ".join(outcomes)))


def progress_outcomes(progress: Path) -> list[str]:
    """Every outcome in a progress folder's markers (see :func:`mark_progress`)."""
    if not progress.is_dir():
        return []
    out: list[str] = []
    for path in progress.iterdir():
        if not path.name.startswith("."):
            with contextlib.suppress(OSError):
                out.extend(path.read_text().split())
    return out
