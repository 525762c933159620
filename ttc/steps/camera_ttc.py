"""FP.4: camera time-to-collision from the scale change between matched keypoints.

For every pair i < j of kept matches, the ratio ``r = d_curr / d_prev`` of their pixel distances
in the current and previous frame measures the object's image scale change. A statistic of
:data:`CAMERA_ESTIMATORS` reduces the ratios to one ``r``; the constant-velocity model gives
``TTC = −dt / (1 − r)`` (seconds). Only pairs at least ``min_dist`` pixels apart in the current
frame are used: short baselines turn pixel noise into large ratio errors. The threshold can
also grow with the object: ``min_box_fraction`` × the width of the current box (pixels), so one
setting fits a car 8 m ahead (a 200 px box, drive 0052) and a van 21 m ahead (40 px, KITTI
odometry sequence 04); the larger of the two thresholds applies.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ttc import reasons
from ttc.robust import median
from ttc.steps.similarity_fit import check_fit, similarity_scale

#: Least previous-frame distance (pixels) of a usable pair: coincident keypoints give no ratio.
MIN_PREV_DIST = 1e-9


@dataclass(frozen=True)
class CameraTTCParams:
    """FP.4 ratio statistic and the least current-frame pair distance: ``min_dist`` (pixels)
    or ``min_box_fraction`` × the current box's width, whichever is larger (0: absolute only)."""

    name: str = "median_ratio"
    min_dist: float = 100.0
    min_box_fraction: float = 0.0
    fit_method: str = "ransac"  # similarity_fit only: ransac or lmeds
    fit_threshold: float = 1.0  # similarity_fit only: RANSAC threshold, pixels

    def __post_init__(self) -> None:
        check_fit(self.fit_method, self.fit_threshold)
        if self.name not in CAMERA_ESTIMATORS and self.name not in POINT_ESTIMATORS:
            known = ", ".join([*CAMERA_ESTIMATORS, *POINT_ESTIMATORS])
            raise ValueError(f"unknown camera TTC estimator {self.name!r}; known: {known}")
        if not self.min_dist >= 0:
            raise ValueError(f"min_dist must be >= 0 pixels, got {self.min_dist}")
        if not 0 <= self.min_box_fraction <= 1:
            raise ValueError(
                f"min_box_fraction must be within 0-1 of the box width, got {self.min_box_fraction}"
            )

    def threshold(self, box_width: float) -> float:
        """The least current-frame pair distance (pixels) for a box ``box_width`` pixels wide."""
        return max(self.min_dist, self.min_box_fraction * box_width)


def median_ratio(ratios: np.ndarray) -> float:
    """Median of the distance ratios (robust to mismatched pairs)."""
    return float(median(ratios))


def mean_ratio(ratios: np.ndarray) -> float:
    """Mean of the distance ratios (the Udacity lesson's first version)."""
    return float(np.mean(ratios))


#: FP.4 ratio statistics by name; all take the non-empty ratios (P,) and return one ratio.
CAMERA_ESTIMATORS: dict[str, Callable[[np.ndarray], float]] = {
    "median_ratio": median_ratio,
    "mean_ratio": mean_ratio,
    "vertical_ratio": median_ratio,
}
#: FP.4 estimators of the scale from the correspondences themselves (not from pair ratios):
#: (prev_xy, curr_xy, params) → (ratio, correspondences used); see :mod:`ttc.steps.similarity_fit`.
POINT_ESTIMATORS: dict[str, Callable[..., tuple[float, int]]] = {
    "similarity_fit": lambda p, c, params: similarity_scale(
        p, c, params.fit_method, params.fit_threshold
    ),
}


@dataclass(frozen=True)
class CameraTTCResult:
    """Camera TTC (seconds; NaN or +inf when degenerate, see ``reason``), the ratio statistic
    (NaN when no pair was usable) and the number of pairs it used."""

    ttc: float
    ratio: float
    n_pairs: int
    reason: str


def distance_ratios(prev_xy: np.ndarray, curr_xy: np.ndarray, min_dist: float) -> np.ndarray:
    """Ratios ``d_curr / d_prev`` over the pairs i < j with ``d_curr ≥ min_dist`` (pixels)."""
    from scipy.spatial.distance import pdist  # noqa: PLC0415 (0.28 s to import: not at planning)

    if len(curr_xy) < 2:
        return np.empty(0)
    d_prev = pdist(prev_xy)
    d_curr = pdist(curr_xy)
    usable = (d_curr >= min_dist) & (d_prev > MIN_PREV_DIST)
    return d_curr[usable] / d_prev[usable]


