"""The cached stages of one setting (objects, lidar, keypoints, descriptors, matches) and the
order they are produced in: the cache keys, the chunked streaming over a frame range, and the
list of input files a run reads. Used by :mod:`ttc.engine.runner`.

============  ==========================================================  ==============
stage         key (besides its version and the OpenCV and numpy versions)  content
============  ==========================================================  ==============
objects       image file, objects params, model files                      YOLO boxes
lidar         scan file, lane crop, object range                           lane points, object-range points
keypoints     image file, detector params                                  (N, 7) array
descriptors   keypoints key, descriptor params                             kept kps, desc
matches       both descriptors keys, matcher params                        k=2 candidates
matches (klt) previous keypoints key, current image file, KLT params      tracks
(dis, farneback) the same with the dense-flow params                        tracks
============  ==========================================================  ==============

A file is named by its identity (resolved path, size, mtime); a ROS 2 bag's image or scan by
its bag files' identity, topic and header stamp (:func:`ttc.io.bag_recording.message_identity`). NN and kNN selection share the
k=2 candidates, so the selector is not part of the matches key. Options at their "off" value
(``detector.subpixel=false``) are left out of the keys (:func:`stage_params`), so entries made
before the option existed stay valid; a ``custom`` stage's key holds the hash of its code. Bump a stage's number in
``STAGE_VERSIONS`` when its code changes results: every key built on it changes too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ttc.engine.cache import Lookup, RecentArrays, StageCache, Task, cache_key
from ttc.features.dense_flow import DENSE_FLOW_MATCHERS, flow_keypoints
from ttc.features.descriptors import NO_DESCRIPTOR, describe_keypoints, descriptor_is_binary
from ttc.features.keypoints import detect_keypoints
from ttc.features.klt import track_keypoints
from ttc.features.learned import extract, glue_candidates
from ttc.features.learned_params import LEARNED_MATCHERS, learned_key
from ttc.features.matching import knn_candidates, tracks_to_arrays, uses_descriptors
from ttc.features.objects import detect_objects, model_identity
from ttc.io import ego_motion, kitti_odometry
from ttc.io.calibration import CAM_TO_CAM, VELO_TO_CAM, calibration_dir
from ttc.io.frames import (
    TIMESTAMP_FILES,
    TRUTH_FILE,
    FrameDataError,
    file_identity,
    frame_clock_ns,
    frame_files,
    frame_pairs,
    missing_time_errors,
    read_image,
    read_lidar_scan,
)
from ttc.io.ros2_bag import METADATA, bag_files, is_bag
from ttc.plugins import USER, code_identity
from ttc.settings import AXIS_BY_NAME, CACHED_STAGE_NAMES, FrameRange, Settings
from ttc.steps.lidar import crop_to_lane
from ttc.steps.object_lidar import object_scan_mask

#: Version of each cached stage (:data:`ttc.settings.CACHED_STAGES`).
STAGE_VERSIONS = dict.fromkeys(CACHED_STAGE_NAMES, 1)


def _params(obj: Any) -> dict[str, Any]:
    return dataclasses.asdict(obj)


def stage_params(params: Any, axis: str) -> dict[str, Any]:
    """The parameters of a detector, descriptor or matcher (``axis``) as they enter a cache
    key: the axis's neutral options (:data:`ttc.settings.NEUTRAL_OPTIONS`, e.g. ``subpixel``)
    only when on, so keys made before the option existed stay valid, and for a ``custom``
    stage the hash of the user's code (editing the function recomputes it)."""
    out = _params(params)
    for key, off in AXIS_BY_NAME[axis].neutral:
        if key in out and type(out[key]) is type(off) and out[key] == off:
            del out[key]
    if out.get("name") == USER:
        out["code"] = code_identity(out["target"])
    return out


