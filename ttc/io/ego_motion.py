"""The ego vehicle's speed over each frame pair, column :data:`EGO_SPEED` of every run's rows.

From whatever the recording holds:

* a KITTI-**odometry** sequence with ``poses/NN.txt``: the distance between the pair's two
  camera positions over the pair's ``times.txt`` interval
  (:func:`ttc.io.kitti_odometry.pair_ego_speeds`);
* a KITTI-**raw** drive with ``oxts/`` and frame ``timestamps.txt``: the mean GPS/IMU forward
  speed ``vf`` over the pair's interval (:func:`ttc.io.oxts.pair_speeds`);
* a ROS 2 bag: the distance between the ego poses (``/tf`` or an Odometry topic) at the
  pair's camera stamps over their interval (:func:`ttc.io.bag_recording.pair_ego_speeds`);
* otherwise (the Udacity copy of drive 0052, a raw drive without ``oxts/``): NaN.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ttc.io import bag_recording, kitti_odometry, oxts
from ttc.io.ros2_bag import is_bag

#: The per-pair column :func:`with_ego_speed` adds (m/s).
EGO_SPEED = "ego_speed_mps"


def pair_ego_speeds(
    sequence_dir: Path | str, frame_ns: np.ndarray | None, pairs: pd.DataFrame
) -> np.ndarray:
    """Ego speed of each frame pair from the recording's poses or oxts (module docstring).

    Parameters
    ----------
    sequence_dir
        The recording folder.
    frame_ns
        Every frame's time (F,), int64 ns since 1970 (:func:`ttc.io.frames.frame_clock_ns`);
        None: the recording has no frame timestamps (then no oxts speed).
    pairs
        Columns ``prev_frame`` and ``frame`` (P rows).

    Returns
    -------
    numpy.ndarray
        (P,) float, m/s; NaN where unknown.
    """
    if is_bag(sequence_dir):
        prev, curr = pairs["prev_frame"].to_numpy(), pairs["frame"].to_numpy()
        return bag_recording.pair_ego_speeds(bag_recording.as_source(sequence_dir), prev, curr)
    speeds = kitti_odometry.pair_ego_speeds(sequence_dir, pairs)
    if speeds is not None:
        return speeds
    if frame_ns is not None and oxts.has_oxts(sequence_dir):
        prev, curr = pairs["prev_frame"].to_numpy(), pairs["frame"].to_numpy()
        return oxts.pair_speeds(sequence_dir, frame_ns, prev, curr)
    return np.full(len(pairs), np.nan)


def with_ego_speed(
    rows: pd.DataFrame, sequence_dir: Path | str, frame_ns: np.ndarray | None
) -> pd.DataFrame:
    """``rows`` (one or more per frame pair: ``prev_frame``, ``frame``) with the
    :data:`EGO_SPEED` column (m/s) of each row's pair (:func:`pair_ego_speeds`, computed once
    per pair)."""
    keys = ["prev_frame", "frame"]
    pairs = rows[keys].drop_duplicates().reset_index(drop=True)
    speeds = pd.Series(
        pair_ego_speeds(sequence_dir, frame_ns, pairs), index=pd.MultiIndex.from_frame(pairs)
    )
    return rows.assign(**{EGO_SPEED: speeds.reindex(pd.MultiIndex.from_frame(rows[keys])).values})


def input_files(sequence_dir: Path | str, frame_ns: np.ndarray | None, indices: list[int]):
    """The files besides the frames' own that the ego speed of a run over frames ``indices``
    reads (some may not exist): the oxts files of a KITTI-raw drive
    (:func:`ttc.io.oxts.input_files`); none for a KITTI-odometry sequence, whose poses are
    among :func:`ttc.io.kitti_odometry.layout_files`."""
    if is_bag(sequence_dir) or kitti_odometry.is_odometry_sequence(sequence_dir):
        return []
    return oxts.input_files(sequence_dir, frame_ns, indices)
