"""A user's TTC file as one long table (:mod:`ttc.evaluation.external`): long CSV or
parquet, the wide FP.6 layout (a row per frame and a column per setting, or a row per
setting and a column per frame) as CSV or a markdown table, and markdown files with several
tables, each under a heading that names its detector and descriptor.

Every problem is an :class:`InputError` naming the file, the line (a parquet file: the row)
and the column; its text is the whole message the command prints.
"""

from __future__ import annotations

import csv
import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

#: Header spellings (lower case, letters, digits and '#' only; units in brackets dropped)
#: and the long table's column each names.
ALIASES: dict[str, str] = {
    "setting": "setting", "frame": "frame", "frame#": "frame", "framenumber": "frame",
    "imgfilename": "frame", "image": "frame", "prevframe": "prev_frame",
    "ttccamera": "ttc_camera", "camerattc": "ttc_camera", "ttclidar": "ttc_lidar",
    "lidarttc": "ttc_lidar", "detector": "detector", "detectortype": "detector",
    "descriptor": "descriptor", "descriptortype": "descriptor", "trackid": "track_id",
    "boxx": "box_x", "boxy": "box_y", "boxw": "box_w", "boxh": "box_h",
}  # fmt: skip
#: Optional numeric columns of a long table, read and checked (the lead's box, track id).
OPTIONAL_NUMBERS = ("prev_frame", "box_x", "box_y", "box_w", "box_h", "track_id")
#: Cell texts that are an invalid estimate (lower case; a blank cell too).
INVALID_TEXTS = {"", "nan", "inf", "+inf", "-inf", "infinity", "-infinity", "+infinity"}
MARKDOWN_SUFFIXES = (".md", ".markdown")
_RULE = re.compile(r"^\s*\|?\s*:?-{3,}:?\s*(\|\s*:?-{3,}:?\s*)*\|?\s*$")
_FRAME = re.compile(r"^\s*(?:frame\s*)?0*(\d+)(?:\.(?:png|jpg|bin))?\s*$", re.IGNORECASE)
_DETECTOR = re.compile(r"detector\s*[=:]\s*([\w.+-]+)", re.IGNORECASE)
_DESCRIPTOR = re.compile(r"descriptor\s*[=:]\s*([\w.+-]+)", re.IGNORECASE)
_IN_PARENS = re.compile(r"\((?:\s*\d+\s*:)?\s*([^()]+?)\s*\)\s*$")


class InputError(Exception):
    """A file that cannot be read as TTC numbers: ``FILE:LINE: column 'C': what is wrong``."""

    def __init__(self, path: Path, line: int, column: str, message: str, unit: str = "line"):
        where = f"{path}" + (f", {unit} {line}" if line else "")
        where += f", column {column!r}" if column else ""
        super().__init__(f"{where}: {message}")


@dataclass
class Grid:
    """A table of text cells: its header, rows, each row's line (1-based) in the file, the
    heading above it (markdown) and the header's line."""

    header: list[str]
    rows: list[list[str]]
    lines: list[int]
    heading: str = ""
    header_line: int = 1


def norm(header: str) -> str:
    """A header's key in :data:`ALIASES`: lower case, units dropped (``[s]``, ``(s)``,
    ``(sec)``), letters, digits and '#' kept."""
    unitless = re.sub(r"\[[^]]*\]|\((?:s|sec|secs|seconds)\)", "", header.lower())
    return re.sub(r"[^a-z0-9#]", "", unitless)


def frame_number(text: str) -> int | None:
    """The frame number a cell or header names (``12``, ``0012.png``, ``frame 12``), else
    None."""
    found = _FRAME.match(text)
    return int(found.group(1)) if found else None


def ttc_value(text: str) -> float | None:
    """A TTC cell's seconds: NaN or ±inf for an invalid estimate (:data:`INVALID_TEXTS`),
    None where the text is no number."""
    t = text.strip().lower()
    if t in INVALID_TEXTS:
        return float(t.replace("infinity", "inf")) if t else np.nan
    try:
        return float(t)
    except ValueError:
        return None


