"""Keypoint detection: thirteen OpenCV detectors behind one call, keypoints as (N, 7) arrays.

The array format and the OpenCV helpers are in :mod:`ttc.features.base` (re-exported here). The
rubric's seven detectors are defined in this module, the other six OpenCV ships
(:data:`EXTRA_DETECTOR_NAMES`) in :mod:`ttc.features.detectors_extra`, and ``custom`` (a callable from
your own module) in :mod:`ttc.plugins`.

Each detector has a frozen parameter dataclass (plain int/float/bool/str fields, so Hydra can
use it as a structured-config schema) whose ``name`` selects it in :data:`DETECTORS` and in
:func:`detect_keypoints`. Defaults are the Udacity course's where it sets them.

Every detector has ``subpixel`` (default False, so the rubric's numbers stay reproducible):
when True, :func:`refine_subpixel` moves each keypoint to the sub-pixel corner position
OpenCV's ``cornerSubPix`` finds on the image gradient, before description. FAST, ORB, HARRIS,
Shi–Tomasi, AGAST and BRISK keypoints sit on integer pixels; with the lead car's scale change
of ~0.7 % per frame (< 1 px across a 100 px pair) many distance ratios are then exactly 1.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ttc.features.base import (  # noqa: F401  (re-exported: the keypoint API lives here)
    ANGLE,
    CLASS_ID,
    CONTRIB_PACKAGE,
    KEYPOINT_COLUMNS,
    OCTAVE,
    RESPONSE,
    SIZE,
    OpenCVFeatureMissing,
    X,
    Y,
    array_to_keypoints,
    check_gray,
    detect_with,
    empty_keypoints,
    keypoints_to_array,
    opencv_constant,
    opencv_factory,
    opencv_lookup,
    points_array,
    require_choice,
    require_name,
    require_positive,
)
from ttc.features.detectors_extra import EXTRA_DETECT, EXTRA_DETECTORS
from ttc.features.learned import detect_learned
from ttc.features.learned_params import LEARNED_DETECTORS
from ttc.plugins import USER, CustomDetectorParams, detect_custom


@dataclass(frozen=True)
class ShiTomasiParams:
    """Shi–Tomasi corners (``cv2.goodFeaturesToTrack``), the course's defaults.

    ``block_size`` (pixels) is also the keypoint size; corners are at least
    ``min_distance = (1 − max_overlap) · block_size`` pixels apart. ``max_corners = 0`` means the
    course's bound H·W / max(1, min_distance). ``k`` is used only with ``use_harris``.
    The response column holds OpenCV's corner quality (minimum eigenvalue).
    """

    name: str = "shitomasi"
    block_size: int = 4
    max_overlap: float = 0.0
    quality_level: float = 0.01
    k: float = 0.04
    use_harris: bool = False
    gradient_size: int = 3
    max_corners: int = 0
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "shitomasi")
        require_positive(block_size=self.block_size, quality_level=self.quality_level,
                        gradient_size=self.gradient_size)  # fmt: skip
        if not 0.0 <= self.max_overlap < 1.0:
            raise ValueError(f"max_overlap must be in [0, 1), got {self.max_overlap!r}")
        if self.max_corners < 0:
            raise ValueError(f"max_corners must be >= 0, got {self.max_corners!r}")

    @property
    def min_distance(self) -> float:
        """Minimum distance between corners, pixels."""
        return (1.0 - self.max_overlap) * self.block_size


@dataclass(frozen=True)
class HarrisParams:
    """Harris corners (``cv2.cornerHarris``), the course's defaults.

    The response is min–max normalised to 0–255 over the image; pixels above ``min_response``
    are candidates. Keypoints get size ``2 · aperture_size`` pixels (the course's) and
    non-maximum suppression keeps a candidate only if it has the highest response (ties: first
    in raster order) within ``nms_distance = (1 − max_overlap) · size`` pixels (Euclidean), so no
    two kept keypoints are closer than that — with ``max_overlap = 0`` no two keypoint circles
    overlap, the course's criterion, without its O(n²) loop.
    """

    name: str = "harris"
    block_size: int = 2
    aperture_size: int = 3
    k: float = 0.04
    min_response: float = 100.0
    max_overlap: float = 0.0
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "harris")
        require_positive(block_size=self.block_size)
        require_choice("aperture_size", self.aperture_size, (1, 3, 5, 7))
        if not 0.0 <= self.max_overlap < 1.0:
            raise ValueError(f"max_overlap must be in [0, 1), got {self.max_overlap!r}")

    @property
    def keypoint_size(self) -> float:
        """Keypoint diameter, pixels."""
        return 2.0 * self.aperture_size

    @property
    def nms_distance(self) -> float:
        """Minimum distance between kept keypoints, pixels."""
        return (1.0 - self.max_overlap) * self.keypoint_size


FAST_TYPES = ("TYPE_5_8", "TYPE_7_12", "TYPE_9_16")


@dataclass(frozen=True)
class FastParams:
    """FAST corners; ``threshold`` is an intensity difference (grey levels)."""

    name: str = "fast"
    threshold: int = 30
    nonmax_suppression: bool = True
    type: str = "TYPE_9_16"
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "fast")
        require_choice("type", self.type, FAST_TYPES)


@dataclass(frozen=True)
class BriskParams:
    """BRISK keypoints: AGAST ``threshold`` (grey levels), scale-space ``octaves``."""

    name: str = "brisk"
    threshold: int = 30
    octaves: int = 3
    pattern_scale: float = 1.0
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "brisk")
        require_positive(pattern_scale=self.pattern_scale)


ORB_SCORE_TYPES = ("HARRIS_SCORE", "FAST_SCORE")


@dataclass(frozen=True)
class OrbParams:
    """ORB keypoints (FAST in an image pyramid, ranked by Harris score).

    ``n_features = 2000`` instead of OpenCV's (and the course's) 500: on the 1242 × 375 KITTI
    frames the other detectors find 1500–2900 keypoints, and 500 ORB keypoints leave only ~100
    on the lead vehicle (≈ 320 with 2000, like BRISK), which starves the camera TTC and makes
    ORB look worse for a reason unrelated to its quality. ``edge_threshold`` and
    ``patch_size`` are pixels at each pyramid level; WTA_K is fixed at 2 (Hamming distance).
    """

    name: str = "orb"
    n_features: int = 2000
    scale_factor: float = 1.2
    n_levels: int = 8
    edge_threshold: int = 31
    first_level: int = 0
    score_type: str = "HARRIS_SCORE"
    patch_size: int = 31
    fast_threshold: int = 20
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "orb")
        require_positive(n_features=self.n_features, n_levels=self.n_levels)
        if not self.scale_factor > 1.0:
            raise ValueError(f"scale_factor must be > 1, got {self.scale_factor!r}")
        require_choice("score_type", self.score_type, ORB_SCORE_TYPES)


AKAZE_DIFFUSIVITIES = ("DIFF_PM_G1", "DIFF_PM_G2", "DIFF_WEICKERT", "DIFF_CHARBONNIER")


@dataclass(frozen=True)
class AkazeParams:
    """AKAZE keypoints in a nonlinear scale space; ``max_points = -1`` keeps them all.

    ``class_id`` of each keypoint is its scale-space level, which the AKAZE descriptor needs.
    """

    name: str = "akaze"
    threshold: float = 0.001
    n_octaves: int = 4
    n_octave_layers: int = 4
    diffusivity: str = "DIFF_PM_G2"
    max_points: int = -1
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "akaze")
        require_positive(threshold=self.threshold, n_octaves=self.n_octaves,
                        n_octave_layers=self.n_octave_layers)  # fmt: skip
        require_choice("diffusivity", self.diffusivity, AKAZE_DIFFUSIVITIES)


@dataclass(frozen=True)
class SiftParams:
    """SIFT keypoints (``n_features = 0``: keep all); ``sigma`` in pixels."""

    name: str = "sift"
    n_features: int = 0
    n_octave_layers: int = 3
    contrast_threshold: float = 0.04
    edge_threshold: float = 10.0
    sigma: float = 1.6
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "sift")
        require_positive(n_octave_layers=self.n_octave_layers, sigma=self.sigma)


#: The rubric's detectors (FP.6's grid), in the course's order.
RUBRIC_DETECTORS: tuple[str, ...] = ("shitomasi", "harris", "fast", "brisk", "orb", "akaze", "sift")

DETECTORS: dict[str, type] = {
    "shitomasi": ShiTomasiParams,
    "harris": HarrisParams,
    "fast": FastParams,
    "brisk": BriskParams,
    "orb": OrbParams,
    "akaze": AkazeParams,
    "sift": SiftParams,
    **EXTRA_DETECTORS,
    **LEARNED_DETECTORS,
    USER: CustomDetectorParams,
}
#: The detectors beyond the rubric (OpenCV's other feature detectors).
EXTRA_DETECTOR_NAMES: tuple[str, ...] = tuple(EXTRA_DETECTORS)


def disk_footprint(distance: float) -> np.ndarray:
    """uint8 kernel of the pixel offsets (dx, dy) with dx² + dy² < distance² (pixels)."""
    radius = max(int(np.ceil(distance)) - 1, 0)
    offsets = np.arange(-radius, radius + 1)
    inside = offsets[:, None] ** 2 + offsets[None, :] ** 2 < max(distance, 1.0) ** 2
    return inside.astype(np.uint8)


def nms_local_maxima(
    response: np.ndarray, min_response: float, distance: float
) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns (raster order) of the pixels above ``min_response`` that beat every
    other such pixel closer than ``distance`` pixels; ties go to the first in raster order.

    Candidates are ranked by (response desc, raster position) and the unique ranks are
    max-filtered with a disk, so two kept pixels are never closer than ``distance``.
    """
    rows, cols = np.nonzero(response > min_response)
    if len(rows) == 0:
        return rows, cols
    order = np.lexsort((np.arange(len(rows)), -response[rows, cols]))
    rank = np.zeros(response.shape, dtype=np.float64)  # float64: ranks exact beyond 2**24
    rank[rows[order], cols[order]] = np.arange(len(rows), 0, -1, dtype=np.float64)
    local_max = cv2.dilate(rank, disk_footprint(distance))
    keep = rank[rows, cols] == local_max[rows, cols]
    return rows[keep], cols[keep]


