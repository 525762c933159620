"""Hydra callbacks of a sweep: a progress bar with time left, the summary and the exit status
at the end, and a record for a job whose process died.

Following Hydra's convention for partial failures (hydra#1465: every job of the batch runs,
then the multirun reports that some failed), a sweep runs every setting, prints the failures
in its summary and then exits with status 1 when a setting of this invocation failed or a
stored rows file is unreadable. ``skipped`` (an invalid detector × descriptor pair) is not a failure.
"""

from __future__ import annotations

import os
import shutil
import socket
import sys
import threading
from pathlib import Path
from typing import Any

from hydra.core.global_hydra import GlobalHydra
from hydra.core.utils import JobReturn, JobStatus
from hydra.experimental.callback import Callback
from omegaconf import DictConfig
from tqdm import tqdm

from experiments.configs.structured import data_root, swept_overrides
from experiments.store import StoreError
from experiments.store.progress import PROGRESS_DIR, PROGRESS_ENV, progress_dir, progress_outcomes


def count_jobs(config: DictConfig) -> int | None:
    """Number of jobs the basic sweeper will launch, or None when it cannot be told."""
    try:
        loader = GlobalHydra.instance().config_loader()
        total = 1
        for override in swept_overrides(config).values():
            if override.is_discrete_sweep() and hasattr(override.value(), "filter"):  # glob
                options = loader.get_group_options(override.key_or_group)
                total *= len(override.value().filter(options))
            else:
                total *= len(list(override.sweep_string_iterator()))
        return total
    except Exception:  # progress is a nicety: never fail a sweep over it
        return None


#: Exit status of a sweep ended by Ctrl-C (128 + SIGINT).
INTERRUPTED_STATUS = 130


def stop_progress() -> None:
    """Stop the sweep's progress bar, if one runs: its last state is drawn and its line
    ended (the end of a sweep, or Ctrl-C)."""
    if _PROGRESS:
        _PROGRESS.pop("stop").set()
        _PROGRESS.pop("thread").join(timeout=10)


# The progress thread lives at module level: Hydra's launchers pickle the callback objects
# to send them to workers, and a thread or lock does not pickle.
_PROGRESS: dict[str, Any] = {}


class SweepCallback(Callback):
    """Shows sweep progress and summarises the sweep when it ends (nothing is merged: the
    store is append-only, :mod:`experiments.store`)."""

    def __init__(self, poll_seconds: float = 1.0) -> None:
        self.poll_seconds = poll_seconds

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        progress = sweep_dir / PROGRESS_DIR / f"{socket.gethostname()}-{os.getpid()}"
        shutil.rmtree(progress, ignore_errors=True)
        progress.mkdir(parents=True, exist_ok=True)
        os.environ[PROGRESS_ENV] = str(progress)  # inherited by the workers started after
        total = count_jobs(config)
        stop = threading.Event()
        thread = threading.Thread(target=self._poll, args=(progress, total, stop), daemon=True)
        _PROGRESS.update(stop=stop, thread=thread)
        thread.start()

    def _poll(self, progress: Path, total: int | None, stop: threading.Event) -> None:
        interactive = sys.stderr.isatty()
        with tqdm(
            total=total,
            desc="settings",
            unit="setting",
            dynamic_ncols=True,
            mininterval=0.5 if interactive else 15.0,  # logs get a line every 15 s, not a flood
        ) as bar:
            while True:
                stopping = stop.wait(self.poll_seconds)
                done = len(progress_outcomes(progress))
                bar.update(done - bar.n)
                if stopping:
                    return

    def on_job_end(self, config: DictConfig, job_return: JobReturn, **kwargs: Any) -> None:
        """Record a job that did not return (its exception escaped, or its worker process
        died: the launcher reports that) as ``failed`` with the reason."""
        if job_return.status != JobStatus.FAILED:
            return
        from experiments.sweep.job import record_crash  # noqa: PLC0415 (slow imports)

        error = job_return._return_value
        message = f"{type(error).__name__}: {error}" if error is not None else "job failed"
        record_crash(config, Path(config.hydra.sweep.dir), message)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        """Summarise the sweep; exit 1 when a setting failed or a rows file is unreadable."""
        stop_progress()
        from experiments.summary.collect import summarise_sweep  # noqa: PLC0415 (slow imports)

        sweep_dir = Path(config.hydra.sweep.dir)
        problems = []
        outcomes = progress_outcomes(progress_dir(sweep_dir))
        unchanged = set(outcomes) <= {"resumed"}
        try:
            summarise_sweep(
                sweep_dir,
                data_dir=data_root(config),
                cache_dir=Path(str(config.cache.dir)),
                unchanged=unchanged,
            )
        except (StoreError, OSError) as exc:
            problems.append(f"stored rows unreadable: {exc}")
        except KeyboardInterrupt:  # Ctrl-C during the summary: every setting is done
            print(f"interrupted during the summary: every setting is done; `python -m "
                  f"experiments.summary.collect {sweep_dir}` summarises them", file=sys.stderr)  # fmt: skip
            sys.exit(INTERRUPTED_STATUS)
        if (failed := outcomes.count("failed")) > 0:
            problems.append(f"{failed} setting(s) failed (listed above); a re-run retries them")
        if problems:
            sys.stdout.flush()
            sys.exit("sweep incomplete: " + "; ".join(problems))