def setting_of_heading(heading: str) -> str:
    """The setting a heading names: ``detector/descriptor`` when it says ``Detector = X`` and
    ``Descriptor = Y``, else its text (lower case)."""
    det, desc = _DETECTOR.search(heading), _DESCRIPTOR.search(heading)
    if det and desc:
        return f"{det.group(1)}/{desc.group(1)}".lower()
    return heading.strip("# ").strip().lower()


def setting_of_column(header: str) -> str:
    """The setting a wide column names: the text in its closing parentheses
    (``ttcCamera [s] (1: SHITOMASI/BRISK)``: ``shitomasi/brisk``), else the header."""
    found = _IN_PARENS.search(header)
    return (found.group(1) if found else header).strip().lower()


# --------------------------------------------------------------------------- files to grids


def _split_row(line: str) -> list[str]:
    """The cells of a markdown table row (outer pipes dropped, ``\\|`` kept)."""
    cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip())]
    if line.strip().startswith("|"):
        cells = cells[1:]
    if line.strip().endswith("|") and not line.strip().endswith("\\|"):
        cells = cells[:-1]
    return cells


def markdown_grids(text: str) -> list[Grid]:
    """Every table of a markdown text (a header row, a rule row, rows), each with the last
    heading above it."""
    lines, grids, heading, i = text.splitlines(), [], "", 0
    while i < len(lines):
        line = lines[i]
        if line.lstrip().startswith("#"):
            heading = line.strip()
        elif "|" in line and i + 1 < len(lines) and _RULE.match(lines[i + 1]):
            grid = Grid(_split_row(line), [], [], heading, i + 1)
            i += 2
            while i < len(lines) and "|" in lines[i] and lines[i].strip():
                grid.rows.append(_split_row(lines[i]))
                grid.lines.append(i + 1)
                i += 1
            grids.append(grid)
            continue
        i += 1
    return grids


def csv_grid(text: str) -> Grid:
    """A CSV text as one grid (blank lines skipped; the first non-blank line the header)."""
    numbered = [(n, row) for n, row in enumerate(csv.reader(io.StringIO(text)), start=1)
                if any(c.strip() for c in row)]  # fmt: skip
    header_line, header = numbered[0]
    rows = [[c.strip() for c in row] for _, row in numbered[1:]]
    return Grid([h.strip() for h in header], rows, [n for n, _ in numbered[1:]], "", header_line)


def parquet_grid(path: Path) -> Grid:
    """A parquet file as one grid of text cells (row ``k`` on "line" ``k + 1``)."""
    table = pd.read_parquet(path)
    cells = table.astype(object).where(table.notna(), "").astype(str)
    rows = cells.to_numpy().tolist()
    return Grid([str(c) for c in table.columns], rows, list(range(1, len(rows) + 1)), "", 0)


def file_grids(path: Path) -> tuple[list[Grid], str]:
    """The grids of a file and the word for its positions ("line", "row" for parquet);
    an empty or binary file, or one without a table, is an :class:`InputError`."""
    data = path.read_bytes()
    if not data.strip():
        raise InputError(path, 0, "", "the file is empty")
    if data[:4] == b"PAR1":
        return [parquet_grid(path)], "row"
    if b"\x00" in data[:8192]:
        raise InputError(path, 0, "", "not a text file (binary content); expected CSV, "
                         "markdown or parquet")  # fmt: skip
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(path, 0, "", f"not a UTF-8 text file (byte {exc.start}); expected "
                         "CSV, markdown or parquet") from None  # fmt: skip
    grids = markdown_grids(text)
    if path.suffix.lower() in MARKDOWN_SUFFIXES or (grids and "," not in text.splitlines()[0]):
        if not grids:
            raise InputError(path, 0, "", "no markdown table (a header row, then |---|)")
        return grids, "line"
    return [csv_grid(text)], "line"
