"""Lidar points of every object box: the object's own points, its nearest face and how sure
that face is.

The lead's points come from the ego-lane crop (:mod:`ttc.steps.lidar`); every other vehicle is
outside it. Here each box gets its own points from the whole scan in front of the car:

1. :func:`object_scan_mask` keeps, once per scan, the points that can be on a vehicle in view:
   in front (``min_x`` ≤ x ≤ ``max_x``, inside ±45° of the forward axis, which holds the
   camera's ≈ 81° field of view) and above the ground (``min_z`` ≤ z ≤ ``max_z``).
2. :func:`associate_objects` projects them once (one projection per scan for all boxes) and
   takes, per shrunk box, the points inside it: the box's frustum, which also holds the road
   edge, other cars and walls behind the object.
3. The frustum's points are split into depth groups where the forward distance jumps by more
   than ``gap_m + gap_per_m · x`` (:func:`depth_groups`): a car's surfaces are continuous in
   x, the gap to a car or wall behind it is not, and the HDL-64E's sampling gets coarser with
   range (0.4° between rings ≈ 0.2 m at 30 m; along a car's side seen obliquely 30 m ahead,
   neighbouring returns lie 0.3–0.8 m apart in x), so a fixed gap splits one far car into
   pieces whose counts then decide which piece is "the object".
4. Of the groups holding at least ``min_points`` points and ``min_fraction`` of the frustum's
   largest group (a few stray returns do not qualify), the object is the one with the most
   support discounted by how far it lies behind the nearest of them:
   ``points · exp(−(near edge − nearest near edge) / support_scale_m)``
   (:func:`object_group`). A post or a truck's edge in the corner of a car's box does not
   take the box from the car 2–3 m behind it (drive 0009 frame 13, drive 0052 frames 44–49,
   seen in the images); a wall 10 m behind a car needs e^2.5 ≈ 12 times the car's points.
   ``support_scale_m = 0`` takes the nearest qualifying group (the rule of issue 30). Boxes
   are resolved nearest first, and the points a nearer object claimed are removed from the
   frusta of the boxes behind it, so a parked car in front of another one does not lend its
   points to the far one's box.
5. How sure the face is (:func:`face_sensitivity`): the nearest face is computed again with
   each one of the box's free frustum points left out, and with each point within
   :data:`EDGE_PX` outside the box let in (a point that moves by centimetres across the box's
   edge, the z band or a depth gap is a point left out or let in). ``distance_sd_m`` is the
   jackknife standard deviation of the faces with one point left out; a box is ``unsure`` when
   one point out or in moves its face by more than ``unsure_m`` or loses the object, or when a
   runner-up group scores at least :data:`CLOSE_SCORE_SHARE` of the object's (two points
   decide). On drive 0009 frames 13–14 every far box whose face moves by 5 cm or more when
   the scan moves by ±2 cm is unsure; the sure ones move by less than 5 cm.

Per box: :func:`nearest_face` (m, the forward distance from the lidar to the object's nearest
face, a low quantile of x), its jackknife sd (m) and unsure flag, the depth extent of its
points (m) and the point counts. Coordinates: Velodyne frame, x forward, y left, z up, metres;
pixels for boxes.
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
#: Points within this many pixels outside a shrunk box are let in one at a time to see how
#: sure its face is (a 2 cm move is 0.3 px at 45 m, 1.4 px at 10 m).
EDGE_PX = 1.0
#: A move (m) of the whole scan an object's face must withstand to be sure: a calibration
#: error's size (kitti2mcap's bag moves drive 0009's points by up to 0.8 px, ≈ 1.6 cm on the
#: far cars). The scan is tried moved by this much left, right, up and down.
MOVE_M = 0.02
#: Points within this many pixels of a shrunk box are the ones a :data:`MOVE_M` move can
#: bring in or out of it (2 cm is 4 px at 3.6 m; nearer objects fill their boxes).
NEAR_PX = 4.0


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


def _scored_groups(xs: np.ndarray, params: ObjectLidarParams):
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
    starts, stops, ok, score = _scored_groups(xs, params)
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


#: A runner-up group whose score is at least this share of the object's makes the object
#: unsure: a point or two in or out of either decides between them.
CLOSE_SCORE_SHARE = 2 / 3


def _face_of(xs: np.ndarray, params: ObjectLidarParams) -> float:
    """The nearest face (m) of the object of ``xs`` (sorted, m); NaN without one."""
    found = object_group(xs, params)
    return nearest_face(xs[found[0] : found[1]]) if found else float("nan")


def _faces_without(group: np.ndarray, ranks: np.ndarray) -> np.ndarray:
    """Nearest faces (m) of ``group`` (sorted, m, ≥ 2 points) with the point of each rank in
    ``ranks`` left out: NumPy's linear quantile of the m − 1 points left, for every rank."""
    m = len(group)
    virtual = NEAREST_FACE_QUANTILE * (m - 2)
    lo = int(virtual)
    a = np.where(lo < ranks, group[lo], group[lo + 1])
    b = np.where(lo + 1 < ranks, group[lo + 1], group[min(lo + 2, m - 1)])
    return a + (b - a) * (virtual - lo)


