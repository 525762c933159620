"""Lidar points of every object box: the object's own points, its nearest face and how sure
that face is.

The lead's points come from the ego-lane crop (:mod:`ttc.steps.lidar`); every other vehicle is
outside it. Here each box gets its own points from the whole scan in front of the car:

1. :func:`~ttc.steps.object_groups.object_scan_mask` keeps, once per scan, the points that
   can be on a vehicle in view: in front (``min_x`` ≤ x ≤ ``max_x``, inside ±45° of the
   forward axis, which holds the camera's ≈ 81° field of view) and above the ground
   (``min_z`` ≤ z ≤ ``max_z``), and those within :data:`~ttc.steps.object_groups.MOVE_M`
   beyond these limits (step 5 moves the scan by that much).
2. :func:`associate_objects` projects them once (one projection per scan for all boxes) and
   takes, per shrunk box, the points inside it: the box's frustum, which also holds the road
   edge, other cars and walls behind the object.
3. The frustum's points are split into depth groups where the forward distance jumps by more
   than ``gap_m + gap_per_m · x`` (:func:`~ttc.steps.object_groups.depth_groups`): a car's
   surfaces are continuous in x, the gap to a car or wall behind it is not, and the HDL-64E's
   sampling gets coarser with range (0.4° between rings ≈ 0.2 m at 30 m; along a car's side
   seen obliquely 30 m ahead, neighbouring returns lie 0.3–0.8 m apart in x), so a fixed gap
   splits one far car into pieces whose counts then decide which piece is "the object".
4. Of the groups holding at least ``min_points`` points and ``min_fraction`` of the frustum's
   largest group (a few stray returns do not qualify), the object is the one with the most
   support discounted by how far it lies behind the nearest of them:
   ``points · exp(−(near edge − nearest near edge) / support_scale_m)``
   (:func:`~ttc.steps.object_groups.object_group`). A post or a truck's edge in the corner of
   a car's box does not take the box from the car 2–3 m behind it (drive 0009 frame 13, drive
   0052 frames 44–49, seen in the images); a wall 10 m behind a car needs e^2.5 ≈ 12 times the
   car's points. ``support_scale_m = 0`` takes the nearest qualifying group (the rule of issue
   30). Boxes are resolved nearest first, and the points a nearer object claimed are removed
   from the frusta of the boxes behind it, so a parked car in front of another one does not
   lend its points to the far one's box.
5. How sure the face is (:mod:`ttc.steps.object_face`): the nearest face is computed again
   with each one of the box's free frustum points left out, with each point within
   :data:`~ttc.steps.object_face.EDGE_PX` outside the box let in (a point that moves by
   centimetres across the box's edge, the z band or a depth gap is a point left out or let
   in), and with the whole scan moved by :data:`~ttc.steps.object_groups.MOVE_M` left, right,
   up and down (a ring of bumper returns at the band's floor or a box edge's column of returns
   crossing together). ``distance_sd_m`` is the jackknife standard deviation of the faces with
   one point left out; a box is ``unsure`` when any of these moves its face by more than
   ``unsure_m`` or loses the object, when a runner-up group scores at least
   :data:`~ttc.steps.object_face.CLOSE_SCORE_SHARE` of the object's (two points decide), or
   when an unsure nearer box claimed points of its frustum (that box may take others when the
   scan moves). On drive 0009 frames 13–14 every far box whose face moves by 5 cm or more when
   the scan moves by ±2 cm is unsure; the sure ones move by less than 5 cm.

Per box: :func:`~ttc.steps.object_groups.nearest_face` (m, the forward distance from the lidar
to the object's nearest face, a low quantile of x), its jackknife sd (m) and unsure flag, the
depth extent of its points (m) and the point counts. Coordinates: Velodyne frame, x forward,
y left, z up, metres; pixels for boxes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ttc.steps.box_matching import points_in_rois, shrink_rois
from ttc.steps.lidar import project_to_image
from ttc.steps.object_face import EDGE_PX, NEAR_PX, face_sensitivity, moves_face
from ttc.steps.object_groups import (
    ObjectLidarParams,
    depth_extent,
    nearest_face,
    nearest_group,
    object_scan_mask,
)

#: The names importers use from here (the parameters and the scan mask live in
#: :mod:`ttc.steps.object_groups`).
__all__ = ["ObjectAssociation", "ObjectLidarParams", "associate_objects", "object_scan_mask"]


@dataclass(frozen=True)
class ObjectAssociation:
    """Object points of one scan: ``owner`` (N,) box index of each scan point given (−1: no
    object's), and per box (M,) ``distance_m`` (nearest face, m), ``spread_m`` (depth extent,
    m), ``n_points`` (object points), ``n_frustum`` (points inside the shrunk box),
    ``distance_sd_m`` (jackknife sd of the nearest face over its free frustum points, m; NaN
    without an object) and ``unsure`` (bool: one point in or out, the scan moved by 2 cm or
    a close runner-up group moves the face by more than ``unsure_m`` or loses it, module
    docstring step 5; True without an object)."""

    owner: np.ndarray
    distance_m: np.ndarray
    spread_m: np.ndarray
    n_points: np.ndarray
    n_frustum: np.ndarray
    distance_sd_m: np.ndarray
    unsure: np.ndarray

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
    distance, spread, sd = np.full(m, np.nan), np.full(m, np.nan), np.full(m, np.nan)
    n_points, n_frustum = np.zeros(m, dtype=np.int64), np.zeros(m, dtype=np.int64)
    unsure = np.ones(m, dtype=bool)
    if n == 0 or m == 0:
        return ObjectAssociation(owner, distance, spread, n_points, n_frustum, sd, unsure)
    uv = project_to_image(points[:, :3], velo_to_image)
    boxes = shrink_rois(rois, shrink)
    member = object_scan_mask(points, params, margin=0.0)[:, None]
    inside = points_in_rois(uv, boxes) & member  # (N, M) bool
    edge = points_in_rois(uv, _grown(boxes, EDGE_PX)) & member & ~inside
    near_box = points_in_rois(uv, _grown(boxes, NEAR_PX))
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
        outside = np.flatnonzero(edge[:, b] & ~claimed)
        sd[b], unsure[b] = face_sensitivity(np.sort(x[free]), params, x[outside])
        # an unsure nearer box may take other points of this frustum when the scan moves
        unsure[b] |= bool(np.any(unsure[owner[frusta[b]][owner[frusta[b]] >= 0]]))
        if not unsure[b]:
            mine_or_free = near_box[:, b] & (~claimed | (owner == b))
            unsure[b] = moves_face(points[mine_or_free, :3], velo_to_image, boxes[b], params)
    return ObjectAssociation(owner, distance, spread, n_points, n_frustum, sd, unsure)


def _grown(boxes: np.ndarray, px: float) -> np.ndarray:
    """``boxes`` (M × 4: x, y, w, h px) grown by ``px`` on every side."""
    return boxes + np.array([-px, -px, 2 * px, 2 * px])
