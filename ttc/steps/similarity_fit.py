"""FP.4 by a scale fit: the scale of a robust similarity between the kept correspondences.

Instead of a statistic of the pairwise distance ratios (:mod:`ttc.steps.camera_ttc`),
``camera_ttc=similarity_fit`` fits one similarity transform ``x' = s·R·x + t`` (4 degrees of
freedom) from the previous to the current frame's kept keypoints with OpenCV's
``estimateAffinePartial2D`` (RANSAC or LMedS, then a Levenberg–Marquardt refinement on the
inliers) and uses its scale ``s`` as the image scale ratio ``r``. Each correspondence enters
once (not once per pair), and mismatches are rejected as a whole instead of diluting the
ratios of every pair they belong to.
"""

from __future__ import annotations

import cv2
import numpy as np

#: Robust estimators of the fit by name (OpenCV flags).
FIT_METHODS: dict[str, int] = {"ransac": cv2.RANSAC, "lmeds": cv2.LMEDS}
#: Seed of OpenCV's RNG before each fit: equal inputs give equal scales in every process.
FIT_SEED = 0
#: Fewest correspondences of a fit (a similarity has 4 degrees of freedom: 2 points).
MIN_POINTS = 3


def check_fit(method: str, threshold: float) -> None:
    """ValueError unless ``method`` is a :data:`FIT_METHODS` name and ``threshold`` > 0 px."""
    if method not in FIT_METHODS:
        raise ValueError(f"fit_method must be one of {sorted(FIT_METHODS)}, got {method!r}")
    if not threshold > 0:
        raise ValueError(f"fit_threshold must be > 0 pixels, got {threshold}")


def similarity_scale(
    prev_xy: np.ndarray, curr_xy: np.ndarray, method: str = "ransac", threshold: float = 1.0
) -> tuple[float, int]:
    """``(scale, inliers)`` of the similarity fitted from ``prev_xy`` to ``curr_xy``.

    Parameters
    ----------
    prev_xy, curr_xy : (K, 2) arrays, pixels; row k of one corresponds to row k of the other.
    method : ``ransac`` or ``lmeds`` (:data:`FIT_METHODS`).
    threshold : RANSAC reprojection threshold, pixels (unused by LMedS).

    Returns
    -------
    The fitted scale ``s`` (dimensionless; > 1 when the object grows) and the number of inlier
    correspondences; ``(nan, 0)`` with fewer than :data:`MIN_POINTS` points or no fit.
    """
    check_fit(method, threshold)
    src = np.ascontiguousarray(prev_xy, dtype=np.float64).reshape(-1, 1, 2)
    dst = np.ascontiguousarray(curr_xy, dtype=np.float64).reshape(-1, 1, 2)
    if len(src) < MIN_POINTS:
        return float("nan"), 0
    cv2.setRNGSeed(FIT_SEED)
    model, inliers = cv2.estimateAffinePartial2D(
        src, dst, method=FIT_METHODS[method], ransacReprojThreshold=threshold,
        maxIters=2000, confidence=0.995, refineIters=10,
    )  # fmt: skip
    if model is None:
        return float("nan"), 0
    return float(np.hypot(model[0, 0], model[1, 0])), int(np.count_nonzero(inliers))
