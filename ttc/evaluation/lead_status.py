"""Is there one lead vehicle to judge against? Frames with no vehicle ahead in the ego lane
(``no_lead``) or where the vehicle ahead is another one than before (``lead_change``: a cut-in,
a lane change of the lead or of the ego car) are found from the reference's lidar distances
alone and split the recording into *segments*, each followed by one lead vehicle. The
reference is smoothed within a segment only (:func:`ttc.evaluation.reference.reference_ttc`),
and a frame pair is judged only when both its frames lie in the same segment, so a missing or
swapped lead never produces a reference TTC.

Rules, per frame k of the recording (``distance_m`` NaN: no lead cluster found):

- ``no_lead``: no lead cluster in a *complete* scan (at least :data:`COMPLETE_SCAN_FRACTION`
  of the recording's median scan size). A lead missing from a truncated scan (frame 77 of
  drive 0052) is a missed measurement instead, interpolated within its segment as before.
  So is a lead missing from complete scans for at most :data:`MAX_DROPOUT_S` between two
  measurements that agree (within ``lead_change``'s speed): the van 21 m ahead of KITTI
  odometry sequence 04 leaves no point in the lane crop of frame 20 alone; no lead leaves the
  lane and comes back at the same distance within a few frames.
- ``lead_change``: the rear distance jumps from the previous measured frame by more than
  :data:`MAX_RELATIVE_SPEED_MPS` × the time between them: no car followed at traffic speeds
  closes or opens that fast, a different car at another distance does.
- ``ok`` otherwise.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

LEAD_OK = "ok"
NO_LEAD = "no_lead"
LEAD_CHANGE = "lead_change"
#: The lead status of a frame, in words of the reports.
LEAD_STATUSES: tuple[str, ...] = (LEAD_OK, NO_LEAD, LEAD_CHANGE)
#: Fastest change of the rear distance (m/s) still taken for the same lead vehicle (54 km/h
#: relative speed; the lead of drive 0052 closes at < 1 m/s, 1.5 m between two 10 Hz frames).
MAX_RELATIVE_SPEED_MPS = 15.0
#: A scan with fewer points than this fraction of the recording's median scan is truncated:
#: a lead missing from it is a missed measurement, not an empty lane (frame 77 of drive 0052
#: holds 62 % of the median).
COMPLETE_SCAN_FRACTION = 0.8
#: Longest gap (s) of complete scans without a lead, between two measurements that agree, that
#: is a missed measurement rather than an empty lane (one missing frame at 10 Hz: two empty
#: scans in a row stay ``no_lead``).
MAX_DROPOUT_S = 0.25


def lead_status(
    distance_m: np.ndarray,
    times_s: np.ndarray,
    scan_points: np.ndarray | None = None,
    max_speed: float = MAX_RELATIVE_SPEED_MPS,
) -> np.ndarray:
    """Status (:data:`LEAD_STATUSES`) of every frame (n,) from its lead rear distance (m, NaN:
    none found), its time (s) and its scan's point count (None: every scan complete is not
    known, so a NaN distance is a missed measurement, never ``no_lead``)."""
    d = np.asarray(distance_m, dtype=float)
    t = np.asarray(times_s, dtype=float)
    status = np.full(len(d), LEAD_OK, dtype=object)
    if scan_points is not None and len(d):
        points = np.asarray(scan_points, dtype=float)
        complete = points >= COMPLETE_SCAN_FRACTION * np.nanmedian(points)
        status[np.isnan(d) & complete] = NO_LEAD
    measured = np.flatnonzero(np.isfinite(d))
    for before, k in zip(measured[:-1], measured[1:], strict=True):
        gap = t[k] - t[before]
        if k - before > 1 and gap <= MAX_DROPOUT_S and abs(d[k] - d[before]) <= max_speed * gap:
            status[before + 1 : k] = LEAD_OK  # a dropout: interpolated like a truncated scan
    for before, k in zip(measured[:-1], measured[1:], strict=True):
        if NO_LEAD in status[before + 1 : k]:
            continue  # the lead came back after an empty lane: a new segment anyway
        if abs(d[k] - d[before]) > max_speed * (t[k] - t[before]):
            status[k] = LEAD_CHANGE
    return status


def lead_segments(status: np.ndarray) -> np.ndarray:
    """Segment number (n,) of every frame: consecutive frames followed by one lead vehicle
    share one, counted from 0; a new one starts after a ``no_lead`` run and at each
    ``lead_change``; −1 for ``no_lead`` frames."""
    status = np.asarray(status, dtype=object)
    segment = np.full(len(status), -1, dtype=np.int64)
    current, open_ = -1, False
    for k, s in enumerate(status):
        if s == NO_LEAD:
            open_ = False
            continue
        if not open_ or s == LEAD_CHANGE:
            current, open_ = current + 1, True
        segment[k] = current
    return segment


def not_judged_frames(reference: pd.DataFrame) -> dict[str, list[int]]:
    """Frames of a reference table (``frame``, ``lead``) per status other than ``ok``."""
    if "lead" not in reference:
        return {NO_LEAD: [], LEAD_CHANGE: []}
    return {
        s: [int(f) for f in reference.loc[reference["lead"] == s, "frame"]]
        for s in (NO_LEAD, LEAD_CHANGE)
    }


def not_judged_text(reference: pd.DataFrame) -> str:
    """One sentence naming the frames without one lead vehicle to judge against."""
    frames = not_judged_frames(reference)

    def listed(values: list[int]) -> str:
        return ", ".join(map(str, values)) or "none"

    return (
        f"Frames without a vehicle ahead in the ego lane (`no_lead`): {listed(frames[NO_LEAD])}; "
        f"frames where the vehicle ahead changes (`lead_change`: a cut-in or lane change): "
        f"{listed(frames[LEAD_CHANGE])}. Frame pairs touching them (or spanning them) have "
        "no reference TTC and are not judged."
    )
