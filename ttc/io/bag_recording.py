"""A ROS 2 bag as a recording (``dataset=ros2_bag``): frame ``i`` is the ``i``-th message of
the camera topic, paired with the lidar scan nearest to it in header stamp; the calibration
comes from ``CameraInfo`` and the tf tree; the ego speed from the ego pose on ``/tf`` (or a
``nav_msgs/msg/Odometry`` topic). :mod:`ttc.io.frames`, :mod:`ttc.io.calibration` and
:mod:`ttc.io.ego_motion` dispatch here for a :class:`~ttc.io.ros2_bag.BagSource`.

Projection of a lidar point X (homogeneous, the cloud's frame) into pixels:

* ``camera_frame: optical`` (ROS, ``image_geometry``): the camera's tf frame is its optical
  frame before rectification: ``P · R · T_camera←lidar · X``;
* ``camera_frame: rectified``: the camera's tf frame is already the rectified frame and
  holds the stereo baseline, so neither ``R`` nor the translation column of ``P`` apply:
  ``P[:, :3] · T_camera←lidar · X``. ``kitti2mcap`` writes such bags (its camera transform is
  pykitti's ``T_cam2_imu`` = baseline · ``R_rect_00`` · extrinsics, its ``R`` is
  ``R_rect_02`` and its ``P`` is ``P_rect_02``, baseline included): read as ``optical`` the
  baseline counts twice (≈ 45 px / z[m] in u) and ``R_rect_02`` once too often.

Frame times are the camera messages' header stamps; a camera message without a scan
within the tolerance is a per-frame fact (:func:`unpaired_errors`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ttc.io import ros2_msgs as msgs
from ttc.io.frame_errors import FrameDataError
from ttc.io.ros2_bag import (
    BagIndex,
    BagMessage,
    BagSource,
    bag_index,
    file_identities,
    header_stamp_ns,
    read_all,
    read_message,
    read_range,
)

CAMERA_FRAMES = ("optical", "rectified")
TF_STATIC, TF = "/tf_static", "/tf"
#: Seconds around a camera stamp searched for the ``/tf`` transforms nearest to it.
TF_WINDOW_S = 1.0
#: REP 105's world frames: the ego pose is the transform of the frame right under one.
WORLD_FRAMES = ("map", "odom", "earth", "world")
#: Seconds a frame may lie outside the ego poses' span and still take the nearest segment's.
EDGE_TOLERANCE_S = 0.05


def as_source(path: Any) -> BagSource:
    """A :class:`BagSource` of ``path`` (itself when it is one; default topics otherwise)."""
    return path if isinstance(path, BagSource) else BagSource(Path(path))


def _one_of(index: BagIndex, given: str, types: tuple[str, ...], what: str, key: str) -> str:
    """The topic ``given``, else the bag's only topic of one of ``types``."""
    if given:
        found = index.topic(given)
        if found.type not in types:
            raise FrameDataError(
                index.files[0], f"{key}={given} is {found.type}, not {' or '.join(types)}"
            )
        return given
    candidates = [t for kind in types for t in index.of_type(kind)]
    if len(candidates) != 1:
        problem = "no" if not candidates else f"{len(candidates)} ({', '.join(candidates)})"
        raise FrameDataError(
            index.files[0],
            f"{problem} {what} topic: name one with dataset.{key}; {index.listing()}",
        )
    return candidates[0]


def topics(source: BagSource) -> tuple[BagIndex, str, str, str]:
    """(index, image topic, camera_info topic, lidar topic) of a bag recording."""
    index = bag_index(source)
    image = _one_of(index, source.image_topic, (msgs.IMAGE_TYPE, msgs.COMPRESSED_TYPE),
                    "camera image", "image_topic")  # fmt: skip
    info = _one_of(index, source.camera_info_topic, (msgs.CAMERA_INFO_TYPE,), "CameraInfo",
                   "camera_info_topic")  # fmt: skip
    lidar = _one_of(index, source.lidar_topic, (msgs.CLOUD_TYPE,), "PointCloud2", "lidar_topic")
    return index, image, info, lidar


def frame_count(source: BagSource) -> int:
    """Number of frames: the camera topic's messages."""
    index, image, _, _ = topics(source)
    return len(index.topic(image))


