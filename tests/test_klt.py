"""KLT tracking as a matcher (``matcher=klt``): accuracy on a synthetic pair with a known
translation and scale, the forward–backward check against injected false tracks, and the
matches it hands the pipeline on the real KITTI frames 0 → 1."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from ttc.features.keypoints import FastParams, ShiTomasiParams, detect_keypoints
from ttc.features.klt import KltParams, Tracks, forward_backward_error, track_keypoints
from ttc.features.matching import (
    MATCHER_PARAMS,
    NO_SELECTOR,
    SelectorParams,
    current_keypoints,
    is_tracks,
    pair_matches,
    tracks_to_arrays,
    tracks_to_matches,
    uses_descriptors,
)
from ttc.io.frames import read_image

HEIGHT, WIDTH = 240, 320  # px
SCALE, SHIFT = 1.007, (2.3, -1.7)  # the lead car's ~0.7 % per frame, a sub-pixel shift (px)
CENTRE = np.array([WIDTH / 2, HEIGHT / 2])
#: Previous-frame coordinates → current-frame coordinates (2 × 3, pixels).
AFFINE = np.array([[SCALE, 0, (1 - SCALE) * CENTRE[0] + SHIFT[0]],
                   [0, SCALE, (1 - SCALE) * CENTRE[1] + SHIFT[1]]])  # fmt: skip
OCCLUDED = (slice(60, 140), slice(100, 180))  # rows, cols (px) replaced in the current frame


def texture(affine: np.ndarray) -> np.ndarray:
    """A smooth random texture (400 Gaussian blobs, σ 2.5–6 px) seen through ``affine``:
    pixel x of the result shows the texture at affine⁻¹(x), evaluated exactly, uint8."""
    rng = np.random.default_rng(0)
    cx, cy = rng.uniform(0, WIDTH, 400), rng.uniform(0, HEIGHT, 400)
    sigma, amp = rng.uniform(2.5, 6.0, 400), rng.uniform(-1.0, 1.0, 400)
    inverse = np.linalg.inv(np.vstack([affine, [0, 0, 1]]))
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH].astype(float)
    u = inverse[0, 0] * xx + inverse[0, 1] * yy + inverse[0, 2]
    v = inverse[1, 0] * xx + inverse[1, 1] * yy + inverse[1, 2]
    img = np.zeros((HEIGHT, WIDTH))
    for i in range(400):
        img += amp[i] * np.exp(-((u - cx[i]) ** 2 + (v - cy[i]) ** 2) / (2 * sigma[i] ** 2))
    return np.clip(np.round(128 + 110 * img), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def synthetic() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(previous frame, current frame, Shi–Tomasi keypoints of the previous frame ≥ 15 px
    from the border)."""
    prev = texture(np.eye(3)[:2])
    curr = texture(AFFINE)
    kps = detect_keypoints(prev, ShiTomasiParams())
    inner = (kps[:, 0] > 15) & (kps[:, 0] < WIDTH - 15) & (kps[:, 1] > 15)
    inner &= kps[:, 1] < HEIGHT - 15
    return prev, curr, kps[inner]


def truth(xy: np.ndarray) -> np.ndarray:
    return xy @ AFFINE[:, :2].T + AFFINE[:, 2]


def test_tracked_points_land_within_0_1_px(synthetic) -> None:
    prev, curr, kps = synthetic
    tracks = track_keypoints(prev, curr, kps, KltParams())
    assert len(kps) > 200 and len(tracks) > 0.95 * len(kps)
    error = np.hypot(*(tracks.keypoints_curr[:, :2] - truth(kps[tracks.prev_idx, :2])).T)
    assert error.max() < 0.1
    np.testing.assert_array_equal(tracks.keypoints_curr[:, 2:], kps[tracks.prev_idx, 2:])
    assert np.all(np.diff(tracks.prev_idx) > 0) and tracks.fb_error.max() <= 1.0


