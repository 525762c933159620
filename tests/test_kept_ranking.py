"""The summary's kept ranking (:mod:`experiments.summary.kept_ranking`): each invocation's
ranking of a real sweep folder (the keys kept by the one before, the new runs ranked and
merged) is :func:`ttc.evaluation.rank_runs` of every run's metrics worked out from scratch;
the merge on synthetic keys; stale kept keys are not taken."""

from __future__ import annotations

import io
import shutil
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments import store
from experiments.summary import collect, kept_ranking, kept_tables
from experiments.summary.kept_ranking import TIME, key_columns, merged_ranking, ranking_keys
from experiments.summary.kept_tables import CACHE_DIR, FRAGMENT
from experiments.summary.lead_rows import LeadRows
from tests.test_report import run_module
from ttc import evaluation as ev

#: Three invocations into one sweep folder: the second and third add runs.
INVOCATIONS = [
    ["-m", "detector=fast,orb", "descriptor=brief,brisk", "dataset.last=3", "sweep_name=inv"],
    ["-m", "detector=fast,orb", "descriptor=brief,brisk", "dataset.last=3", "sweep_name=inv",
     "keypoint_filter=zscore"],
    ["-m", "detector=fast,orb,shitomasi", "descriptor=brief,brisk", "dataset.last=3",
     "sweep_name=inv", "keypoint_filter=none,zscore"],
]  # fmt: skip
#: Columns of the kept keys compared with a ranking from scratch.
KEYS = ["run_id", *key_columns("camera"), "rank"]


@pytest.fixture(scope="module")
def invocations(tmp_path_factory) -> tuple[Path, list[Path], list[str]]:
    """(root, the sweep folder after each invocation, each invocation's printed output)."""
    root = tmp_path_factory.mktemp("kept_ranking")
    sweep, after, printed = root / "sweeps" / "inv", [], []
    for i, args in enumerate(INVOCATIONS):
        done = run_module("experiments.run", args, root)
        assert done.returncode == 0, done.stderr[-3000:]
        after.append(root / f"after{i}")
        shutil.copytree(sweep, after[-1])
        printed.append(done.stdout)
    return root, after, printed


def _reference(root: Path, sweep: Path, data_dir: Path) -> pd.DataFrame:
    """The recording's reference the summary judges the sweep's runs against."""
    frames, runs = store.load_sweep(sweep)
    (reference,) = collect.sweep_references(frames, runs, data_dir, root / "cache").values()
    return reference


def _from_scratch(sweep: Path, reference: pd.DataFrame) -> pd.DataFrame:
    """:func:`ttc.evaluation.rank_runs` of every run's metrics, from all lead rows (a copy of
    the sweep without ``.summary/``), with the kept key columns."""
    copy = sweep.parent / f"{sweep.name}-scratch"
    shutil.rmtree(copy, ignore_errors=True)
    shutil.copytree(sweep, copy, ignore=shutil.ignore_patterns(CACHE_DIR))
    ranked = ev.rank_runs(ev.run_metrics(LeadRows(copy).frame(), reference), "camera")
    return ranked.assign(**{TIME: ev.ranking_time(ranked)})


def _printed_table(ranked: pd.DataFrame, top: int = 5) -> str:
    """The summary's best table as :func:`experiments.summary.collect.summarise_sweep` printed
    it before the ranking was kept: the head of the summary's columns of every run."""
    columns = [*collect.summary_columns("camera"), "ms_per_frame"]
    table = ranked[[c for c in columns if c in ranked]]
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        return table.head(top).to_string(index=False, float_format="%.3g")


def _kept_file(sweep: Path) -> pd.DataFrame:
    """The one kept ranking file of ``sweep``."""
    (path,) = (sweep / CACHE_DIR).glob(f"{kept_ranking.KIND}-*.parquet")
    return pd.read_parquet(path)


@pytest.mark.slow
def test_each_invocations_kept_ranking_is_the_ranking_from_scratch(invocations, data_dir) -> None:
    """After each invocation the ranking its summary kept (the earlier keys merged with the
    new runs') is the ranking of every run's metrics from scratch, every key exact, and the
    best table it printed is the one printed from every run's metrics."""
    root, after, printed = invocations
    reference = _reference(root, after[0], data_dir)
    sizes = []
    for sweep, out in zip(after, printed, strict=True):
        whole = _from_scratch(sweep, reference)
        kept = _kept_file(sweep).sort_values("rank", ignore_index=True)
        pd.testing.assert_frame_equal(kept[KEYS], whole[KEYS], check_exact=True)
        assert _printed_table(whole) in out
        sizes.append(len(whole))
    assert sizes == [4, 8, 16]


