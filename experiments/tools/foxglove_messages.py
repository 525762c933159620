"""Foxglove messages of one exported frame, from arrays and the run's box table.

The schemas are Foxglove's published ones (PyPI ``foxglove-schemas-protobuf``): the camera
image (``foxglove.CompressedImage``), the lidar scan (``foxglove.PointCloud``), the boxes with
their track id and camera, lidar and reference TTC (``foxglove.ImageAnnotations``, and
``foxglove.SceneUpdate`` for a marker at each object's nearest face), and one small JSON
message per tracked box (:func:`track_messages`, :data:`TRACK_SCHEMA`) that Foxglove's Plot
panel draws as a time series per track (``/ttc_bench/ttc{track_id==3}.ttc_camera``).

A box table (:func:`frame_boxes` of :mod:`experiments.tools.export`) has one row per box of a
frame: ``track_id``, ``box`` (the current box id), ``is_lead``, ``box_x``, ``box_y``,
``box_w``, ``box_h`` (pixels), ``ttc_camera``, ``ttc_lidar``, ``ttc_ref`` (seconds; NaN: no
estimate, inf: no collision course), ``camera_reason``, ``lidar_reason``, and from the
object reference ``role``, ``distance_m`` (metres to the nearest face) and ``bearing_deg``
(degrees left of the forward axis).
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import pandas as pd
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.KeyValuePair_pb2 import KeyValuePair
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.Point2_pb2 import Point2
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation
from foxglove_schemas_protobuf.TextPrimitive_pb2 import TextPrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.duration_pb2 import Duration
from google.protobuf.timestamp_pb2 import Timestamp
from scipy.spatial.transform import Rotation

#: Box colours (RGBA 0-1): the lead box yellow, every other box cyan.
LEAD_COLOUR = Color(r=1.0, g=0.85, b=0.0, a=1.0)
BOX_COLOUR = Color(r=0.0, g=0.85, b=1.0, a=1.0)
TEXT_BACKGROUND = Color(r=0.0, g=0.0, b=0.0, a=0.6)
WHITE = Color(r=1.0, g=1.0, b=1.0, a=1.0)
#: Fields of a KITTI scan record (float32 x, y, z in metres, reflectance 0-1): 16 bytes a point.
CLOUD_FIELDS = ("x", "y", "z", "intensity")
#: Edge (m) of the marker cube at an object's nearest face in the 3D scene.
MARKER_M = 0.5
#: A scene entity lasts this long (ns) unless the next frame replaces it (0.1 s at 10 Hz, x2).
ENTITY_LIFETIME_NS = 200_000_000
#: JSON schema of one track's TTC at one frame (:func:`track_messages`).
TRACK_SCHEMA: dict[str, Any] = {
    "title": "ttc_bench.TrackTtc",
    "description": "One tracked box's camera, lidar and reference TTC (s) at one frame; "
    "null: no estimate or no collision course (see the reasons).",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
        },
        "frame": {"type": "integer"},
        "track_id": {"type": "integer"},
        "box": {"type": "integer"},
        "is_lead": {"type": "boolean"},
        "role": {"type": "string"},
        "ttc_camera": {"type": ["number", "null"]},
        "ttc_lidar": {"type": ["number", "null"]},
        "ttc_ref": {"type": ["number", "null"]},
        "camera_reason": {"type": "string"},
        "lidar_reason": {"type": "string"},
    },
}


def stamp(ns: int) -> Timestamp:
    """A protobuf ``Timestamp`` of ``ns`` nanoseconds since 1970."""
    out = Timestamp()
    out.FromNanoseconds(int(ns))
    return out


def ttc_text(seconds: float) -> str:
    """A TTC for a label: ``2.31 s``, ``inf`` (no collision course), ``n/a`` (no estimate)."""
    if math.isnan(seconds):
        return "n/a"
    return f"{seconds:.2f} s" if math.isfinite(seconds) else ("inf" if seconds > 0 else "-inf")


def finite_or_none(seconds: float) -> float | None:
    """``seconds`` when finite, else None (JSON has no NaN or infinity)."""
    return float(seconds) if math.isfinite(seconds) else None


def compressed_image(
    image: np.ndarray, ns: int, frame_id: str, fmt: str = "jpeg", quality: int = 90
) -> CompressedImage:
    """``image`` (H × W × 3 uint8, BGR) encoded as ``fmt`` (``jpeg`` at ``quality``, or ``png``)."""
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)] if fmt == "jpeg" else []
    ok, data = cv2.imencode(".jpg" if fmt == "jpeg" else ".png", image, params)
    if not ok:
        raise ValueError(f"OpenCV could not encode a {image.shape} image as {fmt}")
    return CompressedImage(timestamp=stamp(ns), frame_id=frame_id, data=data.tobytes(), format=fmt)


def point_cloud(points: np.ndarray, ns: int, frame_id: str) -> PointCloud:
    """A scan (N × 4: x, y, z in metres, reflectance) as a ``foxglove.PointCloud`` of float32
    x, y, z, intensity (16 bytes a point) in the lidar's frame ``frame_id``."""
    data = np.ascontiguousarray(np.asarray(points, dtype="<f4").reshape(-1, 4))
    fields = [
        PackedElementField(name=name, offset=4 * k, type=PackedElementField.FLOAT32)
        for k, name in enumerate(CLOUD_FIELDS)
    ]
    pose = Pose(position=Vector3(), orientation=Quaternion(w=1.0))
    return PointCloud(timestamp=stamp(ns), frame_id=frame_id, pose=pose, point_stride=16,
                      fields=fields, data=data.tobytes())  # fmt: skip


