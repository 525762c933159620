"""The reference TTC of a sweep's recording, kept in the stage cache. Light on imports (no plotting): the end-of-sweep summary
ranks against the reference without loading the report's libraries."""

from __future__ import annotations

import hashlib
import inspect
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pandas as pd

from experiments.data.datasets import recording_id
from experiments.host.paths import default_cache_dir, default_data_root
from experiments.summary.recordings import recording_of, recording_source_of, run_ids_by_recording
from ttc import evaluation as ev
from ttc.engine.cache import StageCache, Task, cache_key
from ttc.engine.stages import FrameStages
from ttc.evaluation import lead_distance, lead_status
from ttc.evaluation import reference as reference_module
from ttc.evaluation.object_reference import object_reference
from ttc.features.objects import clear_detector_cache, coco_names
from ttc.io.calibration import load_calibration
from ttc.io.ego_motion import EGO_SPEED
from ttc.io.frame_errors import FrameDataError
from ttc.io.frames import (
    file_identity,
    frame_files,
    frame_interval,
    read_frame_times,
    read_image,
    read_lidar_scan,
    recording_frames,
)
from ttc.io.ros2_bag import BagSource
from ttc.settings import FrameRange, Settings
from ttc.steps.lidar import associate_lead
from ttc.steps.object_lidar import associate_objects

#: Bump to invalidate every cached reference (the key also holds the source of ttc/evaluation/lead_distance.py, lead_status.py and reference.py).
REFERENCE_CACHE_VERSION = 1


def sequence_of(runs: pd.DataFrame) -> str:
    """The one KITTI recording (``dataset.sequence``) of the runs."""
    sequences = sorted(set(recording_of(runs)))
    if len(sequences) != 1:
        raise ValueError(
            f"the sweeps cover {len(sequences)} recordings {sequences}: `python -m "
            "experiments.report` ranks them per drive and pooled (drives.md)"
        )
    return sequences[0]


def _reference_key(sequence_dir: Path | BagSource, last: int, times: np.ndarray | None) -> str:
    scans = [file_identity(frame_files(sequence_dir, i).scan) for i in range(last + 1)]
    code = "".join(inspect.getsource(m) for m in (lead_distance, lead_status, reference_module))
    source = hashlib.sha256(code.encode()).hexdigest()
    clock = None if times is None else hashlib.sha256(times.tobytes()).hexdigest()
    return cache_key("reference", REFERENCE_CACHE_VERSION, source, scans, clock)


def recording_scans(sequence_dir: Path | BagSource, last: int) -> Iterator[tuple[int, np.ndarray]]:
    """``(frame, points)`` of frames 0..``last`` of a recording, one scan read at a time; a
    scan that cannot be read (a bag's damaged chunk, an unpaired camera message) is a frame
    without points: a gap in the reference, like a scan without the lead."""
    for index in range(last + 1):
        try:
            yield index, read_lidar_scan(frame_files(sequence_dir, index).scan).points
        except FrameDataError:
            yield index, np.zeros((0, 4), dtype=np.float32)


def reference_task(sequence_dir: Path | BagSource) -> Task:
    """The stage-cache task of the reference TTC over every frame of the recording
    (:func:`reference_for_sequence`), at the recording's real frame times when it ships a
    ``timestamps.txt`` (:func:`ttc.io.frames.read_frame_times`); key: the scans' identities, the
    frame times and the source of ``ttc/evaluation/lead_distance.py`` and ``reference.py``."""
    frames = recording_frames(sequence_dir)  # any layout (KITTI raw, Udacity, odometry)
    last = frames[-1] if frames else -1
    if last < 1:
        raise FileNotFoundError(f"fewer than two frames under {Path(sequence_dir)}")
    times = read_frame_times(sequence_dir)
    times = None if times is None else np.asarray(times, dtype=float)  # a bag's: read here

    def compute() -> dict[str, np.ndarray]:
        ref = reference_module.reference_for_sequence(
            recording_scans(sequence_dir, last), times=times
        )
        # text columns (object, or pandas' str dtype) as fixed-width strings: cache entries
        # hold no pickled objects, and an object array would make every load discard it
        return {
            c: ref[c].to_numpy().astype(str)
            if pd.api.types.is_string_dtype(ref[c]) or pd.api.types.is_object_dtype(ref[c])
            else ref[c].to_numpy()
            for c in ref.columns
        }

    return Task("reference", _reference_key(sequence_dir, last, times), compute)


def sequence_reference(sequence_dir: Path | BagSource, cache: StageCache) -> pd.DataFrame:
    """Reference TTC over every frame of the recording (:func:`reference_task`), from the
    stage cache when it holds it."""
    return pd.DataFrame(cache.get(reference_task(sequence_dir)).arrays)


def recording_references(
    frames: pd.DataFrame,
    runs: pd.DataFrame,
    data_dir: Path | None = None,
    cache: StageCache | None = None,
) -> dict[str, pd.DataFrame]:
    """What the runs of each recording are judged against, by recording (``dataset.sequence``,
    sorted): a generated recording's exact truth (:func:`ttc.evaluation.truth_reference` of
    its runs' ``frames``), else the recording's reference TTC (:func:`sequence_reference`).
    ``data_dir`` / ``cache``: None for the configured data root and stage cache."""
    root = Path(data_dir) if data_dir else default_data_root()
    out = {}
    for sequence, ids in run_ids_by_recording(runs).items():
        mine = ev.rows_of_runs(frames, ids)
        if ev.has_truth(mine):
            out[sequence] = ev.truth_reference(mine)
            continue
        cache = cache if cache is not None else StageCache(default_cache_dir())
        out[sequence] = sequence_reference(recording_source_of(runs, ids[0], root), cache)
    return out


