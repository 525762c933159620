"""The descriptors OpenCV ships beyond the rubric's six: KAZE, and from opencv-contrib's
``xfeatures2d`` BEBLID, TEBLID, DAISY, LATCH, LUCID, BoostDesc and VGG.

Same contract as :mod:`ttc.features.descriptors` (which merges :data:`EXTRA_DESCRIPTORS` into its
registry): a frozen parameter dataclass per descriptor, named by ``name``, and a factory
``(params, detector name) → OpenCV extractor``. KAZE, DAISY and VGG give float32 descriptors
(L2), the others binary uint8 strings (Hamming); BoostDesc is offered in its binary variants
only, so every name has one distance.

``scale_factor = 0`` (BEBLID, TEBLID, BoostDesc, VGG) means the value OpenCV documents for the
keypoints' detector (:func:`documented_scale`): these descriptors size their sampling window
as ``scale_factor`` × keypoint size, and keypoint sizes differ by detector (ORB's are ~31 px,
FAST's 7 px). LUCID needs a colour image; it is given the grey frame in three channels.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ttc.features.base import (
    opencv_constant,
    opencv_factory,
    opencv_has,
    require_choice,
    require_name,
    require_positive,
)
from ttc.features.detectors_extra import KAZE_DIFFUSIVITIES

#: Documented scale factors (BEBLID/TEBLID: "1.00 for ORB, 6.75 for SIFT, 6.25 for KAZE/SURF,
#: 5.00 for AKAZE, MSD, AGAST, FAST, BRISK"); BoostDesc/VGG say 0.75 for ORB. Detectors the
#: documentation does not name use 5.0 when their keypoints have FAST's small fixed size
#: (Shi–Tomasi, Harris) and the KAZE/SURF default 6.25 when their sizes are scale-adapted.
_BLID_SCALE = {"orb": 1.0, "sift": 6.75, "kaze": 6.25, "akaze": 5.0, "msd": 5.0,
               "agast": 5.0, "fast": 5.0, "brisk": 5.0, "shitomasi": 5.0, "harris": 5.0}  # fmt: skip
_BOOST_VGG_SCALE = {**_BLID_SCALE, "orb": 0.75}
DEFAULT_SCALE = 6.25


def documented_scale(descriptor: str, detector: str) -> float:
    """The sampling-window scale OpenCV documents for ``descriptor`` on ``detector``'s
    keypoints (dimensionless; :data:`DEFAULT_SCALE` for detectors it does not name)."""
    table = _BOOST_VGG_SCALE if descriptor in ("boostdesc", "vgg") else _BLID_SCALE
    return table.get(detector, DEFAULT_SCALE)


def _scale(p: Any, detector: str) -> float:
    return float(p.scale_factor) if p.scale_factor > 0 else documented_scale(p.name, detector)


@dataclass(frozen=True)
class KazeDescriptorParams:
    """KAZE's float descriptor (64, or 128 with ``extended``) in a nonlinear scale space.

    Like AKAZE's it reads each keypoint's scale-space level from ``class_id``: the scale-space
    fields must equal the KAZE detector's (the defaults do).
    """

    name: str = "kaze"
    extended: bool = False
    upright: bool = False
    threshold: float = 0.001
    n_octaves: int = 4
    n_octave_layers: int = 4
    diffusivity: str = "DIFF_PM_G2"

    def __post_init__(self) -> None:
        require_name(self, "kaze")
        require_choice("diffusivity", self.diffusivity, KAZE_DIFFUSIVITIES)
        require_positive(n_octaves=self.n_octaves, n_octave_layers=self.n_octave_layers)


@dataclass(frozen=True)
class BeblidDescriptorParams:
    """BEBLID binary descriptor of ``n_bits`` (256 or 512); ``scale_factor`` 0: documented."""

    name: str = "beblid"
    scale_factor: float = 0.0
    n_bits: int = 512

    def __post_init__(self) -> None:
        require_name(self, "beblid")
        require_choice("n_bits", self.n_bits, (256, 512))
        if self.scale_factor < 0:
            raise ValueError(f"scale_factor must be >= 0, got {self.scale_factor!r}")


@dataclass(frozen=True)
class TeblidDescriptorParams:
    """TEBLID (triplet-trained BEBLID) of ``n_bits`` (256 or 512); ``scale_factor`` 0:
    documented."""

    name: str = "teblid"
    scale_factor: float = 0.0
    n_bits: int = 256

    def __post_init__(self) -> None:
        require_name(self, "teblid")
        require_choice("n_bits", self.n_bits, (256, 512))
        if self.scale_factor < 0:
            raise ValueError(f"scale_factor must be >= 0, got {self.scale_factor!r}")


DAISY_NORMS = ("NRM_NONE", "NRM_PARTIAL", "NRM_FULL", "NRM_SIFT")


@dataclass(frozen=True)
class DaisyDescriptorParams:
    """DAISY float descriptor (200 values by default); ``radius`` in pixels."""

    name: str = "daisy"
    radius: float = 15.0
    q_radius: int = 3
    q_theta: int = 8
    q_hist: int = 8
    norm: str = "NRM_NONE"
    use_orientation: bool = False

    def __post_init__(self) -> None:
        require_name(self, "daisy")
        require_positive(radius=self.radius, q_radius=self.q_radius, q_theta=self.q_theta,
                         q_hist=self.q_hist)  # fmt: skip
        require_choice("norm", self.norm, DAISY_NORMS)


@dataclass(frozen=True)
class LatchDescriptorParams:
    """LATCH binary descriptor of ``descriptor_bytes``; ``half_ssd_size``/``sigma`` in px."""

    name: str = "latch"
    descriptor_bytes: int = 32
    rotation_invariance: bool = True
    half_ssd_size: int = 3
    sigma: float = 2.0

    def __post_init__(self) -> None:
        require_name(self, "latch")
        require_choice("descriptor_bytes", self.descriptor_bytes, (1, 2, 4, 8, 16, 32, 64))
        require_positive(half_ssd_size=self.half_ssd_size)


@dataclass(frozen=True)
class LucidDescriptorParams:
    """LUCID (locally uniform comparison image descriptor); kernels 1 = 3×3, 2 = 5×5, …"""

    name: str = "lucid"
    lucid_kernel: int = 1
    blur_kernel: int = 2

    def __post_init__(self) -> None:
        require_name(self, "lucid")
        require_positive(lucid_kernel=self.lucid_kernel, blur_kernel=self.blur_kernel)


#: BoostDesc's binary variants and their OpenCV enum values (``BoostDesc::BinBoostType``).
BOOSTDESC_TYPES = {"BGM": 100, "BGM_HARD": 101, "BGM_BILINEAR": 102, "BINBOOST_64": 300,
                   "BINBOOST_128": 301, "BINBOOST_256": 302}  # fmt: skip


@dataclass(frozen=True)
class BoostDescDescriptorParams:
    """BoostDesc binary descriptor (``type`` one of :data:`BOOSTDESC_TYPES`); ``scale_factor``
    0: documented."""

    name: str = "boostdesc"
    type: str = "BINBOOST_256"
    use_scale_orientation: bool = True
    scale_factor: float = 0.0

    def __post_init__(self) -> None:
        require_name(self, "boostdesc")
        require_choice("type", self.type, tuple(BOOSTDESC_TYPES))
        if self.scale_factor < 0:
            raise ValueError(f"scale_factor must be >= 0, got {self.scale_factor!r}")


#: VGG's variants and their OpenCV enum values (``VGG::...``): 120, 80, 64 or 48 floats.
VGG_TYPES = {"VGG_120": 100, "VGG_80": 101, "VGG_64": 102, "VGG_48": 103}


@dataclass(frozen=True)
class VggDescriptorParams:
    """VGG float descriptor (learned, ``type`` in :data:`VGG_TYPES`); ``isigma`` in pixels,
    ``scale_factor`` 0: documented."""

    name: str = "vgg"
    type: str = "VGG_120"
    isigma: float = 1.4
    img_normalize: bool = True
    use_scale_orientation: bool = True
    scale_factor: float = 0.0
    dsc_normalize: bool = False

    def __post_init__(self) -> None:
        require_name(self, "vgg")
        require_choice("type", self.type, tuple(VGG_TYPES))
        require_positive(isigma=self.isigma)
        if self.scale_factor < 0:
            raise ValueError(f"scale_factor must be >= 0, got {self.scale_factor!r}")


def _kaze(p: KazeDescriptorParams, detector: str) -> Any:
    return opencv_factory("KAZE")(
        extended=p.extended, upright=p.upright, threshold=p.threshold, nOctaves=p.n_octaves,
        nOctaveLayers=p.n_octave_layers, diffusivity=opencv_constant("KAZE", p.diffusivity),
    )  # fmt: skip


def _blid(kind: str) -> Callable[[Any, str], Any]:
    def make(p: Any, detector: str) -> Any:
        bits = opencv_constant(f"xfeatures2d.{kind}", f"SIZE_{p.n_bits}_BITS")
        return opencv_factory(kind, contrib=True)(_scale(p, detector), bits)

    return make


def _daisy(p: DaisyDescriptorParams, detector: str) -> Any:
    norm = opencv_constant("xfeatures2d.DAISY", p.norm)
    return opencv_factory("DAISY", contrib=True)(
        radius=p.radius, q_radius=p.q_radius, q_theta=p.q_theta, q_hist=p.q_hist, norm=norm,
        use_orientation=p.use_orientation,
    )  # fmt: skip


def _latch(p: LatchDescriptorParams, detector: str) -> Any:
    create = opencv_factory("LATCH", contrib=True)
    return create(p.descriptor_bytes, p.rotation_invariance, p.half_ssd_size, p.sigma)


def _lucid(p: LucidDescriptorParams, detector: str) -> Any:
    return opencv_factory("LUCID", contrib=True)(p.lucid_kernel, p.blur_kernel)


def _boostdesc(p: BoostDescDescriptorParams, detector: str) -> Any:
    create = opencv_factory("BoostDesc", contrib=True)
    return create(BOOSTDESC_TYPES[p.type], p.use_scale_orientation, _scale(p, detector))


def _vgg(p: VggDescriptorParams, detector: str) -> Any:
    return opencv_factory("VGG", contrib=True)(
        VGG_TYPES[p.type], p.isigma, p.img_normalize, p.use_scale_orientation,
        _scale(p, detector), p.dsc_normalize,
    )  # fmt: skip


EXTRA_DESCRIPTORS: dict[str, type] = {
    "kaze": KazeDescriptorParams,
    "beblid": BeblidDescriptorParams,
    "teblid": TeblidDescriptorParams,
    "daisy": DaisyDescriptorParams,
    "latch": LatchDescriptorParams,
    "lucid": LucidDescriptorParams,
    "boostdesc": BoostDescDescriptorParams,
    "vgg": VggDescriptorParams,
}

EXTRA_EXTRACTORS: dict[str, Callable[[Any, str], Any]] = {
    "kaze": _kaze,
    "beblid": _blid("BEBLID"),
    "teblid": _blid("TEBLID"),
    "daisy": _daisy,
    "latch": _latch,
    "lucid": _lucid,
    "boostdesc": _boostdesc,
    "vgg": _vgg,
}

EXTRA_FLOAT_DESCRIPTORS = frozenset({"kaze", "daisy", "vgg"})
#: Descriptors computed on a 3-channel image (the grey frame repeated).
COLOUR_DESCRIPTORS = frozenset({"lucid"})

#: OpenCV algorithm behind each extra descriptor (for :func:`descriptor_available`).
OPENCV_ALGORITHMS: dict[str, str] = {
    "kaze": "KAZE", "beblid": "BEBLID", "teblid": "TEBLID", "daisy": "DAISY",
    "latch": "LATCH", "lucid": "LUCID", "boostdesc": "BoostDesc", "vgg": "VGG",
}  # fmt: skip


def descriptor_available(name: str) -> bool:
    """False when ``name`` is an extra descriptor the installed OpenCV lacks."""
    return name not in OPENCV_ALGORITHMS or opencv_has(OPENCV_ALGORITHMS[name])
