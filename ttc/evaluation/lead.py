"""The lead vehicle of a frame pair: which box it is and its row, points and FP.1 partner in
the intermediate arrays of :func:`ttc.engine.runner.pair_detail`.

One rule throughout: the lead is the current box holding most ego-lane lidar points
(:func:`lead_box_of`); its row is the one flagged ``is_lead``, else the pair's first row with
NaN TTCs (:func:`ttc.evaluation.lead_rows`). The drawing code and the reports ask these
functions instead of deciding again.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ttc.evaluation.errors import lead_rows
from ttc.rows import PairDetail
from ttc.steps.lidar import lead_box_of  # noqa: F401  (the rule, re-exported)


def lead_row(detail: PairDetail) -> pd.Series:
    """The lead row of a pair detail's rows (:func:`ttc.evaluation.lead_rows`: the ``is_lead``
    row, else the first row with NaN TTCs)."""
    rows = detail.rows
    return lead_rows(rows.assign(run_id="")).iloc[0]


def lead_boxes(detail: PairDetail) -> tuple[int, int]:
    """(previous box, current box) of the lead row: the lead box and its FP.1 partner in the
    previous frame (−1 where there is none)."""
    row = lead_row(detail)
    return int(row["prev_box"]), int(row["curr_box"])


def box_points(detail: PairDetail, frame: int, box: int) -> np.ndarray:
    """Lane lidar points (N × 4: x, y, z metres, reflectance) of ``box`` in ``frame`` of a pair
    detail; none for ``box`` −1."""
    if box < 0:
        return detail.lane_points[frame][:0]
    return detail.lane_points[frame][detail.lane_owner[frame] == box]


def lead_clouds(detail: PairDetail) -> dict[int, np.ndarray]:
    """The lead vehicle's points per frame of a pair detail: ``{prev: points of the lead box's
    FP.1 partner, curr: points of the lead box}`` (N × 4 each, metres; none without a box)."""
    prev_box, curr_box = lead_boxes(detail)
    return {
        detail.prev: box_points(detail, detail.prev, prev_box),
        detail.curr: box_points(detail, detail.curr, curr_box),
    }
