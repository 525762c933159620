"""Keypoint descriptors: fourteen OpenCV extractors behind one call, and which pairs are valid.

Each descriptor has a frozen parameter dataclass (plain fields, usable as a Hydra
structured-config schema) whose ``name`` selects it in :data:`DESCRIPTORS` and in
:func:`describe_keypoints`. SIFT descriptors are float32 (L2 distance); the others are binary
uint8 strings (Hamming distance), AKAZE's MLDB included.

Some detector × descriptor pairs cannot work; :data:`INVALID_PAIRS` lists them with the reason,
and :func:`check_pair` refuses them before any work, so a sweep can record a skip instead of
crashing (or trying to allocate 70 GB). What OpenCV 4.14 does with them on KITTI frame 0:

* akaze descriptor on any non-AKAZE keypoints (6 pairs): ``cv2.error`` (-215) in
  AKAZEFeatures.cpp, ``0 <= kpts[i].class_id && kpts[i].class_id < evolution_.size()``: the
  descriptor indexes its scale space with the keypoint's class_id, which only AKAZE sets (−1
  elsewhere).
* orb descriptor on sift keypoints: ``cv2.error`` (-4) "Failed to allocate 70168247552 bytes":
  ORB reads SIFT's packed ``octave`` (up to ~1.7e7) as a pyramid level and sizes its pyramid
  by it.

Every other pair of the rubric's (35 of 42) gives descriptors on KITTI frames 0 and 1 (checked
by ``tests/test_features.py``). The eight descriptors beyond the rubric are in
:mod:`ttc.features.descriptors_extra`; what their pairs do is listed at :data:`INVALID_PAIRS` and checked
on every pair by ``tests/test_feature_zoo.py``. A detector or descriptor the installed OpenCV
lacks raises :class:`FeatureUnavailableError` (a skip, like an invalid pair) before any work.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ttc.features.descriptors_extra import (
    COLOUR_DESCRIPTORS,
    EXTRA_DESCRIPTORS,
    EXTRA_EXTRACTORS,
    EXTRA_FLOAT_DESCRIPTORS,
    descriptor_available,
)
from ttc.features.detectors_extra import detector_available
from ttc.features.keypoints import (
    AKAZE_DIFFUSIVITIES,
    DETECTORS,
    RUBRIC_DETECTORS,
    array_to_keypoints,
    check_gray,
    empty_keypoints,
    keypoints_to_array,
    opencv_constant,
    opencv_factory,
    require_choice,
    require_name,
    require_positive,
)
from ttc.features.learned_params import LEARNED_DESCRIPTORS, LEARNED_REASON, learned_missing
from ttc.plugins import USER, CustomDescriptorParams, describe_custom


@dataclass(frozen=True)
class BriskDescriptorParams:
    """BRISK descriptor (64 bytes); ``pattern_scale`` scales the sampling pattern."""

    name: str = "brisk"
    pattern_scale: float = 1.0

    def __post_init__(self) -> None:
        require_name(self, "brisk")
        require_positive(pattern_scale=self.pattern_scale)


@dataclass(frozen=True)
class BriefDescriptorParams:
    """BRIEF descriptor (opencv-contrib) of ``descriptor_bytes`` bytes (16, 32 or 64)."""

    name: str = "brief"
    descriptor_bytes: int = 32
    use_orientation: bool = False

    def __post_init__(self) -> None:
        require_name(self, "brief")
        require_choice("descriptor_bytes", self.descriptor_bytes, (16, 32, 64))


@dataclass(frozen=True)
class OrbDescriptorParams:
    """ORB (rotated BRIEF) descriptor, 32 bytes, WTA_K = 2 (Hamming distance).

    A keypoint's ``octave`` selects its pyramid level, so on ORB keypoints keep ``scale_factor``
    and ``n_levels`` equal to the detector's. ``edge_threshold``/``patch_size`` in pixels;
    keypoints closer than that to the border are dropped.
    """

    name: str = "orb"
    scale_factor: float = 1.2
    n_levels: int = 8
    edge_threshold: int = 31
    first_level: int = 0
    patch_size: int = 31

    def __post_init__(self) -> None:
        require_name(self, "orb")
        require_positive(n_levels=self.n_levels, patch_size=self.patch_size)
        if not self.scale_factor > 1.0:
            raise ValueError(f"scale_factor must be > 1, got {self.scale_factor!r}")


@dataclass(frozen=True)
class FreakDescriptorParams:
    """FREAK descriptor (opencv-contrib, 64 bytes); ``pattern_scale`` in pixels."""

    name: str = "freak"
    orientation_normalized: bool = True
    scale_normalized: bool = True
    pattern_scale: float = 22.0
    n_octaves: int = 4

    def __post_init__(self) -> None:
        require_name(self, "freak")
        require_positive(pattern_scale=self.pattern_scale, n_octaves=self.n_octaves)


AKAZE_DESCRIPTOR_TYPES = ("MLDB", "MLDB_UPRIGHT")


@dataclass(frozen=True)
class AkazeDescriptorParams:
    """AKAZE's binary MLDB descriptor (``descriptor_size = 0``: full size, 61 bytes).

    It rebuilds the nonlinear scale space and reads each keypoint's level from ``class_id``,
    so the scale-space fields must equal the AKAZE detector's (the defaults do). The float KAZE
    descriptor types are not offered: every descriptor here has one distance per name.
    """

    name: str = "akaze"
    descriptor_type: str = "MLDB"
    descriptor_size: int = 0
    descriptor_channels: int = 3
    threshold: float = 0.001
    n_octaves: int = 4
    n_octave_layers: int = 4
    diffusivity: str = "DIFF_PM_G2"

    def __post_init__(self) -> None:
        require_name(self, "akaze")
        require_choice("descriptor_type", self.descriptor_type, AKAZE_DESCRIPTOR_TYPES)
        require_choice("descriptor_channels", self.descriptor_channels, (1, 2, 3))
        require_choice("diffusivity", self.diffusivity, AKAZE_DIFFUSIVITIES)
        require_positive(n_octaves=self.n_octaves, n_octave_layers=self.n_octave_layers)


@dataclass(frozen=True)
class SiftDescriptorParams:
    """SIFT descriptor, 128 float32; ``sigma`` in pixels (the detector's defaults)."""

    name: str = "sift"
    n_octave_layers: int = 3
    sigma: float = 1.6

    def __post_init__(self) -> None:
        require_name(self, "sift")
        require_positive(n_octave_layers=self.n_octave_layers, sigma=self.sigma)


@dataclass(frozen=True)
class NoDescriptorParams:
    """The descriptor of a setting whose matcher uses none (``matcher=klt``): recorded as
    ``none``, never in :data:`DESCRIPTORS`."""

    name: str = "none"


NO_DESCRIPTOR = NoDescriptorParams()

#: The rubric's descriptors (FP.6's grid).
RUBRIC_DESCRIPTORS: tuple[str, ...] = ("brisk", "brief", "orb", "freak", "akaze", "sift")

DESCRIPTORS: dict[str, type] = {
    "brisk": BriskDescriptorParams,
    "brief": BriefDescriptorParams,
    "orb": OrbDescriptorParams,
    "freak": FreakDescriptorParams,
    "akaze": AkazeDescriptorParams,
    "sift": SiftDescriptorParams,
    **EXTRA_DESCRIPTORS,
    **LEARNED_DESCRIPTORS,
    USER: CustomDescriptorParams,
}
#: The descriptors beyond the rubric (OpenCV's other descriptors).
EXTRA_DESCRIPTOR_NAMES: tuple[str, ...] = tuple(EXTRA_DESCRIPTORS)

FLOAT_DESCRIPTORS = frozenset({"sift"}) | EXTRA_FLOAT_DESCRIPTORS | frozenset(LEARNED_DESCRIPTORS)

_AKAZE_REASON = (
    "the AKAZE descriptor needs AKAZE keypoints: it reads the scale-space level from class_id, "
    "which only the AKAZE detector sets (OpenCV asserts on class_id)"
)
_SIFT_ORB_REASON = (
    "the ORB descriptor reads SIFT's packed octave as a pyramid level and fails inside OpenCV "
    "(tries to allocate ~70 GB)"
)

_KAZE_REASON = (
    "the KAZE descriptor needs KAZE keypoints: it reads the scale-space level from class_id "
    "(OpenCV asserts on class_id for keypoints without one; on AKAZE keypoints, whose levels "
    "differ, 26 % of the descriptor values are NaN and nothing matches)"
)
_MSD_SIFT_REASON = (
    "the SIFT descriptor reads MSD's octave (its scale index) as SIFT's packed octave and "
    "fails inside OpenCV (resize asserts inv_scale_x > 0)"
)
_GRID_REASON = (
    "grid points are for the trackers (matcher klt, dis or farneback): most lie on the road, "
    "the sky or a flat panel, where a descriptor does not tell one point from its neighbours"
)
#: Invalid pairs with the descriptors and detectors beyond the rubric, as found on KITTI
#: frames 0 and 1 by trying every pair (OpenCV 4.14). LUCID works with every detector but
#: matches poorly here (12-21 % of its kNN matches move < 30 px, against > 95 % for the
#: others): it is made for colour images and gets the grey frame in three channels.
EXTRA_INVALID_PAIRS: dict[tuple[str, str], str] = {
    **{(det, "kaze"): _KAZE_REASON for det in DETECTORS if det != "kaze"},
    ("msd", "sift"): _MSD_SIFT_REASON,
    **{("grid", desc): _GRID_REASON for desc in DESCRIPTORS},
}

#: (detector, descriptor) → why the pair cannot work. The one table of invalid pairs.
INVALID_PAIRS: dict[tuple[str, str], str] = {
    **{(det, "akaze"): _AKAZE_REASON for det in DETECTORS if det != "akaze"},
    ("sift", "orb"): _SIFT_ORB_REASON,
    **EXTRA_INVALID_PAIRS,
    **{
        (det, desc): LEARNED_REASON
        for det in DETECTORS
        for desc in DESCRIPTORS
        if {det, desc} & set(LEARNED_DESCRIPTORS) and det != desc
    },  # fmt: skip
}


class InvalidCombinationError(ValueError):
    """A detector × descriptor pair that cannot work; ``reason`` says why."""

    def __init__(self, detector: str, descriptor: str, reason: str) -> None:
        self.detector, self.descriptor, self.reason = detector, descriptor, reason
        super().__init__(f"detector {detector!r} with descriptor {descriptor!r}: {reason}")


class FeatureUnavailableError(InvalidCombinationError):
    """The installed OpenCV lacks the detector or the descriptor of a pair (a skip too)."""


def unavailable_reason(detector: str, descriptor: str) -> str | None:
    """Why the installed OpenCV cannot run the pair (None: it can)."""
    if learned_missing(detector) or learned_missing(descriptor):
        return learned_missing(detector) or learned_missing(descriptor)
    missing = [f"detector {detector!r}"] if not detector_available(detector) else []
    if not descriptor_available(descriptor):
        missing.append(f"descriptor {descriptor!r}")
    if not missing:
        return None
    return f"OpenCV {cv2.__version__} lacks the {' and the '.join(missing)} (unavailable)"


def is_binary(descriptor_name: str) -> bool:
    """True for binary (uint8, Hamming) descriptors, False for float (L2) ones (by name; a
    ``custom`` descriptor says so in its parameters: :func:`descriptor_is_binary`)."""
    if descriptor_name not in DESCRIPTORS:
        raise ValueError(f"unknown descriptor {descriptor_name!r}; choose from {list(DESCRIPTORS)}")
    return descriptor_name not in FLOAT_DESCRIPTORS


def descriptor_is_binary(params: Any) -> bool:
    """True when the descriptor ``params`` gives binary (uint8, Hamming) descriptors."""
    if params.name == USER:
        return bool(params.binary)
    return is_binary(params.name)


def check_pair(detector: str, descriptor: str) -> None:
    """Raise :class:`InvalidCombinationError` for an invalid pair, ValueError for unknown names."""
    if detector not in DETECTORS:
        raise ValueError(f"unknown detector {detector!r}; choose from {list(DETECTORS)}")
    if descriptor not in DESCRIPTORS:
        raise ValueError(f"unknown descriptor {descriptor!r}; choose from {list(DESCRIPTORS)}")
    missing = unavailable_reason(detector, descriptor)
    if missing is not None:
        raise FeatureUnavailableError(detector, descriptor, missing)
    reason = INVALID_PAIRS.get((detector, descriptor))
    if reason is not None:
        raise InvalidCombinationError(detector, descriptor, reason)


def valid_pairs(rubric_only: bool = True) -> list[tuple[str, str]]:
    """Every valid (detector, descriptor) pair, in registry order: the rubric's only (default,
    FP.6's grid) or every registered OpenCV one (``rubric_only=False``)."""
    other = {USER, *LEARNED_DESCRIPTORS}  # learned pairs: +experiment=learned, not the zoo
    dets = RUBRIC_DETECTORS if rubric_only else tuple(d for d in DETECTORS if d not in other)
    descs = RUBRIC_DESCRIPTORS if rubric_only else tuple(d for d in DESCRIPTORS if d not in other)
    return [(d, e) for d in dets for e in descs if (d, e) not in INVALID_PAIRS]


def _brisk(p: BriskDescriptorParams) -> Any:
    return opencv_factory("BRISK")(30, 3, p.pattern_scale)  # thresholds unused by compute()


def _brief(p: BriefDescriptorParams) -> Any:
    create = opencv_factory("BriefDescriptorExtractor", contrib=True)
    return create(p.descriptor_bytes, p.use_orientation)


def _orb(p: OrbDescriptorParams) -> Any:
    return opencv_factory("ORB")(
        scaleFactor=p.scale_factor, nlevels=p.n_levels, edgeThreshold=p.edge_threshold,
        firstLevel=p.first_level, WTA_K=2, patchSize=p.patch_size,
    )  # fmt: skip


def _freak(p: FreakDescriptorParams) -> Any:
    create = opencv_factory("FREAK", contrib=True)
    return create(p.orientation_normalized, p.scale_normalized, p.pattern_scale, p.n_octaves)


def _akaze(p: AkazeDescriptorParams) -> Any:
    return opencv_factory("AKAZE")(
        descriptor_type=opencv_constant("AKAZE", f"DESCRIPTOR_{p.descriptor_type}"),
        descriptor_size=p.descriptor_size, descriptor_channels=p.descriptor_channels,
        threshold=p.threshold, nOctaves=p.n_octaves, nOctaveLayers=p.n_octave_layers,
        diffusivity=opencv_constant("KAZE", p.diffusivity),
    )  # fmt: skip


def _sift(p: SiftDescriptorParams) -> Any:
    return opencv_factory("SIFT")(nOctaveLayers=p.n_octave_layers, sigma=p.sigma)


_EXTRACTORS: dict[str, Callable[[Any], Any]] = {
    "brisk": _brisk,
    "brief": _brief,
    "orb": _orb,
    "freak": _freak,
    "akaze": _akaze,
    "sift": _sift,
}


def make_extractor(params: Any, detector_name: str = "") -> Any:
    """The OpenCV descriptor extractor for ``params`` (one of the :data:`DESCRIPTORS` classes);
    ``detector_name`` sets the documented sampling scale of the descriptors that need one."""
    if params.name in EXTRA_EXTRACTORS:
        return EXTRA_EXTRACTORS[params.name](params, detector_name)
    return _EXTRACTORS[params.name](params)


@functools.lru_cache(maxsize=64)
def _shared_extractor(params: Any, detector_name: str) -> Any:
    return make_extractor(params, detector_name)


def shared_extractor(params: Any, detector_name: str = "") -> Any:
    """:func:`make_extractor`'s object, made once per (params, detector) in this process:
    OpenCV builds BRISK's sampling pattern (~40 ms) when the object is made, more than
    describing a frame. ``compute()`` keeps no state between images; one object per thread
    (the harness runs one thread per process). Unhashable parameters get a new object."""
    try:
        return _shared_extractor(params, detector_name)
    except TypeError:  # unhashable parameters (a user's dataclass with a list)
        return make_extractor(params, detector_name)


def _empty_descriptors(extractor: Any) -> np.ndarray:
    dtype = np.float32 if extractor.descriptorType() == cv2.CV_32F else np.uint8
    return np.empty((0, extractor.descriptorSize()), dtype=dtype)


def describe_keypoints(
    gray: np.ndarray, keypoints: np.ndarray, detector_name: str, params: Any
) -> tuple[np.ndarray, np.ndarray]:
    """(kept keypoints (M, 7), descriptors (M, D)) of ``keypoints`` in a uint8 H × W image.

    ``compute()`` drops keypoints (near the border) and may change them (BRISK and ORB set the
    angle, SIFT and AKAZE read octave/class_id), so the keypoints it returns are returned; row i
    of the descriptors belongs to row i of the kept keypoints. Raises
    :class:`InvalidCombinationError` for an invalid pair before any work.
    """
    check_pair(detector_name, params.name)
    check_gray(gray)
    if params.name == USER:
        return describe_custom(gray, keypoints, params)
    extractor = shared_extractor(params, detector_name)
    if len(keypoints) == 0:
        return empty_keypoints(), _empty_descriptors(extractor)
    image = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR) if params.name in COLOUR_DESCRIPTORS else gray
    kept, descriptors = extractor.compute(image, array_to_keypoints(keypoints))
    if descriptors is None or len(kept) == 0:
        return empty_keypoints(), _empty_descriptors(extractor)
    return keypoints_to_array(kept), descriptors
