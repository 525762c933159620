"""The options beyond the rubric leave the rubric alone: settings stored before they existed keep
their run ids and their TTCs; KLT settings collapse onto one run id per detector; KLT and the
fused TTC run end to end through the pipeline on real frames."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from experiments import store
from experiments.configs.structured import (
    axis_values,
    register_configs,
    run_id,
    setting_config,
    settings_from_config,
)
from tests.conftest import PROJECT_ROOT
from ttc import reasons
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting, run_settings
from ttc.features.descriptors import DESCRIPTORS, NO_DESCRIPTOR
from ttc.features.keypoints import DETECTORS, FastParams
from ttc.features.klt import KltParams
from ttc.features.matching import NO_SELECTOR
from ttc.rows import MEMBER
from ttc.settings import FrameRange, Settings
from ttc.steps import fusion
from ttc.steps.fusion import FusionParams

#: Run ids of settings stored in sweeps before sub-pixel keypoints, KLT and fusion existed
#: (commit 50ad91a): those options must not change them. Issues 30 and 50 changed every id on
#: purpose (every row's object columns; the object lidar's keys and the box-relative camera
#: pair rule; see tests/test_run_ids.py): these are the ids since.
STORED_RUN_IDS = {
    (): "50a4120e621d0272",
    ("detector=orb", "descriptor=orb", "matcher=flann", "selector=nn"): "842636907a87f6d3",
    ("detector=harris", "descriptor=sift", "dataset=kitti_0_77"): "acfaf8dda028b048",
    ("detector=sift", "descriptor=sift", "lidar_ttc=cluster", "keypoint_filter=iqr"):
        "1a88e42900c63c2c",
}  # fmt: skip
RUBRIC_CSV = PROJECT_ROOT / "results" / "kitti_0_18" / "fp6_camera_ttc.csv"


def composed(overrides: list[str]):
    register_configs()
    with initialize_config_dir(config_dir=str(PROJECT_ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


@pytest.mark.parametrize("overrides", list(STORED_RUN_IDS), ids=lambda o: " ".join(o) or "default")
def test_run_ids_of_settings_stored_before_stay(overrides: tuple[str, ...]) -> None:
    expected = STORED_RUN_IDS[overrides]
    assert run_id(composed(list(overrides))) == expected
    explicit = [*overrides, "detector.subpixel=false", "fusion=none"]
    assert run_id(composed(explicit)) == expected
    assert run_id(composed([*overrides, "detector.subpixel=true"])) != expected
    assert run_id(composed([*overrides, "fusion=kalman_ca"])) != expected
    recorded = setting_config(composed(list(overrides)))
    assert recorded["detector"]["subpixel"] is False and recorded["fusion"]["name"] == "none"


def test_klt_settings_differing_only_in_descriptor_share_one_run_id() -> None:
    ids = {
        run_id(composed(["matcher=klt", f"descriptor={d}", f"selector={s}"]))
        for d in ("brief", "orb", "akaze", "sift")
        for s in ("nn", "knn")
    }
    assert len(ids) == 1
    cfg = composed(["matcher=klt", "descriptor=akaze"])  # an invalid pair with descriptors
    setting = setting_config(cfg)
    assert setting["descriptor"] == {"name": "none"} and setting["selector"] == {"name": "none"}
    s = settings_from_config(cfg)
    assert s.descriptor is NO_DESCRIPTOR and s.selector is NO_SELECTOR
    assert s.axes()["descriptor"] == "none" and s.matcher == KltParams()
    again = settings_from_config(OmegaConf.create(setting))  # as a sweep's batch job does
    assert again == s
    assert run_id(composed(["matcher=klt", "detector=orb"])) not in ids
    assert run_id(composed(["matcher=klt", "matcher.fb_threshold=0.5"])) not in ids


def test_recorded_axis_values_tell_the_options_apart() -> None:
    assert axis_values(setting_config(composed([])))["detector"] == "fast"
    refined = axis_values(setting_config(composed(["detector=orb", "detector.subpixel=true"])))
    assert refined["detector"] == "orb+subpixel"
    klt = axis_values(setting_config(composed(["matcher=klt", "fusion=kalman_cv"])))
    assert (klt["descriptor"], klt["selector"], klt["fusion"]) == ("none", "none", "kalman_cv")


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> StageCache:
    return StageCache(tmp_path_factory.mktemp("beyond-cache"))


def test_default_ttcs_equal_the_committed_rubric_report(kitti_dir: Path, cache) -> None:
    """FAST + BRIEF + BF + kNN on frames 0–18 under the configured camera pair rule (the box-
    relative default of conf/camera_ttc) gives the committed report's camera TTCs."""
    committed = pd.read_csv(RUBRIC_CSV).query("setting == 'fast/brief/bf/knn'")
    assert len(committed) == 18
    pairs = settings_from_config(composed([])).camera_ttc
    assert pairs.min_dist == 0 and pairs.min_box_fraction == 0.15
    s = Settings(detector=FastParams(), descriptor=DESCRIPTORS["brief"](), camera_ttc=pairs)
    rows = run_setting(s, FrameRange(kitti_dir, 0, 18), cache)
    lead = rows[rows["is_lead"]].set_index("frame").loc[committed["frame"]]
    np.testing.assert_allclose(lead["camera_ratio"], committed["camera_ratio"], rtol=1e-5)
    np.testing.assert_allclose(lead["ttc_camera"], committed["ttc_camera"], rtol=1e-4)
    assert lead["camera_reason"].tolist() == committed["camera_reason"].tolist()
    assert rows["ttc_fused"].isna().all() and (rows["fused_reason"] == fusion.OFF).all()


