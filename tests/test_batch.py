"""Batched sweeps (issue #11) through the real command line: a batched sweep gives the rows
and records one setting per job gives, a finished sweep launches no worker, and a
grand-style sweep merges into a dataset queryable by partition."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from experiments import store
from tests.conftest import PROJECT_ROOT

pytestmark = pytest.mark.slow

#: 2 detectors x 2 descriptors (one pair invalid) x 2 selectors x 2 filters x 2 estimators
GRID = ["detector=fast,akaze", "descriptor=brief,akaze", "selector=nn,knn",
        "keypoint_filter=none,zscore", "lidar_ttc=median,cluster", "dataset.last=2",
        "cache.enabled=false", "sweep_name=grid"]  # fmt: skip
#: Record fields that differ between two computations of one setting (times, machine load,
#: where the rows are stored).
TIMING_AND_STORAGE = {"start", "end", "wall_s", "peak_rss_mb", "batch_id", "batch_size",
                      "batch_wall_s", "rows_file", "rows_sha256", "traceback"}  # fmt: skip
CODE_VERSION = {"git_commit", "git_dirty"}
TTC_COLUMNS = ["ttc_lidar", "ttc_camera", "d_prev", "d_curr", "camera_ratio", "camera_pairs",
               "matches_total", "matches_in_box", "matches_kept", "lidar_reason",
               "camera_reason", "prev_box", "curr_box", "is_lead"]  # fmt: skip


def run(args: list[str], results: Path, cache: Path) -> subprocess.CompletedProcess:
    """``python -m experiments.run args`` with results and cache where the test says."""
    env = {**os.environ, "TTC_RESULTS_DIR": str(results), "TTC_CACHE_DIR": str(cache)}
    return subprocess.run(
        [sys.executable, "-m", "experiments.run", "-m", *args], cwd=PROJECT_ROOT, env=env,
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip


@pytest.fixture(scope="module")
def two_ways(tmp_path_factory) -> dict[str, object]:
    """The same 32 settings batched (default) and one setting per job, then the batched
    sweep again (nothing to compute)."""
    tmp = tmp_path_factory.mktemp("batch")
    batched = run(GRID, tmp / "batched", tmp / "cache")
    assert batched.returncode == 0, batched.stderr[-3000:]
    single = run([*GRID, "hydra.sweeper.max_settings_per_job=1"], tmp / "single", tmp / "cache")
    assert single.returncode == 0, single.stderr[-3000:]
    runs_dir = tmp / "batched" / "grid" / store.RUNS_DIR
    before = {p.name: p.stat().st_mtime_ns for p in runs_dir.iterdir()}
    # the same sweep in other words (a default restated): the sweeper's plan memory
    again = run([*GRID, "print_rows=20"], tmp / "batched", tmp / "cache")
    assert again.returncode == 0, again.stderr[-3000:]
    # the same command line: recognised before Hydra starts (experiments/sweep/finished.py)
    remembered = run(GRID, tmp / "batched", tmp / "cache")
    assert remembered.returncode == 0, remembered.stderr[-3000:]
    after = {p.name: p.stat().st_mtime_ns for p in runs_dir.iterdir()}
    return {"tmp": tmp, "batched": batched, "single": single, "again": again,
            "remembered": remembered, "before": before, "after": after}  # fmt: skip


def test_batched_sweep_gives_the_rows_and_records_of_one_setting_per_job(two_ways) -> None:
    tmp = two_ways["tmp"]
    assert "to compute in 3 jobs (3 batches)" in two_ways["batched"].stdout
    batched = two_ways["batched"]
    assert "Starting 2 workers while the sweep is planned" in batched.stdout + batched.stderr
    assert "to compute in 24 jobs (0 batches)" in two_ways["single"].stdout
    frames_b, runs_b = store.load_sweep(tmp / "batched" / "grid")
    frames_s, runs_s = store.load_sweep(tmp / "single" / "grid")
    assert len(runs_b) == len(runs_s) == 32
    assert runs_b["status"].value_counts().to_dict() == {"ok": 24, "skipped": 8}
    assert runs_b["batch_size"].dropna().eq(8).all()  # the ok ones were computed in batches
    assert "batch_id" not in runs_s or runs_s["batch_id"].isna().all()
    records_b = {r["run_id"]: r for r in store.list_records(tmp / "batched" / "grid")}
    records_s = {r["run_id"]: r for r in store.list_records(tmp / "single" / "grid")}
    assert records_b.keys() == records_s.keys()  # same run ids
    for records in (records_b, records_s):  # the code version: one per sweep (the tree may
        assert len({r["git_commit"] for r in records.values()}) == 1  # move between the two)
    for rid, single in records_s.items():
        batched = records_b[rid]
        fields = (single.keys() | batched.keys()) - TIMING_AND_STORAGE - CODE_VERSION
        for field in fields:
            assert batched.get(field) == single.get(field), (rid, field)
    assert set(frames_b.columns) == set(frames_s.columns)
    frames_b, frames_s = frames_b.drop(columns="git_commit"), frames_s.drop(columns="git_commit")
    key = ["run_id", "frame", "curr_box", "prev_box"]
    b = frames_b.sort_values(key, ignore_index=True)
    s = frames_s[frames_b.columns].sort_values(key, ignore_index=True)
    assert len(b) == len(s) and b["run_id"].nunique() == 24
    for column in TTC_COLUMNS:
        np.testing.assert_array_equal(b[column].to_numpy(), s[column].to_numpy(), column)
    # one rows file per batch, named by the records that point to it
    files = {r["rows_file"] for r in records_b.values() if r["status"] == "ok"}
    assert len(files) == 3 and all(f.startswith("batch-") for f in files)
    for name in files:  # stored in run id order: the merge need not sort them
        ids = pq.read_table(tmp / "batched" / "grid" / store.RUNS_DIR / name, columns=["run_id"])
        assert ids["run_id"].to_pylist() == sorted(ids["run_id"].to_pylist())


@pytest.mark.parametrize("which", ["again", "remembered"])
def test_finished_sweep_launches_no_worker(two_ways, which) -> None:
    again = two_ways[which]
    assert "sweep plan: 32 settings: 32 already complete (not launched)" in again.stdout
    assert "to compute in 0 jobs" in again.stdout
    assert "Launching" not in again.stderr + again.stdout  # the launcher was not called
    assert "workers while the sweep is planned" not in again.stderr + again.stdout  # nor warmed
    assert "this invocation: 0 computed, 32 already complete" in again.stdout
    assert "settings: 32 total, 24 ok, 8 skipped, 0 failed" in again.stdout
    # only the identical command line is recognised before Hydra composes anything
    assert ("no config composed" in again.stdout) == (which == "remembered")
    assert two_ways["after"] == two_ways["before"]  # no record, rows or lock file touched
    jobs = two_ways["tmp"] / "batched" / "grid" / "jobs"
    assert sorted(p.name for p in jobs.iterdir()) == ["0", "1", "2"]  # the first run's jobs


def test_a_changed_axis_warms_the_workers_up(two_ways, tmp_path) -> None:
    """A re-run with one axis changed into the same folder: the folder holds as many records
    as the sweep has jobs, yet its first setting has none, so the workers start while the
    sweep is planned (they started only at the launch while the records were counted)."""
    folder = tmp_path / "results"
    shutil.copytree(two_ways["tmp"] / "batched", folder)
    changed = [a if not a.startswith("lidar_ttc=") else "lidar_ttc=quantile" for a in GRID]
    proc = run(changed, folder, two_ways["tmp"] / "cache")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "16 settings: 0 already complete" in proc.stdout
    assert "Starting 2 workers while the sweep is planned" in proc.stdout + proc.stderr


def test_a_recomputed_setting_of_a_batch_keeps_the_others(two_ways, tmp_path) -> None:
    """Damage one batched run's record: the re-run computes that setting only (a new rows
    file), and the others keep pointing to the old file, still whole."""
    tmp = two_ways["tmp"]
    sweep = tmp / "batched" / "grid"
    records = [r for r in store.list_records(sweep) if r["status"] == "ok"]
    victim = records[0]
    sibling = next(r for r in records[1:] if r.get("rows_file") == victim["rows_file"])
    store.run_paths(sweep, victim["run_id"])[1].write_text("{not json")
    res = run(GRID, tmp / "batched", tmp / "cache")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "31 already complete (not launched)" in res.stdout
    assert "1 to compute in 1 jobs (0 batches)" in res.stdout
    redone = store.read_record(sweep, victim["run_id"])
    assert redone["status"] == "ok" and "rows_file" not in redone  # computed alone
    frames, runs = store.load_sweep(sweep)
    assert (runs["status"] != "failed").all() and frames["run_id"].nunique() == 24
    old = store.read_record(sweep, sibling["run_id"])  # a batch-mate of the victim
    assert old["rows_file"] == victim["rows_file"] and store.is_complete(sweep, old["run_id"])


def test_grand_style_sweep_compacts_into_partitions(tmp_path) -> None:
    """``+experiment=grand`` with two values per axis on frames 0-2 (128 settings, 32 of an
    invalid pair): compacted into one file, and a query of one partition reads only its row
    groups."""
    args = ["+experiment=grand", "detector=fast,akaze", "descriptor=brief,akaze",
            "matcher=bf,flann", "selector=nn,knn", "box_matching=mutual_best,hungarian",
            "lidar_ttc=median,cluster", "keypoint_filter=none,zscore",
            "camera_ttc=median_ratio,mean_ratio", "dataset.last=2", "sweep_name=g"]  # fmt: skip
    res = run(args, tmp_path / "sweeps", tmp_path / "cache")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "sweep plan: 256 settings" in res.stdout
    assert "64 skipped as invalid" in res.stdout  # fast x akaze, each of its 64 settings
    sweep = tmp_path / "sweeps" / "g"
    runs = store.load_runs(sweep)
    assert len(runs) == 256 and runs["status"].value_counts().to_dict() == {
        "ok": 192,
        "skipped": 64,
    }
    assert (runs.loc[runs["status"] == "skipped", "skipped_at"] == "plan").all()
    assert store.compact(sweep).written == 1
    (path,) = (sweep / store.RUNS_DIR).glob("*.parquet")
    meta = pq.ParquetFile(path).metadata
    columns = {meta.schema.column(i).name: i for i in range(meta.num_columns)}
    groups = []
    for g in range(meta.num_row_groups):
        stats = [
            meta.row_group(g).column(columns[c]).statistics for c in ("detector", "descriptor")
        ]
        assert all(s.min == s.max for s in stats)  # one detector x descriptor per row group
        groups.append((stats[0].min, stats[1].min))
    assert set(groups) == {("fast", "brief"), ("akaze", "brief"), ("akaze", "akaze")}
    whole = pq.read_table(path).to_pandas()
    assert whole["run_id"].nunique() == 192 and len(whole) == meta.num_rows
    part = pq.read_table(path, filters=[("detector", "=", "akaze"), ("descriptor", "=", "akaze")])
    expected = whole[(whole["detector"] == "akaze") & (whole["descriptor"] == "akaze")]
    assert part.num_rows == len(expected) > 0
    wanted = [g for g, key in enumerate(groups) if key == ("akaze", "akaze")]
    assert pq.ParquetFile(path).read_row_groups(wanted).num_rows == len(expected)
    assert json.loads((sweep / ".plan" / f"{runs['batch_id'].dropna().iloc[0]}.json")
                      .read_text())["members"]  # fmt: skip


def test_a_setting_that_kills_its_batch_worker_costs_only_itself(kitti_dir, tmp_path) -> None:
    """SIGKILL every process computing the ORB batch, then every process computing the ORB
    + zscore setting alone: the batch is run again alone, then a setting at a time, and only
    that setting is recorded as failed."""
    args = ["descriptor=brief,orb", "keypoint_filter=none,zscore", "dataset.last=2",
            "sweep_name=crash", "hydra.launcher.n_jobs=2"]  # fmt: skip
    env = {**os.environ, "TTC_RESULTS_DIR": str(tmp_path / "sweeps"),
           "TTC_CACHE_DIR": str(tmp_path / "cache")}  # fmt: skip
    proc = subprocess.Popen(
        [sys.executable, "-m", "experiments.run", "-m", *args], cwd=PROJECT_ROOT, env=env,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    sweep = tmp_path / "sweeps" / "crash"
    killed = _kill_holders(sweep, proc)
    out, err = proc.communicate(timeout=600)
    assert len(killed) == 3, killed  # the batch in the pool, the batch alone, the setting alone
    assert proc.returncode == 1, err[-3000:]
    assert "sweep incomplete: 1 setting(s) failed" in err
    runs = store.load_runs(sweep)
    failed = runs[runs["status"] == "failed"]
    pairs = list(zip(failed["descriptor"], failed["keypoint_filter"], strict=True))
    assert pairs == [("orb", "zscore")]
    assert "worker process died (SIGKILL(-9))" in failed["message"].iloc[0]
    assert (runs["status"] == "ok").sum() == 3


def _kill_holders(sweep: Path, proc: subprocess.Popen) -> list[int]:
    """SIGKILL the holder of a run lock of the ORB batch, or of the ORB + zscore setting run
    alone, until that setting's record exists."""
    import signal  # noqa: PLC0415
    import time  # noqa: PLC0415

    killed: list[int] = []
    runs_dir = sweep / store.RUNS_DIR
    deadline = time.time() + 400
    while proc.poll() is None and time.time() < deadline:
        for lock in runs_dir.glob("*.lock") if runs_dir.is_dir() else []:
            try:
                holder = json.loads(lock.read_text() or "{}")
            except ValueError:
                continue
            label = holder.get("holder", "")
            doomed = "descriptor=orb" in label and (
                lock.name.startswith("batch-") or "keypoint_filter=zscore" in label
            )
            if doomed and holder["pid"] not in killed:
                if not lock.name.startswith("batch-") and lock.with_suffix(".json").exists():
                    return killed
                try:
                    os.kill(holder["pid"], signal.SIGKILL)
                    killed.append(holder["pid"])
                except ProcessLookupError:
                    pass
        time.sleep(0.01)
    return killed