def _left_out_faces(xs: np.ndarray, params: ObjectLidarParams) -> tuple[np.ndarray, np.ndarray]:
    """The object's face (m) with points of ``xs`` (sorted, m) left out one at a time, and how
    many points each face stands for. Only a qualifying group's point can change the object
    when left out (a group that does not qualify still does not; leaving a point out never
    joins groups): each such group's first two points, last point and the points bridging two
    of its parts are left out one by one, the chosen group's points up to its face quantile
    too (their faces computed at once: leaving any of them out changes the groups alike), and
    one plain point stands for all the others of its group (it changes that group's count);
    the points of no qualifying group leave the face as it is."""
    starts, stops, ok, score = _scored_groups(xs, params)
    chosen = ok[np.argmax(score)]
    bridge = np.zeros(len(xs), dtype=bool)
    bridge[1:-1] = xs[2:] - xs[:-2] > params.gap_m + params.gap_per_m * xs[:-2]
    whole, face = np.zeros(len(xs), dtype=bool), np.zeros(len(xs), dtype=bool)
    plain, counts = [], []
    for g in ok:
        start, stop = starts[g], stops[g]
        whole[start : start + 2] = whole[stop - 1] = True
        whole[start:stop] |= bridge[start:stop]
        if g == chosen:
            face[start : start + int(NEAREST_FACE_QUANTILE * (stop - start - 1)) + 2] = True
        rest = start + np.flatnonzero(~whole[start:stop] & ~face[start:stop])
        if len(rest):
            plain.append(rest[0])
            counts.append(len(rest))
    face_only = list(np.flatnonzero(face & ~whole))
    picks = np.concatenate((np.flatnonzero(whole), plain)).astype(np.int64)
    faces = [_face_of(np.delete(xs, i), params) for i in picks]
    counts = [1] * int(whole.sum()) + counts
    if face_only:
        start, stop = starts[chosen], stops[chosen]
        first = np.delete(xs, face_only[0])
        if object_group(first, params) == (start, stop - 1):  # the same group, one point less
            ranks = np.asarray(face_only) - start
            faces += list(_faces_without(xs[start:stop], ranks))
        else:
            faces += [_face_of(np.delete(xs, i), params) for i in face_only]
        counts += [1] * len(face_only)
    others = len(xs) - int((stops[ok] - starts[ok]).sum())  # in no qualifying group
    if others:
        faces.append(nearest_face(xs[starts[chosen] : stops[chosen]]))
        counts.append(others)
    return np.asarray(faces, dtype=np.float64), np.asarray(counts, dtype=np.int64)


def _let_in_faces(xs: np.ndarray, params: ObjectLidarParams, values: np.ndarray) -> np.ndarray:
    """The object's face (m) with each of ``values`` (m) let in among ``xs`` (sorted, m), one
    at a time; a value that lands between two points of one group, past its first two (past
    the chosen group's face quantile), only adds one to that group's count: one such value is
    tried for all of them."""
    starts, stops, ok, score = _scored_groups(xs, params)
    chosen = ok[np.argmax(score)]
    heads = np.full(len(starts), 2)
    heads[chosen] = int(NEAREST_FACE_QUANTILE * (stops[chosen] - starts[chosen])) + 2
    at = np.searchsorted(xs, values)
    group = np.clip(np.searchsorted(starts, at, side="right") - 1, 0, None)
    inner = (at >= starts[group] + heads[group]) & (at < stops[group])
    faces, tried = [], set()
    for value, position, g, plain in zip(values, at, group, inner, strict=True):
        if plain and g in tried:
            continue
        tried.update([g] if plain else [])
        faces.append(_face_of(np.insert(xs, position, value), params))
    return np.asarray(faces, dtype=np.float64)


