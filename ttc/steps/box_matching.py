"""FP.1: match the object boxes of the previous frame to those of the current frame.

Boxes are ``roi`` arrays (M × 4: x, y, w, h in pixels) with ``cv::Rect`` semantics: a box
contains the pixel (u, v) when ``x ≤ u < x + w`` and ``y ≤ v < y + h``. Keypoint matches are
index arrays ``prev_idx``, ``curr_idx`` into the previous / current keypoint coordinates.

:func:`count_shared_matches` builds the P × C matrix of matches shared by every (previous,
current) box pair; a strategy of :data:`BOX_MATCHING_STRATEGIES` turns it into box pairs.
A keypoint inside two overlapping boxes counts for both.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


def shrink_rois(roi: np.ndarray, factor: float) -> np.ndarray:
    """Boxes (M × 4 float, pixels) shrunk about their centres by ``factor`` (0 ≤ factor < 1).

    Each box becomes ``(x + f·w/2, y + f·h/2, w·(1 − f), h·(1 − f))``.
    """
    if not 0.0 <= factor < 1.0:
        raise ValueError(f"shrink factor must be in [0, 1), got {factor}")
    rois = np.asarray(roi, dtype=np.float64).reshape(-1, 4)
    half = 0.5 * factor * rois[:, 2:4]
    return np.hstack([rois[:, 0:2] + half, rois[:, 2:4] * (1.0 - factor)])


def _box_membership(uv: np.ndarray, rois: np.ndarray) -> np.ndarray:
    """Membership matrix transposed (M × N bool); rows are contiguous per box (faster)."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    rois = np.asarray(rois, dtype=np.float64).reshape(-1, 4)
    u, v = uv[:, 0], uv[:, 1]
    x, y = rois[:, 0:1], rois[:, 1:2]
    return (u >= x) & (u < x + rois[:, 2:3]) & (v >= y) & (v < y + rois[:, 3:4])


def points_in_rois(uv: np.ndarray, rois: np.ndarray) -> np.ndarray:
    """Membership matrix (N × M bool): pixel ``uv[n]`` (N × 2) lies in box ``rois[m]`` (M × 4).

    Half-open intervals ``x ≤ u < x + w``, ``y ≤ v < y + h``; NaN pixels are in no box.
    """
    return _box_membership(uv, rois).T


@dataclass(frozen=True)
class BoxCounts:
    """Keypoint matches per box pair.

    ``counts[p, c]``: matches whose previous keypoint is in (shrunk) previous box p and whose
    current keypoint is in (shrunk) current box c. ``prev_totals[p]`` / ``curr_totals[c]``:
    matches whose previous / current keypoint is in that box, wherever the other end lies.
    """

    counts: np.ndarray  # (P, C) int64
    prev_totals: np.ndarray  # (P,) int64
    curr_totals: np.ndarray  # (C,) int64


@dataclass(frozen=True)
class BoxMatches:
    """Matched box pairs, sorted by current box: indices and their shared match count."""

    prev_box: np.ndarray  # (K,) int64
    curr_box: np.ndarray  # (K,) int64
    shared: np.ndarray  # (K,) int64

    def __len__(self) -> int:
        return len(self.curr_box)


def count_shared_matches(
    prev_xy: np.ndarray,
    curr_xy: np.ndarray,
    prev_idx: np.ndarray,
    curr_idx: np.ndarray,
    prev_rois: np.ndarray,
    curr_rois: np.ndarray,
    shrink: float = 0.1,
) -> BoxCounts:
    """Count the matches shared by every (previous box, current box) pair.

    ``prev_xy`` / ``curr_xy`` are keypoint pixel coordinates (N × 2), ``prev_idx`` /
    ``curr_idx`` the matched keypoint indices, the rois are boxes (x, y, w, h pixels) shrunk
    by ``shrink`` before the containment test, so points in the border band do not count.
    """
    prev_pts = np.asarray(prev_xy, dtype=np.float64).reshape(-1, 2)[np.asarray(prev_idx)]
    curr_pts = np.asarray(curr_xy, dtype=np.float64).reshape(-1, 2)[np.asarray(curr_idx)]
    # (boxes × matches) as float32: BLAS matmul, exact for counts below 2**24.
    in_prev = _box_membership(prev_pts, shrink_rois(prev_rois, shrink)).astype(np.float32)
    in_curr = _box_membership(curr_pts, shrink_rois(curr_rois, shrink)).astype(np.float32)
    return BoxCounts(
        counts=(in_prev @ in_curr.T).astype(np.int64),
        prev_totals=in_prev.sum(axis=1).astype(np.int64),
        curr_totals=in_curr.sum(axis=1).astype(np.int64),
    )


@dataclass(frozen=True)
class BoxMatchingParams:
    """FP.1 strategy and its parameters.

    ``min_confidence``: overlap_confidence's acceptance threshold on shared / (matches in the
    current box), exclusive. ``min_count``: least shared matches for a pair in mutual_best,
    greedy_matrix and hungarian; 1 by default for all three (hungarian included), so a sweep
    compares the assignment rules, not thresholds: it only drops the zero-count pairs the
    Hungarian assignment makes to complete a one-to-one matching. Raise it as its own sweep
    value to drop pairs held together by a stray match or two. ``shrink``: box shrink factor
    for counting (0–1).
    """

    name: str = "mutual_best"
    min_confidence: float = 0.5
    min_count: int = 1
    shrink: float = 0.1

    def __post_init__(self) -> None:
        if self.name not in BOX_MATCHING_STRATEGIES:
            known = ", ".join(BOX_MATCHING_STRATEGIES)
            raise ValueError(f"unknown box matching strategy {self.name!r}; known: {known}")
        if not 0.0 <= self.min_confidence < 1.0:
            raise ValueError(f"min_confidence must be in [0, 1), got {self.min_confidence}")
        if self.min_count < 1:
            raise ValueError(f"min_count must be >= 1, got {self.min_count}")
        if not 0.0 <= self.shrink < 1.0:
            raise ValueError(f"shrink must be in [0, 1), got {self.shrink}")


