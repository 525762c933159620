"""FP.1–FP.4 of one frame pair for every setting of a streamed group, each piece computed once.

:class:`PairSteps` holds the arrays of one frame pair (objects, lane points, keypoints, the
matcher's candidates) that every setting of a group reads, and computes each piece of
FP.1–FP.4 once for all the settings that share its inputs (the table in
:mod:`ttc.engine.runner`). Each row is kept as the parts it shares with other rows
(:class:`ttc.row_parts.RowParts`); their columns are built by :mod:`ttc.rows`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ttc.engine.cache import Arrays, Lookup, StageCache
from ttc.features.keypoints import X, Y
from ttc.features.matching import current_keypoints, pair_matches
from ttc.io.calibration import Calibration
from ttc.row_parts import RowBlock, RowParts
from ttc.rows import (
    box_columns,
    camera_columns,
    lidar_columns,
    object_columns,
    pair_columns,
    unmatched_columns,
)
from ttc.settings import CACHED_STAGE_NAMES, FrameRange, Settings
from ttc.steps.box_matching import count_shared_matches, match_boxes
from ttc.steps.camera_ttc import camera_ttc, pair_ratios, ratio_source
from ttc.steps.keypoint_filter import filter_box_matches
from ttc.steps.lidar import LeadAssociation, associate_lead
from ttc.steps.lidar_ttc import lidar_ttc
from ttc.steps.object_lidar import ObjectAssociation, associate_objects


@dataclass(frozen=True)
class FrameLidar:
    """One frame's lidar association: the ego lane's (``lead``: its lead box and the lane
    points' owners) and every box's own points (``objects``)."""

    lead: LeadAssociation
    objects: ObjectAssociation

    def arrays(self) -> Arrays:
        """Its arrays by name (what :meth:`from_arrays` reads back)."""
        o = self.objects
        return {"uv": self.lead.uv, "owner": self.lead.owner, "lead": np.array(self.lead.lead),
                "object_owner": o.owner, "distance_m": o.distance_m, "spread_m": o.spread_m,
                "n_points": o.n_points, "n_frustum": o.n_frustum,
                "distance_sd_m": o.distance_sd_m, "unsure": o.unsure}  # fmt: skip

    @classmethod
    def from_arrays(cls, a: Arrays) -> FrameLidar:
        """The association of :meth:`arrays`' output."""
        lead = LeadAssociation(a["uv"], a["owner"], int(a["lead"]))
        objects = ObjectAssociation(a["object_owner"], a["distance_m"], a["spread_m"],
                                    a["n_points"], a["n_frustum"], a["distance_sd_m"],
                                    a["unsure"])  # fmt: skip
        return cls(lead, objects)


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


class PairSteps:
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
        parts: RowParts,
        frame_lidar: dict[int, FrameLidar] | None = None,
        cache: StageCache | None = None,
    ) -> None:
        """``parts``: where the rows' parts are kept (shared by a batch's pairs).
        ``frame_lidar``: each frame's lidar association, shared by the pairs of a run (a
        frame is the current one of a pair and the previous one of the next); None: this
        pair's own. ``cache``: where a frame's association is kept for the other runs of this
        process (:meth:`StageCache.keep`; it depends on none of a group's own axes)."""
        self.frames, self.calib, self.dt, self.prev, self.curr = frames, calib, dt, prev, curr
        self.parts = parts
        self.frame_lidar = {} if frame_lidar is None else frame_lidar
        self.per_frame, self.match, self.cache = per_frame, match, cache
        self.obj = {i: per_frame["objects"][i].arrays for i in (prev, curr)}
        self.lane = {i: per_frame["lidar"][i].arrays for i in (prev, curr)}
        self.desc_prev = per_frame["descriptors"][prev].arrays
        desc_curr = per_frame["descriptors"][curr].arrays
        self.kp_curr = current_keypoints(desc_curr["keypoints"], match.arrays)  # KLT: tracked
        self.xy_prev = self.desc_prev["keypoints"][:, [X, Y]]
        self.xy_curr = self.kp_curr[:, [X, Y]]
        self.memo: dict[str, dict] = {
            k: {}
            for k in ("sel", "fp1", "fp2", "fp3", "fp4", "base", "boxes", "head", "rows", "ratios")
        }
        self.assoc: tuple | None = None
        self._projection: bytes | None = None

    def rows(self, s: Settings, k: dict[str, str], detail: dict | None = None) -> RowBlock:
        """The rows of this pair under setting ``s`` (step keys ``k``), lead box first (the
        same block for the settings with the same step keys). ``detail``, when given, receives
        the intermediate arrays (see :class:`~ttc.rows.PairDetail`)."""
        key = tuple(k.values())
        if detail is None and key in self.memo["rows"]:
            return self.memo["rows"][key]
        selected, ms_select = _memo(
            self.memo["sel"], k["selector"], lambda: pair_matches(self.match.arrays, s.selector)
        )
        box_matches, ms_fp1 = self._fp1(s, k, selected)
        uv, owners, lead_box, objects, ms_assoc = self._association(s)
        box_pairs, shared = self._box_pairs(k, box_matches, lead_box)
        base = self._base(k, selected, ms_select, ms_fp1, ms_assoc)
        rows = []
        for prev_box, curr_box in box_pairs:
            obj, box, unmatched = self._head(prev_box, curr_box, lead_box, owners, objects)
            if prev_box >= 0:
                lidar = self._fp2(s, k, owners, objects, prev_box, curr_box, lead_box)
                camera = self._fp34(s, k, selected, curr_box, detail, curr_box == lead_box)
                rows.append((base, obj, box, lidar, camera, -1, -1, shared.get(curr_box, 0)))
            else:
                rows.append((base, obj, box, -1, -1, unmatched, -1, 0))
        if detail is not None:
            detail.update(matches=selected, box_matches=box_matches, uv=uv, owners=owners,
                          lead_box=lead_box, objects=objects)  # fmt: skip
        self.memo["rows"][key] = block = RowBlock.of(rows)
        return block

    def _box_pairs(
        self, k: dict[str, str], box_matches: Any, lead_box: int
    ) -> tuple[list[tuple[int, int]], dict[int, int]]:
        """(the box pairs of FP.1's result, lead first: one ``(-1, lead)`` when the lead has
        no match; shared matches by current box), once per FP.1 result."""
        key = (k["selector"], k["box_matching"])
        if key not in self.memo["boxes"]:
            prev, curr = box_matches.prev_box.tolist(), box_matches.curr_box.tolist()
            pairs = list(zip(prev, curr, strict=True))
            if lead_box >= 0 and lead_box in curr:
                pairs.sort(key=lambda pc: pc[1] != lead_box)
            else:
                pairs.insert(0, (-1, lead_box))  # the lead row is always present
            shared = dict(zip(curr, box_matches.shared.tolist(), strict=True))
            self.memo["boxes"][key] = (pairs, shared)
        return self.memo["boxes"][key]

    def _head(
        self, prev_box: int, curr_box: int, lead_box: int, owners: dict, objects: dict
    ) -> tuple[int, int, int]:
        """Parts of a box pair that no step axis changes: the current box's own lidar points,
        the box pair's columns, and (no previous box) the empty result, −1 otherwise."""
        key = (prev_box, curr_box)
        if key not in self.memo["head"]:
            add, assoc = self.parts.add, objects[self.curr]
            unmatched = -1
            if prev_box < 0:
                if curr_box < 0:
                    points = 0
                elif curr_box == lead_box:  # its lane points
                    points = int(np.sum(owners[self.curr] == curr_box))
                else:
                    points = int(assoc.n_points[curr_box])
                unmatched = add("unmatched", unmatched_columns(curr_box, points))
            self.memo["head"][key] = (
                add("object", object_columns(assoc, curr_box)),
                add("box", box_columns(self.obj[self.curr], prev_box, curr_box, lead_box)),
                unmatched,
            )
        return self.memo["head"][key]

    def _association(self, s: Settings) -> tuple[dict, dict, int, dict, float]:
        """(lane points' pixels, their owner box, lead box, every box's own lidar points
        (:func:`associate_objects`), ms) per frame of the pair. Each frame is associated once
        per run (:attr:`frame_lidar`: a frame is the current one of a pair and the previous
        one of the next) and once per process for the runs that share its boxes, points
        and shrink (:meth:`_frame_lidar`); ms: the computing time of the frames this pair
        associated for its run. The lead is the current box holding most lane lidar points."""
        if self.assoc is None:
            store, ms = self.frame_lidar, 0.0
            for i in (self.prev, self.curr):
                if i not in store:
                    store[i], ms_i = self._frame_lidar(i, s)
                    ms += ms_i
            found = {i: store[i] for i in (self.prev, self.curr)}
            uv = {i: a.lead.uv for i, a in found.items()}
            owners = {i: a.lead.owner for i, a in found.items()}
            objects = {i: a.objects for i, a in found.items()}
            self.assoc = (uv, owners, found[self.curr].lead.lead, objects, ms)
        return self.assoc

    def _lidar_name(self, i: int, s: Settings) -> tuple | None:
        """The name frame ``i``'s lidar association is kept under in :attr:`cache`: the keys
        of its boxes and points, the calibration and the parameters; None when there is no
        cache or an entry has no key (then nothing derived from it is kept)."""
        objects, lidar = self.per_frame["objects"][i].key, self.per_frame["lidar"][i].key
        if self.cache is None or not (objects and lidar):
            return None
        if self._projection is None:  # the 3 × 4 product, once per pair
            self._projection = self.calib.velo_to_image.tobytes()
        return ("lidar_association", objects, lidar, self._projection, s.lidar_shrink,
                repr(s.object_lidar))  # fmt: skip

    def _frame_lidar(self, i: int, s: Settings) -> tuple[FrameLidar, float]:
        """Frame ``i``'s association and the ms it took to compute: computed, or kept by
        :attr:`cache` from another run of this process (named by the keys of the frame's
        boxes and points, the calibration and the parameters: it cannot go stale)."""
        name = self._lidar_name(i, s)
        keyed = name is not None
        if keyed and (kept := self.cache.recent(name)) is not None:
            return FrameLidar.from_arrays(kept), float(kept["ms"])
        lane, roi = self.lane[i], self.obj[i]["roi"]
        velo_to_image = self.calib.velo_to_image
        found, ms = _timed(lambda: FrameLidar(
            associate_lead(lane["points"], velo_to_image, roi, s.lidar_shrink),
            associate_objects(lane["object_points"], velo_to_image, roi, s.lidar_shrink,
                              s.object_lidar),
        ))  # fmt: skip
        if keyed:
            self.cache.keep(name, {**found.arrays(), "ms": np.array(ms)})
        return found, ms

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
    ) -> int:
        """The pair's columns (:func:`ttc.rows.pair_columns`), once per selection and FP.1:
        their part's index."""
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
            self.memo["base"][key] = self.parts.add("pair", pair_columns(
                prev, curr, self.dt, self.lane, boxes, counts, ms, cached,
                self.frames.min_scan_points,
            ))  # fmt: skip
        return self.memo["base"][key]

    def _fp2(
        self,
        s: Settings,
        k: dict[str, str],
        owners: dict,
        objects: dict[int, ObjectAssociation],
        prev_box: int,
        curr_box: int,
        lead_box: int,
    ) -> int:
        """FP.2 of a box pair (its part's index): the lead's ego-lane points, every other
        box's own points.

        It reads the two frames' lidar associations, the boxes, the interval and the
        estimator, and no camera stage: besides this pair's memo (the settings of its group),
        it is kept in :attr:`cache` for the other groups of this process (each
        detector × descriptor × matcher of a ``grand`` sweep), named by the associations'
        names (:meth:`_lidar_name`), with the time it took to compute."""
        key = (prev_box, curr_box, k["lidar_ttc"])
        if key in self.memo["fp2"]:
            return self.memo["fp2"][key]
        names = (self._lidar_name(self.prev, s), self._lidar_name(self.curr, s))
        name = ("fp2", *names, prev_box, curr_box, self.dt, k["lidar_ttc"])
        keyed = None not in names
        if keyed and (kept := self.cache.recent(name)) is not None:
            columns = {column: value.item() for column, value in kept.items()}
        else:
            p, c = self.prev, self.curr
            if curr_box == lead_box:
                pts_prev = self.lane[p]["points"][owners[p] == prev_box][:, :3]
                pts_curr = self.lane[c]["points"][owners[c] == curr_box][:, :3]
            else:
                pts_prev = objects[p].of_box(self.lane[p]["object_points"], prev_box)[:, :3]
                pts_curr = objects[c].of_box(self.lane[c]["object_points"], curr_box)[:, :3]
            dt = self.dt
            lid, ms = _timed(lambda: lidar_ttc(pts_prev, pts_curr, dt, s.lidar_ttc))
            columns = lidar_columns(lid, pts_prev, pts_curr, ms)
            if keyed:
                self.cache.keep(name, {column: np.asarray(v) for column, v in columns.items()})
        self.memo["fp2"][key] = self.parts.add("lidar", columns)
        return self.memo["fp2"][key]

    def _fp34(
        self,
        s: Settings,
        k: dict[str, str],
        selected: Any,
        curr_box: int,
        detail: dict | None = None,
        is_lead: bool = False,
    ) -> int:
        """FP.3/FP.4 of the current box (its part's index); ``detail`` receives the lead's
        kept and removed matches."""
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
            dt, params = self.dt, s.camera_ttc
            width = float(self.obj[self.curr]["roi"][curr_box][2])
            ratios, ms_ratios = None, 0.0
            if (source := ratio_source(params, width)) is not None:  # shared by the statistics
                ratios, ms_ratios = _memo(
                    self.memo["ratios"],
                    (fp3_key, source),
                    lambda: pair_ratios(kept_prev, kept_curr, params, width),
                )
            cam, ms_fp4 = _timed(
                lambda: camera_ttc(kept_prev, kept_curr, dt, params, box_width=width, ratios=ratios)
            )
            self.memo["fp4"][fp4_key] = self.parts.add(
                "camera", camera_columns(cam, filt, ms_fp3, ms_ratios + ms_fp4)
            )
        return self.memo["fp4"][fp4_key]
