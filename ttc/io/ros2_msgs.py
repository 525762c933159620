"""Decoded ROS 2 messages (:func:`ttc.io.ros2_bag.read_message`) to arrays: images
(``sensor_msgs/msg/Image`` in ``bgr8``, ``rgb8``, ``mono8`` and friends,
``sensor_msgs/msg/CompressedImage`` JPEG/PNG), ``PointCloud2`` scans, ``CameraInfo``
matrices and ``tf`` transforms. Every problem raises :class:`ValueError` saying what is
wrong; the caller names the bag and the topic."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
TF_TYPE = "tf2_msgs/msg/TFMessage"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
#: Channels and the conversion to BGR of each raw encoding read.
ENCODINGS = {
    "bgr8": (3, None),
    "rgb8": (3, cv2.COLOR_RGB2BGR),
    "mono8": (1, cv2.COLOR_GRAY2BGR),
    "bgra8": (4, cv2.COLOR_BGRA2BGR),
    "rgba8": (4, cv2.COLOR_RGBA2BGR),
}
#: Names a lidar driver gives the return strength, in order of preference.
INTENSITY_NAMES = ("intensity", "reflectance", "reflectivity", "i")
#: PointField datatypes read (sensor_msgs/msg/PointField constants).
POINT_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def image_size(msg: Any) -> tuple[int, int]:
    """(width, height) of an Image or CameraInfo message."""
    return int(msg.width), int(msg.height)


def image_bgr(msg: Any) -> np.ndarray:
    """An ``Image`` (:data:`ENCODINGS`) or ``CompressedImage`` as 8-bit BGR (H × W × 3)."""
    if hasattr(msg, "format"):  # CompressedImage: JPEG or PNG bytes
        image = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"undecodable compressed image (format {msg.format!r})")
        return image
    encoding = str(msg.encoding).lower()
    if encoding not in ENCODINGS:
        raise ValueError(f"image encoding {msg.encoding!r} not read (one of {list(ENCODINGS)})")
    channels, code = ENCODINGS[encoding]
    width, height, step = int(msg.width), int(msg.height), int(msg.step)
    data = np.frombuffer(bytes(msg.data), np.uint8)
    if step < width * channels or len(data) < step * height:
        raise ValueError(f"{len(data)} bytes do not hold {height} rows of step {step}")
    rows = data[: step * height].reshape(height, step)[:, : width * channels]
    image = rows.reshape(height, width, channels)
    return np.ascontiguousarray(image if code is None else cv2.cvtColor(image, code))


def cloud_fields(msg: Any) -> dict[str, tuple[int, str]]:
    """{name: (offset, numpy type)} of a PointCloud2's fields; ValueError without x/y/z."""
    order = ">" if msg.is_bigendian else "<"
    fields = {
        f.name: (int(f.offset), order + POINT_TYPES[f.datatype])
        for f in msg.fields
        if f.datatype in POINT_TYPES and int(f.count) == 1
    }
    missing = [n for n in "xyz" if n not in fields]
    if missing:
        names = [f.name for f in msg.fields]
        raise ValueError(f"PointCloud2 lacks field(s) {', '.join(missing)} (has {names})")
    return fields