def _detect_shitomasi(gray: np.ndarray, p: ShiTomasiParams) -> np.ndarray:
    max_corners = p.max_corners or int(gray.size / max(1.0, p.min_distance))
    corners, quality = cv2.goodFeaturesToTrackWithQuality(
        gray, max_corners, p.quality_level, p.min_distance, None,
        blockSize=p.block_size, gradientSize=p.gradient_size,
        useHarrisDetector=p.use_harris, k=p.k,
    )  # fmt: skip
    if corners is None or len(corners) == 0:
        return empty_keypoints()
    return points_array(corners.reshape(-1, 2), p.block_size, quality.reshape(-1))


def _detect_harris(gray: np.ndarray, p: HarrisParams) -> np.ndarray:
    response = cv2.cornerHarris(gray, p.block_size, p.aperture_size, p.k)
    norm = cv2.normalize(response, None, 0.0, 255.0, cv2.NORM_MINMAX, cv2.CV_32F)
    rows, cols = nms_local_maxima(norm, p.min_response, p.nms_distance)
    xy = np.column_stack([cols, rows])
    return points_array(xy, p.keypoint_size, norm[rows, cols])


def _detect_fast(gray: np.ndarray, p: FastParams) -> np.ndarray:
    kind = opencv_constant("FastFeatureDetector", p.type)
    create = opencv_factory("FastFeatureDetector")
    return detect_with(create(p.threshold, p.nonmax_suppression, kind), gray)


