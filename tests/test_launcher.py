"""The launcher's workers get every job's config from the sweep's composer, exactly as Hydra
composes it; a dead worker is named; a worker killed mid-job costs no setting; the workers end
with the sweep."""

from __future__ import annotations

import contextlib
import itertools
import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import OmegaConf

from experiments.configs.structured import register_configs
from experiments.store import load_runs
from experiments.sweep.compose import Composer, variant_jobs
from experiments.sweep.sweeper import group_combination_jobs, meanwhile, validation_jobs
from experiments.sweep.workers import STARTED_DIR, shut_down_workers, worker_death
from tests.conftest import PROJECT_ROOT


@pytest.fixture(scope="module")
def loader_and_master():
    register_configs()
    with initialize_config_dir(config_dir=str(PROJECT_ROOT / "conf"), version_base="1.3"):
        master = compose(
            config_name="config",
            overrides=["+experiment=fp6_grid", "keypoint_filter=zscore"],
            return_hydra_config=True,
        )
        yield GlobalHydra.instance().config_loader(), master


def comparable(cfg):
    """The whole config, interpolations unresolved, and the job's part resolved."""
    job = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"])
    return OmegaConf.to_container(cfg, resolve=False), OmegaConf.to_container(job, resolve=True)


def test_every_job_gets_hydras_config(loader_and_master) -> None:
    loader, master = loader_and_master
    jobs = [
        ["+experiment=fp6_grid", "keypoint_filter=zscore", f"detector={d}", f"descriptor={e}",
         f"matcher={m}", f"dataset={ds}", f"lidar.shrink={s}"]
        for d, e, m, ds, s in itertools.product(("fast", "sift"), ("brief", "akaze"),
                                                ("bf", "flann"), ("kitti_0_18", "kitti_0_77"),
                                                (0.1, 0.2))
    ]  # fmt: skip
    composer = Composer(loader, master)
    for job in jobs:
        assert comparable(composer.config(job)) == comparable(
            loader.load_sweep_config(master, job)
        ), job
    # the template plus one variant per further value of each swept key; the rest are copies
    assert composer.full_compositions == 1 + 5


def test_jobs_composed_from_the_sweepers_compositions(loader_and_master) -> None:
    """Seeded with the sweeper's compositions (template + one variant per value), the
    workers' composer composes nothing itself and still gives every job Hydra's config."""
    loader, master = loader_and_master
    jobs = [[f"detector={d}", f"descriptor={e}", f"matcher={m}", "lidar.shrink=0.2"]
            for d, e, m in itertools.product(("fast", "sift", "orb"), ("brief", "akaze"),
                                             ("bf", "flann"))]  # fmt: skip
    known = {tuple(v): loader.load_sweep_config(master, v) for v in variant_jobs(jobs)}
    assert len(known) == 1 + 2 + 1 + 1
    composer = Composer(loader, master, known, template=jobs[0])
    for job in jobs[::-1]:
        cfg = composer.config(job)
        assert comparable(cfg) == comparable(loader.load_sweep_config(master, job)), job
        cfg.hydra.job.num = 7  # the launcher sets it on the job's config: not on a shared one
    batch = composer.config([*jobs[3], "batch=batch-0123"])
    assert batch.batch == "batch-0123" and batch.hydra.overrides.task[-1] == "batch=batch-0123"
    assert composer.full_compositions == 0
    assert all(OmegaConf.is_missing(c.hydra.job, "num") for c in known.values())


def test_workers_start_from_the_sweepers_parts(loader_and_master) -> None:
    """The state a worker gets (:meth:`Composer.shared`, through pickle as the launcher sends
    it) holds the template's composition and the parts, not the variants' compositions: the
    worker's composer composes nothing and gives every job Hydra's config."""
    loader, master = loader_and_master
    jobs = [["+experiment=fp6_grid", "keypoint_filter=zscore", f"detector={d}",
             f"descriptor={e}", f"matcher={m}", "dataset.last=5"]
            for d, e, m in itertools.product(("fast", "sift", "orb"), ("brief", "akaze"),
                                             ("bf", "flann"))]  # fmt: skip
    sweeper = Composer(loader, master)
    for job in variant_jobs(jobs):  # what the sweeper's validation composes
        sweeper.setting(job)
    assert sweeper.full_compositions == 1 + 2 + 1 + 1
    known, template, earlier, parts = pickle.loads(pickle.dumps(sweeper.shared()))
    assert list(known) == [tuple(template)] and earlier is None
    detached = [p for p in parts.values() if p is not None]
    assert detached and all(p.config is None for p in detached)
    assert all(p.node._get_parent() is None for p in detached if OmegaConf.is_config(p.node))
    worker = Composer(loader, master, known, template, earlier, parts)
    for job in jobs[::-1]:
        assert comparable(worker.config(job)) == comparable(loader.load_sweep_config(master, job))
    assert worker.full_compositions == 0