def cloud_points(msg: Any) -> tuple[np.ndarray, int]:
    """``(points, n_dropped)``: N × 4 float32 (x, y, z in metres in the cloud's frame,
    intensity: the first of :data:`INTENSITY_NAMES`, else 0) and the number of points with
    a non-finite coordinate, dropped."""
    fields = cloud_fields(msg)
    step, width, height = int(msg.point_step), int(msg.width), int(msg.height)
    row_step = int(msg.row_step) or step * width
    data = np.frombuffer(bytes(msg.data), np.uint8)
    if len(data) < row_step * height or row_step < step * width:
        raise ValueError(f"{len(data)} bytes do not hold {height} × {width} points")
    rows = data[: row_step * height].reshape(height, row_step)[:, : step * width]
    records = np.ascontiguousarray(rows).reshape(-1)
    intensity = next((n for n in INTENSITY_NAMES if n in fields), None)
    names = ["x", "y", "z"] + ([intensity] if intensity else [])
    dtype = np.dtype(
        {
            "names": names,
            "formats": [fields[n][1] for n in names],
            "offsets": [fields[n][0] for n in names],
            "itemsize": step,
        }
    )
    cloud = records.view(dtype)
    points = np.zeros((len(cloud), 4), np.float32)
    for col, name in enumerate(names):
        points[:, col] = cloud[name]
    finite = np.isfinite(points).all(axis=1)
    n_dropped = int(len(points) - np.count_nonzero(finite))
    return (points[finite] if n_dropped else points), n_dropped


def camera_matrices(msg: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K 3 × 3, R 3 × 3, P 3 × 4) of a CameraInfo; ValueError when P is all zero (an
    uncalibrated camera) or not finite."""
    k = np.asarray(msg.k, float).reshape(3, 3)
    r = np.asarray(msg.r, float).reshape(3, 3)
    p = np.asarray(msg.p, float).reshape(3, 4)
    if not np.isfinite(p).all() or not p.any():
        raise ValueError("CameraInfo has no projection matrix P (uncalibrated camera)")
    if not r.any():  # an unset R means no rectification
        r = np.eye(3)
    return k, r, p


def transform_matrix(transform: Any) -> np.ndarray:
    """4 × 4 of a ``geometry_msgs/Transform``: the child frame's pose in its parent, i.e.
    it maps child coordinates to parent coordinates."""
    q = transform.rotation
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    n = x * x + y * y + z * z + w * w
    if not n > 0:
        raise ValueError("transform with a zero quaternion")
    s = 2.0 / n
    out = np.eye(4)
    out[:3, :3] = [
        [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
        [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
        [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
    ]
    t = transform.translation
    out[:3, 3] = [float(t.x), float(t.y), float(t.z)]
    return out


def stamp_ns(header: Any) -> int:
    """A ``std_msgs/Header``'s stamp in ns since 1970."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def tf_edges(messages: list[Any], at_ns: int | None = None) -> dict[str, tuple[str, np.ndarray]]:
    """{child frame: (parent frame, child → parent 4 × 4)} of TFMessages: for each child the
    transform whose header stamp is nearest ``at_ns`` (None: the last one)."""
    edges, gaps = {}, {}
    for msg in messages:
        for t in msg.transforms:
            child = str(t.child_frame_id).lstrip("/")
            gap = 0 if at_ns is None else abs(stamp_ns(t.header) - at_ns)
            if child not in gaps or gap <= gaps[child]:
                gaps[child] = gap
                edges[child] = (str(t.header.frame_id).lstrip("/"), transform_matrix(t.transform))
    return edges


def _to_root(frame: str, edges: dict[str, tuple[str, np.ndarray]]) -> list[tuple[str, np.ndarray]]:
    """[(frame, frame → that frame's root)] walking up from ``frame``."""
    chain, pose = [(frame, np.eye(4))], np.eye(4)
    while frame in edges and len(chain) <= len(edges):
        frame, step = edges[frame]
        pose = step @ pose
        chain.append((frame, pose))
    return chain


def frame_transform(
    source: str, target: str, edges: dict[str, tuple[str, np.ndarray]]
) -> np.ndarray | None:
    """4 × 4 mapping ``source`` frame coordinates to ``target`` frame coordinates through
    the tree ``edges`` (:func:`tf_edges`); None when they are not connected."""
    up_source = dict(_to_root(source.lstrip("/"), edges))
    for frame, target_to_frame in _to_root(target.lstrip("/"), edges):
        if frame in up_source:
            return np.linalg.inv(target_to_frame) @ up_source[frame]
    return None
