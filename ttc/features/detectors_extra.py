"""The keypoint detectors OpenCV ships beyond the rubric's seven: KAZE, AGAST, MSER, Star,
MSD and Harris–Laplace (the last three from opencv-contrib's ``xfeatures2d``), and ``grid``:
points on a regular lattice for the trackers (KLT, DIS, Farnebäck) to follow, so dense flow
gives correspondences on a grid inside the boxes rather than at corners.

Same contract as :mod:`ttc.features.keypoints` (which merges :data:`EXTRA_DETECTORS` into its
registry): a frozen parameter dataclass per detector, named by ``name``, and a function
``(gray uint8 H × W, params) → (N, 7) keypoint array``. Defaults are OpenCV's, except AGAST's
``threshold`` (30 grey levels, as this project's FAST and BRISK: OpenCV's 10 gives ~10⁴
keypoints on a KITTI frame). A detector the installed OpenCV lacks raises
:class:`~ttc.features.base.OpenCVFeatureMissing` (see :func:`detector_available`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ttc.features.base import (
    check_gray,
    detect_with,
    opencv_constant,
    opencv_factory,
    opencv_has,
    points_array,
    require_choice,
    require_name,
    require_positive,
)

KAZE_DIFFUSIVITIES = ("DIFF_PM_G1", "DIFF_PM_G2", "DIFF_WEICKERT", "DIFF_CHARBONNIER")


@dataclass(frozen=True)
class KazeParams:
    """KAZE keypoints in a nonlinear scale space (``class_id`` = scale-space level).

    ``extended``/``upright`` only matter for the KAZE descriptor; kept here so the detector's
    object is the descriptor's.
    """

    name: str = "kaze"
    extended: bool = False
    upright: bool = False
    threshold: float = 0.001
    n_octaves: int = 4
    n_octave_layers: int = 4
    diffusivity: str = "DIFF_PM_G2"
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "kaze")
        require_positive(threshold=self.threshold, n_octaves=self.n_octaves,
                         n_octave_layers=self.n_octave_layers)  # fmt: skip
        require_choice("diffusivity", self.diffusivity, KAZE_DIFFUSIVITIES)


AGAST_TYPES = ("AGAST_5_8", "AGAST_7_12d", "AGAST_7_12s", "OAST_9_16")


@dataclass(frozen=True)
class AgastParams:
    """AGAST corners (adaptive FAST); ``threshold`` is an intensity difference (grey levels)."""

    name: str = "agast"
    threshold: int = 30
    nonmax_suppression: bool = True
    type: str = "OAST_9_16"
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "agast")
        require_choice("type", self.type, AGAST_TYPES)


@dataclass(frozen=True)
class MserParams:
    """MSER regions as keypoints (centre, size = region diameter); areas in pixels²."""

    name: str = "mser"
    delta: int = 5
    min_area: int = 60
    max_area: int = 14400
    max_variation: float = 0.25
    min_diversity: float = 0.2
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "mser")
        require_positive(delta=self.delta, min_area=self.min_area, max_area=self.max_area)
        if self.max_area < self.min_area:
            raise ValueError(f"max_area {self.max_area} < min_area {self.min_area}")


@dataclass(frozen=True)
class StarParams:
    """Star (CenSurE) keypoints; ``max_size`` and ``suppress_nonmax_size`` in pixels."""

    name: str = "star"
    max_size: int = 45
    response_threshold: int = 30
    line_threshold_projected: int = 10
    line_threshold_binarized: int = 8
    suppress_nonmax_size: int = 5
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "star")
        require_choice("max_size", self.max_size, (4, 6, 8, 11, 12, 16, 22, 23, 32, 45, 46,
                                                   64, 90, 128))  # fmt: skip
        require_positive(suppress_nonmax_size=self.suppress_nonmax_size)


@dataclass(frozen=True)
class MsdParams:
    """Maximal self-dissimilarity keypoints; radii in pixels, ``n_scales = -1``: all scales."""

    name: str = "msd"
    patch_radius: int = 3
    search_area_radius: int = 5
    nms_radius: int = 5
    nms_scale_radius: int = 0
    th_saliency: float = 250.0
    knn: int = 4
    scale_factor: float = 1.25
    n_scales: int = -1
    compute_orientation: bool = False
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "msd")
        require_positive(patch_radius=self.patch_radius, knn=self.knn,
                         search_area_radius=self.search_area_radius)  # fmt: skip
        if not self.scale_factor > 1.0:
            raise ValueError(f"scale_factor must be > 1, got {self.scale_factor!r}")


@dataclass(frozen=True)
class HarrisLaplaceParams:
    """Harris–Laplace corners (scale-adapted Harris, scale from the Laplacian)."""

    name: str = "harris_laplace"
    n_octaves: int = 6
    corner_threshold: float = 0.01
    dog_threshold: float = 0.01
    max_corners: int = 5000
    n_layers: int = 4
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "harris_laplace")
        require_positive(n_octaves=self.n_octaves, max_corners=self.max_corners)
        require_choice("n_layers", self.n_layers, (2, 4))


@dataclass(frozen=True)
class GridParams:
    """Points on a regular lattice every ``step`` pixels, ``margin`` pixels from the image
    border (size ``step`` px, no angle, octave 0): what a tracker follows when the
    correspondences should cover the box evenly instead of its corners. No descriptor is
    computed on them (:data:`ttc.features.descriptors.INVALID_PAIRS`): use ``matcher`` klt,
    dis or farneback."""

    name: str = "grid"
    step: int = 8
    margin: int = 8
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, "grid")
        require_positive(step=self.step)
        if self.margin < 0:
            raise ValueError(f"margin must be >= 0 pixels, got {self.margin}")


def grid_points(shape: tuple[int, int], p: GridParams) -> np.ndarray:
    """The (N, 7) keypoint array of the lattice of :class:`GridParams` ``p`` on an image of
    ``shape`` (H, W) pixels, row by row; empty when the margins leave no room."""
    h, w = shape
    xs = np.arange(p.margin, w - p.margin, p.step, dtype=np.float64)
    ys = np.arange(p.margin, h - p.margin, p.step, dtype=np.float64)
    gx, gy = np.meshgrid(xs, ys)
    return points_array(np.column_stack([gx.ravel(), gy.ravel()]), float(p.step))


def _detect_grid(gray: np.ndarray, p: GridParams) -> np.ndarray:
    check_gray(gray)
    return grid_points(gray.shape[:2], p)


def _detect_kaze(gray: np.ndarray, p: KazeParams) -> np.ndarray:
    detector = opencv_factory("KAZE")(
        extended=p.extended, upright=p.upright, threshold=p.threshold, nOctaves=p.n_octaves,
        nOctaveLayers=p.n_octave_layers, diffusivity=opencv_constant("KAZE", p.diffusivity),
    )  # fmt: skip
    return detect_with(detector, gray)


def _detect_agast(gray: np.ndarray, p: AgastParams) -> np.ndarray:
    kind = opencv_constant("AgastFeatureDetector", p.type)
    create = opencv_factory("AgastFeatureDetector")
    return detect_with(create(p.threshold, p.nonmax_suppression, kind), gray)


def _detect_mser(gray: np.ndarray, p: MserParams) -> np.ndarray:
    detector = opencv_factory("MSER")(
        delta=p.delta, min_area=p.min_area, max_area=p.max_area,
        max_variation=p.max_variation, min_diversity=p.min_diversity,
    )  # fmt: skip
    return detect_with(detector, gray)


def _detect_star(gray: np.ndarray, p: StarParams) -> np.ndarray:
    detector = opencv_factory("StarDetector", contrib=True)(
        p.max_size, p.response_threshold, p.line_threshold_projected,
        p.line_threshold_binarized, p.suppress_nonmax_size,
    )  # fmt: skip
    return detect_with(detector, gray)


def _detect_msd(gray: np.ndarray, p: MsdParams) -> np.ndarray:
    detector = opencv_factory("MSDDetector", contrib=True)(
        p.patch_radius, p.search_area_radius, p.nms_radius, p.nms_scale_radius,
        p.th_saliency, p.knn, p.scale_factor, p.n_scales, p.compute_orientation,
    )  # fmt: skip
    return detect_with(detector, gray)


def _detect_harris_laplace(gray: np.ndarray, p: HarrisLaplaceParams) -> np.ndarray:
    detector = opencv_factory("HarrisLaplaceFeatureDetector", contrib=True)(
        p.n_octaves, p.corner_threshold, p.dog_threshold, p.max_corners, p.n_layers
    )
    return detect_with(detector, gray)


EXTRA_DETECTORS: dict[str, type] = {
    "kaze": KazeParams,
    "agast": AgastParams,
    "mser": MserParams,
    "star": StarParams,
    "msd": MsdParams,
    "harris_laplace": HarrisLaplaceParams,
    "grid": GridParams,
}

EXTRA_DETECT: dict[str, Callable[[np.ndarray, Any], np.ndarray]] = {
    "kaze": _detect_kaze,
    "agast": _detect_agast,
    "mser": _detect_mser,
    "star": _detect_star,
    "msd": _detect_msd,
    "harris_laplace": _detect_harris_laplace,
    "grid": _detect_grid,
}

#: OpenCV algorithm behind each extra detector (for :func:`detector_available`).
OPENCV_ALGORITHMS: dict[str, str] = {
    "kaze": "KAZE",
    "agast": "AgastFeatureDetector",
    "mser": "MSER",
    "star": "StarDetector",
    "msd": "MSDDetector",
    "harris_laplace": "HarrisLaplaceFeatureDetector",
}


def detector_available(name: str) -> bool:
    """False when ``name`` is an extra detector the installed OpenCV lacks (True otherwise)."""
    return name not in OPENCV_ALGORITHMS or opencv_has(OPENCV_ALGORITHMS[name])