def camera_calibration(
    p_rect: np.ndarray, size: tuple[int, int], ns: int, frame_id: str
) -> CameraCalibration:
    """The rectified camera (``p_rect``: 3 × 4 projection, pixels; ``size``: width, height px)
    as a ``foxglove.CameraCalibration``: no distortion, ``K`` its left 3 × 3, ``R`` identity.
    With :func:`frame_transform` Foxglove's Image panel draws the scan on the image."""
    p = np.asarray(p_rect, dtype=float).reshape(3, 4)
    return CameraCalibration(timestamp=stamp(ns), frame_id=frame_id, width=int(size[0]),
                             height=int(size[1]), distortion_model="plumb_bob",
                             D=[0.0] * 5, K=p[:, :3].ravel().tolist(),
                             R=np.eye(3).ravel().tolist(), P=p.ravel().tolist())  # fmt: skip


def frame_transform(
    parent_from_child: np.ndarray, ns: int, parent: str, child: str
) -> FrameTransform:
    """The pose of frame ``child`` in frame ``parent`` (``parent_from_child``: 4 × 4, metres;
    its rotation made orthonormal) as a ``foxglove.FrameTransform``."""
    m = np.asarray(parent_from_child, dtype=float)
    x, y, z, w = Rotation.from_matrix(m[:3, :3]).as_quat()
    t = m[:3, 3]
    return FrameTransform(timestamp=stamp(ns), parent_frame_id=parent, child_frame_id=child,
                          translation=Vector3(x=t[0], y=t[1], z=t[2]),
                          rotation=Quaternion(x=x, y=y, z=z, w=w))  # fmt: skip


def box_label(row: Any) -> str:
    """A box's label: ``#track cam X lidar Y ref Z``."""
    return (
        f"#{int(row.track_id)} cam {ttc_text(row.ttc_camera)} lidar {ttc_text(row.ttc_lidar)} "
        f"ref {ttc_text(row.ttc_ref)}"
    )


def box_metadata(row: Any) -> list[KeyValuePair]:
    """The numbers of a box's label as key-value pairs (repr: exact, ``nan``, ``inf``)."""
    values = {"track_id": int(row.track_id), "box": int(row.box), "is_lead": bool(row.is_lead),
              "ttc_camera": float(row.ttc_camera), "ttc_lidar": float(row.ttc_lidar),
              "ttc_ref": float(row.ttc_ref)}  # fmt: skip
    return [KeyValuePair(key=k, value=repr(v)) for k, v in values.items()]


