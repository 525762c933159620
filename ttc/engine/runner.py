"""The one FP.1–FP.4 runner: one setting is a batch of one.

:func:`run_settings` runs a list of settings over a :class:`~ttc.settings.FrameRange`. Each
group of settings with the same upstream stages (objects, detector, descriptor, matcher, lane
crop: every axis but the FP.1–FP.4 steps and the fusion) is streamed once through the stage
cache (:func:`ttc.engine.stages.stream`), and within a frame pair each piece of FP.1–FP.4 is computed
once for all the settings that share its inputs:

=================  ==========================================================
piece              shared by the settings with the same
=================  ==========================================================
selection          selector
lidar association  boxes, points, shrink: a frame once per process (its runs)
FP.1               selector, box matching
FP.2               box pair, lidar estimator (once per process)
FP.3               selector, box, box-matching shrink, keypoint filter
FP.4 pair ratios   the FP.3 result, the ratios' source, the least pair distance
FP.4               the FP.3 result, camera estimator
=================  ==========================================================

A shared piece is timed once and reported in every row that uses it. A setting that raises
gets its exception instead of rows; the others go on. :func:`run_setting` (one setting,
raising its exception) and :func:`pair_detail` (one frame pair with its intermediate
arrays) are the same path. A row is kept as the parts it shares with others
(:class:`ttc.row_parts.RowParts`, columns built by :mod:`ttc.rows`) and the batch's rows become
one frame once all are done.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pandas as pd

from ttc.engine.cache import StageCache
from ttc.engine.pair_steps import PairSteps
from ttc.engine.stages import stream
from ttc.features.matching import check_features
from ttc.io.calibration import Calibration, load_calibration
from ttc.io.frames import (
    FrameDataError,
    check_frame_range,
    frame_files,
    pair_interval,
    read_frame_times,
    read_image,
    timestamps_file,
    with_truth,
)
from ttc.row_parts import MemberRows, RowBlock, RowParts
from ttc.rows import MEMBER, PairDetail, error_columns
from ttc.settings import FrameRange, Settings, axes_with_role
from ttc.steps.fusion import FUSION_INPUTS, fused_columns
from ttc.steps.tracks import TRACK_ID, chain_tracks

#: Axes computed per pair from the cached stages: they vary within a streamed group.
STEP_AXES = axes_with_role("step")
#: Axes downstream of the cached stages (the steps and the fusion over a run).
DOWNSTREAM_AXES = axes_with_role("step", "fusion")


def params_key(obj: Any) -> str:
    """A hashable, canonical text of a parameter dataclass (its fields as sorted JSON)."""
    return json.dumps(dataclasses.asdict(obj), sort_keys=True, default=str)


#: The fields of :class:`~ttc.settings.Settings` the cached stages depend on: every field
#: but :data:`DOWNSTREAM_AXES`.
UPSTREAM_FIELDS = tuple(
    f.name for f in dataclasses.fields(Settings) if f.name not in DOWNSTREAM_AXES
)


def upstream_key(settings: Settings) -> str:
    """What the cached stages of a setting depend on: its :data:`UPSTREAM_FIELDS` (settings
    with equal keys are streamed once)."""
    fields = {name: getattr(settings, name) for name in UPSTREAM_FIELDS}
    return json.dumps(
        {k: dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v for k, v in fields.items()},
        sort_keys=True,
        default=str,
    )


def member_keys(settings: Settings) -> dict[str, str]:
    """:func:`params_key` of each of a setting's :data:`STEP_AXES`, made once."""
    return {axis: params_key(getattr(settings, axis)) for axis in STEP_AXES}


def setting_keys(settings: Sequence[Settings]) -> tuple[list[str], list[dict[str, str]]]:
    """(:func:`upstream_key`, :func:`member_keys`) of each setting, each made once per
    distinct set of field objects: settings made together share one object per distinct
    value (``experiments.sweep.compose.core_settings``), and making the same JSON again for
    each of a batch's 160 settings took 6 % of the batch. Keyed by the objects' ids, which
    hold while ``settings`` holds the objects (this call)."""
    upstream: dict[tuple[int, ...], str] = {}
    step: dict[int, str] = {}
    ups, members = [], []
    for s in settings:
        ids = tuple(id(getattr(s, name)) for name in UPSTREAM_FIELDS)
        if ids not in upstream:
            upstream[ids] = upstream_key(s)
        ups.append(upstream[ids])
        keys = {}
        for axis in STEP_AXES:
            value = getattr(s, axis)
            if id(value) not in step:
                step[id(value)] = params_key(value)
            keys[axis] = step[id(value)]
        members.append(keys)
    return ups, members


