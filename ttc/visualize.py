"""Pictures of the pipeline: boxes, lidar overlays, a bird's-eye view, keypoint and box matches.

Every drawing function is pure: arrays in, a new BGR uint8 image out (inputs are never
modified). Image coordinates are pixels (u right, v down); lidar coordinates are metres in the
Velodyne frame (x forward, y left). Points are rasterised with numpy (one vectorised splat per
picture, nearest point on top), boxes, lines and text with OpenCV calls over at most a few
hundred items. :func:`save_png` writes a picture atomically; nothing is ever shown in a window.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd

from ttc.atomic import write_bytes_atomic
from ttc.keypoints import X, Y
from ttc.lidar_ttc import LIDAR_ESTIMATORS, LidarTTCParams, rear_distance

FONT = cv2.FONT_HERSHEY_SIMPLEX
BOX_COLOUR = (230, 170, 40)  # BGR: light blue, ordinary boxes
HIGHLIGHT_COLOUR = (0, 230, 255)  # BGR: yellow, the lead box
UNMATCHED_COLOUR = (150, 150, 150)  # BGR: grey
KEPT_COLOUR = (40, 220, 40)  # BGR: green
REMOVED_COLOUR = (40, 40, 240)  # BGR: red
#: Distinct BGR colours (tab10 without grey) for box pairs, clouds and estimator marks.
PALETTE: tuple[tuple[int, int, int], ...] = (
    (180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214), (189, 103, 148),
    (75, 86, 140), (194, 119, 227), (34, 189, 188), (207, 190, 23),
)  # fmt: skip

#: World window of :func:`top_view`: ((x_min, x_max), (y_min, y_max)) in metres.
World = tuple[tuple[float, float], tuple[float, float]]


# --------------------------------------------------------------------------- primitives


def palette_colour(i: int) -> tuple[int, int, int]:
    """The ``i``-th palette colour (BGR), cycling."""
    return PALETTE[i % len(PALETTE)]


def distance_colours(x_m: np.ndarray, max_x: float = 20.0, min_x: float = 0.0) -> np.ndarray:
    """BGR colours (N × 3 uint8) for distances in metres: ``min_x`` red → ``max_x`` green.

    The Udacity starter's scale (red = 255·(max − x)/max, green = the rest), clipped to the range.
    """
    if not max_x > min_x:
        raise ValueError(f"need max_x > min_x, got {min_x}, {max_x}")
    t = np.clip((np.asarray(x_m, dtype=np.float64) - min_x) / (max_x - min_x), 0.0, 1.0)
    t = np.nan_to_num(t, nan=1.0)
    out = np.zeros((len(t), 3), dtype=np.uint8)
    out[:, 1] = np.rint(255.0 * t)
    out[:, 2] = np.rint(255.0 * (1.0 - t))
    return out


def _disc_offsets(radius: int) -> np.ndarray:
    """Integer (dv, du) offsets (K × 2) of a filled disc of ``radius`` pixels."""
    r = max(int(radius), 0)
    dv, du = np.mgrid[-r : r + 1, -r : r + 1]
    inside = dv**2 + du**2 <= r * r + r  # a little rounder than the strict circle
    return np.column_stack([dv[inside], du[inside]])


def splat(
    image: np.ndarray,
    uv: np.ndarray,
    colours: np.ndarray,
    radius: int = 2,
    depth: np.ndarray | None = None,
) -> np.ndarray:
    """A copy of ``image`` with a filled disc per point (pixels, N × 2: u, v).

    ``colours``: N × 3 BGR (or one colour). Where discs overlap, the point with the smallest
    ``depth`` wins (default: the later point). NaN and off-image pixels are skipped.
    """
    out = image.copy()
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    n = len(uv)
    cols = np.broadcast_to(np.asarray(colours, dtype=np.uint8).reshape(-1, 3), (n, 3))
    keys = -np.arange(n, dtype=np.float64) if depth is None else np.asarray(depth, np.float64)
    ok = np.isfinite(uv).all(axis=1)
    if not ok.any():
        return out
    centre = np.rint(uv[ok]).astype(np.int64)
    offsets = _disc_offsets(radius)
    v = (centre[:, 1:2] + offsets[None, :, 0]).ravel()
    u = (centre[:, 0:1] + offsets[None, :, 1]).ravel()
    point = np.repeat(np.flatnonzero(ok), len(offsets))
    h, w = out.shape[:2]
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    pixel, point = v[inside] * w + u[inside], point[inside]
    order = np.lexsort((keys[point], pixel))  # by pixel, then nearest first
    first = np.unique(pixel[order], return_index=True)[1]
    winner = order[first]
    out.reshape(-1, out.shape[2])[pixel[winner]] = cols[point[winner]]
    return out


def put_text(
    image: np.ndarray,
    text: str,
    org: tuple[int, int],
    colour: tuple[int, int, int] = (255, 255, 255),
    scale: float = 0.5,
    background: tuple[int, int, int] | None = (0, 0, 0),
    thickness: int = 1,
) -> int:
    """Draw ``text`` in place with its baseline-left corner at ``org`` (pixels) on a filled
    background; return the text's width in pixels. The box is kept inside the image."""
    (tw, th), base = cv2.getTextSize(text, FONT, scale, thickness)
    h, w = image.shape[:2]
    x = int(min(max(org[0], 0), max(w - tw - 2, 0)))
    y = int(min(max(org[1], th + 2), h - base - 1))
    if background is not None:
        cv2.rectangle(image, (x - 2, y - th - 3), (x + tw + 2, y + base + 1), background, -1)
    cv2.putText(image, text, (x, y), FONT, scale, colour, thickness, cv2.LINE_AA)
    return tw


