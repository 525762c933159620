"""FP.3: the keypoint matches of a box, with implausible displacements removed.

A match belongs to a box when its current keypoint lies in the (shrunk) current box. Each filter
of :data:`KEYPOINT_FILTERS` looks at the displacement ``curr − prev`` (pixels) of those matches
and returns a keep mask; :func:`filter_box_matches` does both steps.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ttc.robust import MAD_TO_SIGMA, column_medians, median, quantiles
from ttc.steps.box_matching import points_in_rois, shrink_rois


@dataclass(frozen=True)
class KeypointFilterParams:
    """FP.3 filter and its parameters.

    ``factor``: median_distance keeps lengths ≤ factor × median length. ``z``: zscore keeps
    ``|d − mean| ≤ z · std``. ``iqr_k``: Tukey fences ``[Q1 − k·IQR, Q3 + k·IQR]``.
    ``mad_threshold``: displacement_mad keeps vectors within this many robust standard
    deviations of the median vector. ``mad_floor`` (pixels): least robust standard deviation
    per axis, so integer-quantised keypoints (MAD 0) do not turn 1 px into an outlier.
    """

    name: str = "median_distance"
    factor: float = 1.5
    z: float = 2.0
    iqr_k: float = 1.5
    mad_threshold: float = 3.5
    mad_floor: float = 0.5

    def __post_init__(self) -> None:
        if self.name not in KEYPOINT_FILTERS:
            known = ", ".join(KEYPOINT_FILTERS)
            raise ValueError(f"unknown keypoint filter {self.name!r}; known: {known}")
        for field in ("factor", "z", "mad_threshold"):
            if not getattr(self, field) > 0:
                raise ValueError(f"{field} must be > 0, got {getattr(self, field)}")
        for field in ("iqr_k", "mad_floor"):
            if not getattr(self, field) >= 0:
                raise ValueError(f"{field} must be >= 0, got {getattr(self, field)}")


def displacement_lengths(prev_xy: np.ndarray, curr_xy: np.ndarray) -> np.ndarray:
    """Length (pixels) of each matched pair's displacement ``curr − prev`` (K,)."""
    return np.hypot(curr_xy[:, 0] - prev_xy[:, 0], curr_xy[:, 1] - prev_xy[:, 1])


def keep_all(prev_xy: np.ndarray, curr_xy: np.ndarray, params: KeypointFilterParams) -> np.ndarray:
    """No filtering: every match is kept."""
    return np.ones(len(curr_xy), dtype=bool)


def median_distance(
    prev_xy: np.ndarray, curr_xy: np.ndarray, params: KeypointFilterParams
) -> np.ndarray:
    """Seed 001: drop matches whose displacement length exceeds ``factor`` × the median."""
    d = displacement_lengths(prev_xy, curr_xy)
    if len(d) == 0:
        return np.ones(0, dtype=bool)
    return d <= params.factor * median(d)


def zscore(prev_xy: np.ndarray, curr_xy: np.ndarray, params: KeypointFilterParams) -> np.ndarray:
    """Drop matches whose displacement length is more than ``z`` standard deviations off the mean.

    Keeps everything when all lengths are equal.
    """
    d = displacement_lengths(prev_xy, curr_xy)
    if len(d) == 0 or np.ptp(d) == 0:  # no spread: rounding must not drop equal lengths
        return np.ones(len(d), dtype=bool)
    return np.abs(d - d.mean()) <= params.z * d.std()


def iqr(prev_xy: np.ndarray, curr_xy: np.ndarray, params: KeypointFilterParams) -> np.ndarray:
    """Tukey fences on displacement length: keep ``Q1 − k·IQR ≤ d ≤ Q3 + k·IQR``."""
    d = displacement_lengths(prev_xy, curr_xy)
    if len(d) == 0:
        return np.ones(0, dtype=bool)
    q1, q3 = quantiles(d, (0.25, 0.75))
    spread = params.iqr_k * (q3 - q1)
    return (d >= q1 - spread) & (d <= q3 + spread)