#: Library versions in every cache key: a new OpenCV or numpy may change any stage's output.
LIBRARY_VERSIONS = {"opencv": cv2.__version__, "numpy": np.__version__}
#: Frames whose per-frame stages are resolved together (cooperative fill); the decoded images
#: and stage arrays of at most this many frames (+1) are held at once.
CHUNK_FRAMES = 8
PER_FRAME_STAGES = ("objects", "lidar", "keypoints", "descriptors")


#: Most bytes of decoded grey images a process keeps (a 1242 × 375 KITTI frame: 0.47 MB).
GRAY_MEMORY_BYTES = 64 * 2**20
#: Grey images decoded in this process, by image file identity.
_GRAYS = RecentArrays()


def gray_image(path: Path, decode: Callable[[], np.ndarray]) -> np.ndarray:
    """The grey image (H × W uint8, read-only) of image file ``path``: ``decode()`` (its BGR
    image) converted once per process and file content (:func:`ttc.io.frames.file_identity`).
    A batch of settings reads each frame's image once per detector and descriptor: decoding
    the PNG again cost more than describing it with a fast descriptor."""
    ident = file_identity(path)
    kept = _GRAYS.get(ident)
    if kept is None:
        gray = cv2.cvtColor(decode(), cv2.COLOR_BGR2GRAY)
        kept = _GRAYS.put(ident, {"gray": gray}, GRAY_MEMORY_BYTES)
    return kept["gray"]