def test_klt_runs_through_the_pipeline(kitti_dir: Path, cache) -> None:
    s = Settings(detector=FastParams(), descriptor=NO_DESCRIPTOR, matcher=KltParams(),
                 selector=NO_SELECTOR)  # fmt: skip
    rows = run_setting(s, FrameRange(kitti_dir, 0, 6), cache)
    lead = rows[rows["is_lead"]]
    assert lead["frame"].tolist() == [1, 2, 3, 4, 5, 6]
    assert (lead["matches_total"] > 0.5 * lead["keypoints_prev"]).all()  # most tracks kept
    assert (lead["matches_in_box"] > 20).all() and (lead["camera_reason"] == reasons.OK).all()
    assert lead["ttc_camera"].between(3, 40).all()
    again = run_setting(s, FrameRange(kitti_dir, 0, 6), cache)
    assert again["cached_matches"].all()
    pd.testing.assert_series_equal(again["ttc_camera"], rows["ttc_camera"])


def test_fused_ttc_through_the_pipeline(kitti_dir: Path, cache) -> None:
    s = Settings(detector=DETECTORS["fast"](), descriptor=DESCRIPTORS["brief"](),
                 fusion=FusionParams(name="kalman_ca"))  # fmt: skip
    rows = run_setting(s, FrameRange(kitti_dir, 0, 18), cache)
    lead = rows[rows["is_lead"]]
    assert lead["fused_reason"].isin([fusion.FUSED, fusion.LIDAR_ONLY, fusion.CAMERA_ONLY]).all()
    assert lead["ttc_fused"].between(3, 40).all() and (lead["ttc_fused_sd"] > 0).all()
    assert np.isfinite(lead["fused_ratio"]).all()
    others = rows[~rows["is_lead"]]
    assert (others["fused_reason"] == fusion.NOT_LEAD).all() and others["ttc_fused"].isna().all()
    # The fused series is smoother than either sensor's.
    jitter = {c: lead[c].diff().abs().median() for c in ("ttc_fused", "ttc_camera", "ttc_lidar")}
    assert jitter["ttc_fused"] < min(jitter["ttc_camera"], jitter["ttc_lidar"])


def test_batched_execution_gives_the_same_klt_and_fused_rows(kitti_dir: Path, cache) -> None:
    klt = Settings(detector=FastParams(), descriptor=NO_DESCRIPTOR, matcher=KltParams(),
                   selector=NO_SELECTOR, fusion=FusionParams(name="kalman_ca"))  # fmt: skip
    fused = Settings(detector=FastParams(subpixel=True), descriptor=DESCRIPTORS["orb"](),
                     fusion=FusionParams(name="kalman_cv"))  # fmt: skip
    frames = FrameRange(kitti_dir, 0, 5)
    together, failed = run_settings([klt, fused], frames, cache)
    assert not failed
    for member, s in enumerate((klt, fused)):
        alone = run_setting(s, frames, cache)
        batch = together[together[MEMBER] == member].drop(columns=MEMBER)
        numbers = [c for c in alone if not c.startswith(("ms_", "cached_"))]
        pd.testing.assert_frame_equal(batch[numbers].reset_index(drop=True), alone[numbers])
        assert alone.loc[alone["is_lead"], "ttc_fused"].notna().all()


@pytest.mark.slow
def test_a_klt_sweep_runs_once_per_detector(tmp_path: Path) -> None:
    """``matcher=klt`` over four descriptors and two selectors: one run per detector."""
    env = {**os.environ, "TTC_RESULTS_DIR": str(tmp_path / "sweeps"),
           "TTC_CACHE_DIR": str(tmp_path / "cache")}  # fmt: skip
    args = ["-m", "detector=fast,orb", "matcher=klt", "descriptor=brief,orb,akaze,sift",
            "selector=nn,knn", "fusion=kalman_cv", "dataset.last=3", "sweep_name=klt"]  # fmt: skip
    done = subprocess.run([sys.executable, "-m", "experiments.run", *args], cwd=PROJECT_ROOT,
                          env=env, capture_output=True, text=True, timeout=900)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    runs = store.load_runs(tmp_path / "sweeps" / "klt")
    assert len(runs) == 2 and (runs["status"] == "ok").all()
    assert set(runs["descriptor"]) == {"none"} and set(runs["detector"]) == {"fast", "orb"}
    frames = store.load_sweep(tmp_path / "sweeps" / "klt")[0]
    lead = frames[frames["is_lead"]]
    assert len(lead) == 2 * 3 and (lead["fusion"] == "kalman_cv").all()
    assert lead["ttc_fused"].notna().all()
