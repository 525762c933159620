"""Several settings at once, sharing every stage they have in common.

:func:`run_settings` gives the rows :func:`ttc.pipeline.run_setting` gives for each of a list
of settings, but streams each group of settings with the same upstream stages (detector,
descriptor, matcher, objects, lane crop) once, and within a frame pair computes each piece of
FP.1–FP.4 once for all the settings that share its inputs:

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

The numbers are the same as one setting at a time (the same functions on the same arrays);
only the per-stage timing columns differ (a shared piece is timed once and reported in every
row that uses it). A setting that raises gets its exception instead of rows; the others go
on.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pandas as pd

from ttc import reasons
from ttc.box_matching import count_shared_matches, match_boxes
from ttc.cache import Lookup, StageCache
from ttc.camera_ttc import camera_ttc
from ttc.frames import (
    pair_interval,
    with_truth,
)
from ttc.keypoint_filter import filter_box_matches
from ttc.keypoints import X, Y
from ttc.lidar import assign_points_to_boxes, lead_box_of, project_to_image
from ttc.lidar_ttc import lidar_ttc
from ttc.matching import current_keypoints, pair_matches
from ttc.pipeline import (
    CACHED_STAGES,
    EMPTY_BOX_RESULT,
    FrameRange,
    Settings,
    _error_row,
    _timed,
    check_range,
    check_setting,
    finish_rows,
    stream,
)

#: Column of :func:`run_settings`' rows: the index of the setting in the list it was given.
MEMBER = "member"
#: Settings fields that are not upstream of FP.1–FP.4 (they vary within a streamed group).
DOWNSTREAM_FIELDS = ("selector", "box_matching", "lidar_ttc", "keypoint_filter", "camera_ttc")


def params_key(obj: Any) -> str:
    """A hashable, canonical text of a parameter dataclass (its fields as sorted JSON)."""
    return json.dumps(dataclasses.asdict(obj), sort_keys=True, default=str)


def upstream_key(settings: Settings) -> str:
    """What the cached stages of a setting depend on: every field but :data:`DOWNSTREAM_FIELDS`
    (settings with equal keys are streamed once)."""
    fields = {
        f.name: getattr(settings, f.name)
        for f in dataclasses.fields(settings)
        if f.name not in DOWNSTREAM_FIELDS
    }
    return json.dumps(
        {k: dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v for k, v in fields.items()},
        sort_keys=True,
        default=str,
    )


@dataclasses.dataclass(frozen=True)
class MemberKeys:
    """The texts of a setting's downstream parameters (:func:`params_key`), made once."""

    selector: str
    box_matching: str
    lidar_ttc: str
    keypoint_filter: str
    camera_ttc: str


def member_keys(settings: Settings) -> MemberKeys:
    """:class:`MemberKeys` of a setting."""
    return MemberKeys(*(params_key(getattr(settings, f)) for f in DOWNSTREAM_FIELDS))


def run_settings(
    settings: Sequence[Settings],
    frames: FrameRange,
    cache: StageCache | None = None,
    calibration: Any = None,
) -> tuple[pd.DataFrame, dict[int, Exception]]:
    """Rows of every setting (column :data:`MEMBER` = its index in ``settings``) and the
    exception of each setting that raised (invalid detector × descriptor pair, bad frame
    range or calibration: the same exceptions :func:`~ttc.pipeline.run_setting` raises).

    Rows of one setting are in the order ``run_setting`` gives them.
    """
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
        rows = _group_rows(settings, members, frames, cache, indices, times, calib, failed)
        parts.extend(rows)
    return with_truth(_finish(settings, parts, failed), frames.sequence_dir), failed


