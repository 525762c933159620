"""The one FP.1–FP.4 runner: one setting is a batch of one.

:func:`run_settings` runs a list of settings over a :class:`~ttc.settings.FrameRange`. Each
group of settings with the same upstream stages (objects, detector, descriptor, matcher, lane
crop: every axis but the FP.1–FP.4 steps and the fusion) is streamed once through the stage
cache (:func:`ttc.stages.stream`), and within a frame pair each piece of FP.1–FP.4 is computed
once for all the settings that share its inputs:

=================  ==========================================================
piece              shared by the settings with the same
=================  ==========================================================
selection          selector
lidar association  (the group: lane points, boxes and shrink are upstream)
FP.1               selector, box matching
FP.2               box pair, lidar estimator
FP.3               selector, box, box-matching shrink, keypoint filter
FP.4               the FP.3 result, camera estimator
=================  ==========================================================

A shared piece is timed once and reported in every row that uses it. A setting that raises
gets its exception instead of rows; the others go on. :func:`run_setting` (one setting,
raising its exception) and :func:`pair_detail` (one frame pair with its intermediate
arrays) are the same path. Rows are built by :mod:`ttc.rows`.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pandas as pd

from ttc.box_matching import count_shared_matches, match_boxes
from ttc.cache import Lookup, StageCache
from ttc.camera_ttc import camera_ttc
from ttc.descriptors import check_pair
from ttc.frames import (
    Calibration,
    FrameDataError,
    check_frame_range,
    frame_files,
    load_calibration,
    pair_interval,
    read_frame_times,
    read_image,
    timestamps_file,
    with_truth,
)
from ttc.fusion import fuse_rows
from ttc.keypoint_filter import filter_box_matches
from ttc.keypoints import X, Y
from ttc.lidar import assign_points_to_boxes, lead_box_of, project_to_image
from ttc.lidar_ttc import lidar_ttc
from ttc.matching import current_keypoints, pair_matches, uses_descriptors
from ttc.rows import (
    PairDetail,
    box_head,
    camera_columns,
    error_row,
    lidar_columns,
    pair_columns,
)
from ttc.settings import CACHED_STAGE_NAMES, FrameRange, Settings, axes_with_role
from ttc.stages import stream

#: Column of :func:`run_settings`' rows: the index of the setting in the list it was given.
MEMBER = "member"
#: Axes computed per pair from the cached stages: they vary within a streamed group.
STEP_AXES = axes_with_role("step")
#: Axes downstream of the cached stages (the steps and the fusion over a run).
DOWNSTREAM_AXES = axes_with_role("step", "fusion")


def params_key(obj: Any) -> str:
    """A hashable, canonical text of a parameter dataclass (its fields as sorted JSON)."""
    return json.dumps(dataclasses.asdict(obj), sort_keys=True, default=str)


def upstream_key(settings: Settings) -> str:
    """What the cached stages of a setting depend on: every field but
    :data:`DOWNSTREAM_AXES` (settings with equal keys are streamed once)."""
    fields = {
        f.name: getattr(settings, f.name)
        for f in dataclasses.fields(settings)
        if f.name not in DOWNSTREAM_AXES
    }
    return json.dumps(
        {k: dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v for k, v in fields.items()},
        sort_keys=True,
        default=str,
    )


def member_keys(settings: Settings) -> dict[str, str]:
    """:func:`params_key` of each of a setting's :data:`STEP_AXES`, made once."""
    return {axis: params_key(getattr(settings, axis)) for axis in STEP_AXES}


def check_setting(settings: Settings) -> None:
    """Raise :class:`ttc.descriptors.InvalidCombinationError` for an invalid (or unavailable)
    detector × descriptor pair; a tracking matcher (KLT) uses no descriptor, so never."""
    if uses_descriptors(settings.matcher):
        check_pair(settings.detector.name, settings.descriptor.name)


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
    """A setting's rows once all its frame pairs are done: the work over a whole run, the
    fused TTC over the lead rows (:func:`ttc.fusion.fuse_rows`)."""
    return fuse_rows(rows, settings.fusion)


def run_setting(
    settings: Settings,
    frames: FrameRange,
    cache: StageCache | None = None,
    calibration: Calibration | None = None,
) -> pd.DataFrame:
    """TTC rows for every frame pair of ``frames`` under one setting: :func:`run_settings`
    of one, raising the setting's exception (an invalid detector × descriptor pair, a frame
    range past the recording's last frame, a bad calibration or timestamps file: before any
    work). A frame that cannot be read gives its pairs one row each with reason
    ``frame_error``; every degenerate TTC case is a row with NaN/inf and a reason code."""
    rows, failed = run_settings([settings], frames, cache, calibration)
    if failed:
        raise failed[0]
    return rows.drop(columns=MEMBER)