def _detect_brisk(gray: np.ndarray, p: BriskParams) -> np.ndarray:
    return detect_with(opencv_factory("BRISK")(p.threshold, p.octaves, p.pattern_scale), gray)


def _detect_orb(gray: np.ndarray, p: OrbParams) -> np.ndarray:
    detector = opencv_factory("ORB")(
        nfeatures=p.n_features, scaleFactor=p.scale_factor, nlevels=p.n_levels,
        edgeThreshold=p.edge_threshold, firstLevel=p.first_level, WTA_K=2,
        scoreType=opencv_constant("ORB", p.score_type), patchSize=p.patch_size,
        fastThreshold=p.fast_threshold,
    )  # fmt: skip
    return detect_with(detector, gray)


def _detect_akaze(gray: np.ndarray, p: AkazeParams) -> np.ndarray:
    detector = opencv_factory("AKAZE")(
        threshold=p.threshold, nOctaves=p.n_octaves, nOctaveLayers=p.n_octave_layers,
        diffusivity=opencv_constant("KAZE", p.diffusivity), max_points=p.max_points,
    )  # fmt: skip
    return detect_with(detector, gray)


def _detect_sift(gray: np.ndarray, p: SiftParams) -> np.ndarray:
    detector = opencv_factory("SIFT")(
        p.n_features, p.n_octave_layers, p.contrast_threshold, p.edge_threshold, p.sigma
    )
    return detect_with(detector, gray)