@pytest.mark.slow
def test_a_summary_judges_only_the_new_runs_and_merges_them(
    invocations, data_dir, monkeypatch
) -> None:
    """An invocation's summary with the keys the one before kept: only the new runs judged,
    the ranking and the best runs' full metrics as from scratch, the output the same; a
    summary again takes the kept ranking as it is (its file not written again)."""
    root, after, _ = invocations
    reference = _reference(root, after[0], data_dir)
    judged: list[str] = []
    real = ev.run_metrics

    def counted(rows: pd.DataFrame, *args, **kwargs) -> pd.DataFrame:
        judged.extend(rows["run_id"].unique())
        return real(rows, *args, **kwargs)

    for i in (1, 2):
        sweep = root / f"merge{i}"
        shutil.copytree(after[i], sweep, ignore=shutil.ignore_patterns(CACHE_DIR))
        shutil.copytree(after[i - 1] / CACHE_DIR, sweep / CACHE_DIR)
        whole = _from_scratch(sweep, reference)
        before = set(store.load_runs(after[i - 1])["run_id"])
        monkeypatch.setattr(ev, "run_metrics", counted)
        judged.clear()
        n = len(whole)  # every run's full metrics: the new ones judged, the others read
        ranked, best = kept_ranking.kept_ranking(LeadRows(sweep), reference, "camera", n)
        assert sorted(judged) == sorted(set(whole["run_id"]) - before)  # the new runs alone
        pd.testing.assert_frame_equal(ranked[KEYS], whole[KEYS], check_exact=True)
        # the kept metrics' means may differ in the last bit (judged a fragment at a time)
        pd.testing.assert_frame_equal(best, whole.drop(columns=[TIME, "rank"]))
        judged.clear()
        (path,) = (sweep / CACHE_DIR).glob(f"{kept_ranking.KIND}-*.parquet")
        written = path.stat().st_mtime_ns
        again, best = kept_ranking.kept_ranking(LeadRows(sweep), reference, "camera", 5)
        assert judged == [] and path.stat().st_mtime_ns == written
        pd.testing.assert_frame_equal(again[KEYS], whole[KEYS], check_exact=True)
        pd.testing.assert_frame_equal(best, whole.drop(columns=[TIME, "rank"]).head(5))
        monkeypatch.undo()
        out = io.StringIO()
        with redirect_stdout(out):
            table = collect.summarise_sweep(sweep, data_dir=data_dir, cache_dir=root / "cache")
        assert _printed_table(whole) in out.getvalue()
        pd.testing.assert_frame_equal(table, collect._ranking(whole, "camera").head(5))


