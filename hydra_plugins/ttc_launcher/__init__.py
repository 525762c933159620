"""Hydra launcher of ttc-bench: Hydra's joblib launcher with cheaper per-job set-up.

Hydra's joblib launcher does three things per job besides the job: it pickles the sweep's
shared state (Hydra context, master config, task function, singletons) again for every job,
the worker re-discovers every Hydra plugin when it restores the singletons, and the worker
composes the job's config from scratch (~0.13 s with this config tree, more than a warm
job's own work). For the 168 jobs of ``fp6_grid`` that is most of a warm sweep's time.

This launcher runs the same jobs with the same joblib/loky pool and the same
``hydra.core.utils.run_job`` (job folders, logs, callbacks), but:

* the shared state is pickled once; each worker unpickles it and restores the singletons
  once per sweep;
* :class:`JobComposer` composes one template job with Hydra and, for every other
  ``key=value`` of the sweep, one variant job (the template with that one value); when the
  variant differs from the template only under ``key`` (a config group option or a plain
  value, no ``@package`` tricks), a job's config is the template with those subtrees
  replaced. Any override it cannot prove local goes through Hydra's full composition. A test
  checks that every job of a sweep gets exactly the config Hydra composes;
* the ttc sweeper has composed the same template and variants to validate and plan the
  sweep: it hands them over (:meth:`TTCLauncher.share_compositions`) and the workers reuse
  them instead of composing them again (~0.2 s each, per worker);
* the sweeper starts the workers while it plans (:meth:`TTCLauncher.warm_up`): their
  imports and the restored sweep state overlap the main process's planning, and each then
  calls the task module's ``warm_up(master config)`` when it has one (ttc-bench's:
  :mod:`experiments.warm_up`, the stages every setting shares).

A worker that dies (a signal: an out-of-memory kill, a segfault in native code) breaks a joblib
pool and would end the sweep with ``TerminatedWorkerError``. This launcher instead re-runs each
job that was running at that moment alone in a fresh one-worker pool: a job that dies there
too is reported as failed with the signal (``JobStatus.FAILED``, and the callbacks'
``on_job_end`` records it), every other job runs normally, and the sweep goes on.

Select it with ``override hydra/launcher: ttc_joblib`` (the project's default launcher,
``conf/hydra/launcher/local.yaml``); it takes the joblib launcher's options.
"""

# No ``from __future__ import annotations``: Hydra loads plugin modules without registering
# them in sys.modules, and dataclasses then cannot resolve string annotations.
import copy
import hashlib
import importlib
import logging
import os
import pickle
import re
import shutil
import sys
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cloudpickle
from hydra._internal.config_loader_impl import get_overrides_dirname
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override, OverrideType
from hydra.core.singleton import Singleton
from hydra.core.utils import (
    JobReturn,
    JobStatus,
    configure_log,
    filter_overrides,
    run_job,
    setup_globals,
)
from hydra_plugins.hydra_joblib_launcher._core import process_joblib_cfg
from hydra_plugins.hydra_joblib_launcher.config import JobLibLauncherConf
from hydra_plugins.hydra_joblib_launcher.joblib_launcher import JoblibLauncher
from joblib import Parallel, delayed, effective_n_jobs
from joblib.externals.loky import get_reusable_executor
from joblib.externals.loky.process_executor import TerminatedWorkerError
from omegaconf import DictConfig, OmegaConf, open_dict

log = logging.getLogger(__name__)


@dataclass
class TTCLauncherConf(JobLibLauncherConf):
    _target_: str = "hydra_plugins.ttc_launcher.TTCLauncher"


ConfigStore.instance().store(
    group="hydra/launcher", name="ttc_joblib", node=TTCLauncherConf, provider="ttc"
)

#: The override naming the batch a job computes (``experiments.plan``).
BATCH_PREFIX = "batch="
#: Keys of the Hydra node that a job's overrides change (besides ``runtime.choices``).
JOB_KEYS = ("overrides.task", "job.override_dirname", "job.id", "job.num")


def _drop(container: dict[str, Any], dotted: str) -> None:
    """Remove ``dotted`` (a.b.c) from nested dicts, if present."""
    *parents, leaf = dotted.split(".")
    for part in parents:
        container = container.get(part)
        if not isinstance(container, dict):
            return
    container.pop(leaf, None)


