"""Encoding and writing report files: markdown tables, deterministic CSVs, PNG drawings within
a byte budget, full-size WebP photographs. Every file is written atomically
(:mod:`ttc.atomic`)."""

from __future__ import annotations

import csv
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
#: Values of a float column looked at to tell whether it repeats them (then formatted once).
_SAMPLE = 4096


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
    """Deterministic CSV (atomically): fixed float format, ``\\n`` line ends, no index.

    Byte for byte ``df.to_csv(tmp, index=False, float_format=FLOAT_FORMAT,
    lineterminator="\\n")``, each column formatted at once (:func:`_csv_text`: a 600k × 20
    float frame in 4.8 s instead of 14.9 s, a 43k-row FP.6 table in 0.21 s instead of 0.38 s);
    a frame it cannot prove identical is written by pandas itself."""
    text = _csv_text(df)
    if text is None:
        return atomic_write(
            path,
            lambda tmp: df.to_csv(tmp, index=False, float_format=FLOAT_FORMAT, lineterminator="\n"),
        )
    return write_bytes_atomic(text.encode("utf-8"), path)


def _quoted_by_csv(char: str) -> bool:
    """Whether the csv writer pandas uses (QUOTE_MINIMAL, ``\\n`` line ends) quotes a field
    holding ``char``."""
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerow(["a" + char])
    return buffer.getvalue().startswith('"')


#: Characters that make the csv writer quote a field (asked once of the writer itself).
_QUOTE_CHARS = tuple(c for c in ",\"\n\r\t '" if _quoted_by_csv(c))


def _quote(cell: str) -> str:
    """``cell`` as the csv writer writes it: quoted (inner quotes doubled) when it must be."""
    if any(c in cell for c in _QUOTE_CHARS):
        return '"' + cell.replace('"', '""') + '"'
    return cell


def _float_cells(values: np.ndarray) -> list[str]:
    """Cells of a float16/32/64 column (n,): ``FLOAT_FORMAT`` of each value, ``""`` for NaN
    (pandas' float formatter applies the format to the value as a Python float). A column
    that repeats its values formats each distinct bit pattern once (-0.0 apart from 0.0)."""
    wide = np.ascontiguousarray(values, dtype=np.float64)
    sample = wide[:_SAMPLE].view(np.int64)
    if len(np.unique(sample)) * 2 > len(sample):
        return _formatted(wide)
    distinct, inverse = np.unique(wide.view(np.int64), return_inverse=True)
    return np.array(_formatted(distinct.view(np.float64)), dtype=object)[inverse].tolist()


def _formatted(values: np.ndarray) -> list[str]:
    """``FLOAT_FORMAT`` of each float64 of ``values`` (n,), ``""`` for NaN."""
    cells = [FLOAT_FORMAT % v for v in values.tolist()]
    for i in np.flatnonzero(np.isnan(values)).tolist():
        cells[i] = ""
    return cells


def _string_cells(column: pd.Series) -> list[str] | None:
    """Cells of a column of strings (str dtype, or object holding only str and missing
    values): each string quoted as needed (each distinct one once), ``""`` where missing;
    None for another column."""
    if isinstance(column.dtype, pd.StringDtype):
        pass
    elif column.dtype != object or pd.api.types.infer_dtype(column, skipna=True) not in (
        "string",
        "empty",
    ):
        return None
    values = column.to_numpy(dtype=object, copy=True)
    values[column.isna().to_numpy()] = ""
    cells = values.tolist()
    quoted = {cell: _quote(cell) for cell in set(cells)}
    return list(map(quoted.__getitem__, cells))


def _pandas_cells(column: pd.Series) -> list[str] | None:
    """Cells of any other column as pandas writes it (that column alone, read back); None
    when its text holds a carriage return (the csv reader would split the row there)."""
    text = column.to_frame().to_csv(
        index=False, header=False, float_format=FLOAT_FORMAT, lineterminator="\n"
    )
    if "\r" in text:
        return None
    rows = list(csv.reader(io.StringIO(text, newline="")))
    if len(rows) != len(column) or any(len(row) != 1 for row in rows):
        return None
    return [_quote(row[0]) for row in rows]


def _column_cells(column: pd.Series) -> list[str] | None:
    """The written cells of one column (n,), or None when not proven identical to pandas."""
    dtype = column.dtype
    if isinstance(dtype, np.dtype) and dtype.kind == "f" and dtype.itemsize <= 8:
        return _float_cells(column.to_numpy())
    if isinstance(dtype, np.dtype) and dtype.kind in "iu":
        return list(map(str, column.to_numpy().tolist()))
    if isinstance(dtype, np.dtype) and dtype.kind == "b":
        return ["True" if v else "False" for v in column.to_numpy().tolist()]
    cells = _string_cells(column)
    return cells if cells is not None else _pandas_cells(column)


def _csv_text(df: pd.DataFrame) -> str | None:
    """``df.to_csv(index=False, float_format=FLOAT_FORMAT, lineterminator="\\n")`` built
    column by column; None for a frame without columns, with MultiIndex or non-str column
    names, or with a column it cannot write identically."""
    names = df.columns
    if len(names) == 0 or isinstance(names, pd.MultiIndex):
        return None
    if not all(isinstance(name, str) for name in names):
        return None
    columns = []
    for i in range(len(names)):
        cells = _column_cells(df.iloc[:, i])
        if cells is None:
            return None
        columns.append(cells)
    rows = [[_quote(name) for name in names]]
    if len(columns) == 1:  # the csv writer quotes a row's only field when it is empty
        columns = [[cell or '""' for cell in columns[0]]]
        rows = [[cell or '""' for cell in rows[0]]]
    lines = map(",".join, zip(*columns, strict=True))
    return "\n".join([",".join(rows[0]), *lines]) + "\n"


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
