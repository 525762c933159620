"""Hydra sweeper of ttc-bench: the basic sweeper with a cheaper up-front validation of keys,
types *and values*, and Hydra's partial-failure convention.

Hydra's basic sweeper composes every job's config in the main process before launching any
(``validate_batch_is_legal``), ~0.15 s each with this config tree: 25 s of serial work for
the 168-setting ``fp6_grid``, longer than the rest of a warm sweep. This sweeper composes the
first job and one variant per further value of each swept key (the first job with that
value; the planner reads the same compositions), plus one per distinct combination of the
``dataset`` overrides (frame ranges are checked across their keys): a typo in any key or
value, and any value the ``validator`` (``experiments.config.validate_config``: parameter
ranges, frame range, data present) refuses, fails with Hydra's message before any job runs.

While it validates and plans a sweep that will compute something (some setting has no run
record yet), the ttc launcher starts its workers (``warm_up``); the compositions it made are
handed to the launcher (``share_compositions``), whose workers reuse them.

Before launching, it plans the sweep (:mod:`experiments.plan`): settings whose run is
complete are dropped (resume before launch: a finished sweep starts no worker), invalid
detector × descriptor pairs are recorded as skipped once per pair, and the other settings
are grouped into batches that share their expensive stages, one job per batch (at most
``max_settings_per_job`` settings; 1 gives one setting per job). It prints the plan in one
line.

Jobs that fail (the task raised, or the launcher reports that the worker died) do not stop
the sweep: every job of the batch runs, the failures are logged, and the callbacks' end of
the multirun decides the exit status (hydra#1465's convention: the multirun still reports
that a job failed).
"""

# No ``from __future__ import annotations``: Hydra loads plugin modules without registering
# them in sys.modules, and dataclasses then cannot resolve string annotations.
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from hydra._internal.core_plugins.basic_sweeper import BasicSweeper, BasicSweeperConf
from hydra.core.config_store import ConfigStore
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.utils import JobReturn, JobStatus
from hydra.errors import ConfigCompositionException
from hydra.utils import get_method
from omegaconf import OmegaConf

log = logging.getLogger(__name__)


@dataclass
class TTCSweeperConf(BasicSweeperConf):
    _target_: str = "hydra_plugins.ttc_sweeper.TTCSweeper"
    #: Dotted path of a function(cfg) raising ValueError for a config whose values are wrong.
    validator: Optional[str] = "experiments.config.validate_config"  # noqa: UP045 (Hydra)
    #: Most settings one job computes together (1: one setting per job, no batches).
    max_settings_per_job: int = 200


ConfigStore.instance().store(group="hydra/sweeper", name="ttc", node=TTCSweeperConf, provider="ttc")


def representative_jobs(batch: Sequence[Sequence[str]]) -> list[list[str]]:
    """Jobs that hold every distinct ``key=value`` of ``batch`` at least once: the k-th takes
    the k-th distinct value at every position (the first job's value where a position has
    fewer); as many jobs as the most values of one position. A job whose overrides do not
    line up with the first job's is kept as it is."""
    if not batch:
        return []
    first = list(batch[0])
    values: list[list[str]] = [[item] for item in first]
    odd: list[list[str]] = []
    for job in batch[1:]:
        if len(job) != len(first):
            odd.append(list(job))
            continue
        for position, item in enumerate(job):
            if item not in values[position]:
                values[position].append(item)
    count = max((len(v) for v in values), default=1)
    jobs = [[v[k] if k < len(v) else v[0] for v in values] for k in range(count)]
    return jobs + odd


def group_combination_jobs(batch: Sequence[Sequence[str]], group: str) -> list[list[str]]:
    """One job per distinct combination of the overrides of ``group`` (``group=...``,
    ``group.key=...``), the first job's values elsewhere: values checked across keys of one
    group (``dataset.first`` against ``dataset.last``) are checked for every combination."""
    if not batch:
        return []
    parser = OverridesParser.create()
    first = list(batch[0])
    in_group = [
        o.key_or_group.split(".")[0].lstrip("+~") == group for o in parser.parse_overrides(first)
    ]
    seen: dict[tuple[str, ...], list[str]] = {}
    for job in batch:
        if len(job) != len(first):
            continue
        combo = tuple(item for item, mine in zip(job, in_group, strict=True) if mine)
        if combo not in seen:
            seen[combo] = [
                j if mine else f for j, f, mine in zip(job, first, in_group, strict=True)
            ]
    return list(seen.values())