def test_forward_backward_check_removes_injected_false_tracks(synthetic) -> None:
    """A patch of unrelated texture replaces part of the current frame: the keypoints under
    it have no true position there. Without the check they are tracked somewhere wrong; the
    check removes every track more than 2 px off and keeps the visible ones."""
    prev, curr, kps = synthetic
    occluded_curr = curr.copy()
    patch = np.random.default_rng(5).integers(0, 255, (80, 80)).astype(np.uint8)
    occluded_curr[OCCLUDED] = cv2.GaussianBlur(patch, (0, 0), 2.0)
    rows, cols = OCCLUDED
    under = (kps[:, 0] >= cols.start - 5) & (kps[:, 0] < cols.stop + 5)
    under &= (kps[:, 1] >= rows.start - 5) & (kps[:, 1] < rows.stop + 5)
    assert under.sum() > 30

    forward, _ = forward_backward_error(prev, occluded_curr, kps[:, :2], KltParams())
    wrong = np.hypot(*(forward - truth(kps[:, :2])).T) > 2.0
    assert wrong.sum() > 25  # the injected false tracks exist without the check

    tracks = track_keypoints(prev, occluded_curr, kps, KltParams())
    kept = np.zeros(len(kps), bool)
    kept[tracks.prev_idx] = True
    assert not np.any(kept & wrong)
    assert np.mean(kept[~under]) > 0.95
    tight = track_keypoints(prev, occluded_curr, kps, KltParams(fb_threshold=0.05))
    assert len(tight) < len(tracks)  # the threshold is the configurable knob


def test_klt_is_a_matcher_without_descriptors(synthetic) -> None:
    prev, curr, kps = synthetic
    assert MATCHER_PARAMS["klt"] is KltParams and not uses_descriptors(KltParams())
    tracks = track_keypoints(prev, curr, kps, KltParams())
    m = tracks_to_matches(tracks)
    np.testing.assert_array_equal(m.prev_idx, tracks.prev_idx)
    np.testing.assert_array_equal(m.curr_idx, np.arange(len(tracks)))
    assert m.prev_idx.dtype == m.curr_idx.dtype == np.int32 and m.distance.dtype == np.float32
    entry = tracks_to_arrays(tracks)  # the matches-stage entry the pipeline caches
    assert is_tracks(entry) and not is_tracks({"idx": np.zeros((0, 2)), "dist": np.zeros((0, 2))})
    from_entry = pair_matches(entry, NO_SELECTOR)
    np.testing.assert_array_equal(from_entry.prev_idx, m.prev_idx)
    np.testing.assert_array_equal(current_keypoints(kps, entry), tracks.keypoints_curr)
    candidates = {"idx": np.array([[3, 1]], np.int32), "dist": np.array([[1.0, 9.0]], np.float32)}
    assert current_keypoints(kps, candidates) is kps
    assert pair_matches(candidates, SelectorParams()).curr_idx.tolist() == [3]
    assert len(track_keypoints(prev, curr, kps[:0], KltParams())) == 0
    assert isinstance(Tracks.empty(), Tracks)
    with pytest.raises(ValueError, match="sizes differ"):
        track_keypoints(prev, curr[:100], kps, KltParams())
    with pytest.raises(ValueError, match="fb_threshold"):
        KltParams(fb_threshold=0.0)


def test_klt_on_kitti_frames_0_1(kitti_dir: Path) -> None:
    """FAST keypoints tracked 0 → 1: most survive, and the tracks move little (~1 m of
    motion at 8 m)."""
    grays = [
        cv2.cvtColor(read_image(kitti_dir / f"image_02/data/{i:010d}.png"), cv2.COLOR_BGR2GRAY)
        for i in (0, 1)
    ]
    kps = detect_keypoints(grays[0], FastParams())
    tracks = track_keypoints(grays[0], grays[1], kps, KltParams())
    assert len(tracks) > 0.5 * len(kps)
    moved = np.hypot(*(tracks.keypoints_curr[:, :2] - kps[tracks.prev_idx, :2]).T)
    assert np.mean(moved < 30.0) > 0.95
    assert np.mean(tracks.keypoints_curr[:, :2] != np.round(tracks.keypoints_curr[:, :2])) > 0.9
