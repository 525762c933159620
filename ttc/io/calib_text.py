"""The text of KITTI calibration files: ``key: v1 v2 ...`` lines, read into finite numbers with
errors that name the file, the key and the value (:class:`~ttc.io.frame_errors.FrameDataError`).
Shared by the KITTI-raw files (:mod:`ttc.io.calibration`) and the odometry ``calib.txt``
(:mod:`ttc.io.kitti_odometry`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ttc.io.frame_errors import FrameDataError


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


def numbers(entries: dict[str, str], key: str, path: Path | str) -> np.ndarray:
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
        values[key] = numbers(entries, key, source)
    return values


def read_calibration_file(path: Path) -> dict[str, str]:
    """:func:`calibration_entries` of the file ``path`` (errors name it: missing, unreadable,
    no entries)."""
    if not path.is_file():
        raise FrameDataError(path, "calibration file not found")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise FrameDataError(path, f"unreadable calibration file ({exc})") from exc
    return calibration_entries(text, path)


def matrix(entries: dict[str, str], key: str, shape: tuple[int, int], path: Path) -> np.ndarray:
    """Entry ``key`` as a finite matrix of ``shape``; an error naming the file and key else."""
    if key not in entries:
        raise FrameDataError(path, f"missing entry '{key}'")
    values = numbers(entries, key, path)
    if values.size != shape[0] * shape[1]:
        raise FrameDataError(path, f"'{key}' has {values.size} numbers, expected {shape}")
    return values.reshape(shape)
