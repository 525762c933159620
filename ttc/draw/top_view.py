"""Bird's-eye view of lidar clouds (x forward up, y left to the left) with labelled distance
marks, like the Udacity starter's ``show3DObjects``.

Points and marks are metres in the Velodyne frame; the picture is a new BGR uint8 image. The
marks are given: drawing never runs an estimator (see
:func:`ttc.evaluation.estimator_marks`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ttc.draw.raster import FONT, palette_colour, put_text, splat

#: World window of :func:`top_view`: ((x_min, x_max), (y_min, y_max)) in metres.
World = tuple[tuple[float, float], tuple[float, float]]


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
