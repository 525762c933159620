"""Raster primitives of the pictures: colours, point splats, text, legends, stacking.

Every function returns a new BGR uint8 image (inputs are never modified) except the ``put_*``
text calls, which draw in place on an image the caller owns. Pixels: u right, v down. Points
are rasterised with numpy (one vectorised splat per picture, nearest point on top), text with
OpenCV.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

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


def stack(top: np.ndarray, bottom: np.ndarray) -> np.ndarray:
    """Two equally wide images one above the other, with a white 2 px seam at the join."""
    out = np.vstack([top, bottom])
    h = top.shape[0]
    out[h - 1 : h + 1] = 255
    return out


def text_band(lines: list[str], width: int, scale: float = 0.45) -> np.ndarray:
    """A dark band (uint8 BGR, (10 + 20 · len(lines)) × ``width`` pixels) holding ``lines``."""
    band = np.full((10 + 20 * len(lines), width, 3), 20, dtype=np.uint8)
    put_lines(band, lines, (6, 18), scale)
    return band
