"""KITTI's difficulty levels of every box (issue 50, item 2): synthetic boxes (exact checks of
height, border and a nearer overlapping box), and drive 0009's boxes."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ttc.evaluation.difficulty import (
    box_difficulty,
    in_level,
    occluded_share,
    union_cover,
    worse_level,
)

SIZE = (1242, 375)  # KITTI's image, px


def _boxes(rows: list[tuple[float, float, float, float, float]]) -> pd.DataFrame:
    """Boxes of one frame: x, y, w, h (px) and lidar distance (m)."""
    t = pd.DataFrame(rows, columns=["box_x", "box_y", "box_w", "box_h", "distance_m"])
    return t.assign(frame=0)


def test_height_decides_between_easy_moderate_and_no_level() -> None:
    boxes = _boxes([(100, 100, 60, 40, 10.0), (300, 100, 60, 39.9, 12.0),
                    (500, 100, 60, 25, 14.0), (700, 100, 60, 24.9, 16.0)])  # fmt: skip
    assert box_difficulty(boxes, SIZE)["difficulty"].tolist() == [
        "easy",
        "moderate",
        "moderate",
        "none",
    ]


def test_a_box_at_the_image_border_is_truncated_and_hard_at_best() -> None:
    boxes = _boxes([(2, 100, 80, 60, 10.0), (1242 - 82, 100, 80, 60, 10.0),
                    (400, 375 - 62, 80, 60, 10.0), (400, 5, 80, 60, 10.0)])  # fmt: skip
    out = box_difficulty(boxes, SIZE)
    assert out["truncated"].tolist() == [True, True, True, False]
    assert out["difficulty"].tolist() == ["hard", "hard", "hard", "easy"]
    # without the image height only the left and right borders cut
    assert box_difficulty(boxes, (1242, None))["difficulty"].tolist() == [
        "hard",
        "hard",
        "easy",
        "easy",
    ]


def test_a_nearer_overlapping_box_occludes_the_farther_one_only() -> None:
    """A far car (100 × 50 px, 20 m) with a near car (8 m) in front of 30 % of it: partly
    occluded (moderate); with 60 % covered: largely occluded (hard); the near box is not
    occluded by the far one; a box without a distance is behind every measured one."""
    far, near = (100, 100, 100, 50, 20.0), (170, 80, 60, 100, 8.0)
    out = box_difficulty(_boxes([far, near]), SIZE)
    assert out["occluded_share"].tolist() == pytest.approx([0.3, 0.0])
    assert out["difficulty"].tolist() == ["moderate", "easy"]
    out = box_difficulty(_boxes([far, (140, 80, 60, 100, 8.0)]), SIZE)
    assert out["occluded_share"].tolist() == pytest.approx([0.6, 0.0])
    assert out["difficulty"].tolist() == ["hard", "easy"]
    unknown = box_difficulty(_boxes([(*far[:4], np.nan), near]), SIZE)
    assert unknown["occluded_share"].tolist() == pytest.approx([0.3, 0.0])
    reversed_ = box_difficulty(_boxes([(*far[:4], 5.0), near]), SIZE)  # the big box is nearer
    assert reversed_["occluded_share"].iloc[0] == 0.0 and reversed_["occluded_share"].iloc[1] > 0


def test_overlapping_occluders_count_their_union_once() -> None:
    box = np.array([0.0, 0.0, 100.0, 10.0])
    assert union_cover(box, np.array([[0, 0, 40, 10], [30, 0, 40, 10]])) == pytest.approx(0.7)
    rng = np.random.default_rng(1)
    for _ in range(50):  # against a pixel raster
        others = np.c_[rng.integers(-20, 90, (4, 2)), rng.integers(1, 60, (4, 2))]
        grid = np.zeros((10, 100), bool)
        for x, y, w, h in others:
            grid[max(y, 0) : max(y + h, 0), max(x, 0) : max(x + w, 0)] = True
        assert union_cover(box, others) == pytest.approx(grid.mean())


def test_shares_are_per_frame_and_equal_distances_do_not_occlude() -> None:
    assert occluded_share(
        np.array([[0, 0, 10, 10], [5, 0, 10, 10]]), np.array([5.0, 5.0])
    ).tolist() == [0, 0]
    two = pd.concat(
        [_boxes([(0, 0, 50, 50, 9.0)]), _boxes([(10, 10, 50, 50, 4.0)]).assign(frame=1)]
    )
    assert box_difficulty(two.reset_index(drop=True), SIZE)["occluded_share"].tolist() == [0, 0]


def test_a_pair_takes_the_worse_level_and_levels_are_cumulative() -> None:
    a = np.array(["easy", "easy", "moderate", "hard", "none"])
    b = np.array(["easy", "hard", "easy", "none", "easy"])
    pair = worse_level(a, b)
    assert pair.tolist() == ["easy", "hard", "moderate", "none", "none"]
    assert in_level(pair, "easy").tolist() == [True, False, False, False, False]
    assert in_level(pair, "moderate").tolist() == [True, False, True, False, False]
    assert in_level(pair, "hard").tolist() == [True, True, True, False, False]
    assert in_level(pair, "all").all()
    with pytest.raises(ValueError, match="difficulty level 'medium'"):
        in_level(pair, "medium")
