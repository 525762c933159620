"""Pictures of a frame pair's matches: keypoint matches of the lead box (kept / removed by
FP.3, with a zoomed flow panel) and the FP.1 box pairs.

The previous image is drawn above the current one (2H × W, pixels); the lead box and its FP.1
partner come from :mod:`ttc.evaluation.lead`. Arrays in, a new BGR uint8 image out.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from ttc.draw.overlays import box_labels, draw_boxes, draw_frame_boxes, ttc_lines
from ttc.draw.raster import (
    HIGHLIGHT_COLOUR,
    KEPT_COLOUR,
    REMOVED_COLOUR,
    UNMATCHED_COLOUR,
    palette_colour,
    put_lines,
    put_text,
    stack,
)
from ttc.evaluation.lead import lead_boxes, lead_row
from ttc.features.keypoints import X, Y
from ttc.rows import PairDetail


def _subsample(idx: np.ndarray, n: int) -> np.ndarray:
    """At most ``n`` evenly spaced entries of ``idx``."""
    if n >= len(idx):
        return idx
    return idx[np.unique(np.linspace(0, len(idx) - 1, max(n, 0)).round().astype(np.int64))]


def _zoom_region(rois: list[np.ndarray], shape: tuple[int, ...], pad: int = 24) -> tuple[int, ...]:
    """The union of boxes (x, y, w, h pixels) padded by ``pad`` and clipped: (x0, y0, x1, y1)."""
    r = np.asarray(rois, dtype=np.int64).reshape(-1, 4)
    h, w = shape[:2]
    x0, y0 = max(int(r[:, 0].min()) - pad, 0), max(int(r[:, 1].min()) - pad, 0)
    x1 = min(int((r[:, 0] + r[:, 2]).max()) + pad, w)
    y1 = min(int((r[:, 1] + r[:, 3]).max()) + pad, h)
    return x0, y0, x1, y1


def _draw_match_lines(
    image: np.ndarray,
    p: np.ndarray,
    c: np.ndarray,
    colour: tuple[int, int, int],
    thick: int = 1,
) -> None:
    """Lines (in place) from pixels ``p`` to ``c`` (N × 2 each) with a small circle at both ends."""
    for (pu, pv), (cu, cv) in zip(np.rint(p).astype(int), np.rint(c).astype(int), strict=True):
        cv2.line(image, (pu, pv), (cu, cv), colour, thick, cv2.LINE_AA)
        cv2.circle(image, (pu, pv), 2 + thick, colour, thick, cv2.LINE_AA)
        cv2.circle(image, (cu, cv), 2 + thick, colour, thick, cv2.LINE_AA)


def draw_keypoint_matches(
    detail: PairDetail,
    max_draw: int | None = None,
    names: Sequence[str] | None = None,
    title: str = "",
    zoom: bool = True,
) -> np.ndarray:
    """Previous image above the current one (2H × W) with the lead box's FP.3 matches as
    lines between their keypoints (kept green, removed red, drawn on top), the boxes drawn
    and the lead pair highlighted. With ``zoom``, a panel on the right (the picture is then
    2H × (W + 4 + panel width)) enlarges the lead boxes' region: the previous keypoints above,
    the current ones below with an arrow from each match's previous position (its flow).

    ``max_draw``: at most this many matches drawn (removed ones first, the rest evenly).
    """
    prev, curr, lead = detail.prev, detail.curr, detail.lead_box
    h = detail.images[prev].shape[0]
    prev_lead = lead_boxes(detail)[0]
    top = draw_frame_boxes(detail, prev, names, prev_lead)
    img = stack(top, draw_frame_boxes(detail, curr, names, lead))
    kept, removed = np.asarray(detail.kept), np.asarray(detail.removed)
    if max_draw is not None:
        removed = _subsample(removed, max_draw)
        kept = _subsample(kept, max_draw - len(removed))
    m = detail.matches
    ends = []
    for idx, colour, thick in ((kept, KEPT_COLOUR, 1), (removed, REMOVED_COLOUR, 2)):
        p = detail.keypoints[prev][np.asarray(m.prev_idx)[idx]][:, [X, Y]]
        c = detail.keypoints[curr][np.asarray(m.curr_idx)[idx]][:, [X, Y]]
        _draw_match_lines(img, p, c + (0.0, h), colour, thick)
        ends.append((p, c, colour, thick))

    if zoom and lead >= 0:
        boxes = [detail.objects[curr]["roi"][lead]]
        if prev_lead >= 0:
            boxes.append(detail.objects[prev]["roi"][prev_lead])
        x0, y0, x1, y1 = _zoom_region(boxes, detail.images[curr].shape)
        scale = min(3.0, h / (y1 - y0))
        size = (int(round((x1 - x0) * scale)), int(round((y1 - y0) * scale)))
        crops = [
            cv2.resize(panel[y0:y1, x0:x1], size, interpolation=cv2.INTER_LINEAR)
            for panel in (detail.images[prev], detail.images[curr])
        ]
        panel = np.zeros((2 * h, size[0], 3), dtype=np.uint8)
        panel[: size[1]], panel[h : h + size[1]] = crops
        panel[h - 1 : h + 1] = 255
        origin = np.array([x0, y0], dtype=np.float64)
        for frame, box, dv in ((prev, prev_lead, 0), (curr, lead, h)):
            if box >= 0:
                bx, by, bw, bh = detail.objects[frame]["roi"][box]
                a = np.rint((np.array([bx, by]) - origin) * scale).astype(int) + (0, dv)
                b = np.rint((np.array([bx + bw, by + bh]) - origin) * scale).astype(int) + (0, dv)
                cv2.rectangle(panel, tuple(a.tolist()), tuple(b.tolist()), HIGHLIGHT_COLOUR, 2)
        for p, c, colour, thick in ends:  # top: previous keypoints; bottom: flow arrows
            for (pu, pv), (cu, cv) in zip(
                np.rint((p - origin) * scale).astype(int).tolist(),
                np.rint((c - origin) * scale + (0.0, h)).astype(int).tolist(),
                strict=True,
            ):
                cv2.circle(panel, (pu, pv), 3, colour, -1, cv2.LINE_AA)
                cv2.circle(panel, (cu, cv), 3, colour, -1, cv2.LINE_AA)
                cv2.arrowedLine(panel, (pu, pv + h), (cu, cv), colour, thick, cv2.LINE_AA,
                                tipLength=0.25)  # fmt: skip
        put_text(panel, f"zoom x{scale:.1f}: keypoints in frame {prev}", (4, 16), scale=0.45)
        put_text(panel, f"frame {curr}: arrows from the previous position", (4, h + 16),
                 scale=0.45)  # fmt: skip
        img = np.hstack([img, np.full((2 * h, 4, 3), 90, np.uint8), panel])

    row = lead_row(detail)
    n_kept, n_removed = len(detail.kept), len(detail.removed)
    shown = "" if max_draw is None else f" (drawn: {len(kept)} + {len(removed)})"
    lines = ([title] if title else []) + [
        f"frame {prev} (top, box #{prev_lead}) -> {curr} (bottom, lead box #{lead}): "
        f"{n_kept + n_removed} matches in the box, {n_kept} kept (green), "
        f"{n_removed} removed (red){shown}",
        ttc_lines(row)[1],
    ]
    put_lines(img, lines)
    return img


def draw_box_matches(
    detail: PairDetail, names: Sequence[str] | None = None, title: str = ""
) -> np.ndarray:
    """Previous image above the current one (2H × W): each FP.1 box pair in its own colour in
    both frames, joined centre to centre and listed with its shared-match count; unmatched
    boxes grey; the lead pair 3 px thick."""
    prev, curr = detail.prev, detail.curr
    h = detail.images[prev].shape[0]
    bm = detail.box_matches
    rois = {f: np.asarray(detail.objects[f]["roi"]).reshape(-1, 4) for f in (prev, curr)}
    cols = {f: [UNMATCHED_COLOUR] * len(rois[f]) for f in (prev, curr)}
    thick = {f: [1] * len(rois[f]) for f in (prev, curr)}
    labels = {f: [f"#{i}" for i in range(len(rois[f]))] for f in (prev, curr)}
    names_of = {f: box_labels(detail.objects[f], names) for f in (prev, curr)}
    pairs = list(zip(np.asarray(bm.prev_box).tolist(), np.asarray(bm.curr_box).tolist(),
                     np.asarray(bm.shared).tolist(), strict=True))  # fmt: skip
    legend: list[str] = []
    for k, (p, c, n) in enumerate(pairs):
        cols[prev][p] = cols[curr][c] = palette_colour(k)
        if c == detail.lead_box:
            thick[prev][p] = thick[curr][c] = 3
        labels[prev][p] = f"#{p} -> #{c}"
        labels[curr][c] = f"#{c} <- #{p}: {n}"
        lead = "  (lead)" if c == detail.lead_box else ""
        legend.append(f"{names_of[prev][p]}  ->  {names_of[curr][c]}: {n} shared{lead}")
    top = draw_boxes(detail.images[prev], rois[prev], labels[prev], None, cols[prev], thick[prev])
    bottom = draw_boxes(detail.images[curr], rois[curr], labels[curr], None, cols[curr],
                        thick[curr])  # fmt: skip
    img = stack(top, bottom)
    for k, (p, c, _) in enumerate(pairs):
        pc = rois[prev][p, :2] + rois[prev][p, 2:] / 2
        cc = rois[curr][c, :2] + rois[curr][c, 2:] / 2 + (0, h)
        cv2.line(img, tuple(np.rint(pc).astype(int).tolist()),
                 tuple(np.rint(cc).astype(int).tolist()), palette_colour(k), 1, cv2.LINE_AA)  # fmt: skip
    n_unmatched = (len(rois[prev]) - len(pairs), len(rois[curr]) - len(pairs))
    head = ([title] if title else []) + [
        f"FP.1 box matches, frame {prev} (top) -> {curr} (bottom): {len(pairs)} pairs; "
        f"unmatched (grey): {n_unmatched[0]} previous, {n_unmatched[1]} current"
    ]
    below = put_lines(img, head)
    put_lines(img, legend, (6, below), 0.45, [(0, 0, 0)] * len(legend),
              [palette_colour(k) for k in range(len(legend))])  # fmt: skip
    return img