class StampTimes:
    """Frame times read on demand: ``times[i]`` decodes camera message ``i``'s header (kept);
    ``np.asarray(times)`` reads them all. Seconds from frame 0, or int64 ns (``seconds=False``)."""

    def __init__(self, stamp: Callable[[int], int], n: int, seconds: bool) -> None:
        self._stamp, self._n, self._seconds = stamp, n, seconds

    def __len__(self) -> int:
        return self._n

    def _value(self, i: int):
        if not -self._n <= i < self._n:
            raise IndexError(i)
        ns = self._stamp(i % self._n)
        return (ns - self._stamp(0)) / 1e9 if self._seconds else ns

    def __getitem__(self, i):
        if isinstance(i, int | np.integer):
            return self._value(int(i))
        return np.asarray([self._value(k) for k in np.arange(self._n)[i]])

    def __array__(self, dtype=None, copy=None):
        return np.asarray([self._value(k) for k in range(self._n)], dtype=dtype)


def frame_times(source: BagSource, seconds: bool = True) -> StampTimes:
    """Every frame's header stamp: seconds from frame 0, or int64 ns since 1970."""
    index, image, _, _ = topics(source)
    return StampTimes(lambda i: header_stamp_ns(index, image, i), frame_count(source), seconds)


def scan_tolerance_s(source: BagSource) -> float:
    """``source.scan_tolerance_s``, else half the lidar's median period (its log times)."""
    if source.scan_tolerance_s is not None:
        return float(source.scan_tolerance_s)
    index, _, _, lidar = topics(source)
    gaps = np.diff(index.topic(lidar).log_ns)
    return float(np.median(gaps)) / 2e9 if len(gaps) else 0.05


def paired_scan(source: BagSource, frame: int) -> tuple[int | None, str]:
    """(position of the scan nearest in header stamp to camera message ``frame``, or None,
    and why none): the candidates are the scans logged around the camera's stamp."""
    index, image, _, lidar = topics(source)
    stamp = header_stamp_ns(index, image, frame)
    log = index.topic(lidar).log_ns
    at = int(np.searchsorted(log, stamp))
    candidates = range(max(at - 1, 0), min(at + 2, len(log)))
    if not candidates:
        return None, f"{lidar} has no messages"
    gaps, damaged = {}, []
    for k in candidates:
        try:
            gaps[k] = abs(header_stamp_ns(index, lidar, k) - stamp)
        except FrameDataError as exc:  # a scan in a damaged chunk: not a candidate
            damaged.append(exc.problem)
    if not gaps:
        return None, f"{image} #{frame}: every {lidar} scan near it is unreadable: {damaged[0]}"
    best = min(gaps, key=gaps.get)
    tolerance = scan_tolerance_s(source)
    if gaps[best] > tolerance * 1e9:
        if damaged:  # the scan it would have had is in a damaged chunk: say that
            return None, f"{image} #{frame}: its {lidar} scan is unreadable: {damaged[0]}"
        return None, (
            f"{image} #{frame}: no {lidar} scan within {tolerance * 1000:.1f} ms of its stamp "
            f"(nearest {gaps[best] / 1e6:.1f} ms); dataset.scan_tolerance_s sets the limit"
        )
    return best, ""


def frame_messages(source: BagSource, frame: int) -> tuple[BagMessage, BagMessage]:
    """(image message, scan message) of a frame; an unpaired frame's scan has position -1."""
    _, image, _, lidar = topics(source)
    scan, _ = paired_scan(source, frame)
    return BagMessage(source, image, frame), BagMessage(source, lidar, -1 if scan is None else scan)


def unpaired_errors(source: BagSource, indices: list[int]) -> dict[int, FrameDataError]:
    """A FrameDataError for each frame of ``indices`` without a scan within the tolerance, or
    whose image stamp cannot be read (a damaged chunk: the error names it)."""
    out = {}
    for i in indices:
        try:
            scan, why = paired_scan(source, i)
        except FrameDataError as exc:  # its own image unreadable (a damaged chunk)
            out[i] = exc
            continue
        if scan is None:
            out[i] = FrameDataError(source.path, why)
    return out


def message_identity(ref: BagMessage) -> tuple[str, int, int]:
    """(bag files + topic + header stamp, size, mtime): a message's identity for caching."""
    files = file_identities(ref.source.path)
    # a frame without a readable scan (none paired, or in a damaged chunk): "none", stable
    stamp = (
        header_stamp_ns(bag_index(ref.source), ref.topic, ref.position)
        if ref.position >= 0
        else "none"
    )
    names = "|".join(f[0] for f in files)
    return f"{names}#{ref.topic}@{stamp}", sum(f[1] for f in files), max(f[2] for f in files)