def _comparable(container: dict[str, Any], key: str) -> dict[str, Any]:
    """A copy of a config's plain containers (``OmegaConf.to_container``, interpolations
    unresolved) without ``key``, its choice and the job-specific Hydra keys."""
    out = copy.deepcopy(container)
    _drop(out, key)
    for job_key in JOB_KEYS:
        _drop(out["hydra"], job_key)
    out["hydra"]["runtime"]["choices"].pop(key, None)
    return out


class JobComposer:
    """Job configs of one sweep: Hydra's composition of a template job and of one variant per
    distinct ``key=value``, then each job as the template with its values' subtrees."""

    def __init__(
        self,
        config_loader: Any,
        master: DictConfig,
        known: Mapping[tuple[str, ...], DictConfig] | None = None,
        template: Sequence[str] | None = None,
    ) -> None:
        """``known``: Hydra's compositions of some jobs (by their overrides), made elsewhere
        from the same ``master`` (the sweeper's); ``template``: the job to use as template
        (one of ``known``; default: the first job composed)."""
        self.loader = config_loader
        self.master = master
        self.known = dict(known or {})
        self.parser = OverridesParser.create()
        self.template: list[str] | None = None
        self.template_keys: list[str] = []
        self.base: DictConfig | None = None
        self.base_container: dict[str, Any] = {}
        self.parts: dict[tuple[int, str], tuple[str, Any, str | None] | None] = {}
        self.full_compositions = 0
        if template is not None:
            self._set_template(list(template))

    def _set_template(self, overrides: list[str]) -> None:
        self.template, self.base = overrides, self._composed(overrides)
        self.base_container = OmegaConf.to_container(self.base, resolve=False)
        self.template_keys = [o.key_or_group for o in self.parser.parse_overrides(overrides)]

    def _composed(self, overrides: Sequence[str]) -> DictConfig:
        """Hydra's composition of a job, shared: a known one or a new one (not to modify)."""
        key = tuple(overrides)
        if key not in self.known:
            self.full_compositions += 1
            self.known[key] = self.loader.load_sweep_config(self.master, list(overrides))
        return self.known[key]

    def full(self, overrides: Sequence[str]) -> DictConfig:
        """Hydra's own composition of a job (what the joblib launcher does every time), a
        copy of the known one when there is one."""
        key = tuple(overrides)
        if key in self.known:
            return copy.deepcopy(self.known[key])
        self.full_compositions += 1
        return self.loader.load_sweep_config(self.master, list(overrides))

    def _part(self, position: int, override: Override) -> tuple[str, Any, str | None] | None:
        """(config key, its node in a variant job, its group choice) when the variant differs
        from the template only under that key; None otherwise."""
        memo = (position, override.input_line)
        if memo not in self.parts:
            self.parts[memo] = None
            if override.type == OverrideType.CHANGE and override.package is None:
                variant = list(self.template)
                variant[position] = override.input_line
                cfg = self._composed(variant)
                key = override.key_or_group.replace("/", ".")
                variant_container = OmegaConf.to_container(cfg, resolve=False)
                if _comparable(variant_container, key) == _comparable(self.base_container, key):
                    choice = cfg.hydra.runtime.choices.get(key)
                    self.parts[memo] = (key, OmegaConf.select(cfg, key), choice)
        return self.parts[memo]

    def compose(self, overrides: Sequence[str]) -> DictConfig:
        """The config of the job with these overrides (a batch's ``batch=<id>``, a plain
        string each batch has its own of, is set on the composed config)."""
        overrides = list(overrides)
        batch = [o for o in overrides if o.startswith(BATCH_PREFIX)]
        if batch:
            cfg = self.compose([o for o in overrides if not o.startswith(BATCH_PREFIX)])
            with open_dict(cfg):
                cfg.batch = batch[-1][len(BATCH_PREFIX) :]
                cfg.hydra.overrides.task.extend(batch)
            return cfg
        if self.base is None:
            self._set_template(overrides)
        parsed = self.parser.parse_overrides(overrides)
        if len(overrides) != len(self.template):
            return self.full(overrides)
        cfg = copy.deepcopy(self.base)
        for position, (item, override) in enumerate(zip(overrides, parsed, strict=True)):
            if item == self.template[position]:
                continue
            if self.template_keys[position] != override.key_or_group:
                return self.full(overrides)
            part = self._part(position, override)
            if part is None:
                return self.full(overrides)
            key, node, choice = part
            with open_dict(cfg):
                OmegaConf.update(cfg, key, copy.deepcopy(node), merge=False)
            if choice is not None:
                with open_dict(cfg.hydra):
                    cfg.hydra.runtime.choices[key] = choice
        task = [o for o in parsed if not o.is_hydra_override()]
        with open_dict(cfg.hydra):
            cfg.hydra.overrides.task = [o.input_line for o in task]
            naming = cfg.hydra.job.config.override_dirname
            cfg.hydra.job.override_dirname = get_overrides_dirname(
                overrides=task,
                kv_sep=naming.kv_sep,
                item_sep=naming.item_sep,
                exclude_keys=list(naming.exclude_keys),
            )
        return cfg


