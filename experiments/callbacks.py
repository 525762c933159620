"""Hydra callbacks of a sweep: a progress bar with time left, and the merge at the end."""

from __future__ import annotations

import shutil
import sys
import threading
from pathlib import Path
from typing import Any

from hydra.core.global_hydra import GlobalHydra
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.experimental.callback import Callback
from omegaconf import DictConfig
from tqdm import tqdm

PROGRESS_DIR = ".progress"


def count_jobs(config: DictConfig) -> int | None:
    """Number of jobs the basic sweeper will launch, or None when it cannot be told."""
    try:
        params = config.hydra.sweeper.get("params") or {}
        args = [f"{k}={v}" for k, v in params.items()] + list(config.hydra.overrides.task)
        overrides = OverridesParser.create().parse_overrides(args)
        loader = GlobalHydra.instance().config_loader()
        sizes: dict[str, int] = {}
        for override in overrides:
            if not override.is_sweep_override():
                sizes.pop(override.get_key_element(), None)
                continue
            if override.is_discrete_sweep() and hasattr(override.value(), "filter"):  # glob
                options = loader.get_group_options(override.key_or_group)
                n = len(override.value().filter(options))
            else:
                n = len(list(override.sweep_string_iterator()))
            sizes[override.get_key_element()] = n
        total = 1
        for n in sizes.values():
            total *= n
        return total
    except Exception:  # progress is a nicety: never fail a sweep over it
        return None


# The progress thread lives at module level: Hydra's launchers pickle the callback objects
# to send them to workers, and a thread or lock does not pickle.
_PROGRESS: dict[str, Any] = {}


class SweepCallback(Callback):
    """Shows sweep progress and merges all runs into one dataset when the sweep ends."""

    def __init__(self, poll_seconds: float = 1.0) -> None:
        self.poll_seconds = poll_seconds

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        progress = sweep_dir / PROGRESS_DIR
        shutil.rmtree(progress, ignore_errors=True)
        progress.mkdir(parents=True, exist_ok=True)
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
                done = sum(1 for _ in progress.iterdir())
                bar.update(done - bar.n)
                if stopping:
                    return

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        from experiments.collect import summarise_sweep  # noqa: PLC0415 (import cycle)

        if _PROGRESS:
            _PROGRESS.pop("stop").set()
            _PROGRESS.pop("thread").join(timeout=10)
        from experiments.config import data_root  # noqa: PLC0415

        summarise_sweep(
            Path(config.hydra.sweep.dir),
            data_dir=data_root(config),
            cache_dir=Path(str(config.cache.dir)),
        )