def box_annotations(boxes: pd.DataFrame, ns: int, header: list[str]) -> ImageAnnotations:
    """Each box's outline (a closed line, lead yellow) and its label above it, plus ``header``
    lines at the image's top left; every element stamped ``ns`` (the image's time)."""
    when = stamp(ns)
    out = ImageAnnotations(timestamp=when)
    for k, line in enumerate(header):
        out.texts.append(TextAnnotation(timestamp=when, position=Point2(x=8.0, y=20.0 + 22.0 * k),
                         text=line, font_size=16.0, text_color=WHITE,
                         background_color=TEXT_BACKGROUND))  # fmt: skip
    for row in boxes.itertuples(index=False):
        x0, y0 = float(row.box_x), float(row.box_y)
        x1, y1 = x0 + float(row.box_w), y0 + float(row.box_h)
        colour = LEAD_COLOUR if row.is_lead else BOX_COLOUR
        corners = [Point2(x=x, y=y) for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1))]
        out.points.append(PointsAnnotation(timestamp=when, type=PointsAnnotation.LINE_LOOP,
                          points=corners, outline_color=colour, thickness=2.0,
                          metadata=box_metadata(row)))  # fmt: skip
        out.texts.append(TextAnnotation(timestamp=when, position=Point2(x=x0, y=max(y0 - 4.0, 12.0)),
                         text=box_label(row), font_size=12.0, text_color=colour,
                         background_color=TEXT_BACKGROUND, metadata=box_metadata(row)))  # fmt: skip
    return out


def scene_update(boxes: pd.DataFrame, ns: int, frame_id: str) -> SceneUpdate:
    """A marker cube and the box's label at each object's nearest face (``distance_m`` ahead,
    ``bearing_deg`` left; boxes without a reference distance have none), in the lidar frame."""
    out = SceneUpdate()
    when, life = stamp(ns), Duration(nanos=ENTITY_LIFETIME_NS)
    for row in boxes.itertuples(index=False):
        if not (np.isfinite(row.distance_m) and np.isfinite(row.bearing_deg)):
            continue
        x = float(row.distance_m)
        y = x * math.tan(math.radians(float(row.bearing_deg)))
        pose = Pose(position=Vector3(x=x, y=y, z=0.0), orientation=Quaternion(w=1.0))
        colour = LEAD_COLOUR if row.is_lead else BOX_COLOUR
        size = Vector3(x=MARKER_M, y=MARKER_M, z=MARKER_M)
        label = Pose(position=Vector3(x=x, y=y, z=1.0), orientation=Quaternion(w=1.0))
        out.entities.append(SceneEntity(
            timestamp=when, frame_id=frame_id, id=f"track {int(row.track_id)}", lifetime=life,
            cubes=[CubePrimitive(pose=pose, size=size, color=colour)],
            texts=[TextPrimitive(pose=label, billboard=True, font_size=14.0, scale_invariant=True,
                                 color=colour, text=box_label(row))],
            metadata=box_metadata(row),
        ))  # fmt: skip
    return out


def track_messages(boxes: pd.DataFrame, ns: int, frame: int) -> list[dict[str, Any]]:
    """One :data:`TRACK_SCHEMA` message per box of ``boxes`` (JSON-ready dicts)."""
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return [
        {
            "timestamp": {"sec": sec, "nsec": nsec},
            "frame": int(frame),
            "track_id": int(row.track_id),
            "box": int(row.box),
            "is_lead": bool(row.is_lead),
            "role": str(row.role),
            "ttc_camera": finite_or_none(row.ttc_camera),
            "ttc_lidar": finite_or_none(row.ttc_lidar),
            "ttc_ref": finite_or_none(row.ttc_ref),
            "camera_reason": str(row.camera_reason),
            "lidar_reason": str(row.lidar_reason),
        }  # fmt: skip
        for row in boxes.itertuples(index=False)
    ]
