"""FP.2: lidar time-to-collision from the points of a matched box in two frames.

Points are (N × 3) arrays in the Velodyne frame (x forward, metres). An estimator of
:data:`LIDAR_ESTIMATORS` reduces each frame's points to one distance to the object's rear and
says how many points it treated as outliers; :func:`lidar_ttc` applies the constant-velocity
model ``TTC = d_curr · dt / (d_prev − d_curr)`` (seconds).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ttc import reasons, robust

#: Modified z-score above which the ``median`` estimator counts a point as an outlier
#: (Iglewicz & Hoaglin), on the MAD scaled by :data:`ttc.robust.MAD_TO_SIGMA`.
MEDIAN_OUTLIER_Z = 3.5


@dataclass(frozen=True)
class LidarTTCParams:
    """FP.2 estimator and its parameters.

    ``quantile``: rank (0–1) of the ``quantile`` estimator. ``band_low`` / ``band_high``:
    quantile band (0–1) averaged by ``quantile_band_mean``. ``cluster_tolerance`` (metres):
    largest gap inside one Euclidean cluster; 0.2 m bridges neighbouring HDL-64E rings on a
    car's rear up to ~20 m (0.4–0.5° vertical spacing: ~6 cm at 8 m, ~17 cm at 20 m; points
    within a ring are ~1.3 cm apart at 8 m) but separates returns 0.2 m or more in front of
    the bumper. ``min_cluster_size``: least points of the kept cluster.
    """

    name: str = "median"
    quantile: float = 0.1
    band_low: float = 0.05
    band_high: float = 0.30
    cluster_tolerance: float = 0.2
    min_cluster_size: int = 3

    def __post_init__(self) -> None:
        if self.name not in LIDAR_ESTIMATORS:
            known = ", ".join(LIDAR_ESTIMATORS)
            raise ValueError(f"unknown lidar TTC estimator {self.name!r}; known: {known}")
        if not 0.0 <= self.quantile <= 1.0:
            raise ValueError(f"quantile must be in [0, 1], got {self.quantile}")
        if not 0.0 <= self.band_low < self.band_high <= 1.0:
            raise ValueError(
                f"need 0 <= band_low < band_high <= 1, got {self.band_low}, {self.band_high}"
            )
        if not self.cluster_tolerance > 0.0:
            raise ValueError(f"cluster_tolerance must be > 0 m, got {self.cluster_tolerance}")
        if self.min_cluster_size < 1:
            raise ValueError(f"min_cluster_size must be >= 1, got {self.min_cluster_size}")


class RearDistance(NamedTuple):
    """Distance to the object's rear (metres; NaN if none) and points treated as outliers."""

    distance: float
    n_outliers: int


def closest(points: np.ndarray, params: LidarTTCParams) -> RearDistance:
    """Smallest x (metres); no outliers."""
    return RearDistance(float(np.min(points[:, 0])), 0)


def quantile(points: np.ndarray, params: LidarTTCParams) -> RearDistance:
    """x at ``params.quantile`` (linear interpolation); outliers: points in front of it."""
    x = points[:, 0]
    d = float(robust.quantile(x, params.quantile))
    return RearDistance(d, int(np.count_nonzero(x < d)))


def median(points: np.ndarray, params: LidarTTCParams) -> RearDistance:
    """Median x (metres).

    The median rejects no point by rule; its outlier count is the points it is robust against
    in the usual sense: a modified z-score ``|x − median| / (1.4826 · MAD)`` above
    :data:`MEDIAN_OUTLIER_Z` (any point off the median when MAD is 0).
    """
    x = points[:, 0]
    d = float(robust.median(x))
    dev = np.abs(x - d)
    scale = robust.MAD_TO_SIGMA * float(robust.median(dev))
    return RearDistance(d, int(np.count_nonzero(dev > MEDIAN_OUTLIER_Z * scale)))


def quantile_band_mean(points: np.ndarray, params: LidarTTCParams) -> RearDistance:
    """Mean x of the points between the ``band_low`` and ``band_high`` quantiles (metres).

    The band's ends are data values (lower / higher order statistic), so it is never empty;
    outliers: points outside the band.
    """
    x = points[:, 0]
    lo = np.quantile(x, params.band_low, method="lower")
    hi = np.quantile(x, params.band_high, method="higher")
    band = (x >= lo) & (x <= hi)
    return RearDistance(float(np.mean(x[band])), int(len(x) - np.count_nonzero(band)))