def put_lines(
    image: np.ndarray,
    lines: Sequence[str],
    org: tuple[int, int] = (6, 18),
    scale: float = 0.5,
    colours: Sequence[tuple[int, int, int]] | None = None,
    backgrounds: Sequence[tuple[int, int, int]] | None = None,
) -> int:
    """Draw a block of text lines in place, top-left at ``org`` (pixels): white on a dark band
    unless ``colours`` / ``backgrounds`` (one BGR per line) say otherwise. Returns the row
    (pixels) below the block."""
    step = int(round(22 * scale / 0.5))
    for i, line in enumerate(lines):
        colour = (255, 255, 255) if colours is None else colours[i]
        background = (20, 20, 20) if backgrounds is None else backgrounds[i]
        put_text(image, line, (org[0], org[1] + i * step), colour, scale, background)
    return org[1] + len(lines) * step


def draw_distance_legend(
    image: np.ndarray,
    min_x: float,
    max_x: float,
    org: tuple[int, int] | None = None,
    length: int = 160,
) -> np.ndarray:
    """A copy of ``image`` with a horizontal colour bar of :func:`distance_colours` and its
    range in metres; ``org`` is the bar's top-left pixel (default: bottom-right corner)."""
    out = image.copy()
    h, w = out.shape[:2]
    length = min(length, w - 20)
    x0, y0 = org if org is not None else (w - length - 12, h - 24)
    bar = distance_colours(np.linspace(min_x, max_x, length), max_x, min_x)
    out[y0 : y0 + 8, x0 : x0 + length] = bar[None, :, :]
    cv2.rectangle(out, (x0 - 1, y0 - 1), (x0 + length, y0 + 8), (255, 255, 255), 1)
    put_text(out, f"{min_x:.1f} m", (x0, y0 + 21), scale=0.4, background=(20, 20, 20))
    label = f"{max_x:.1f} m"
    tw = cv2.getTextSize(label, FONT, 0.4, 1)[0][0]
    put_text(out, label, (x0 + length - tw, y0 + 21), scale=0.4, background=(20, 20, 20))
    return out


