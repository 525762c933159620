"""Hydra's ``run_job`` for one sweep job in a worker, without its copies of the job's config.

Hydra's ``hydra.core.utils.run_job`` (1.3) sets the job's Hydra config twice (each a masked
copy of its ``hydra`` node), deep-copies the whole job config to hand the task its config
without ``hydra``, and deep-copies the Hydra config again for the job's return: ≈ 35 ms of
each job, 17 % of the workers' time in a served ``fp6_grid`` re-run (35 jobs of 4 settings).
:func:`run_sweep_job` does the same steps in the same order with one Hydra config (its
output folder set on it as on the job's config) and a copy of only the task's keys; the task,
the callbacks and the job's return see what Hydra's would give them (a test compares them).
The job's config is the caller's own (:meth:`experiments.sweep.compose.Composer.config`
makes a new one per job): its ``hydra.runtime.output_dir`` is set as Hydra sets it.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from hydra import version
from hydra.core.hydra_config import HydraConfig
from hydra.core.utils import (
    JobReturn,
    JobRuntime,
    JobStatus,
    _flush_loggers,
    _save_config,
    configure_log,
    env_override,
)
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

#: Where a sweep job's folder is: ``<hydra.sweep.dir>/<hydra.sweep.subdir>``.
JOB_DIR_KEY, JOB_SUBDIR_KEY = "hydra.sweep.dir", "hydra.sweep.subdir"


def task_config(config: DictConfig) -> DictConfig:
    """The task's config: a copy of ``config`` without its ``hydra`` key, the root's flags
    (struct, read-only) those of ``config`` as in Hydra's deep copy."""
    task = OmegaConf.masked_copy(config, [key for key in config if key != "hydra"])
    OmegaConf.set_struct(task, OmegaConf.is_struct(config))
    OmegaConf.set_readonly(task, OmegaConf.is_readonly(config))
    return task


def run_sweep_job(
    task_function: TaskFunction, config: DictConfig, hydra_context: HydraContext
) -> JobReturn:
    """Run ``task_function`` on a sweep job's ``config`` as Hydra's ``run_job`` would (job
    folder, Hydra config, logging, ``.hydra`` files when ``hydra.output_subdir`` is set, the
    job's environment, callbacks, working folder), and return its :class:`JobReturn`."""
    callbacks = hydra_context.callbacks
    old_cwd = os.getcwd()
    instance: Any = HydraConfig.instance()
    orig_hydra_cfg = instance.cfg
    instance.set_config(config)  # the job's folder below may read its Hydra keys
    output_dir = os.path.abspath(
        os.path.join(
            str(OmegaConf.select(config, JOB_DIR_KEY)),
            str(OmegaConf.select(config, JOB_SUBDIR_KEY)),
        )
    )
    for cfg in (config, instance.cfg):  # the job's config and the Hydra config made of it
        with read_write(cfg.hydra.runtime), open_dict(cfg.hydra.runtime):
            cfg.hydra.runtime.output_dir = output_dir
    chdir = False
    try:
        ret = JobReturn()
        task_cfg = task_config(config)
        ret.cfg = task_cfg
        hydra_cfg = instance.cfg
        ret.hydra_cfg = hydra_cfg
        overrides = OmegaConf.to_container(config.hydra.overrides.task)
        assert isinstance(overrides, list)
        ret.overrides = overrides
        Path(output_dir).mkdir(parents=True, exist_ok=True)
        chdir = hydra_cfg.hydra.job.chdir
        if chdir is None:  # Hydra's default: stay from version_base 1.2 on
            chdir = not version.base_at_least("1.2")
        if chdir:
            os.chdir(output_dir)
            ret.working_dir = output_dir
        else:
            ret.working_dir = os.getcwd()
        configure_log(config.hydra.job_logging, config.hydra.verbose)
        if config.hydra.output_subdir is not None:
            hydra_output = Path(output_dir) / Path(config.hydra.output_subdir)
            _save_config(task_cfg, "config.yaml", hydra_output)
            _save_config(hydra_cfg, "hydra.yaml", hydra_output)
            _save_config(config.hydra.overrides.task, "overrides.yaml", hydra_output)
        with env_override(hydra_cfg.hydra.job.env_set):
            callbacks.on_job_start(config=config, task_function=task_function)
            try:
                ret.return_value = task_function(task_cfg)
                ret.status = JobStatus.COMPLETED
            except Exception as e:
                ret.return_value = e
                ret.status = JobStatus.FAILED
        ret.task_name = JobRuntime.instance().get("name")
        _flush_loggers()
        callbacks.on_job_end(config=config, job_return=ret)
        return ret
    finally:
        instance.cfg = orig_hydra_cfg
        if chdir:
            os.chdir(old_cwd)