def face_sensitivity(
    xs: np.ndarray, params: ObjectLidarParams, near_edge: np.ndarray | None = None
) -> tuple[float, bool]:
    """How sure the nearest face of ``xs`` (a box's free frustum points' sorted forward
    distances, m) is: the jackknife standard deviation (m) of the faces found with each point
    left out, and whether it is unsure: one point left out, or one of ``near_edge`` (forward
    distances, m, of the points just outside the box) let in, moves the face by more than
    ``unsure_m`` or loses the object, or a runner-up group scores at least
    :data:`CLOSE_SCORE_SHARE` of the object's. Points let in beyond the object's group and its
    gap are not tried: they can only add to a group behind it, which the runner-up test
    covers once it qualifies. NaN and True when there is no object."""
    found = object_group(xs, params)
    if found is None:
        return float("nan"), True
    face = nearest_face(xs[found[0] : found[1]])
    faces, counts = _left_out_faces(xs, params)
    last = xs[found[1] - 1]
    edge = np.asarray(near_edge if near_edge is not None else [], dtype=np.float64)
    edge = edge[edge <= last + params.gap_m + params.gap_per_m * last]
    moved = np.abs(np.concatenate((faces, _let_in_faces(xs, params, edge))) - face)
    score = np.sort(_scored_groups(xs, params)[3])
    close = params.support_scale_m > 0 and len(score) > 1
    close = close and score[-2] >= CLOSE_SCORE_SHARE * score[-1]
    unsure = bool(close or not np.all(moved <= params.unsure_m))
    kept = ~np.isnan(faces)
    if not kept.any():
        return float("nan"), True
    w, f, n = counts[kept], faces[kept], counts.sum()
    mean = np.average(f, weights=w)
    return float(np.sqrt((n - 1) / n * np.sum(w * (f - mean) ** 2))), unsure


@dataclass(frozen=True)
class ObjectAssociation:
    """Object points of one scan: ``owner`` (N,) box index of each scan point given (−1: no
    object's), and per box (M,) ``distance_m`` (nearest face, m), ``spread_m`` (depth extent,
    m), ``n_points`` (object points), ``n_frustum`` (points inside the shrunk box),
    ``distance_sd_m`` (jackknife sd of the nearest face over its free frustum points, m; NaN
    without an object) and ``unsure`` (bool: one point left out moves the face by more than
    ``unsure_m`` or loses it; True without an object)."""

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
        if not unsure[b]:
            mine_or_free = near_box[:, b] & (~claimed | (owner == b))
            unsure[b] = _moves_face(points[mine_or_free, :3], velo_to_image, boxes[b], params)
    return ObjectAssociation(owner, distance, spread, n_points, n_frustum, sd, unsure)


def _grown(boxes: np.ndarray, px: float) -> np.ndarray:
    """``boxes`` (M × 4: x, y, w, h px) grown by ``px`` on every side."""
    return boxes + np.array([-px, -px, 2 * px, 2 * px])


def _moves_face(
    points: np.ndarray, velo_to_image: np.ndarray, box: np.ndarray, params: ObjectLidarParams
) -> bool:
    """Whether moving ``points`` (K × 3, m: the ones near the shrunk ``box`` (4,) px that no
    other box claimed) by :data:`MOVE_M` left, right, up or down moves the face of the points
    then inside the box and the height band by more than ``unsure_m`` (or loses it): many
    points cross a box edge or the band's floor together (a ring of bumper returns at the
    floor, the column of a box's edge) where one point in or out changes little."""
    face = _face_of(np.sort(points[_inside(points, velo_to_image, box, params), 0]), params)
    for move in MOVE_M * np.array([[0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]):
        moved = points + move
        now = _face_of(np.sort(moved[_inside(moved, velo_to_image, box, params), 0]), params)
        if not abs(now - face) <= params.unsure_m:
            return True
    return False


def _inside(
    points: np.ndarray, velo_to_image: np.ndarray, box: np.ndarray, params: ObjectLidarParams
) -> np.ndarray:
    """(K,) bool: ``points`` (K × 3, m) inside the shrunk ``box`` (4,) px and the limits."""
    inside = points_in_rois(project_to_image(points, velo_to_image), box[None, :])[:, 0]
    return inside & object_scan_mask(points, params, margin=0.0)
