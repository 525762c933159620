"""Sub-pixel keypoint refinement (``detector.subpixel``): a synthetic pair with a known
sub-pixel scale change, where integer keypoints pin the camera ratio at exactly 1, and the
refinement's contract on a real KITTI frame."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from ttc import reasons
from ttc.features.keypoints import (
    DETECTORS,
    SUBPIXEL_HALF_WINDOW,
    FastParams,
    HarrisParams,
    OrbParams,
    detect_keypoints,
    refine_subpixel,
)
from ttc.io.frames import read_image
from ttc.steps.camera_ttc import CameraTTCParams, camera_ttc

SUPERSAMPLE = 16  # render at 16× and area-average: edges land at sub-pixel positions
HEIGHT, WIDTH = 200, 300  # px
CENTRE = np.array([150.0, 100.0])  # px, the centre of expansion
SCALE = 1.004  # image scale change between the frames: 0.4 %, ≤ 0.25 px at the pattern's rim


def _squares() -> list[np.ndarray]:
    """12 rotated bright squares (corner arrays, px) within ±62 px of the centre."""
    rng = np.random.default_rng(3)
    grid = np.array([[x, y] for x in (-50, -17, 17, 50) for y in (-45, 0, 45)], float)
    centres = grid + CENTRE + rng.uniform(-3, 3, grid.shape)
    unit = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)
    out = []
    for i, c in enumerate(centres):
        angle = np.deg2rad(10 + 7 * i)
        rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        out.append(unit * (7 + i % 3) @ rot.T + c)
    return out


def render(scale: float) -> np.ndarray:
    """The pattern expanded by ``scale`` about :data:`CENTRE`, anti-aliased, slightly blurred
    (a camera's optics), uint8."""
    big = np.zeros((HEIGHT * SUPERSAMPLE, WIDTH * SUPERSAMPLE), np.uint8)
    for corners in _squares():
        moved = CENTRE + scale * (corners - CENTRE)
        cv2.fillPoly(big, [np.round(moved * SUPERSAMPLE).astype(np.int32)], 200)
    small = cv2.resize(big, (WIDTH, HEIGHT), interpolation=cv2.INTER_AREA) + 20
    return cv2.GaussianBlur(small, (0, 0), 0.7)


@pytest.fixture(scope="module")
def pair() -> tuple[np.ndarray, np.ndarray]:
    return render(1.0), render(SCALE)


def camera_ratio(pair, params) -> tuple[float, str, int]:
    """(FP.4 median ratio, reason, pairs matched) of the detector's keypoints, matched by the
    known expansion (nearest keypoint within 1 px of the predicted position)."""
    k0, k1 = (detect_keypoints(g, params) for g in pair)
    predicted = CENTRE + SCALE * (k0[:, :2] - CENTRE)
    dist = np.linalg.norm(predicted[:, None, :] - k1[None, :, :2], axis=2)
    nearest = dist.argmin(axis=1)
    ok = dist[np.arange(len(k0)), nearest] < 1.0
    result = camera_ttc(k0[ok, :2], k1[nearest[ok], :2], 0.1, CameraTTCParams())
    return result.ratio, result.reason, int(ok.sum())


def test_integer_fast_keypoints_pin_the_ratio_at_one(pair) -> None:
    ratio, reason, matched = camera_ratio(pair, FastParams())
    assert matched >= 30
    assert ratio == 1.0 and reason == reasons.RATIO_ONE


@pytest.mark.parametrize("params", [FastParams(subpixel=True), OrbParams(subpixel=True)],
                         ids=["fast", "orb"])  # fmt: skip
def test_subpixel_keypoints_recover_the_scale_within_0_1_percent(pair, params) -> None:
    ratio, reason, matched = camera_ratio(pair, params)
    assert matched >= 30 and reason == reasons.OK
    assert abs(ratio / SCALE - 1.0) < 1e-3


def test_subpixel_moves_integer_corners_off_the_grid(pair) -> None:
    plain = detect_keypoints(pair[1], HarrisParams())
    refined = detect_keypoints(pair[1], HarrisParams(subpixel=True))
    assert np.all(plain[:, :2] == np.round(plain[:, :2]))
    assert np.mean(refined[:, :2] != np.round(refined[:, :2])) > 0.9
    np.testing.assert_array_equal(refined[:, 2:], plain[:, 2:])  # only x, y change


def test_refinement_contract_on_a_real_frame(kitti_dir: Path) -> None:
    """Same count and order, every move within the search window, and keypoints without a
    corner nearby (blob centres) keep their position rather than jump."""
    gray = cv2.cvtColor(read_image(kitti_dir / "image_02/data/0000000000.png"), cv2.COLOR_BGR2GRAY)
    plain = detect_keypoints(gray, FastParams())
    refined = refine_subpixel(gray, plain)
    assert refined.shape == plain.shape
    moved = np.hypot(*(refined[:, :2] - plain[:, :2]).T)
    assert moved.max() <= SUBPIXEL_HALF_WINDOW and np.mean(moved > 0) > 0.3
    h, w = gray.shape
    assert refined[:, 0].min() >= 0 and refined[:, 0].max() <= w - 1
    np.testing.assert_array_equal(detect_keypoints(gray, FastParams(subpixel=True)), refined)
    flat = np.full((50, 50), 90, np.uint8)
    assert np.array_equal(refine_subpixel(flat, plain[:3] % 40), plain[:3] % 40)
    assert refine_subpixel(gray, plain[:0]).shape == (0, 7)


def test_every_detector_has_subpixel_off_by_default() -> None:
    for name, cls in DETECTORS.items():
        assert cls().subpixel is False, name
