"""FP.1 box matching: hand-counted shared matches and constructed count matrices."""

from __future__ import annotations

import numpy as np
import pytest

from ttc.steps.box_matching import (
    BOX_MATCHING_STRATEGIES,
    BoxCounts,
    BoxMatchingParams,
    count_shared_matches,
    match_boxes,
    points_in_rois,
    shrink_rois,
)

STRATEGIES = sorted(BOX_MATCHING_STRATEGIES)


def _counts(matrix, curr_totals=None) -> BoxCounts:
    matrix = np.asarray(matrix, dtype=np.int64)
    totals = matrix.sum(axis=0) if curr_totals is None else np.asarray(curr_totals)
    return BoxCounts(matrix, matrix.sum(axis=1), totals)


def _pairs(counts: BoxCounts, name: str, **kw) -> list[tuple[int, int]]:
    m = match_boxes(counts, BoxMatchingParams(name=name, **kw))
    assert np.all(np.diff(m.curr_box) > 0), "sorted by current box, one pair per box"
    assert len(set(m.prev_box.tolist())) == len(m), "one pair per previous box"
    np.testing.assert_array_equal(m.shared, counts.counts[m.prev_box, m.curr_box])
    return list(zip(m.prev_box.tolist(), m.curr_box.tolist(), strict=True))


# -- geometry helpers ---------------------------------------------------------------------------


def test_shrink_rois_formula() -> None:
    out = shrink_rois(np.array([[10, 20, 100, 50]]), 0.1)
    np.testing.assert_allclose(out, [[15.0, 22.5, 90.0, 45.0]])
    assert out.dtype == np.float64
    np.testing.assert_array_equal(shrink_rois(np.array([[1, 2, 3, 4]]), 0.0), [[1, 2, 3, 4]])
    assert shrink_rois(np.zeros((0, 4), dtype=int), 0.1).shape == (0, 4)
    with pytest.raises(ValueError, match="shrink"):
        shrink_rois(np.array([[0, 0, 1, 1]]), 1.0)


def test_points_in_rois_is_half_open() -> None:
    rois = np.array([[0, 0, 10, 10], [5, 5, 10, 10]])
    uv = np.array([[0, 0], [9.999, 9.999], [10, 5], [5, 10], [7, 7], [np.nan, 1], [-0.1, 3]])
    expected = [
        [True, False],
        [True, True],
        [False, True],
        [False, True],
        [True, True],
        [False, False],
        [False, False],
    ]
    np.testing.assert_array_equal(points_in_rois(uv, rois), expected)
    assert points_in_rois(np.zeros((0, 2)), rois).shape == (0, 2)
    assert points_in_rois(uv, np.zeros((0, 4))).shape == (7, 0)


def test_count_shared_matches_by_hand() -> None:
    """Two boxes per frame (100 × 100 px, shrunk by 0.1 to [5, 95) × [5, 95) + offset)."""
    prev_rois = np.array([[0, 0, 100, 100], [200, 0, 100, 100]])
    curr_rois = np.array([[10, 0, 100, 100], [210, 0, 100, 100]])
    prev_xy = np.array(
        [
            [50, 50],  # 0: prev box 0
            [60, 40],  # 1: prev box 0
            [250, 50],  # 2: prev box 1
            [3, 50],  # 3: border band of prev box 0 -> in no shrunk box
            [94.9, 50],  # 4: last column inside shrunk prev box 0
            [150, 50],  # 5: between the boxes
        ]
    )
    curr_xy = np.array(
        [
            [60, 50],  # 0: curr box 0
            [260, 40],  # 1: curr box 1
            [260, 50],  # 2: curr box 1
            [20, 50],  # 3: curr box 0
            [105, 50],  # 4: right edge of shrunk curr box 0 (exclusive) -> no box
            [100, 50],  # 5: curr box 0
        ]
    )
    # match k: prev keypoint prev_idx[k] -> curr keypoint curr_idx[k]
    prev_idx = np.array([0, 1, 2, 3, 4, 5, 4], dtype=np.int32)
    curr_idx = np.array([0, 1, 2, 3, 4, 5, 5], dtype=np.int32)
    c = count_shared_matches(prev_xy, curr_xy, prev_idx, curr_idx, prev_rois, curr_rois, 0.1)
    # 0: (p0, c0); 1: (p0, c1); 2: (p1, c1); 3: (-, c0); 4: (p0, -); 5: (-, c0); 6: (p0, c0)
    np.testing.assert_array_equal(c.counts, [[2, 1], [0, 1]])
    np.testing.assert_array_equal(c.prev_totals, [4, 1])
    np.testing.assert_array_equal(c.curr_totals, [4, 2])
    assert c.counts.dtype == np.int64
    # Without shrinking, the border points count: matches 3 and 4 join (p0, c0).
    c0 = count_shared_matches(prev_xy, curr_xy, prev_idx, curr_idx, prev_rois, curr_rois, 0.0)
    np.testing.assert_array_equal(c0.counts, [[4, 1], [0, 1]])