def _box_matches(prev_box, curr_box, counts: np.ndarray) -> BoxMatches:
    prev_box = np.asarray(prev_box, dtype=np.int64)
    curr_box = np.asarray(curr_box, dtype=np.int64)
    order = np.argsort(curr_box, kind="stable")
    prev_box, curr_box = prev_box[order], curr_box[order]
    return BoxMatches(prev_box, curr_box, counts[prev_box, curr_box].astype(np.int64))


def overlap_confidence(counts: BoxCounts, params: BoxMatchingParams) -> BoxMatches:
    """Seed 000: each current box takes its best previous box if confident enough.

    For current box c, confidence(p, c) = counts[p, c] / curr_totals[c]: the share of the
    matches inside c that come from previous box p. (Seed 000's "totalkpts" read as the current
    box's total: its loop asks, per current box, where its keypoints came from; with this
    denominator the most-shared previous box is also the most confident one, and > 0.5 means
    a majority.) Current boxes are visited in index order;
    c takes the previous box with most shared matches among those free or held by a pair of
    lower confidence, if its confidence exceeds ``min_confidence``. A held box changes hands
    and the displaced current box is matched again the same way (a stack instead of recursion).
    Each hand-over strictly raises a previous box's confidence, so this terminates.
    """
    shared = counts.counts
    n_prev, n_curr = shared.shape
    with np.errstate(divide="ignore", invalid="ignore"):
        conf = np.where(shared > 0, shared / counts.curr_totals[None, :], 0.0)
    owner = np.full(n_prev, -1, dtype=np.int64)  # current box holding previous box p
    owner_conf = np.zeros(n_prev)
    pending = list(range(n_curr))[::-1]
    while pending:
        c = pending.pop()
        eligible = (shared[:, c] > 0) & ((owner < 0) | (conf[:, c] > owner_conf))
        if not eligible.any():
            continue
        p = int(np.argmax(np.where(eligible, shared[:, c], -1)))
        if conf[p, c] <= params.min_confidence:
            continue
        if owner[p] >= 0:
            pending.append(int(owner[p]))
        owner[p], owner_conf[p] = c, conf[p, c]
    held = np.flatnonzero(owner >= 0)
    return _box_matches(held, owner[held], shared)


def mutual_best(counts: BoxCounts, params: BoxMatchingParams) -> BoxMatches:
    """Seed 001: (p, c) when c is p's best current box and p is c's best previous box.

    Ties go to the lower index; pairs below ``min_count`` shared matches are dropped.
    """
    shared = counts.counts
    if shared.size == 0:
        return _box_matches([], [], shared)
    best_curr = np.argmax(shared, axis=1)  # per previous box
    best_prev = np.argmax(shared, axis=0)  # per current box
    prev = np.arange(shared.shape[0])
    mutual = (best_prev[best_curr] == prev) & (shared[prev, best_curr] >= params.min_count)
    return _box_matches(prev[mutual], best_curr[mutual], shared)


def greedy_matrix(counts: BoxCounts, params: BoxMatchingParams) -> BoxMatches:
    """Seed 002: take the largest cell, clear its row and column, repeat while ≥ ``min_count``.

    Ties go to the first cell in row-major order.
    """
    work = counts.counts.astype(np.int64, copy=True)
    prev, curr = [], []
    for _ in range(min(work.shape)):
        flat = int(np.argmax(work))
        p, c = divmod(flat, work.shape[1])
        if work[p, c] < params.min_count:
            break
        prev.append(p)
        curr.append(c)
        work[p, :] = -1
        work[:, c] = -1
    return _box_matches(prev, curr, counts.counts)


def hungarian(counts: BoxCounts, params: BoxMatchingParams) -> BoxMatches:
    """One-to-one assignment maximising the total shared matches (Hungarian / Jonker–Volgenant).

    The assignment pairs every box of the smaller side; pairs below ``min_count`` are dropped.
    """
    shared = counts.counts
    if shared.size == 0:
        return _box_matches([], [], shared)
    # imported here: scipy.optimize takes ~0.6 s to import, paid by every worker otherwise
    from scipy.optimize import linear_sum_assignment  # noqa: PLC0415

    prev, curr = linear_sum_assignment(shared, maximize=True)
    keep = shared[prev, curr] >= params.min_count
    return _box_matches(prev[keep], curr[keep], shared)


#: FP.1 strategies by name; all take ``(BoxCounts, BoxMatchingParams)``.
BOX_MATCHING_STRATEGIES: dict[str, Callable[[BoxCounts, BoxMatchingParams], BoxMatches]] = {
    "overlap_confidence": overlap_confidence,
    "mutual_best": mutual_best,
    "greedy_matrix": greedy_matrix,
    "hungarian": hungarian,
}


def match_boxes(counts: BoxCounts, params: BoxMatchingParams) -> BoxMatches:
    """Box pairs by the strategy ``params.name``."""
    return BOX_MATCHING_STRATEGIES[params.name](counts, params)