def vertical_ratios(prev_xy: np.ndarray, curr_xy: np.ndarray, min_dist: float) -> np.ndarray:
    """Ratios ``|Δv_curr| / |Δv_prev|`` of the vertical components over the mostly vertical
    pairs i < j (``|Δu_curr| ≤ |Δv_curr|``) with ``|Δv_curr| ≥ min_dist`` (pixels).

    A car seen obliquely shows its side: points along it lie at different depths, so their
    horizontal separation does not scale like the distance of the car's nearest face, while
    the vertical separation of two points above one another (at one depth) scales exactly
    with that depth (the ``camera_ttc=vertical_ratio`` estimator, the median of these)."""
    from scipy.spatial.distance import pdist  # noqa: PLC0415 (as in distance_ratios)

    if len(curr_xy) < 2:
        return np.empty(0)
    du_curr = pdist(curr_xy[:, :1])
    dv_prev, dv_curr = pdist(prev_xy[:, 1:2]), pdist(curr_xy[:, 1:2])
    usable = (dv_curr >= min_dist) & (du_curr <= dv_curr) & (dv_prev > MIN_PREV_DIST)
    return dv_curr[usable] / dv_prev[usable]


#: The pair ratios each ratio statistic of :data:`CAMERA_ESTIMATORS` reduces.
RATIO_SOURCES: dict[str, Callable[[np.ndarray, np.ndarray, float], np.ndarray]] = {
    "vertical_ratio": vertical_ratios,
}


def _ratios_of(params: CameraTTCParams) -> Callable[[np.ndarray, np.ndarray, float], np.ndarray]:
    """The function making the pair ratios of ``params``' ratio statistic (its
    :data:`RATIO_SOURCES` entry, else :func:`distance_ratios`)."""
    return RATIO_SOURCES.get(params.name, distance_ratios)


def ratio_source(params: CameraTTCParams, box_width: float) -> tuple[str, float] | None:
    """What the pair ratios of ``params``' estimator depend on besides the points: (the
    ratios' source, the least pair distance in px for a box ``box_width`` px wide); None for
    an estimator of :data:`POINT_ESTIMATORS` (it uses no pair ratios). Estimators with equal
    sources (``median_ratio`` and ``mean_ratio`` at one ``min_dist``) reduce the same ratios."""
    if params.name in POINT_ESTIMATORS:
        return None
    return _ratios_of(params).__name__, params.threshold(box_width)


def pair_ratios(
    prev_xy: np.ndarray, curr_xy: np.ndarray, params: CameraTTCParams, box_width: float = 0.0
) -> np.ndarray:
    """The pair ratios (P,) that ``params``' ratio statistic reduces, of the kept matches'
    keypoints (K × 2 pixels, row k ↔ row k) in a box ``box_width`` pixels wide."""
    source = _ratios_of(params)
    prev_xy = np.asarray(prev_xy, dtype=np.float64).reshape(-1, 2)
    curr_xy = np.asarray(curr_xy, dtype=np.float64).reshape(-1, 2)
    return source(prev_xy, curr_xy, params.threshold(box_width))


def ttc_from_ratio(ratio: float, dt: float) -> float:
    """Raw constant-velocity TTC ``−dt / (1 − r)`` (seconds; ±inf at r = 1)."""
    with np.errstate(divide="ignore"):
        return float(-dt / (1.0 - np.float64(ratio)))


def camera_ttc(
    prev_xy: np.ndarray,
    curr_xy: np.ndarray,
    dt: float,
    params: CameraTTCParams,
    box_width: float = 0.0,
    ratios: np.ndarray | None = None,
) -> CameraTTCResult:
    """Camera TTC (seconds) from the kept matches' keypoints (K × 2 pixels, row k ↔ row k).

    ``dt``: seconds between the frames; ``box_width``: the current box's width (pixels), for
    :meth:`CameraTTCParams.threshold`; ``ratios``: these points' :func:`pair_ratios` for
    ``params`` when made already (shared by the estimators of one :func:`ratio_source`).
    Degenerate cases return NaN (no matches, no usable pair) or +inf (ratio exactly 1, or a
    shrinking image: receding) with a reason code; only a non-positive ``dt`` or mismatched
    shapes raise (caller errors).
    """
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt}")
    prev_xy = np.asarray(prev_xy, dtype=np.float64).reshape(-1, 2)
    curr_xy = np.asarray(curr_xy, dtype=np.float64).reshape(-1, 2)
    if prev_xy.shape != curr_xy.shape:
        raise ValueError(f"prev_xy {prev_xy.shape} and curr_xy {curr_xy.shape} differ")
    nan = float("nan")
    if len(curr_xy) == 0:
        return CameraTTCResult(nan, nan, 0, reasons.NO_MATCHES_IN_BOX)
    if params.name in POINT_ESTIMATORS:
        r, n_used = POINT_ESTIMATORS[params.name](prev_xy, curr_xy, params)
    else:
        if ratios is None:
            ratios = pair_ratios(prev_xy, curr_xy, params, box_width)
        r, n_used = (
            (CAMERA_ESTIMATORS[params.name](ratios), len(ratios)) if len(ratios) else (nan, 0)
        )
    if n_used == 0:
        return CameraTTCResult(nan, nan, 0, reasons.TOO_FEW_PAIRS)
    if r == 1.0:
        return CameraTTCResult(float("inf"), r, n_used, reasons.RATIO_ONE)
    ttc = ttc_from_ratio(r, dt)
    if ttc < 0:
        return CameraTTCResult(float("inf"), r, n_used, reasons.RECEDING)
    return CameraTTCResult(ttc, r, n_used, reasons.OK)