def test_count_shared_matches_empty_inputs() -> None:
    xy = np.zeros((3, 2))
    none = np.zeros(0, dtype=np.int32)
    rois = np.array([[0, 0, 10, 10]])
    c = count_shared_matches(xy, xy, none, none, rois, np.zeros((0, 4), dtype=int))
    assert c.counts.shape == (1, 0) and c.curr_totals.shape == (0,)
    c = count_shared_matches(xy, xy, none, none, rois, rois)
    np.testing.assert_array_equal(c.counts, [[0]])


# -- strategies ---------------------------------------------------------------------------------


def test_clear_case_all_agree() -> None:
    counts = _counts([[50, 2, 0], [1, 30, 0], [0, 0, 0]])
    for name in STRATEGIES:
        assert _pairs(counts, name) == [(0, 0), (1, 1)], name


def test_mirror_fragment_strategies_disagree() -> None:
    """Seed 001's case: a whole vehicle ends up matched to just its mirror.

    Previous frame: the lead car detected twice (P0 "car" and a larger P1 "truck" box that
    survived per-class NMS). Current frame: the car C0 and a fragment box C1 on its mirror.
    The mirror's 10 keypoints lie in both previous boxes.
    """
    counts = _counts([[45, 10], [50, 10]], curr_totals=[50, 10])
    # Greedy takes (P1, C0) = 50, then the fragment grabs the remaining car box P0.
    assert _pairs(counts, "greedy_matrix") == [(1, 0), (0, 1)]
    # Maximum total (50 + 10 > 45 + 10) gives the same answer.
    assert _pairs(counts, "hungarian") == [(1, 0), (0, 1)]
    # Seed 000: C1 has all its matches in P0 (confidence 1.0 > 0.5), P0 is free: taken.
    assert _pairs(counts, "overlap_confidence") == [(1, 0), (0, 1)]
    # Two-way maximum: P0's best is C0, not C1, so the mirror stays unmatched.
    assert _pairs(counts, "mutual_best") == [(1, 0)]


def test_greedy_pairs_leftovers_mutual_does_not() -> None:
    """After the car pair, greedy pairs a stray truck match with the mirror box."""
    counts = _counts([[40, 8], [0, 2]])
    assert _pairs(counts, "greedy_matrix") == [(0, 0), (1, 1)]
    assert _pairs(counts, "hungarian") == [(0, 0), (1, 1)]
    assert _pairs(counts, "mutual_best") == [(0, 0)]
    # Seed 000: C1's only eligible box P1 has confidence 2 / 10 <= 0.5.
    assert _pairs(counts, "overlap_confidence") == [(0, 0)]
    # A count floor removes the stray pair from greedy and hungarian.
    assert _pairs(counts, "greedy_matrix", min_count=3) == [(0, 0)]
    assert _pairs(counts, "hungarian", min_count=3) == [(0, 0)]


def test_hungarian_maximises_the_total_greedy_does_not() -> None:
    counts = _counts([[10, 8], [9, 0]])
    assert _pairs(counts, "greedy_matrix") == [(0, 0)]
    assert _pairs(counts, "mutual_best") == [(0, 0)]
    assert _pairs(counts, "hungarian") == [(1, 0), (0, 1)]  # 9 + 8 > 10


