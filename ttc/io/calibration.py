"""A recording's calibration: the Velodyne → image projection of the official KITTI-raw files
(``calib_cam_to_cam.txt``, ``calib_velo_to_cam.txt``, in the recording folder or its date
folder) or of a KITTI-odometry sequence's ``calib.txt`` (:mod:`ttc.io.kitti_odometry`). Every
reader raises :class:`~ttc.io.frame_errors.FrameDataError` naming the file and the key."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ttc.io import kitti_odometry
from ttc.io.frame_errors import FrameDataError

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


def calibration_entries(text: str, source: Path | str = "<text>") -> dict[str, str]:
    """The ``key: value`` lines of a calibration file as raw strings (no parsing)."""
    entries: dict[str, str] = {}
    for line in text.splitlines():
        key, sep, rest = line.partition(":")
        if sep:
            entries[key.strip()] = rest.strip()
    if not entries:
        raise FrameDataError(source, "no 'key: numbers' lines found")
    return entries


def _numbers(entries: dict[str, str], key: str, path: Path | str) -> np.ndarray:
    """The entry ``key`` as finite float64 numbers; an error naming file, key and value else."""
    raw = entries[key]
    try:
        values = np.array([float(word) for word in raw.split()], dtype=np.float64)
    except ValueError:
        bad = next(w for w in raw.split() if not _is_float(w))
        raise FrameDataError(path, f"'{key}' has a non-numeric value {bad!r}") from None
    if not np.isfinite(values).all():
        bad = raw.split()[int(np.flatnonzero(~np.isfinite(values))[0])]
        raise FrameDataError(path, f"'{key}' has a non-finite value {bad!r}")
    return values


def _is_float(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def parse_calibration_text(text: str, source: Path | str = "<text>") -> dict[str, np.ndarray]:
    """Parse ``key: v1 v2 ...`` lines into finite float arrays.

    Entries whose every word is non-numeric (``calib_time: 15-Mar-2012 11:37:16``) are left
    out; an entry mixing numbers with a non-numeric word (``7.2l5377e+02``) or holding a
    non-finite number raises :class:`FrameDataError` naming the file, key and value.
    """
    entries = calibration_entries(text, source)
    values: dict[str, np.ndarray] = {}
    for key, raw in entries.items():
        if raw and not any(_is_float(word) for word in raw.split()):
            continue  # a date or a name, not numbers
        values[key] = _numbers(entries, key, source)
    return values


def _read_calibration_file(path: Path) -> dict[str, str]:
    if not path.is_file():
        raise FrameDataError(path, "calibration file not found")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise FrameDataError(path, f"unreadable calibration file ({exc})") from exc
    return calibration_entries(text, path)


def _matrix(entries: dict[str, str], key: str, shape: tuple[int, int], path: Path) -> np.ndarray:
    if key not in entries:
        raise FrameDataError(path, f"missing entry '{key}'")
    values = _numbers(entries, key, path)
    if values.size != shape[0] * shape[1]:
        raise FrameDataError(path, f"'{key}' has {values.size} numbers, expected {shape}")
    return values.reshape(shape)


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
    rectifying rotation).
    """
    if projection not in PROJECTIONS:
        raise ValueError(f"projection must be one of {PROJECTIONS}, got {projection!r}")
    if kitti_odometry.is_odometry_sequence(sequence_dir):  # calib.txt: P2 · Tr
        p_rect, velo_to_cam = kitti_odometry.read_calibration(sequence_dir, projection)
        size = kitti_odometry.image_size(sequence_dir)
        return Calibration(p_rect, np.eye(3), velo_to_cam, size, projection)
    sequence_dir = calibration_dir(sequence_dir)
    cam_path, velo_path = sequence_dir / CAM_TO_CAM, sequence_dir / VELO_TO_CAM
    cam = _read_calibration_file(cam_path)
    velo = _read_calibration_file(velo_path)
    velo_to_cam = np.eye(4)
    velo_to_cam[:3, :3] = _matrix(velo, "R", (3, 3), velo_path)
    velo_to_cam[:3, 3] = _matrix(velo, "T", (3, 1), velo_path)[:, 0]
    size = _matrix(cam, "S_rect_02", (1, 2), cam_path)[0] if "S_rect_02" in cam else (1242, 375)
    return Calibration(
        p_rect=_matrix(cam, projection, (3, 4), cam_path),
        r_rect_00=_matrix(cam, "R_rect_00", (3, 3), cam_path),
        velo_to_cam=velo_to_cam,
        image_size=(int(size[0]), int(size[1])),
        projection=projection,
    )