class TTCSweeper(BasicSweeper):
    """:class:`BasicSweeper` validating a few compositions, values included, and running
    every job even when some fail."""

    def __init__(
        self,
        max_batch_size: Optional[int],  # noqa: UP045
        params: Any = None,
        validator=None,
        max_settings_per_job: int = 200,
    ):
        super().__init__(max_batch_size=max_batch_size, params=params)
        self.validator = validator
        self.max_settings_per_job = max_settings_per_job
        self.planner: Any = None
        self.run_ids: list[str] = []  # of every plan of this sweep

    def _planner(self) -> Any:
        """The sweep's :class:`experiments.plan.SettingPlanner` (its compositions are shared
        by validation and planning)."""
        from experiments.plan import Compositions, SettingPlanner  # noqa: PLC0415

        if self.planner is None:
            assert self.config is not None and self.hydra_context is not None
            compositions = Compositions(self.hydra_context.config_loader, self.config)
            self.planner = SettingPlanner(compositions)
        return self.planner

    def validate_batch_is_legal(self, batch: Sequence[Sequence[str]]) -> None:
        """Compose (Hydra) and validate the first job, one variant per further value of each
        swept key (:func:`experiments.plan.variant_jobs`, the configs the planner reads too)
        and every combination of the ``dataset`` overrides."""
        from experiments.plan import variant_jobs  # noqa: PLC0415

        jobs = variant_jobs(batch)
        jobs += [j for j in group_combination_jobs(batch, "dataset") if j not in jobs]
        compositions = self._planner().composer
        validate = get_method(self.validator) if self.validator else None
        for overrides in jobs:
            cfg = compositions.full(overrides)
            if validate is None:
                continue
            try:
                validate(cfg)
            except ValueError as exc:
                raise ConfigCompositionException(
                    f"{exc}\n(job overrides: {' '.join(overrides)})"
                ) from None

    def sweep(self, arguments: list[str]) -> Any:
        """Hydra's basic sweep, except that a failed job does not raise: it is logged."""
        assert self.config is not None and self.launcher is not None
        parser = OverridesParser.create(config_loader=self.hydra_context.config_loader)
        overrides = parser.parse_overrides([*self._parse_config(), *arguments])
        self.overrides = self.split_arguments(overrides, self.max_batch_size)
        sweep_dir = Path(self.config.hydra.sweep.dir)
        sweep_dir.mkdir(parents=True, exist_ok=True)
        OmegaConf.save(self.config, sweep_dir / "multirun.yaml")
        returns: list[Sequence[JobReturn]] = []
        initial_job_idx = 0
        try:
            while not self.is_done():
                batch = self.get_job_batch()
                jobs = self.plan(batch, sweep_dir)
                results = (
                    self.launcher.launch(jobs, initial_job_idx=initial_job_idx) if jobs else []
                )
                for r in results:
                    if r.status == JobStatus.FAILED:
                        log.error(f"job {' '.join(r.overrides)} failed: {r._return_value}")
                initial_job_idx += len(jobs)
                returns.append(results)
        finally:  # workers warmed up for a plan with no job, or one that failed validation
            if hasattr(self.launcher, "release"):
                self.launcher.release()
        return returns

    def plan(self, batch: Sequence[Sequence[str]], sweep_dir: Path) -> list[list[str]]:
        """The jobs to launch for ``batch`` (:func:`experiments.plan.make_plan`, after
        validation), printed. A sweep planned before with the same jobs, config, config files
        and code (:func:`experiments.plan.plan_key`) whose every run is complete launches
        nothing without composing a config."""
        from experiments import plan as planning  # noqa: PLC0415
        from experiments.finished import remember_command  # noqa: PLC0415

        assert self.config is not None
        key = planning.plan_key(batch, self.config)
        plan = planning.finished_from_memory(sweep_dir, key, self.config)
        if plan is None:  # validate, then plan (the launcher's workers start meanwhile)
            if hasattr(self.launcher, "warm_up") and planning.records_missing(sweep_dir, batch):
                self.launcher.warm_up()
            self.validate_batch_is_legal(batch)
            limit = max(1, self.max_settings_per_job)
            planner = self._planner()
            plan = planning.make_plan(batch, planner, self.config, sweep_dir, limit)
            planning.remember_run_ids(sweep_dir, key, plan.run_ids)
            if hasattr(self.launcher, "share_compositions") and planner.template is not None:
                self.launcher.share_compositions(planner.template, planner.composer.memo)
        self.run_ids += plan.run_ids
        remember_command(sweep_dir, self.run_ids)  # python -m experiments.run checks it first
        print(plan.summary(), flush=True)
        return plan.jobs


__all__ = ["TTCSweeper", "TTCSweeperConf", "group_combination_jobs", "representative_jobs"]