@dataclass(frozen=True)
class SweepState:
    """What every job of a sweep needs besides its overrides, pickled once in the main
    process and restored once per worker process (each part keyed by its SHA-256).

    ``payload``: (Hydra context, master config, task function, singletons); ``shared``:
    (template overrides, {overrides: Hydra's composition}) from the sweeper, or empty;
    ``started``: the folder of the running jobs' markers.
    """

    key: str
    payload: bytes
    started: str
    shared_key: str = ""
    shared: bytes = b""


#: The sweep state of this worker process: restored once per sweep, not once per job.
_WORKER: dict[str, Any] = {}


def _worker_state(state: SweepState) -> dict[str, Any]:
    if _WORKER.get("key") != state.key:
        hydra_context, master, task_function, singletons = pickle.loads(state.payload)
        setup_globals()
        Singleton.set_state(singletons)
        _WORKER.clear()
        _WORKER.update(key=state.key, hydra_context=hydra_context, master=master,
                       task_function=task_function)  # fmt: skip
    if _WORKER.get("shared_key") != state.shared_key or "composer" not in _WORKER:
        template, known = pickle.loads(state.shared) if state.shared else (None, {})
        loader = _WORKER["hydra_context"].config_loader
        _WORKER["composer"] = JobComposer(loader, _WORKER["master"], known, template)
        _WORKER["shared_key"] = state.shared_key
    return _WORKER


def _warm(state: SweepState, modules: Sequence[str]) -> int:
    """Import ``modules``, restore the sweep state in this worker and call each module's
    ``warm_up(master config)`` if it has one (work any job of the sweep needs, done while the
    main process plans); this worker's process id."""
    imported = [importlib.import_module(name) for name in modules]
    worker = _worker_state(state)
    HydraConfig.instance().set_config(worker["master"])
    for module in imported:
        if callable(hook := getattr(module, "warm_up", None)):
            hook(worker["master"])
    return os.getpid()


#: Folder (in the sweep folder) of the markers of the jobs running right now: ``<job idx>``.
STARTED_DIR = ".launcher"


class WorkerDiedError(RuntimeError):
    """The process running a job died (a signal: out of memory, a crash in native code)."""


def worker_death(exc: BaseException) -> str:
    """What killed a loky worker, from its ``TerminatedWorkerError``, in words."""
    found = re.search(r"exit codes of the workers are \{([^}]*)\}", str(exc))
    codes = found.group(1) if found else "unknown"
    return (
        f"worker process died ({codes}): killed by a signal, e.g. out of memory or a crash "
        "in native code (OpenCV)"
    )


def execute_job(idx: int, overrides: Sequence[str], state: SweepState) -> JobReturn:
    """One job in a worker: its config (:class:`JobComposer`), then Hydra's ``run_job``.
    ``<state.started>/<idx>`` exists while it runs (it stays when the worker dies)."""
    marker = Path(state.started) / str(idx)
    marker.write_text(str(os.getpid()))
    ret = _execute_job(idx, overrides, state)
    marker.unlink(missing_ok=True)
    return ret


