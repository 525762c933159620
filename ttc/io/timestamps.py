"""KITTI ``timestamps.txt`` files: one ``YYYY-MM-DD HH:MM:SS.fffffffff`` line per frame or
packet, read to integer nanoseconds since 1970 (UTC assumed).

Shared by the frames' clocks (:mod:`ttc.io.frames`: ``velodyne_points/`` and ``image_02/``)
and the GPS/IMU packets' (:mod:`ttc.io.oxts`). A **blank** line is a frame or packet KITTI
published without data (drive 0009's lidar files are blank at frames 177–180):
:data:`MISSING_NS`. Raises :class:`ttc.io.frame_errors.FrameDataError` naming the file and line.
"""

from __future__ import annotations

import datetime as dt
import re
from pathlib import Path

import numpy as np

from ttc.io.frame_errors import FrameDataError

_TIMESTAMP = re.compile(r"(\d{4})-(\d{2})-(\d{2}) (\d{2}):(\d{2}):(\d{2})(?:\.(\d{1,9}))?")
#: A blank line of a ``timestamps.txt`` (a frame without this sensor's data), in nanoseconds.
MISSING_NS = np.iinfo(np.int64).min
#: Largest disagreement (s) between the camera's and the lidar's interval of one frame pair:
#: a tenth of the 10 Hz period. One dt serves the lidar and the camera TTC of a pair, so
#: clocks further apart would scale one of them silently by more than 10 %.
CLOCK_TOLERANCE_S = 0.01


def timestamp_ns(line: str, path: Path, number: int) -> int:
    """Nanoseconds since 1970 of one ``YYYY-MM-DD HH:MM:SS.fffffffff`` line (UTC assumed);
    :class:`FrameDataError` naming ``path`` and line ``number`` when it is malformed."""
    match = _TIMESTAMP.fullmatch(line.strip())
    try:
        if match is None:
            raise ValueError("expected 'YYYY-MM-DD HH:MM:SS.fffffffff'")
        year, month, day, hour, minute, second = (int(g) for g in match.groups()[:6])
        when = dt.datetime(year, month, day, hour, minute, second, tzinfo=dt.UTC)
    except ValueError as exc:
        raise FrameDataError(path, f"line {number}: malformed timestamp {line!r} ({exc})") from None
    fraction = (match.group(7) or "").ljust(9, "0")
    return int(when.timestamp()) * 1_000_000_000 + int(fraction or 0)


def read_times_ns(path: Path) -> tuple[np.ndarray, list[str]]:
    """Nanoseconds since 1970 (int64, one per line) of one KITTI ``timestamps.txt`` and its
    lines; a blank line is :data:`MISSING_NS`, trailing blank lines are dropped.

    Raises :class:`FrameDataError` naming the file (and line) when it cannot be read, holds
    no timestamp, has a malformed line, or times that do not strictly increase (blank lines
    skipped).
    """
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise FrameDataError(path, f"unreadable timestamps file ({exc})") from exc
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise FrameDataError(path, "no timestamps")
    ns = [
        timestamp_ns(line, path, number) if line.strip() else MISSING_NS
        for number, line in enumerate(lines, start=1)
    ]
    last = None  # index of the previous present line
    for number in range(len(ns)):
        if ns[number] == MISSING_NS:
            continue
        if last is not None and ns[number] <= ns[last]:
            raise FrameDataError(
                path,
                f"line {number + 1}: time {lines[number].strip()!r} is not after line "
                f"{last + 1}'s {lines[last].strip()!r} (times must strictly increase)",
            )
        last = number
    return np.array(ns, dtype=np.int64), lines


def check_clocks_agree(lidar: Path, lidar_ns: np.ndarray, camera: Path, camera_ns: np.ndarray):
    """Raise :class:`FrameDataError` naming the camera file (and line) when it does not list
    as many frames as the lidar file, or when a frame pair's camera interval differs from its
    lidar interval by more than :data:`CLOCK_TOLERANCE_S`."""
    if len(camera_ns) != len(lidar_ns):
        raise FrameDataError(
            camera, f"{len(camera_ns)} timestamps, but {lidar} has {len(lidar_ns)} (one per frame)"
        )
    gap = np.abs(np.diff(camera_ns) - np.diff(lidar_ns)) / 1e9
    present = (camera_ns != MISSING_NS) & (lidar_ns != MISSING_NS)
    bad = np.flatnonzero((gap > CLOCK_TOLERANCE_S) & present[1:] & present[:-1])
    if bad.size:
        k = int(bad[0]) + 1  # frame k: the pair (k - 1, k), line k + 1
        raise FrameDataError(
            camera,
            f"line {k + 1}: the camera's interval of frames {k - 1}->{k} differs from the "
            f"lidar's ({lidar}) by {gap[k - 1] * 1e3:.1f} ms (> {CLOCK_TOLERANCE_S * 1e3:.0f} ms)",
        )
