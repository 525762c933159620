"""Overlays on a camera image: object boxes with labels, projected lidar points coloured by
distance, and the lead vehicle's TTC panel.

Arrays in, a new BGR uint8 image out. Image coordinates are pixels (u right, v down); lidar
distances are metres (Velodyne x, forward). The lead box and its row come from
:mod:`ttc.evaluation.lead`: drawing never decides which box is the lead.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np
import pandas as pd

from ttc.draw.raster import (
    BOX_COLOUR,
    FONT,
    HIGHLIGHT_COLOUR,
    distance_colours,
    draw_distance_legend,
    put_lines,
    put_text,
    splat,
)
from ttc.evaluation.lead import lead_row
from ttc.rows import PairDetail


def box_labels(objects: dict[str, np.ndarray], names: Sequence[str] | None = None) -> list[str]:
    """``"#i name 0.95"`` for every box of an objects dict (class_id, confidence, roi)."""
    names = names or ()
    labels = []
    for i, (cid, conf) in enumerate(
        zip(objects["class_id"].tolist(), objects["confidence"].tolist(), strict=True)
    ):
        name = names[cid] if 0 <= cid < len(names) else f"class {cid}"
        labels.append(f"#{i} {name} {conf:.2f}")
    return labels


LABEL_SCALE = 0.45


def _label_rect(text: str, org: tuple[int, int], shape: tuple[int, ...]) -> tuple[int, ...]:
    """The rectangle (x0, y0, x1, y1 pixels) :func:`put_text` fills for ``text`` at ``org``."""
    (tw, th), base = cv2.getTextSize(text, FONT, LABEL_SCALE, 1)
    h, w = shape[:2]
    x = int(min(max(org[0], 0), max(w - tw - 2, 0)))
    y = int(min(max(org[1], th + 2), h - base - 1))
    return (x - 2, y - th - 3, x + tw + 2, y + base + 1)


def _overlaps(a: tuple[int, ...], b: tuple[int, ...]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _label_spot(
    text: str, roi: Sequence[int], shape: tuple[int, ...], taken: list[tuple[int, ...]]
) -> tuple[tuple[int, int], tuple[int, ...]]:
    """Where a box's label goes: above its top-left corner, else below the box, stacked
    higher up, or inside, whichever first overlaps no label in ``taken``; returns (org,
    rectangle)."""
    x, y, w, h = (int(v) for v in roi)
    th = cv2.getTextSize(text, FONT, LABEL_SCALE, 1)[0][1]
    step = th + 7
    spots = [(x, y - 4), (x, y + h + th + 4)]
    spots += [(x, y - 4 - k * step) for k in range(1, 6)] + [(x + 2, y + th + 4)]
    rects = [_label_rect(text, org, shape) for org in spots]
    for org, rect in zip(spots, rects, strict=True):
        if not any(_overlaps(rect, t) for t in taken):
            return org, rect
    return spots[0], rects[0]


def draw_boxes(
    image: np.ndarray,
    rois: np.ndarray,
    labels: list[str],
    highlight: int | None = None,
    colours: Sequence[tuple[int, int, int]] | None = None,
    thickness: Sequence[int] | None = None,
) -> np.ndarray:
    """A copy of ``image`` with boxes (M × 4: x, y, w, h pixels) and their labels.

    The box ``highlight`` is yellow and 3 px thick; ``colours`` (M BGR) and ``thickness``
    (M pixels) override the others' light blue, 1 px. Labels sit on the box's colour above
    its corner and move (with a leader line) where they would cover another label.
    """
    out = image.copy()
    rois = np.asarray(rois).reshape(-1, 4)
    if len(labels) != len(rois):
        raise ValueError(f"{len(rois)} boxes but {len(labels)} labels")
    n = len(rois)
    col = [BOX_COLOUR] * n if colours is None else [tuple(int(c) for c in k) for k in colours]
    thick = [1] * n if thickness is None else [int(t) for t in thickness]
    if highlight is not None and 0 <= highlight < n:
        col[highlight], thick[highlight] = HIGHLIGHT_COLOUR, 3
    order = sorted(range(n), key=lambda i: (i != highlight, -thick[i], i))
    for i in reversed(order):  # the highlighted box last, on top
        x, y, w, h = (int(v) for v in rois[i])
        cv2.rectangle(out, (x, y), (x + w - 1, y + h - 1), col[i], thick[i])
    taken: list[tuple[int, ...]] = []
    for i in order:  # the highlighted label first: it gets the best spot
        if not labels[i]:
            continue
        org, rect = _label_spot(labels[i], rois[i], out.shape, taken)
        if rect[3] < int(rois[i][1]) - 12:  # moved up: a leader line to the box corner
            cv2.line(out, (rect[0] + 2, rect[3]), (int(rois[i][0]), int(rois[i][1])), col[i], 1)
        put_text(out, labels[i], org, (0, 0, 0), LABEL_SCALE, col[i])
        taken.append(rect)
    return out


def draw_frame_boxes(
    detail: PairDetail, frame: int, names: Sequence[str] | None, highlight: int
) -> np.ndarray:
    """The image of ``frame`` of a pair detail with its boxes and labels, box ``highlight``
    (−1: none) highlighted (:func:`draw_boxes`)."""
    objects = detail.objects[frame]
    return draw_boxes(detail.images[frame], objects["roi"], box_labels(objects, names),
                      highlight if highlight >= 0 else None)  # fmt: skip


def draw_lidar_on_image(
    image: np.ndarray,
    uv: np.ndarray,
    x_m: np.ndarray,
    max_x: float = 20.0,
    min_x: float = 0.0,
    radius: int = 2,
) -> np.ndarray:
    """A copy of ``image`` with projected lidar points (N × 2 pixels) coloured by their
    distance ``x_m`` (metres): ``min_x`` red → ``max_x`` green; nearer points on top."""
    x_m = np.asarray(x_m, dtype=np.float64).reshape(-1)
    if len(x_m) != len(np.asarray(uv).reshape(-1, 2)):
        raise ValueError("uv and x_m must have one row per point")
    return splat(image, uv, distance_colours(x_m, max_x, min_x), radius, depth=x_m)


# --------------------------------------------------------------------------- lead TTC


def format_ttc(value: float, reason: str) -> str:
    """A TTC (seconds) for a picture: ``"11.98 s"``, ``"inf (receding)"``, ``"n/a (...)"``."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return f"n/a ({reason or 'no value'})"
    if math.isinf(value):
        return f"{'+' if value > 0 else '-'}inf ({reason})"
    suffix = "" if reason in ("", "ok") else f" ({reason})"
    return f"{value:.2f} s{suffix}"


