"""Encoding and writing report files: markdown tables, deterministic CSVs, PNG drawings within
a byte budget, full-size WebP photographs. Every file is written atomically
(:mod:`ttc.atomic`)."""

from __future__ import annotations

import io
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd
from PIL import Image

from ttc.atomic import atomic_write, write_bytes_atomic

FLOAT_FORMAT = "%.6g"
#: Largest PNG (bytes): pictures are downscaled until they fit.
MAX_PICTURE_BYTES = 120_000
#: Largest FP.5 top view (bytes): there is one per flagged frame.
LIDAR_PICTURE_BYTES = 60_000
#: WebP quality of an FP.6 match picture: photographs with text, 6-8x smaller than PNG at
#: full size, text and keypoint marks still sharp.
WEBP_QUALITY = 80
#: Colours of an FP.5 top view's palette PNG (lines and dots on white: 4x smaller than RGB).
TOP_VIEW_COLOURS = 32


# --------------------------------------------------------------------------- text


def _cell(value: Any) -> str:
    if isinstance(value, float | np.floating):
        if np.isnan(value):
            return ""
        if np.isinf(value):
            return "inf" if value > 0 else "-inf"
        return f"{value:.3g}" if abs(value) < 1000 else f"{value:.0f}"
    return str(value).replace("|", "\\|").replace("\n", " ")


def markdown_table(df: pd.DataFrame) -> str:
    """``df`` as a GitHub markdown table (floats with 3 significant digits)."""
    if df.empty:
        return "_(none)_"
    header = "| " + " | ".join(map(str, df.columns)) + " |"
    rule = "|" + "---|" * len(df.columns)
    cells = df.map(_cell).astype(str)
    body = (("| " + cells.agg(" | ".join, axis=1) + " |").tolist()) if len(df) else []
    return "\n".join([header, rule, *body])


def write_text(text: str, path: Path) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def write_csv(df: pd.DataFrame, path: Path) -> Path:
    """Deterministic CSV (atomically): fixed float format, ``\\n`` line ends, no index."""
    return atomic_write(
        path,
        lambda tmp: df.to_csv(tmp, index=False, float_format=FLOAT_FORMAT, lineterminator="\n"),
    )


# --------------------------------------------------------------------------- pictures


def rgb_png(image: np.ndarray) -> bytes:
    """A BGR image (H × W × 3 or H × W uint8) encoded as a PNG (OpenCV's default
    compression)."""
    ok, buffer = cv2.imencode(".png", image)
    if not ok:
        raise OSError("OpenCV could not encode the picture as PNG")
    return buffer.tobytes()


def palette_png(image: np.ndarray, colours: int = TOP_VIEW_COLOURS) -> bytes:
    """A BGR drawing encoded as a palette PNG of ``colours`` colours: plots and top views have
    few colours, so it stays sharp at a quarter of the bytes of an RGB PNG."""
    rgb = Image.fromarray(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
    buffer = io.BytesIO()
    rgb.quantize(colours, method=Image.Quantize.MEDIANCUT).save(buffer, "PNG", optimize=True)
    return buffer.getvalue()


def shrink_to_fit(
    image: np.ndarray, encode: Callable[[np.ndarray], bytes], max_bytes: int
) -> tuple[np.ndarray, bytes]:
    """``image`` downscaled in 15 % steps (not below 200 px wide) until ``encode`` of it fits
    ``max_bytes``; the image and its encoding."""
    data = encode(image)
    while len(data) > max_bytes and image.shape[1] > 200:
        image = cv2.resize(image, None, fx=0.85, fy=0.85, interpolation=cv2.INTER_AREA)
        data = encode(image)
    return image, data


def within_budget(image: np.ndarray, max_bytes: int = MAX_PICTURE_BYTES) -> np.ndarray:
    """``image`` downscaled in 15 % steps until its PNG encoding fits ``max_bytes``."""
    return shrink_to_fit(image, rgb_png, max_bytes)[0]


def save_top_view(image: np.ndarray, path: Path, max_bytes: int = LIDAR_PICTURE_BYTES) -> Path:
    """Write a drawing as a palette PNG (atomically), downscaled until it fits ``max_bytes``."""
    return write_bytes_atomic(shrink_to_fit(image, palette_png, max_bytes)[1], path)


def save_webp(image: np.ndarray, path: Path, quality: int = WEBP_QUALITY) -> Path:
    """Write ``image`` (BGR) full size as a lossy WebP of ``quality`` (atomically)."""
    ok, buffer = cv2.imencode(".webp", image, [cv2.IMWRITE_WEBP_QUALITY, quality])
    if not ok:
        raise OSError(f"{path}: OpenCV could not encode the picture as WebP")
    return write_bytes_atomic(buffer.tobytes(), path)


def save_png(image: np.ndarray, path: Path | str) -> Path:
    """Write ``image`` (H × W × 3 or H × W, uint8) to ``path`` (``.png``) atomically, full size.

    Creates missing folders. Raises ValueError for another extension or a non-image array,
    OSError when OpenCV cannot encode or the file cannot be written.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: pictures are written as PNG; the name must end in .png")
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or image.size == 0:
        raise ValueError(f"{path}: expected a non-empty uint8 image, got {image.dtype} "
                         f"{image.shape}")  # fmt: skip
    try:
        data = rgb_png(image)
    except cv2.error as exc:
        raise OSError(f"{path}: OpenCV could not encode the image as PNG: {exc}") from exc
    except OSError as exc:
        raise OSError(f"{path}: {exc}") from exc
    return write_bytes_atomic(data, path)