#: Frames beyond the judged ones on either side whose boxes enter an object reference: the
#: Savitzky–Golay window's half-width, so a judged frame is smoothed as within the recording.
MARGIN_FRAMES = reference_module.WINDOW // 2


def recording_boxes(
    sequence_dir: Path | BagSource,
    settings: Settings,
    cache: StageCache,
    projection: str = "P_rect_02",
    span: tuple[int, int] | None = None,
) -> tuple[pd.DataFrame, np.ndarray, int]:
    """Every YOLO box of the frames ``span`` (first, last; default every frame) of a recording with its object's nearest face
    (:func:`ttc.steps.object_lidar.associate_objects`) and whether it is the ego lane's lead
    (:func:`ttc.steps.lidar.associate_lead`) and its bearing (degrees left of the forward axis,
    the median of its points'), under ``settings``' objects, lane crop, shrink
    and object range, projected with ``projection``; the YOLO boxes and scans come from the
    stage cache (a sweep computed them). Returns the boxes (:func:`ttc.evaluation.object_reference.object_reference`'s
    input), the frame times (s, index = frame) and the image width (px)."""
    frames = recording_frames(sequence_dir)
    if span is not None:
        frames = [f for f in frames if span[0] <= f <= span[1]]
    rng = FrameRange(sequence_dir, first=frames[0], last=frames[-1], projection=projection)
    stages = FrameStages(settings, rng, cache)
    calib = load_calibration(sequence_dir, rng.projection)
    names = coco_names(settings.objects)
    parts = []
    for index in frames:
        stages.forget(keep=index)  # the frames done: their boxes and scans freed as it goes
        try:
            obj, lid = (cache.get(t).arrays for t in (stages.objects(index), stages.lidar(index)))
        except FrameDataError:  # an unreadable frame (a bag's damaged chunk): no boxes
            continue
        roi = obj["roi"]
        near = associate_objects(lid["object_points"], calib.velo_to_image, roi,
                                 settings.lidar_shrink, settings.object_lidar)  # fmt: skip
        lead = associate_lead(lid["points"], calib.velo_to_image, roi, settings.lidar_shrink).lead
        pts = lid["object_points"]
        angle = np.degrees(np.arctan2(pts[:, 1], pts[:, 0]))
        bearing = [float(np.median(angle[near.owner == b])) if near.n_points[b] else np.nan
                   for b in range(len(roi))]  # fmt: skip
        parts.append(pd.DataFrame({
            "frame": index, "box": np.arange(len(roi)),
            "class": [names[c] if 0 <= c < len(names) else str(c) for c in obj["class_id"]],
            "box_x": roi[:, 0], "box_y": roi[:, 1], "box_w": roi[:, 2], "box_h": roi[:, 3],
            "distance_m": near.distance_m, "object_points": near.n_points, "bearing_deg": bearing,
            "is_lead": np.arange(len(roi)) == lead,
        }))  # fmt: skip
    # the frames no sweep ran (the margins) were detected here: YOLOv3-tiny is not held for
    # the caller's later steps (≈ 0.2 GB through a report's "every object" step, its peak;
    # 19 ms to load again where another detection needs it)
    clear_detector_cache()
    times = read_frame_times(sequence_dir)
    if times is None:
        times = np.arange(frames[-1] + 1) * frame_interval()
    times = np.asarray(times, dtype=float)
    width = read_image(frame_files(sequence_dir, frames[0]).image).shape[1]
    return pd.concat(parts, ignore_index=True), times, int(width)


def object_references(
    frames: pd.DataFrame,
    runs: pd.DataFrame,
    settings_of: Callable[[str], tuple[Settings, FrameRange]],
    data_dir: Path | None = None,
    cache: StageCache | None = None,
) -> dict[str, pd.DataFrame]:
    """The reference of every tracked object of each real recording of the runs
    (:func:`ttc.evaluation.object_reference.object_reference`), by recording
    (``dataset.sequence``), with a ``recording`` column (its id, e.g. ``2011_09_26_drive_0009``); the ego speed per frame
    from the rows' ``ego_speed_mps`` where they have it. The frames are the runs' (from the first
    previous frame to the last frame) and :data:`MARGIN_FRAMES` on either side where the
    recording has them: a report pays YOLO for the frames it judges, not for a whole drive. ``settings_of(run_id)``: a run's
    core settings and frame range (the recording's first run sets the objects, the lidar
    association and the projection)."""
    root = Path(data_dir) if data_dir else default_data_root()
    cache = cache if cache is not None else StageCache(default_cache_dir())
    out = {}
    for sequence, ids in run_ids_by_recording(runs).items():
        mine = ev.rows_of_runs(frames, ids)
        if ev.has_truth(mine):
            continue
        settings, rng = settings_of(ids[0])
        span = (
            int(mine["prev_frame"].min()) - MARGIN_FRAMES,
            int(mine["frame"].max()) + MARGIN_FRAMES,
        )
        source = recording_source_of(runs, ids[0], root)  # a bag: the run's topics
        boxes, times, width = recording_boxes(source, settings, cache, rng.projection, span)
        ego = None
        if EGO_SPEED in mine and mine[EGO_SPEED].notna().any():
            per_frame = mine.groupby("frame")[EGO_SPEED].median()
            ego = per_frame.reindex(np.arange(len(times))).to_numpy(dtype=float)
        first = frame_files(source, int(boxes["frame"].iloc[0])) if len(boxes) else None
        height = read_image(first.image).shape[0] if first is not None else None
        ref = object_reference(boxes, times, width, ego, image_height=height)
        out[sequence] = ref.assign(recording=recording_id(sequence))
    return out
