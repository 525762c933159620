"""A batch's rows kept as shared parts (ttc.row_parts): the table made by columns is exactly
pandas' ``DataFrame.from_records`` of the rows as dicts (the rows' definition), on real
KITTI batches (matched, unmatched and unreadable pairs) and on parts that mix types. Every
table here is made by columns however few its rows (a few rows are made from the records)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments.configs.structured import frame_range_from_config, settings_from_config
from tests.conftest import copy_frames
from tests.test_beyond_rubric import composed
from ttc import row_parts
from ttc.engine import runner
from ttc.engine.cache import StageCache
from ttc.io.frames import frame_files
from ttc.row_parts import KINDS, RowBlock, RowParts
from ttc.rows import MEMBER
from ttc.settings import FrameRange


@pytest.fixture(autouse=True)
def by_columns(monkeypatch) -> None:
    """Tables made by columns however few their rows."""
    monkeypatch.setattr(row_parts, "RECORDS_UP_TO", 0)


def _row(shared: int = 0, text: str = "", **parts: int) -> RowBlock:
    """A block of one row of the given parts (by kind), shared matches and error text."""
    return RowBlock.of([(*(parts.get(kind, -1) for kind in KINDS), shared)], text)


def _same_as_records(parts: RowParts, members, make=RowParts.table) -> pd.DataFrame:
    """The table, checked equal to ``from_records`` of the rows as dicts (dtypes, order)."""
    table = make(parts, members)
    pd.testing.assert_frame_equal(table, pd.DataFrame.from_records(parts.records(members)))
    return table


def test_real_batches_are_their_rows_as_records(
    kitti_dir: Path, tmp_path: Path, monkeypatch
) -> None:
    """Every table the runner makes equals its records' ``from_records``: KITTI frames 0–6
    with frame 3's scan missing (matched boxes and unreadable pairs) and drive 0009 frames
    0–4 (no lead vehicle: the stand-in rows), for settings that share some parts and not
    others (one invalid), and a pair's detail."""
    seq = copy_frames(kitti_dir, tmp_path / "data", range(7))
    frame_files(seq, 3).scan.unlink()
    overrides = [[], ["keypoint_filter=zscore"], ["lidar_ttc=cluster"], ["fusion=kalman_ca"],
                 ["box_matching=mutual_best", "camera_ttc=mean_ratio"],
                 ["detector=sift", "descriptor=orb"]]  # fmt: skip
    seen: list[pd.DataFrame] = []

    def checked(self, members, make=RowParts.table):
        seen.append(_same_as_records(self, members, make))
        return seen[-1]

    monkeypatch.setattr(RowParts, "table", checked)
    cache = StageCache(tmp_path / "cache")
    settings = [settings_from_config(composed(o)) for o in overrides]
    rows, failed = runner.run_settings(settings, FrameRange(seq, 0, 6), cache)
    assert list(failed) == [5] and len(seen) == 1 and len(rows) == len(seen[0])
    assert sorted(seen[0][MEMBER].unique()) == [0, 1, 2, 3, 4]
    assert (seen[0]["error"] != "").sum() == 2 * 5  # pairs 2→3 and 3→4, each member
    assert (seen[0]["prev_box"] >= 0).sum() > 100
    raw = composed(["dataset=kitti_raw_0009", "dataset.last=4"])
    settings = [settings_from_config(composed(["dataset=kitti_raw_0009", *o]))
                for o in overrides[:3]]  # fmt: skip
    runner.run_settings(settings, frame_range_from_config(raw), cache)
    stand_in = (seen[1]["prev_box"] < 0) & (seen[1]["error"] == "")
    assert stand_in.any() and (seen[1]["prev_box"] >= 0).any()
    runner.pair_detail(settings[0], FrameRange(seq, 0, 6), 0, 1, cache)
    assert len(seen) == 3 and (seen[2][MEMBER] == 0).all()


def test_columns_that_kinds_give_with_different_types() -> None:
    """int in one kind and float in another: float; bool and int: object; texts from two
    kinds; a column some rows lack: NaN, and placed where ``from_records`` first meets it."""
    parts = RowParts()
    pair = [parts.add("pair", {"a": 1, "b": True, "s": "x"}) for _ in range(2)]
    lidar = parts.add("lidar", {"t": 2.5, "flag": True, "reason": "ok", "z": -0.0})
    camera = parts.add("camera", {"cam": np.float64(1.0)})
    unmatched = parts.add("unmatched", {"t": 3, "flag": 1, "reason": "no_box_match", "z": 0.0})
    error = parts.add("error", {"a": 7, "b": False, "s": "y", "t": np.nan})
    members = [
        (4, [_row(pair=pair[0], unmatched=unmatched), _row(pair=pair[1], lidar=lidar,
                                                           camera=camera)]),
        (2, [_row(3, "broken", error=error), _row(pair=pair[0], lidar=lidar)]),
    ]  # fmt: skip
    table = _same_as_records(parts, members)
    assert table["t"].dtype == np.float64 and table["flag"].dtype == object
    assert list(table.columns[:3]) == ["a", "b", "s"] and table.columns[-1] == "cam"
    assert np.signbit(table["z"].iloc[1]) and not np.signbit(table["z"].iloc[0])
    assert table["cam"].isna().tolist() == [True, False, True, True]
    assert table[MEMBER].tolist() == [4, 4, 2, 2]


def test_the_part_rules_are_checked() -> None:
    """Parts of one row that share a column, or parts of one kind with other columns, are
    a builder's mistake: named, not silently merged; no rows is an empty table."""
    parts = RowParts()
    a, b = parts.add("pair", {"x": 1}), parts.add("object", {"x": 2})
    with pytest.raises(ValueError, match="share columns"):
        parts.table([(0, [_row(pair=a, object=b)])])
    c = parts.add("pair", {"y": 1})
    with pytest.raises(ValueError, match="pair parts differ"):
        parts.table([(0, [_row(pair=a), _row(pair=c)])])
    own = parts.add("box", {"error": "x"})
    with pytest.raises(ValueError, match="share columns"):
        parts.table([(0, [_row(box=own)])])
    assert parts.table([(0, [])]).empty