def test_overlap_confidence_replaces_a_weaker_pair_and_rematches() -> None:
    """Seed 000's re-pairing.

    C0 is visited first and takes P0 (7 of its 8 matches: confidence 0.875). C1 then finds P0
    held by a weaker pair: its own confidence is 10 / 10 = 1.0, so P0 changes hands and C0 is
    matched again: P0 is no longer eligible (0.875 < 1.0), P1 (5 of 8: 0.625 > 0.5) is.
    P0 and P1 overlap, so C0's overlap keypoints count for both.
    """
    counts = _counts([[7, 10], [5, 0]], curr_totals=[8, 10])
    m = match_boxes(counts, BoxMatchingParams(name="overlap_confidence"))
    np.testing.assert_array_equal(m.prev_box, [1, 0])
    np.testing.assert_array_equal(m.curr_box, [0, 1])
    np.testing.assert_array_equal(m.shared, [5, 10])
    # With a higher threshold the displaced C0 stays unmatched (0.625 <= 0.7).
    assert _pairs(counts, "overlap_confidence", min_confidence=0.7) == [(0, 1)]
    # mutual_best does not re-pair: P0 is C0's best, and C0 is not P0's best.
    assert _pairs(counts, "mutual_best") == [(0, 1)]


def test_overlap_confidence_chain_of_displacements() -> None:
    """An equal confidence does not displace; a higher one starts a chain of re-matches."""
    counts = _counts(
        [
            [6, 9, 0],
            [0, 10, 10],
            [4, 0, 0],
        ],
        curr_totals=[10, 10, 10],
    )
    # C0: P0 (0.6). C1: P1 (10, 1.0). C2: P1 held at 1.0, own 1.0 not greater -> nothing.
    assert _pairs(counts, "overlap_confidence") == [(0, 0), (1, 1)]
    counts = _counts(
        [
            [6, 9, 0],
            [0, 10, 10],
            [6, 0, 0],
        ],
        curr_totals=[10, 11, 10],
    )
    # C0 -> P0 (6, first of the tie, 0.6). C1 -> P1 (10/11). C2 -> P1 (1.0 > 0.909),
    # displaced C1 -> P0 (9/11 = 0.818 > 0.6), displaced C0 -> P2 (0.6).
    assert _pairs(counts, "overlap_confidence") == [(2, 0), (0, 1), (1, 2)]


def test_overlap_confidence_keeps_the_stronger_pair() -> None:
    counts = _counts([[9, 6]], curr_totals=[10, 10])
    assert _pairs(counts, "overlap_confidence") == [(0, 0)]


@pytest.mark.parametrize("name", STRATEGIES)
@pytest.mark.parametrize("shape", [(0, 0), (0, 3), (3, 0), (2, 2)])
def test_empty_and_zero_counts_give_no_pairs(name: str, shape: tuple[int, int]) -> None:
    counts = _counts(np.zeros(shape, dtype=np.int64))
    m = match_boxes(counts, BoxMatchingParams(name=name))
    assert len(m) == 0
    assert m.prev_box.dtype == m.curr_box.dtype == m.shared.dtype == np.int64


@pytest.mark.parametrize("name", STRATEGIES)
def test_more_boxes_on_one_side(name: str) -> None:
    counts = _counts([[0, 12, 0, 1], [20, 0, 0, 0]])
    assert _pairs(counts, name) == [(1, 0), (0, 1)]


@pytest.mark.parametrize(
    "kwargs",
    [
        {"name": "nearest"},
        {"min_confidence": 1.0},
        {"min_confidence": -0.1},
        {"min_count": 0},
        {"shrink": 1.0},
        {"shrink": -0.1},
    ],
)
def test_params_validation(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        BoxMatchingParams(**kwargs)


def test_default_params() -> None:
    p = BoxMatchingParams()
    assert (p.name, p.min_confidence, p.min_count, p.shrink) == ("mutual_best", 0.5, 1, 0.1)