class FrameStages:
    """Cache tasks of one job, created lazily and shared between the pairs that need them.

    Each key chains the keys of the stages it is computed from (keypoints → descriptors →
    matches), so a new version or parameter of an upstream stage reaches every downstream key.
    """

    def __init__(self, settings: Settings, frames: FrameRange, cache: StageCache) -> None:
        self.settings, self.frames, self.cache = settings, frames, cache
        self.tracking = not uses_descriptors(settings.matcher)
        self.binary = not self.tracking and descriptor_is_binary(settings.descriptor)
        self._tasks: dict[tuple, Task] = {}
        self._images: dict[int, np.ndarray] = {}
        self._grays: dict[int, np.ndarray] = {}
        self._model: list | None = None

    def forget(self, keep: int) -> None:
        """Drop the images and tasks (with their arrays) of every frame but ``keep``."""
        self._images = {i: v for i, v in self._images.items() if i == keep}
        self._grays = {i: v for i, v in self._grays.items() if i == keep}
        self._tasks = {k: t for k, t in self._tasks.items() if k[1] == (keep,)}

    def _image(self, index: int) -> np.ndarray:
        if index not in self._images:
            self._images[index] = read_image(frame_files(self.frames.sequence_dir, index).image)
        return self._images[index]

    def _gray(self, index: int) -> np.ndarray:
        if index not in self._grays:
            path = frame_files(self.frames.sequence_dir, index).image
            self._grays[index] = gray_image(path, lambda: self._image(index))
        return self._grays[index]

    def _task(self, stage: str, ident: tuple, parts: Callable[[], tuple], compute) -> Task:
        if (stage, ident) not in self._tasks:
            key = cache_key(stage, STAGE_VERSIONS[stage], LIBRARY_VERSIONS, *parts())
            self._tasks[(stage, ident)] = Task(stage, key, compute)
        return self._tasks[(stage, ident)]

    def _image_id(self, index: int) -> tuple:
        return file_identity(frame_files(self.frames.sequence_dir, index).image)

    def objects(self, index: int) -> Task:
        params = self.settings.objects
        if self._model is None:
            self._model = model_identity(params)

        def compute() -> dict:
            det = detect_objects(self._image(index), params)
            return {"class_id": det.class_id, "confidence": det.confidence, "roi": det.roi}

        key = stage_params(params, "objects")  # tiles: in the key only when on
        parts = lambda: (self._image_id(index), key, self._model)  # noqa: E731
        return self._task("objects", (index,), parts, compute)

    def lidar(self, index: int) -> Task:
        path = frame_files(self.frames.sequence_dir, index).scan
        crop, objects = self.settings.lane, self.settings.object_lidar

        def compute() -> dict:
            scan = read_lidar_scan(path)
            return {
                "points": crop_to_lane(scan.points, crop),
                "object_points": scan.points[object_scan_mask(scan.points, objects)],
                "n_scan": np.int64(len(scan)),
                "n_dropped": np.int64(scan.n_dropped),
            }

        parts = lambda: (file_identity(path), _params(crop), _params(objects))  # noqa: E731
        return self._task("lidar", (index,), parts, compute)

    def keypoints(self, index: int) -> Task:
        params = self.settings.detector

        def compute() -> dict:
            return {"keypoints": detect_keypoints(self._gray(index), params)}

        def parts() -> tuple:
            return (self._image_id(index), stage_params(params, "detector"), *learned_key(params))

        return self._task("keypoints", (index,), parts, compute)

    def descriptors(self, index: int) -> Task:
        det, desc = self.settings.detector, self.settings.descriptor
        upstream = self.keypoints(index)

        def compute() -> dict:
            keypoints = self.cache.get(upstream).arrays["keypoints"]
            if self.tracking:  # KLT: every detected keypoint, no descriptor
                return {"keypoints": keypoints, "descriptors": np.empty((len(keypoints), 0))}
            if desc.name == det.name and learned_key(det):  # one network run: both at once
                descriptors = extract(self._gray(index), det)[1]  # rows ↔ keypoints' rows
                return {"keypoints": keypoints, "descriptors": descriptors}
            kept, descriptors = describe_keypoints(self._gray(index), keypoints, det.name, desc)
            return {"keypoints": kept, "descriptors": descriptors}

        desc_key = _params(NO_DESCRIPTOR) if self.tracking else stage_params(desc, "descriptor")
        parts = lambda: (upstream.key, desc_key)  # noqa: E731
        return self._task("descriptors", (index,), parts, compute)

    def matches(self, prev: int, curr: int) -> Task:
        if self.tracking:
            return self.tracks(prev, curr)
        s = self.settings
        up_prev, up_curr = self.descriptors(prev), self.descriptors(curr)

        def compute() -> dict:
            a, b = self.cache.get(up_prev).arrays, self.cache.get(up_curr).arrays
            if s.matcher.name in LEARNED_MATCHERS:  # LightGlue: keypoints and descriptors
                size = self._gray(curr).shape[::-1]
                idx, dist = glue_candidates(a["keypoints"], a["descriptors"], b["keypoints"],
                                            b["descriptors"], size, s.descriptor.name, s.matcher)  # fmt: skip
            else:
                idx, dist = knn_candidates(
                    a["descriptors"], b["descriptors"], self.binary, s.matcher
                )
            return {"idx": idx, "dist": dist}

        def parts() -> tuple:
            glue = learned_key(s.matcher, s.descriptor.name)
            return (up_prev.key, up_curr.key, stage_params(s.matcher, "matcher"), *glue)

        return self._task("matches", (prev, curr), parts, compute)

    def tracks(self, prev: int, curr: int) -> Task:
        """KLT or dense flow: the previous frame's keypoints followed into the current frame
        (the matches stage of ``matcher=klt``, ``dis`` or ``farneback``)."""
        klt = self.settings.matcher
        upstream = self.keypoints(prev)
        follow = flow_keypoints if klt.name in DENSE_FLOW_MATCHERS else track_keypoints

        def compute() -> dict:
            keypoints = self.cache.get(upstream).arrays["keypoints"]
            return tracks_to_arrays(follow(self._gray(prev), self._gray(curr), keypoints, klt))

        parts = lambda: (upstream.key, self._image_id(curr), _params(klt))  # noqa: E731
        return self._task("matches", (prev, curr), parts, compute)


