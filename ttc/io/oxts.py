"""A KITTI-raw drive's GPS/IMU packets (``oxts/``) and the ego's forward speed over a frame pair.

Layout, beside the drive's ``image_02/`` and ``velodyne_points/``::

    oxts/dataformat.txt          one line per column: ``name: meaning (unit)``; 30 columns
    oxts/timestamps.txt          one ``YYYY-MM-DD HH:MM:SS.fffffffff`` line per packet
    oxts/data/NNNNNNNNNN.txt     packet NNNNNNNNNN: one line of space-separated numbers

The forward speed is the column named :data:`FORWARD_SPEED` (``vf``, m/s, parallel to the
earth's surface) in ``dataformat.txt``: its position is read from that file, not assumed
(KITTI's file lists 30 names, ``vf`` the 9th). A packet's time is its line of
``timestamps.txt``, matched to the frames' times (:func:`ttc.io.frames.frame_clock_ns`) on the
same clock; packets are not assumed to be one per frame. A pair's speed is the **integral**
of ``vf`` over the pair's interval divided by its length (``vf`` linear between packets:
:func:`mean_speed`), not the mean of the speeds interpolated at its two ends; the two agree
when no packet lies inside the interval.

**Data gaps are per packet**: a missing, blank or malformed packet file (not one number per
column, a non-numeric value, a non-finite ``vf``) or a blank line of ``timestamps.txt`` makes
that packet's speed unknown, and every pair whose interval needs it NaN; the other pairs keep
theirs. A **whole file** that cannot serve (``timestamps.txt`` or ``dataformat.txt`` missing
or unreadable, a malformed or non-increasing time, no ``vf`` column) raises
:class:`ttc.io.frame_errors.FrameDataError` naming the file (and line).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ttc.io.frame_errors import FrameDataError
from ttc.io.timestamps import MISSING_NS, read_times_ns

OXTS_DIR = Path("oxts")
DATA_DIR = OXTS_DIR / "data"
TIMESTAMPS = OXTS_DIR / "timestamps.txt"
DATAFORMAT = OXTS_DIR / "dataformat.txt"
#: The ``dataformat.txt`` name of the forward speed (m/s).
FORWARD_SPEED = "vf"
#: How far (s) a frame's time may lie before the first packet or after the last and still
#: take that packet's speed: half a 10 Hz period. KITTI's synced drives pair each frame with
#: its nearest packet (drive 0009's frame 0 is 12 ms before its first packet); further out
#: the speed is unknown (NaN).
EDGE_TOLERANCE_S = 0.05


def has_oxts(sequence_dir: Path | str) -> bool:
    """True when the recording folder holds an ``oxts/`` folder."""
    return (Path(sequence_dir) / OXTS_DIR).is_dir()


def packet_path(sequence_dir: Path | str, packet: int) -> Path:
    """The file of packet ``packet`` (10-digit zero-padded name)."""
    return Path(sequence_dir) / DATA_DIR / f"{packet:010d}.txt"


def column_names(sequence_dir: Path | str) -> list[str]:
    """The packets' column names in order, from ``oxts/dataformat.txt`` (the text before the
    ``:`` of each non-blank line). Raises :class:`FrameDataError` naming the file (and line)
    when it is missing, unreadable, empty or has a line without ``name:``."""
    path = Path(sequence_dir) / DATAFORMAT
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        raise FrameDataError(path, "oxts column names not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FrameDataError(path, f"unreadable oxts data format ({exc})") from None
    names = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        name, colon, _ = line.partition(":")
        if not colon or not name.strip() or len(name.split()) != 1:
            raise FrameDataError(path, f"line {number}: expected 'name: meaning', got {line!r}")
        names.append(name.strip())
    if not names:
        raise FrameDataError(path, "no column names")
    return names


def forward_speed_column(sequence_dir: Path | str) -> tuple[int, int]:
    """(index of :data:`FORWARD_SPEED` counting from 0, number of columns) of the packets;
    :class:`FrameDataError` naming ``dataformat.txt`` when it has no such column."""
    names = column_names(sequence_dir)
    if FORWARD_SPEED not in names:
        raise FrameDataError(
            Path(sequence_dir) / DATAFORMAT,
            f"no column {FORWARD_SPEED!r} (forward speed) among {len(names)} names",
        )
    return names.index(FORWARD_SPEED), len(names)


def read_packet_times_ns(sequence_dir: Path | str) -> np.ndarray:
    """Nanoseconds since 1970 (int64, one per packet) of ``oxts/timestamps.txt``; a blank
    line (a packet without a time) is :data:`ttc.io.timestamps.MISSING_NS`. Raises
    :class:`FrameDataError` naming the file (and line) when it is missing or unreadable."""
    path = Path(sequence_dir) / TIMESTAMPS
    if not path.is_file():
        raise FrameDataError(path, "oxts timestamps not found (oxts/ has no timestamps.txt)")
    return read_times_ns(path)[0]


def read_packet_value(path: Path, column: int, n_columns: int) -> float:
    """Value of column ``column`` (counting from 0; in the column's unit) of one packet
    file of ``n_columns`` numbers; NaN when the file is missing or unreadable, blank, not
    ``n_columns`` numbers, or the value is not finite."""
    try:
        words = path.read_text().split()
        if len(words) != n_columns:
            return np.nan
        value = float(words[column])
    except (OSError, UnicodeDecodeError, ValueError):
        return np.nan
    return value if np.isfinite(value) else np.nan


def packet_seconds(packet_ns: np.ndarray, origin_ns: int) -> np.ndarray:
    """Seconds after ``origin_ns`` of each packet (float, one per packet). A packet with a
    blank time line lies between its neighbours: it is given the time halfway on the index
    line between the known times around it (its speed is unknown anyway); NaN before the
    first known time and after the last."""
    present = packet_ns != MISSING_NS
    known = np.flatnonzero(present)
    seconds = (packet_ns[known] - origin_ns) / 1e9
    out = np.interp(np.arange(len(packet_ns)), known, seconds)
    out[: known[0]] = np.nan
    out[known[-1] + 1 :] = np.nan
    return out


def bracket(times: np.ndarray, start: float, end: float) -> range | None:
    """The packets a mean over ``[start, end]`` uses.

    Parameters
    ----------
    times
        Packet times (K,), s, strictly increasing and finite.
    start, end
        The interval's ends, s on the same clock.

    Returns
    -------
    range or None
        Positions in ``times`` from the last packet at or before ``start`` to the first at or
        after ``end``; the first (last) packet when ``start`` (``end``) lies before (after)
        all packets by at most :data:`EDGE_TOLERANCE_S`. None when an end is NaN, the
        interval is empty, or it reaches further outside the packets.
    """
    if not (np.isfinite(start) and np.isfinite(end) and start < end and len(times)):
        return None
    if start < times[0] - EDGE_TOLERANCE_S or end > times[-1] + EDGE_TOLERANCE_S:
        return None
    lo = max(int(np.searchsorted(times, start, side="right")) - 1, 0)
    hi = min(int(np.searchsorted(times, end, side="left")), len(times) - 1)
    return range(lo, hi + 1)


def mean_speed(times: np.ndarray, speeds: np.ndarray, start: float, end: float) -> float:
    """Mean speed over ``[start, end]``: the speed integrated over the interval, divided by
    its length (not the mean of the two ends' speeds: packets inside count too).

    Parameters
    ----------
    times
        Packet times (K,), s, strictly increasing and finite.
    speeds
        Packet speeds (K,), m/s; NaN: unknown. The speed is linear between packets and held
        at the first (last) packet's value before (after) them.
    start, end
        The interval's ends, s on the clock of ``times``.

    Returns
    -------
    float
        The mean speed, m/s; NaN when :func:`bracket` finds no packets or any packet it
        names has an unknown speed.
    """
    span = bracket(times, start, end)
    if span is None or np.isnan(speeds[span.start : span.stop]).any():
        return np.nan
    t, v = times[span.start : span.stop], speeds[span.start : span.stop]
    knots = np.concatenate([[start], t[(t > start) & (t < end)], [end]])
    return float(np.trapezoid(np.interp(knots, t, v), knots) / (end - start))


def packet_clock(sequence_dir: Path | str) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(packet seconds after the first known packet time, their packet numbers, whether each
    has its own time line, that origin in ns since 1970) of the packets that have a place on
    the clock (:func:`packet_seconds`: all but blank lines before the first time or after
    the last)."""
    packet_ns = read_packet_times_ns(sequence_dir)
    origin = int(packet_ns[packet_ns != MISSING_NS][0])
    seconds = packet_seconds(packet_ns, origin)
    numbers = np.flatnonzero(np.isfinite(seconds))
    return seconds[numbers], numbers, packet_ns[numbers] != MISSING_NS, origin


def frame_seconds(frame_ns: np.ndarray, origin_ns: int) -> np.ndarray:
    """Seconds after ``origin_ns`` of each frame (NaN for a frame without a time)."""
    present = frame_ns != MISSING_NS
    return np.where(present, (np.where(present, frame_ns, origin_ns) - origin_ns) / 1e9, np.nan)


def needed_packets(
    times: np.ndarray, seconds: np.ndarray, prev: np.ndarray, curr: np.ndarray
) -> list[int]:
    """Positions in ``times`` of every packet the pairs' means use (:func:`bracket`); a pair
    with a frame beyond ``seconds`` (the frames' times, s) needs none."""
    out: set[int] = set()
    for p, c in zip(prev, curr, strict=True):
        if max(p, c) < len(seconds) and (span := bracket(times, seconds[p], seconds[c])):
            out.update(span)
    return sorted(out)


def pair_speeds(
    sequence_dir: Path | str, frame_ns: np.ndarray, prev: np.ndarray, curr: np.ndarray
) -> np.ndarray:
    """Mean forward speed over each frame pair's interval, from the drive's ``oxts/``
    (:func:`mean_speed` of ``vf``). Only the packet files the pairs need are read.

    Parameters
    ----------
    sequence_dir
        The drive folder (holding ``oxts/``).
    frame_ns
        Every frame's time (F,), int64 ns since 1970 (:func:`ttc.io.frames.frame_clock_ns`;
        ``MISSING_NS``: the frame has none).
    prev, curr
        Frame indices (P,) of each pair's previous and current frame.

    Returns
    -------
    numpy.ndarray
        (P,) float, m/s; NaN for a pair with a frame without a time, outside the packets'
        times (beyond :data:`EDGE_TOLERANCE_S`), or needing a packet whose speed is unknown.

    Raises
    ------
    FrameDataError
        Naming ``oxts/timestamps.txt`` or ``oxts/dataformat.txt`` (and the line) when the
        whole file cannot serve (module docstring).
    """
    column, n_columns = forward_speed_column(sequence_dir)
    times, numbers, timed, origin = packet_clock(sequence_dir)
    seconds = frame_seconds(frame_ns, origin)
    speeds = np.full(len(times), np.nan)
    for k in needed_packets(times, seconds, prev, curr):
        if timed[k]:
            speeds[k] = read_packet_value(packet_path(sequence_dir, numbers[k]), column, n_columns)
    known = lambda i: seconds[i] if i < len(seconds) else np.nan  # noqa: E731
    return np.array(
        [mean_speed(times, speeds, known(p), known(c)) for p, c in zip(prev, curr, strict=True)],
        dtype=float,
    )


def input_files(sequence_dir: Path | str, frame_ns: np.ndarray | None, indices: list[int]):
    """The ``oxts/`` files a run over frames ``indices`` reads (some may not exist):
    ``timestamps.txt``, ``dataformat.txt`` and the packet files between the first and the
    last frame's times (:func:`needed_packets`); the first two alone when the frames or the
    packets have no readable times (the run then fails on them or has no ego speed)."""
    fixed = [Path(sequence_dir) / TIMESTAMPS, Path(sequence_dir) / DATAFORMAT]
    if frame_ns is None or not indices or not has_oxts(sequence_dir):
        return fixed
    try:
        times, numbers, _, origin = packet_clock(sequence_dir)
    except FrameDataError:
        return fixed
    ends = np.array([indices[0]]), np.array([indices[-1]])
    used = needed_packets(times, frame_seconds(frame_ns, origin), *ends)
    return fixed + [packet_path(sequence_dir, numbers[k]) for k in used]


def layout_problems(sequence_dir: Path | str) -> list[str]:
    """What is wrong with a drive's ``oxts/`` as a whole, in words (each naming the file):
    ``timestamps.txt`` and ``dataformat.txt`` present and readable, ``vf`` among the columns.
    Nothing without ``oxts/`` (its pairs' ego speed is NaN) and for a bad packet file (that
    packet's pairs' speed is NaN)."""
    if not has_oxts(sequence_dir):
        return []
    problems = []
    for check in (read_packet_times_ns, forward_speed_column):
        try:
            check(sequence_dir)
        except FrameDataError as exc:
            problems.append(str(exc))
    return problems