def test_the_summary_ranks_its_lead_rows_as_the_whole_dataset(two_ways, data_dir) -> None:
    """The end-of-sweep summary reads only the lead rows and the columns the metrics read
    (:func:`experiments.summary.lead_rows.lead_rows`, kept per fragment by the sweep's summary and
    read back here); its ranking is the ranking of every row."""
    from experiments.summary.collect import ranked_runs
    from experiments.summary.lead_rows import lead_rows
    from experiments.summary.references import recording_references
    from ttc.engine.cache import StageCache

    sweep = two_ways["tmp"] / "batched" / "grid"
    frames, runs = store.load_sweep(sweep)
    ok, cache = runs[runs["status"] == "ok"], StageCache(two_ways["tmp"] / "cache")
    (reference,) = recording_references(frames, ok, data_dir, cache).values()
    few = lead_rows(sweep)
    assert len(few) < len(frames) and "git_commit" not in few
    whole = ranked_runs(frames, reference, "camera")
    assert len(whole) == 24
    pd.testing.assert_frame_equal(ranked_runs(few, reference, "camera"), whole)


def test_kept_run_metrics_are_taken_back_only_while_what_they_read_is_unchanged(
    two_ways, data_dir, tmp_path, monkeypatch
) -> None:
    """The summary's run metrics kept per fragment (:mod:`experiments.summary.run_metrics`) are
    :func:`ttc.evaluation.run_metrics` of every lead row each time: read back with no run
    judged again; a new fragment whose stages all came from the cache is judged alone; one
    whose runs computed the keypoints of ``fast`` again (1 s a frame) moves the median computing
    time that the cached rows of ``fast`` look up: the fragments with ``fast`` runs are
    judged again, the others taken as kept; against another reference, every fragment."""
    import shutil

    from experiments.summary.lead_rows import LeadRows
    from experiments.summary.references import recording_references
    from experiments.summary.run_metrics import kept_run_metrics
    from ttc import evaluation as ev
    from ttc.engine.cache import StageCache

    folder = tmp_path / "grid"
    shutil.copytree(two_ways["tmp"] / "batched" / "grid", folder)
    frames, runs = store.load_sweep(folder)
    ok = runs[runs["status"] == "ok"]
    cache = StageCache(two_ways["tmp"] / "cache")
    (reference,) = recording_references(frames, ok, data_dir, cache).values()
    judged: list[str] = []
    real = ev.run_metrics

    def counted(rows: pd.DataFrame, *args, **kwargs) -> pd.DataFrame:
        judged.extend(rows["run_id"].unique())
        return real(rows, *args, **kwargs)

    def summary(against: pd.DataFrame = reference) -> pd.DataFrame:
        judged.clear()
        lead = LeadRows(folder)
        got = kept_run_metrics(lead, against)
        pd.testing.assert_frame_equal(got, real(lead.frame(), against))
        return got.set_index("run_id")

    def add(run_ids: list[str], **columns) -> None:
        """New runs: a fast run's rows, every stage loaded from the cache but ``columns``."""
        base = frames[frames["run_id"] == ok.loc[ok["detector"] == "fast", "run_id"].iloc[0]]
        cached = {f"cached_{s}": True for s in ("objects", "lidar", "keypoints", "descriptors",
                                                 "matches")}  # fmt: skip
        rows = pd.concat([base.assign(run_id=r, **{**cached, **columns}) for r in run_ids])
        records = [{"run_id": r, "status": "ok", "n_rows": len(base)} for r in run_ids]
        store.save_batch(folder, f"batch-{run_ids[0]}", records, rows)

    monkeypatch.setattr(ev, "run_metrics", counted)
    summary()
    assert summary() is not None and judged == []
    loaded = "a" * 16
    add([loaded], ms_keypoints=0.5)  # loaded from the cache in 0.5 ms
    before = summary()
    assert judged == [loaded]
    fast = set(ok.loc[ok["detector"] == "fast", "run_id"])
    computed = [f"c{i:015d}" for i in range(len(fast) + 1)]  # more than the fast runs
    add(computed, cached_keypoints=False, ms_keypoints=1000.0)
    after = summary()
    assert set(judged) == fast | {loaded, *computed}  # the akaze fragments taken as kept
    moved = after.loc[loaded, "ms_compute_per_frame"] - before.loc[loaded, "ms_compute_per_frame"]
    assert moved > 0  # the kept value would have been wrong
    # the oldest kept file (stale copies of the fast fragments) read first: still valid
    kept = sorted(
        (folder / ".summary").glob("metrics-*.parquet"), key=lambda p: p.stat().st_mtime_ns
    )
    assert len(kept) >= 2
    for i, path in enumerate(kept):
        path.rename(path.with_name(f"metrics-{i:04d}.parquet"))
    summary()
    assert judged == []
    summary(reference.assign(ttc_ref_s=reference["ttc_ref_s"] * 1.01))
    assert set(judged) == set(after.index)


def test_a_batch_is_the_settings_equal_but_on_the_free_axes() -> None:
    """:func:`experiments.sweep.plan.batch_key`: settings whose entries are equal but on
    :data:`~experiments.sweep.plan.BATCH_FREE_AXES` share a key, whether their entries are
    one object or equal copies (the memo is by object), in any key order; a different value
    elsewhere or a missing entry does not."""
    import copy

    from experiments.sweep.plan import BATCH_FREE_AXES, batch_key

    free = sorted(BATCH_FREE_AXES)[0]
    detector = {"name": "orb", "n": 500}
    base = {"detector": detector, "dataset": {"last": 18}, free: {"name": "a"}}
    memo: dict = {}
    key = batch_key(base, memo)
    assert batch_key({**base, free: {"name": "b"}}, memo) == key
    assert batch_key(copy.deepcopy(base), memo) == key
    assert batch_key(dict(reversed(list(base.items()))), {}) == key
    assert batch_key({**base, "detector": {"name": "orb", "n": 501}}, memo) != key
    assert batch_key({k: v for k, v in base.items() if k != "dataset"}, memo) != key
