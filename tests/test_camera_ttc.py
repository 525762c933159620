"""FP.4 camera TTC: keypoints scaled about a centre give the exact TTC; degenerate cases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import pdist

from ttc import reasons
from ttc.steps.camera_ttc import (
    CAMERA_ESTIMATORS,
    CameraTTCParams,
    camera_ttc,
    distance_ratios,
    pair_ratios,
    ratio_source,
    ttc_from_ratio,
)

ESTIMATORS = sorted(CAMERA_ESTIMATORS)
DT = 0.1  # s
CENTRE = np.array([620.0, 190.0])  # px


def keypoints(n: int = 120, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return CENTRE + rng.uniform([-160, -80], [160, 80], size=(n, 2))


def scaled(prev: np.ndarray, s: float, shift=(0.0, 0.0)) -> np.ndarray:
    return CENTRE + s * (prev - CENTRE) + np.asarray(shift)


@pytest.mark.parametrize("name", ESTIMATORS)
@pytest.mark.parametrize(("s", "shift"), [(1.05, (0, 0)), (1.02, (7.5, -3.0)), (1.002, (1, 1))])
def test_scaled_keypoints_give_exact_ttc(name: str, s: float, shift) -> None:
    prev = keypoints()
    res = camera_ttc(prev, scaled(prev, s, shift), DT, CameraTTCParams(name=name))
    assert res.reason == reasons.OK
    assert res.ratio == pytest.approx(s, rel=1e-12)
    assert res.ttc == pytest.approx(DT / (s - 1.0), rel=1e-6)


def test_only_pairs_at_least_min_dist_apart() -> None:
    prev = keypoints()
    curr = scaled(prev, 1.05)
    d_curr = np.linalg.norm(curr[:, None, :] - curr[None, :, :], axis=-1)
    upper = np.triu(np.ones_like(d_curr, dtype=bool), k=1)
    for min_dist in (0.0, 100.0, 250.0):
        res = camera_ttc(prev, curr, DT, CameraTTCParams(min_dist=min_dist))
        assert res.n_pairs == np.count_nonzero(upper & (d_curr >= min_dist))
    assert camera_ttc(prev, curr, DT, CameraTTCParams(min_dist=0.0)).n_pairs == 120 * 119 // 2


def test_median_resists_mismatches_mean_does_not() -> None:
    prev = keypoints()
    curr = scaled(prev, 1.05)
    curr[:8] = curr[:8][::-1] + 40.0  # eight mismatched keypoints
    med = camera_ttc(prev, curr, DT, CameraTTCParams(name="median_ratio"))
    mean = camera_ttc(prev, curr, DT, CameraTTCParams(name="mean_ratio"))
    assert med.ttc == pytest.approx(2.0, rel=0.02)
    assert abs(mean.ttc - 2.0) > 0.1


def test_distance_ratios_skip_coincident_previous_points() -> None:
    prev = np.array([[0.0, 0.0], [0.0, 0.0], [300.0, 0.0]])
    curr = np.array([[0.0, 0.0], [150.0, 0.0], [330.0, 0.0]])
    # pairs (0,1): d_prev 0 -> skipped; (0,2): 330/300; (1,2): 180 < 200 -> skipped
    np.testing.assert_allclose(distance_ratios(prev, curr, 200.0), [1.1])


# -- degenerate cases ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", ESTIMATORS)
def test_no_matches(name: str) -> None:
    res = camera_ttc(np.zeros((0, 2)), np.zeros((0, 2)), DT, CameraTTCParams(name=name))
    assert np.isnan(res.ttc) and np.isnan(res.ratio)
    assert (res.n_pairs, res.reason) == (0, reasons.NO_MATCHES_IN_BOX)


@pytest.mark.parametrize("name", ESTIMATORS)
@pytest.mark.parametrize(
    ("prev", "curr"),
    [
        ([[10.0, 10.0]], [[12.0, 10.0]]),  # one match: no pair
        ([[0.0, 0.0], [50.0, 0.0]], [[0.0, 0.0], [60.0, 0.0]]),  # closer than 100 px
        ([[5.0, 5.0], [5.0, 5.0]], [[0.0, 0.0], [150.0, 0.0]]),  # coincident previously
    ],
)
def test_too_few_pairs(name: str, prev, curr) -> None:
    res = camera_ttc(np.array(prev), np.array(curr), DT, CameraTTCParams(name=name))
    assert np.isnan(res.ttc) and np.isnan(res.ratio)
    assert (res.n_pairs, res.reason) == (0, reasons.TOO_FEW_PAIRS)


@pytest.mark.parametrize("name", ESTIMATORS)
def test_ratio_one_is_inf(name: str) -> None:
    prev = keypoints()
    res = camera_ttc(prev, prev.copy(), DT, CameraTTCParams(name=name))
    assert res.ttc == np.inf and res.ratio == 1.0 and res.reason == reasons.RATIO_ONE
    assert res.n_pairs > 0


@pytest.mark.parametrize("name", ESTIMATORS)
def test_shrinking_image_is_receding(name: str) -> None:
    prev = keypoints()
    res = camera_ttc(prev, scaled(prev, 0.95), DT, CameraTTCParams(name=name))
    assert res.ttc == np.inf and res.reason == reasons.RECEDING
    assert res.ratio == pytest.approx(0.95, rel=1e-12)
    assert ttc_from_ratio(res.ratio, DT) == pytest.approx(-2.0, rel=1e-9)


def test_caller_errors_raise() -> None:
    prev = keypoints()
    for dt in (0.0, -0.1, np.nan):
        with pytest.raises(ValueError, match="dt"):
            camera_ttc(prev, prev, dt, CameraTTCParams())
    with pytest.raises(ValueError, match="differ"):
        camera_ttc(prev, prev[:-1], DT, CameraTTCParams())


@pytest.mark.parametrize("kwargs", [{"name": "trimmed_mean"}, {"min_dist": -1.0}])
def test_params_validation(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        CameraTTCParams(**kwargs)


def test_the_pair_distance_can_follow_the_box_width() -> None:
    """``min_box_fraction``: the least pair distance is that fraction of the box width when it
    exceeds ``min_dist`` (a 40 px box 21 m ahead and a 200 px box 8 m ahead alike)."""
    rng = np.random.default_rng(3)
    prev = rng.uniform(0, 40, size=(60, 2))
    curr = scaled(prev, 1.01)
    d = pdist(curr)
    params = CameraTTCParams(min_dist=0.0, min_box_fraction=0.25)
    assert params.threshold(40.0) == 10.0 and params.threshold(0.0) == 0.0
    assert camera_ttc(prev, curr, DT, params, box_width=40.0).n_pairs == int((d >= 10.0).sum())
    larger = CameraTTCParams(min_dist=12.0, min_box_fraction=0.25)  # the larger one applies
    assert camera_ttc(prev, curr, DT, larger, box_width=40.0).n_pairs == int((d >= 12.0).sum())
    assert camera_ttc(prev, curr, DT, params).n_pairs == len(d)  # no box: absolute only
    with pytest.raises(ValueError, match="min_box_fraction"):
        CameraTTCParams(min_box_fraction=1.5)


def test_statistics_of_one_ratio_source_share_the_ratios() -> None:
    """``median_ratio`` and ``mean_ratio`` at one least distance reduce the same pair ratios
    (what the engine computes once for both): given, they give the same result as made
    inside; ``vertical_ratio``, another distance or box width is another source; the
    similarity fit uses none."""
    prev = keypoints(60, seed=3)
    curr = scaled(prev, 1.03, (2.0, -1.0)).astype(np.float32)  # as the engine's keypoints
    median, mean = (
        CameraTTCParams("median_ratio", 40.0, 0.5),
        CameraTTCParams("mean_ratio", 40.0, 0.5),
    )
    assert ratio_source(median, 120.0) == ratio_source(mean, 120.0) == ("distance_ratios", 60.0)
    ratios = pair_ratios(prev, curr, median, 120.0)
    for params in (median, mean):
        given = camera_ttc(prev, curr, DT, params, box_width=120.0, ratios=ratios)
        assert given == camera_ttc(prev, curr, DT, params, box_width=120.0)
    assert ratio_source(median, 40.0) != ratio_source(median, 120.0)
    assert ratio_source(CameraTTCParams("vertical_ratio", 40.0, 0.5), 120.0)[0] == "vertical_ratios"
    assert ratio_source(CameraTTCParams("similarity_fit"), 120.0) is None