# --------------------------------------------------------------------------- boxes and lidar


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


# --------------------------------------------------------------------------- bird's-eye view


def world_to_pixel(
    x_m: np.ndarray, y_m: np.ndarray, world: World, size: tuple[int, int]
) -> np.ndarray:
    """Top-view pixels (N × 2: column, row; float) of points (metres, x forward, y left).

    ``world`` = ((x_min, x_max), (y_min, y_max)) fills ``size`` = (width, height) pixels:
    x_max at row 0, x_min at row ``height``; y_max (left) at column 0. The two axes may have
    different scales (pixels per metre).
    """
    (x0, x1), (y0, y1) = world
    width, height = size
    col = (y1 - np.asarray(y_m, dtype=np.float64)) / (y1 - y0) * width
    row = (x1 - np.asarray(x_m, dtype=np.float64)) / (x1 - x0) * height
    return np.column_stack([col, row])


def _grid_values(lo: float, hi: float, step: float) -> np.ndarray:
    """Multiples of ``step`` in [lo, hi]."""
    return np.arange(math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9) + 1) * step


def _metres(value: float) -> str:
    """``"8 m"``, ``"7.5 m"``, ``"7.25 m"``: a grid value without trailing zeros."""
    return f"{round(value, 3):g} m"


def _spread(rows: list[float], gap: float, lo: float, hi: float) -> list[float]:
    """Label rows (pixels, sorted ascending) pushed apart to at least ``gap``, inside [lo, hi]."""
    out: list[float] = []
    for r in rows:
        out.append(max(r, lo) if not out else max(r, out[-1] + gap))
    overflow = out[-1] - hi if out else 0.0
    return [r - overflow for r in out] if overflow > 0 else out


def _xy(points: np.ndarray) -> np.ndarray:
    """The x, y columns (N × 2 float64, metres) of an (N × ≥2) array; empty → (0, 2)."""
    arr = np.asarray(points, dtype=np.float64)
    return np.empty((0, 2)) if arr.size == 0 else arr.reshape(len(arr), -1)[:, :2]


def cloud_summary(points: np.ndarray) -> str:
    """``"x_min 7.55 m, w 1.62 m, 315 pts"`` of a cloud (N × ≥2, metres)."""
    if len(points) == 0:
        return "no points"
    x, y = points[:, 0], points[:, 1]
    return f"x_min {x.min():.2f} m, w {np.ptp(y):.2f} m, {len(points)} pts"