def _decoded(ref: BagMessage, convert: Callable[[Any], Any]) -> Any:
    """``convert`` of a message; its ValueError becomes a FrameDataError naming the topic."""
    if ref.position < 0:
        raise FrameDataError(ref.source.path, f"{ref.topic}: no scan paired with this frame")
    try:
        return convert(read_message(bag_index(ref.source), ref.topic, ref.position))
    except ValueError as exc:
        if isinstance(exc, FrameDataError):
            raise
        raise FrameDataError(ref.source.path, f"{ref.topic} #{ref.position}: {exc}") from None


def read_image(ref: BagMessage) -> np.ndarray:
    """8-bit BGR image (H × W × 3) of a camera message."""
    return _decoded(ref, msgs.image_bgr)


def read_scan(ref: BagMessage) -> tuple[np.ndarray, int]:
    """(N × 4 float32 points, non-finite points dropped) of a scan message."""
    return _decoded(ref, msgs.cloud_points)


def calibration(source: BagSource) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
    """(P' 3 × 4, R' 3 × 3, T_camera←lidar 4 × 4, (width, height)) with
    ``P' · R' · T`` the projection of ``source.camera_frame`` (module docstring)."""
    index, image, info_topic, lidar = topics(source)
    if source.camera_frame not in CAMERA_FRAMES:
        raise ValueError(
            f"camera_frame must be one of {CAMERA_FRAMES}, got {source.camera_frame!r}"
        )
    info = read_message(index, info_topic, 0)
    try:
        _, r, p = msgs.camera_matrices(info)
    except ValueError as exc:
        raise FrameDataError(source.path, f"{info_topic}: {exc}") from None
    camera = str(info.header.frame_id) or str(read_message(index, image, 0).header.frame_id)
    cloud = str(read_message(index, lidar, 0).header.frame_id)
    t = lidar_to_camera(index, cloud, camera, header_stamp_ns(index, image, 0))
    if source.camera_frame == "rectified":
        p, r = np.hstack([p[:, :3], np.zeros((3, 1))]), np.eye(3)
    return p, r, t, msgs.image_size(info)


def moving_edges(index: BagIndex, at_ns: int) -> dict[str, tuple[str, np.ndarray]]:
    """The ``/tf`` tree at ``at_ns`` (ns): each child frame's transform whose header stamp is
    nearest, among those logged within :data:`TF_WINDOW_S` of it; empty without ``/tf``."""
    if TF not in index.topics:
        return {}
    window = int(TF_WINDOW_S * 1e9)
    moving = read_range(index, TF, at_ns - window, at_ns + window)
    return msgs.tf_edges([m for _, m in moving], at_ns)


def lidar_to_camera(index: BagIndex, cloud: str, camera: str, at_ns: int) -> np.ndarray:
    """4 × 4 lidar → camera at ``at_ns`` (the first camera stamp) from ``/tf_static``, and
    ``/tf`` (:func:`moving_edges`) where the chain goes through a frame published there; a
    FrameDataError naming what is missing and the topics the bag holds."""
    static = read_all(index, TF_STATIC) if TF_STATIC in index.topics else []
    edges = msgs.tf_edges(static)
    found = msgs.frame_transform(cloud, camera, edges)
    if found is None:
        found = msgs.frame_transform(cloud, camera, {**moving_edges(index, at_ns), **edges})
    if found is None:
        where = TF_STATIC if TF_STATIC in index.topics else f"{TF_STATIC} (the bag has none)"
        raise FrameDataError(
            index.files[0],
            f"no transform from the lidar frame {cloud!r} to the camera frame {camera!r} in "
            f"{where} or {TF}; {index.listing()}",
        )
    return found


def bag_problems(source: BagSource) -> list[str]:
    """What keeps a bag from being a recording, in words (empty: nothing): its topics, the
    calibration and transform, the first scan's fields, the image size against CameraInfo."""
    try:
        index, image, info, lidar = topics(source)
        calibration(source)
        first = read_message(index, image, 0)
        size, expected = msgs.image_size(read_message(index, info, 0)), None
        if hasattr(first, "width"):
            expected = msgs.image_size(first)
        else:
            expected = read_image(BagMessage(source, image, 0)).shape[1::-1]
        if tuple(expected) != tuple(size):
            return [f"{source.path}: {image} images are {expected[0]} × {expected[1]} but "
                    f"{info} says {size[0]} × {size[1]}"]  # fmt: skip
        try:
            msgs.cloud_fields(read_message(index, lidar, 0))
        except ValueError as exc:
            return [f"{source.path}: {lidar}: {exc}"]
    except (FrameDataError, ValueError) as exc:
        return [str(exc)]
    return []


