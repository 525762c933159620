"""KITTI frames: camera images, Velodyne scans, frame times and pairs of a recording (its
calibration: :mod:`ttc.io.calibration`).

Layout of one recording (``kitti/2011_09_26`` under the data root)::

    image_02/data/NNNNNNNNNN.png          left colour camera, rectified
    velodyne_points/data/NNNNNNNNNN.bin   float32 records x, y, z, reflectance
    calib_cam_to_cam.txt                  R_rect_00, P_rect_00, P_rect_02, ...
    calib_velo_to_cam.txt                 R, T  (Velodyne -> camera 0)

The official KITTI-raw layout keeps the calibration one folder up, beside the drive folders
(``<date>/calib_*.txt``, ``<date>/<date>_drive_<drive>_sync/image_02/...``):
:func:`ttc.io.calibration.calibration_dir` finds it there when the recording folder has none.

Every loader raises :class:`FrameDataError` naming the file and what is wrong. Non-finite
lidar coordinates are *dropped and counted* (``LidarScan.n_dropped``), not refused: one bad
record should not cost a frame, and the count makes the damage visible in the results.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from ttc.io import bag_recording, ego_motion, kitti_odometry
from ttc.io.frame_errors import FrameDataError
from ttc.io.ros2_bag import BagMessage, is_bag
from ttc.io.timestamps import MISSING_NS, check_clocks_agree, read_times_ns

IMAGE_DIR = Path("image_02") / "data"
LIDAR_DIR = Path("velodyne_points") / "data"
LIDAR_RECORD_BYTES = 16  # float32 x, y, z, reflectance
SENSOR_RATE_HZ = 10.0


@dataclass(frozen=True)
class LidarScan:
    """One Velodyne scan: ``points`` (N × 4 float32: x, y, z in metres, reflectance)."""

    points: np.ndarray
    path: Path
    n_dropped: int = 0

    def __len__(self) -> int:
        return len(self.points)


def read_lidar_scan(path: Path | str | BagMessage) -> LidarScan:
    """Read a KITTI ``.bin`` scan (or a bag's ``PointCloud2`` message,
    :func:`ttc.io.bag_recording.read_scan`); non-finite records are dropped and counted."""
    if isinstance(path, BagMessage):
        points, n_dropped = bag_recording.read_scan(path)
        return LidarScan(points=points, path=path.source.path, n_dropped=n_dropped)
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


def read_image(path: Path | str | BagMessage) -> np.ndarray:
    """Read an 8-bit BGR image (H × W × 3) from a file or a bag's camera message."""
    if isinstance(path, BagMessage):
        return bag_recording.read_image(path)
    path = Path(path)
    if not path.is_file():
        raise FrameDataError(path, "image not found")
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise FrameDataError(path, "unreadable image (not a valid PNG/JPEG or truncated)")
    return image


@dataclass(frozen=True)
class FrameFiles:
    """Paths of one frame's image and scan (a bag recording's: its two messages)."""

    index: int
    image: Path | BagMessage
    scan: Path | BagMessage


def frame_files(sequence_dir: Path | str, index: int) -> FrameFiles:
    """The image and scan paths of frame ``index`` (10-digit zero-padded names; a KITTI-odometry
    sequence's 6-digit ``image_2/`` and ``velodyne/`` names, :mod:`ttc.io.kitti_odometry`; a
    bag's camera message and its paired scan, :mod:`ttc.io.bag_recording`)."""
    if is_bag(sequence_dir):
        image, scan = bag_recording.frame_messages(bag_recording.as_source(sequence_dir), index)
        return FrameFiles(index, image, scan)
    sequence_dir = Path(sequence_dir)
    if kitti_odometry.is_odometry_sequence(sequence_dir):
        image = kitti_odometry.image_path(sequence_dir, index)
        return FrameFiles(index, image, kitti_odometry.scan_path(sequence_dir, index))
    stem = f"{index:010d}"
    return FrameFiles(
        index=index,
        image=sequence_dir / IMAGE_DIR / f"{stem}.png",
        scan=sequence_dir / LIDAR_DIR / f"{stem}.bin",
    )


def file_identity(path: Path | str | BagMessage) -> tuple[str, int, int]:
    """(resolved path, size in bytes, mtime in ns): identifies a file's content for caching;
    a bag message's: its bag files, topic and header stamp
    (:func:`ttc.io.bag_recording.message_identity`).

    Raises :class:`FrameDataError` naming the file when it does not exist.
    """
    if isinstance(path, BagMessage):
        return bag_recording.message_identity(path)
    path = Path(path).resolve()
    try:
        stat = path.stat()
    except FileNotFoundError:
        raise FrameDataError(path, "file not found") from None
    except OSError as exc:
        raise FrameDataError(path, f"cannot read ({exc.strerror})") from None
    return str(path), stat.st_size, stat.st_mtime_ns


