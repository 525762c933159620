"""The real Hydra command line in subprocesses: sweep, merge, resume, kill + resume, typos."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments import store
from tests.conftest import PROJECT_ROOT
from ttc.engine.entry_file import read_entry

pytestmark = pytest.mark.slow

GRID = ["detector=fast,akaze", "descriptor=brief,akaze", "matcher=bf,flann", "dataset.last=3"]


def hydra_run(
    args: list[str], tmp: Path, timeout: float = 600, **kwargs
) -> subprocess.CompletedProcess:
    """Run ``python -m experiments.run`` with results and cache under ``tmp``."""
    env = {
        **os.environ,
        "TTC_RESULTS_DIR": str(tmp / "sweeps"),
        "TTC_CACHE_DIR": str(tmp / "cache"),
    }
    return subprocess.run(
        [sys.executable, "-m", "experiments.run", *args],
        cwd=PROJECT_ROOT, env=env, capture_output=True, text=True, timeout=timeout, **kwargs,
    )  # fmt: skip


@pytest.fixture(scope="module")
def sweep(
    tmp_path_factory,
) -> tuple[Path, subprocess.CompletedProcess, subprocess.CompletedProcess]:
    """The 2 × 2 × 2 grid over frames 0–3, run twice (the second run must resume)."""
    tmp = tmp_path_factory.mktemp("sweep")
    first = hydra_run(["-m", *GRID, "sweep_name=grid"], tmp)
    assert first.returncode == 0, first.stderr[-3000:]
    second = hydra_run(["-m", *GRID, "sweep_name=grid"], tmp)
    assert second.returncode == 0, second.stderr[-3000:]
    return tmp / "sweeps" / "grid", first, second


def test_sweep_merges_into_one_dataset(sweep) -> None:
    sweep_dir, first, _ = sweep
    frames = store.load_sweep(sweep_dir)[0]
    runs = store.load_runs(sweep_dir)
    assert len(runs) == 8
    assert runs["run_id"].is_unique
    assert runs["status"].value_counts().to_dict() == {"ok": 6, "skipped": 2}
    skipped = runs[runs["status"] == "skipped"]
    assert set(skipped["detector"]) == {"fast"} and set(skipped["descriptor"]) == {"akaze"}
    assert skipped["message"].str.contains("AKAZE", case=False).all()
    assert frames["run_id"].nunique() == 6
    lead = frames[frames["is_lead"]]
    assert len(lead) == 6 * 3  # three frame pairs per ok setting
    assert set(lead.groupby("run_id")["frame"].apply(tuple)) == {(1, 2, 3)}
    assert "settings: 8 total, 6 ok, 2 skipped, 0 failed" in first.stdout
    assert "best 5 settings" in first.stdout
    assert not list(sweep_dir.rglob("*.tmp"))


def test_sweep_columns_and_types(sweep) -> None:
    from tests.test_pipeline import check_frame_columns

    frames = store.load_sweep(sweep[0])[0]
    check_frame_columns(frames)
    assert frames["git_commit"].notna().all()
    runs = store.load_runs(sweep[0])
    for column in ("config", "git_commit", "git_dirty", "version_opencv", "version_numpy",
                   "version_python", "start", "end", "wall_s", "peak_rss_mb"):  # fmt: skip
        assert column in runs, column


def test_second_run_computes_nothing(sweep) -> None:
    sweep_dir, first, second = sweep
    runs = store.load_runs(sweep_dir)
    assert "this invocation: 0 computed, 8 already complete" in second.stdout
    assert "settings: 8 total, 6 ok, 2 skipped" in second.stdout
    assert (runs.loc[runs["status"] == "ok", "stages_computed"] > 0).all()  # first run computed
    # re-running one setting in place (force) now finds every stage in the cache
    tmp = sweep_dir.parents[1]
    forced = hydra_run(["detector=fast", "descriptor=brief", "matcher=flann", "dataset.last=3",
                        "force=true", "hydra.run.dir=" + str(tmp / "single")], tmp)  # fmt: skip
    assert forced.returncode == 0, forced.stderr[-3000:]
    rows = pd.read_parquet(next((tmp / "single" / "runs").glob("*.parquet")))
    cached = rows[[c for c in rows if c.startswith("cached_")]]
    assert cached.to_numpy().all()


def test_determinism_same_setting_same_numbers(tmp_path: Path) -> None:
    """Two runs of one setting, cache off, give identical TTC columns."""
    args = [
        "detector=orb",
        "descriptor=brisk",
        "matcher=flann",
        "dataset.last=4",
        "cache.enabled=false",
    ]
    outs = []
    for i in range(2):
        res = hydra_run([*args, f"hydra.run.dir={tmp_path / str(i)}"], tmp_path)
        assert res.returncode == 0, res.stderr[-3000:]
        outs.append(pd.read_parquet(next((tmp_path / str(i) / "runs").glob("*.parquet"))))
    a, b = outs
    assert not a["cached_keypoints"].any()
    for column in ("ttc_lidar", "ttc_camera", "matches_total", "matches_kept"):
        np.testing.assert_array_equal(a[column].to_numpy(), b[column].to_numpy())


def test_typo_in_override_fails_fast(tmp_path: Path) -> None:
    start = time.perf_counter()
    res = hydra_run(["detector.treshold=5"], tmp_path)
    assert res.returncode != 0
    assert "treshold" in res.stderr
    res = hydra_run(["detector=fastt"], tmp_path)
    assert res.returncode != 0 and "Could not find 'detector/fastt'" in res.stderr
    res = hydra_run(["matcher.flann_trees=many"], tmp_path)
    assert res.returncode != 0 and "flann_trees" in res.stderr
    assert time.perf_counter() - start < 60
    assert not (tmp_path / "cache").exists()  # nothing was computed
    # a sweep whose first job does not compose: Hydra's words (its workers may warm up)
    res = hydra_run(["-m", "detector=fastt,orb", "dataset.last=2"], tmp_path / "sweep")
    assert res.returncode != 0 and "Could not find 'detector/fastt'" in res.stderr


def test_missing_data_root_says_how_to_get_it(tmp_path: Path) -> None:
    res = hydra_run([f"dataset.root={tmp_path / 'nowhere'}"], tmp_path)
    assert res.returncode != 0
    assert "KITTI frames not found" in res.stderr
    assert "experiments.data.download" in res.stderr


def test_kill_and_resume(tmp_path: Path) -> None:
    """SIGKILL a sweep after its first settings, re-run: every setting once, no partial files."""
    args = ["-m", "detector=fast,orb,brisk", "descriptor=brief,orb", "dataset.last=2",
            "sweep_name=killed", "hydra.launcher.n_jobs=1"]  # fmt: skip
    env = {**os.environ, "TTC_RESULTS_DIR": str(tmp_path / "sweeps"),
           "TTC_CACHE_DIR": str(tmp_path / "cache")}  # fmt: skip
    proc = subprocess.Popen(
        [sys.executable, "-m", "experiments.run", *args], cwd=PROJECT_ROOT, env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    runs_dir = tmp_path / "sweeps" / "killed" / "runs"
    deadline = time.time() + 300
    while time.time() < deadline and len(list(runs_dir.glob("*.json"))) < 2:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    done_before = len(list(runs_dir.glob("*.json")))
    assert 2 <= done_before < 6, "the sweep should have been killed midway"

    res = hydra_run(args, tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    resumed = re.search(r"this invocation: (\d+) computed, (\d+) already complete", res.stdout)
    assert resumed and int(resumed[2]) >= done_before and int(resumed[1]) == 6 - int(resumed[2])
    runs = store.load_runs(tmp_path / "sweeps" / "killed")
    frames = store.load_sweep(tmp_path / "sweeps" / "killed")[0]
    assert len(runs) == 6 and runs["run_id"].is_unique
    assert (runs["status"] == "ok").all()
    lead = frames[frames["is_lead"]]
    assert not lead.duplicated(["run_id", "frame"]).any()
    assert len(lead) == 6 * 2
    assert not list((tmp_path / "sweeps").rglob("*.tmp"))  # collect removed stale temp files
    entries = list((tmp_path / "cache").rglob("*.arr"))
    assert entries
    for entry in entries:  # every cache entry is whole
        key, arrays = read_entry(entry)
        assert key == entry.stem and arrays


def test_submitit_local_launcher(tmp_path: Path) -> None:
    """The Slurm path's launcher, run locally, on a batched sweep (a batch per array task):
    same records and merged dataset."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    res = hydra_run(["-m", "hydra/launcher=submitit_local", "detector=fast",
                     "descriptor=brief,orb", "keypoint_filter=none,zscore", "dataset.last=2",
                     "sweep_name=sub"], tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    assert "4 to compute in 2 jobs (2 batches)" in res.stdout
    runs = store.load_runs(tmp_path / "sweeps" / "sub")
    assert sorted(runs["descriptor"]) == ["brief", "brief", "orb", "orb"]
    assert (runs["status"] == "ok").all() and runs["batch_id"].nunique() == 2
    frames = store.load_sweep(tmp_path / "sweeps" / "sub")[0]
    assert frames.loc[frames["is_lead"]].groupby("run_id").size().eq(2).all()
