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
  checks that every job of a sweep gets exactly the config Hydra composes.

Select it with ``override hydra/launcher: ttc_joblib`` (the project's default launcher,
``conf/hydra/launcher/local.yaml``); it takes the joblib launcher's options.
"""

# No ``from __future__ import annotations``: Hydra loads plugin modules without registering
# them in sys.modules, and dataclasses then cannot resolve string annotations.
import copy
import hashlib
import logging
import pickle
from collections.abc import Sequence
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
from hydra.core.utils import JobReturn, configure_log, filter_overrides, run_job, setup_globals
from hydra_plugins.hydra_joblib_launcher._core import process_joblib_cfg
from hydra_plugins.hydra_joblib_launcher.config import JobLibLauncherConf
from hydra_plugins.hydra_joblib_launcher.joblib_launcher import JoblibLauncher
from joblib import Parallel, delayed
from omegaconf import DictConfig, OmegaConf, open_dict

log = logging.getLogger(__name__)


@dataclass
class TTCLauncherConf(JobLibLauncherConf):
    _target_: str = "hydra_plugins.ttc_launcher.TTCLauncher"


ConfigStore.instance().store(
    group="hydra/launcher", name="ttc_joblib", node=TTCLauncherConf, provider="ttc"
)

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

    def __init__(self, config_loader: Any, master: DictConfig) -> None:
        self.loader = config_loader
        self.master = master
        self.parser = OverridesParser.create()
        self.template: list[str] | None = None
        self.template_keys: list[str] = []
        self.base: DictConfig | None = None
        self.base_container: dict[str, Any] = {}
        self.parts: dict[tuple[int, str], tuple[str, Any, str | None] | None] = {}
        self.full_compositions = 0

    def full(self, overrides: Sequence[str]) -> DictConfig:
        """Hydra's own composition of a job (what the joblib launcher does every time)."""
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
                cfg = self.full(variant)
                key = override.key_or_group.replace("/", ".")
                variant_container = OmegaConf.to_container(cfg, resolve=False)
                if _comparable(variant_container, key) == _comparable(self.base_container, key):
                    choice = cfg.hydra.runtime.choices.get(key)
                    self.parts[memo] = (key, OmegaConf.select(cfg, key), choice)
        return self.parts[memo]

    def compose(self, overrides: Sequence[str]) -> DictConfig:
        """The config of the job with these overrides."""
        overrides = list(overrides)
        if self.base is None:
            self.template, self.base = overrides, self.full(overrides)
            self.base_container = OmegaConf.to_container(self.base, resolve=False)
            self.template_keys = [o.key_or_group for o in self.parser.parse_overrides(overrides)]
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


#: The sweep state of this worker process: restored once per sweep, not once per job.
_WORKER: dict[str, Any] = {}


def _worker_state(key: str, payload: bytes) -> dict[str, Any]:
    if _WORKER.get("key") != key:
        hydra_context, master, task_function, singletons = pickle.loads(payload)
        setup_globals()
        Singleton.set_state(singletons)
        _WORKER.clear()
        _WORKER.update(
            key=key,
            hydra_context=hydra_context,
            task_function=task_function,
            composer=JobComposer(hydra_context.config_loader, master),
        )
    return _WORKER


def execute_job(idx: int, overrides: Sequence[str], key: str, payload: bytes) -> JobReturn:
    """One job in a worker: its config (:class:`JobComposer`), then Hydra's ``run_job``."""
    state = _worker_state(key, payload)
    sweep_config = state["composer"].compose(overrides)
    with open_dict(sweep_config):
        sweep_config.hydra.job.id = f"{sweep_config.hydra.job.name}_{idx}"
        sweep_config.hydra.job.num = idx
    HydraConfig.instance().set_config(sweep_config)
    return run_job(
        hydra_context=state["hydra_context"],
        config=sweep_config,
        task_function=state["task_function"],
        job_dir_key="hydra.sweep.dir",
        job_subdir_key="hydra.sweep.subdir",
    )


class TTCLauncher(JoblibLauncher):
    """:class:`JoblibLauncher` that pickles the sweep state once and composes jobs cheaply."""

    def launch(
        self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int
    ) -> Sequence[JobReturn]:
        setup_globals()
        assert self.config is not None and self.hydra_context is not None
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        joblib_cfg = self.joblib
        joblib_cfg["backend"] = "loky"
        process_joblib_cfg(joblib_cfg)
        log.info(f"Launching {len(job_overrides)} jobs, sweep output dir: {sweep_dir}")
        for idx, overrides in enumerate(job_overrides):
            log.info(f"\t#{initial_job_idx + idx} : {' '.join(filter_overrides(overrides))}")
        payload = cloudpickle.dumps(
            (self.hydra_context, self.config, self.task_function, Singleton.get_state())
        )
        key = hashlib.sha256(payload).hexdigest()
        runs = Parallel(**joblib_cfg)(
            delayed(execute_job)(initial_job_idx + idx, list(overrides), key, payload)
            for idx, overrides in enumerate(job_overrides)
        )
        assert all(isinstance(run, JobReturn) for run in runs)
        return runs


__all__ = ["JobComposer", "TTCLauncher", "TTCLauncherConf", "execute_job"]