def check_setting(settings: Settings) -> None:
    """Raise a ValueError (:func:`ttc.features.matching.check_features`) for an invalid or
    unavailable detector × descriptor × matcher combination; a tracking matcher (KLT, dense
    flow) uses no descriptor."""
    s = settings
    variant = getattr(s.detector, "variant", "n16")
    check_features(s.detector.name, s.descriptor.name, s.matcher.name, variant)


def check_range(
    frames: FrameRange, calibration: Calibration | None = None
) -> tuple[list[int], np.ndarray | None, Calibration]:
    """(frame indices, frame times in s or None, calibration) of a run over ``frames``, checked
    before any work: at least two frames, none past the recording's last, a timestamp for
    each, a readable calibration (``calibration`` when given). Raises ValueError or
    :class:`ttc.io.frames.FrameDataError` naming the file."""
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


def finish_rows(
    settings: Sequence[Settings], rows: pd.DataFrame, failed: dict[int, Exception]
) -> pd.DataFrame:
    """The rows of settings (column :data:`MEMBER`: the index in ``settings``) once all their
    frame pairs are done, with the work over a whole run added as columns: the fused TTC over
    each run's lead rows (:func:`ttc.steps.fusion.fused_columns`) and the track of every box
    pair (:func:`ttc.steps.tracks.chain_tracks`). A setting that raises is put in ``failed``
    and its rows left out; the others keep their order, members in order of first row.

    The columns are made for every member at once (one frame, a few arrays filled per
    member): a frame per member, copied and extended, cost 2 ms a member. The tracks are
    chained once per distinct sequence of box pairs (a ``grand`` batch of 200 settings has 3).
    """
    at = rows.groupby(MEMBER, sort=False).indices
    order = np.concatenate(list(at.values())) if at else np.zeros(0, dtype=np.int64)
    if (np.diff(order) < 0).any():  # each member's rows together, members as first seen
        rows = rows.take(order).reset_index(drop=True)
        at = rows.groupby(MEMBER, sort=False).indices
    inputs = rows[[c for c in FUSION_INPUTS if c in rows]]
    boxes = [rows[c].to_numpy() for c in ("prev_frame", "frame", "prev_box", "curr_box")]
    tracks: dict[tuple[bytes, ...], np.ndarray] = {}  # by box pairs: shared by most members
    kept, added = np.ones(len(rows), dtype=bool), []
    for member, where in at.items():  # the members' rows, one block after the other
        block = slice(int(where[0]), int(where[-1]) + 1)  # = where: a view, not a take
        assert block.stop - block.start == len(where), "a member's rows are together"
        try:
            fused = fused_columns(inputs.iloc[block], settings[member].fusion)
            pairs = [c[block] for c in boxes]
            key = tuple(c.tobytes() for c in pairs)
            if key not in tracks:
                tracks[key] = chain_tracks(*pairs)
            added.append({**fused, TRACK_ID: tracks[key]})
        except Exception as exc:  # a setting that raises costs only itself
            failed[member] = exc
            kept[block] = False
    if not added:
        return pd.DataFrame()
    columns = {name: np.concatenate([a[name] for a in added]) for name in added[0]}
    return (rows if kept.all() else rows[kept].reset_index(drop=True)).assign(**columns)


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
    10 Hz. Frames are streamed in chunks (:data:`ttc.engine.stages.CHUNK_FRAMES`), so memory does
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
    upstream, keys = setting_keys([settings[i] for i in valid])
    groups: dict[str, list[int]] = {}
    for i, key in zip(valid, upstream, strict=True):
        groups.setdefault(key, []).append(i)
    step_keys = dict(zip(valid, keys, strict=True))
    parts, rows = RowParts(), []
    for members in groups.values():
        rows.extend(_group_rows(settings, {m: step_keys[m] for m in members}, frames, cache,
                                indices, times, calib, parts, failed))  # fmt: skip
    return with_truth(_finish(settings, parts, rows, failed), frames.sequence_dir), failed


