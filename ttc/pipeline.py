"""One setting end to end: frames → objects, lidar, keypoints, descriptors, matches → FP.1–FP.4.

:func:`run_setting` takes a :class:`Settings` (one value per axis) and a :class:`FrameRange`
and returns one row per (frame pair, matched box pair); the lead vehicle's row has
``is_lead=True``. The expensive stages (objects, lidar, keypoints, descriptors, matches) go
through a :class:`~ttc.cache.StageCache`; their keys and the chunked order they are produced in
are in :mod:`ttc.stages`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ttc import reasons
from ttc.box_matching import BoxMatchingParams, count_shared_matches, match_boxes
from ttc.cache import Lookup, StageCache
from ttc.camera_ttc import CameraTTCParams, camera_ttc
from ttc.descriptors import check_pair
from ttc.frames import (
    Calibration,
    FrameDataError,
    check_frame_range,
    frame_files,
    frame_indices,
    frame_interval,
    frame_pairs,
    load_calibration,
    pair_interval,
    read_frame_times,
    read_image,
    timestamps_file,
    with_truth,
)
from ttc.fusion import FusionParams, fuse_rows
from ttc.keypoint_filter import KeypointFilterParams, filter_box_matches
from ttc.keypoints import X, Y
from ttc.lidar import LaneCropParams, assign_points_to_boxes, lead_box_of, project_to_image
from ttc.lidar_ttc import LidarTTCParams, lidar_ttc
from ttc.matching import (
    MatcherParams,
    SelectorParams,
    current_keypoints,
    pair_matches,
    uses_descriptors,
)
from ttc.objects import ObjectDetectorParams
from ttc.settings import CACHED_STAGE_NAMES as CACHED_STAGES
from ttc.stages import (  # noqa: F401 (re-exported: the stage table and inputs of a run)

    CHUNK_FRAMES,
    LIBRARY_VERSIONS,
    STAGE_VERSIONS,
    input_files,
    stream,
)

#: Field metadata of a :class:`Settings` field that is a sweep axis.
AXIS = {"axis": True}


@dataclass(frozen=True)
class Settings:
    """One value of every axis of a sweep (each a params dataclass of its stage)."""

    detector: Any = field(metadata=AXIS)
    descriptor: Any = field(metadata=AXIS)
    matcher: MatcherParams = field(default_factory=MatcherParams, metadata=AXIS)
    selector: SelectorParams = field(default_factory=SelectorParams, metadata=AXIS)
    box_matching: BoxMatchingParams = field(default_factory=BoxMatchingParams, metadata=AXIS)
    lidar_ttc: LidarTTCParams = field(default_factory=LidarTTCParams, metadata=AXIS)
    keypoint_filter: KeypointFilterParams = field(
        default_factory=KeypointFilterParams, metadata=AXIS
    )
    camera_ttc: CameraTTCParams = field(default_factory=CameraTTCParams, metadata=AXIS)
    fusion: FusionParams = field(default_factory=FusionParams, metadata=AXIS)
    objects: ObjectDetectorParams = field(default_factory=ObjectDetectorParams, metadata=AXIS)
    lane: LaneCropParams = field(default_factory=LaneCropParams)
    lidar_shrink: float = 0.10

    def axes(self) -> dict[str, str]:
        """The name chosen on every axis, e.g. ``{"detector": "fast", ...}``."""
        return {axis: getattr(self, axis).name for axis in SETTING_AXES}


#: The stage axes of a setting: the fields of :class:`Settings` that pick a variant by name.
SETTING_AXES: tuple[str, ...] = tuple(
    f.name for f in dataclasses.fields(Settings) if f.metadata.get("axis")
)
#: Every axis of a sweep, in the order of the results' columns: the stage axes, then the
#: dataset (the recording and frame range). The one list: configs, runs, metrics, reports.
AXES: tuple[str, ...] = (*SETTING_AXES, "dataset")


@dataclass(frozen=True)
class FrameRange:
    """Frames ``first..last`` (every ``step``-th) of one KITTI-raw recording folder."""

    sequence_dir: Path
    first: int = 0
    last: int = 18
    step: int = 1
    projection: str = "P_rect_02"
    min_scan_points: int = 100_000
    pairing: str = "consecutive"  # or "disjoint": pairs 0→1, 2→3, … (ttc.frames.frame_pairs)

    @property
    def pairs(self) -> list[tuple[int, int]]:
        """The (previous, current) frame pairs of the range."""
        return frame_pairs(self.indices, self.pairing)

    @property
    def indices(self) -> list[int]:
        return frame_indices(self.first, self.last, self.step)

    @property
    def dt(self) -> float:
        """Seconds between two processed frames."""
        return frame_interval(self.step)


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


def _error_row(prev: int, curr: int, dt: float, error: Exception) -> dict[str, Any]:
    """The one row of a frame pair whose input could not be read."""
    row: dict[str, Any] = {
        "prev_frame": prev, "frame": curr, "dt": dt, "scan_points_prev": 0,
        "scan_points_curr": 0, "scan_short": False, "scan_dropped_curr": 0,
        "lane_points_curr": 0, "boxes_prev": 0, "boxes_curr": 0, "keypoints_prev": 0,
        "keypoints_curr": 0, "described_curr": 0, "matches_total": 0,
        **{f"ms_{stage}": 0.0 for stage in ("objects", "lidar", "keypoints", "descriptors",
                                             "matching", "box_matching")},
        **{f"cached_{stage}": False for stage in CACHED_STAGES},
        "prev_box": -1, "curr_box": -1, "is_lead": True, "box_class": -1,
        "box_confidence": np.nan, "box_x": -1, "box_y": -1, "box_w": -1, "box_h": -1,
        **EMPTY_BOX_RESULT, "lidar_reason": reasons.FRAME_ERROR,
        "camera_reason": reasons.FRAME_ERROR, "box_shared_matches": 0, "error": str(error),
    }  # fmt: skip
    return row


def _timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    start = time.perf_counter()
    out = fn()
    return out, 1e3 * (time.perf_counter() - start)


def _pairs(indices: list[int]) -> Iterator[tuple[int, int]]:
    return zip(indices[:-1], indices[1:], strict=True)


def run_setting(
    settings: Settings,
    frames: FrameRange,
    cache: StageCache | None = None,
    calibration: Calibration | None = None,
) -> pd.DataFrame:
    """TTC rows for every consecutive frame pair of ``frames`` under one setting.

    Raises :class:`ttc.descriptors.InvalidCombinationError` before any work for an invalid
    detector × descriptor pair, and :class:`ttc.frames.FrameDataError` before any work for a
    frame range past the recording's last frame or a bad calibration or timestamps file. A
    frame that cannot be read gives its pairs one row each with reason ``frame_error`` and
    the message; every degenerate TTC case is a row with NaN/inf and a reason code. ``dt``
    comes from the recording's timestamps when it has them, else the nominal 10 Hz.
    Frames are processed in chunks of :data:`CHUNK_FRAMES`, so memory does not grow with the
    length of the range.
    """
    check_setting(settings)
    indices, times, calib = check_range(frames, calibration)
    cache = cache if cache is not None else StageCache(None)
    rows: list[dict[str, Any]] = []
    for pairs, per_frame, matches, broken in stream(settings, frames, cache, indices):
        for prev, curr in pairs:
            dt = pair_interval(times, prev, curr, frames.step)
            if (prev, curr) in matches:
                match = matches[(prev, curr)]
                rows.extend(_pair_rows(settings, frames, calib, dt, prev, curr, per_frame, match))
            else:
                rows.append(_error_row(prev, curr, dt, broken.get(curr) or broken[prev]))
    return with_truth(finish_rows(settings, pd.DataFrame.from_records(rows)), frames.sequence_dir)


def check_range(
    frames: FrameRange, calibration: Calibration | None = None
) -> tuple[list[int], np.ndarray | None, Calibration]:
    """(frame indices, frame times in s or None, calibration) of a run over ``frames``, checked
    before any work: at least two frames, none past the recording's last, a timestamp for
    each, a readable calibration (``calibration`` when given). Raises ValueError or
    :class:`ttc.frames.FrameDataError` naming the file."""
    indices = frames.indices
    if len(indices) < 2:
        raise ValueError(f"need at least two frames, got {indices}")
    check_frame_range(frames.sequence_dir, indices)
    times = read_frame_times(frames.sequence_dir)
    if times is not None and indices[-1] >= len(times):
        raise FrameDataError(
            timestamps_file(frames.sequence_dir),
            f"{len(times)} timestamps: none for frame {indices[-1]}",
        )
    return indices, times, calibration or load_calibration(frames.sequence_dir, frames.projection)


def finish_rows(settings: Settings, rows: pd.DataFrame) -> pd.DataFrame:
    """A setting's rows once all its frame pairs are done: the place for work over a whole
    run: the fused TTC over the lead rows (:func:`ttc.fusion.fuse_rows`). :func:`run_setting`
    and the batched execution (:func:`ttc.batch.run_settings`) both end with it, so both give
    the same rows."""
    return fuse_rows(rows, settings.fusion)


def check_setting(settings: Settings) -> None:
    """Raise :class:`ttc.descriptors.InvalidCombinationError` for an invalid (or unavailable)
    detector × descriptor pair; a tracking matcher (KLT) uses no descriptor, so never."""
    if uses_descriptors(settings.matcher):
        check_pair(settings.detector.name, settings.descriptor.name)


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


def pair_detail(
    settings: Settings, frames: FrameRange, prev: int, curr: int, cache: StageCache | None = None
) -> PairDetail:
    """Run one frame pair and keep every intermediate array (for pictures)."""
    check_setting(settings)
    cache = cache if cache is not None else StageCache(None)
    calib = load_calibration(frames.sequence_dir, frames.projection)
    pair = dataclasses.replace(frames, first=prev, last=curr, step=curr - prev)
    check_frame_range(frames.sequence_dir, [prev, curr])
    dt = pair_interval(read_frame_times(frames.sequence_dir), prev, curr, curr - prev)
    _, per_frame, matches, broken = next(stream(settings, pair, cache, [prev, curr]))
    if broken:
        raise next(iter(broken.values()))
    detail: dict[str, Any] = {}
    match = matches[(prev, curr)]
    rows = _pair_rows(settings, pair, calib, dt, prev, curr, per_frame, match, detail)
    empty = np.zeros(0, dtype=np.int64)
    return PairDetail(
        prev=prev,
        curr=curr,
        images={i: read_image(frame_files(frames.sequence_dir, i).image) for i in (prev, curr)},
        objects={i: per_frame["objects"][i].arrays for i in (prev, curr)},
        keypoints={
            prev: per_frame["descriptors"][prev].arrays["keypoints"],
            curr: detail["keypoints_curr"],
        },  # fmt: skip
        matches=detail["matches"],
        box_matches=detail["box_matches"],
        lane_points={i: per_frame["lidar"][i].arrays["points"] for i in (prev, curr)},
        lane_uv=detail["uv"],
        lane_owner=detail["owners"],
        lead_box=detail["lead_box"],
        kept=detail.get("kept", empty),
        removed=detail.get("removed", empty),
        rows=finish_rows(settings, pd.DataFrame.from_records(rows)),
    )


def _pair_rows(
    s: Settings,
    frames: FrameRange,
    calib: Calibration,
    dt: float,
    prev: int,
    curr: int,
    per_frame: dict[str, dict[int, Lookup]],
    match_lookup: Lookup,
    detail: dict[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """FP.1–FP.4 for one frame pair ``dt`` seconds apart: one row per matched box pair
    (lead first).

    ``detail``, when given, receives the intermediate arrays (see :class:`PairDetail`).
    """
    obj = {i: per_frame["objects"][i].arrays for i in (prev, curr)}
    lane = {i: per_frame["lidar"][i].arrays for i in (prev, curr)}
    desc = {i: per_frame["descriptors"][i].arrays for i in (prev, curr)}
    kp_prev = desc[prev]["keypoints"]
    kp_curr = current_keypoints(desc[curr]["keypoints"], match_lookup.arrays)  # KLT: tracked
    xy_prev, xy_curr = kp_prev[:, [X, Y]], kp_curr[:, [X, Y]]

    selected, ms_select = _timed(lambda: pair_matches(match_lookup.arrays, s.selector))

    # FP.1 box matching
    def fp1():
        counts = count_shared_matches(
            xy_prev, xy_curr, selected.prev_idx, selected.curr_idx,
            obj[prev]["roi"], obj[curr]["roi"], s.box_matching.shrink,
        )  # fmt: skip
        return match_boxes(counts, s.box_matching)

    box_matches, ms_fp1 = _timed(fp1)

    # Lead object: the current box holding most lane lidar points.
    def associate():
        uv = {
            i: project_to_image(lane[i]["points"][:, :3], calib.velo_to_image) for i in (prev, curr)
        }
        return uv, {i: assign_points_to_boxes(uv[i], obj[i]["roi"], s.lidar_shrink) for i in uv}

    (uv, owners), ms_assoc = _timed(associate)
    lead_box = lead_box_of(owners[curr], len(obj[curr]["roi"]))

    box_pairs = list(zip(box_matches.prev_box.tolist(), box_matches.curr_box.tolist(), strict=True))
    shared = dict(zip(box_matches.curr_box.tolist(), box_matches.shared.tolist(), strict=True))
    curr_boxes = [c for _, c in box_pairs]
    if lead_box >= 0 and lead_box in curr_boxes:
        box_pairs.sort(key=lambda pc: pc[1] != lead_box)
    else:
        box_pairs.insert(0, (-1, lead_box))  # the lead row is always present

    base = {
        "prev_frame": prev,
        "frame": curr,
        "dt": dt,
        "scan_points_prev": int(lane[prev]["n_scan"]),
        "scan_points_curr": int(lane[curr]["n_scan"]),
        "scan_short": bool(lane[curr]["n_scan"] < frames.min_scan_points),
        "scan_dropped_curr": int(lane[curr]["n_dropped"]),
        "lane_points_curr": int(len(lane[curr]["points"])),
        "boxes_prev": len(obj[prev]["roi"]),
        "boxes_curr": len(obj[curr]["roi"]),
        "keypoints_prev": int(per_frame["keypoints"][prev].arrays["keypoints"].shape[0]),
        "keypoints_curr": int(per_frame["keypoints"][curr].arrays["keypoints"].shape[0]),
        "described_curr": int(kp_curr.shape[0]),
        "matches_total": int(len(selected.prev_idx)),
        "ms_objects": per_frame["objects"][curr].ms,
        "ms_lidar": per_frame["lidar"][curr].ms + ms_assoc,
        "ms_keypoints": per_frame["keypoints"][curr].ms,
        "ms_descriptors": per_frame["descriptors"][curr].ms,
        "ms_matching": match_lookup.ms + ms_select,
        "ms_box_matching": ms_fp1,
    }
    for stage in CACHED_STAGES:
        lookup = match_lookup if stage == "matches" else per_frame[stage][curr]
        base[f"cached_{stage}"] = lookup.cached

    if detail is not None:
        detail.update(matches=selected, box_matches=box_matches, uv=uv, owners=owners,
                      lead_box=lead_box, keypoints_curr=kp_curr)  # fmt: skip
    pair = _PairData(s, dt, prev, curr, obj, lane, owners, xy_prev, xy_curr, selected)
    rows = []
    for prev_box, curr_box in box_pairs:
        row = dict(base)
        row.update(
            _box_row(pair, prev_box, curr_box, lead_box, detail if curr_box == lead_box else None)
        )
        row["box_shared_matches"] = shared.get(curr_box, 0) if prev_box >= 0 else 0
        row["error"] = ""
        rows.append(row)
    return rows


@dataclass(frozen=True)
class _PairData:
    """What FP.2–FP.4 need of one frame pair (built once per pair, shared by its boxes)."""

    s: Settings
    dt: float
    prev: int
    curr: int
    obj: dict[int, dict[str, np.ndarray]]
    lane: dict[int, dict[str, np.ndarray]]
    owners: dict[int, np.ndarray]
    xy_prev: np.ndarray
    xy_curr: np.ndarray
    selected: Any


def _box_row(
    pair: _PairData, prev_box: int, curr_box: int, lead_box: int, detail: dict | None = None
) -> dict[str, Any]:
    """FP.2–FP.4 for one matched box pair (prev_box = −1: the lead box found no match)."""
    s, dt, prev, curr = pair.s, pair.dt, pair.prev, pair.curr
    obj, lane, owners, selected = pair.obj, pair.lane, pair.owners, pair.selected
    xy_prev, xy_curr = pair.xy_prev, pair.xy_curr
    row: dict[str, Any] = {
        "prev_box": prev_box,
        "curr_box": curr_box,
        "is_lead": curr_box == lead_box and curr_box >= 0,
    }
    if curr_box >= 0:
        roi = obj[curr]["roi"][curr_box]
        row.update(
            box_class=int(obj[curr]["class_id"][curr_box]),
            box_confidence=float(obj[curr]["confidence"][curr_box]),
            box_x=int(roi[0]), box_y=int(roi[1]), box_w=int(roi[2]), box_h=int(roi[3]),
        )  # fmt: skip
    else:
        row.update(box_class=-1, box_confidence=np.nan, box_x=-1, box_y=-1, box_w=-1, box_h=-1)

    if prev_box < 0:
        reason = reasons.NO_LEAD_BOX if curr_box < 0 else reasons.NO_BOX_MATCH
        row.update(EMPTY_BOX_RESULT, lidar_reason=reason, camera_reason=reason)
        if curr_box >= 0:
            row["lidar_points_curr"] = int(np.sum(owners[curr] == curr_box))
        return row

    # FP.2 lidar TTC
    pts_prev = lane[prev]["points"][owners[prev] == prev_box][:, :3]
    pts_curr = lane[curr]["points"][owners[curr] == curr_box][:, :3]
    lid, ms_fp2 = _timed(lambda: lidar_ttc(pts_prev, pts_curr, dt, s.lidar_ttc))
    row.update(
        ttc_lidar=lid.ttc, lidar_reason=lid.reason, d_prev=lid.d_prev, d_curr=lid.d_curr,
        lidar_points_prev=len(pts_prev), lidar_points_curr=len(pts_curr),
        lidar_outliers_prev=lid.outliers_prev, lidar_outliers_curr=lid.outliers_curr,
        lidar_closest_prev=float(pts_prev[:, 0].min()) if len(pts_prev) else np.nan,
        lidar_closest_curr=float(pts_curr[:, 0].min()) if len(pts_curr) else np.nan,
        lidar_median_prev=float(np.median(pts_prev[:, 0])) if len(pts_prev) else np.nan,
        lidar_median_curr=float(np.median(pts_curr[:, 0])) if len(pts_curr) else np.nan,
        ms_lidar_ttc=ms_fp2,
    )  # fmt: skip

    # FP.3 keypoint matches of the box, outliers out
    def fp3():
        return filter_box_matches(
            xy_prev, xy_curr, selected.prev_idx, selected.curr_idx,
            obj[curr]["roi"][curr_box], s.box_matching.shrink, s.keypoint_filter,
        )  # fmt: skip

    filt, ms_fp3 = _timed(fp3)
    if detail is not None:
        detail.update(kept=filt.kept, removed=filt.removed)
    kept_prev = xy_prev[selected.prev_idx[filt.kept]]
    kept_curr = xy_curr[selected.curr_idx[filt.kept]]

    # FP.4 camera TTC
    cam, ms_fp4 = _timed(lambda: camera_ttc(kept_prev, kept_curr, dt, s.camera_ttc))
    row.update(
        ttc_camera=cam.ttc, camera_reason=cam.reason, camera_ratio=cam.ratio,
        camera_pairs=cam.n_pairs, matches_in_box=filt.n_in_box, matches_kept=filt.n_kept,
        matches_removed=filt.n_removed, ms_keypoint_filter=ms_fp3, ms_camera_ttc=ms_fp4,
    )  # fmt: skip
    return row
