"""Fault injection: damaged copies of the frames in a temporary folder, one test per fault of
issue #10 (each asserts the rows, statuses, exit code and message, and that nothing else was
lost). Undamaged frames are symlinks to the real ones; damaged files are real copies."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments import store
from tests.conftest import PROJECT_ROOT
from ttc import reasons
from ttc.engine import stages
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting
from ttc.features.descriptors import DESCRIPTORS
from ttc.features.keypoints import DETECTORS
from ttc.io.calibration import CAM_TO_CAM, VELO_TO_CAM, load_calibration
from ttc.io.frames import FrameDataError, frame_files
from ttc.settings import FrameRange, Settings

SEQUENCE = Path("kitti") / "2011_09_26"
FRAMES = range(5)  # frames 0-4


def farm(kitti_dir: Path, root: Path, frames=FRAMES) -> Path:
    """A data root whose recording holds ``frames`` as symlinks and copied calibration files
    (to be damaged); returns the recording folder."""
    seq = root / SEQUENCE
    for index in frames:
        files = frame_files(kitti_dir, index)
        for src in (files.image, files.scan):
            dst = seq / src.relative_to(kitti_dir)
            dst.parent.mkdir(parents=True, exist_ok=True)
            dst.symlink_to(src)
    for name in (CAM_TO_CAM, VELO_TO_CAM):
        shutil.copy(kitti_dir / name, seq / name)
    return seq


def run_cli(args: list[str], root: Path, tmp: Path, cache: Path | None = None, **kw):
    """``python -m <module> args`` (default experiments.run) with data, results and cache
    under the test's folders."""
    env = {
        **os.environ,
        "TTC_DATA_DIR": str(root),
        "TTC_RESULTS_DIR": str(tmp / "sweeps"),
        "TTC_CACHE_DIR": str(cache or tmp / "cache"),
    }
    module = kw.pop("module", "experiments.run")
    return subprocess.run(
        [sys.executable, "-m", module, *args], cwd=PROJECT_ROOT, env=env,
        capture_output=True, text=True, timeout=600, **kw,
    )  # fmt: skip


def settings(detector: str = "fast", descriptor: str = "brief") -> Settings:
    return Settings(detector=DETECTORS[detector](), descriptor=DESCRIPTORS[descriptor]())


def single_rows(run_dir: Path) -> tuple[pd.DataFrame, dict]:
    """Rows and record of the one run in a single-run folder."""
    record_path = next((run_dir / store.RUNS_DIR).glob("*.json"))
    record = json.loads(record_path.read_text())
    return pd.read_parquet(record_path.with_suffix(".parquet")), record


@pytest.fixture(scope="module")
def shared_cache(tmp_path_factory) -> Path:
    """One stage cache for the tests of this module (symlinked frames share its entries)."""
    return tmp_path_factory.mktemp("fault-cache")


# -- 1. a missing frame costs only its pairs ----------------------------------------------
@pytest.mark.parametrize("kind", ["image", "scan"])
def test_1_missing_frame_costs_only_its_pairs(kitti_dir, tmp_path, shared_cache, kind) -> None:
    seq = farm(kitti_dir, tmp_path / "data")
    missing = getattr(frame_files(seq, 2), kind)
    missing.unlink()
    rows = run_setting(settings(), FrameRange(seq, 0, 4), StageCache(shared_cache))
    lead = rows[rows["is_lead"]].set_index("frame")
    assert lead.index.tolist() == [1, 2, 3, 4]  # every pair has its row
    for frame in (2, 3):  # the pairs touching frame 2
        assert lead.loc[frame, "lidar_reason"] == reasons.FRAME_ERROR
        assert lead.loc[frame, "camera_reason"] == reasons.FRAME_ERROR
        assert f"{missing}: file not found" in lead.loc[frame, "error"]
    for frame in (1, 4):  # the others are computed as usual
        assert lead.loc[frame, "error"] == ""
        assert lead.loc[frame, "lidar_reason"] == reasons.OK
        assert np.isfinite(lead.loc[frame, "ttc_lidar"])


