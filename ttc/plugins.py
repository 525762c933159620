"""Your own detector, descriptor or matcher, from your own module, without editing the package.

Choose ``detector=custom`` (or ``descriptor=custom``, ``matcher=custom``) and name a Python
callable in ``target`` as ``"package.module:function"``; ``params`` (a mapping) is passed to it
as keyword arguments. The callable has the registry's signature:

=============  ================================================  ===================================
option         called as                                         returns
=============  ================================================  ===================================
detector       ``fn(gray, **params)``                            keypoints: (N, 7) array, (N, 2)
                                                                 x, y array (pixels) or a list of
                                                                 ``cv2.KeyPoint``
descriptor     ``fn(gray, keypoints, **params)``                 (kept keypoints (M, 7), descriptors
                                                                 (M, D)); uint8 with ``binary``
                                                                 (Hamming), else float32 (L2)
matcher        ``fn(desc_prev, desc_curr, binary, **params)``    (idx int (Q, 2), dist float (Q, 2)):
                                                                 the two nearest current
                                                                 descriptors of every previous
                                                                 one, best first, −1 / +inf where
                                                                 missing (as
                                                                 :func:`ttc.features.matching.knn_candidates`)
=============  ================================================  ===================================

``gray`` is the uint8 H × W frame, ``keypoints`` a (N, 7) array (:mod:`ttc.features.base`). The
stage cache keys a custom stage by ``target``, ``params`` and the function's compiled code, so
editing the function recomputes it. The defaults point at the small examples below.
"""

from __future__ import annotations

import hashlib
import importlib
import marshal
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from ttc.features.base import (
    KEYPOINT_COLUMNS,
    check_gray,
    empty_keypoints,
    keypoints_to_array,
    points_array,
    require_name,
)

USER = "custom"


def resolve_callable(target: str) -> Callable[..., Any]:
    """The callable named ``"module:attr"`` (or ``"module.attr"``); ValueError when it does
    not import or is not callable."""
    module_name, sep, attr = target.partition(":")
    if not sep:
        module_name, _, attr = target.rpartition(".")
    if not module_name or not attr:
        raise ValueError(f"target must be 'module:function', got {target!r}")
    try:
        obj: Any = importlib.import_module(module_name)
        for part in attr.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"cannot import target {target!r}: {exc}") from exc
    if not callable(obj):
        raise ValueError(f"target {target!r} is not callable")
    return obj


def code_identity(target: str) -> str:
    """A hash of the target's compiled code (changes when the function is edited); the
    target's name when it has no Python code object (a builtin, a class)."""
    fn = resolve_callable(target)
    code = getattr(fn, "__code__", None)
    blob = marshal.dumps(code) if code is not None else target.encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def _check_target(params: Any) -> None:
    if not isinstance(params.target, str) or not params.target:
        raise ValueError(f"{type(params).__name__}.target must name a callable 'module:function'")


@dataclass(frozen=True)
class CustomDetectorParams:
    """A detector from your module: ``target`` ``"module:function"``, ``params`` its keyword
    arguments, ``subpixel`` as for every detector."""

    name: str = USER
    target: str = "ttc.plugins:example_detector"
    params: dict[str, Any] = field(default_factory=dict)
    subpixel: bool = False

    def __post_init__(self) -> None:
        require_name(self, USER)
        _check_target(self)


@dataclass(frozen=True)
class CustomDescriptorParams:
    """A descriptor from your module; ``binary``: uint8 descriptors matched by Hamming
    distance (else float32, L2)."""

    name: str = USER
    target: str = "ttc.plugins:example_descriptor"
    params: dict[str, Any] = field(default_factory=dict)
    binary: bool = False

    def __post_init__(self) -> None:
        require_name(self, USER)
        _check_target(self)


@dataclass(frozen=True)
class CustomMatcherParams:
    """A k = 2 candidate matcher from your module (NN and kNN select from its candidates)."""

    name: str = USER
    target: str = "ttc.plugins:example_matcher"
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        require_name(self, USER)
        _check_target(self)


def as_keypoint_array(result: Any) -> np.ndarray:
    """A detector's return value as a (N, 7) keypoint array (see the module table)."""
    if isinstance(result, list | tuple) and (
        len(result) == 0 or isinstance(result[0], cv2.KeyPoint)
    ):
        return keypoints_to_array(result) if len(result) else empty_keypoints()
    arr = np.asarray(result, dtype=np.float64)
    if arr.ndim == 2 and arr.shape[1] == len(KEYPOINT_COLUMNS):
        return arr
    if arr.ndim == 2 and arr.shape[1] == 2:
        return points_array(arr, size=7.0)
    if arr.size == 0:
        return empty_keypoints()
    raise ValueError(f"a custom detector must return (N, 7) or (N, 2) arrays, got {arr.shape}")


