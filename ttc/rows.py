"""The columns of a run's rows: one row per (frame pair, matched box pair), built in one place.

A row is the pair's columns (:func:`pair_columns`: frames, ``dt`` in s, scan and box
counts, keypoint and match counts, stage times in ms, cache flags), the current box's own
lidar points (:func:`object_columns`), the box pair's (:func:`box_columns`: box pair, lead
flag, class, confidence, box in px), then FP.2 (:func:`lidar_columns`, distances in m, TTC in
s) and FP.3/FP.4 (:func:`camera_columns`), or the empty result of a box without a previous
one (:func:`unmatched_columns`), then ``box_shared_matches`` and ``error``. A pair that could
not be read is one row of :func:`error_columns`. Each of these is a part that many rows share
(:class:`ttc.row_parts.RowParts` makes the rows one table). The fused columns and the track
are added over a whole run (:func:`ttc.engine.runner.finish_rows`).

:class:`PairDetail` holds the intermediate arrays of one frame pair (for pictures and the
report's explanations).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from ttc import reasons
from ttc.robust import median
from ttc.settings import CACHED_STAGE_NAMES

#: Column of a batch's rows (:func:`ttc.engine.runner.run_settings`): the index of the row's
#: setting in the list the batch was given.
MEMBER = "member"
#: FP.2–FP.4 columns of a box pair that could not be evaluated (types as in a full row).
EMPTY_BOX_RESULT: dict[str, Any] = {
    "ttc_lidar": np.nan, "lidar_reason": "", "d_prev": np.nan, "d_curr": np.nan,
    "lidar_points_prev": 0, "lidar_points_curr": 0, "lidar_outliers_prev": 0,
    "lidar_outliers_curr": 0, "lidar_closest_prev": np.nan, "lidar_closest_curr": np.nan,
    "lidar_median_prev": np.nan, "lidar_median_curr": np.nan, "ttc_camera": np.nan,
    "camera_reason": "", "camera_ratio": np.nan, "camera_pairs": 0, "matches_in_box": 0,
    "matches_kept": 0, "matches_removed": 0, "ms_lidar_ttc": 0.0, "ms_keypoint_filter": 0.0,
    "ms_camera_ttc": 0.0,
}  # fmt: skip
#: Stages timed per pair before FP.2 (``ms_<stage>`` columns of :func:`pair_columns`).
PAIR_TIMED_STAGES = ("objects", "lidar", "keypoints", "descriptors", "matching", "box_matching")


def error_columns(prev: int, curr: int, dt: float) -> dict[str, Any]:
    """The columns of a frame pair (``dt`` s apart) whose input could not be read (its one
    row's ``error`` holds the reason)."""
    row: dict[str, Any] = {
        "prev_frame": prev, "frame": curr, "dt": dt, "scan_points_prev": 0,
        "scan_points_curr": 0, "scan_short": False, "scan_dropped_curr": 0,
        "lane_points_curr": 0, "boxes_prev": 0, "boxes_curr": 0, "keypoints_prev": 0,
        "keypoints_curr": 0, "described_curr": 0, "matches_total": 0,
        **{f"ms_{stage}": 0.0 for stage in PAIR_TIMED_STAGES},
        **{f"cached_{stage}": False for stage in CACHED_STAGE_NAMES}, **EMPTY_OBJECT,
        "prev_box": -1, "curr_box": -1, "is_lead": True, "box_class": -1,
        "box_confidence": np.nan, "box_x": -1, "box_y": -1, "box_w": -1, "box_h": -1,
        **EMPTY_BOX_RESULT, "lidar_reason": reasons.FRAME_ERROR,
        "camera_reason": reasons.FRAME_ERROR,
    }  # fmt: skip
    return row


def pair_columns(
    prev: int,
    curr: int,
    dt: float,
    lane: dict[int, dict[str, np.ndarray]],
    boxes: dict[int, int],
    counts: dict[str, int],
    ms: dict[str, float],
    cached: dict[str, bool],
    min_scan_points: int,
) -> dict[str, Any]:
    """The columns of frame pair ``prev`` → ``curr`` shared by its box rows.

    ``lane``: each frame's lane-crop arrays (``points``, ``n_scan``, ``n_dropped``);
    ``boxes``: boxes per frame; ``counts``: ``keypoints_prev``, ``keypoints_curr``,
    ``described_curr``, ``matches_total``; ``ms``: time per stage of
    :data:`PAIR_TIMED_STAGES` (ms); ``cached``: cache flag per cached stage.
    """
    row: dict[str, Any] = {
        "prev_frame": prev,
        "frame": curr,
        "dt": dt,
        "scan_points_prev": int(lane[prev]["n_scan"]),
        "scan_points_curr": int(lane[curr]["n_scan"]),
        "scan_short": bool(lane[curr]["n_scan"] < min_scan_points),
        "scan_dropped_curr": int(lane[curr]["n_dropped"]),
        "lane_points_curr": int(len(lane[curr]["points"])),
        "boxes_prev": boxes[prev],
        "boxes_curr": boxes[curr],
        **{name: int(counts[name]) for name in _COUNTS},
        **{f"ms_{stage}": ms[stage] for stage in PAIR_TIMED_STAGES},
    }
    for stage in CACHED_STAGE_NAMES:
        row[f"cached_{stage}"] = cached[stage]
    return row


_COUNTS = ("keypoints_prev", "keypoints_curr", "described_curr", "matches_total")


def box_columns(
    objects: dict[str, np.ndarray], prev_box: int, curr_box: int, lead: int
) -> dict[str, Any]:
    """The columns of box pair ``prev_box`` → ``curr_box`` (−1: none) of the current frame's
    ``objects`` (``roi`` x, y, w, h in px; ``class_id``; ``confidence``); ``lead``: the lead
    box (−1: none)."""
    row: dict[str, Any] = {
        "prev_box": prev_box,
        "curr_box": curr_box,
        "is_lead": curr_box == lead and curr_box >= 0,
    }
    if curr_box >= 0:
        roi = objects["roi"][curr_box]
        row.update(
            box_class=int(objects["class_id"][curr_box]),
            box_confidence=float(objects["confidence"][curr_box]),
            box_x=int(roi[0]), box_y=int(roi[1]), box_w=int(roi[2]), box_h=int(roi[3]),
        )  # fmt: skip
    else:
        row.update(box_class=-1, box_confidence=np.nan, box_x=-1, box_y=-1, box_w=-1, box_h=-1)
    return row


def unmatched_columns(curr_box: int, lidar_points_curr: int) -> dict[str, Any]:
    """The FP.2–FP.4 columns of a box pair without a previous box: the empty result with
    reason ``no_lead_box`` (no current box either, ``curr_box`` −1) or ``no_box_match``, and
    the count of the current box's lidar points."""
    reason = reasons.NO_LEAD_BOX if curr_box < 0 else reasons.NO_BOX_MATCH
    return {**EMPTY_BOX_RESULT, "lidar_reason": reason, "camera_reason": reason,
            "lidar_points_curr": lidar_points_curr}  # fmt: skip


#: Columns of the current box's own lidar points (:func:`object_columns`), empty values.
EMPTY_OBJECT: dict[str, Any] = {
    "object_distance_m": np.nan, "object_spread_m": np.nan, "object_points": 0,
    "object_frustum_points": 0,
}  # fmt: skip


def object_columns(assoc: Any, curr_box: int) -> dict[str, Any]:
    """The current box's own lidar points (``assoc``: the current frame's
    :class:`ttc.steps.object_lidar.ObjectAssociation`): ``object_distance_m`` (m, forward
    distance of its nearest face), ``object_spread_m`` (m, depth extent), ``object_points``
    (points kept) and ``object_frustum_points`` (points inside the shrunk box); empty values
    for a row without a current box."""
    if curr_box < 0:
        return dict(EMPTY_OBJECT)
    return {
        "object_distance_m": float(assoc.distance_m[curr_box]),
        "object_spread_m": float(assoc.spread_m[curr_box]),
        "object_points": int(assoc.n_points[curr_box]),
        "object_frustum_points": int(assoc.n_frustum[curr_box]),
    }


def lidar_columns(
    lid: Any, pts_prev: np.ndarray, pts_curr: np.ndarray, ms: float
) -> dict[str, Any]:
    """FP.2 columns: the estimator's result ``lid`` (:class:`ttc.steps.lidar_ttc.LidarTTCResult`) on the
    box points ``pts_prev`` / ``pts_curr`` (N × 3, m, Velodyne frame), computed in ``ms``."""
    return dict(
        ttc_lidar=lid.ttc, lidar_reason=lid.reason, d_prev=lid.d_prev, d_curr=lid.d_curr,
        lidar_points_prev=len(pts_prev), lidar_points_curr=len(pts_curr),
        lidar_outliers_prev=lid.outliers_prev, lidar_outliers_curr=lid.outliers_curr,
        lidar_closest_prev=float(pts_prev[:, 0].min()) if len(pts_prev) else np.nan,
        lidar_closest_curr=float(pts_curr[:, 0].min()) if len(pts_curr) else np.nan,
        lidar_median_prev=float(median(pts_prev[:, 0])) if len(pts_prev) else np.nan,
        lidar_median_curr=float(median(pts_curr[:, 0])) if len(pts_curr) else np.nan,
        ms_lidar_ttc=ms,
    )  # fmt: skip


def camera_columns(cam: Any, filt: Any, ms_filter: float, ms_camera: float) -> dict[str, Any]:
    """FP.3/FP.4 columns: the box's filtered matches ``filt``
    (:class:`ttc.steps.keypoint_filter.FilterResult`) and the camera estimate ``cam``
    (:class:`ttc.steps.camera_ttc.CameraTTCResult`), with their times in ms."""
    return dict(
        ttc_camera=cam.ttc, camera_reason=cam.reason, camera_ratio=cam.ratio,
        camera_pairs=cam.n_pairs, matches_in_box=filt.n_in_box, matches_kept=filt.n_kept,
        matches_removed=filt.n_removed, ms_keypoint_filter=ms_filter, ms_camera_ttc=ms_camera,
    )  # fmt: skip


@dataclass
class PairDetail:
    """Intermediate arrays of one frame pair under one setting (for pictures and reports).

    Pixel coordinates for keypoints and boxes; lidar points in metres (Velodyne frame).
    ``kept`` / ``removed`` index ``matches`` (the lead box's FP.3 outcome).
    """

    prev: int
    curr: int
    images: dict[int, np.ndarray]
    objects: dict[int, dict[str, np.ndarray]]
    keypoints: dict[int, np.ndarray]
    matches: Any
    box_matches: Any
    lane_points: dict[int, np.ndarray]
    lane_uv: dict[int, np.ndarray]
    lane_owner: dict[int, np.ndarray]
    lead_box: int
    kept: np.ndarray
    removed: np.ndarray
    rows: pd.DataFrame