def cluster(points: np.ndarray, params: LidarTTCParams) -> RearDistance:
    """Smallest x (metres) of the largest Euclidean cluster (3-D, ``cluster_tolerance``).

    Points are linked when closer than the tolerance; connected components are the clusters.
    Outliers: points outside the largest cluster. NaN if that cluster is below
    ``min_cluster_size``.
    """
    from scipy.sparse import csr_matrix  # noqa: PLC0415 (slow to import: not at planning)
    from scipy.sparse.csgraph import connected_components  # noqa: PLC0415
    from scipy.spatial import cKDTree  # noqa: PLC0415

    xyz = points[:, :3]
    n = len(xyz)
    pairs = cKDTree(xyz).query_pairs(params.cluster_tolerance, output_type="ndarray")
    # float64 CSR is csgraph's native format: no conversion inside connected_components
    graph = csr_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels)
    main = int(np.argmax(sizes))
    if sizes[main] < params.min_cluster_size:
        return RearDistance(float("nan"), n)
    return RearDistance(float(np.min(xyz[labels == main, 0])), int(n - sizes[main]))


#: FP.2 distance estimators by name; all take ``(points (N × 3, metres), LidarTTCParams)``
#: with N ≥ 1.
LIDAR_ESTIMATORS: dict[str, Callable[[np.ndarray, LidarTTCParams], RearDistance]] = {
    "closest": closest,
    "quantile": quantile,
    "median": median,
    "quantile_band_mean": quantile_band_mean,
    "cluster": cluster,
}


@dataclass(frozen=True)
class LidarTTCResult:
    """Lidar TTC (seconds; NaN or +inf when degenerate, see ``reason``) and its inputs.

    ``d_prev`` / ``d_curr`` (metres) are kept for RECEDING and NO_DISTANCE_CHANGE, so the raw
    value can be recomputed; they are NaN when that frame gave no distance.
    """

    ttc: float
    d_prev: float
    d_curr: float
    outliers_prev: int
    outliers_curr: int
    reason: str


def as_points(points: np.ndarray) -> np.ndarray:
    """The x, y, z columns (N × 3 float64, metres) of an (N × ≥3) array; empty input → (0, 3)."""
    arr = np.asarray(points, dtype=np.float64)
    if arr.size == 0:
        return np.empty((0, 3))
    if arr.ndim != 2 or arr.shape[1] < 3:
        raise ValueError(f"lidar points must be an (N, >=3) array, got shape {arr.shape}")
    return arr[:, :3]


def rear_distance(points: np.ndarray, params: LidarTTCParams) -> RearDistance:
    """Distance to the rear (metres) by ``params.name``; NaN and 0 outliers for no points."""
    points = as_points(points)
    if len(points) == 0:
        return RearDistance(float("nan"), 0)
    return LIDAR_ESTIMATORS[params.name](points, params)


def ttc_from_distances(d_prev: float, d_curr: float, dt: float) -> float:
    """Raw constant-velocity TTC ``d_curr · dt / (d_prev − d_curr)`` (seconds; ±inf at 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.float64(d_curr) * dt / (np.float64(d_prev) - d_curr))


def lidar_ttc(
    points_prev: np.ndarray, points_curr: np.ndarray, dt: float, params: LidarTTCParams
) -> LidarTTCResult:
    """Lidar TTC (seconds) of one box from its points (N × ≥3, metres) in two frames.

    ``dt`` is the time between the frames (seconds, e.g. step / 10 Hz). Degenerate cases
    return NaN (no points, no cluster) or +inf (no distance change, receding) with a reason
    code; only a non-positive ``dt`` raises (a caller error, not a data case).
    """
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt}")
    points_prev, points_curr = as_points(points_prev), as_points(points_curr)
    prev = rear_distance(points_prev, params)
    curr = rear_distance(points_curr, params)

    def result(ttc: float, reason: str) -> LidarTTCResult:
        return LidarTTCResult(
            ttc, prev.distance, curr.distance, prev.n_outliers, curr.n_outliers, reason
        )

    nan = float("nan")
    if len(points_prev) == 0:
        return result(nan, reasons.NO_LIDAR_POINTS_PREV)
    if len(points_curr) == 0:
        return result(nan, reasons.NO_LIDAR_POINTS_CURR)
    if np.isnan(prev.distance):
        return result(nan, reasons.NO_CLUSTER_PREV)
    if np.isnan(curr.distance):
        return result(nan, reasons.NO_CLUSTER_CURR)
    if prev.distance == curr.distance:
        return result(float("inf"), reasons.NO_DISTANCE_CHANGE)
    ttc = ttc_from_distances(prev.distance, curr.distance, dt)
    if ttc < 0:
        return result(float("inf"), reasons.RECEDING)
    return result(ttc, reasons.OK)
