"""The layouts a grid of text cells (:mod:`experiments.judge.readers`) may have, each read
into the long table of :mod:`ttc.evaluation.external`:

- **long**: a row per setting and frame, columns ``setting`` (or ``detector`` and
  ``descriptor``; or none, under a markdown heading naming the setting), ``frame``,
  ``ttc_camera`` and/or ``ttc_lidar`` (spellings: :data:`~experiments.judge.readers.ALIASES`),
  optional ``prev_frame``, ``box_x, box_y, box_w, box_h``, ``track_id``; other columns ignored;
- **wide by frame**: the first column the frame, a column per setting (camera TTC); when
  some headers start with "TTC camera", only those are settings (named by the text in their
  closing parentheses) and a "TTC lidar" column is every setting's lidar TTC;
- **wide by setting**: the first column the setting, a column per frame (headers: frame
  numbers), camera TTC.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from experiments.judge.readers import (
    ALIASES,
    OPTIONAL_NUMBERS,
    Grid,
    InputError,
    file_grids,
    frame_number,
    norm,
    setting_of_column,
    setting_of_heading,
    ttc_value,
)
from ttc.evaluation.external import TTC_COLUMNS


class _Cells:
    """Reading a grid's cells with errors that name the file, line and column."""

    def __init__(self, grid: Grid, path: Path, unit: str) -> None:
        self.grid, self.path, self.unit = grid, path, unit

    def error(self, line: int, column: str, message: str) -> InputError:
        return InputError(self.path, line, column, message, self.unit)

    def cell(self, r: int, c: int) -> str:
        row = self.grid.rows[r]
        if c >= len(row):
            raise self.error(self.grid.lines[r], self.grid.header[c],
                             f"the row has {len(row)} cells, the header {len(self.grid.header)}")  # fmt: skip
        return row[c]

    def frame(self, r: int, c: int) -> int:
        text = self.cell(r, c)
        found = frame_number(text)
        if found is None:
            raise self.error(self.grid.lines[r], self.grid.header[c],
                             f"text where a frame number belongs: {text!r}")  # fmt: skip
        return found

    def number(self, r: int, c: int, what: str = "a TTC in seconds") -> float:
        text = self.cell(r, c)
        value = ttc_value(text)
        if value is None:
            raise self.error(self.grid.lines[r], self.grid.header[c],
                             f"text where a number ({what}) belongs: {text!r}")  # fmt: skip
        return value


def _columns(grid: Grid) -> dict[str, int]:
    """Each long-table column the header names (:data:`ALIASES`) and its position (first)."""
    found: dict[str, int] = {}
    for i, h in enumerate(grid.header):
        name = ALIASES.get(norm(h))
        if name and name not in found:
            found[name] = i
    return found


def _camera_columns(grid: Grid) -> list[int]:
    """The wide columns that hold a setting's camera TTC: headers that start with "TTC
    camera" and say more (``ttcCamera [s] (1: SHITOMASI/BRISK)``)."""
    return [i for i, h in enumerate(grid.header)
            if norm(h).startswith(("ttccamera", "camerattc")) and norm(h) not in ALIASES]  # fmt: skip


def long_rows(cells: _Cells, cols: dict[str, int]) -> pd.DataFrame:
    """A long grid's rows (:mod:`module docstring <experiments.judge.layouts>`)."""
    grid = cells.grid
    heading = setting_of_heading(grid.heading) if grid.heading else ""
    out: dict[str, list] = {"setting": [], "frame": [], "line": []}
    present = [c for c in (*TTC_COLUMNS, *OPTIONAL_NUMBERS) if c in cols]
    out.update({c: [] for c in present})
    for r, line in enumerate(grid.lines):
        if "setting" in cols:
            setting = cells.cell(r, cols["setting"]).strip().lower()
        elif "detector" in cols and "descriptor" in cols:
            det, desc = cells.cell(r, cols["detector"]), cells.cell(r, cols["descriptor"])
            setting = f"{det.strip()}/{desc.strip()}".lower()
        else:
            setting = heading
        if not setting:
            raise cells.error(line, "setting", "no setting named on this row")
        out["setting"].append(setting)
        out["frame"].append(cells.frame(r, cols["frame"]))
        out["line"].append(line)
        for c in present:
            what = "a TTC in seconds" if c in TTC_COLUMNS else "a number"
            out[c].append(cells.number(r, cols[c], what))
    return pd.DataFrame(out)


