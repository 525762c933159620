"""The append-only store: invocations add fragments and rewrite nothing, readers see one
dataset (also through the ``runs/*.parquet`` glob), ``compact`` keeps every row, a corrupt
fragment is named, concurrent writers into one folder both land."""

from __future__ import annotations

import hashlib
import importlib
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pyarrow.dataset as ds
import pytest

from experiments import store
from experiments.store.dataset import iter_tables, unified_schema
from tests.conftest import PROJECT_ROOT

compact_module = importlib.import_module("experiments.store.compact")
KEY = ["run_id", "frame", "curr_box"]


def file_hashes(folder: Path) -> dict[str, str]:
    """SHA-256 of every rows file and record of a sweep folder, by name."""
    runs = folder / store.RUNS_DIR
    return {
        p.name: hashlib.sha256(p.read_bytes()).hexdigest()
        for p in runs.iterdir()
        if p.suffix in (".parquet", ".json")
    }


def sorted_rows(frames: pd.DataFrame) -> pd.DataFrame:
    """Rows in one order, whatever order the fragments were read in."""
    key = [c for c in KEY if c in frames]
    return frames.sort_values(key, kind="stable", ignore_index=True)


def glob_rows(sweep: Path) -> pd.DataFrame:
    """The rows as a user's glob reads them (``pyarrow.dataset`` over ``runs/*.parquet``)."""
    files = sorted(str(p) for p in sweep.glob(store.ROWS_GLOB))
    return ds.dataset(files).to_table().to_pandas()


# -- exact checks on a synthetic store -----------------------------------------------------
def rows_of(run_id: str, n: int, value: float, detector: str = "fast") -> pd.DataFrame:
    return pd.DataFrame(
        {
            "run_id": run_id,
            "detector": detector,
            "descriptor": "brief",
            "frame": range(1, n + 1),
            "curr_box": 0,
            "ttc_camera": [value + i for i in range(n)],
        }
    )


def record(run_id: str, n: int) -> dict:
    return {"run_id": run_id, "status": "ok", "n_rows": n}


def synthetic_sweep(folder: Path) -> None:
    """Two batches, a run computed alone, a run of the first batch recomputed alone (its old
    rows stay in the batch's file, superseded) and a failed run."""
    store.save_batch(
        folder, "batch-a", [record("a1", 3), record("a2", 2)],
        pd.concat([rows_of("a1", 3, 10.0), rows_of("a2", 2, 20.0)]),
    )  # fmt: skip
    store.save_batch(
        folder, "batch-b", [record("b1", 2), record("c0", 1)],
        pd.concat([rows_of("b1", 2, 30.0, "orb"), rows_of("c0", 1, 40.0, "orb")]),
    )  # fmt: skip
    store.save_run(folder, record("s1", 2), rows_of("s1", 2, 50.0))
    store.save_run(folder, record("a2", 4), rows_of("a2", 4, 60.0))  # recomputed alone
    store.save_run(folder, {"run_id": "f1", "status": "failed", "message": "boom"}, None)


def test_compaction_keeps_every_row_and_a_reader_never_sees_a_run_missing_or_twice(
    tmp_path, monkeypatch
) -> None:
    """``compact`` gives the same rows in the same order, byte for byte; a reader between
    any two of its record changes sees every run once; afterwards the glob is exact."""
    synthetic_sweep(tmp_path)
    before, runs_before = store.load_sweep(tmp_path)
    assert sorted(before["run_id"].unique()) == ["a1", "a2", "b1", "c0", "s1"]
    assert (before.loc[before["run_id"] == "a2", "ttc_camera"] >= 60).all()  # the new rows
    assert len(glob_rows(tmp_path)) == len(before) + 2  # the glob still sees a2's old rows

    seen = []
    real_write = compact_module.write_json_atomic

    def write_and_read(obj, path, indent=None):
        real_write(obj, path, indent=indent)
        seen.append(sorted_rows(store.load_sweep(tmp_path)[0]))

    monkeypatch.setattr(compact_module, "write_json_atomic", write_and_read)
    done = store.compact(tmp_path)
    monkeypatch.undo()
    assert (done.merged, done.written, done.runs) == (4, 1, 5)
    assert len(seen) == 5  # a reader after each record changed
    for rows in seen:
        pd.testing.assert_frame_equal(rows, sorted_rows(before))
    after, runs_after = store.load_sweep(tmp_path)
    pd.testing.assert_frame_equal(after, before)  # same rows, same order
    pd.testing.assert_frame_equal(
        runs_after.drop(columns=["rows_file", "rows_sha256"]),
        runs_before.drop(columns=["rows_file", "rows_sha256"]),
    )
    (only,) = [p.name for p in (tmp_path / store.RUNS_DIR).glob("*.parquet")]
    assert only.startswith("compact-")
    pd.testing.assert_frame_equal(glob_rows(tmp_path), before)  # exact now
    assert store.rows_dataset(tmp_path).to_table().to_pandas().equals(before)
    assert store.compact(tmp_path).written == 0  # nothing left to merge
    assert store.load_sweep(tmp_path)[0].equals(before)