def top_view(
    clouds: list[tuple[str, np.ndarray]],
    marks: dict[str, float] | None = None,
    world: World = ((0.0, 20.0), (-3.0, 3.0)),
    size: tuple[int, int] = (500, 1000),
    grid: float = 2.0,
    radius: int = 2,
    title: str = "",
    lateral_grid: float | None = None,
) -> np.ndarray:
    """Bird's-eye view (height × width × 3 BGR) of lidar clouds, like the starter's
    ``show3DObjects``: x (forward) up, y (left) to the left, see :func:`world_to_pixel`.

    ``clouds``: (label, N × ≥3 points in metres); each gets a palette colour and a legend line
    with its closest x, width (y extent) and point count. ``marks``: name → distance x
    (metres), drawn as labelled horizontal lines (NaN marks are listed, not drawn). Grid lines
    every ``grid`` metres of x and every ``lateral_grid`` (default ``grid``) metres of y.
    """
    width, height = size
    (x0, x1), (y0, y1) = world
    lateral_grid = grid if lateral_grid is None else lateral_grid
    if not (x1 > x0 and y1 > y0 and width > 0 and height > 0 and grid > 0 and lateral_grid > 0):
        raise ValueError(f"empty top view: world={world}, size={size}, grid={grid}")
    img = np.full((height, width, 3), 255, dtype=np.uint8)

    # metre grid: distance lines (rows) and lateral lines (columns)
    for xv in _grid_values(x0, x1, grid):
        row = int(round(world_to_pixel(xv, 0.0, world, size)[0, 1]))
        cv2.line(img, (0, row), (width - 1, row), (205, 205, 205), 1)
        if 12 < row < height - 20:
            put_text(img, _metres(xv), (3, row - 3), (110, 110, 110), 0.4, None)
    for yv in _grid_values(y0, y1, lateral_grid):
        col = int(round(world_to_pixel(x0, yv, world, size)[0, 0]))
        cv2.line(img, (col, 0), (col, height - 1), (225, 225, 225), 1)
        if 40 < col < width - 50:
            put_text(img, f"y {_metres(yv)}", (col + 3, height - 6), (110, 110, 110), 0.4, None)

    # points, one colour per cloud (a single splat: nearest x on top)
    xy = [_xy(p) for _, p in clouds]
    if clouds:
        allp = np.vstack(xy)
        cols = np.vstack([np.tile(palette_colour(i), (len(p), 1)) for i, p in enumerate(xy)])
        img = splat(img, world_to_pixel(allp[:, 0], allp[:, 1], world, size),
                    cols.astype(np.uint8), radius, depth=allp[:, 0])  # fmt: skip

    # estimator marks: one coloured line each, labels spread apart on the right
    legend: list[tuple[str, tuple[int, int, int]]] = []
    if marks:
        drawn = [(n, d) for n, d in marks.items() if np.isfinite(d) and x0 <= d <= x1]
        drawn.sort(key=lambda nd: -nd[1])
        rows = [float(world_to_pixel(d, 0.0, world, size)[0, 1]) for _, d in drawn]
        label_rows = _spread(rows, 15.0, 14.0, height - 20.0)
        for k, ((name, d), row, lrow) in enumerate(zip(drawn, rows, label_rows, strict=True)):
            colour = palette_colour(len(clouds) + k + 1)
            r = int(round(row))
            cv2.line(img, (0, r), (width - 1, r), colour, 1)
            text = f"{name} {d:.2f} m"
            tw = cv2.getTextSize(text, FONT, 0.42, 1)[0][0]
            lx = width - tw - 50
            cv2.line(img, (lx - 12, r), (lx - 3, int(round(lrow)) - 4), colour, 1, cv2.LINE_AA)
            put_text(img, text, (lx, int(round(lrow))), colour, 0.42, (255, 255, 255))
        legend += [(f"{n}: n/a", (90, 90, 90)) for n, d in marks.items() if not np.isfinite(d)]

    # legend: title, then one line per cloud in its colour
    lines = ([title] if title else []) + [
        f"{label}: {cloud_summary(p)}" for (label, _), p in zip(clouds, xy, strict=True)
    ]
    colours = ([(0, 0, 0)] if title else []) + [palette_colour(i) for i in range(len(clouds))]
    lines += [t for t, _ in legend]
    colours += [c for _, c in legend]
    for i, (line, colour) in enumerate(zip(lines, colours, strict=True)):
        put_text(img, line, (6, 16 + 17 * i), colour, 0.45, (255, 255, 255))
    return img


def estimator_marks(points: np.ndarray, params: LidarTTCParams | None = None) -> dict[str, float]:
    """The distance (metres, NaN if none) every estimator of
    :data:`~ttc.lidar_ttc.LIDAR_ESTIMATORS` picks on one box's points (N × ≥3, metres),
    with the parameters of ``params`` (default :class:`LidarTTCParams`)."""
    params = params or LidarTTCParams()
    return {
        name: rear_distance(points, dataclasses.replace(params, name=name)).distance
        for name in LIDAR_ESTIMATORS
    }


# --------------------------------------------------------------------------- frame pairs