def input_files(settings: Settings, frames: FrameRange) -> list[Path]:
    """Every input file a run of ``settings`` on ``frames`` reads (some may not exist): the
    calibration and timestamps files, the ego speed's (:func:`ttc.io.ego_motion.input_files`:
    the oxts packets of the frames' times), each frame's image and scan, the object model
    files. A ROS 2 bag's: its files (``.mcap``, a rosbag2 folder's ``metadata.yaml``)."""
    models = [Path(path) for path, _, _ in model_identity(settings.objects)]
    if is_bag(frames.sequence_dir):
        bag = Path(frames.sequence_dir)
        return [*([bag / METADATA] if bag.is_dir() else []), *bag_files(bag), *models]
    seq = Path(frames.sequence_dir)
    calib = calibration_dir(seq)
    files = [calib / CAM_TO_CAM, calib / VELO_TO_CAM, *(seq / name for name in TIMESTAMP_FILES)]
    files += [seq / TRUTH_FILE] if (seq / TRUTH_FILE).is_file() else []
    files += kitti_odometry.layout_files(seq) if kitti_odometry.is_odometry_sequence(seq) else []
    try:
        clock = frame_clock_ns(seq)
    except FrameDataError:  # the run fails on it, naming the file
        clock = None
    files += ego_motion.input_files(seq, clock, frames.indices)
    for index in frames.indices:
        ff = frame_files(seq, index)
        files += [ff.image, ff.scan]
    return files + models


def shared_frame_tasks(settings: Settings, frames: FrameRange, cache: StageCache) -> list[Task]:
    """The cache tasks every setting over ``frames`` with these objects and lane crop
    shares, whatever its features: each frame's objects and lane points (a cold sweep
    computes them first, e.g. while it is being planned)."""
    stages = FrameStages(settings, frames, cache)
    return [task for i in frames.indices for task in (stages.objects(i), stages.lidar(i))]


def resolve_frames(
    stages: FrameStages,
    todo: list[int],
    per_frame: dict[str, dict[int, Lookup]],
    broken: dict[int, Exception],
) -> None:
    """Resolve the per-frame stages of ``todo`` into ``per_frame``; unreadable frames (a
    missing or damaged file, found when the key or the entry is made) go to ``broken``."""
    for name in PER_FRAME_STAGES:
        tasks, owners = [], []
        for i in todo:
            if i in broken:
                continue
            try:
                tasks.append(getattr(stages, name)(i))
                owners.append(i)
            except FrameDataError as exc:
                broken[i] = exc
        found = stages.cache.resolve(tasks, errors=(FrameDataError,))
        for i, out in zip(owners, found, strict=True):
            if isinstance(out, Exception):
                broken[i] = out
            else:
                per_frame[name][i] = out


def stream(
    settings: Settings, frames: FrameRange, cache: StageCache, indices: list[int]
) -> Iterator[tuple[list, dict, dict, dict]]:
    """Yield ``(pairs, per-frame lookups, pair matches, broken frames)`` chunk by chunk.

    Cooperative fill within a chunk: per-frame stages first, then the pairs ending in the
    chunk; entries another worker is computing right now are deferred (see
    :meth:`StageCache.resolve`). After a chunk only its last frame's data is kept. A frame
    with a blank timestamp line is broken from the start (:func:`ttc.io.frames.missing_time_errors`).
    """
    stages = FrameStages(settings, frames, cache)
    per_frame: dict[str, dict[int, Lookup]] = {name: {} for name in PER_FRAME_STAGES}
    broken: dict[int, Exception] = missing_time_errors(frames.sequence_dir, indices)
    all_pairs = frame_pairs(indices, frames.pairing)
    for start in range(0, len(indices), CHUNK_FRAMES):
        todo = indices[start : start + CHUNK_FRAMES]
        resolve_frames(stages, todo, per_frame, broken)
        pairs = [(p, c) for p, c in all_pairs if c in todo]
        good = [(p, c) for p, c in pairs if p not in broken and c not in broken]
        found = cache.resolve([stages.matches(p, c) for p, c in good])
        yield pairs, per_frame, dict(zip(good, found, strict=True)), broken
        stages.forget(keep=todo[-1])
        for lookups in per_frame.values():
            for i in [i for i in lookups if i != todo[-1]]:
                del lookups[i]
