"""What every keypoint detector and descriptor module shares: the keypoint array format, the
OpenCV look-ups (with a clear error when the installed OpenCV lacks an algorithm) and the
parameter checks.

A keypoint array is float64, shape (N, 7), columns :data:`KEYPOINT_COLUMNS`: x, y (pixels),
size (diameter, pixels), angle (degrees, −1 when the detector sets none), response, octave
(OpenCV's packed int) and class_id. Every field of ``cv2.KeyPoint`` is kept because descriptors
read them back: ORB and SIFT use ``octave``, AKAZE's descriptor indexes its scale space with the
``class_id`` its detector set. float64 holds the float32 and int32 fields exactly, so
:func:`keypoints_to_array` and :func:`array_to_keypoints` round-trip losslessly; they are the
only loops over keypoints and run at the OpenCV boundary.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import reduce
from itertools import starmap
from operator import attrgetter
from typing import Any

import cv2
import numpy as np

KEYPOINT_COLUMNS = ("x", "y", "size", "angle", "response", "octave", "class_id")
X, Y, SIZE, ANGLE, RESPONSE, OCTAVE, CLASS_ID = range(7)

CONTRIB_PACKAGE = "opencv-contrib-python-headless"

_SCALAR_FIELDS = attrgetter("size", "angle", "response", "octave", "class_id")


class OpenCVFeatureMissing(RuntimeError):
    """The installed OpenCV lacks a factory or constant this module needs."""


def _getattr_path(root: Any, path: str) -> Any:
    return reduce(getattr, path.split("."), root)


def opencv_lookup(*paths: str, hint: str = "") -> Any:
    """The first of ``paths`` (dotted, relative to ``cv2``) that exists, else a clear error."""
    for path in paths:
        try:
            return _getattr_path(cv2, path)
        except AttributeError:
            continue
    tried = ", ".join(f"cv2.{p}" for p in paths)
    message = f"OpenCV {cv2.__version__} provides none of {tried}"
    raise OpenCVFeatureMissing(f"{message}; {hint}" if hint else message)


def opencv_factory(name: str, contrib: bool = False) -> Callable[..., Any]:
    """The ``create`` function of an OpenCV algorithm, wherever this OpenCV version keeps it.

    Tries ``cv2.<name>_create``, ``cv2.<name>.create`` and the same under ``cv2.xfeatures2d``
    (where contrib algorithms live, and where SIFT lived before 4.4).
    """
    paths = (f"{name}_create", f"{name}.create", f"xfeatures2d.{name}_create",
             f"xfeatures2d.{name}.create")  # fmt: skip
    hint = f"{name} needs {CONTRIB_PACKAGE}" if contrib else "is OpenCV installed correctly?"
    return opencv_lookup(*paths, hint=hint)


def opencv_has(name: str) -> bool:
    """True when the installed OpenCV has a factory for algorithm ``name``."""
    try:
        opencv_factory(name)
    except OpenCVFeatureMissing:
        return False
    return True


def opencv_constant(owner: str, name: str) -> int:
    """An enum value such as ``FastFeatureDetector.TYPE_9_16`` under any binding spelling."""
    return int(opencv_lookup(f"{owner}_{name}", f"{owner}.{name}"))


def require_name(params: Any, expected: str) -> None:
    """ValueError unless ``params.name == expected``."""
    if params.name != expected:
        raise ValueError(f"{type(params).__name__}.name must be {expected!r}, got {params.name!r}")


def require_choice(field: str, value: Any, choices: tuple[Any, ...]) -> None:
    """ValueError unless ``value`` is one of ``choices``."""
    if value not in choices:
        raise ValueError(f"{field} must be one of {choices}, got {value!r}")


def require_positive(**values: float) -> None:
    """ValueError naming the first of ``values`` that is not > 0."""
    for field, value in values.items():
        if not value > 0:
            raise ValueError(f"{field} must be > 0, got {value!r}")


def check_gray(gray: np.ndarray) -> None:
    """Raise ValueError unless ``gray`` is a 2-D uint8 image."""
    if not isinstance(gray, np.ndarray) or gray.ndim != 2 or gray.dtype != np.uint8:
        desc = f"{gray.dtype} {gray.shape}" if isinstance(gray, np.ndarray) else type(gray)
        raise ValueError(f"expected a 2-D uint8 grayscale image, got {desc}")


def empty_keypoints() -> np.ndarray:
    """A (0, 7) keypoint array."""
    return np.empty((0, len(KEYPOINT_COLUMNS)), dtype=np.float64)


def keypoints_to_array(keypoints: list[cv2.KeyPoint] | tuple[cv2.KeyPoint, ...]) -> np.ndarray:
    """(N, 7) float64 array of OpenCV keypoints, columns :data:`KEYPOINT_COLUMNS`."""
    if len(keypoints) == 0:
        return empty_keypoints()
    out = np.empty((len(keypoints), len(KEYPOINT_COLUMNS)), dtype=np.float64)
    out[:, X : Y + 1] = cv2.KeyPoint_convert(keypoints)
    out[:, SIZE:] = list(map(_SCALAR_FIELDS, keypoints))
    return out


def array_to_keypoints(array: np.ndarray) -> list[cv2.KeyPoint]:
    """OpenCV keypoints of an (N, 7) array (octave and class_id rounded to int)."""
    array = np.asarray(array, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != len(KEYPOINT_COLUMNS):
        raise ValueError(f"keypoint array must be (N, {len(KEYPOINT_COLUMNS)}), got {array.shape}")
    columns = array[:, :OCTAVE].T.tolist()
    columns += np.rint(array[:, OCTAVE:]).astype(np.int64).T.tolist()
    return list(starmap(cv2.KeyPoint, zip(*columns, strict=True)))


def points_array(xy: np.ndarray, size: float, response: np.ndarray | float = 0.0) -> np.ndarray:
    """Keypoint array of pixel positions (N × 2) with one size (pixels), no angle, octave 0,
    class_id −1."""
    out = np.zeros((len(xy), len(KEYPOINT_COLUMNS)), dtype=np.float64)
    out[:, X : Y + 1] = xy
    out[:, SIZE] = size
    out[:, ANGLE] = -1.0
    out[:, RESPONSE] = response
    out[:, CLASS_ID] = -1.0
    return out


def detect_with(detector: Any, gray: np.ndarray) -> np.ndarray:
    """Keypoint array of an OpenCV ``Feature2D``'s ``detect`` on ``gray``."""
    return keypoints_to_array(detector.detect(gray, None))