_DETECT: dict[str, Callable[[np.ndarray, Any], np.ndarray]] = {
    "shitomasi": _detect_shitomasi,
    "harris": _detect_harris,
    "fast": _detect_fast,
    "brisk": _detect_brisk,
    "orb": _detect_orb,
    "akaze": _detect_akaze,
    "sift": _detect_sift,
    **EXTRA_DETECT,
    **dict.fromkeys(LEARNED_DETECTORS, detect_learned),
    USER: detect_custom,
}

#: ``cornerSubPix`` search window half-size (pixels: a 7 × 7 window), the zero zone (none) and
#: the stop criteria (40 iterations or a step below 0.001 px).
SUBPIXEL_HALF_WINDOW = 3
SUBPIXEL_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.001)


def refine_subpixel(
    gray: np.ndarray, keypoints: np.ndarray, half_window: int = SUBPIXEL_HALF_WINDOW
) -> np.ndarray:
    """Keypoints (N, 7) moved to their sub-pixel corner positions (OpenCV ``cornerSubPix``).

    ``cornerSubPix`` iterates to the point where the image gradient in a
    (2·``half_window`` + 1)² pixel window is orthogonal to the vectors from it, which is the
    corner's position for a corner. A keypoint whose refined position is not finite, lies
    outside the image or moved farther than ``half_window`` pixels (no corner there: blobs,
    edges) keeps its original position. Only x and y change; order and count are kept.
    """
    check_gray(gray)
    if len(keypoints) == 0:
        return keypoints.copy()
    start = np.ascontiguousarray(keypoints[:, [X, Y]], dtype=np.float32).reshape(-1, 1, 2)
    win = (half_window, half_window)
    refined = cv2.cornerSubPix(gray, start.copy(), win, (-1, -1), SUBPIXEL_CRITERIA)
    refined = refined.reshape(-1, 2).astype(np.float64)
    h, w = gray.shape
    moved = np.hypot(*(refined - keypoints[:, [X, Y]]).T)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(refined).all(axis=1) & (moved <= half_window)
        ok &= (refined[:, 0] >= 0) & (refined[:, 0] <= w - 1)
        ok &= (refined[:, 1] >= 0) & (refined[:, 1] <= h - 1)
    out = keypoints.copy()
    out[ok, X], out[ok, Y] = refined[ok, 0], refined[ok, 1]
    return out


def detect_keypoints(gray: np.ndarray, params: Any) -> np.ndarray:
    """Keypoints (N, 7) of a uint8 H × W image, in the detector's own (deterministic) order.

    ``params`` is one of the :data:`DETECTORS` dataclasses; its ``name`` picks the detector.
    With ``params.subpixel`` the positions are refined by :func:`refine_subpixel`.
    """
    if params.name not in _DETECT:
        raise ValueError(f"unknown detector {params.name!r}; choose from {sorted(_DETECT)}")
    check_gray(gray)
    keypoints = _DETECT[params.name](gray, params)
    return refine_subpixel(gray, keypoints) if getattr(params, "subpixel", False) else keypoints
