"""The report's rows cut per fragment and kept (:mod:`experiments.report.kept_judged`): a
report from the kept cuts loads what one cut from the fragments loads, and nothing stale is
used (a run recomputed since, a damaged kept file, a sweep judged beside another)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest

from experiments import store
from experiments.report import kept_judged
from experiments.report.load import SweepData, load_sweeps
from experiments.summary import kept_tables as kt
from tests.test_report import camera_grid  # noqa: F401 (the session's 2 × 2 grid, frames 0–5)

KINDS = (kept_judged.JUDGED, kept_judged.BOXES)


def _copy(camera_grid, tmp_path: Path) -> Path:  # noqa: F811
    """The grid sweep copied (its kept tables left behind)."""
    sweep = tmp_path / "grid"
    shutil.copytree(camera_grid[1], sweep, ignore=shutil.ignore_patterns(kt.CACHE_DIR))
    return sweep


def _assert_same(got: SweepData, expected: SweepData) -> None:
    """The judged rows, box pairs and runs of two loads exactly equal."""
    assert len(got.frames) > 0 and len(got.boxes) > 0
    for name in ("frames", "boxes", "runs"):
        pd.testing.assert_frame_equal(getattr(got, name), getattr(expected, name),
                                      check_exact=True)  # fmt: skip


def _no_fragment_read(monkeypatch) -> None:
    """Reading a fragment fails the test."""

    def refuse(*_args, **_kwargs):
        raise AssertionError("a fragment was read although its cut is kept")

    monkeypatch.setattr(kept_judged, "iter_tables", refuse)


def _kept(sweep: Path, kind: str) -> list[Path]:
    return sorted((sweep / kt.CACHE_DIR).glob(f"{kind}-*"))


def test_a_second_load_reads_the_kept_cuts_and_gets_the_same_rows(
    camera_grid,  # noqa: F811
    tmp_path,
    monkeypatch,
) -> None:
    sweep = _copy(camera_grid, tmp_path)
    first = load_sweeps([sweep])
    assert all(_kept(sweep, kind) for kind in (*KINDS, kept_judged.COUNTED))
    with monkeypatch.context() as m:
        _no_fragment_read(m)
        _assert_same(load_sweeps([sweep]), first)
    assert (
        "ms_compute_per_frame" in first.frames and first.frames["ms_compute_per_frame"].gt(0).all()
    )


def test_a_damaged_kept_file_is_cut_again(camera_grid, tmp_path) -> None:  # noqa: F811
    sweep = _copy(camera_grid, tmp_path)
    first = load_sweeps([sweep])
    (judged,) = _kept(sweep, kept_judged.JUDGED)
    judged.write_bytes(judged.read_bytes()[:100])
    (counted,) = _kept(sweep, kept_judged.COUNTED)
    counted.write_bytes(b"not a pickle")
    _assert_same(load_sweeps([sweep]), first)


def test_a_run_recomputed_since_has_its_fragment_cut_again(
    camera_grid,  # noqa: F811
    tmp_path,
    monkeypatch,
) -> None:
    """A run computed again (its rows written to its own file again, another SHA-256): its
    fragment's kept cut is stale and made again, and the rows are those a load without any
    kept cut gives; the other fragments' cuts are read as kept."""
    sweep = _copy(camera_grid, tmp_path)
    load_sweeps([sweep])
    rows, runs = store.load_sweep(sweep)
    run_id = runs.loc[runs["status"] == "ok", "run_id"].iloc[0]
    record = next(r for r in store.list_records(sweep) if r["run_id"] == run_id)
    new_rows = rows[rows["run_id"] == run_id].copy()
    new_rows["ttc_camera"] = new_rows["ttc_camera"] + 1.0
    record = {k: v for k, v in record.items() if k not in ("rows_file", "rows_sha256")}
    store.save_run(sweep, record, new_rows)

    cut = []
    real = kept_judged.jr.cut_fragment
    monkeypatch.setattr(kept_judged.jr, "cut_fragment",
                        lambda table, *a: cut.append(table.num_rows) or real(table, *a))  # fmt: skip
    again = load_sweeps([sweep])
    assert cut, "the changed fragments were cut again"
    assert sum(cut) < len(rows), "fragments that did not change were read as kept"
    judged = again.frames[again.frames["run_id"] == run_id]
    assert judged["ttc_camera"].dropna().gt(0).any()
    shutil.rmtree(sweep / kt.CACHE_DIR)
    _assert_same(again, load_sweeps([sweep]))


def test_many_kept_files_become_one(camera_grid, tmp_path, monkeypatch) -> None:  # noqa: F811
    sweep = _copy(camera_grid, tmp_path)
    first = load_sweeps([sweep])
    monkeypatch.setattr(kt, "MAX_KEPT_FILES", 0)
    _assert_same(load_sweeps([sweep]), first)
    for kind in (*KINDS, kept_judged.COUNTED):
        assert len(_kept(sweep, kind)) == 1, kind
    monkeypatch.undo()
    with monkeypatch.context() as m:
        _no_fragment_read(m)
        _assert_same(load_sweeps([sweep]), first)


def test_a_sweep_judged_beside_another_keeps_its_own_cuts(
    camera_grid,  # noqa: F811
    tmp_path,
) -> None:
    """Two folders holding the same runs: the second's are judged from the first (each run
    once), so the second's rows are not judged; each folder alone still gives all its rows."""
    sweep = _copy(camera_grid, tmp_path)
    twin = tmp_path / "twin"
    shutil.copytree(sweep, twin)
    alone = load_sweeps([twin])
    both = load_sweeps([sweep, twin])
    assert both.repeated == len(alone.runs) and len(both.frames) == len(alone.frames)
    _assert_same(load_sweeps([twin]), alone)


@pytest.mark.parametrize("kind", KINDS)
def test_a_kept_file_without_its_label_column_is_left_out(
    camera_grid,  # noqa: F811
    tmp_path,
    kind,
) -> None:
    sweep = _copy(camera_grid, tmp_path)
    first = load_sweeps([sweep])
    (path,) = _kept(sweep, kind)
    keys = kt.kept_files(sweep, kind)[path]
    table = kt.read_kept(path, keys, whole=True).drop_columns([kt.FRAGMENT])
    kt.keep(sweep, kind, table, sorted(keys))  # a file listing the keys, its rows unlabelled
    _assert_same(load_sweeps([sweep]), first)