def test_a_dataset_over_a_fragment_with_superseded_rows_reads_only_live_rows(tmp_path) -> None:
    synthetic_sweep(tmp_path)
    frames = store.load_sweep(tmp_path, columns=["run_id", "ttc_camera", "no_such_column"])[0]
    assert list(frames.columns) == ["run_id", "ttc_camera"]
    got = store.rows_dataset(tmp_path).to_table(columns=["run_id", "ttc_camera"]).to_pandas()
    pd.testing.assert_frame_equal(
        got.sort_values(["run_id", "ttc_camera"], ignore_index=True),
        frames.sort_values(["run_id", "ttc_camera"], ignore_index=True),
    )


def test_a_corrupt_fragment_is_named_and_compaction_changes_nothing(tmp_path) -> None:
    synthetic_sweep(tmp_path)
    (bad,) = (tmp_path / store.RUNS_DIR).glob("batch-b-*.parquet")
    bad.write_bytes(bad.read_bytes()[:-50])
    hashes = file_hashes(tmp_path)
    for read in (store.load_sweep, store.rows_dataset, store.compact):
        with pytest.raises(store.StoreError, match=f"{bad.name}: rows file corrupt"):
            read(tmp_path)
    assert file_hashes(tmp_path) == hashes
    res = subprocess.run(
        [sys.executable, "-m", "experiments.cli", "compact", str(tmp_path)],
        cwd=PROJECT_ROOT, capture_output=True, text=True,
    )  # fmt: skip
    assert res.returncode == 1 and f"{bad}: rows file corrupt" in res.stderr
    assert "Traceback" not in res.stderr


def test_merged_files_of_earlier_versions_are_never_read_and_compact_removes_them(
    tmp_path,
) -> None:
    """A sweep folder of an earlier version holds ``frames.parquet`` / ``runs.parquet``
    merged once: stale as soon as a run is added, so readers take the fragments only."""
    synthetic_sweep(tmp_path)
    expected = store.load_sweep(tmp_path)[0]
    stale = rows_of("zz", 5, 0.0)
    for name in store.LEGACY_MERGED_FILES:
        store.write_parquet_atomic(stale, tmp_path / name)
    assert store.load_sweep(tmp_path)[0].equals(expected)
    store.compact(tmp_path)
    assert not any((tmp_path / name).exists() for name in store.LEGACY_MERGED_FILES)
    assert store.load_sweep(tmp_path)[0].equals(expected)


def sweep_cmd(args: list[str], tmp: Path) -> tuple[list[str], dict[str, str]]:
    """The command line and environment of a sweep into ``<tmp>/sweeps/shared``."""
    env = {**os.environ, "TTC_RESULTS_DIR": str(tmp / "sweeps"),
           "TTC_CACHE_DIR": str(tmp / "cache")}  # fmt: skip
    base = ["-m", "dataset.last=2", "sweep_name=shared"]
    if not any(a.startswith("hydra/launcher=") for a in args):
        base.append("hydra.launcher.n_jobs=1")
    return [sys.executable, "-m", "experiments.run", *base, *args], env