def ttc_lines(row: pd.Series) -> list[str]:
    """The lidar and the camera TTC line of a result row (seconds, metres, counts)."""
    lidar = (
        f"TTC lidar  {format_ttc(float(row['ttc_lidar']), str(row['lidar_reason']))}"
        f"   d {row['d_prev']:.2f} -> {row['d_curr']:.2f} m, "
        f"{int(row['lidar_points_curr'])} pts ({int(row['lidar_outliers_curr'])} outliers)"
    )
    camera = (
        f"TTC camera {format_ttc(float(row['ttc_camera']), str(row['camera_reason']))}"
        f"   ratio {row['camera_ratio']:.4f}, {int(row['matches_kept'])}/"
        f"{int(row['matches_in_box'])} matches kept, {int(row['camera_pairs'])} pairs"
    )
    return [lidar, camera]


def draw_lead_ttc(
    detail: PairDetail, names: Sequence[str] | None = None, title: str = ""
) -> np.ndarray:
    """The current image with the lead box, its lidar points coloured by distance (the box's
    own range, legend bottom right) and the lidar / camera TTC of the lead row as text.

    ``names``: class names for the box labels; ``title``: an extra first line (the setting).
    """
    curr, lead = detail.curr, detail.lead_box
    row = lead_row(detail)
    img = draw_frame_boxes(detail, curr, names, lead)
    lines = ([title] if title else []) + [f"frame {detail.prev} -> {curr}"]
    if lead >= 0:
        mine = detail.lane_owner[curr] == lead
        x = detail.lane_points[curr][mine, 0]
        if len(x):  # colour range: the box's own depth (closest to its 95th percentile)
            lo = math.floor(float(x.min()) * 10) / 10
            hi = max(lo + 0.5, math.ceil(float(np.quantile(x, 0.95)) * 10) / 10)
            img = draw_lidar_on_image(img, detail.lane_uv[curr][mine], x, hi, lo, radius=2)
            img = draw_distance_legend(img, lo, hi)
        lines[-1] += f", lead box #{lead}, {len(x)} lidar points in it"
    else:
        lines[-1] += ": no lead box (no box holds lane lidar points)"
    put_lines(img, lines + ttc_lines(row))
    return img