def _execute_job(idx: int, overrides: Sequence[str], state: SweepState) -> JobReturn:
    worker = _worker_state(state)
    sweep_config = worker["composer"].compose(overrides)
    with open_dict(sweep_config):
        sweep_config.hydra.job.id = f"{sweep_config.hydra.job.name}_{idx}"
        sweep_config.hydra.job.num = idx
    return run_job(  # sets the job's HydraConfig
        hydra_context=worker["hydra_context"],
        config=sweep_config,
        task_function=worker["task_function"],
        job_dir_key="hydra.sweep.dir",
        job_subdir_key="hydra.sweep.subdir",
    )


class TTCLauncher(JoblibLauncher):
    """:class:`JoblibLauncher` that pickles the sweep state once and composes jobs cheaply."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._payload: tuple[str, bytes] | None = None
        self._shared: tuple[str, bytes] = ("", b"")
        self._warming: threading.Thread | None = None

    def _joblib_cfg(self) -> dict[str, Any]:
        """The joblib options of this sweep's pool (loky, one job per dispatch: a dead worker
        loses one job, not a batch of them)."""
        joblib_cfg = dict(self.joblib)
        joblib_cfg["backend"] = "loky"
        process_joblib_cfg(joblib_cfg)
        joblib_cfg["batch_size"] = 1
        return joblib_cfg

    def _state(self, started: Path) -> SweepState:
        """The sweep state the jobs get (the payload pickled once per sweep)."""
        if self._payload is None:
            assert self.hydra_context is not None and self.config is not None
            payload = cloudpickle.dumps(
                (self.hydra_context, self.config, self.task_function, Singleton.get_state())
            )
            self._payload = (hashlib.sha256(payload).hexdigest(), payload)
        key, payload = self._payload
        return SweepState(key, payload, str(started), *self._shared)

    def share_compositions(
        self, template: Sequence[str], known: Mapping[tuple[str, ...], DictConfig]
    ) -> None:
        """Hand over the sweeper's compositions of the sweep's template job and its variants
        (made from this launcher's master config): the workers' :class:`JobComposer` reuses
        them instead of composing them again."""
        shared = cloudpickle.dumps((list(template), dict(known)))
        self._shared = (hashlib.sha256(shared).hexdigest(), shared)

    def warm_up(self) -> None:
        """Start the pool's workers now, in the background: each imports the task's module and
        restores the sweep state while the main process validates and plans. :meth:`launch`
        waits for it; :meth:`release` stops the workers when nothing is launched."""
        if self._warming is not None:
            return
        assert self.config is not None
        main_spec = getattr(sys.modules.get("__main__"), "__spec__", None)
        modules = [main_spec.name] if main_spec is not None else []
        state = self._state(Path(str(self.config.hydra.sweep.dir)) / STARTED_DIR)
        joblib_cfg = self._joblib_cfg()
        workers = effective_n_jobs(joblib_cfg.get("n_jobs"))

        def start() -> None:
            try:
                Parallel(**joblib_cfg)(delayed(_warm)(state, modules) for _ in range(workers))
            except Exception as exc:  # the launch starts the pool again and reports errors
                log.debug(f"warming the workers up failed: {exc!r}")

        log.info(f"Starting {workers} workers while the sweep is planned")
        self._warming = threading.Thread(target=start, name="ttc-warm-up", daemon=True)
        self._warming.start()

    def _wait_for_warm_up(self) -> bool:
        """Wait for a running :meth:`warm_up`; True when there was one."""
        if self._warming is None:
            return False
        self._warming.join()
        self._warming = None
        return True

    def release(self) -> None:
        """Wait for a :meth:`warm_up` and stop the workers it started (a sweep that launched
        nothing)."""
        if self._wait_for_warm_up():
            shut_down_workers(self._joblib_cfg().get("n_jobs"))

    def launch(
        self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int
    ) -> Sequence[JobReturn]:
        setup_globals()
        assert self.config is not None and self.hydra_context is not None
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        joblib_cfg = self._joblib_cfg()
        log.info(f"Launching {len(job_overrides)} jobs, sweep output dir: {sweep_dir}")
        for idx, overrides in enumerate(job_overrides):  # hydra.verbose=true shows them
            log.debug(f"\t#{initial_job_idx + idx} : {' '.join(filter_overrides(overrides))}")
        self._wait_for_warm_up()
        started = sweep_dir / STARTED_DIR
        shutil.rmtree(started, ignore_errors=True)
        started.mkdir(parents=True)
        state = self._state(started)
        jobs = {initial_job_idx + i: list(o) for i, o in enumerate(job_overrides)}
        results: dict[int, JobReturn] = {}
        while pending := [i for i in jobs if i not in results]:
            try:
                runs = Parallel(**joblib_cfg, return_as="generator_unordered")(
                    delayed(_indexed)(i, jobs[i], state) for i in pending
                )
                for i, ret in runs:  # kept one by one: a later crash loses none of them
                    results[i] = ret
            except TerminatedWorkerError as exc:
                left = [i for i in pending if i not in results]
                running = [i for i in left if (started / str(i)).exists()] or left[:1]
                log.warning(f"{worker_death(exc)}; re-running its jobs {running} one by one")
                for i in running:
                    results[i] = self._alone(i, jobs[i], state)
        shutil.rmtree(started, ignore_errors=True)
        shut_down_workers(joblib_cfg.get("n_jobs"), wait=False)
        assert all(isinstance(run, JobReturn) for run in results.values())
        return [results[i] for i in sorted(jobs)]

    def _alone(self, idx: int, overrides: list[str], state: SweepState) -> JobReturn:
        """Run one job alone in a fresh worker; a job that kills it is reported FAILED. A
        batch that kills it is run again a setting at a time (each alone), so the setting that
        dies costs only itself."""
        executor = get_reusable_executor(max_workers=1, kill_workers=True)
        try:
            return executor.submit(execute_job, idx, overrides, state).result()
        except TerminatedWorkerError as exc:
            message = worker_death(exc)
        members = self._batch_members(overrides)
        if members:
            log.warning(f"job #{idx} (a batch of {len(members)}): {message}; one by one now")
            returns = [self._alone(idx, m, state) for m in members]
            failed = [r for r in returns if r.status == JobStatus.FAILED]
            return failed[0] if failed else returns[0]
        log.error(f"job #{idx} ({' '.join(overrides)}): {message}")
        assert self.hydra_context is not None and self.config is not None
        cfg = self.hydra_context.config_loader.load_sweep_config(self.config, overrides)
        with open_dict(cfg):
            cfg.hydra.job.id, cfg.hydra.job.num = f"{cfg.hydra.job.name}_{idx}", idx
        ret = JobReturn(
            overrides=overrides,
            cfg=cfg,
            hydra_cfg=cfg,
            status=JobStatus.FAILED,
            _return_value=WorkerDiedError(message),
        )
        self.hydra_context.callbacks.on_job_end(config=cfg, job_return=ret)
        return ret

    def _batch_members(self, overrides: list[str]) -> list[list[str]]:
        """The overrides of each setting of a batch job (none for a one-setting job)."""
        batch = [o[len(BATCH_PREFIX) :] for o in overrides if o.startswith(BATCH_PREFIX)]
        if not batch:
            return []
        from experiments.plan import read_plan  # noqa: PLC0415

        assert self.config is not None
        plan = read_plan(Path(str(self.config.hydra.sweep.dir)), batch[-1])
        return [list(m["overrides"]) for m in plan["members"]]


def shut_down_workers(n_jobs: int | None, wait: bool = True) -> None:
    """Stop the pool's worker processes once a sweep's jobs are done: loky keeps idle workers
    for reuse, each holding its imports and in-memory stage cache (~0.7 GB on ``grand``)
    while the main process merges and ranks. ``wait=False``: tell them to exit and go on
    (they are gone within a fraction of a second; waiting for it cost a sweep ~0.3 s)."""
    get_reusable_executor(max_workers=effective_n_jobs(n_jobs)).shutdown(wait=wait)


def _indexed(idx: int, overrides: Sequence[str], state: SweepState) -> tuple[int, JobReturn]:
    return idx, execute_job(idx, overrides, state)


__all__ = [
    "JobComposer",
    "SweepState",
    "TTCLauncher",
    "TTCLauncherConf",
    "WorkerDiedError",
    "execute_job",
    "shut_down_workers",
    "worker_death",
]