def recording_frames(sequence_dir: Path | str) -> list[int]:
    """Indices of the frames a recording holds (an image or a scan named ``NNNNNNNNNN``, or
    ``NNNNNN`` in a KITTI-odometry sequence; a bag's camera messages 0, 1, …)."""
    if is_bag(sequence_dir):
        return list(range(bag_recording.frame_count(bag_recording.as_source(sequence_dir))))
    sequence_dir = Path(sequence_dir)
    if kitti_odometry.is_odometry_sequence(sequence_dir):
        return kitti_odometry.frames_on_disk(sequence_dir)
    found: set[int] = set()
    for folder, suffix in ((IMAGE_DIR, ".png"), (LIDAR_DIR, ".bin")):
        with contextlib.suppress(FileNotFoundError, NotADirectoryError):
            for entry in os.scandir(sequence_dir / folder):
                stem, ext = os.path.splitext(entry.name)
                if ext == suffix and len(stem) == 10 and stem.isdigit():
                    found.add(int(stem))
    return sorted(found)


def check_frame_range(sequence_dir: Path | str, indices: list[int]) -> None:
    """Raise :class:`FrameDataError` when ``indices`` go past the recording's last frame.

    A frame missing *inside* the recording is not refused here: it becomes a frame error of
    its pairs. The message names the frames that exist.
    """
    present = recording_frames(sequence_dir)
    if not present and is_bag(sequence_dir):
        raise FrameDataError(sequence_dir, "no camera messages")
    sequence_dir = Path(sequence_dir)
    if not present:
        raise FrameDataError(sequence_dir / IMAGE_DIR, "no frames (NNNNNNNNNN.png / .bin) found")
    if indices and max(indices) > present[-1]:
        raise FrameDataError(
            sequence_dir,
            f"frame range {indices[0]}..{max(indices)} goes past the recording's last frame: "
            f"frames {present[0]}–{present[-1]} exist",
        )


#: KITTI timestamp files beside the data folders, in order of preference (lidar first).
TIMESTAMP_FILES = (LIDAR_DIR.parent / "timestamps.txt", IMAGE_DIR.parent / "timestamps.txt")


def timestamps_file(sequence_dir: Path | str) -> Path | None:
    """The timestamps file :func:`read_frame_times` takes dt from (lidar preferred; a
    KITTI-odometry sequence's ``times.txt``), or None (a bag: its path)."""
    if is_bag(sequence_dir):
        return Path(sequence_dir)
    if kitti_odometry.is_odometry_sequence(sequence_dir):
        path = kitti_odometry.times_file(sequence_dir)
        return path if path.is_file() else None
    for name in TIMESTAMP_FILES:
        if (Path(sequence_dir) / name).is_file():
            return Path(sequence_dir) / name
    return None


def frame_clock_ns(sequence_dir: Path | str) -> np.ndarray | None:
    """Nanoseconds since 1970 (int64) of every frame index, from the recording's KITTI
    ``timestamps.txt`` (``velodyne_points/`` preferred over ``image_02/``); a blank line is
    :data:`ttc.io.timestamps.MISSING_NS`; None when the recording has neither file (and for
    a KITTI-odometry sequence, whose ``times.txt`` counts from its start).

    When both files exist, both are read and must agree (:func:`check_clocks_agree`: as many
    lines, every pair's intervals within ``CLOCK_TOLERANCE_S``); the lidar's times are
    returned (KITTI triggers the camera from the lidar's rotation). When one is missing, the
    other alone is used. Raises :class:`FrameDataError` naming the file and line for a
    malformed line, times that are not strictly increasing, and clocks that disagree.
    A bag's frames: its camera messages' header stamps
    (:func:`ttc.io.bag_recording.frame_times`, read on demand).
    """
    if is_bag(sequence_dir):
        return bag_recording.frame_times(bag_recording.as_source(sequence_dir), seconds=False)
    sequence_dir = Path(sequence_dir)
    if kitti_odometry.is_odometry_sequence(sequence_dir):
        return None
    paths = [sequence_dir / name for name in TIMESTAMP_FILES if (sequence_dir / name).is_file()]
    if not paths:
        return None
    clocks = [read_times_ns(path)[0] for path in paths]
    if len(paths) == 2:
        check_clocks_agree(paths[0], clocks[0], paths[1], clocks[1])
    return clocks[0]


def read_frame_times(sequence_dir: Path | str) -> np.ndarray | None:
    """Seconds of every frame index relative to frame 0, from :func:`frame_clock_ns` (the
    lidar's ``timestamps.txt``, checked against the camera's); None when the recording has
    no timestamps file. A blank line is a missing frame: its time is NaN (its pairs become
    frame errors, :func:`missing_time_errors`), and the times count from the first frame
    that has one. Values are rounded to the nanosecond of the file. A KITTI-odometry
    sequence's times come from its ``times.txt`` (:func:`ttc.io.kitti_odometry.read_times`);
    a bag's from its camera messages' header stamps (read on demand).
    """
    if is_bag(sequence_dir):
        return bag_recording.frame_times(bag_recording.as_source(sequence_dir))
    sequence_dir = Path(sequence_dir)
    if kitti_odometry.is_odometry_sequence(sequence_dir):
        return kitti_odometry.read_times(sequence_dir)
    ns = frame_clock_ns(sequence_dir)
    if ns is None:
        return None
    present = ns != MISSING_NS
    origin = ns[np.argmax(present)]
    seconds = (np.where(present, ns, origin) - origin) / 1e9
    seconds[~present] = np.nan
    return seconds


