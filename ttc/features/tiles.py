"""Full-height tiles for an object detector (``objects.tiles``, ``objects.tile_overlap``).

A far car is 13–25 px wide in a 1242-px KITTI frame; resized to a detector's input it is a few
pixels and unseen. Cutting the frame into ``N`` full-height vertical strips, each resized to the
network input on its own, enlarges every object ``N``-fold horizontally. Neighbouring strips
share ``overlap`` of a strip's width, so an object narrower than that is whole in one of them.

Pure geometry and merging (arrays in, arrays out): :func:`tile_spans` places the strips,
:func:`tiled_boxes` runs a detector on each and maps its boxes back to image pixels, and
:func:`merge_split_boxes` joins the two parts of an object a strip border cut in two (each
part touches its strip's cut edge; same class; the parts' vertical extents agree). Duplicates
of an object seen whole in two strips are left to the caller's class-agnostic NMS, and a part
seen beside the whole object to its containment rule (:mod:`ttc.features.objects`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: A box edge within this fraction of the strip's width of a cut edge touches it (pixels of
#: the strip: a detector's box of a cut object stops at, or a few pixels short of, the cut).
EDGE_FRACTION = 0.02
#: Least 1-D IoU of two parts' vertical extents (rows) for them to be one object.
MIN_VERTICAL_IOU = 0.5

Boxes = tuple[np.ndarray, np.ndarray, np.ndarray]  # x, y, w, h (K × 4 float64), class, score


def tile_spans(width: int, tiles: int, overlap: float) -> np.ndarray:
    """Column ranges of ``tiles`` full-height strips covering an image ``width`` pixels wide.

    Neighbours share ``overlap`` (0 ≤ overlap < 1) of a strip's width; every strip has the
    same width (± 1 px of rounding), the first starts at column 0 and the last ends at
    ``width``. Returns (N, 2) int64: ``x0, x1`` (pixels, ``x1`` exclusive).
    """
    if tiles < 1:
        raise ValueError(f"tiles must be >= 1, got {tiles}")
    if not 0.0 <= overlap < 1.0:
        raise ValueError(f"tile_overlap must be in [0, 1), got {overlap}")
    if width < tiles:
        raise ValueError(f"an image {width} px wide cannot be cut into {tiles} tiles")
    strip = width / (tiles - (tiles - 1) * overlap)
    starts = np.rint(np.arange(tiles) * (1.0 - overlap) * strip)
    ends = np.minimum(np.rint(starts + strip), width)
    ends[-1] = width
    return np.column_stack([starts, ends]).astype(np.int64)


def to_image(boxes: np.ndarray, span: np.ndarray, height: int) -> np.ndarray:
    """Boxes (K × 4 float64: x, y, w, h pixels of the strip ``span``) clipped to the strip
    and moved to image pixels."""
    x0, x1 = float(span[0]), float(span[1])
    corners = np.hstack([boxes[:, 0:2], boxes[:, 0:2] + boxes[:, 2:4]])
    corners = np.clip(corners, 0.0, (x1 - x0, height, x1 - x0, height))
    corners[:, [0, 2]] += x0
    return np.hstack([corners[:, 0:2], corners[:, 2:4] - corners[:, 0:2]])


def _vertical_iou(a: np.ndarray, b: np.ndarray) -> float:
    """1-D IoU of the rows two boxes (x, y, w, h) cover."""
    inter = min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1])
    union = max(a[1] + a[3], b[1] + b[3]) - min(a[1], b[1])
    return max(inter, 0.0) / union if union > 0 else 0.0


def _best_pair(
    boxes: np.ndarray, class_id: np.ndarray, left: np.ndarray, right: np.ndarray
) -> tuple[int, int] | None:
    """The pair (one of ``left``, one of ``right`` indices) of one class whose parts overlap
    or touch horizontally with the largest vertical IoU ≥ :data:`MIN_VERTICAL_IOU`."""
    best, pair = MIN_VERTICAL_IOU, None
    for i in left:
        for j in right:
            reach = boxes[i, 0] + boxes[i, 2] >= boxes[j, 0]
            if class_id[i] == class_id[j] and reach:
                iou = _vertical_iou(boxes[i], boxes[j])
                if iou >= best:
                    best, pair = iou, (int(i), int(j))
    return pair


def merge_split_boxes(
    boxes: np.ndarray,
    class_id: np.ndarray,
    confidence: np.ndarray,
    tile: np.ndarray,
    spans: np.ndarray,
) -> Boxes:
    """Join the parts of objects cut by a strip border.

    ``boxes`` (K × 4 float64: x, y, w, h image pixels), ``class_id`` (K), ``confidence`` (K)
    and ``tile`` (K: index of the strip each box was found in, into ``spans`` of
    :func:`tile_spans`). For each border, left to right: a box of the left strip whose right
    edge touches that strip's end and a box of the right strip whose left edge touches its
    start (within :data:`EDGE_FRACTION` of the strip's width), of one class, reaching each
    other and with vertical IoU ≥ :data:`MIN_VERTICAL_IOU`, become their union box with the
    higher confidence (best pairs first, each box once; the union counts as the right strip's,
    so an object cut twice is joined twice). Returns the boxes, class ids and confidences.
    """
    boxes, class_id = boxes.astype(np.float64), class_id.copy()
    confidence, tile = confidence.copy(), tile.copy()
    alive = np.ones(len(boxes), dtype=bool)
    for k in range(len(spans) - 1):
        end, start = spans[k, 1], spans[k + 1, 0]
        edge_l = EDGE_FRACTION * (spans[k, 1] - spans[k, 0])
        edge_r = EDGE_FRACTION * (spans[k + 1, 1] - spans[k + 1, 0])
        left = np.flatnonzero(alive & (tile == k) & (boxes[:, 0] + boxes[:, 2] >= end - edge_l))
        right = np.flatnonzero(alive & (tile == k + 1) & (boxes[:, 0] <= start + edge_r))
        while (pair := _best_pair(boxes, class_id, left, right)) is not None:
            i, j = pair
            lo = np.minimum(boxes[i, 0:2], boxes[j, 0:2])
            hi = np.maximum(boxes[i, 0:2] + boxes[i, 2:4], boxes[j, 0:2] + boxes[j, 2:4])
            boxes[j] = np.concatenate([lo, hi - lo])
            confidence[j] = max(confidence[i], confidence[j])
            alive[i] = False
            left, right = left[left != i], right[right != j]
    return boxes[alive], class_id[alive], confidence[alive]


def tiled_boxes(
    image: np.ndarray, spans: np.ndarray, detect: Callable[[np.ndarray], Boxes]
) -> Boxes:
    """``detect`` run on each strip of ``image`` (H × W × C) and its boxes in image pixels,
    the parts of cut objects joined (:func:`merge_split_boxes`).

    ``detect(strip)`` returns boxes (K × 4 float64: x, y, w, h pixels of the strip), class
    ids (K int32) and confidences (K float32). Returns the same for the whole image, in strip
    order (the caller's NMS and containment rule remove the duplicates).
    """
    parts: list[Boxes] = []
    tiles = []
    for k, (x0, x1) in enumerate(spans):
        found, cls, conf = detect(np.ascontiguousarray(image[:, x0:x1]))
        parts.append((to_image(np.asarray(found, np.float64).reshape(-1, 4), spans[k],
                               image.shape[0]), cls, conf))  # fmt: skip
        tiles.append(np.full(len(cls), k, dtype=np.int64))
    boxes = np.concatenate([p[0] for p in parts])
    class_id = np.concatenate([p[1] for p in parts]).astype(np.int32)
    confidence = np.concatenate([p[2] for p in parts]).astype(np.float32)
    return merge_split_boxes(boxes, class_id, confidence, np.concatenate(tiles), spans)
