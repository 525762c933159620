"""Reference TTC of every tracked object, from its own lidar points.

The lead's yardstick (:mod:`ttc.evaluation.reference`) run on every vehicle: each frame's
boxes carry the forward distance of their object's nearest face
(:mod:`ttc.steps.object_lidar`); boxes are linked frame to frame without keypoints
(:func:`link_boxes`: the most overlapping box, Hungarian on IoU), chained into tracks
(:func:`ttc.steps.tracks.chain_tracks`, the same ids a setting's FP.1 chain gets where it
agrees), and each track's distances are smoothed on their own (the lead's Savitzky–Golay
smoothing, its residual noise and its per-pair standard deviation). TTC here is the time to
reach the object's plane: forward distance over closing speed, defined for every object.

A box cut by the image's left or right edge shows only part of its object: the nearest face
may be out of view (a parked car being passed), so its distance is not used (NaN, not
interpolated across). Each track gets a role (:func:`track_role`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from ttc.evaluation.difficulty import box_difficulty
from ttc.evaluation.reference import MIN_CLOSING_SPEED_MPS
from ttc.evaluation.track_ends import TRACK_COLUMNS, recording_noise, track_reference
from ttc.steps.tracks import chain_tracks

#: Least IoU (0–1) of two boxes of consecutive frames that are one object: a parked car
#: passed at 10.7 m/s grows by ≤ 10 % a frame and keeps IoU ≥ 0.6 with its previous box.
MIN_IOU = 0.3
#: Roles of a track, in the order of the report.
ROLES: tuple[str, ...] = (
    "lead", "same_direction", "static", "oncoming", "receding", "closing", "unknown"
)  # fmt: skip
#: A track is ``static`` when its closing speed is within this of the ego's (m/s), or this
#: fraction of the ego speed, whichever is larger.
STATIC_TOLERANCE_MPS = 1.0
STATIC_TOLERANCE_FRACTION = 0.10
#: Closing speed (m/s) below which a track is ``receding`` (its distance grows).
RECEDING_MPS = -0.5
#: Pixels from the image's left or right edge within which a box counts as cut by it (YOLO's
#: clipped boxes end 1–3 px inside the image).
EDGE_PX = 4
#: The columns of ``reference_objects.csv``, in order.
REFERENCE_OBJECT_COLUMNS: tuple[str, ...] = (
    "recording", "frame", "track_id", "class", "role", "box_x", "box_y", "box_w", "box_h",
    "distance_m", "distance_sd_m", "closing_speed_mps", "ttc_ref_s", "ttc_ref_sd_s", "fit",
    "difficulty", "occluded_share",
)  # fmt: skip


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(P, C) intersection over union of boxes ``a`` (P × 4) and ``b`` (C × 4: x, y, w, h px)."""
    a, b = np.asarray(a, dtype=float).reshape(-1, 4), np.asarray(b, dtype=float).reshape(-1, 4)
    lo = np.maximum(a[:, None, :2], b[None, :, :2])
    hi = np.minimum(a[:, None, :2] + a[:, None, 2:], b[None, :, :2] + b[None, :, 2:])
    inter = np.prod(np.clip(hi - lo, 0, None), axis=2)
    union = (a[:, 2] * a[:, 3])[:, None] + (b[:, 2] * b[:, 3])[None, :] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def link_boxes(
    prev: np.ndarray, curr: np.ndarray, min_iou: float = MIN_IOU
) -> tuple[np.ndarray, np.ndarray]:
    """``(prev_idx, curr_idx)``: the one-to-one pairing of boxes ``prev`` (P × 4) and ``curr``
    (C × 4, px) with the largest total IoU, pairs below ``min_iou`` dropped."""
    iou = box_iou(prev, curr)
    if not iou.size:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    p, c = linear_sum_assignment(iou, maximize=True)
    keep = iou[p, c] >= min_iou
    return p[keep].astype(np.int64), c[keep].astype(np.int64)


def reference_tracks(boxes: pd.DataFrame) -> pd.Series:
    """Track id of every box (``frame``, ``box``, ``box_x`` … ``box_h`` columns; consecutive
    frames linked by :func:`link_boxes`), as a Series aligned with ``boxes``."""
    frames = sorted(boxes["frame"].unique())
    by_frame = {f: g.sort_values("box") for f, g in boxes.groupby("frame")}
    cols = ["box_x", "box_y", "box_w", "box_h"]
    pf, f_, pb, cb = [], [], [], []
    for prev, curr in zip([None, *frames[:-1]], frames, strict=True):  # the first: no previous
        b = by_frame[curr]
        matched = np.full(len(b), -1)
        if prev is not None and curr == prev + 1:
            a = by_frame[prev]
            p, c = link_boxes(a[cols].to_numpy(), b[cols].to_numpy())
            matched[c] = a["box"].to_numpy()[p]
        pf += [curr - 1] * len(b)
        f_ += [curr] * len(b)
        pb += matched.tolist()
        cb += b["box"].tolist()
    ids = chain_tracks(np.array(pf), np.array(f_), np.array(pb), np.array(cb))
    key = dict(zip(zip(f_, cb, strict=True), ids.tolist(), strict=True))
    return pd.Series([key[(f, b)] for f, b in zip(boxes["frame"], boxes["box"], strict=True)],
                     index=boxes.index, dtype=np.int64)  # fmt: skip