def sweep(args: list[str], tmp: Path) -> subprocess.CompletedProcess:
    cmd, env = sweep_cmd(args, tmp)
    res = subprocess.run(cmd, cwd=PROJECT_ROOT, env=env, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    return res


@pytest.mark.slow
def test_two_invocations_into_one_folder_rewrite_nothing_and_compact(tmp_path) -> None:
    """A second invocation adds its fragments and records beside the first's (whose files
    keep their bytes); both are read as one dataset, also through the glob; a re-run of both
    computes nothing; ``ttc-bench compact`` keeps every row."""
    sweep(["detector=fast", "descriptor=brief,orb"], tmp_path)
    folder = tmp_path / "sweeps" / "shared"
    first = file_hashes(folder)
    sweep(["detector=orb", "descriptor=brief,orb"], tmp_path)
    second = file_hashes(folder)
    assert {k: second.get(k) for k in first} == first  # nothing rewritten
    assert len(second) > len(first)
    frames, runs = store.load_sweep(folder)
    assert sorted(zip(runs["detector"], runs["descriptor"], strict=True)) == [
        ("fast", "brief"), ("fast", "orb"), ("orb", "brief"), ("orb", "orb")]  # fmt: skip
    assert frames["run_id"].nunique() == 4 and not frames.duplicated(KEY).any()
    pd.testing.assert_frame_equal(sorted_rows(glob_rows(folder)), sorted_rows(frames))
    res = sweep(["detector=fast,orb", "descriptor=brief,orb"], tmp_path)
    assert "4 already complete (not launched)" in res.stdout
    assert file_hashes(folder) == second

    res = subprocess.run(
        [sys.executable, "-m", "experiments.cli", "compact", str(folder)],
        cwd=PROJECT_ROOT, capture_output=True, text=True,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert len(list(folder.glob(store.ROWS_GLOB))) == 1
    pd.testing.assert_frame_equal(store.load_sweep(folder)[0], frames)
    res = sweep(["detector=fast,orb", "descriptor=brief,orb"], tmp_path)
    assert "4 already complete (not launched)" in res.stdout  # records repointed, checked


@pytest.mark.slow
def test_two_concurrent_writers_both_land(tmp_path) -> None:
    """Two invocations started at once into one folder, one through ``submitit_local`` (the
    Slurm path, run locally), sharing one setting: both exit 0, every setting is stored once
    as one run, and a re-run of both sees them all complete."""
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    procs = []
    for args in (["detector=fast", "descriptor=brief,orb"],
                 ["hydra/launcher=submitit_local", "detector=fast", "descriptor=orb,brisk"]):  # fmt: skip
        cmd, env = sweep_cmd(args, tmp_path)
        procs.append(subprocess.Popen(cmd, cwd=PROJECT_ROOT, env=env, text=True,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE))  # fmt: skip
    for proc in procs:
        out, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err[-3000:]
    folder = tmp_path / "sweeps" / "shared"
    frames, runs = store.load_sweep(folder)
    assert sorted(runs["descriptor"]) == ["brief", "brisk", "orb"]
    assert (runs["status"] == "ok").all() and frames["run_id"].nunique() == 3
    assert not frames.duplicated(KEY).any()
    res = sweep(["detector=fast", "descriptor=brief,orb,brisk"], tmp_path)
    assert "3 already complete (not launched)" in res.stdout


def test_the_runs_table_keeps_long_texts_as_the_records_strings(tmp_path) -> None:
    """``runs_table(records, texts=...)`` (the summary's, whose filters would copy every
    run's 2 kB config as Arrow strings) holds the same values as the table of every field,
    the texts as the records' own strings (object dtype), rows in run id order."""
    records = [
        {"run_id": "b2", "status": "ok", "n_rows": 3, "config": '{"dataset": {"s": "x"}}'},
        {"run_id": "a1", "status": "failed", "message": "boom", "config": '{"é": 1}'},
        {"run_id": "c3", "status": "skipped", "n_rows": 0},
    ]
    whole = store.runs_table(records)
    kept = store.runs_table(records, texts=("config",))
    assert kept["config"].dtype == object and list(kept.columns)[-1] == "config"
    assert kept["config"].iloc[0] is records[1]["config"]
    pd.testing.assert_frame_equal(kept[whole.columns].astype({"config": whole["config"].dtype}),
                                  whole)  # fmt: skip
    assert list(kept["run_id"]) == ["a1", "b2", "c3"]


def test_a_fragment_read_on_some_columns_keeps_live_rows_and_is_checked_whole(tmp_path) -> None:
    """The report reads fragments on the columns it needs (decoding only those): the live
    rows on those columns, as the whole rows give them; a byte changed anywhere in the file
    is named all the same."""
    synthetic_sweep(tmp_path)
    frags = store.fragments(tmp_path)
    schema = unified_schema(frags)
    got = pd.concat([t.to_pandas() for t in iter_tables(frags, schema, ["ttc_camera", "run_id"])],
                    ignore_index=True)  # fmt: skip
    whole = store.load_sweep(tmp_path)[0][["ttc_camera", "run_id"]]
    assert list(got.columns) == ["ttc_camera", "run_id"] and len(got) == 12
    pd.testing.assert_frame_equal(
        got.sort_values("ttc_camera", ignore_index=True),
        whole.sort_values("ttc_camera", ignore_index=True),
    )
    (bad,) = (tmp_path / store.RUNS_DIR).glob("batch-b-*.parquet")
    data = bytearray(bad.read_bytes())
    data[len(data) // 2] ^= 0xFF
    bad.write_bytes(bytes(data))
    tables = iter_tables(frags, schema, ["ttc_camera"])
    with pytest.raises(store.StoreError, match=f"{bad.name}: rows file corrupt"):
        list(tables)
