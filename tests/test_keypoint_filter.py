"""FP.3 keypoint filters: planted outliers in a synthetic displacement field, box membership."""

from __future__ import annotations

import numpy as np
import pytest

from ttc.steps.keypoint_filter import (
    KEYPOINT_FILTERS,
    KeypointFilterParams,
    filter_box_matches,
    matches_in_box,
)

FILTERS = sorted(KEYPOINT_FILTERS)
REJECTING = [n for n in FILTERS if n != "none"]
LENGTH_ONLY = ["median_distance", "zscore", "iqr"]
CENTRE = np.array([600.0, 200.0])  # px
SCALE = 1.01
SHIFT = np.array([8.0, 2.0])  # px


def keep(name: str, prev: np.ndarray, curr: np.ndarray, **kw) -> np.ndarray:
    mask = KEYPOINT_FILTERS[name](prev, curr, KeypointFilterParams(name=name, **kw))
    assert mask.dtype == bool and mask.shape == (len(prev),)
    return mask


def field(n: int = 200, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints of a box expanding by 1 % about its centre and shifting by (8, 2) px."""
    rng = np.random.default_rng(seed)
    prev = CENTRE + rng.uniform([-100, -60], [100, 60], size=(n, 2))
    return prev, CENTRE + SCALE * (prev - CENTRE) + SHIFT


def with_outliers(displacements) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The field plus one match per given displacement (px); returns prev, curr, outlier mask."""
    prev, curr = field()
    d = np.asarray(displacements, dtype=float)
    extra = CENTRE + np.linspace(-50, 50, len(d))[:, None] * [1.0, 0.5]
    prev = np.vstack([prev, extra])
    curr = np.vstack([curr, extra + d])
    return prev, curr, np.r_[np.zeros(len(prev) - len(d), bool), np.ones(len(d), bool)]


@pytest.mark.parametrize("name", REJECTING)
def test_long_jumps_removed_inliers_kept(name: str) -> None:
    prev, curr, outlier = with_outliers([[40, 0], [-35, 10], [0, 45], [30, 30], [50, -5]])
    mask = keep(name, prev, curr)
    np.testing.assert_array_equal(mask, ~outlier)


def test_none_keeps_everything() -> None:
    prev, curr, _ = with_outliers([[40, 0], [2, 8]])
    assert keep("none", prev, curr).all()


def test_wrong_direction_caught_only_by_displacement_mad() -> None:
    """(2, 8) px has the inliers' length |(8, 2)| but points the wrong way."""
    prev, curr, outlier = with_outliers([[2, 8], [-8, -2]])
    for name in LENGTH_ONLY:
        assert keep(name, prev, curr)[outlier].all(), name
    np.testing.assert_array_equal(keep("displacement_mad", prev, curr), ~outlier)


def test_heavy_contamination_median_based_filters_hold() -> None:
    """80 of 280 matches jump 30 px the same way: the median-based filters still find them;
    the mean / standard deviation of zscore and the quartiles of iqr are captured by them."""
    prev, curr, outlier = with_outliers(np.tile([30.0, 0.0], (80, 1)))
    for name in ("median_distance", "displacement_mad"):
        np.testing.assert_array_equal(keep(name, prev, curr), ~outlier, err_msg=name)
    for name in ("zscore", "iqr"):
        assert keep(name, prev, curr)[outlier].all(), name


def test_thresholds_matter() -> None:
    prev, curr, outlier = with_outliers([[14, 3]])  # 1.74 × the median length
    assert not keep("median_distance", prev, curr)[outlier].any()
    assert keep("median_distance", prev, curr, factor=2.0)[outlier].all()
    assert not keep("displacement_mad", prev, curr)[outlier].any()
    assert keep("displacement_mad", prev, curr, mad_threshold=20.0)[outlier].all()


def test_zscore_k() -> None:
    d = np.r_[np.zeros(8), 1.0, 10.0]  # lengths along x
    prev = np.zeros((10, 2))
    curr = np.column_stack([d, np.zeros(10)])
    # mean 1.1, std 2.97: 10 is 3.0 std away
    assert keep("zscore", prev, curr, z=2.0).tolist() == [True] * 9 + [False]
    assert keep("zscore", prev, curr, z=3.5).all()


def test_iqr_fences_both_sides() -> None:
    d = np.r_[np.full(5, 10.0), np.full(5, 12.0), 0.5, 30.0]  # Q1 10, Q3 12: fences [7, 15]
    prev = np.zeros((len(d), 2))
    curr = np.column_stack([np.zeros_like(d), d])
    assert keep("iqr", prev, curr).tolist() == [True] * 10 + [False, False]
    assert keep("iqr", prev, curr, iqr_k=10.0).all()


def test_displacement_mad_floor_for_integer_keypoints() -> None:
    """Integer keypoints: MAD 0 per axis; a 1 px difference stays an inlier thanks to the floor."""
    prev = np.zeros((20, 2))
    curr = np.tile([8.0, 2.0], (20, 1))
    curr[:3, 0] = 9.0
    assert keep("displacement_mad", prev, curr).all()
    assert keep("displacement_mad", prev, curr, mad_floor=0.0).tolist() == [False] * 3 + [True] * 17


@pytest.mark.parametrize("name", FILTERS)
def test_degenerate_inputs_never_raise(name: str) -> None:
    empty = np.zeros((0, 2))
    assert keep(name, empty, empty).shape == (0,)
    one = np.array([[1.0, 2.0]])
    assert keep(name, one, one + 3).all()
    prev = np.arange(20.0).reshape(10, 2)
    assert keep(name, prev, prev + [0.1, 0.7]).all()  # identical displacements
    assert keep(name, prev, prev).all()  # static


# -- box membership and the whole FP.3 step -----------------------------------------------------


def test_matches_in_box_uses_the_shrunk_current_box() -> None:
    curr_xy = np.array([[50.0, 50.0], [2.0, 50.0], [96.0, 50.0], [94.0, 94.0], [500.0, 5.0]])
    curr_idx = np.array([4, 3, 2, 1, 0, 0], dtype=np.int32)
    roi = np.array([0, 0, 100, 100])  # shrunk by 0.1: [5, 95) × [5, 95)
    np.testing.assert_array_equal(
        matches_in_box(curr_xy, curr_idx, roi, 0.1), [False, True, False, False, True, True]
    )
    np.testing.assert_array_equal(
        matches_in_box(curr_xy, curr_idx, roi, 0.0), [False, True, True, True, True, True]
    )


def test_filter_box_matches_indices_and_counts() -> None:
    prev_in, curr_in, outlier = with_outliers([[40, 0], [0, -45]])
    n_in = len(prev_in)
    # Two matches outside the box, placed first; keypoint arrays in shuffled order.
    prev_xy = np.vstack([[[10.0, 10.0], [20.0, 20.0]], prev_in])
    curr_xy = np.vstack([[[12.0, 10.0], [22.0, 20.0]], curr_in])
    rng = np.random.default_rng(1)
    perm_p, perm_c = rng.permutation(len(prev_xy)), rng.permutation(len(curr_xy))
    prev_idx = np.argsort(perm_p).astype(np.int32)  # match k -> row of shuffled prev array
    curr_idx = np.argsort(perm_c).astype(np.int32)
    roi = np.array([450, 100, 300, 200])
    res = filter_box_matches(
        prev_xy[perm_p], curr_xy[perm_c], prev_idx, curr_idx, roi, 0.1,
        KeypointFilterParams(name="displacement_mad"),
    )  # fmt: skip
    assert res.n_in_box == n_in
    assert (res.n_kept, res.n_removed) == (n_in - 2, 2)
    np.testing.assert_array_equal(res.removed, 2 + np.flatnonzero(outlier))
    np.testing.assert_array_equal(res.kept, 2 + np.flatnonzero(~outlier))
    none = filter_box_matches(
        prev_xy[perm_p],
        curr_xy[perm_c],
        prev_idx,
        curr_idx,
        roi,
        0.1,
        KeypointFilterParams(name="none"),
    )
    assert (none.n_in_box, none.n_kept, none.n_removed) == (n_in, n_in, 0)


def test_filter_box_matches_empty_box() -> None:
    xy = np.array([[10.0, 10.0]])
    idx = np.array([0], dtype=np.int32)
    res = filter_box_matches(
        xy, xy, idx, idx, np.array([500, 500, 10, 10]), 0.1, KeypointFilterParams()
    )
    assert (res.n_in_box, res.n_kept, res.n_removed) == (0, 0, 0)
    assert res.kept.dtype == np.int64 and len(res.kept) == 0
    none = np.zeros(0, dtype=np.int32)
    res = filter_box_matches(
        xy, xy, none, none, np.array([0, 0, 50, 50]), 0.1, KeypointFilterParams()
    )
    assert res.n_in_box == 0


@pytest.mark.parametrize(
    "kwargs",
    [
        {"name": "ransac"},
        {"factor": 0.0},
        {"z": -1.0},
        {"iqr_k": -0.5},
        {"mad_threshold": 0.0},
        {"mad_floor": -1.0},
    ],
)
def test_params_validation(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        KeypointFilterParams(**kwargs)