def run_settings(
    settings: Sequence[Settings],
    frames: FrameRange,
    cache: StageCache | None = None,
    calibration: Calibration | None = None,
) -> tuple[pd.DataFrame, dict[int, Exception]]:
    """Rows of every setting (column :data:`MEMBER` = its index in ``settings``; one row per
    frame pair and matched box pair, the lead's first) and the exception of each setting that
    raised. ``dt`` comes from the recording's timestamps when it has them, else the nominal
    10 Hz. Frames are streamed in chunks (:data:`ttc.stages.CHUNK_FRAMES`), so memory does
    not grow with the length of the range."""
    failed: dict[int, Exception] = {}
    valid = []
    for i, s in enumerate(settings):
        try:
            check_setting(s)
            valid.append(i)
        except Exception as exc:
            failed[i] = exc
    if not valid:
        return pd.DataFrame(), failed
    try:
        indices, times, calib = check_range(frames, calibration)
    except Exception as exc:  # the same for every setting
        return pd.DataFrame(), {**failed, **dict.fromkeys(valid, exc)}
    cache = cache if cache is not None else StageCache(None)
    groups: dict[str, list[int]] = {}
    for i in valid:
        groups.setdefault(upstream_key(settings[i]), []).append(i)
    parts = []
    for members in groups.values():
        parts.extend(_group_rows(settings, members, frames, cache, indices, times, calib, failed))
    return with_truth(_finish(settings, parts, failed), frames.sequence_dir), failed


def pair_detail(
    settings: Settings, frames: FrameRange, prev: int, curr: int, cache: StageCache | None = None
) -> PairDetail:
    """Run one frame pair ``prev`` → ``curr`` and keep every intermediate array (for
    pictures and explanations); raises the pair's :class:`ttc.frames.FrameDataError`."""
    check_setting(settings)
    cache = cache if cache is not None else StageCache(None)
    calib = load_calibration(frames.sequence_dir, frames.projection)
    pair = dataclasses.replace(frames, first=prev, last=curr, step=curr - prev)
    check_frame_range(frames.sequence_dir, [prev, curr])
    dt = pair_interval(read_frame_times(frames.sequence_dir), prev, curr, curr - prev)
    _, per_frame, matches, broken = next(stream(settings, pair, cache, [prev, curr]))
    if broken:
        raise next(iter(broken.values()))
    shared = _SharedPair(pair, calib, dt, prev, curr, per_frame, matches[(prev, curr)])
    detail: dict[str, Any] = {}
    rows = pd.DataFrame.from_records(shared.rows(settings, member_keys(settings), 0, detail))
    empty = np.zeros(0, dtype=np.int64)
    return PairDetail(
        prev=prev,
        curr=curr,
        images={i: read_image(frame_files(frames.sequence_dir, i).image) for i in (prev, curr)},
        objects=shared.obj,
        keypoints={prev: shared.desc_prev["keypoints"], curr: shared.kp_curr},
        matches=detail["matches"],
        box_matches=detail["box_matches"],
        lane_points={i: shared.lane[i]["points"] for i in (prev, curr)},
        lane_uv=detail["uv"],
        lane_owner=detail["owners"],
        lead_box=detail["lead_box"],
        kept=detail.get("kept", empty),
        removed=detail.get("removed", empty),
        rows=finish_rows(settings, rows.drop(columns=MEMBER)),
    )


def _finish(
    settings: Sequence[Settings], parts: list[tuple[int, list[dict]]], failed: dict[int, Exception]
) -> pd.DataFrame:
    """One frame of every member's rows (failed members left out), each member's rows through
    :func:`finish_rows`. The rows become one frame first (one frame per member would cost
    more than the rows themselves)."""
    records = [row for member, rows in parts if member not in failed for row in rows]
    if not records:
        return pd.DataFrame()
    every = pd.DataFrame.from_records(records)
    out = []
    for member, rows in every.groupby(MEMBER, sort=False):
        try:
            out.append(finish_rows(settings[member], rows))
        except Exception as exc:  # a setting that raises costs only itself
            failed[member] = exc
    return pd.concat(out, ignore_index=True) if out else pd.DataFrame()


def _group_rows(
    settings: Sequence[Settings],
    members: list[int],
    frames: FrameRange,
    cache: StageCache,
    indices: list[int],
    times: np.ndarray | None,
    calib: Calibration,
    failed: dict[int, Exception],
) -> list[tuple[int, list[dict]]]:
    """Rows of the members of one upstream group: ``[(member, rows)]``."""
    out: dict[int, list[dict]] = {m: [] for m in members}
    keys = {m: member_keys(settings[m]) for m in members}
    first = settings[members[0]]
    try:
        for pairs, per_frame, matches, broken in stream(first, frames, cache, indices):
            for prev, curr in pairs:
                dt = pair_interval(times, prev, curr, frames.step)
                if (prev, curr) not in matches:
                    error = broken.get(curr) or broken[prev]
                    for m in members:
                        out[m].append({**error_row(prev, curr, dt, error), MEMBER: m})
                    continue
                shared = _SharedPair(
                    frames, calib, dt, prev, curr, per_frame, matches[(prev, curr)]
                )
                for m in members:
                    if m in failed:
                        continue
                    try:
                        out[m].extend(shared.rows(settings[m], keys[m], m))
                    except Exception as exc:  # a setting that raises costs only itself
                        failed[m] = exc
    except Exception as exc:  # the group's stages raised: every member fails with it
        for m in members:
            failed.setdefault(m, exc)
    return list(out.items())


