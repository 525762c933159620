"""The official KITTI **odometry** layout: one sequence folder, calibration, times and poses.

Layout of sequence ``NN`` under ``<data root>/kitti_odometry/``::

    sequences/NN/image_2/NNNNNN.png     left colour camera, rectified (6-digit names)
    sequences/NN/velodyne/NNNNNN.bin    float32 records x, y, z, reflectance
    sequences/NN/calib.txt              P0..P3 (3 × 4, rectified), Tr (3 × 4, Velodyne -> cam 0)
    sequences/NN/times.txt              seconds since the sequence's start, one line a frame
    poses/NN.txt                        camera 0's pose per frame (3 × 4, row-major), optional

A Velodyne point X projects into image_2 as ``P2 · Tr · X`` (no separate rectifying rotation:
``Tr`` already maps into the rectified camera 0). :mod:`ttc.io.frames` dispatches here when a
recording folder is in this layout (:func:`is_odometry_sequence`); this module returns plain
arrays and paths and raises :class:`ttc.io.frame_errors.FrameDataError` naming the file.
"""

from __future__ import annotations

import contextlib
import os
import struct
from pathlib import Path

import numpy as np
import pandas as pd

from ttc.io.calib_text import matrix, read_calibration_file
from ttc.io.frame_errors import FrameDataError

IMAGE_DIR = Path("image_2")
LIDAR_DIR = Path("velodyne")
CALIB = "calib.txt"
TIMES = "times.txt"
POSES_DIR = "poses"
DIGITS = 6
#: ``dataset.projection`` (the KITTI-raw names) -> the matrix of ``calib.txt`` it means.
PROJECTIONS = {"P_rect_02": "P2", "P_rect_00": "P0"}


def is_odometry_sequence(sequence_dir: Path | str) -> bool:
    """True when ``sequence_dir`` is in the odometry layout (holds ``calib.txt`` or ``image_2/``)."""
    sequence_dir = Path(sequence_dir)
    return (sequence_dir / CALIB).is_file() or (sequence_dir / IMAGE_DIR).is_dir()


def image_path(sequence_dir: Path | str, index: int) -> Path:
    """The image_2 PNG of frame ``index``."""
    return Path(sequence_dir) / IMAGE_DIR / f"{index:0{DIGITS}d}.png"


def scan_path(sequence_dir: Path | str, index: int) -> Path:
    """The Velodyne ``.bin`` of frame ``index``."""
    return Path(sequence_dir) / LIDAR_DIR / f"{index:0{DIGITS}d}.bin"


def frames_on_disk(sequence_dir: Path | str) -> list[int]:
    """Indices of the frames the sequence holds (an image or a scan named ``NNNNNN``)."""
    found: set[int] = set()
    for folder, suffix in ((IMAGE_DIR, ".png"), (LIDAR_DIR, ".bin")):
        with contextlib.suppress(FileNotFoundError, NotADirectoryError):
            for entry in os.scandir(Path(sequence_dir) / folder):
                stem, ext = os.path.splitext(entry.name)
                if ext == suffix and len(stem) == DIGITS and stem.isdigit():
                    found.add(int(stem))
    return sorted(found)


def read_calibration(sequence_dir: Path | str, projection: str) -> tuple[np.ndarray, np.ndarray]:
    """``(P, velo_to_cam)`` of the sequence: ``P`` (3 × 4, pixels) the rectified projection
    ``projection`` names (:data:`PROJECTIONS`: ``P_rect_02`` -> ``P2``), ``velo_to_cam``
    (4 × 4, metres) ``Tr`` made homogeneous. Raises :class:`FrameDataError` naming
    ``calib.txt`` and the key (missing, non-numeric, non-finite, wrong count)."""
    if projection not in PROJECTIONS:
        raise ValueError(f"projection must be one of {tuple(PROJECTIONS)}, got {projection!r}")
    path = Path(sequence_dir) / CALIB
    entries = read_calibration_file(path)
    velo_to_cam = np.eye(4)
    velo_to_cam[:3, :] = matrix(entries, "Tr", (3, 4), path)
    return matrix(entries, PROJECTIONS[projection], (3, 4), path), velo_to_cam


def image_size(sequence_dir: Path | str) -> tuple[int, int]:
    """(width, height) in pixels of the sequence's first image, from its PNG header."""
    frames = frames_on_disk(sequence_dir)
    path = image_path(sequence_dir, frames[0] if frames else 0)
    try:
        with path.open("rb") as f:
            header = f.read(24)
    except OSError as exc:
        raise FrameDataError(path, f"cannot read the image size ({exc})") from None
    if header[:8] != b"\x89PNG\r\n\x1a\n" or len(header) < 24:
        raise FrameDataError(path, "not a PNG: cannot read the image size")
    width, height = struct.unpack(">II", header[16:24])
    return int(width), int(height)


def times_file(sequence_dir: Path | str) -> Path:
    """The sequence's ``times.txt``."""
    return Path(sequence_dir) / TIMES


