"""Bags for the ROS 2 bag tests: the shared KITTI raw drive 0009 converted by kitti2mcap
(installed --no-deps by .ci/run: its declared opencv-python-headless would overwrite our
OpenCV), variants of it written with the mcap writer, and their configs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from hydra import compose, initialize_config_dir
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer

from experiments.configs.structured import register_configs
from tests.conftest import PROJECT_ROOT, data_root

RAW = Path("kitti_raw") / "2011_09_26"
DRIVE = RAW / "2011_09_26_drive_0009_sync"
IMAGE = "/kitti/camera_color_left/image_raw"
LIDAR = "/kitti/velodyne_points"
_RULE = "=" * 80
_HEADER = f"""{_RULE}
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
{_RULE}
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
_XYZ = "float64 x\nfloat64 y\nfloat64 z\n"
#: Message definitions (ROS 2's concatenated form) of the types the tests write.
SCHEMAS = {
    "sensor_msgs/msg/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data\n"
    + _HEADER,
    "nav_msgs/msg/Odometry": f"""std_msgs/Header header
string child_frame_id
geometry_msgs/PoseWithCovariance pose
geometry_msgs/TwistWithCovariance twist
{_HEADER}{_RULE}
MSG: geometry_msgs/PoseWithCovariance
Pose pose
float64[36] covariance
{_RULE}
MSG: geometry_msgs/Pose
Point position
Quaternion orientation
{_RULE}
MSG: geometry_msgs/Point
{_XYZ}{_RULE}
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
{_RULE}
MSG: geometry_msgs/TwistWithCovariance
Twist twist
float64[36] covariance
{_RULE}
MSG: geometry_msgs/Twist
Vector3 linear
Vector3 angular
{_RULE}
MSG: geometry_msgs/Vector3
{_XYZ}""",
}


def make_bag(out: Path) -> Path:
    """Drive 0009 frames 0-15 as kitti2mcap writes it at ``out`` (≈ 35 MB, ≈ 2 s)."""
    cmd = [sys.executable, "-m", "kitti2mcap", "--date", "2011_09_26", "--drive", "0009",
           "--kitti-dir", str(data_root() / "kitti_raw"), "--output", str(out), "--frames", "16"]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True)
    return out


def rewrite(src: Path, dst: Path, change) -> Path:
    """``src`` written again message by message; ``change(topic, schema name, message)``
    returns ``(schema name, message)``, None to drop it, or a list of ``(topic, schema name,
    message)`` written in its place (the schema of a new name: :data:`SCHEMAS`, else the
    message's own)."""
    with src.open("rb") as f, dst.open("wb") as g:
        writer, schemas = Writer(g), {}
        for schema, channel, message, decoded in make_reader(
            f, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages():
            out = change(channel.topic, schema.name, decoded)
            out = [] if out is None else out if isinstance(out, list) else [(channel.topic, *out)]
            for topic, name, msg in out:
                if name not in schemas:
                    text = SCHEMAS.get(name) or schema.data.decode()
                    schemas[name] = writer.register_msgdef(name, text)
                writer.write_message(topic, schemas[name], msg, message.log_time,
                                     message.publish_time)  # fmt: skip
        writer.finish()
    return dst


def composed(overrides: list[str]):
    register_configs()
    with initialize_config_dir(config_dir=str(PROJECT_ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def bag_config(path: Path, *extra: str):
    return composed(["dataset=kitti2mcap", f"dataset.path={path}", *extra])
