"""The lead vehicle's rear distance per frame from lidar alone (no camera detector).

The ego-lane crop keeps essentially the lead vehicle's rear; of its Euclidean clusters the
largest vertical one is the lead (:func:`lead_points`), and its rear distance is a trimmed
mean of the nearest quarter of that cluster (:func:`rear_distance`). The reference TTC
(:mod:`ttc.evaluation.reference`) smooths this series over the whole recording.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ttc.robust import quantiles
from ttc.steps.lidar import LaneCropParams, crop_to_lane

#: Largest gap (m) inside one Euclidean cluster: bridges neighbouring HDL-64E rings on a car's
#: rear up to ~20 m (≈ 0.17 m apart there) and separates returns ≥ 0.2 m off the surface.
CLUSTER_TOLERANCE_M = 0.2
#: Fewest points for a distance; fewer gives NaN (e.g. frame 77's truncated scan).
MIN_POINTS = 5
#: Least vertical extent (m) of the lead cluster: a vehicle's rear is a vertical surface seen
#: by several laser rings (≈ 0.5 m in the lane crop's z band); a patch of road or kerb far
#: ahead is one ring (≈ 1 cm), which frame 77's truncated scan would otherwise pick.
MIN_HEIGHT_M = 0.1
#: Quantile band (0–1) of x averaged by :func:`rear_distance`.
REAR_BAND = (0.05, 0.30)


def euclidean_clusters(xyz: np.ndarray, tolerance: float = CLUSTER_TOLERANCE_M) -> np.ndarray:
    """Cluster label per point (N × 3, metres): connected components at ``tolerance`` metres."""
    n = len(xyz)
    if n == 0:
        return np.empty(0, dtype=np.int64)
    pairs = cKDTree(xyz).query_pairs(tolerance, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), (n, n))
    return connected_components(graph, directed=False)[1]


def rear_distance(
    points: np.ndarray,
    tolerance: float = CLUSTER_TOLERANCE_M,
    band: tuple[float, float] = REAR_BAND,
    min_points: int = MIN_POINTS,
) -> float:
    """Distance (m) to the lead vehicle's rear from its lidar points (N × ≥3, x forward, metres).

    Method: keep the largest Euclidean cluster (``tolerance`` metres), then average x over the
    points between its ``band`` quantiles (5–30 % by default). The cluster drops returns
    separated from the car (spray, points a metre ahead of the bumper, far objects); the lower
    trim drops the few stray points that still touch the cluster; averaging the nearest
    quarter of the rear (≈ 75–150 points here) reduces the ≈ 2 cm range noise of a single
    return to a few millimetres, where a minimum would keep it and a median would drift towards
    the curved corners and the trunk lid. NaN when the cluster has fewer than ``min_points``.
    """
    arr = np.asarray(points, dtype=np.float64)
    if arr.size == 0 or len(arr) < min_points:
        return float("nan")
    xyz = arr[:, :3]
    labels = euclidean_clusters(xyz, tolerance)
    sizes = np.bincount(labels)
    main = int(np.argmax(sizes))
    if sizes[main] < min_points:
        return float("nan")
    x = xyz[labels == main, 0]
    lo, hi = quantiles(x, band)
    return float(np.mean(x[(x >= lo) & (x <= hi)]))


def lead_points(
    points: np.ndarray,
    crop: LaneCropParams | None = None,
    tolerance: float = CLUSTER_TOLERANCE_M,
    min_points: int = MIN_POINTS,
    min_height: float = MIN_HEIGHT_M,
) -> np.ndarray:
    """The lead vehicle's points (K × 4) of a scan (N × 4, metres), without a camera detector.

    The ego-lane crop keeps essentially the lead car's rear (other vehicles are outside
    |y| ≤ 2 m); of its Euclidean clusters the largest one with at least ``min_points`` points
    and a vertical extent of ``min_height`` metres is the lead car. Empty (0 × 4) when no
    cluster qualifies. Independent of YOLO on purpose: the reference shares no box error with
    the estimators it judges.
    """
    lane = crop_to_lane(points, crop if crop is not None else LaneCropParams())
    labels = euclidean_clusters(lane[:, :3].astype(np.float64), tolerance)
    if len(labels) == 0:
        return lane
    z = pd.Series(lane[:, 2]).groupby(labels).agg(["size", "min", "max"])
    ok = z[(z["size"] >= min_points) & (z["max"] - z["min"] >= min_height)]
    if ok.empty:
        return lane[:0]
    return lane[labels == ok["size"].idxmax()]


def lead_distance_series(
    scans: Iterable[tuple[int, np.ndarray]], crop: LaneCropParams | None = None
) -> pd.DataFrame:
    """Lead-vehicle distance per frame of ``scans`` (``(frame, points)``, points N × 4 in the
    Velodyne frame, m; an iterable so a whole recording need not be held at once):
    ``frame``, ``distance_m`` (m, NaN: none), ``n_points`` (lead points), ``scan_points``
    (points in the whole scan)."""
    rows = []
    for index, points in scans:
        lead = lead_points(points, crop)
        rows.append((index, rear_distance(lead), len(lead), len(points)))
    return pd.DataFrame(rows, columns=["frame", "distance_m", "n_points", "scan_points"])