def pair_detail(
    settings: Settings,
    frames: FrameRange,
    prev: int,
    curr: int,
    cache: StageCache | None = None,
    read: Callable[[Any], np.ndarray] = read_image,
) -> PairDetail:
    """Run one frame pair ``prev`` → ``curr`` and keep every intermediate array (for
    pictures and explanations); raises the pair's :class:`ttc.io.frames.FrameDataError`.
    ``read``: the pair's two images (H × W × 3 BGR) from their file or bag message
    (:func:`ttc.io.frames.read_image`; a caller asking for many pairs can share the frames
    read). Each frame's lidar association and each box pair's lidar TTC are kept in
    ``cache``'s memory for the other pairs and runs of the process, as a sweep's are
    (:class:`~ttc.engine.pair_steps.PairSteps`)."""
    check_setting(settings)
    cache = cache if cache is not None else StageCache(None)
    calib = load_calibration(frames.sequence_dir, frames.projection)
    pair = dataclasses.replace(frames, first=prev, last=curr, step=curr - prev)
    check_frame_range(frames.sequence_dir, [prev, curr])
    dt = pair_interval(read_frame_times(frames.sequence_dir), prev, curr, curr - prev)
    _, per_frame, matches, broken = next(stream(settings, pair, cache, [prev, curr]))
    if broken:
        raise next(iter(broken.values()))
    parts = RowParts()
    shared = PairSteps(pair, calib, dt, prev, curr, per_frame, matches[(prev, curr)], parts,
                       cache=cache)  # fmt: skip
    detail: dict[str, Any] = {}
    rows = parts.table([(0, [shared.rows(settings, member_keys(settings), detail)])])
    empty = np.zeros(0, dtype=np.int64)
    return PairDetail(
        prev=prev,
        curr=curr,
        images={i: read(frame_files(frames.sequence_dir, i).image) for i in (prev, curr)},
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
        rows=with_truth(_finished_alone(settings, rows), frames.sequence_dir),
    )


def _finish(
    settings: Sequence[Settings], parts: RowParts, rows: MemberRows, failed: dict[int, Exception]
) -> pd.DataFrame:
    """One frame of every member's rows (failed members left out) through
    :func:`finish_rows`. The rows become one frame first (one frame per member would cost
    more than the rows themselves)."""
    table = parts.table([(member, mine) for member, mine in rows if member not in failed])
    return finish_rows(settings, table, failed) if len(table) else table


def _finished_alone(settings: Settings, rows: pd.DataFrame) -> pd.DataFrame:
    """:func:`finish_rows` of one setting's rows (member 0), without :data:`MEMBER`; raises
    what the setting raised."""
    failed: dict[int, Exception] = {}
    out = finish_rows([settings], rows, failed)
    if failed:
        raise failed[0]
    return out.drop(columns=MEMBER)


def _group_rows(
    settings: Sequence[Settings],
    keys: dict[int, dict[str, str]],
    frames: FrameRange,
    cache: StageCache,
    indices: list[int],
    times: np.ndarray | None,
    calib: Calibration,
    parts: RowParts,
    failed: dict[int, Exception],
) -> list[tuple[int, list]]:
    """Rows of the members of one upstream group: ``[(member, row blocks)]`` (their parts
    kept in ``parts``); ``keys``: each member's :func:`member_keys`."""
    members = list(keys)
    out: dict[int, list] = {m: [] for m in members}
    first = settings[members[0]]
    frame_lidar: dict = {}  # each frame's lidar association, shared by its two pairs
    try:
        for pairs, per_frame, matches, broken in stream(first, frames, cache, indices):
            for prev, curr in pairs:
                dt = pair_interval(times, prev, curr, frames.step)
                if (prev, curr) not in matches:
                    error = broken.get(curr) or broken[prev]
                    part = parts.add("error", error_columns(prev, curr, dt))
                    block = RowBlock.unreadable(part, str(error))
                    for m in members:
                        out[m].append(block)
                    continue
                for done in [i for i in frame_lidar if i != prev]:
                    del frame_lidar[done]
                shared = PairSteps(frames, calib, dt, prev, curr, per_frame,
                                   matches[(prev, curr)], parts, frame_lidar, cache)  # fmt: skip
                for m in members:
                    if m in failed:
                        continue
                    try:
                        out[m].append(shared.rows(settings[m], keys[m]))
                    except Exception as exc:  # a setting that raises costs only itself
                        failed[m] = exc
    except Exception as exc:  # the group's stages raised: every member fails with it
        for m in members:
            failed.setdefault(m, exc)
    return list(out.items())
