"""The documented schema of a sweep's rows (``runs/*.parquet``, :func:`experiments.store.load_sweep`:
one row per run × frame pair × box pair).

The schema table of docs/results.md is generated from :data:`FRAME_COLUMNS`
(``python -m experiments.store.schema``) and the tests check real sweeps against it.
"""

from __future__ import annotations

import pandas as pd

from ttc.settings import AXIS_TABLE

# (column, pandas dtype kind, unit, meaning); kinds: "str", "int", "float", "bool"
FRAME_COLUMNS: list[tuple[str, str, str, str]] = [
    ("run_id", "str", "", "hash of the run's setting config; joins the run records"),
    ("sweep_id", "str", "", "sweep folder name"),
    *((axis.name, "str", "", axis.doc) for axis in AXIS_TABLE),
    ("git_commit", "str", "", "code version of the run"),
    ("prev_frame", "int", "", "index of the previous frame"),
    ("frame", "int", "", "index of the current frame"),
    ("dt", "float", "s", "time between the two frames"),
    (
        "ego_speed_mps",
        "float",
        "m/s",
        "ego's mean speed over the pair: oxts vf (KITTI raw), poses (odometry); NaN: neither",
    ),
    ("scan_points_prev", "int", "points", "points in the previous scan"),
    ("scan_points_curr", "int", "points", "points in the current scan"),
    ("scan_short", "bool", "", "current scan below dataset.min_scan_points (truncated)"),
    ("scan_dropped_curr", "int", "points", "non-finite points dropped from the current scan"),
    ("lane_points_curr", "int", "points", "current scan points inside the ego-lane crop"),
    ("boxes_prev", "int", "boxes", "objects detected in the previous frame"),
    ("boxes_curr", "int", "boxes", "objects detected in the current frame"),
    ("keypoints_prev", "int", "keypoints", "keypoints detected in the previous frame"),
    ("keypoints_curr", "int", "keypoints", "keypoints detected in the current frame"),
    (
        "described_curr",
        "int",
        "keypoints",
        "current keypoints kept by the descriptor (klt: tracked)",
    ),
    ("matches_total", "int", "matches", "keypoint matches between the frames (after selector)"),
    (
        "object_distance_m",
        "float",
        "m",
        "forward distance of the current box's object's nearest face (its own lidar points)",
    ),
    ("object_spread_m", "float", "m", "depth extent of the current box's object points"),
    ("object_points", "int", "points", "lidar points kept as the current box's object"),
    ("object_frustum_points", "int", "points", "lidar points inside the current (shrunk) box"),
    (
        "track_id",
        "int",
        "",
        "chain of the run's FP.1 matches: first frame * 1000 + first box; -1: no current box",
    ),
    ("prev_box", "int", "", "matched previous box id (-1: none)"),
    ("curr_box", "int", "", "current box id (-1: no lead box)"),
    ("is_lead", "bool", "", "the current box holds most ego-lane lidar points"),
    ("box_class", "int", "", "COCO class id of the current box"),
    ("box_confidence", "float", "", "detector confidence of the current box"),
    ("box_x", "int", "px", "current box left"),
    ("box_y", "int", "px", "current box top"),
    ("box_w", "int", "px", "current box width"),
    ("box_h", "int", "px", "current box height"),
    ("box_shared_matches", "int", "matches", "FP.1 score: matches shared by the box pair"),
    ("ttc_lidar", "float", "s", "FP.2 lidar TTC (NaN: invalid, inf: no collision course)"),
    ("lidar_reason", "str", "", "reason code of ttc_lidar (ok or why not)"),
    ("d_prev", "float", "m", "distance the estimator chose, previous frame"),
    ("d_curr", "float", "m", "distance the estimator chose, current frame"),
    ("lidar_points_prev", "int", "points", "lidar points in the previous box"),
    ("lidar_points_curr", "int", "points", "lidar points in the current box"),
    (
        "lidar_outliers_prev",
        "int",
        "points",
        "previous-box points the estimator treated as outliers",
    ),
    (
        "lidar_outliers_curr",
        "int",
        "points",
        "current-box points the estimator treated as outliers",
    ),
    ("lidar_closest_prev", "float", "m", "minimum x of the previous box's points"),
    ("lidar_closest_curr", "float", "m", "minimum x of the current box's points"),
    ("lidar_median_prev", "float", "m", "median x of the previous box's points"),
    ("lidar_median_curr", "float", "m", "median x of the current box's points"),
    ("ttc_camera", "float", "s", "FP.4 camera TTC (NaN: invalid, inf: no collision course)"),
    ("camera_reason", "str", "", "reason code of ttc_camera"),
    ("camera_ratio", "float", "", "distance ratio statistic r (current / previous)"),
    ("camera_pairs", "int", "pairs", "keypoint pairs used for r"),
    ("matches_in_box", "int", "matches", "matches with the current keypoint in the shrunk box"),
    ("matches_kept", "int", "matches", "matches kept by the FP.3 filter"),
    ("matches_removed", "int", "matches", "matches removed by the FP.3 filter"),
    ("ttc_fused", "float", "s", "FP.7 fused TTC d/v (NaN: none, inf: no collision course)"),
    ("ttc_fused_sd", "float", "s", "standard deviation of ttc_fused (delta method)"),
    ("fused_ratio", "float", "", "fused distance ratio d_prev / d_curr of the filter's state"),
    ("fused_reason", "str", "", "reason code of ttc_fused (ttc.steps.fusion.REASONS)"),
    ("ms_objects", "float", "ms", "YOLO (or cache load), current frame"),
    ("ms_lidar", "float", "ms", "scan load + crop (or cache load) + projection, current frame"),
    ("ms_keypoints", "float", "ms", "keypoint detection (or cache load), current frame"),
    ("ms_descriptors", "float", "ms", "description (or cache load), current frame"),
    ("ms_matching", "float", "ms", "k=2 matching (or cache load) + selection, this pair"),
    ("ms_box_matching", "float", "ms", "FP.1, this pair"),
    ("ms_lidar_ttc", "float", "ms", "FP.2, this box pair"),
    ("ms_keypoint_filter", "float", "ms", "FP.3, this box pair"),
    ("ms_camera_ttc", "float", "ms", "FP.4, this box pair"),
    ("cached_objects", "bool", "", "objects came from the stage cache"),
    ("cached_lidar", "bool", "", "lane points came from the stage cache"),
    ("cached_keypoints", "bool", "", "keypoints came from the stage cache"),
    ("cached_descriptors", "bool", "", "descriptors came from the stage cache"),
    ("cached_matches", "bool", "", "matches came from the stage cache"),
    ("error", "str", "", "why a frame pair could not be processed (empty: fine)"),
]

_KIND_CHECKS = {
    "str": lambda s: pd.api.types.is_string_dtype(s) or pd.api.types.is_object_dtype(s),
    "int": pd.api.types.is_integer_dtype,
    "float": pd.api.types.is_float_dtype,
    "bool": pd.api.types.is_bool_dtype,
}


def schema_problems(frames: pd.DataFrame) -> list[str]:
    """Columns missing from ``frames`` or of the wrong kind (empty list: conforms)."""
    problems = []
    for name, kind, _, _ in FRAME_COLUMNS:
        if name not in frames:
            problems.append(f"missing column {name}")
        elif not _KIND_CHECKS[kind](frames[name]):
            problems.append(f"{name}: expected {kind}, got {frames[name].dtype}")
    return problems


def markdown_table() -> str:
    """The schema as a markdown table (for docs/results.md)."""
    lines = ["| column | type | unit | meaning |", "|---|---|---|---|"]
    lines += [f"| `{n}` | {k} | {u} | {m} |" for n, k, u, m in FRAME_COLUMNS]
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown_table())
