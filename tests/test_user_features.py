"""Your own feature in ten lines: a detector defined in this file runs through a real sweep
(``detector=custom detector.target=tests.test_user_features:grid_corners``), and the plugin
contract (signatures, return types, errors, the cache identity of the code)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from experiments import store
from tests.conftest import PROJECT_ROOT
from ttc.features.descriptors import DESCRIPTORS, describe_keypoints, descriptor_is_binary
from ttc.features.keypoints import DETECTORS, detect_keypoints
from ttc.features.matching import MATCHER_PARAMS, SelectorParams, knn_candidates, select_matches
from ttc.io.frames import read_image
from ttc.plugins import (
    CustomDescriptorParams,
    CustomDetectorParams,
    CustomMatcherParams,
    code_identity,
    resolve_callable,
)

TARGET = "tests.test_user_features:grid_corners"


def grid_corners(gray: np.ndarray, cell: int = 16, quality: float = 0.02) -> np.ndarray:
    """The user's detector: the strongest Shi–Tomasi corner of every ``cell`` × ``cell`` px
    cell whose response beats ``quality`` × the image's best, as (N, 2) x, y."""
    response = cv2.cornerMinEigenVal(gray, 3)
    h, w = (s - s % cell for s in gray.shape)
    cells = response[:h, :w].reshape(h // cell, cell, w // cell, cell).transpose(0, 2, 1, 3)
    flat = cells.reshape(h // cell, w // cell, -1)
    best = flat.argmax(axis=2)
    rows, cols = np.nonzero(flat.max(axis=2) > quality * response.max())
    dy, dx = np.divmod(best[rows, cols], cell)
    return np.column_stack([cols * cell + dx, rows * cell + dy]).astype(np.float64)


def keypoint_list(gray: np.ndarray) -> list[cv2.KeyPoint]:
    return [cv2.KeyPoint(10.0, 12.0, 5.0), cv2.KeyPoint(30.5, 40.25, 7.0)]


def one_candidate_row(desc_prev, desc_curr, binary: bool):
    return np.zeros((1, 2)), np.zeros((1, 2))


def one_descriptor_too_many(gray: np.ndarray, keypoints: np.ndarray):
    return keypoints, np.zeros((len(keypoints) + 1, 4))


@pytest.fixture(scope="module")
def gray(kitti_dir: Path) -> np.ndarray:
    return cv2.cvtColor(read_image(kitti_dir / "image_02/data/0000000000.png"), cv2.COLOR_BGR2GRAY)


def test_custom_detector_through_the_registry(gray) -> None:
    params = CustomDetectorParams(target=TARGET, params={"cell": 24})
    assert DETECTORS["custom"] is CustomDetectorParams
    kps = detect_keypoints(gray, params)
    assert kps.shape[1] == 7 and 100 < len(kps) <= (375 // 24) * (1242 // 24)
    np.testing.assert_array_equal(kps[:, :2], grid_corners(gray, cell=24))
    refined = detect_keypoints(gray, CustomDetectorParams(target=TARGET, subpixel=True))
    assert np.mean(refined[:, :2] != np.round(refined[:, :2])) > 0.5
    listed = detect_keypoints(gray, CustomDetectorParams(target=f"{__name__}:keypoint_list"))
    np.testing.assert_array_equal(listed[:, :3], [[10, 12, 5], [30.5, 40.25, 7]])


def test_default_examples_describe_and_match(kitti_dir: Path, gray) -> None:
    gray1 = cv2.cvtColor(read_image(kitti_dir / "image_02/data/0000000001.png"), cv2.COLOR_BGR2GRAY)
    det, desc = CustomDetectorParams(), DESCRIPTORS["custom"]()
    (k0, d0), (k1, d1) = (describe_keypoints(g, detect_keypoints(g, det), "custom", desc)
                          for g in (gray, gray1))  # fmt: skip
    assert d0.dtype == np.float32 and not descriptor_is_binary(desc) and len(k0) == len(d0)
    idx, dist = knn_candidates(d0, d1, False, MATCHER_PARAMS["custom"]())
    m = select_matches(idx, dist, SelectorParams())
    moved = np.hypot(*(k1[m.curr_idx, :2] - k0[m.prev_idx, :2]).T)
    assert len(m) > 100 and np.mean(moved < 30) > 0.8


def test_bad_targets_and_returns_say_what_is_wrong(gray) -> None:
    with pytest.raises(ValueError, match="cannot import"):
        resolve_callable("tests.no_such_module:fn")
    with pytest.raises(ValueError, match="module:function"):
        CustomDetectorParams(target="")
    with pytest.raises(ValueError, match="not callable"):
        resolve_callable("tests.test_user_features:TARGET")
    bad = CustomDescriptorParams(target=f"{__name__}:one_descriptor_too_many")
    with pytest.raises(ValueError, match="2 keypoints but descriptors"):
        describe_keypoints(gray, np.zeros((2, 7)), "fast", bad)
    with pytest.raises(ValueError, match="candidates"):
        knn_candidates(np.zeros((3, 4), np.float32), np.zeros((2, 4), np.float32), False,
                       CustomMatcherParams(target=f"{__name__}:one_candidate_row"))  # fmt: skip


def test_code_identity_follows_the_code() -> None:
    assert code_identity(TARGET) == code_identity(TARGET)
    assert code_identity(TARGET) != code_identity(f"{__name__}:keypoint_list")


@pytest.mark.slow
def test_sweep_with_a_detector_defined_in_this_file(tmp_path: Path) -> None:
    env = {**os.environ, "TTC_RESULTS_DIR": str(tmp_path / "sweeps"),
           "TTC_CACHE_DIR": str(tmp_path / "cache")}  # fmt: skip
    args = ["-m", "detector=custom", f"detector.target={TARGET}", "+detector.params.cell=20",
            "descriptor=brief,orb", "dataset.last=3", "sweep_name=mine"]  # fmt: skip
    done = subprocess.run([sys.executable, "-m", "experiments.run", *args], cwd=PROJECT_ROOT,
                          env=env, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    sweep = tmp_path / "sweeps" / "mine"
    runs = store.load_runs(sweep)
    assert (runs["status"] == "ok").all() and len(runs) == 2
    assert set(runs["detector"]) == {"custom"} and TARGET in runs["config"].iloc[0]
    lead = store.load_sweep(sweep)[0].query("is_lead")
    assert len(lead) == 2 * 3 and (lead["keypoints_curr"] > 100).all()
    assert (lead["matches_in_box"] > 10).all() and np.isfinite(lead["ttc_camera"]).any()