@pytest.mark.slow
def test_1_range_past_the_last_frame_fails_at_start(kitti_dir, tmp_path) -> None:
    seq = farm(kitti_dir, tmp_path / "data")
    with pytest.raises(FrameDataError, match=r"past the recording's last frame: frames 0–4"):
        run_setting(settings(), FrameRange(seq, 0, 90), StageCache(None))
    res = run_cli(["-m", "descriptor=brief,orb", "dataset.last=90"], tmp_path / "data", tmp_path)
    assert res.returncode == 1
    assert "dataset.last=90 is past the recording's last frame: frames 0–4 exist" in res.stderr
    assert not (tmp_path / "sweeps" / "adhoc" / "runs").exists()  # no job ran


# -- 2. failures exit non-zero -------------------------------------------------------------
@pytest.mark.slow
def test_2_failures_exit_nonzero(kitti_dir, tmp_path, shared_cache) -> None:
    seq = farm(kitti_dir, tmp_path / "data")
    good = (seq / VELO_TO_CAM).read_text()
    t_line = next(line for line in good.splitlines() if line.startswith("T:"))
    (seq / VELO_TO_CAM).write_text(good.replace(t_line, "T: nan " + " ".join(t_line.split()[2:])))
    root = tmp_path / "data"
    # a sweep whose every computed setting fails (the AKAZE pair is skipped: not a failure)
    args = ["-m", "detector=fast", "descriptor=brief,orb,akaze", "dataset.last=1",
            "hydra.launcher.n_jobs=1"]  # fmt: skip
    res = run_cli([*args, "sweep_name=bad"], root, tmp_path, shared_cache)
    assert res.returncode == 1, res.stderr[-2000:]
    assert "settings: 3 total, 0 ok, 1 skipped, 2 failed" in res.stdout
    assert res.stdout.count("'T' has a non-finite value 'nan'") >= 2  # listed in the summary
    assert "sweep incomplete: 2 setting(s) failed" in res.stderr
    # calibration repaired: the failed settings are retried and succeed
    (seq / VELO_TO_CAM).write_text(good)
    res = run_cli([*args, "sweep_name=bad"], root, tmp_path, shared_cache)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "setting(s) failed" not in res.stderr  # skipped is no failure
    runs = pd.DataFrame(store.list_records(tmp_path / "sweeps" / "bad"))
    assert sorted(runs["status"]) == ["ok", "ok", "skipped"]  # the rows are all there


# -- 3. stale results are recomputed -------------------------------------------------------
@pytest.mark.slow
def test_3_frame_error_run_is_retried_after_repair(kitti_dir, tmp_path, shared_cache) -> None:
    seq = farm(kitti_dir, tmp_path / "data")
    image = frame_files(seq, 2).image
    target = image.readlink()
    image.unlink()
    run_dir = tmp_path / "single"
    args = ["dataset.last=3", f"hydra.run.dir={run_dir}", "print_rows=0"]
    res = run_cli(args, tmp_path / "data", tmp_path, shared_cache)
    assert res.returncode == 0, res.stderr[-2000:]  # the setting ran; its bad frames are rows
    rows, record = single_rows(run_dir)
    assert record["status"] == "ok" and record["n_frame_errors"] == 2
    assert "2 frame pair(s) with frame_error" in res.stdout and "0000000002.png" in res.stdout
    assert sorted(rows.loc[rows["error"] != "", "frame"].unique()) == [2, 3]
    image.symlink_to(target)  # repaired
    res = run_cli(args, tmp_path / "data", tmp_path, shared_cache)
    assert res.returncode == 0, res.stderr[-2000:]
    assert f"recomputing: input changed since it ran: {image}" in res.stdout
    rows, record = single_rows(run_dir)
    assert (rows["error"] == "").all() and record["n_frame_errors"] == 0
    assert record["recomputed_because"].startswith("input changed")
    res = run_cli(args, tmp_path / "data", tmp_path, shared_cache)
    assert "already complete (ok)" in res.stdout