def _timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    """``(fn(), ms)``."""
    start = time.perf_counter()
    out = fn()
    return out, 1e3 * (time.perf_counter() - start)


def _memo(store: dict, key: Any, fn: Callable[[], Any]) -> tuple[Any, float]:
    """``(fn(), ms)`` computed once per ``key`` (later calls get the first's result and time)."""
    if key not in store:
        store[key] = _timed(fn)
    return store[key]


class _SharedPair:
    """One frame pair of a group: the arrays every member reads and the FP.1–FP.4 pieces
    computed so far, keyed by the parameters they depend on (see the module docstring)."""

    def __init__(
        self,
        frames: FrameRange,
        calib: Calibration,
        dt: float,
        prev: int,
        curr: int,
        per_frame: dict[str, dict[int, Lookup]],
        match: Lookup,
    ) -> None:
        self.frames, self.calib, self.dt, self.prev, self.curr = frames, calib, dt, prev, curr
        self.per_frame, self.match = per_frame, match
        self.obj = {i: per_frame["objects"][i].arrays for i in (prev, curr)}
        self.lane = {i: per_frame["lidar"][i].arrays for i in (prev, curr)}
        self.desc_prev = per_frame["descriptors"][prev].arrays
        desc_curr = per_frame["descriptors"][curr].arrays
        self.kp_curr = current_keypoints(desc_curr["keypoints"], match.arrays)  # KLT: tracked
        self.xy_prev = self.desc_prev["keypoints"][:, [X, Y]]
        self.xy_curr = self.kp_curr[:, [X, Y]]
        self.memo: dict[str, dict] = {k: {} for k in ("sel", "fp1", "fp2", "fp3", "fp4", "base")}
        self.assoc: tuple | None = None

    def rows(
        self, s: Settings, k: dict[str, str], member: int, detail: dict | None = None
    ) -> list[dict[str, Any]]:
        """The rows of this pair under setting ``s`` (step keys ``k``), lead box first, each
        with :data:`MEMBER` = ``member``. ``detail``, when given, receives the intermediate
        arrays (see :class:`~ttc.rows.PairDetail`)."""
        selected, ms_select = _memo(
            self.memo["sel"], k["selector"], lambda: pair_matches(self.match.arrays, s.selector)
        )
        box_matches, ms_fp1 = self._fp1(s, k, selected)
        uv, owners, lead_box, ms_assoc = self._association(s)
        box_pairs = list(
            zip(box_matches.prev_box.tolist(), box_matches.curr_box.tolist(), strict=True)
        )
        shared = dict(zip(box_matches.curr_box.tolist(), box_matches.shared.tolist(), strict=True))
        if lead_box >= 0 and lead_box in [c for _, c in box_pairs]:
            box_pairs.sort(key=lambda pc: pc[1] != lead_box)
        else:
            box_pairs.insert(0, (-1, lead_box))  # the lead row is always present
        base = self._base(k, selected, ms_select, ms_fp1, ms_assoc)
        rows = []
        for prev_box, curr_box in box_pairs:
            row = {**base, **box_head(self.obj[self.curr], owners[self.curr], prev_box,
                                      curr_box, lead_box)}  # fmt: skip
            if prev_box >= 0:
                row.update(self._fp2(s, k, owners, prev_box, curr_box))
                row.update(self._fp34(s, k, selected, curr_box, detail, curr_box == lead_box))
            row["box_shared_matches"] = shared.get(curr_box, 0) if prev_box >= 0 else 0
            row["error"] = ""
            row[MEMBER] = member
            rows.append(row)
        if detail is not None:
            detail.update(matches=selected, box_matches=box_matches, uv=uv, owners=owners,
                          lead_box=lead_box)  # fmt: skip
        return rows

    def _association(self, s: Settings) -> tuple[dict, dict, int, float]:
        """(lane points' pixels, their owner box, lead box, ms) per frame, once per pair (its
        inputs are upstream of every member). The lead is the current box holding most lane
        lidar points."""
        if self.assoc is None:
            prev, curr, lane, obj = self.prev, self.curr, self.lane, self.obj

            def associate():
                uv = {
                    i: project_to_image(lane[i]["points"][:, :3], self.calib.velo_to_image)
                    for i in (prev, curr)
                }
                owners = {
                    i: assign_points_to_boxes(uv[i], obj[i]["roi"], s.lidar_shrink) for i in uv
                }
                return uv, owners

            (uv, owners), ms = _timed(associate)
            self.assoc = (uv, owners, lead_box_of(owners[curr], len(obj[curr]["roi"])), ms)
        return self.assoc

    def _fp1(self, s: Settings, k: dict[str, str], selected: Any) -> tuple[Any, float]:
        prev, curr, obj = self.prev, self.curr, self.obj

        def fp1():
            counts = count_shared_matches(
                self.xy_prev, self.xy_curr, selected.prev_idx, selected.curr_idx,
                obj[prev]["roi"], obj[curr]["roi"], s.box_matching.shrink,
            )  # fmt: skip
            return match_boxes(counts, s.box_matching)

        return _memo(self.memo["fp1"], (k["selector"], k["box_matching"]), fp1)

    def _base(
        self, k: dict[str, str], selected: Any, ms_select: float, ms_fp1: float, ms_assoc: float
    ) -> dict[str, Any]:
        """The pair's columns (:func:`ttc.rows.pair_columns`), once per selection and FP.1."""
        key = (k["selector"], k["box_matching"])
        if key not in self.memo["base"]:
            prev, curr, pf = self.prev, self.curr, self.per_frame
            counts = {
                "keypoints_prev": pf["keypoints"][prev].arrays["keypoints"].shape[0],
                "keypoints_curr": pf["keypoints"][curr].arrays["keypoints"].shape[0],
                "described_curr": self.kp_curr.shape[0],
                "matches_total": len(selected.prev_idx),
            }
            ms = {
                "objects": pf["objects"][curr].ms,
                "lidar": pf["lidar"][curr].ms + ms_assoc,
                "keypoints": pf["keypoints"][curr].ms,
                "descriptors": pf["descriptors"][curr].ms,
                "matching": self.match.ms + ms_select,
                "box_matching": ms_fp1,
            }
            cached = {
                stage: (self.match if stage == "matches" else pf[stage][curr]).cached
                for stage in CACHED_STAGE_NAMES
            }
            boxes = {i: len(self.obj[i]["roi"]) for i in (prev, curr)}
            self.memo["base"][key] = pair_columns(
                prev, curr, self.dt, self.lane, boxes, counts, ms, cached,
                self.frames.min_scan_points,
            )  # fmt: skip
        return self.memo["base"][key]

    def _fp2(
        self, s: Settings, k: dict[str, str], owners: dict, prev_box: int, curr_box: int
    ) -> dict[str, Any]:
        key = (prev_box, curr_box, k["lidar_ttc"])
        if key not in self.memo["fp2"]:
            pts_prev = self.lane[self.prev]["points"][owners[self.prev] == prev_box][:, :3]
            pts_curr = self.lane[self.curr]["points"][owners[self.curr] == curr_box][:, :3]
            dt = self.dt
            lid, ms = _timed(lambda: lidar_ttc(pts_prev, pts_curr, dt, s.lidar_ttc))
            self.memo["fp2"][key] = lidar_columns(lid, pts_prev, pts_curr, ms)
        return self.memo["fp2"][key]

    def _fp34(
        self,
        s: Settings,
        k: dict[str, str],
        selected: Any,
        curr_box: int,
        detail: dict | None = None,
        is_lead: bool = False,
    ) -> dict[str, Any]:
        fp3_key = (k["selector"], curr_box, s.box_matching.shrink, k["keypoint_filter"])
        if fp3_key not in self.memo["fp3"]:
            roi = self.obj[self.curr]["roi"][curr_box]
            self.memo["fp3"][fp3_key] = _timed(
                lambda: filter_box_matches(
                    self.xy_prev,
                    self.xy_curr,
                    selected.prev_idx,
                    selected.curr_idx,
                    roi,
                    s.box_matching.shrink,
                    s.keypoint_filter,
                )  # fmt: skip
            )
        filt, ms_fp3 = self.memo["fp3"][fp3_key]
        if detail is not None and is_lead:
            detail.update(kept=filt.kept, removed=filt.removed)
        fp4_key = (fp3_key, k["camera_ttc"])
        if fp4_key not in self.memo["fp4"]:
            kept_prev = self.xy_prev[selected.prev_idx[filt.kept]]
            kept_curr = self.xy_curr[selected.curr_idx[filt.kept]]
            dt = self.dt
            cam, ms_fp4 = _timed(lambda: camera_ttc(kept_prev, kept_curr, dt, s.camera_ttc))
            self.memo["fp4"][fp4_key] = camera_columns(cam, filt, ms_fp3, ms_fp4)
        return self.memo["fp4"][fp4_key]