def format_ttc(value: float, reason: str) -> str:
    """A TTC (seconds) for a picture: ``"11.98 s"``, ``"inf (receding)"``, ``"n/a (...)"``."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return f"n/a ({reason or 'no value'})"
    if math.isinf(value):
        return f"{'+' if value > 0 else '-'}inf ({reason})"
    suffix = "" if reason in ("", "ok") else f" ({reason})"
    return f"{value:.2f} s{suffix}"


def lead_row(detail: Any) -> pd.Series:
    """The lead box's row of a :class:`~ttc.pipeline.PairDetail` (first row if none is)."""
    rows = detail.rows
    lead = rows[rows["is_lead"]]
    return lead.iloc[0] if len(lead) else rows.iloc[0]


def matched_prev_box(detail: Any, curr_box: int) -> int:
    """The previous-frame box matched to ``curr_box`` by FP.1, or −1."""
    bm = detail.box_matches
    hit = np.flatnonzero(np.asarray(bm.curr_box) == curr_box)
    return int(np.asarray(bm.prev_box)[hit[0]]) if len(hit) else -1


def _labels(detail: Any, frame: int, names: Sequence[str] | None) -> list[str]:
    return box_labels(detail.objects[frame], names)


def _ttc_lines(row: pd.Series) -> list[str]:
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


def draw_lead_ttc(detail: Any, names: Sequence[str] | None = None, title: str = "") -> np.ndarray:
    """The current image with the lead box, its lidar points coloured by distance (the box's
    own range, legend bottom right) and the lidar / camera TTC of the lead row as text.

    ``names``: class names for the box labels; ``title``: an extra first line (the setting).
    """
    curr, lead = detail.curr, detail.lead_box
    row = lead_row(detail)
    img = draw_boxes(detail.images[curr], detail.objects[curr]["roi"],
                     _labels(detail, curr, names), lead if lead >= 0 else None)  # fmt: skip
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
    put_lines(img, lines + _ttc_lines(row))
    return img


def stack(top: np.ndarray, bottom: np.ndarray) -> np.ndarray:
    """Two equally wide images one above the other, with a white 2 px seam at the join."""
    out = np.vstack([top, bottom])
    h = top.shape[0]
    out[h - 1 : h + 1] = 255
    return out


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
    detail: Any,
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
    prev_lead = matched_prev_box(detail, lead) if lead >= 0 else -1
    top = draw_boxes(detail.images[prev], detail.objects[prev]["roi"],
                     _labels(detail, prev, names), prev_lead if prev_lead >= 0 else None)  # fmt: skip
    bottom = draw_boxes(detail.images[curr], detail.objects[curr]["roi"],
                        _labels(detail, curr, names), lead if lead >= 0 else None)  # fmt: skip
    img = stack(top, bottom)
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
        _ttc_lines(row)[1],
    ]
    put_lines(img, lines)
    return img


def draw_box_matches(
    detail: Any, names: Sequence[str] | None = None, title: str = ""
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
    names_of = {f: _labels(detail, f, names) for f in (prev, curr)}
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


# --------------------------------------------------------------------------- files


def save_png(image: np.ndarray, path: Path | str) -> Path:
    """Write ``image`` (H × W × 3 or H × W, uint8) to ``path`` (``.png``) atomically.

    Creates missing folders, encodes in memory, writes a temporary file beside the target and
    renames it, so a reader never sees half a picture. Raises ValueError for another extension
    or a non-image array, OSError when OpenCV cannot encode or the file cannot be written.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: pictures are written as PNG; the name must end in .png")
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or image.size == 0:
        raise ValueError(f"{path}: expected a non-empty uint8 image, got {image.dtype} "
                         f"{image.shape}")  # fmt: skip
    try:
        ok, buf = cv2.imencode(".png", image)
    except cv2.error as exc:
        raise OSError(f"{path}: OpenCV could not encode the image as PNG: {exc}") from exc
    if not ok:
        raise OSError(f"{path}: OpenCV could not encode the image as PNG")
    return write_bytes_atomic(buf.tobytes(), path)