def displacement_mad(
    prev_xy: np.ndarray, curr_xy: np.ndarray, params: KeypointFilterParams
) -> np.ndarray:
    """Robust filter on the 2-D displacement vectors (direction as well as length).

    With ``v = curr − prev``, ``m`` its coordinate-wise median and, per axis,
    ``s = max(1.4826 · median(|v − m|), mad_floor)`` (pixels), a match is kept when
    ``‖(v − m) / s‖₂ ≤ mad_threshold``: a modified z-score (Iglewicz–Hoaglin) per axis,
    combined as a diagonal robust Mahalanobis distance. A vector of the right length in the
    wrong direction is far from ``m`` and is dropped; length-only filters keep it.
    """
    v = np.asarray(curr_xy, dtype=np.float64) - np.asarray(prev_xy, dtype=np.float64)
    if len(v) == 0:
        return np.ones(0, dtype=bool)
    dev = v - column_medians(v)
    scale = np.maximum(MAD_TO_SIGMA * column_medians(np.abs(dev)), params.mad_floor)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(dev == 0, 0.0, dev / scale)
    return np.hypot(z[:, 0], z[:, 1]) <= params.mad_threshold


#: FP.3 filters by name; all take ``(prev_xy (K × 2), curr_xy (K × 2), KeypointFilterParams)``
#: and return a keep mask (K,).
KEYPOINT_FILTERS: dict[
    str, Callable[[np.ndarray, np.ndarray, KeypointFilterParams], np.ndarray]
] = {
    "none": keep_all,
    "median_distance": median_distance,
    "zscore": zscore,
    "iqr": iqr,
    "displacement_mad": displacement_mad,
}


def matches_in_box(
    curr_xy: np.ndarray, curr_idx: np.ndarray, roi: np.ndarray, shrink: float
) -> np.ndarray:
    """Mask over the matches (K,) whose current keypoint lies in ``roi`` shrunk by ``shrink``.

    ``curr_xy``: current keypoint pixels (N × 2); ``curr_idx``: matched indices (K,);
    ``roi``: one box (x, y, w, h pixels).
    """
    pts = np.asarray(curr_xy, dtype=np.float64).reshape(-1, 2)[np.asarray(curr_idx)]
    return points_in_rois(pts, shrink_rois(roi, shrink))[:, 0]


@dataclass(frozen=True)
class FilterResult:
    """Matches of a box after FP.3: ``kept`` / ``removed`` index the match arrays."""

    kept: np.ndarray  # (n_kept,) int64 indices into prev_idx / curr_idx
    removed: np.ndarray  # (n_removed,) int64: in the box but filtered out
    n_in_box: int
    n_kept: int
    n_removed: int


def filter_box_matches(
    prev_xy: np.ndarray,
    curr_xy: np.ndarray,
    prev_idx: np.ndarray,
    curr_idx: np.ndarray,
    roi: np.ndarray,
    shrink: float,
    params: KeypointFilterParams,
) -> FilterResult:
    """The matches whose current keypoint is in the shrunk box, minus the filter's outliers.

    ``prev_xy`` / ``curr_xy``: keypoint pixels (N × 2) of each frame; ``prev_idx`` /
    ``curr_idx``: the matches; ``roi``: the current box (x, y, w, h pixels).
    """
    prev_idx, curr_idx = np.asarray(prev_idx), np.asarray(curr_idx)
    in_box = np.flatnonzero(matches_in_box(curr_xy, curr_idx, roi, shrink))
    prev_pts = np.asarray(prev_xy, dtype=np.float64).reshape(-1, 2)[prev_idx[in_box]]
    curr_pts = np.asarray(curr_xy, dtype=np.float64).reshape(-1, 2)[curr_idx[in_box]]
    keep = KEYPOINT_FILTERS[params.name](prev_pts, curr_pts, params)
    kept, removed = in_box[keep], in_box[~keep]
    return FilterResult(
        kept=kept.astype(np.int64),
        removed=removed.astype(np.int64),
        n_in_box=len(in_box),
        n_kept=len(kept),
        n_removed=len(removed),
    )
