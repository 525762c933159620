"""A recording's calibration: the Velodyne → image projection of the official KITTI-raw files
(``calib_cam_to_cam.txt``, ``calib_velo_to_cam.txt``, in the recording folder or its date
folder) or of a KITTI-odometry sequence's ``calib.txt`` (:mod:`ttc.io.kitti_odometry`). Every
reader raises :class:`~ttc.io.frame_errors.FrameDataError` naming the file and the key."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ttc.io import bag_recording, kitti_odometry
from ttc.io.calib_text import matrix, read_calibration_file
from ttc.io.ros2_bag import is_bag

CAM_TO_CAM = "calib_cam_to_cam.txt"
VELO_TO_CAM = "calib_velo_to_cam.txt"
PROJECTIONS = ("P_rect_02", "P_rect_00")


@dataclass(frozen=True)
class Calibration:
    """Camera and Velodyne calibration of one KITTI recording.

    ``velo_to_image`` (3 × 4) maps homogeneous Velodyne points (metres) to homogeneous
    image_02 pixels: ``P_rect · R_rect_00 · [R | T]``.
    """

    p_rect: np.ndarray
    r_rect_00: np.ndarray
    velo_to_cam: np.ndarray
    image_size: tuple[int, int]
    projection: str

    @property
    def velo_to_image(self) -> np.ndarray:
        r_rect = np.eye(4)
        r_rect[:3, :3] = self.r_rect_00
        return self.p_rect @ r_rect @ self.velo_to_cam


def calibration_dir(sequence_dir: Path | str) -> Path:
    """The folder holding a recording's ``calib_*.txt``: the recording folder itself (the
    Udacity layout), else its parent when that holds them (the official KITTI-raw layout,
    ``<date>/calib_*.txt`` beside ``<date>/<date>_drive_NNNN_sync/``); the recording folder
    when neither does, so the error names the file where it was first looked for."""
    sequence_dir = Path(sequence_dir)
    if not (sequence_dir / CAM_TO_CAM).exists() and (sequence_dir.parent / CAM_TO_CAM).exists():
        return sequence_dir.parent
    return sequence_dir


def load_calibration(sequence_dir: Path | str, projection: str = "P_rect_02") -> Calibration:
    """Read both calibration files of a recording.

    ``projection="P_rect_02"`` is correct for image_02; ``"P_rect_00"`` reproduces the Udacity
    C++ starter (a shift of ≈ 45 px / z[m] in u). A KITTI-odometry sequence's ``calib.txt``
    is read by :func:`ttc.io.kitti_odometry.read_calibration` (``P2`` / ``P0`` and ``Tr``, no
    rectifying rotation). A ROS 2 bag's comes from its ``CameraInfo`` and tf tree
    (:func:`ttc.io.bag_recording.calibration`; ``projection`` does not apply).
    """
    if projection not in PROJECTIONS:
        raise ValueError(f"projection must be one of {PROJECTIONS}, got {projection!r}")
    if is_bag(sequence_dir):  # CameraInfo and tf: P · R · T (ttc.io.bag_recording)
        p, r, velo_to_cam, size = bag_recording.calibration(bag_recording.as_source(sequence_dir))
        return Calibration(p, r, velo_to_cam, size, projection)
    if kitti_odometry.is_odometry_sequence(sequence_dir):  # calib.txt: P2 · Tr
        p_rect, velo_to_cam = kitti_odometry.read_calibration(sequence_dir, projection)
        size = kitti_odometry.image_size(sequence_dir)
        return Calibration(p_rect, np.eye(3), velo_to_cam, size, projection)
    sequence_dir = calibration_dir(sequence_dir)
    cam_path, velo_path = sequence_dir / CAM_TO_CAM, sequence_dir / VELO_TO_CAM
    cam = read_calibration_file(cam_path)
    velo = read_calibration_file(velo_path)
    velo_to_cam = np.eye(4)
    velo_to_cam[:3, :3] = matrix(velo, "R", (3, 3), velo_path)
    velo_to_cam[:3, 3] = matrix(velo, "T", (3, 1), velo_path)[:, 0]
    size = matrix(cam, "S_rect_02", (1, 2), cam_path)[0] if "S_rect_02" in cam else (1242, 375)
    return Calibration(
        p_rect=matrix(cam, projection, (3, 4), cam_path),
        r_rect_00=matrix(cam, "R_rect_00", (3, 3), cam_path),
        velo_to_cam=velo_to_cam,
        image_size=(int(size[0]), int(size[1])),
        projection=projection,
    )
