"""Depth groups of a box's frustum and the one that is its object (the parameters, the scan
mask, the nearest face and the group choice of :mod:`ttc.steps.object_lidar`, steps 1, 3
and 4). Forward distances in metres, Velodyne frame (x forward, y left, z up)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ttc.robust import quantile, quantiles

#: Quantile (0–1) of an object's forward distances taken as its nearest face: just above the
#: minimum, so a single stray return does not set it.
NEAREST_FACE_QUANTILE = 0.05
#: Quantiles (0–1) of x whose difference is an object's depth extent (``object_spread_m``).
SPREAD_QUANTILES = (0.05, 0.95)
#: A move (m) of the whole scan an object's face must withstand to be sure: a calibration
#: error's size (kitti2mcap's bag moves drive 0009's points by up to 0.8 px, ≈ 1.6 cm on the
#: far cars). The scan is tried moved by this much left, right, up and down.
MOVE_M = 0.02


@dataclass(frozen=True)
class ObjectLidarParams:
    """Which scan points can belong to an object box, and how its own points are kept.

    ``min_x`` / ``max_x``: forward range (m; 60 m covers every recording shipped: drive 0009's
    parked cars are 4–50 m ahead). ``min_z`` / ``max_z``: height band (m, lidar frame; the
    ground is at ≈ −1.73 m on KITTI, so −1.4 m keeps bumpers and drops the road).
    ``gap_m`` + ``gap_per_m`` · x: a jump in forward distance (m) that separates two objects
    in one frustum, x (m) the nearer side of the jump. ``min_points``: fewest points of an
    object; ``min_fraction``: least share (0–1) of the frustum's largest depth group an
    object's group must hold. ``support_scale_m``: depth (m) over which a group's support is
    discounted behind the nearest qualifying group (0: the nearest one is the object).
    ``unsure_m``: a face that moves by more than this (m) when one frustum point is left out
    is unsure.
    """

    min_x: float = 2.0
    max_x: float = 60.0
    min_z: float = -1.4
    max_z: float = 1.0
    gap_m: float = 0.5
    gap_per_m: float = 0.02
    min_points: int = 3
    min_fraction: float = 0.2
    support_scale_m: float = 4.0
    unsure_m: float = 0.25

    def __post_init__(self) -> None:
        if not (0 <= self.min_x < self.max_x and self.min_z < self.max_z):
            raise ValueError(f"empty object range: {self}")
        if self.gap_m <= 0 or self.gap_per_m < 0 or self.min_points < 1:
            raise ValueError(f"gap_m > 0, gap_per_m >= 0, min_points >= 1: {self}")
        if not 0 <= self.min_fraction <= 1 or self.support_scale_m < 0 or self.unsure_m <= 0:
            raise ValueError(f"0 <= min_fraction <= 1, support_scale_m >= 0, unsure_m > 0: {self}")


def object_scan_mask(
    points: np.ndarray, params: ObjectLidarParams, margin: float = MOVE_M
) -> np.ndarray:
    """(N,) bool: the rows of ``points`` (N × ≥3, m) that can lie on a vehicle in view, and
    those within ``margin`` (m) beyond the range and height limits: :func:`associate_objects`
    keeps only the ones inside as objects' points and tries the scan moved by ``margin``."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    return (
        (x >= params.min_x - margin)
        & (x <= params.max_x + margin)
        & (np.abs(y) <= x + margin)
        & (z >= params.min_z - margin)
        & (z <= params.max_z + margin)
    )


def nearest_face(x: np.ndarray) -> float:
    """Forward distance (m) of an object's nearest face from its points' x (m): the
    :data:`NEAREST_FACE_QUANTILE` quantile; NaN without points."""
    return float(quantile(x, NEAREST_FACE_QUANTILE)) if len(x) else float("nan")


def depth_extent(x: np.ndarray) -> float:
    """Depth extent (m) of an object's points: the :data:`SPREAD_QUANTILES` range of x; small
    for a face turned to the camera, metres for a car seen along its side. NaN without points."""
    if not len(x):
        return float("nan")
    lo, hi = quantiles(x, SPREAD_QUANTILES)
    return float(hi - lo)


def depth_groups(xs: np.ndarray, params: ObjectLidarParams) -> tuple[np.ndarray, np.ndarray]:
    """Start and stop positions (G,) of the depth groups of ``xs`` (sorted forward distances,
    m): a new group starts where x jumps by more than ``gap_m + gap_per_m`` · x."""
    jumps = np.flatnonzero(xs[1:] - xs[:-1] > params.gap_m + params.gap_per_m * xs[:-1]) + 1
    bounds = np.concatenate(([0], jumps, [len(xs)]))
    return bounds[:-1], bounds[1:]


def scored_groups(xs: np.ndarray, params: ObjectLidarParams):
    """The depth groups of ``xs`` (sorted, m): starts and stops (G,), the qualifying ones
    (positions into the groups, nearest first) and their scores (module docstring, step 4)."""
    starts, stops = depth_groups(xs, params)
    sizes = stops - starts
    ok = np.flatnonzero(sizes >= max(params.min_points, params.min_fraction * sizes.max()))
    if params.support_scale_m > 0 and len(ok) > 1:
        behind = xs[starts[ok]] - xs[starts[ok[0]]]
        return starts, stops, ok, sizes[ok] * np.exp(-behind / params.support_scale_m)
    first = np.zeros(len(ok))
    first[:1] = 1.0  # the nearest qualifying group
    return starts, stops, ok, first


def object_group(xs: np.ndarray, params: ObjectLidarParams) -> tuple[int, int] | None:
    """Start and stop positions into ``xs`` (sorted forward distances, m) of the object's
    depth group (module docstring, step 4); None when no group qualifies."""
    if len(xs) < params.min_points:
        return None
    starts, stops, ok, score = scored_groups(xs, params)
    if not len(ok):
        return None
    pick = ok[np.argmax(score)]
    return int(starts[pick]), int(stops[pick])


def nearest_group(x: np.ndarray, params: ObjectLidarParams) -> np.ndarray:
    """Positions into ``x`` (forward distances, m, any order) of the object's depth group
    (:func:`object_group`); empty when none qualifies."""
    order = np.argsort(x, kind="stable")
    found = object_group(x[order], params)
    return order[found[0] : found[1]] if found else np.empty(0, dtype=np.int64)
