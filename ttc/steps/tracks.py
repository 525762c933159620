"""Tracks: chains of box matches (previous box → current box) through a recording.

A track is named by where it starts, ``track_id = first_frame · TRACK_BASE + first_box``
(:func:`track_key`): two chains that start at the same box of the same frame carry the same
id, so a setting's FP.1 chain and the reference's chain of the same object share their id
wherever they agree. A track ends where its box is not matched into the next frame; a current
box without a previous one starts a new track. ``−1``: a row without a current box.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

#: Box indices per frame are below this (YOLO keeps at most a few dozen boxes a frame).
TRACK_BASE = 1000
#: The track id column of a run's rows.
TRACK_ID = "track_id"


def track_key(frame: int, box: int) -> int:
    """The id of a track starting at box ``box`` of frame ``frame``."""
    if not 0 <= box < TRACK_BASE:
        raise ValueError(f"box index {box} outside 0..{TRACK_BASE - 1}")
    return frame * TRACK_BASE + box


def chain_tracks(
    prev_frame: np.ndarray, frame: np.ndarray, prev_box: np.ndarray, curr_box: np.ndarray
) -> np.ndarray:
    """Track id (int64, (N,)) of each box pair ``prev_box`` of ``prev_frame`` → ``curr_box``
    of ``frame`` (N each; box −1: none). Pairs are chained in the order of ``frame``; where two
    current boxes claim the same previous box, the first (lowest ``curr_box``) continues the
    track and the other starts one."""
    prev_frame, frame = np.asarray(prev_frame), np.asarray(frame)
    prev_box, curr_box = np.asarray(prev_box), np.asarray(curr_box)
    out = np.full(len(frame), -1, dtype=np.int64)
    ids: dict[tuple[int, int], int] = {}
    taken: set[tuple[int, int]] = set()
    for i in np.lexsort((curr_box, frame)):
        c = int(curr_box[i])
        if c < 0:
            continue
        f, p = int(frame[i]), int(prev_box[i])
        start = (int(prev_frame[i]), p)
        if p >= 0 and start not in taken:
            taken.add(start)
            tid = ids.get(start, track_key(*start))
        else:
            tid = track_key(f, c)
        ids[(f, c)] = tid
        out[i] = tid
    return out


def with_tracks(rows: pd.DataFrame) -> pd.DataFrame:
    """``rows`` of one run (``prev_frame``, ``frame``, ``prev_box``, ``curr_box``) with the
    :data:`TRACK_ID` column (:func:`chain_tracks`)."""
    if rows.empty:
        return rows.assign(**{TRACK_ID: np.zeros(0, dtype=np.int64)})
    ids = chain_tracks(rows["prev_frame"].to_numpy(), rows["frame"].to_numpy(),
                       rows["prev_box"].to_numpy(), rows["curr_box"].to_numpy())  # fmt: skip
    return rows.assign(**{TRACK_ID: ids})
