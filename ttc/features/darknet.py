"""YOLO's Darknet networks through ``cv2.dnn``: the weight checks and the output decoding.

Decoding follows the Udacity starter: each output row is ``cx, cy, w, h`` (relative to the
input, 0–1), an objectness score and one score per class; a row's class is its best class and
its confidence that class's score (objectness is not multiplied in).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from ttc.features.model_files import ModelFileError

DARKNET_STRIDE = 32  # input sizes must be multiples of this (pixels)
_ROW_HEAD = 5  # cx, cy, w, h, objectness before the class scores
_WEIGHT_LAYERS = {"Convolution", "BatchNorm", "InnerProduct"}  # layers read from .weights


class Candidates(NamedTuple):
    """Boxes (K × 4 float64: x, y, w, h pixels, unclipped), class ids (K int32), confidences
    (K float32), and how many classes the network predicts."""

    boxes: np.ndarray
    class_id: np.ndarray
    confidence: np.ndarray
    n_classes: int


def darknet_weight_count(path: Path | str) -> int:
    """Number of float32 parameters in a Darknet ``.weights`` file (after its header)."""
    path = Path(path)
    try:
        size = path.stat().st_size
        header = np.fromfile(path, dtype=np.int32, count=3)
    except OSError as exc:
        raise ModelFileError(path, f"cannot read weights: {exc}") from exc
    if size < 16 or len(header) < 3:
        raise ModelFileError(path, f"weights file too short ({size} bytes)")
    major, minor = int(header[0]), int(header[1])
    seen_bytes = 8 if (major * 10 + minor) >= 2 and major < 1000 and minor < 1000 else 4
    return (size - 12 - seen_bytes) // 4


def net_parameter_count(net: cv2.dnn.Net) -> int:
    """Number of learned parameters a Darknet-imported network holds (YOLO anchors excluded)."""
    layers = (net.getLayer(net.getLayerId(name)) for name in net.getLayerNames())
    return sum(b.size for layer in layers if layer.type in _WEIGHT_LAYERS for b in layer.blobs)


def decode_outputs(
    outputs: list[np.ndarray] | tuple[np.ndarray, ...],
    image_size: tuple[int, int],
    threshold: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Candidate boxes from YOLO output rows, best class and its score above ``threshold``.

    ``image_size`` is (width, height) in pixels. Returns boxes (K × 4 float64: x, y, w, h
    pixels, unclipped), class ids (K int32) and confidences (K float32).
    """
    rows = np.concatenate(
        [np.asarray(o, dtype=np.float32).reshape(-1, o.shape[-1]) for o in outputs]
    )
    scores = rows[:, _ROW_HEAD:]
    class_id = np.argmax(scores, axis=1).astype(np.int32)
    confidence = scores[np.arange(len(rows)), class_id]
    keep = confidence > threshold
    rows, class_id, confidence = rows[keep], class_id[keep], confidence[keep]
    width, height = image_size
    centre = rows[:, 0:2].astype(np.float64) * (width, height)
    size = rows[:, 2:4].astype(np.float64) * (width, height)
    boxes = np.hstack([centre - size / 2.0, size])
    return boxes, class_id, confidence.astype(np.float32)


def darknet_candidates(
    image: np.ndarray,
    net: cv2.dnn.Net,
    input_size: tuple[int, int],
    scale: float,
    swap_rb: bool,
    threshold: float,
) -> Candidates:
    """:func:`decode_outputs` of one BGR image (H × W × 3 uint8) resized to ``input_size``
    (width, height pixels), pixel values times ``scale``, RGB when ``swap_rb``."""
    blob = cv2.dnn.blobFromImage(
        image, scalefactor=scale, size=input_size, mean=(0, 0, 0), swapRB=swap_rb, crop=False
    )
    net.setInput(blob)
    outputs = net.forward(net.getUnconnectedOutLayersNames())
    n_classes = outputs[0].shape[-1] - _ROW_HEAD
    if n_classes <= 0:
        return Candidates(np.zeros((0, 4)), np.zeros(0, np.int32), np.zeros(0, np.float32), 0)
    image_size = (image.shape[1], image.shape[0])
    return Candidates(*decode_outputs(outputs, image_size, threshold), n_classes)
