"""Run one setting (or, with ``-m`` / an experiment, a sweep of settings) through the pipeline.

Examples::

    python -m experiments.run detector=fast descriptor=brief dataset.last=10
    python -m experiments.run +experiment=fp6_grid            # the main sweep (multirun)
    python -m experiments.run -m detector=fast,orb matcher=glob(*) sweep_name=mine

A job is one setting, or in a sweep a batch of settings that share their expensive stages
(``batch=<id>``, planned by the sweeper: :mod:`experiments.sweep.plan`, run by
:mod:`experiments.sweep.batch`). A setting's rows go to ``<sweep>/runs/<run_id>.parquet`` (its
batch's rows file in a batch) and its record (resolved config, code and package versions,
timings, status, rows checksum, identities of the input files read) to ``<run_id>.json``.
The sweeper launches no job for a complete run (:func:`store.incomplete_reason`), and a job
checks again (resume); any other is recomputed with a line saying why. Invalid
detector × descriptor pairs are recorded as ``skipped``, any other exception as ``failed``:
neither stops a sweep. A single run whose setting failed exits 1; a sweep exits 1 at its end
when a setting failed (:mod:`experiments.sweep.callbacks`).

This module is the Hydra entry; the computation (:mod:`experiments.sweep.job`: OpenCV, pandas, the
engine, ≈ 0.5 s of imports) is imported when a job runs, so a sweep's main process, which
validates and plans, starts its workers that much sooner; they import it while it plans.
"""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

if __name__ == "__main__":  # a finished sweep is reported before the slow imports below
    from experiments.sweep.finished import report_if_finished

    if report_if_finished(sys.argv[1:]):
        sys.exit(0)

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from experiments.configs.structured import (
    config_problems,
    missing_data_message,
    register_configs,
    sequence_dir,
)
from experiments.data.first_run import ensure_data
from experiments.host import paths
from experiments.sweep.mode_composition import compose_once

register_configs()
compose_once()  # Hydra composes a multirun's config twice (hydra#3440)


def output_dir() -> Path:
    """The sweep folder in a multirun, the run folder otherwise."""
    hc = HydraConfig.get()
    return Path(hc.sweep.dir if hc.mode == RunMode.MULTIRUN else hc.run.dir)


def check_data(cfg: DictConfig) -> None:
    """Exit with a plain message when the data root is missing."""
    recording = sequence_dir(cfg)
    if not (recording.is_dir() or (cfg.dataset.get("path") and recording.exists())):
        sys.exit(missing_data_message(cfg))


def warm_up(master: DictConfig) -> None:
    """What a sweep's worker does while the main process plans (the ttc launcher calls the
    task module's ``warm_up``): import the computation (:mod:`experiments.sweep.job`) and fill the
    stage cache with the entries every setting reads (:func:`experiments.sweep.warm_up.warm_up`)."""
    from experiments.sweep.warm_up import warm_up as fill_cache  # noqa: PLC0415

    with contextlib.suppress(Exception):  # the jobs meet the same problem and record it
        import experiments.sweep.job  # noqa: F401, PLC0415 (else the first job imports it)
    fill_cache(master)


@hydra.main(version_base="1.3", config_path=str(paths.CONF_DIR), config_name="config")
def main(cfg: DictConfig) -> None:
    multirun = HydraConfig.get().mode == RunMode.MULTIRUN
    if not multirun:  # a sweep's configs are checked by the sweeper before any job runs
        problems = config_problems(cfg)
        if problems:
            sys.exit("invalid configuration:\n  " + "\n  ".join(problems))
    from experiments.sweep.job import run_main  # noqa: PLC0415 (the computation's imports)

    run_main(cfg, output_dir(), multirun)


if __name__ == "__main__":
    sys.argv[1:] = ensure_data(sys.argv[1:])  # data on first run (experiments/data/first_run.py)
    main()
