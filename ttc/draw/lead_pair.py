"""A readable picture of the lead box's matches in a frame pair (FP.6 way-off frames): the
lead box region of the previous and the current frame side by side at native resolution or
enlarged, kept and removed matches in distinct colours and shapes, and the caller's numbers
in legible text above.

Arrays in, a new BGR uint8 image out (:func:`lead_match_picture`); the lead boxes come from
:mod:`ttc.evaluation.lead`.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from ttc.draw.raster import FONT, HIGHLIGHT_COLOUR, put_text
from ttc.evaluation.lead import lead_boxes
from ttc.features.keypoints import X, Y
from ttc.rows import PairDetail

#: Colours (BGR) of the picture's matches: kept green dots, removed magenta crosses (told
#: apart by shape as well as colour).
KEPT = (60, 200, 40)
REMOVED = (200, 40, 230)
#: Smallest width (pixels) of the picture; the crops are enlarged to reach it.
MIN_WIDTH = 900
#: Largest enlargement of the crops, and the width they are not enlarged beyond.
MAX_SCALE = 4.0
MAX_WIDTH = 1800
GAP = 16
PAD = 24
TEXT_SCALE = 0.6
LINE_STEP = 24


def lead_region(detail: PairDetail) -> tuple[int, int, int, int]:
    """The union of both frames' lead boxes padded by :data:`PAD` (x0, y0, x1, y1 pixels),
    clipped to the image; the whole image without a lead box."""
    prev_box, curr_box = lead_boxes(detail)
    rois = [detail.objects[f]["roi"][b] for f, b in ((detail.prev, prev_box),
                                                      (detail.curr, curr_box)) if b >= 0]  # fmt: skip
    h, w = detail.images[detail.curr].shape[:2]
    if not rois:
        return 0, 0, w, h
    r = np.asarray(rois, dtype=np.int64).reshape(-1, 4)
    x0, y0 = max(int(r[:, 0].min()) - PAD, 0), max(int(r[:, 1].min()) - PAD, 0)
    x1, y1 = (
        min(int((r[:, 0] + r[:, 2]).max()) + PAD, w),
        min(int((r[:, 1] + r[:, 3]).max()) + PAD, h),
    )
    return x0, y0, x1, y1


def crop_scale(width: int, min_width: int = MIN_WIDTH) -> float:
    """The enlargement of two crops ``width`` pixels wide side by side: enough to reach
    ``min_width``, never below 1 (native resolution), at most :data:`MAX_SCALE` and not past
    :data:`MAX_WIDTH` unless native resolution is wider."""
    scale = max(1.0, (min_width - GAP) / (2 * width))
    return float(max(1.0, min(scale, MAX_SCALE, (MAX_WIDTH - GAP) / (2 * width))))


def wrap(text: str, width: int, scale: float = TEXT_SCALE) -> list[str]:
    """``text`` broken into lines at spaces so that each fits ``width`` pixels."""
    lines: list[str] = []
    for word in text.split(" "):
        candidate = f"{lines[-1]} {word}" if lines else word
        if lines and cv2.getTextSize(candidate, FONT, scale, 1)[0][0] <= width:
            lines[-1] = candidate
        else:
            lines.append(word)
    return lines


def _markers(image: np.ndarray, points: np.ndarray, removed: bool) -> None:
    """Kept: filled dots with a dark rim; removed: crosses (in place)."""
    for u, v in np.rint(points).astype(int).tolist():
        if removed:
            cv2.drawMarker(image, (u, v), (0, 0, 0), cv2.MARKER_TILTED_CROSS, 13, 4, cv2.LINE_AA)
            cv2.drawMarker(image, (u, v), REMOVED, cv2.MARKER_TILTED_CROSS, 12, 2, cv2.LINE_AA)
        else:
            cv2.circle(image, (u, v), 5, (0, 0, 0), -1, cv2.LINE_AA)
            cv2.circle(image, (u, v), 4, KEPT, -1, cv2.LINE_AA)


def _legend(width: int) -> np.ndarray:
    """A dark band explaining the marks: kept, removed, the lead box."""
    band = np.full((34, width, 3), 24, dtype=np.uint8)
    white = (255, 255, 255)
    _markers(band, np.array([[16.0, 17.0]]), removed=False)
    x = 28 + put_text(band, "kept match (FP.3)", (28, 22), white, TEXT_SCALE, None)
    _markers(band, np.array([[x + 24.0, 17.0]]), removed=True)
    x += 38 + put_text(band, "removed as outlier", (x + 38, 22), white, TEXT_SCALE, None)
    cv2.rectangle(band, (x + 24, 9), (x + 44, 25), HIGHLIGHT_COLOUR, 2)
    put_text(band, "lead box (left: its FP.1 partner)", (x + 54, 22), white, TEXT_SCALE, None)
    return band


def _text_band(lines: Sequence[str], width: int) -> np.ndarray:
    """Dark band with ``lines`` wrapped to ``width`` in legible white text."""
    wrapped = [w for line in lines for w in wrap(line, width - 20)]
    band = np.full((12 + LINE_STEP * len(wrapped), width, 3), 24, dtype=np.uint8)
    for i, line in enumerate(wrapped):
        cv2.putText(band, line, (10, 24 + i * LINE_STEP), FONT, TEXT_SCALE, (255, 255, 255), 1,
                    cv2.LINE_AA)  # fmt: skip
    return band


def lead_match_picture(
    detail: PairDetail, lines: Sequence[str] = (), min_width: int = MIN_WIDTH
) -> np.ndarray:
    """The lead box region of the previous (left) and current (right) frame, enlarged to make
    the picture at least ``min_width`` pixels wide (never shrunk), with every FP.3 match of
    the lead box: kept ones as green dots, removed ones as magenta crosses, joined across the
    frames by thin lines; the lead boxes outlined; ``lines`` (the numbers that explain the
    frame) wrapped in a text band on top and a legend below."""
    x0, y0, x1, y1 = lead_region(detail)
    scale = crop_scale(x1 - x0, min_width)
    size = (int(round((x1 - x0) * scale)), int(round((y1 - y0) * scale)))
    panels = [cv2.resize(detail.images[f][y0:y1, x0:x1], size, interpolation=cv2.INTER_CUBIC)
              for f in (detail.prev, detail.curr)]  # fmt: skip
    body = np.full((size[1], 2 * size[0] + GAP, 3), 255, dtype=np.uint8)
    body[:, : size[0]], body[:, size[0] + GAP :] = panels
    shift = np.array([size[0] + GAP, 0.0])
    origin = np.array([x0, y0], dtype=np.float64)
    prev_box, curr_box = lead_boxes(detail)
    for offset, frame, box in ((np.zeros(2), detail.prev, prev_box),
                               (shift, detail.curr, curr_box)):  # fmt: skip
        if box >= 0:
            bx, by, bw, bh = (float(v) for v in detail.objects[frame]["roi"][box])
            a = np.rint((np.array([bx, by]) - origin) * scale + offset).astype(int)
            b = np.rint((np.array([bx + bw, by + bh]) - origin) * scale + offset).astype(int)
            cv2.rectangle(body, tuple(a.tolist()), tuple(b.tolist()), HIGHLIGHT_COLOUR, 2)
        put_text(body, f"frame {frame}" + (" (previous)" if frame == detail.prev else
                                           " (current)"), (int(offset[0]) + 6, 22),
                 scale=TEXT_SCALE)  # fmt: skip
    m = detail.matches
    ends = []
    overlay = body.copy()
    for idx, removed in ((np.asarray(detail.kept), False), (np.asarray(detail.removed), True)):
        p = (detail.keypoints[detail.prev][np.asarray(m.prev_idx)[idx]][:, [X, Y]] - origin) * scale
        c = (detail.keypoints[detail.curr][np.asarray(m.curr_idx)[idx]][:, [X, Y]] - origin) * scale
        c = c + shift
        colour = REMOVED if removed else KEPT
        for (pu, pv), (cu, cv) in zip(np.rint(p).astype(int).tolist(),
                                      np.rint(c).astype(int).tolist(), strict=True):  # fmt: skip
            cv2.line(overlay, (pu, pv), (cu, cv), colour, 1, cv2.LINE_AA)
        ends.append((p, c, removed))
    body = cv2.addWeighted(overlay, 0.5, body, 0.5, 0.0)  # lines half transparent
    for p, c, removed in ends:  # removed drawn last, on top
        _markers(body, p, removed)
        _markers(body, c, removed)
    width = body.shape[1]
    if width < min_width:  # a region wider than the image is tall: pad to the width
        body = np.hstack([body, np.full((body.shape[0], min_width - width, 3), 255, np.uint8)])
    return np.vstack([_text_band(lines, body.shape[1]), body, _legend(body.shape[1])])
