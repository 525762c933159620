"""The tf tree of a ROS 2 bag, on synthetic transforms (exact checks): the ``/tf`` transform
nearest a stamp, and which frame's pose is the ego pose."""

from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np

from ttc.io.bag_recording import ego_frame
from ttc.io.ros2_msgs import frame_transform, tf_edges


def tf(parent: str, child: str, x: float, ns: int) -> NS:
    """A TFMessage of one transform: ``child`` at ``x`` m along ``parent``'s x at ``ns``."""
    header = NS(frame_id=parent, stamp=NS(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000))
    move = NS(translation=NS(x=x, y=0.0, z=0.0), rotation=NS(x=0.0, y=0.0, z=0.0, w=1.0))
    return NS(transforms=[NS(header=header, child_frame_id=child, transform=move)])


def test_each_child_takes_the_transform_stamped_nearest() -> None:
    s = 1_000_000_000
    messages = [tf("base_link", "velodyne", x, t) for x, t in ((1.0, 10 * s), (2.0, 11 * s))]
    messages.append(tf("base_link", "camera", 5.0, 10 * s))
    for at, x in ((10 * s, 1.0), (10 * s + 400_000_000, 1.0), (10 * s + 600_000_000, 2.0)):
        edges = tf_edges(messages, at)
        velo_to_camera = frame_transform("velodyne", "camera", edges)
        assert np.array_equal(velo_to_camera[:3, 3], [x - 5.0, 0.0, 0.0]), at
    assert tf_edges(messages)["velodyne"][1][0, 3] == 2.0  # no stamp: the last one


def test_the_ego_pose_is_the_frame_right_under_the_world() -> None:
    static = tf_edges([tf("base_link", "velodyne", 1.0, 0), tf("base_link", "camera", 1.0, 0)])
    moving = tf_edges([tf("map", "base_link", 3.0, 0)])
    assert ego_frame("velodyne", static, moving) == "base_link"
    # the lidar published on /tf (it moves on base_link): still base_link
    assert ego_frame("velodyne", {}, {**moving, "velodyne": static["velodyne"]}) == "base_link"
    # map -> odom -> base_link: odom -> base_link is the ego pose
    chain = tf_edges([tf("map", "odom", 0.0, 0), tf("odom", "base_link", 3.0, 0)])
    assert ego_frame("velodyne", static, chain) == "base_link"
    # no world frame above: the root of the static tree, as before
    other = tf_edges([tf("vehicle", "base_link", 3.0, 0)])
    assert ego_frame("velodyne", static, other) == "base_link"
    assert ego_frame("velodyne", {}, {}) == "velodyne"
