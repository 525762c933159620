"""Dense optical flow as a matcher (``matcher=dis``, ``matcher=farneback``): accuracy on the
synthetic pair of tests/test_klt.py (known translation and scale) and the pipeline on the real
KITTI frames 0 → 2 (descriptor recorded as none, camera TTC finite on the lead car), at the
detector's keypoints and on a regular grid (``detector=grid``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.test_klt import synthetic, truth  # noqa: F401  (the shared synthetic pair)
from ttc import reasons
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting
from ttc.features.dense_flow import DenseFlowParams, flow_keypoints
from ttc.features.descriptors import NO_DESCRIPTOR, InvalidCombinationError
from ttc.features.detectors_extra import GridParams, grid_points
from ttc.features.keypoints import FastParams
from ttc.features.matching import MATCHER_PARAMS, NO_SELECTOR, check_features, uses_descriptors
from ttc.settings import FrameRange, Settings
from ttc.steps.camera_ttc import CameraTTCParams

#: Settings that reach 0.1 px on the synthetic pair (full-resolution DIS, dense patches).
ACCURATE = {
    "dis": DenseFlowParams("dis", preset="medium", finest_scale=0, patch_stride=2),
    "farneback": DenseFlowParams("farneback", win_size=21, iterations=5, poly_n=7, poly_sigma=1.5),
}


@pytest.mark.parametrize("name", ["dis", "farneback"])
def test_dense_flow_recovers_a_known_translation_and_scale(synthetic, name: str) -> None:  # noqa: F811
    prev, curr, kps = synthetic
    tracks = flow_keypoints(prev, curr, kps, ACCURATE[name])
    assert len(tracks) > 0.95 * len(kps)
    error = np.hypot(*(tracks.keypoints_curr[:, :2] - truth(kps[tracks.prev_idx, :2])).T)
    assert np.median(error) < 0.05 and np.percentile(error, 90) < 0.1  # px
    assert MATCHER_PARAMS[name] is DenseFlowParams and not uses_descriptors(ACCURATE[name])


def test_dense_flow_parameters_are_checked() -> None:
    with pytest.raises(ValueError, match="preset"):
        DenseFlowParams(preset="slow")
    with pytest.raises(ValueError, match="name"):
        DenseFlowParams(name="lk")


@pytest.mark.parametrize("name", ["dis", "farneback"])
def test_dense_flow_runs_through_the_pipeline(kitti_dir: Path, tmp_path: Path, name: str) -> None:
    s = Settings(detector=FastParams(), descriptor=NO_DESCRIPTOR, matcher=DenseFlowParams(name),
                 selector=NO_SELECTOR, camera_ttc=CameraTTCParams("similarity_fit"))  # fmt: skip
    rows = run_setting(s, FrameRange(kitti_dir, 0, 2), StageCache(tmp_path / "cache"))
    lead = rows[rows["is_lead"]]
    assert lead["frame"].tolist() == [1, 2]
    assert (lead["matches_in_box"] > 50).all() and (lead["camera_reason"] == reasons.OK).all()
    assert lead["ttc_camera"].between(3, 40).all(), lead["ttc_camera"].tolist()


def test_grid_points_are_a_lattice_inside_the_margins() -> None:
    points = grid_points((20, 30), GridParams(step=8, margin=2))
    np.testing.assert_array_equal(points[:, :2], [[2, 2], [10, 2], [18, 2], [26, 2],
                                                  [2, 10], [10, 10], [18, 10], [26, 10]])  # fmt: skip
    assert (points[:, 2] == 8).all() and len(grid_points((20, 30), GridParams(margin=15))) == 0
    with pytest.raises(ValueError, match="step"):
        GridParams(step=0)
    with pytest.raises(InvalidCombinationError, match="trackers"):
        check_features("grid", "sift", "bf")
    check_features("grid", "sift", "dis")  # a tracker computes no descriptor


def test_dis_on_a_grid_recovers_a_known_translation_and_scale(synthetic) -> None:  # noqa: F811
    """Every lattice point, textured or not (Farnebäck: 90th percentile 0.16 px here)."""
    prev, curr, _ = synthetic
    grid = grid_points(prev.shape, GridParams(step=8, margin=16))
    tracks = flow_keypoints(prev, curr, grid, ACCURATE["dis"])
    assert len(grid) > 900 and len(tracks) > 0.95 * len(grid)
    error = np.hypot(*(tracks.keypoints_curr[:, :2] - truth(grid[tracks.prev_idx, :2])).T)
    assert np.median(error) < 0.05 and np.percentile(error, 90) < 0.1  # px


def test_dense_flow_on_a_grid_runs_through_the_pipeline(kitti_dir: Path, tmp_path: Path) -> None:
    s = Settings(detector=GridParams(), descriptor=NO_DESCRIPTOR, matcher=DenseFlowParams("dis"),
                 selector=NO_SELECTOR, camera_ttc=CameraTTCParams("similarity_fit"))  # fmt: skip
    rows = run_setting(s, FrameRange(kitti_dir, 0, 2), StageCache(tmp_path / "cache"))
    lead = rows[rows["is_lead"]]
    assert lead["frame"].tolist() == [1, 2]
    # the lead box (~190 x 140 px) holds hundreds of lattice points
    assert (lead["matches_in_box"] > 200).all() and (lead["camera_reason"] == reasons.OK).all()
    assert lead["ttc_camera"].between(3, 40).all(), lead["ttc_camera"].tolist()