def ego_frame(lidar: str, static: dict, moving: dict) -> str:
    """The frame whose pose is the ego pose: walking up from the ``lidar`` frame through the
    ``static`` and ``moving`` edges (:func:`ttc.io.ros2_msgs.tf_edges`), the first whose
    parent is one of :data:`WORLD_FRAMES`; without one, the root of the lidar's static tree."""
    frame = lidar
    for _ in range(len(static) + len(moving)):  # a cycle ends the walk
        if frame not in static and frame not in moving:
            break
        parent = (static.get(frame) or moving[frame])[0]
        if parent in WORLD_FRAMES:
            return frame
        frame = parent
    frame = lidar
    for _ in range(len(static)):
        frame = static.get(frame, (frame,))[0]
    return frame


def _ego_track(source: BagSource, start_ns: int, end_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """(stamps ns (S,), positions (S, 3) m) of the ego pose: the ``/tf`` transforms of
    :func:`ego_frame`, else a single Odometry topic's poses."""
    index, _, _, lidar = topics(source)
    static = msgs.tf_edges(read_all(index, TF_STATIC)) if TF_STATIC in index.topics else {}
    cloud = str(read_message(index, lidar, 0).header.frame_id).lstrip("/")
    frame = ego_frame(cloud, static, moving_edges(index, start_ns))
    margin = 1_000_000_000
    samples = []
    if TF in index.topics:
        for _, m in read_range(index, TF, start_ns - margin, end_ns + margin):
            for t in m.transforms:
                if str(t.child_frame_id).lstrip("/") == frame:
                    v = t.transform.translation
                    samples.append((msgs.stamp_ns(t.header), (v.x, v.y, v.z)))
    odometry = index.of_type(msgs.ODOMETRY_TYPE)
    if not samples and len(odometry) == 1:
        for _, m in read_range(index, odometry[0], start_ns - margin, end_ns + margin):
            p = m.pose.pose.position
            samples.append((msgs.stamp_ns(m.header), (p.x, p.y, p.z)))
    samples.sort(key=lambda s: s[0])
    return np.asarray([s[0] for s in samples], np.int64), np.asarray([s[1] for s in samples], float)


def _position(stamps: np.ndarray, xyz: np.ndarray, t: int) -> np.ndarray:
    """Position at ``t`` (ns): linear between poses, the nearest segment's line up to
    :data:`EDGE_TOLERANCE_S` outside; NaN further out."""
    tol = EDGE_TOLERANCE_S * 1e9
    if len(stamps) < 2 or t < stamps[0] - tol or t > stamps[-1] + tol:
        return np.full(3, np.nan)
    k = int(np.clip(np.searchsorted(stamps, t) - 1, 0, len(stamps) - 2))
    a, b = stamps[k], stamps[k + 1]
    w = (t - a) / (b - a) if b > a else 0.0
    return xyz[k] + w * (xyz[k + 1] - xyz[k])


def pair_ego_speeds(source: BagSource, prev: np.ndarray, curr: np.ndarray) -> np.ndarray:
    """Ego speed (m/s) of each frame pair: the distance between the ego positions at the two
    frames' stamps over their interval; NaN where the bag has no ego pose there."""
    out = np.full(len(prev), np.nan)
    if not len(prev):
        return out
    times = frame_times(source, seconds=False)
    frames = sorted({int(i) for i in [*prev, *curr]})
    ns = {i: int(times[i]) for i in frames}
    stamps, xyz = _ego_track(source, ns[frames[0]], ns[frames[-1]])
    for k, (a, b) in enumerate(zip(prev, curr, strict=True)):
        dt = (ns[int(b)] - ns[int(a)]) / 1e9
        if dt > 0:
            gap = _position(stamps, xyz, ns[int(b)]) - _position(stamps, xyz, ns[int(a)])
            out[k] = float(np.linalg.norm(gap)) / dt
    return out
