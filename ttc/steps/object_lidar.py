"""Lidar points of every object box: the object's own points and its nearest face.

The lead's points come from the ego-lane crop (:mod:`ttc.steps.lidar`); every other vehicle is
outside it. Here each box gets its own points from the whole scan in front of the car:

1. :func:`object_scan_mask` keeps, once per scan, the points that can be on a vehicle in view:
   in front (``min_x`` ≤ x ≤ ``max_x``, inside ±45° of the forward axis, which holds the
   camera's ≈ 81° field of view) and above the ground (``min_z`` ≤ z ≤ ``max_z``).
2. :func:`associate_objects` projects them once (one projection per scan for all boxes) and
   takes, per shrunk box, the points inside it: the box's frustum, which also holds the road
   edge, other cars and walls behind the object.
3. The frustum's points are split into depth groups where the forward distance jumps by more
   than ``gap_m`` (a car's surfaces are continuous in x; the gap to a car or wall behind it
   is not), and the **nearest compact group** is the object: the nearest group holding at
   least ``min_points`` points and ``min_fraction`` of the frustum's largest group (a few
   stray returns in front of the car do not qualify). Boxes are resolved nearest first, and
   the points a nearer object claimed are removed from the frusta of the boxes behind it, so
   a parked car in front of another one does not lend its points to the far one's box.

Per box: :func:`nearest_face` (m, the forward distance from the lidar to the object's nearest
face, a low quantile of x), the depth extent of its points (m) and the point counts.
Coordinates: Velodyne frame, x forward, y left, z up, metres; pixels for boxes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ttc.robust import quantile, quantiles
from ttc.steps.box_matching import points_in_rois, shrink_rois
from ttc.steps.lidar import project_to_image

#: Quantile (0–1) of an object's forward distances taken as its nearest face: just above the
#: minimum, so a single stray return does not set it.
NEAREST_FACE_QUANTILE = 0.05
#: Quantiles (0–1) of x whose difference is an object's depth extent (``object_spread_m``).
SPREAD_QUANTILES = (0.05, 0.95)


@dataclass(frozen=True)
class ObjectLidarParams:
    """Which scan points can belong to an object box, and how its own points are kept.

    ``min_x`` / ``max_x``: forward range (m; 60 m covers every recording shipped: drive 0009's
    parked cars are 4–50 m ahead). ``min_z`` / ``max_z``: height band (m, lidar frame; the
    ground is at ≈ −1.73 m on KITTI, so −1.4 m keeps bumpers and drops the road).
    ``gap_m``: a jump in forward distance (m) that separates two objects in one frustum.
    ``min_points``: fewest points of an object; ``min_fraction``: least share (0–1) of the
    frustum's largest depth group an object's group must hold.
    """

    min_x: float = 2.0
    max_x: float = 60.0
    min_z: float = -1.4
    max_z: float = 1.0
    gap_m: float = 0.5
    min_points: int = 3
    min_fraction: float = 0.2

    def __post_init__(self) -> None:
        if not (0 <= self.min_x < self.max_x and self.min_z < self.max_z):
            raise ValueError(f"empty object range: {self}")
        if self.gap_m <= 0 or self.min_points < 1 or not 0 <= self.min_fraction <= 1:
            raise ValueError(f"gap_m > 0, min_points >= 1, 0 <= min_fraction <= 1: {self}")


def object_scan_mask(points: np.ndarray, params: ObjectLidarParams) -> np.ndarray:
    """(N,) bool: the rows of ``points`` (N × ≥3, m) that can lie on a vehicle in view."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    return (
        (x >= params.min_x)
        & (x <= params.max_x)
        & (np.abs(y) <= x)
        & (z >= params.min_z)
        & (z <= params.max_z)
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


def nearest_group(x: np.ndarray, params: ObjectLidarParams) -> np.ndarray:
    """Positions into ``x`` (forward distances, m) of the nearest compact depth group (see the
    module docstring); empty when none qualifies."""
    if len(x) < params.min_points:
        return np.empty(0, dtype=np.int64)
    order = np.argsort(x, kind="stable")
    group = np.r_[0, np.cumsum(np.diff(x[order]) > params.gap_m)]
    sizes = np.bincount(group)
    need = max(params.min_points, params.min_fraction * sizes.max())
    ok = np.flatnonzero(sizes >= need)
    return order[group == ok[0]] if len(ok) else np.empty(0, dtype=np.int64)


@dataclass(frozen=True)
class ObjectAssociation:
    """Object points of one scan: ``owner`` (N,) box index of each scan point given (−1: no
    object's), and per box (M,) ``distance_m`` (nearest face, m), ``spread_m`` (depth extent,
    m), ``n_points`` (object points) and ``n_frustum`` (points inside the shrunk box)."""

    owner: np.ndarray
    distance_m: np.ndarray
    spread_m: np.ndarray
    n_points: np.ndarray
    n_frustum: np.ndarray

    def of_box(self, points: np.ndarray, box_index: int) -> np.ndarray:
        """The rows of ``points`` (the N points given) that are box ``box_index``'s object."""
        return points[self.owner == box_index]


def associate_objects(
    points: np.ndarray,
    velo_to_image: np.ndarray,
    rois: np.ndarray,
    shrink: float = 0.10,
    params: ObjectLidarParams | None = None,
) -> ObjectAssociation:
    """Each box's own lidar points (see the module docstring).

    ``points``: N × ≥3 (m, Velodyne frame), already :func:`object_scan_mask`-ed;
    ``velo_to_image``: 3 × 4; ``rois``: M × 4 (x, y, w, h px), shrunk by ``shrink`` (a
    fraction) before points are tested.
    """
    params = params or ObjectLidarParams()
    n, m = len(points), len(rois)
    owner = np.full(n, -1, dtype=np.int64)
    distance, spread = np.full(m, np.nan), np.full(m, np.nan)
    n_points, n_frustum = np.zeros(m, dtype=np.int64), np.zeros(m, dtype=np.int64)
    if n == 0 or m == 0:
        return ObjectAssociation(owner, distance, spread, n_points, n_frustum)
    uv = project_to_image(points[:, :3], velo_to_image)
    inside = points_in_rois(uv, shrink_rois(rois, shrink))  # (N, M) bool
    x = np.asarray(points[:, 0], dtype=np.float64)
    frusta = [np.flatnonzero(inside[:, b]) for b in range(m)]
    n_frustum[:] = [len(f) for f in frusta]
    first = [nearest_group(x[f], params) for f in frusta]
    near = [x[f[g]].min() if len(g) else np.inf for f, g in zip(frusta, first, strict=True)]
    claimed = np.zeros(n, dtype=bool)
    for b in np.argsort(near, kind="stable"):
        free = frusta[b][~claimed[frusta[b]]]
        mine = free[nearest_group(x[free], params)]
        if not len(mine):
            continue
        claimed[mine] = True
        owner[mine] = b
        distance[b], spread[b], n_points[b] = (
            nearest_face(x[mine]),
            depth_extent(x[mine]),
            len(mine),
        )
    return ObjectAssociation(owner, distance, spread, n_points, n_frustum)
