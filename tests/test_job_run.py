"""A sweep job run without Hydra's copies (:func:`experiments.sweep.job_run.run_sweep_job`)
gives the task, the callbacks and the job's return what Hydra's own ``run_job`` gives them, on
real job configs of the project's sweeps (values, interpolations, flags, the Hydra config seen
inside the job, the job folder, ``.hydra`` files when asked for)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.core.utils import JobStatus, run_job
from hydra.types import HydraContext
from omegaconf import OmegaConf, open_dict

from experiments.configs.structured import register_configs
from experiments.sweep.compose import Composer
from experiments.sweep.job_run import run_sweep_job
from tests.conftest import PROJECT_ROOT

JOBS = [
    ["+experiment=fp6_grid", "detector=fast", "descriptor=brief", "dataset.last=5"],
    ["+experiment=fp6_grid", "detector=sift", "descriptor=akaze", "dataset.last=5"],
]


class Recorder:
    """Callbacks and task that note what they are given (containers and flags; the Hydra
    config unresolved: its ``run.dir`` reads the clock)."""

    def __init__(self, fail: bool) -> None:
        self.seen: list[Any] = []
        self.fail = fail

    def on_job_start(self, config, task_function) -> None:
        self.seen.append(("start", OmegaConf.to_container(config, resolve=False)))

    def on_job_end(self, config, job_return) -> None:
        self.seen.append(("end", OmegaConf.to_container(config, resolve=False)))

    def task(self, cfg) -> str:
        self.seen.append(("task", OmegaConf.to_container(cfg, resolve=True),
                          OmegaConf.is_struct(cfg), OmegaConf.is_readonly(cfg), "hydra" in cfg,
                          OmegaConf.to_container(HydraConfig.get(), resolve=False),
                          OmegaConf.to_container(HydraConfig.get().sweep, resolve=True),
                          Path.cwd()))  # fmt: skip
        if self.fail:
            raise ValueError("the task failed")
        return "done"


def returned(ret) -> tuple:
    """A job return's fields, configs as containers."""
    return (OmegaConf.to_container(ret.cfg, resolve=False), OmegaConf.is_struct(ret.cfg),
            OmegaConf.to_container(ret.hydra_cfg, resolve=False), ret.overrides,
            ret.working_dir, ret.task_name, ret.status, repr(ret._return_value))  # fmt: skip


@pytest.fixture
def jobs(tmp_path, monkeypatch):
    """Real job configs of ``fp6_grid`` from the composer, results under ``tmp_path``."""
    monkeypatch.setenv("TTC_RESULTS_DIR", str(tmp_path / "results"))
    register_configs()
    with initialize_config_dir(config_dir=str(PROJECT_ROOT / "conf"), version_base="1.3"):
        master = compose(config_name="config", overrides=JOBS[0][:1], return_hydra_config=True)
        loader = GlobalHydra.instance().config_loader()
        composer = Composer(loader, master)
        configs = []
        for idx, job in enumerate(JOBS):
            cfg = composer.config(job)
            with open_dict(cfg):
                cfg.hydra.job.id, cfg.hydra.job.num = f"{cfg.hydra.job.name}_{idx}", idx
            configs.append(cfg)
        yield loader, configs


@pytest.mark.parametrize("fail", [False, True])
@pytest.mark.parametrize("output_subdir", [None, ".hydra"])
def test_same_as_hydras_run_job(jobs, tmp_path, fail, output_subdir) -> None:
    loader, configs = jobs
    for cfg in configs:
        with open_dict(cfg):
            cfg.hydra.output_subdir = output_subdir
        mine, hydras = Recorder(fail), Recorder(fail)
        theirs_cfg = copy.deepcopy(cfg)
        before = HydraConfig.instance().cfg
        ret = run_sweep_job(mine.task, cfg, HydraContext(config_loader=loader, callbacks=mine))
        assert HydraConfig.instance().cfg is before  # put back as Hydra does
        expected = run_job(hydras.task, theirs_cfg, "hydra.sweep.dir", "hydra.sweep.subdir",
                           HydraContext(config_loader=loader, callbacks=hydras))  # fmt: skip
        assert mine.seen == hydras.seen
        assert returned(ret) == returned(expected)
        assert OmegaConf.to_container(cfg, resolve=False) == OmegaConf.to_container(
            theirs_cfg, resolve=False
        )  # the output folder set on the job's config as Hydra sets it
        assert ret.status == (JobStatus.FAILED if fail else JobStatus.COMPLETED)
        job_dir = Path(cfg.hydra.runtime.output_dir)
        assert job_dir.is_dir() and job_dir.parent.parent.parent == tmp_path / "results"
        assert job_dir.parent.name == "jobs" and job_dir.name == str(cfg.hydra.job.num)
        files = sorted(p.name for p in job_dir.rglob("*.yaml"))
        assert files == ([] if output_subdir is None else ["config.yaml", "hydra.yaml",
                                                            "overrides.yaml"])  # fmt: skip