def read_times(sequence_dir: Path | str) -> np.ndarray | None:
    """Seconds of every frame relative to frame 0 (``times.txt``), None without the file.
    A blank line is a missing frame (NaN). Raises :class:`FrameDataError` naming the file and
    line for a non-numeric line and for times that do not strictly increase."""
    path = times_file(sequence_dir)
    if not path.is_file():
        return None
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise FrameDataError(path, f"unreadable times file ({exc})") from exc
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise FrameDataError(path, "no times")
    seconds = np.array([_seconds(line, path, n) for n, line in enumerate(lines, 1)])
    present = np.flatnonzero(~np.isnan(seconds))
    back = np.flatnonzero(np.diff(seconds[present]) <= 0)
    if back.size:
        k, before = int(present[back[0] + 1]), int(present[back[0]])
        raise FrameDataError(
            path,
            f"line {k + 1}: time {lines[k].strip()!r} is not after line {before + 1}'s "
            f"{lines[before].strip()!r} (times must strictly increase)",
        )
    return seconds - seconds[present[0]] if present.size else seconds


def _seconds(line: str, path: Path, number: int) -> float:
    """One line of ``times.txt`` in seconds; NaN for a blank line."""
    if not line.strip():
        return np.nan
    try:
        value = float(line)
    except ValueError:
        raise FrameDataError(path, f"line {number}: malformed time {line!r}") from None
    if not np.isfinite(value):
        raise FrameDataError(path, f"line {number}: non-finite time {line!r}")
    return value


def poses_file(sequence_dir: Path | str) -> Path:
    """``poses/NN.txt`` beside ``sequences/`` for sequence folder ``sequences/NN``."""
    sequence_dir = Path(sequence_dir)
    return sequence_dir.parent.parent / POSES_DIR / f"{sequence_dir.name}.txt"


def read_positions(sequence_dir: Path | str) -> np.ndarray | None:
    """Camera 0's position (N × 3, metres, in the first frame's camera coordinates) of every
    frame from ``poses/NN.txt``; None without the file. Raises :class:`FrameDataError`
    naming the file and line for a line that is not 12 numbers."""
    path = poses_file(sequence_dir)
    if not path.is_file():
        return None
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        words = line.split()
        if not words:
            continue
        try:
            values = [float(w) for w in words]
        except ValueError:
            raise FrameDataError(path, f"line {number}: non-numeric pose {line!r}") from None
        if len(values) != 12:
            raise FrameDataError(path, f"line {number}: {len(values)} numbers, expected 12")
        rows.append(values)
    return np.array(rows).reshape(-1, 3, 4)[:, :, 3] if rows else None


def ego_speeds(positions: np.ndarray, times: np.ndarray, pairs: pd.DataFrame) -> np.ndarray:
    """Ego speed (m/s) of each frame pair (``prev_frame``, ``frame`` columns): the distance
    between the two poses' positions over the time between the frames; NaN where a frame
    has no pose or no time."""
    prev, curr = pairs["prev_frame"].to_numpy(), pairs["frame"].to_numpy()
    known = (curr < len(positions)) & (curr < len(times)) & (prev >= 0)
    speed = np.full(len(pairs), np.nan)
    p, c = prev[known], curr[known]
    speed[known] = np.linalg.norm(positions[c] - positions[p], axis=1) / (times[c] - times[p])
    return speed


def pair_ego_speeds(sequence_dir: Path | str, pairs: pd.DataFrame) -> np.ndarray | None:
    """Ego speed (m/s, one per row of ``pairs``: ``prev_frame``, ``frame``) of an odometry
    sequence from ``poses/NN.txt`` and ``times.txt`` (:func:`ego_speeds`); None for another
    layout or without either file (:func:`ttc.io.ego_motion.with_ego_speed` makes it NaN)."""
    if not is_odometry_sequence(sequence_dir):
        return None
    positions, times = read_positions(sequence_dir), read_times(sequence_dir)
    if positions is None or times is None:
        return None
    return ego_speeds(positions, times, pairs)


def layout_files(sequence_dir: Path | str) -> list[Path]:
    """The sequence's files besides its frames: calibration, times and poses."""
    return [Path(sequence_dir) / CALIB, times_file(sequence_dir), poses_file(sequence_dir)]


def layout_problems(sequence_dir: Path | str) -> list[str]:
    """What is wrong with an odometry sequence beyond its frames, in words: its
    ``calib.txt`` must hold ``P2`` and ``Tr``, its ``times.txt`` be there and readable."""
    problems = []
    try:
        read_calibration(sequence_dir, "P_rect_02")
    except FrameDataError as exc:
        problems.append(str(exc))
    try:
        if read_times(sequence_dir) is None:
            problems.append(f"{times_file(sequence_dir)}: times file not found")
    except FrameDataError as exc:
        problems.append(str(exc))
    return problems