def detect_custom(gray: np.ndarray, p: CustomDetectorParams) -> np.ndarray:
    """Keypoints (N, 7) of the user's detector."""
    return as_keypoint_array(resolve_callable(p.target)(gray, **p.params))


def describe_custom(
    gray: np.ndarray, keypoints: np.ndarray, p: CustomDescriptorParams
) -> tuple[np.ndarray, np.ndarray]:
    """(kept keypoints (M, 7), descriptors (M, D)) of the user's descriptor, typed and checked."""
    kept, desc = resolve_callable(p.target)(gray, keypoints, **p.params)
    kept = as_keypoint_array(kept)
    desc = np.asarray(desc, dtype=np.uint8 if p.binary else np.float32)
    if desc.ndim != 2 or len(desc) != len(kept):
        raise ValueError(
            f"custom descriptor {p.target}: {len(kept)} keypoints but descriptors {desc.shape}"
        )
    return kept, np.ascontiguousarray(desc)


def match_custom(
    desc_prev: np.ndarray, desc_curr: np.ndarray, binary: bool, p: CustomMatcherParams
) -> tuple[np.ndarray, np.ndarray]:
    """(idx int32 (Q, 2), dist float32 (Q, 2)) of the user's matcher, checked."""
    idx, dist = resolve_callable(p.target)(desc_prev, desc_curr, binary, **p.params)
    idx, dist = np.asarray(idx, dtype=np.int32), np.asarray(dist, dtype=np.float32)
    if idx.shape != (len(desc_prev), 2) or dist.shape != idx.shape:
        raise ValueError(
            f"custom matcher {p.target}: expected ({len(desc_prev)}, 2) candidates, "
            f"got idx {idx.shape} and dist {dist.shape}"
        )
    return idx, dist


# --- the examples the defaults point at -----------------------------------------------------


def example_detector(gray: np.ndarray, max_corners: int = 2000, quality: float = 0.01):
    """Shi–Tomasi corners refined to sub-pixel positions, as (N, 2) x, y (pixels)."""
    check_gray(gray)
    corners = cv2.goodFeaturesToTrack(gray, max_corners, quality, 4)
    if corners is None:
        return np.empty((0, 2))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.001)
    return cv2.cornerSubPix(gray, corners, (3, 3), (-1, -1), criteria).reshape(-1, 2)


def example_descriptor(gray: np.ndarray, keypoints: np.ndarray, radius: int = 4):
    """Zero-mean, unit-norm (2·radius+1)² grey patches (float32) of the keypoints at least
    ``radius`` pixels inside the image."""
    h, w = gray.shape
    xy = np.rint(keypoints[:, :2]).astype(int)
    inside = (xy[:, 0] >= radius) & (xy[:, 0] < w - radius)
    inside &= (xy[:, 1] >= radius) & (xy[:, 1] < h - radius)
    kept, xy = keypoints[inside], xy[inside]
    offsets = np.arange(-radius, radius + 1)
    rows = xy[:, 1, None, None] + offsets[None, :, None]
    cols = xy[:, 0, None, None] + offsets[None, None, :]
    patches = gray[rows, cols].reshape(len(kept), -1).astype(np.float32)
    patches -= patches.mean(axis=1, keepdims=True)
    patches /= np.linalg.norm(patches, axis=1, keepdims=True) + 1e-6
    return kept, patches


def example_matcher(desc_prev: np.ndarray, desc_curr: np.ndarray, binary: bool):
    """Brute-force k = 2 candidates with OpenCV (Hamming or L2)."""
    norm = cv2.NORM_HAMMING if binary else cv2.NORM_L2
    idx = np.full((len(desc_prev), 2), -1, np.int32)
    dist = np.full((len(desc_prev), 2), np.inf, np.float32)
    if len(desc_prev) == 0 or len(desc_curr) == 0:
        return idx, dist
    for q, found in enumerate(cv2.BFMatcher(norm).knnMatch(desc_prev, desc_curr, k=2)):
        for j, m in enumerate(found):
            idx[q, j], dist[q, j] = m.trainIdx, m.distance
    return idx, dist
