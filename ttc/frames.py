"""KITTI-raw frames: calibration files, camera images and Velodyne scans.

Layout of one recording (``kitti/2011_09_26`` under the data root)::

    image_02/data/NNNNNNNNNN.png          left colour camera, rectified
    velodyne_points/data/NNNNNNNNNN.bin   float32 records x, y, z, reflectance
    calib_cam_to_cam.txt                  R_rect_00, P_rect_00, P_rect_02, ...
    calib_velo_to_cam.txt                 R, T  (Velodyne -> camera 0)

Every loader raises :class:`FrameDataError` naming the file and what is wrong. Non-finite
lidar coordinates are *dropped and counted* (``LidarScan.n_dropped``), not refused: one bad
record should not cost a frame, and the count makes the damage visible in the results.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

IMAGE_DIR = Path("image_02") / "data"
LIDAR_DIR = Path("velodyne_points") / "data"
CAM_TO_CAM = "calib_cam_to_cam.txt"
VELO_TO_CAM = "calib_velo_to_cam.txt"
PROJECTIONS = ("P_rect_02", "P_rect_00")
LIDAR_RECORD_BYTES = 16  # float32 x, y, z, reflectance
SENSOR_RATE_HZ = 10.0


class FrameDataError(ValueError):
    """An input file is missing or malformed; ``path`` names it."""

    def __init__(self, path: Path | str, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


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


def parse_calibration_text(text: str, source: Path | str = "<text>") -> dict[str, np.ndarray]:
    """Parse ``key: v1 v2 ...`` lines into float arrays; non-numeric entries are skipped."""
    values: dict[str, np.ndarray] = {}
    for line in text.splitlines():
        key, sep, rest = line.partition(":")
        if not sep:
            continue
        try:
            values[key.strip()] = np.array(rest.split(), dtype=np.float64)
        except ValueError:
            continue  # e.g. calib_time: 15-Mar-2012 11:37:16
    if not values:
        raise FrameDataError(source, "no 'key: numbers' lines found")
    return values


def _read_calibration_file(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise FrameDataError(path, "calibration file not found")
    return parse_calibration_text(path.read_text(), path)


def _matrix(values: dict[str, np.ndarray], key: str, shape: tuple[int, int], path: Path):
    if key not in values:
        raise FrameDataError(path, f"missing entry '{key}'")
    if values[key].size != shape[0] * shape[1]:
        raise FrameDataError(path, f"'{key}' has {values[key].size} numbers, expected {shape}")
    return values[key].reshape(shape)


def load_calibration(sequence_dir: Path | str, projection: str = "P_rect_02") -> Calibration:
    """Read both calibration files of a recording.

    ``projection="P_rect_02"`` is correct for image_02; ``"P_rect_00"`` reproduces the Udacity
    C++ starter (a shift of ≈ 45 px / z[m] in u).
    """
    if projection not in PROJECTIONS:
        raise ValueError(f"projection must be one of {PROJECTIONS}, got {projection!r}")
    sequence_dir = Path(sequence_dir)
    cam_path, velo_path = sequence_dir / CAM_TO_CAM, sequence_dir / VELO_TO_CAM
    cam = _read_calibration_file(cam_path)
    velo = _read_calibration_file(velo_path)
    velo_to_cam = np.eye(4)
    velo_to_cam[:3, :3] = _matrix(velo, "R", (3, 3), velo_path)
    velo_to_cam[:3, 3] = _matrix(velo, "T", (3, 1), velo_path)[:, 0]
    size = cam.get("S_rect_02", np.array([1242.0, 375.0]))
    return Calibration(
        p_rect=_matrix(cam, projection, (3, 4), cam_path),
        r_rect_00=_matrix(cam, "R_rect_00", (3, 3), cam_path),
        velo_to_cam=velo_to_cam,
        image_size=(int(size[0]), int(size[1])),
        projection=projection,
    )


@dataclass(frozen=True)
class LidarScan:
    """One Velodyne scan: ``points`` (N × 4 float32: x, y, z in metres, reflectance)."""

    points: np.ndarray
    path: Path
    n_dropped: int = 0

    def __len__(self) -> int:
        return len(self.points)


def read_lidar_scan(path: Path | str) -> LidarScan:
    """Read a KITTI ``.bin`` scan; non-finite records are dropped and counted."""
    path = Path(path)
    if not path.is_file():
        raise FrameDataError(path, "lidar scan not found")
    size = path.stat().st_size
    if size % LIDAR_RECORD_BYTES:
        raise FrameDataError(
            path,
            f"size {size} bytes is not a multiple of {LIDAR_RECORD_BYTES} (x, y, z, r float32)",
        )
    points = np.fromfile(path, dtype="<f4").reshape(-1, 4)
    finite = np.isfinite(points).all(axis=1)
    n_dropped = int(len(points) - np.count_nonzero(finite))
    if n_dropped:
        points = points[finite]
    return LidarScan(points=points, path=path, n_dropped=n_dropped)


def read_image(path: Path | str) -> np.ndarray:
    """Read an 8-bit BGR image (H × W × 3)."""
    path = Path(path)
    if not path.is_file():
        raise FrameDataError(path, "image not found")
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise FrameDataError(path, "unreadable image (not a valid PNG/JPEG or truncated)")
    return image


@dataclass(frozen=True)
class FrameFiles:
    """Paths of one frame's image and scan."""

    index: int
    image: Path
    scan: Path


def frame_files(sequence_dir: Path | str, index: int) -> FrameFiles:
    """The image and scan paths of frame ``index`` (10-digit zero-padded names)."""
    sequence_dir = Path(sequence_dir)
    stem = f"{index:010d}"
    return FrameFiles(
        index=index,
        image=sequence_dir / IMAGE_DIR / f"{stem}.png",
        scan=sequence_dir / LIDAR_DIR / f"{stem}.bin",
    )


def file_identity(path: Path | str) -> tuple[str, int, int]:
    """(resolved path, size in bytes, mtime in ns): identifies a file's content for caching."""
    path = Path(path).resolve()
    stat = path.stat()
    return str(path), stat.st_size, stat.st_mtime_ns


@dataclass(frozen=True)
class Frame:
    """One synchronised camera image + lidar scan."""

    index: int
    image: np.ndarray
    scan: LidarScan
    files: FrameFiles

    @property
    def gray(self) -> np.ndarray:
        return cv2.cvtColor(self.image, cv2.COLOR_BGR2GRAY)

    def scan_is_short(self, min_points: int) -> bool:
        """True when the scan holds fewer than ``min_points`` points (truncated scan)."""
        return len(self.scan) < min_points


def load_frame(sequence_dir: Path | str, index: int) -> Frame:
    """Load frame ``index`` (image and scan) of a KITTI-raw recording."""
    files = frame_files(sequence_dir, index)
    return Frame(
        index=index, image=read_image(files.image), scan=read_lidar_scan(files.scan), files=files
    )


def frame_indices(first: int, last: int, step: int = 1) -> list[int]:
    """Frame indices ``first, first+step, …, ≤ last``."""
    if step < 1 or last < first or first < 0:
        raise ValueError(f"invalid frame range first={first} last={last} step={step}")
    return list(range(first, last + 1, step))


def frame_interval(step: int = 1, rate_hz: float = SENSOR_RATE_HZ) -> float:
    """Time between two processed frames in seconds (``step`` sensor periods)."""
    return step / rate_hz