def _finish(
    settings: Sequence[Settings], parts: list[tuple[int, list[dict]]], failed: dict[int, Exception]
) -> pd.DataFrame:
    """One frame of every member's rows (failed members left out), each member's rows through
    :func:`~ttc.pipeline.finish_rows`. The rows become one frame first (one frame per member
    would cost more than the rows themselves)."""
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
    times: Any,
    calib: Any,
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
                        out[m].append({**_error_row(prev, curr, dt, error), MEMBER: m})
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
        calib: Any,
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
        desc = {i: per_frame["descriptors"][i].arrays for i in (prev, curr)}
        self.kp_curr = current_keypoints(desc[curr]["keypoints"], match.arrays)  # KLT: tracked
        self.xy_prev = desc[prev]["keypoints"][:, [X, Y]]
        self.xy_curr = self.kp_curr[:, [X, Y]]
        self.memo: dict[str, dict] = {
            k: {} for k in ("sel", "fp1", "fp2", "fp3", "fp4", "base", "head")
        }
        self.assoc: tuple | None = None

    def _selected(self, s: Settings, k: MemberKeys) -> tuple[Any, float]:
        arrays = self.match.arrays
        return _memo(
            self.memo["sel"],
            k.selector,
            lambda: pair_matches(arrays, s.selector),
        )

    def _association(self, s: Settings) -> tuple[Any, dict, int]:
        """(uv, owners, lead box) and its ms, once per pair (upstream of every member)."""
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
            self.assoc = (owners, lead_box_of(owners[curr], len(obj[curr]["roi"])), ms)
        return self.assoc

    def _fp1(self, s: Settings, k: MemberKeys, selected: Any) -> tuple[Any, float]:
        prev, curr, obj = self.prev, self.curr, self.obj

        def fp1():
            counts = count_shared_matches(
                self.xy_prev, self.xy_curr, selected.prev_idx, selected.curr_idx,
                obj[prev]["roi"], obj[curr]["roi"], s.box_matching.shrink,
            )  # fmt: skip
            return match_boxes(counts, s.box_matching)

        return _memo(self.memo["fp1"], (k.selector, k.box_matching), fp1)

    def _base(self, k: MemberKeys, selected: Any, ms_select: float, ms_fp1: float, ms_assoc: float):
        """The pair's columns before the box columns (as ``_pair_rows`` builds them)."""
        key = (k.selector, k.box_matching)
        if key in self.memo["base"]:
            return self.memo["base"][key]
        prev, curr, lane, obj, pf = self.prev, self.curr, self.lane, self.obj, self.per_frame
        base = {
            "prev_frame": prev,
            "frame": curr,
            "dt": self.dt,
            "scan_points_prev": int(lane[prev]["n_scan"]),
            "scan_points_curr": int(lane[curr]["n_scan"]),
            "scan_short": bool(lane[curr]["n_scan"] < self.frames.min_scan_points),
            "scan_dropped_curr": int(lane[curr]["n_dropped"]),
            "lane_points_curr": int(len(lane[curr]["points"])),
            "boxes_prev": len(obj[prev]["roi"]),
            "boxes_curr": len(obj[curr]["roi"]),
            "keypoints_prev": int(pf["keypoints"][prev].arrays["keypoints"].shape[0]),
            "keypoints_curr": int(pf["keypoints"][curr].arrays["keypoints"].shape[0]),
            "described_curr": int(self.kp_curr.shape[0]),
            "matches_total": int(len(selected.prev_idx)),
            "ms_objects": pf["objects"][curr].ms,
            "ms_lidar": pf["lidar"][curr].ms + ms_assoc,
            "ms_keypoints": pf["keypoints"][curr].ms,
            "ms_descriptors": pf["descriptors"][curr].ms,
            "ms_matching": self.match.ms + ms_select,
            "ms_box_matching": ms_fp1,
        }
        for stage in CACHED_STAGES:
            lookup = self.match if stage == "matches" else pf[stage][curr]
            base[f"cached_{stage}"] = lookup.cached
        self.memo["base"][key] = base
        return base

    def rows(self, s: Settings, k: MemberKeys, member: int) -> list[dict[str, Any]]:
        """The rows ``_pair_rows`` gives for this pair under setting ``s`` (keys ``k``), each
        with :data:`MEMBER` = ``member``."""
        selected, ms_select = self._selected(s, k)
        box_matches, ms_fp1 = self._fp1(s, k, selected)
        owners, lead_box, ms_assoc = self._association(s)
        box_pairs = list(
            zip(box_matches.prev_box.tolist(), box_matches.curr_box.tolist(), strict=True)
        )
        shared = dict(zip(box_matches.curr_box.tolist(), box_matches.shared.tolist(), strict=True))
        if lead_box >= 0 and lead_box in [c for _, c in box_pairs]:
            box_pairs.sort(key=lambda pc: pc[1] != lead_box)
        else:
            box_pairs.insert(0, (-1, lead_box))
        base = self._base(k, selected, ms_select, ms_fp1, ms_assoc)
        rows = []
        for prev_box, curr_box in box_pairs:
            row = {**base, **self._head(owners, prev_box, curr_box, lead_box)}
            if prev_box >= 0:
                row.update(self._fp2(s, k, owners, prev_box, curr_box))
                row.update(self._fp34(s, k, selected, curr_box))
            row["box_shared_matches"] = shared.get(curr_box, 0) if prev_box >= 0 else 0
            row["error"] = ""
            row[MEMBER] = member
            rows.append(row)
        return rows

    def _head(self, owners: dict, prev_box: int, curr_box: int, lead: int) -> dict[str, Any]:
        """The box columns of ``ttc.pipeline._box_row`` (with its empty FP.2–FP.4 result when
        the box pair has no previous box), once per box pair."""
        key = (prev_box, curr_box, lead)
        if key in self.memo["head"]:
            return self.memo["head"][key]
        curr, obj = self.curr, self.obj
        row: dict[str, Any] = {
            "prev_box": prev_box,
            "curr_box": curr_box,
            "is_lead": curr_box == lead and curr_box >= 0,
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
        self.memo["head"][key] = row
        return row

    def _fp2(
        self, s: Settings, k: MemberKeys, owners: dict, prev_box: int, curr_box: int
    ) -> dict[str, Any]:
        key = (prev_box, curr_box, k.lidar_ttc)
        if key not in self.memo["fp2"]:
            prev, curr, lane = self.prev, self.curr, self.lane
            pts_prev = lane[prev]["points"][owners[prev] == prev_box][:, :3]
            pts_curr = lane[curr]["points"][owners[curr] == curr_box][:, :3]
            dt = self.dt
            lid, ms = _timed(lambda: lidar_ttc(pts_prev, pts_curr, dt, s.lidar_ttc))
            self.memo["fp2"][key] = dict(
                ttc_lidar=lid.ttc, lidar_reason=lid.reason, d_prev=lid.d_prev, d_curr=lid.d_curr,
                lidar_points_prev=len(pts_prev), lidar_points_curr=len(pts_curr),
                lidar_outliers_prev=lid.outliers_prev, lidar_outliers_curr=lid.outliers_curr,
                lidar_closest_prev=float(pts_prev[:, 0].min()) if len(pts_prev) else np.nan,
                lidar_closest_curr=float(pts_curr[:, 0].min()) if len(pts_curr) else np.nan,
                lidar_median_prev=float(np.median(pts_prev[:, 0])) if len(pts_prev) else np.nan,
                lidar_median_curr=float(np.median(pts_curr[:, 0])) if len(pts_curr) else np.nan,
                ms_lidar_ttc=ms,
            )  # fmt: skip
        return self.memo["fp2"][key]

    def _fp34(self, s: Settings, k: MemberKeys, selected: Any, curr_box: int) -> dict[str, Any]:
        fp3_key = (k.selector, curr_box, s.box_matching.shrink, k.keypoint_filter)
        fp4_key = (fp3_key, k.camera_ttc)
        found = self.memo["fp4"].get(fp4_key)
        if found is not None:
            return found
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
        kept_prev = self.xy_prev[selected.prev_idx[filt.kept]]
        kept_curr = self.xy_curr[selected.curr_idx[filt.kept]]
        dt = self.dt
        cam, ms_fp4 = _timed(lambda: camera_ttc(kept_prev, kept_curr, dt, s.camera_ttc))
        self.memo["fp4"][fp4_key] = dict(
            ttc_camera=cam.ttc, camera_reason=cam.reason, camera_ratio=cam.ratio,
            camera_pairs=cam.n_pairs, matches_in_box=filt.n_in_box, matches_kept=filt.n_kept,
            matches_removed=filt.n_removed, ms_keypoint_filter=ms_fp3, ms_camera_ttc=ms_fp4,
        )  # fmt: skip
        return self.memo["fp4"][fp4_key]
