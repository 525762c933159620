"""The sweeper of ttc-bench: Hydra's basic sweeper (the same jobs: :mod:`.jobs`) with a cheaper
up-front validation of keys, types *and values*, a plan before launch, Hydra's partial-failure
convention and a one-line Ctrl-C. It implements Hydra's public ``Sweeper`` interface.

Hydra's basic sweeper composes every job's config in the main process before launching any
(``validate_batch_is_legal``), ~0.15 s each with this config tree: 25 s of serial work for the
168-setting ``fp6_grid``. This sweeper composes the first job and one variant per further value
of each swept key (:func:`experiments.sweep.compose.variant_jobs`: the compositions the
:class:`~experiments.sweep.compose.Composer` derives every job from), plus one per distinct
combination of the ``dataset`` overrides (frame ranges are checked across their keys): a typo
in any key or value, and any value the ``validator`` (``experiments.configs.structured.validate_config``:
parameter ranges, frame range, data present) refuses, fails with Hydra's message before any
job runs.

While it validates and plans a sweep that will compute something (some setting has no run
record yet), the launcher starts its workers (``warm_up``); the composer's compositions are
then handed to the launcher (``share_compositions``), whose workers reuse them.

Before launching, it plans the sweep (:mod:`experiments.sweep.plan`): settings whose run is complete
are dropped (resume before launch), invalid detector × descriptor pairs are recorded as
skipped once per pair, and the other settings are grouped into batches that share their
expensive stages, one job per batch (at most ``max_settings_per_job`` settings). It prints the
plan in one line.

Jobs that fail (the task raised, or the launcher reports that the worker died) do not stop the
sweep: every job runs, the failures are logged, and the callbacks' end of the multirun decides
the exit status (hydra#1465). Ctrl-C stops it at once: the workers are ended and one line says
how many settings are done (:mod:`experiments.sweep.interrupt`); the exit status is 130.

``hydra_plugins/ttc_sweeper`` registers it with Hydra (``hydra/sweeper=ttc``).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.plugins import Plugins
from hydra.core.utils import JobReturn, JobStatus
from hydra.errors import ConfigCompositionException
from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from hydra.utils import get_method
from omegaconf import DictConfig, OmegaConf

from experiments.data.first_run import ensure_config_models
from experiments.host.heap import freeze_alive
from experiments.sweep.compose import Composer, variant_jobs
from experiments.sweep.earlier import EarlierPlan
from experiments.sweep.interrupt import SigintSeen, exit_interrupted, watch_sigint
from experiments.sweep.jobs import batches, expand
from experiments.sweep.kept import (
    compositions_key,
    earlier_key,
    keep_compositions,
    keep_earlier,
    load_compositions,
    load_earlier,
)

if TYPE_CHECKING:
    from experiments.sweep.plan import Plan

log = logging.getLogger(__name__)


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


def validation_jobs(batch: Sequence[Sequence[str]]) -> list[list[str]]:
    """The jobs whose configs the sweeper validates: the composer's template and variants,
    and every combination of the ``dataset`` overrides."""
    jobs = variant_jobs(batch)
    return jobs + [j for j in group_combination_jobs(batch, "dataset") if j not in jobs]


@contextlib.contextmanager
def meanwhile(work: Callable[[], None] | None) -> Iterator[None]:
    """Run ``work`` (None: nothing) in a thread while the block runs, and wait for it at the
    block's end (its exception raised then, unless the block raised one)."""
    if work is None:
        yield
        return
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="ttc-meanwhile") as pool:
        done = pool.submit(work)
        yield
        done.result()