@pytest.mark.slow
def test_3_load_sweep_sees_a_run_added_by_a_single_run(kitti_dir, tmp_path, shared_cache) -> None:
    root = tmp_path / "data"
    farm(kitti_dir, root)
    sweep = tmp_path / "sweeps" / "grow"
    res = run_cli(["-m", "descriptor=brief", "dataset.last=1", "sweep_name=grow",
                   "hydra.launcher.n_jobs=1"], root, tmp_path, shared_cache)  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    assert store.load_sweep(sweep)[0]["run_id"].nunique() == 1
    # one more setting into the same folder (a single run there)
    res = run_cli(["descriptor=orb", "dataset.last=1", f"hydra.run.dir={sweep}"], root,
                  tmp_path, shared_cache)  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    frames, runs = store.load_sweep(sweep)
    assert sorted(runs["descriptor"]) == ["brief", "orb"]
    assert sorted(frames["descriptor"].unique()) == ["brief", "orb"]
    assert frames["run_id"].nunique() == 2


# -- 4. a corrupt rows file ----------------------------------------------------------------
@pytest.mark.slow
def test_4_corrupt_rows_file_is_named_and_recomputed(kitti_dir, tmp_path, shared_cache) -> None:
    root = tmp_path / "data"
    farm(kitti_dir, root)
    args = ["-m", "descriptor=brief,orb", "dataset.last=1", "sweep_name=c",
            "hydra.launcher.n_jobs=1"]  # fmt: skip
    assert run_cli(args, root, tmp_path, shared_cache).returncode == 0
    sweep = tmp_path / "sweeps" / "c"
    runs = store.load_runs(sweep)
    bad = sweep / store.RUNS_DIR / f"{runs['run_id'][0]}.parquet"
    bad.write_bytes(bad.read_bytes()[: bad.stat().st_size // 2])
    res = run_cli([str(sweep)], root, tmp_path, module="experiments.summary.collect")
    assert res.returncode == 1
    assert f"{bad}: rows file corrupt" in res.stderr and "Traceback" not in res.stderr
    with pytest.raises(store.StoreError, match="rows file corrupt"):
        store.load_sweep(sweep)
    res = run_cli(args, root, tmp_path, shared_cache)
    assert res.returncode == 0, res.stderr[-2000:]
    assert f"recomputing: rows file {bad.name} corrupt" in res.stdout
    assert "this invocation: 1 computed, 1 already complete" in res.stdout
    frames, runs = store.load_sweep(sweep)
    assert (runs["status"] == "ok").all() and frames["run_id"].nunique() == 2


# -- 5. a dead worker costs only its setting -----------------------------------------------
def _kill_worker_of(sweep: Path, setting: str, proc: subprocess.Popen) -> list[int]:
    """SIGKILL every process that holds the run lock of ``setting`` until its record exists
    (the setting "always crashes"); returns the killed pids."""
    killed: list[int] = []
    runs_dir = sweep / store.RUNS_DIR
    deadline = time.time() + 300
    while proc.poll() is None and time.time() < deadline:
        for lock in runs_dir.glob("*.lock") if runs_dir.is_dir() else []:
            try:
                holder = json.loads(lock.read_text() or "{}")
            except ValueError:
                continue
            if setting in holder.get("holder", "") and holder["pid"] not in killed:
                if lock.with_suffix(".json").exists():
                    return killed
                try:
                    os.kill(holder["pid"], signal.SIGKILL)
                    killed.append(holder["pid"])
                except ProcessLookupError:
                    pass
        time.sleep(0.01)
    return killed


@pytest.mark.slow
def test_5_dead_worker_costs_only_its_setting(kitti_dir, tmp_path) -> None:
    root = tmp_path / "data"
    farm(kitti_dir, root)
    args = ["-m", "descriptor=brief,orb", "dataset.last=2", "cache.enabled=false",
            "sweep_name=crash", "hydra.launcher.n_jobs=2"]  # fmt: skip
    env = {**os.environ, "TTC_DATA_DIR": str(root), "TTC_RESULTS_DIR": str(tmp_path / "sweeps"),
           "TTC_CACHE_DIR": str(tmp_path / "cache")}  # fmt: skip
    proc = subprocess.Popen(
        [sys.executable, "-m", "experiments.run", *args], cwd=PROJECT_ROOT, env=env,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    sweep = tmp_path / "sweeps" / "crash"
    killed = _kill_worker_of(sweep, "descriptor=orb", proc)
    out, err = proc.communicate(timeout=300)
    assert len(killed) == 2  # its worker in the pool, then its worker alone
    assert proc.returncode == 1, err[-3000:]
    assert "sweep incomplete: 1 setting(s) failed" in err
    runs = store.load_runs(sweep).set_index("descriptor")
    assert runs.loc["orb", "status"] == "failed"
    assert "worker process died (SIGKILL(-9))" in runs.loc["orb", "message"]
    assert runs.loc["brief", "status"] == "ok"  # the other setting is whole
    frames = store.load_sweep(sweep)[0]
    assert frames.loc[frames["is_lead"], "descriptor"].tolist() == ["brief", "brief"]
    # a re-run retries the crashed setting only
    res = run_cli(args, root, tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "this invocation: 1 computed, 1 already complete" in res.stdout
    assert (store.load_runs(sweep)["status"] == "ok").all()


# -- 6. bad calibration values -------------------------------------------------------------
@pytest.mark.parametrize(
    ("name", "key", "value", "problem"),
    [
        (VELO_TO_CAM, "T", "nan", "non-finite"),
        (VELO_TO_CAM, "R", "inf", "non-finite"),
        (CAM_TO_CAM, "P_rect_02", "7.2l5377e+02", "non-numeric"),
    ],
)
def test_6_bad_calibration_value_names_file_key_value(
    kitti_dir, tmp_path, name, key, value, problem
) -> None:
    seq = farm(kitti_dir, tmp_path, frames=[0, 1])
    path = seq / name
    lines = path.read_text().splitlines()
    i = next(n for n, line in enumerate(lines) if line.startswith(f"{key}:"))
    words = lines[i].split()
    lines[i] = " ".join([words[0], value, *words[2:]])
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(FrameDataError) as info:
        load_calibration(seq)
    assert str(info.value) == f"{path}: '{key}' has a {problem} value '{value}'"
    # and a whole run fails with that message instead of NaN rows
    with pytest.raises(FrameDataError, match=f"'{key}' has a {problem} value"):
        run_setting(settings(), FrameRange(seq, 0, 1), StageCache(None))


# -- 7. invalid ranges and thresholds fail at start ----------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize(
    ("overrides", "messages"),
    [
        (
            ["dataset.first=3", "dataset.last=1", "camera_ttc.min_dist=-1",
             "keypoint_filter.factor=0"],
            ["dataset.last=1 must be >= dataset.first + dataset.step = 4",
             "camera_ttc: min_dist must be >= 0 pixels, got -1",
             "keypoint_filter: factor must be > 0, got 0"],
        ),
        (["dataset.step=0"], ["dataset.step=0 must be >= 1"]),
        (["dataset.first=0,3", "dataset.last=2,4"], ["dataset.last=2 must be >= dataset.first"]),
    ],
)  # fmt: skip
def test_7_invalid_values_fail_before_any_job(kitti_dir, tmp_path, overrides, messages) -> None:
    root = tmp_path / "data"
    farm(kitti_dir, root)
    res = run_cli(["-m", "descriptor=brief,orb", *overrides], root, tmp_path)
    assert res.returncode == 1
    for message in messages:
        assert message in res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "sweeps" / "adhoc" / "runs").exists()  # no job ran
    assert not (tmp_path / "cache").exists()


# -- 8. the cache cannot go stale ----------------------------------------------------------
def test_8_cache_keys_chain_upstream_versions_and_libraries(kitti_dir, monkeypatch) -> None:
    frames = FrameRange(kitti_dir, 0, 1)

    def keys() -> dict[str, str]:
        st = stages.FrameStages(settings(), frames, StageCache(None))
        tasks = {name: getattr(st, name)(0) for name in stages.PER_FRAME_STAGES}
        return {**{n: t.key for n, t in tasks.items()}, "matches": st.matches(0, 1).key}

    base = keys()
    monkeypatch.setitem(stages.STAGE_VERSIONS, "keypoints", 99)
    bumped = keys()
    assert {s for s in base if base[s] != bumped[s]} == {"keypoints", "descriptors", "matches"}
    monkeypatch.setitem(stages.STAGE_VERSIONS, "keypoints", 1)
    monkeypatch.setitem(stages.LIBRARY_VERSIONS, "opencv", "9.9.9")
    assert all(base[s] != v for s, v in keys().items())
    monkeypatch.setitem(stages.LIBRARY_VERSIONS, "opencv", stages.cv2.__version__)
    monkeypatch.setitem(stages.LIBRARY_VERSIONS, "numpy", "0.0")
    assert all(base[s] != v for s, v in keys().items())


def test_8_objects_key_holds_model_files_identity(kitti_dir, tmp_path) -> None:
    from ttc.features.objects import ObjectDetectorParams, model_file

    bundled = ObjectDetectorParams()
    copies = {}
    for kind in ("cfg", "weights", "names"):
        copies[kind] = tmp_path / model_file(bundled, kind).name
        copies[kind].symlink_to(model_file(bundled, kind))
    params = ObjectDetectorParams(**{f"{k}_path": str(p) for k, p in copies.items()})
    s = Settings(detector=DETECTORS["fast"](), descriptor=DESCRIPTORS["brief"](), objects=params)

    def key() -> str:
        return stages.FrameStages(s, FrameRange(kitti_dir, 0, 1), StageCache(None)).objects(0).key

    before = key()
    copies["weights"].unlink()
    shutil.copy(model_file(bundled, "weights"), copies["weights"])  # same bytes, new file
    assert key() != before


def test_8_unwritable_cache_computes_without_caching(kitti_dir, tmp_path, monkeypatch) -> None:
    frames = FrameRange(kitti_dir, 0, 2)
    expected = run_setting(settings(), frames, StageCache(None))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rows = run_setting(settings(), frames, StageCache("/sys/ttc-cache"))  # EPERM: read-only
    pd.testing.assert_frame_equal(rows.filter(like="ttc_"), expected.filter(like="ttc_"))
    assert not rows.filter(like="cached_").to_numpy().any()
    unwritable = [w for w in caught if "cannot be written" in str(w.message)]
    assert len(unwritable) == 1 and "/sys/ttc-cache" in str(unwritable[0].message)

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("ttc.engine.cache.atomic_write", full)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rows = run_setting(settings(), frames, StageCache(tmp_path / "full"))
    pd.testing.assert_frame_equal(rows.filter(like="ttc_"), expected.filter(like="ttc_"))
    assert [str(w.message) for w in caught if "No space left" in str(w.message)]


# -- 9. memory does not grow with the frame range ------------------------------------------
def test_9_decoded_images_are_bounded(kitti_dir, monkeypatch) -> None:
    import weakref

    alive: list[weakref.ref] = []
    most = [0]
    real = stages.read_image

    def tracked(path):
        image = real(path)
        alive.append(weakref.ref(image))
        most[0] = max(most[0], sum(ref() is not None for ref in alive))
        return image

    monkeypatch.setattr(stages, "read_image", tracked)
    rows = run_setting(settings(), FrameRange(kitti_dir, 0, 18), StageCache(None))
    assert rows["frame"].nunique() == 18
    assert len(alive) == 19  # each image decoded once
    assert most[0] <= stages.CHUNK_FRAMES + 1  # not all 19 at once


# -- 10. two identical sweeps at once ------------------------------------------------------
@pytest.mark.slow
def test_10_two_identical_sweeps_compute_each_setting_once(kitti_dir, tmp_path) -> None:
    root = tmp_path / "data"
    farm(kitti_dir, root)
    args = ["-m", "descriptor=brief,orb", "dataset.last=2", "cache.enabled=false",
            "sweep_name=twice", "hydra.launcher.n_jobs=1"]  # fmt: skip
    env = {**os.environ, "TTC_DATA_DIR": str(root), "TTC_RESULTS_DIR": str(tmp_path / "sweeps"),
           "TTC_CACHE_DIR": str(tmp_path / "cache")}  # fmt: skip
    procs = [
        subprocess.Popen([sys.executable, "-m", "experiments.run", *args], cwd=PROJECT_ROOT,
                         env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for _ in range(2)
    ]  # fmt: skip
    outs = [p.communicate(timeout=600) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], [e[-2000:] for _, e in outs]
    computed = []
    for out, _ in outs:
        line = next(x for x in out.splitlines() if x.startswith("this invocation:"))
        computed.append(int(line.split()[2]))
    assert sum(computed) == 2, computed  # each setting computed by one of them
    runs = store.load_runs(tmp_path / "sweeps" / "twice")
    assert len(runs) == 2 and (runs["status"] == "ok").all()