def test_a_value_it_cannot_prove_local_goes_through_hydra(loader_and_master) -> None:
    loader, master = loader_and_master
    composer = Composer(loader, master)
    jobs = [["+experiment=fp6_grid", f"+extra={v}"] for v in (1, 2, 3)]  # additions, not changes
    for job in jobs:
        assert comparable(composer.config(job)) == comparable(loader.load_sweep_config(master, job))
    assert composer.full_compositions == 3


def test_overlapping_keys_go_through_hydra(loader_and_master) -> None:
    """A group and a value under it, both differing from the template: the order Hydra
    applies them in is not the job's order, so the job is composed by Hydra."""
    loader, master = loader_and_master
    template = ["dataset.last=5", "dataset=kitti_0_18"]
    composer = Composer(loader, master, template=template)
    for job in (["dataset.last=6", "dataset=kitti_0_77"], ["dataset.last=6", "dataset=kitti_0_18"],
                ["dataset.last=5", "dataset=kitti_0_77"]):  # fmt: skip
        assert comparable(composer.config(job)) == comparable(
            loader.load_sweep_config(master, job)
        ), job
        assert composer.setting(job)["dataset"]["last"] == int(job[0].split("=")[1])
    assert composer.parts(["dataset.last=6", "dataset=kitti_0_77"]) is None


def test_validation_jobs_cover_every_value_once_per_key() -> None:
    batch = [list(j) for j in itertools.product(("d=a", "d=b", "d=c"), ("e=1", "e=2"), ("m=x",))]
    jobs = variant_jobs(batch)
    assert len(jobs) == 1 + 2 + 1  # the template, then one variant per further value
    for position in range(3):
        assert {job[position] for job in jobs} == {job[position] for job in batch}


def test_every_combination_of_the_dataset_overrides_is_validated() -> None:
    batch = [list(j) for j in itertools.product(("detector=fast", "detector=orb"),
                                                ("dataset.first=0", "dataset.first=3"),
                                                ("dataset.last=2", "dataset.last=5"))]  # fmt: skip
    jobs = group_combination_jobs(batch, "dataset")
    assert len(jobs) == 4  # (first, last) pairs; the detector stays the first job's
    assert {tuple(j[1:]) for j in jobs} == {tuple(j[1:]) for j in batch}
    assert {j[0] for j in jobs} == {"detector=fast"}
    # the template and its variants miss the (3, 5) pair; the validation holds it
    assert ["detector=fast", "dataset.first=3", "dataset.last=5"] not in variant_jobs(batch)
    assert ["detector=fast", "dataset.first=3", "dataset.last=5"] in jobs
    assert ["detector=fast", "dataset.first=3", "dataset.last=5"] in validation_jobs(batch)


def test_meanwhile_runs_beside_the_block_and_is_waited_for() -> None:
    """The deferred work (the plan's skipped records) runs in another thread while the block
    runs, is finished when the block ends, and its error is raised then; the block's own
    error wins over it; None runs nothing."""
    started, release, seen = threading.Event(), threading.Event(), []

    def work() -> None:
        started.set()
        assert release.wait(5)
        seen.append(threading.current_thread().name)

    with meanwhile(work):
        assert started.wait(5)  # runs while the block does
        assert not seen
        release.set()
    assert seen and seen[0].startswith("ttc-meanwhile")  # waited for, in its own thread

    def broken() -> None:
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"), meanwhile(broken):
        pass
    with pytest.raises(KeyboardInterrupt), meanwhile(broken):
        raise KeyboardInterrupt
    with meanwhile(None):
        pass


def test_worker_death_names_the_signal() -> None:
    from joblib.externals.loky.process_executor import TerminatedWorkerError

    exc = TerminatedWorkerError(
        "A worker process managed by the executor was unexpectedly terminated. This could be "
        "caused by a segmentation fault ...\n\nThe exit codes of the workers are {SIGKILL(-9)}"
    )
    assert worker_death(exc).startswith("worker process died (SIGKILL(-9)): killed by a signal")