class SweepSweeper(Sweeper):
    """Hydra's basic sweep validating a few compositions, values included, planning before
    launch and running every job even when some fail."""

    def __init__(
        self,
        max_batch_size: int | None = None,
        params: Any = None,
        validator: str | None = None,
        max_settings_per_job: int = 200,
    ) -> None:
        """``max_batch_size``: most jobs launched at once (None: all); ``params``: the swept
        overrides, ``{key: values}``; ``validator``: dotted path of a function(cfg) raising
        ValueError for a config whose values are wrong; ``max_settings_per_job``: most
        settings one job computes together (1: one setting per job)."""
        self.max_batch_size = max_batch_size
        self.params = dict(params or {})
        self.validator = validator
        self.max_settings_per_job = max_settings_per_job
        self.hydra_context: HydraContext | None = None
        self.config: DictConfig | None = None
        self.launcher: Any = None
        self.composer: Composer | None = None
        self.run_ids: list[str] = []  # of every plan of this sweep

    def setup(
        self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig
    ) -> None:
        """Keep Hydra's context and master config; make the launcher."""
        self.hydra_context, self.config = hydra_context, config
        self.launcher = Plugins.instance().instantiate_launcher(
            hydra_context=hydra_context, task_function=task_function, config=config
        )

    def _composer(self, earlier: EarlierPlan | None = None) -> Composer:
        """The sweep's composer (its compositions serve validation, planning and the jobs;
        ``earlier``: the sweep folder's earlier plan, for the first one)."""
        if self.composer is None:
            assert self.config is not None and self.hydra_context is not None
            loader = self.hydra_context.config_loader
            self.composer = Composer(loader, self.config, earlier=earlier)
        return self.composer

    def validate_batch_is_legal(self, batch: Sequence[Sequence[str]]) -> None:
        """Compose and validate :func:`validation_jobs` (the composer's configs: Hydra's
        composition for a variant it has no part of, so a typo fails with Hydra's message);
        every detector's files are found (downloaded, once) before the workers need them."""
        composer = self._composer()
        validate = get_method(self.validator) if self.validator else None
        for overrides in validation_jobs(batch):
            with composer.shared_config(overrides) as cfg:
                ensure_config_models(cfg.objects)
                if validate is None:
                    continue
                try:
                    validate(cfg)
                except ValueError as exc:
                    raise ConfigCompositionException(
                        f"{exc}\n(job overrides: {' '.join(overrides)})"
                    ) from None

    def sweep(self, arguments: list[str]) -> Any:
        """Hydra's basic sweep, except that a failed job does not raise (it is logged) and
        Ctrl-C ends the sweep with one line (exit status 130)."""
        assert self.config is not None and self.launcher is not None
        sweep_dir = Path(self.config.hydra.sweep.dir)
        sigint = SigintSeen()
        try:
            with watch_sigint(sigint):
                return self._sweep(arguments, sweep_dir)
        except KeyboardInterrupt:
            self._interrupted(sweep_dir)
        except Exception:  # Ctrl-C inside Hydra/OmegaConf can surface as another exception
            if not sigint.seen:
                raise
            self._interrupted(sweep_dir)
        finally:  # workers warmed up for a plan with no job, or one that failed validation
            if hasattr(self.launcher, "release"):
                self.launcher.release()

    def _interrupted(self, sweep_dir: Path) -> NoReturn:
        """Stop the workers, print the one line and exit with status 130."""
        if hasattr(self.launcher, "stop"):
            self.launcher.stop()
        exit_interrupted(sweep_dir, self.run_ids)

    def _sweep(self, arguments: list[str], sweep_dir: Path) -> list[Sequence[JobReturn]]:
        """Expand the jobs, then plan and launch them batch by batch; the returns."""
        assert self.config is not None and self.launcher is not None
        assert self.hydra_context is not None
        parser = OverridesParser.create(config_loader=self.hydra_context.config_loader)
        params = [f"{key}={value}" for key, value in self.params.items()]
        overrides = parser.parse_overrides([*params, *arguments])
        sweep_dir.mkdir(parents=True, exist_ok=True)
        OmegaConf.save(self.config, sweep_dir / "multirun.yaml")
        returns: list[Sequence[JobReturn]] = []
        initial_job_idx = 0
        for batch in batches(expand(overrides), self.max_batch_size):
            plan = self.plan(batch, sweep_dir)
            jobs = plan.jobs
            with meanwhile(plan.deferred):  # the skipped records, written while jobs run
                results = (
                    self.launcher.launch(jobs, initial_job_idx=initial_job_idx) if jobs else []
                )
            for r in results:
                if r.status == JobStatus.FAILED:
                    log.error(f"job {' '.join(r.overrides)} failed: {r._return_value}")
            initial_job_idx += len(jobs)
            returns.append(results)
        return returns

    def plan(self, batch: Sequence[Sequence[str]], sweep_dir: Path) -> Plan:
        """The plan of ``batch`` (:func:`experiments.sweep.plan.make_plan`, after validation:
        its jobs to launch and the work left for while they run), printed. A sweep planned
        before with the same jobs, config, config files and code
        (:func:`experiments.sweep.plan.plan_key`) whose every run is complete launches nothing
        without composing a config."""
        from experiments.sweep import plan as planning  # noqa: PLC0415 (pandas, OpenCV)
        from experiments.sweep.finished import remember_command  # noqa: PLC0415

        assert self.config is not None
        # the imported stack lives as long as this process: out of the garbage collector's
        # passes (a full collection walked it, 70 ms, 10 times in a grand re-run; done by the
        # warm server for the commands it serves), after one collection (the master config's
        # composition left 14,000 objects of garbage: 0.04 s)
        freeze_alive()
        key = planning.plan_key(batch, self.config)
        plan = planning.finished_from_memory(sweep_dir, key, self.config)
        if plan is None:  # validate, then plan (the launcher's workers start meanwhile)
            warm = hasattr(self.launcher, "warm_up")
            if warm and planning.records_missing(sweep_dir, batch):
                self.launcher.warm_up()
            kept_key, reuse_key = compositions_key(key, self.config), earlier_key(self.config)
            composer = self._composer(load_earlier(sweep_dir, reuse_key))
            composer.known.update(load_compositions(sweep_dir, kept_key))
            made = composer.full_compositions
            if warm and planning.first_record_missing(sweep_dir, composer, batch):
                self.launcher.warm_up()  # once: a second call does nothing
            self.validate_batch_is_legal(batch)
            limit = max(1, self.max_settings_per_job)
            plan = planning.make_plan(batch, composer, self.config, sweep_dir, limit)
            planning.remember_run_ids(sweep_dir, key, plan.run_ids)
            if composer.template is not None and not composer.inherited:  # for the next plans
                keep_earlier(sweep_dir, reuse_key, EarlierPlan(composer.template, composer.known))
            elif composer.full_compositions > made:  # for a re-plan of this one (resumed)
                keep_compositions(sweep_dir, kept_key, composer.known)
            if hasattr(self.launcher, "share_compositions"):
                self.launcher.share_compositions(composer)
        self.run_ids += plan.run_ids
        remember_command(sweep_dir, self.run_ids)  # python -m experiments.run checks it first
        print(plan.summary(), flush=True)
        return plan
