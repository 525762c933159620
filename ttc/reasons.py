"""Reason codes: why a TTC value is what it is.

Every TTC result carries one of these short strings. Degenerate inputs never raise: the value
is NaN (no estimate possible) or +inf (no collision course) and the code says which case it was.
The codes are stable: they are written to the results store and grouped on in the reports.
"""

from __future__ import annotations

OK = "ok"

# Association (pipeline level)
FRAME_ERROR = "frame_error"
NO_LEAD_BOX = "no_lead_box"
NO_BOX_MATCH = "no_box_match"

# FP.2 lidar TTC
NO_LIDAR_POINTS_PREV = "no_lidar_points_prev"
NO_LIDAR_POINTS_CURR = "no_lidar_points_curr"
NO_CLUSTER_PREV = "no_cluster_prev"
NO_CLUSTER_CURR = "no_cluster_curr"
NO_DISTANCE_CHANGE = "no_distance_change"
RECEDING = "receding"

# FP.3 / FP.4 camera TTC
NO_MATCHES_IN_BOX = "no_matches_in_box"
TOO_FEW_PAIRS = "too_few_pairs"
RATIO_ONE = "ratio_one"

#: One line per code, for reports and notebooks.
DESCRIPTIONS: dict[str, str] = {
    OK: "finite TTC from a valid estimate",
    FRAME_ERROR: "an input file of the frame pair could not be read (NaN; see the error column)",
    NO_LEAD_BOX: "no box in the current frame holds lane lidar points (NaN)",
    NO_BOX_MATCH: "the current box has no matching box in the previous frame (NaN)",
    NO_LIDAR_POINTS_PREV: "no lidar points in the previous frame's box (NaN)",
    NO_LIDAR_POINTS_CURR: "no lidar points in the current frame's box (NaN)",
    NO_CLUSTER_PREV: "no lidar cluster of min_cluster_size points in the previous box (NaN)",
    NO_CLUSTER_CURR: "no lidar cluster of min_cluster_size points in the current box (NaN)",
    NO_DISTANCE_CHANGE: "distance to the object unchanged between frames (+inf)",
    RECEDING: "object moving away: the raw TTC is negative, reported as +inf",
    NO_MATCHES_IN_BOX: "no keypoint match left in the current box (NaN)",
    TOO_FEW_PAIRS: "fewer than two matches, or no pair of them at least min_dist apart (NaN)",
    RATIO_ONE: "distance ratio exactly 1: no scale change between frames (+inf)",
}

#: Every code, in the order above.
ALL: tuple[str, ...] = tuple(DESCRIPTIONS)


def describe(code: str) -> str:
    """The one-line description of ``code`` (``KeyError`` for an unknown code)."""
    return DESCRIPTIONS[code]