def track_role(closing_mps: float, ego_mps: float, is_lead: bool) -> str:
    """Role of a track from its median closing speed and the ego's median speed (m/s; NaN:
    unknown): ``lead`` (the ego lane's lead vehicle), ``static`` (closing at the ego's speed),
    ``oncoming`` (faster), ``receding`` (distance grows), ``same_direction`` (another lane,
    closing slower than the ego drives), and ``closing`` where the ego speed is unknown and
    the object closes (static or slower: the data cannot tell); ``unknown`` without two
    consecutive measured distances."""
    if is_lead:
        return "lead"
    if not np.isfinite(closing_mps):
        return "unknown"
    if closing_mps < RECEDING_MPS:
        return "receding"
    if not np.isfinite(ego_mps):
        return "closing" if closing_mps > MIN_CLOSING_SPEED_MPS else "same_direction"
    tolerance = max(STATIC_TOLERANCE_MPS, STATIC_TOLERANCE_FRACTION * abs(ego_mps))
    if abs(closing_mps - ego_mps) <= tolerance:
        return "static"
    return "oncoming" if closing_mps > ego_mps else "same_direction"


def median_closing_speed(frames: np.ndarray, distances: np.ndarray, times: np.ndarray) -> float:
    """Median closing speed (m/s) of a track from its distances (m, NaN: not measured) at
    ``frames`` (ascending), over the pairs of consecutive frames: robust to a few jumps (a box
    that briefly holds another car) that bend a smoothed curve; NaN without two consecutive
    measurements. ``times``: seconds of every frame (index = frame)."""
    d, f = np.asarray(distances, dtype=float), np.asarray(frames)
    consecutive = np.diff(f) == 1
    step = np.diff(times[f]) if len(f) > 1 else np.zeros(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        speed = (d[:-1] - d[1:]) / step
    speed = speed[consecutive & np.isfinite(speed)]
    return float(np.median(speed)) if len(speed) else float("nan")


#: A measured distance further than this (m) from the track's straight line, and than
#: :data:`JUMP_MADS` robust standard deviations, is a jump (the box briefly held another car).
JUMP_MIN_M = 0.5
JUMP_MADS = 3.0


def drop_jumps(track: pd.DataFrame, times: np.ndarray) -> np.ndarray:
    """A track's usable distances (``distance_m``, m, NaN kept) with jumps set to NaN: the
    residuals from the line of its median two-frame closing speed (:func:`median_closing_speed`)
    beyond ``max(JUMP_MIN_M, JUMP_MADS · 1.4826 · MAD)``. The smoothing then interpolates
    those frames instead of bending through them."""
    d, frames = track["distance_m"].to_numpy(dtype=float), track["frame"].to_numpy()
    speed = median_closing_speed(frames, d, times)
    if not np.isfinite(speed) or np.isfinite(d).sum() < 4:
        return d
    t = times[frames]
    line = d + speed * t
    resid = line - np.nanmedian(line)
    mad = np.nanmedian(np.abs(resid - np.nanmedian(resid)))
    limit = max(JUMP_MIN_M, JUMP_MADS * 1.4826 * mad)
    return np.where(np.abs(resid) > limit, np.nan, d)


def object_reference(
    boxes: pd.DataFrame,
    times: np.ndarray,
    image_width: int,
    ego_speed: np.ndarray | None = None,
    image_height: int | None = None,
    track_ends: bool = True,
) -> pd.DataFrame:
    """Reference of every tracked object.

    ``boxes``: one row per box and frame: ``frame``, ``box`` (index in its frame), ``class``
    (name), ``box_x``, ``box_y``, ``box_w``, ``box_h`` (px), ``distance_m`` (nearest face, m;
    NaN: no object points), ``is_lead`` (the ego lane's lead box). ``times``: seconds of every
    frame (index = frame); ``image_width`` and ``image_height`` (px; height None: a box is
    truncated by the left and right borders only); ``ego_speed``: m/s per frame (index =
    frame), None when unknown. ``track_ends``: False gives the smoothing's reference only
    (no one-sided end fits, no noise borrowed from other tracks: the reference before
    :mod:`ttc.evaluation.track_ends`).

    Returns one row per box: the input columns, ``track_id``, ``role``, ``edge_cut`` (box at
    the image's left/right edge: its distance unused), ``distance_raw_m`` (the measured
    nearest face), ``distance_m`` (smoothed, m), ``distance_sd_m``, ``closing_speed_mps``
    (mean over the pair ending at the frame), ``ratio_ref`` (the pair's distance ratio
    ``D(k−1) / D(k)``), ``ttc_ref_s`` (s; +inf when not closing),
    ``ttc_ref_sd_s`` and ``judgeable`` (as the lead's reference), ``jump`` (its measured
    distance left the track's line: not used), ``noise_sd_m`` (the
    distance noise its standard deviations come from), ``fit``
    (:data:`ttc.evaluation.track_ends.FITS`) and the box's KITTI level
    (:func:`ttc.evaluation.difficulty.box_difficulty`: ``truncated``, ``occluded_share``,
    ``occlusion``, ``difficulty``; the nearer box by its measured distance, else its
    reference distance).
    """
    boxes = boxes.reset_index(drop=True).copy()
    boxes["track_id"] = reference_tracks(boxes) if len(boxes) else pd.Series(dtype=np.int64)
    right = boxes["box_x"] + boxes["box_w"]
    boxes["edge_cut"] = (boxes["box_x"] <= EDGE_PX) | (right >= image_width - EDGE_PX)
    boxes["distance_raw_m"] = boxes["distance_m"].astype(float)
    refs, closing = _references(boxes, np.asarray(times, dtype=float), track_ends)
    out = boxes.drop(columns="distance_m").merge(refs, on=["frame", "track_id"], how="left")
    out = out.rename(columns={"distance_smooth_m": "distance_m"})
    out["judgeable"] = out["judgeable"].fillna(False).astype(bool)
    out["fit"] = out["fit"].fillna("")
    out["jump"] = out["jump"].fillna(False).astype(bool)
    ego = None if ego_speed is None else np.asarray(ego_speed, dtype=float)
    roles = {}
    for tid, track in out.groupby("track_id"):
        frames = track["frame"].to_numpy()
        v = ego[frames[frames < len(ego)]] if ego is not None else np.array([])
        ego_mps = float(np.nanmedian(v)) if np.isfinite(v).any() else float("nan")
        roles[tid] = track_role(closing[tid], ego_mps, bool(track["is_lead"].mean() > 0.5))
    out["role"] = out["track_id"].map(roles)
    nearer = out.assign(by=out["distance_raw_m"].fillna(out["distance_m"]))
    out = out.join(box_difficulty(nearer, (image_width, image_height), distance="by"))
    return out.sort_values(["frame", "box"]).reset_index(drop=True)


def _references(
    boxes: pd.DataFrame, times: np.ndarray, track_ends: bool
) -> tuple[pd.DataFrame, dict[int, float]]:
    """Every track's reference (:func:`ttc.evaluation.track_ends.track_reference` of its
    usable distances: not cut by the border, jumps dropped), one row per ``frame`` and
    ``track_id``, and each track's median closing speed (m/s) by track id. Neither a box cut
    by the border nor one whose distance was a jump gets an extrapolated distance: inside a
    track the frames on both sides say the object stayed on its line (a jump there is
    interpolated), beyond its last measurement nothing does (the box may have passed to
    another object, or the nearest face out of view). Tracks without
    their own noise estimate are done again with the recording's (:func:`recording_noise`)."""
    usable = boxes["distance_raw_m"].where(~boxes["edge_cut"])
    inputs, closing, jumps = {}, {}, {}
    for tid, track in boxes.assign(distance_m=usable).groupby("track_id", sort=True):
        track = track.sort_values("frame")
        closing[tid] = median_closing_speed(track["frame"], track["distance_m"], times)
        kept = drop_jumps(track, times)
        jump = track["distance_m"].notna().to_numpy() & np.isnan(kept)
        inputs[tid] = (track["frame"].to_numpy(), kept, times,
                       ~track["edge_cut"].to_numpy(dtype=bool) & ~jump)  # fmt: skip
        jumps[tid] = jump
    parts = {tid: track_reference(*args, ends=track_ends) for tid, args in inputs.items()}
    if track_ends:
        own = [p["noise_sd_m"].iloc[0] for p in parts.values() if (p["fit"] == "savgol").any()]
        noise = recording_noise(np.array(own, dtype=float))
        for tid, part in parts.items():
            if not (part["fit"] == "savgol").any() and (part["fit"] != "").any():
                parts[tid] = track_reference(*inputs[tid], noise_m=noise)
    columns = ["frame", "track_id", *TRACK_COLUMNS, "jump"]
    if not parts:
        return pd.DataFrame(columns=columns), closing
    refs = pd.concat([p.assign(track_id=int(tid), jump=jumps[tid]) for tid, p in parts.items()])
    return refs[columns], closing
