"""How sure an object's nearest face is (:mod:`ttc.steps.object_lidar`, step 5): its face
with one frustum point left out or let in at a time, computed exactly but only for the points
that can change it, and with the scan moved by :data:`MOVE_M`. Forward distances in metres;
pixels for boxes."""

from __future__ import annotations

import numpy as np

from ttc.steps.box_matching import points_in_rois
from ttc.steps.lidar import project_to_image
from ttc.steps.object_groups import (
    MOVE_M,
    NEAREST_FACE_QUANTILE,
    ObjectLidarParams,
    nearest_face,
    object_group,
    object_scan_mask,
    scored_groups,
)

#: Points within this many pixels outside a shrunk box are let in one at a time to see how
#: sure its face is (a 2 cm move is 0.3 px at 45 m, 1.4 px at 10 m).
EDGE_PX = 1.0
#: Points within this many pixels of a shrunk box are the ones a :data:`MOVE_M` move can
#: bring in or out of it (2 cm is 4 px at 3.6 m; nearer objects fill their boxes).
NEAR_PX = 4.0

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
    starts, stops, ok, score = scored_groups(xs, params)
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
    starts, stops, ok, score = scored_groups(xs, params)
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
    score = np.sort(scored_groups(xs, params)[3])
    close = params.support_scale_m > 0 and len(score) > 1
    close = close and score[-2] >= CLOSE_SCORE_SHARE * score[-1]
    unsure = bool(close or not np.all(moved <= params.unsure_m))
    kept = ~np.isnan(faces)
    if not kept.any():
        return float("nan"), True
    w, f, n = counts[kept], faces[kept], counts.sum()
    mean = np.average(f, weights=w)
    return float(np.sqrt((n - 1) / n * np.sum(w * (f - mean) ** 2))), unsure


def moves_face(
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