def wide_by_frame(cells: _Cells, cols: dict[str, int]) -> pd.DataFrame:
    """A grid with a row per frame and a column per setting."""
    grid = cells.grid
    chosen = _camera_columns(grid) or [
        i for i in range(1, len(grid.header)) if grid.header[i].strip() and i not in cols.values()
    ]
    lidar = cols.get("ttc_lidar")
    parts = []
    for c in chosen:
        setting = setting_of_column(grid.header[c])
        rows = [(setting, cells.frame(r, 0), line, cells.number(r, c),
                 cells.number(r, lidar) if lidar is not None else np.nan)
                for r, line in enumerate(grid.lines)]  # fmt: skip
        parts.append(pd.DataFrame(rows, columns=["setting", "frame", "line", "ttc_camera",
                                                 "ttc_lidar"]))  # fmt: skip
    if not parts:
        raise cells.error(grid.header_line, "", "a row per frame but no column of a setting")
    out = pd.concat(parts, ignore_index=True)
    return out if lidar is not None else out.drop(columns="ttc_lidar")


def wide_by_setting(cells: _Cells, frames: list[int]) -> pd.DataFrame:
    """A grid with a row per setting and a column per frame (``frames``: the frame of each
    column after the first)."""
    rows = []
    for r, line in enumerate(cells.grid.lines):
        setting = cells.cell(r, 0).strip().lower()
        if not setting:
            raise cells.error(line, cells.grid.header[0], "no setting named on this row")
        rows += [(setting, f, line, cells.number(r, c)) for c, f in enumerate(frames, start=1)]
    return pd.DataFrame(rows, columns=["setting", "frame", "line", "ttc_camera"])


def grid_long(grid: Grid, path: Path, unit: str = "line") -> pd.DataFrame:
    """A grid as a long table, its layout told from its header (module docstring); a header
    that fits none is an :class:`InputError` naming the columns it lacks."""
    cells, cols = _Cells(grid, path, unit), _columns(grid)
    if not grid.rows:
        raise cells.error(grid.header_line, "", "a header but no rows")
    named = "setting" in cols or ("detector" in cols and "descriptor" in cols)
    ttc = any(c in cols for c in TTC_COLUMNS)
    first_is_frame = cols.get("frame") == 0
    frames = [frame_number(h) for h in grid.header[1:]]
    if len(frames) > 1 and all(f is not None for f in frames):
        return wide_by_setting(cells, frames)  # type: ignore[arg-type]
    if named or (grid.heading and ttc and "frame" in cols and not _camera_columns(grid)):
        missing = [c for c in ("frame",) if c not in cols]
        if missing or not ttc:
            lacks = "frame" if missing else "ttc_camera/ttc_lidar"
            unknown = [h for h in grid.header if norm(h) not in ALIASES]
            raise cells.error(grid.header_line, lacks, f"no such column (found: {', '.join(grid.header)}"
                              + (f"; not understood: {', '.join(unknown)})" if unknown else ")"))  # fmt: skip
        return long_rows(cells, cols)
    if first_is_frame:
        return wide_by_frame(cells, cols)
    raise cells.error(
        grid.header_line, grid.header[0],
        "cannot tell the layout: a long table needs columns setting (or detector and "
        "descriptor), frame and ttc_camera or ttc_lidar; a wide one a first column 'frame' "
        "(a column per setting) or frame numbers as the other headers (a row per setting)",
    )  # fmt: skip


def read_long(path: Path) -> pd.DataFrame:
    """Every table of the file at ``path`` as one long table (an :class:`InputError` for
    anything that cannot be read)."""
    grids, unit = file_grids(path)
    parts = [grid_long(g, path, unit) for g in grids if g.rows or len(grids) == 1]
    return pd.concat(parts, ignore_index=True)