def test_worker_processes_end_with_the_sweep() -> None:
    """After the jobs, no pool worker stays alive holding memory (loky's resource trackers,
    a few MB, are all that remains)."""
    psutil = pytest.importorskip("psutil")
    from joblib import Parallel, delayed  # noqa: PLC0415

    pids = set(Parallel(n_jobs=2, backend="loky")(delayed(os.getpid)() for _ in range(4)))
    alive = {c.pid for c in psutil.Process().children(recursive=True)}
    assert pids <= alive  # the pool keeps its workers for reuse
    shut_down_workers(2)
    assert not pids & {c.pid for c in psutil.Process().children(recursive=True)}

    # without waiting (what a sweep does): the call returns, the workers exit on their own
    from joblib.externals.loky import get_reusable_executor, reusable_executor  # noqa: PLC0415

    pids = set(Parallel(n_jobs=2, backend="loky")(delayed(os.getpid)() for _ in range(4)))
    pool = get_reusable_executor(reuse=True)  # the pool the jobs ran on
    shut_down_workers(2, wait=False)
    # that pool was told to stop, not replaced by a new one (which loky does, after waiting
    # for the old one's workers, when asked with other arguments than joblib's)
    assert pool._flags.shutdown and reusable_executor._executor is pool
    procs = []
    for pid in pids:
        with contextlib.suppress(psutil.NoSuchProcess):  # already gone
            procs.append(psutil.Process(pid))
    _, alive = psutil.wait_procs(procs, timeout=10)
    assert not alive  # none still alive after 10 s
    assert not pids & {c.pid for c in psutil.Process().children(recursive=True)}


@pytest.mark.parametrize("max_batch_size", [None, 5])
def test_the_jobs_are_hydras_basic_sweepers(loader_and_master, max_batch_size) -> None:
    """Sweep overrides expand into the jobs, in the order and batches, of Hydra's basic
    sweeper (params first, a later override of a key taking its place; glob and range)."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper  # noqa: PLC0415
    from hydra.core.override_parser.overrides_parser import OverridesParser  # noqa: PLC0415

    from experiments.sweep.jobs import batches, expand  # noqa: PLC0415

    loader, _ = loader_and_master
    parser = OverridesParser.create(config_loader=loader)
    for args in (["detector=fast,orb", "matcher=glob(*)", "dataset.last=range(3,5)"],
                 ["descriptor=brief,orb", "selector=nn", "descriptor=sift", "+experiment=x"],
                 ["lidar_ttc=glob(*,exclude=cluster)", "detector=fast,orb", "lidar.shrink=0.2"],
                 []):  # fmt: skip
        overrides = parser.parse_overrides(args)
        expected = BasicSweeper.split_arguments(overrides, max_batch_size)
        assert batches(expand(overrides), max_batch_size) == expected, args


def _kill_first_job(started: Path, proc: subprocess.Popen) -> int:
    """SIGKILL the worker of the first job to start (its marker in ``started`` holds its pid)
    while it computes; its pid (0 when the sweep ended first)."""
    deadline = time.time() + 300
    while proc.poll() is None and time.time() < deadline:
        for marker in started.glob("*") if started.is_dir() else []:
            with contextlib.suppress(OSError, ValueError):  # just created or just removed
                pid = int(marker.read_text())
                os.kill(pid, signal.SIGKILL)
                return pid
        time.sleep(0.01)
    return 0


@pytest.mark.slow
def test_a_worker_killed_mid_job_costs_no_setting(tmp_path: Path) -> None:
    """Issue 32: SIGKILL (the OOM killer's signal) to the worker of the first job while jobs
    are still waiting: the jobs that were running are re-run alone, the waiting ones go on in a
    joblib pool, every setting ends ``ok``. The re-runs' one-worker pool once became the pool
    joblib reused for the waiting jobs: ``AttributeError: '_ReusablePoolExecutor' object has
    no attribute '_temp_folder_manager'``, a traceback and exit 1."""
    psutil = pytest.importorskip("psutil")
    env = {**os.environ, "TTC_RESULTS_DIR": str(tmp_path / "sweeps"),
           "TTC_CACHE_DIR": str(tmp_path / "cache")}  # fmt: skip
    args = ["-m", "detector=fast,orb", "descriptor=brief,orb", "dataset.last=3",
            "cache.enabled=false", "hydra.launcher.n_jobs=2", "sweep_name=killed"]  # fmt: skip
    proc = subprocess.Popen(
        [sys.executable, "-m", "experiments.run", *args], cwd=PROJECT_ROOT, env=env, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    sweep = tmp_path / "sweeps" / "killed"
    killed = _kill_first_job(sweep / STARTED_DIR, proc)
    seen: set = set()  # every process the sweep started, the re-runs' worker included
    while proc.poll() is None:
        with contextlib.suppress(psutil.NoSuchProcess):
            seen.update(psutil.Process(proc.pid).children(recursive=True))
        time.sleep(0.1)
    out, err = proc.communicate(timeout=300)
    assert killed, err[-3000:]
    assert proc.returncode == 0, err[-3000:]
    assert "Traceback" not in err, err[-3000:]
    assert "worker process died (SIGKILL(-9)): killed by a signal" in out  # the reason, logged
    assert "re-running its jobs [0" in out
    runs = load_runs(sweep)
    assert len(runs) == 4 and (runs["status"] == "ok").all(), runs[["status", "message"]]
    _, alive = psutil.wait_procs(list(seen), timeout=10)
    assert not alive, f"processes left behind: {alive}"
