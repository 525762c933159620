"""camera_ttc=similarity_fit: the scale of a robust similarity between the correspondences."""

from __future__ import annotations

import numpy as np
import pytest

from ttc.steps.camera_ttc import CameraTTCParams, camera_ttc
from ttc.steps.similarity_fit import similarity_scale

SCALE = 1.02


def _pair(outlier_share: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """100 keypoints in a 200 × 150 px box scaled by SCALE about (600, 200), rotated 0.5°,
    shifted (3, -2) px, with 0.05 px noise; ``outlier_share`` of them are background points
    (no scale change, shifted (9, 2) px, 1 px noise), which pull distance ratios towards 1."""
    rng = np.random.default_rng(seed)
    prev = rng.uniform([500, 125], [700, 275], size=(100, 2))
    a = np.deg2rad(0.5)
    rot = SCALE * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    curr = (prev - [600, 200]) @ rot.T + [600, 200] + [3, -2]
    curr += rng.normal(0, 0.05, curr.shape)
    bad = rng.choice(len(prev), int(outlier_share * len(prev)), replace=False)
    curr[bad] = prev[bad] + [9, 2] + rng.normal(0, 1.0, (len(bad), 2))
    return prev, curr


@pytest.mark.parametrize("method", ["ransac", "lmeds"])
def test_similarity_fit_recovers_the_scale_despite_30_percent_outliers(method: str) -> None:
    prev, curr = _pair(0.30)
    scale, inliers = similarity_scale(prev, curr, method, threshold=0.5)
    assert abs(scale / SCALE - 1) < 5e-4
    assert 65 <= inliers <= 75
    fit = camera_ttc(prev, curr, 0.1, CameraTTCParams("similarity_fit", fit_method=method))
    median = camera_ttc(prev, curr, 0.1, CameraTTCParams("median_ratio", min_dist=0.0))
    truth = -0.1 / (1 - SCALE)
    assert abs(fit.ttc / truth - 1) < 0.03
    assert abs(median.ratio - SCALE) > abs(fit.ratio - SCALE)


def test_similarity_fit_degenerate_inputs_give_nan_with_a_reason() -> None:
    xy = np.array([[0.0, 0.0], [10.0, 0.0]])
    out = camera_ttc(xy, xy * 1.01, 0.1, CameraTTCParams("similarity_fit"))
    assert np.isnan(out.ttc) and out.n_pairs == 0 and out.reason


def test_similarity_fit_parameters_are_checked() -> None:
    with pytest.raises(ValueError, match="fit_method"):
        CameraTTCParams("similarity_fit", fit_method="lsq")
    with pytest.raises(ValueError, match="fit_threshold"):
        CameraTTCParams("similarity_fit", fit_threshold=0.0)