def missing_time_errors(sequence_dir: Path | str, indices: list[int]) -> dict[int, Exception]:
    """A :class:`FrameDataError` for each frame of ``indices`` whose line in the recording's
    timestamps file (:func:`timestamps_file`) is blank; the pairs of such a frame become
    ``frame_error`` rows. Empty when the recording has no timestamps. A bag's: each camera
    message without a scan within the tolerance (:func:`ttc.io.bag_recording.unpaired_errors`)."""
    if is_bag(sequence_dir):
        return bag_recording.unpaired_errors(bag_recording.as_source(sequence_dir), indices)
    times = read_frame_times(sequence_dir)
    if times is None:
        return {}
    path = timestamps_file(sequence_dir)
    return {
        i: FrameDataError(path, f"line {i + 1}: blank timestamp: frame {i} was not recorded")
        for i in indices
        if i < len(times) and np.isnan(times[i])
    }


def pair_interval(times: np.ndarray | None, prev: int, curr: int, step: int = 1) -> float:
    """Seconds between frames ``prev`` and ``curr``: from ``times`` (:func:`read_frame_times`)
    when given, else ``step`` periods of the nominal 10 Hz."""
    if times is None:
        return frame_interval(step)
    return float(np.round(times[curr] - times[prev], 9))


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


#: How a frame range is cut into pairs: every frame with the next (``consecutive``: 0→1, 1→2,
#: …) or frames two by two (``disjoint``: 0→1, 2→3, …; a generated recording of independent
#: pairs, :mod:`ttc.io.scaled_pairs`).
PAIRINGS = ("consecutive", "disjoint")


def frame_pairs(indices: list[int], pairing: str = "consecutive") -> list[tuple[int, int]]:
    """The (previous, current) frame pairs of ``indices`` under ``pairing`` (:data:`PAIRINGS`);
    ``disjoint`` needs an even number of frames."""
    if pairing == "consecutive":
        return list(zip(indices[:-1], indices[1:], strict=True))
    if pairing != "disjoint":
        raise ValueError(f"pairing must be one of {PAIRINGS}, got {pairing!r}")
    if len(indices) % 2:
        raise ValueError(f"disjoint pairs need an even number of frames, got {len(indices)}")
    return list(zip(indices[0::2], indices[1::2], strict=True))


#: A recording's truth table (generated recordings, :mod:`ttc.io.scaled_pairs`): one row per frame
#: pair, labelled by its current ``frame``, with the columns of :data:`TRUTH_COLUMNS`.
TRUTH_FILE = "truth.csv"
#: Columns a truth table gives every row of its pair: the true TTC (s) and distance ratio
#: d_prev / d_curr, the real frame the pair was made from, the target TTC (s) and the number
#: of injected lidar outlier points.
TRUTH_COLUMNS = ("source_frame", "ttc_target", "ttc_true", "ratio_true", "outliers_injected")


def read_truth(sequence_dir: Path | str) -> pd.DataFrame | None:
    """The recording's truth table (``frame`` and :data:`TRUTH_COLUMNS`), None when it has no
    :data:`TRUTH_FILE`; :class:`FrameDataError` naming the file when a column is missing."""
    path = Path(sequence_dir) / TRUTH_FILE
    if is_bag(sequence_dir) or not path.is_file():
        return None
    try:
        table = pd.read_csv(path)
    except (OSError, ValueError) as exc:
        raise FrameDataError(path, f"unreadable truth table ({exc})") from exc
    missing = [c for c in ("frame", *TRUTH_COLUMNS) if c not in table]
    if missing:
        raise FrameDataError(path, f"missing column(s) {', '.join(missing)}")
    return table[["frame", *TRUTH_COLUMNS]]


def with_truth(rows: pd.DataFrame, sequence_dir: Path | str) -> pd.DataFrame:
    """``rows`` (one per frame pair × box pair) with the ego speed of each row's pair
    (:func:`ttc.io.ego_motion.with_ego_speed`: column ``ego_speed_mps``, NaN without oxts or
    poses) and the recording's :data:`TRUTH_COLUMNS` of each row's pair (by ``frame``) when it
    has a truth table."""
    if rows.empty:
        return rows
    rows = ego_motion.with_ego_speed(rows, sequence_dir, frame_clock_ns(sequence_dir))
    truth = read_truth(sequence_dir)
    if truth is None:
        return rows
    return rows.merge(truth, on="frame", how="left", validate="many_to_one")


def frame_interval(step: int = 1, rate_hz: float = SENSOR_RATE_HZ) -> float:
    """Time between two processed frames in seconds (``step`` sensor periods)."""
    return step / rate_hz