@pytest.mark.slow
def test_stale_kept_keys_are_not_taken(invocations, data_dir, monkeypatch) -> None:
    """Kept keys whose runs look up computing times that moved (new runs computed the
    keypoints of ``fast`` again, at 1 s a frame) are judged again: the ``fast`` runs, the
    ``orb`` runs taken as kept; a run recomputed into another fragment is judged again;
    against another reference every run is. Each ranking is the one from scratch."""
    root, after, _ = invocations
    reference = _reference(root, after[0], data_dir)
    sweep = root / "stale"
    shutil.copytree(after[0], sweep)
    kept = _kept_file(sweep).set_index("run_id")
    frames, runs = store.load_sweep(sweep)
    fast = sorted(runs.loc[runs["detector"] == "fast", "run_id"])
    base = frames[frames["run_id"] == fast[0]]
    computed = [f"c{i:015d}" for i in range(len(fast) + 1)]  # outnumber the fast runs' times
    rows = pd.concat([base.assign(run_id=r, cached_keypoints=False, ms_keypoints=1000.0)
                      for r in computed])  # fmt: skip
    records = [{"run_id": r, "status": "ok", "n_rows": len(base)} for r in computed]
    store.save_batch(sweep, "batch-computed", records, rows)
    judged: list[str] = []
    real = ev.run_metrics

    def counted(rows: pd.DataFrame, *args, **kwargs) -> pd.DataFrame:
        judged.extend(rows["run_id"].unique())
        return real(rows, *args, **kwargs)

    def check(against: pd.DataFrame = reference) -> pd.DataFrame:
        judged.clear()
        monkeypatch.setattr(ev, "run_metrics", counted)
        ranked, _ = kept_ranking.kept_ranking(LeadRows(sweep), against, "camera", 5)
        monkeypatch.undo()
        whole = _from_scratch(sweep, against)
        pd.testing.assert_frame_equal(ranked[KEYS], whole[KEYS], check_exact=True)
        return ranked.set_index("run_id")

    ranked = check()
    assert sorted(judged) == sorted([*fast, *computed])  # the orb runs' keys taken as kept
    moved = ranked.loc[fast, TIME] - kept.loc[fast, TIME]
    assert (moved >= 0).all() and (moved > 0).any()  # a kept key would have been wrong
    redo = frames[frames["run_id"] == fast[0]]
    store.save_batch(sweep, "batch-redo", [{"run_id": fast[0], "status": "ok",
                                            "n_rows": len(redo)}], redo)  # fmt: skip
    check()
    assert judged == [fast[0]]  # its old fragment no longer live
    check(reference.assign(ttc_ref_s=reference["ttc_ref_s"] * 1.01))
    assert sorted(judged) == sorted(ranked.index)
    metrics_files = list((sweep / CACHE_DIR).glob("metrics-*.parquet"))
    assert len(metrics_files) > 1
    monkeypatch.setattr(kept_tables, "MAX_KEPT_FILES", 1)  # every run's kept metrics as one file
    check()
    assert judged == [] and len(list((sweep / CACHE_DIR).glob("metrics-*.parquet"))) == 1


def test_merged_keys_rank_as_all_runs_do() -> None:
    """:func:`~experiments.summary.kept_ranking.merged_ranking` of kept keys (ranked) and new
    ones (merged in by binary search) is :func:`ttc.evaluation.rank_runs` of all runs: ties
    broken by the time, then by ``run_id``; a NaN key sorts last within its key; a NaN
    computing time falls back to ``ms_per_frame``. A hand-checked order, then random tables
    with many ties, cut anywhere."""
    invalid, mid, _ = key_columns("camera")
    nan = np.nan
    hand = pd.DataFrame({
        "run_id": ["e", "d", "c", "b", "a", "f", "g"],
        invalid: [0.0, 0.0, 0.0, 0.0, nan, 0.5, 0.0],
        mid: [2.0, 1.0, 1.0, 1.0, 0.0, 0.0, nan],
        "ms_compute_per_frame": [1.0, 5.0, nan, 5.0, 1.0, 1.0, 1.0],
        "ms_per_frame": [9.0, 9.0, 3.0, 9.0, 9.0, 9.0, 9.0],
    })  # fmt: skip
    keys = ranking_keys(hand, "camera")
    merged = merged_ranking(merged_ranking(keys.iloc[:0], keys.iloc[:3], "camera"),
                            keys.iloc[3:], "camera")  # fmt: skip
    assert merged["run_id"].tolist() == ["c", "b", "d", "e", "g", "f", "a"]
    assert merged["rank"].tolist() == list(range(1, 8))
    rng = np.random.default_rng(51)
    for _ in range(200):
        n = int(rng.integers(1, 40))
        metrics = pd.DataFrame({
            "run_id": [f"r{i}" for i in rng.choice(1000, n, replace=False)],  # r10 < r9
            invalid: rng.choice([0.0, 0.25, nan], n),
            mid: rng.choice([1.0, 2.0, nan, np.inf], n),  # NaN ties with +inf
            "ms_compute_per_frame": rng.choice([3.0, 4.0, nan], n),
            "ms_per_frame": rng.choice([3.0, 5.0], n),
        })  # fmt: skip
        whole = ev.rank_runs(metrics, "camera")
        cut = int(rng.integers(0, n + 1))
        keys = ranking_keys(metrics, "camera")
        earlier = merged_ranking(keys.iloc[:0], keys.iloc[:cut], "camera")  # as kept: ranked
        merged = merged_ranking(earlier, keys.iloc[cut:], "camera")
        assert merged["run_id"].tolist() == whole["run_id"].tolist()
        assert merged["rank"].tolist() == whole["rank"].tolist()
        np.testing.assert_array_equal(merged[TIME], ev.ranking_time(whole))
    assert FRAGMENT not in merged
