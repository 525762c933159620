"""The end-of-sweep summary ranks on the sensor whose axes vary."""

from __future__ import annotations

import importlib

import pandas as pd
import pytest

from experiments.summary.collect import ranked_sensor


def runs_varying(**axes: list[str]) -> pd.DataFrame:
    base = {"detector": "fast", "descriptor": "brief", "lidar_ttc": "median", "camera_ttc": "x"}
    n = max(len(v) for v in axes.values())
    return pd.DataFrame([{**base, **{k: v[i % len(v)] for k, v in axes.items()}} for i in range(n)])


def test_a_lidar_estimator_sweep_ranks_on_the_lidar() -> None:
    assert ranked_sensor(runs_varying(lidar_ttc=["median", "closest", "cluster"])) == "lidar"


def test_camera_axes_rank_on_the_camera() -> None:
    assert ranked_sensor(runs_varying(detector=["fast", "orb"])) == "camera"
    both = runs_varying(detector=["fast", "orb"], lidar_ttc=["median", "closest"])
    assert ranked_sensor(both) == "camera"
    assert ranked_sensor(runs_varying(detector=["fast"])) == "camera"  # one setting


def test_a_fusion_sweep_ranks_on_the_fused_ttc() -> None:
    runs = runs_varying(fusion=["none", "kalman_cv", "kalman_ca"], lidar_ttc=["median"])
    assert ranked_sensor(runs) == "fused"
    assert ranked_sensor(runs_varying(fusion=["none", "kalman_cv"], detector=["fast", "orb"])) == (
        "camera"
    )


def test_lead_rows_kept_per_fragment_are_the_whole_sweeps(tmp_path) -> None:
    """The summary's rows (a fragment at a time, without the columns no metric reads, kept
    in one file of ``.summary/`` and read back by the next summary) are
    :func:`ttc.evaluation.lead_rows` of all rows: a pair without a lead row keeps its first
    row, blanked."""
    import numpy as np

    from experiments import store
    from experiments.summary import lead_rows
    from ttc import evaluation as ev

    rows = pd.DataFrame(
        {
            "run_id": ["a", "a", "a", "a", "b", "b", "b", "b"],
            "frame": [1, 1, 2, 2, 1, 2, 2, 2],
            "is_lead": [False, True, False, False, True, False, False, True],
            "ttc_camera": [9.0, 1.0, 8.0, 7.0, 2.0, 6.0, 5.0, 3.0],
            "git_commit": ["c0ffee"] * 8,  # read by no metric: left unread
        }
    )
    for run_id, own in rows.groupby("run_id"):
        store.save_run(tmp_path, {"run_id": run_id, "status": "ok", "n_rows": 4}, own)
    whole = ev.lead_rows(rows.drop(columns="git_commit"))
    computed = lead_rows.lead_rows(tmp_path)
    (kept_file,) = (tmp_path / lead_rows.CACHE_DIR).glob("lead-*.parquet")  # both fragments
    written = kept_file.stat().st_mtime_ns
    kept = lead_rows.lead_rows(tmp_path)
    assert list((tmp_path / lead_rows.CACHE_DIR).glob("lead-*.parquet")) == [kept_file]
    assert kept_file.stat().st_mtime_ns == written  # read, not written again
    for got in (computed, kept):
        got = got.sort_values(["run_id", "frame"], ignore_index=True)
        pd.testing.assert_frame_equal(
            got, whole.sort_values(["run_id", "frame"], ignore_index=True)
        )
    np.testing.assert_array_equal(kept["ttc_camera"], [1.0, np.nan, 2.0, 3.0])  # a/2: no lead
    # a run recomputed into another fragment: the old fragment's kept rows are not used
    redo = rows[rows["run_id"] == "a"].assign(ttc_camera=[9.0, 4.0, 8.0, 7.0])
    store.save_batch(tmp_path, "batch-x", [{"run_id": "a", "status": "ok", "n_rows": 4}], redo)
    again = lead_rows.lead_rows(tmp_path)
    np.testing.assert_array_equal(again["ttc_camera"], [4.0, np.nan, 2.0, 3.0])
    assert len(list((tmp_path / lead_rows.CACHE_DIR).glob("lead-*.parquet"))) == 2


def spec_lead_rows(frames: pd.DataFrame) -> pd.DataFrame:
    """The lead-row rule as first written (a stable sort on run, frame and the flag, the
    first row of each pair), the definition :func:`ttc.evaluation.lead_rows` must keep."""
    import numpy as np

    order = frames.sort_values(
        ["run_id", "frame", "is_lead"], ascending=[True, True, False], kind="stable"
    )
    lead = order.drop_duplicates(["run_id", "frame"]).reset_index(drop=True)
    blanked = ["ttc_camera", "ttc_lidar", "ttc_fused", "camera_ratio", "fused_ratio", "d_prev",
               "d_curr"]  # fmt: skip
    lead.loc[~lead["is_lead"].astype(bool), [c for c in blanked if c in lead]] = np.nan
    return lead


def random_rows(seed: int, unknown_flags: bool) -> pd.DataFrame:
    """Rows of a few runs in shuffled order: pairs with several lead rows, none, or (with
    ``unknown_flags``) flags of unknown value (None); NaN estimates; an integer column."""
    import numpy as np

    rng = np.random.default_rng(seed)
    n = 400
    flags = rng.random(n) < 0.3
    is_lead = flags.astype(object) if unknown_flags else flags
    if unknown_flags:
        is_lead[rng.random(n) < 0.2] = None
    ttc = rng.normal(8.0, 3.0, n)
    ttc[rng.random(n) < 0.1] = np.nan
    return pd.DataFrame(
        {
            "run_id": rng.choice([f"{i:016x}" for i in rng.integers(0, 2**60, 7)], n),
            "frame": rng.integers(0, 12, n),
            "is_lead": is_lead,
            "ttc_camera": ttc,
            "d_prev": rng.normal(10.0, 1.0, n),
            "n_matches": rng.integers(0, 500, n),
            "detector": rng.choice(["fast", "orb"], n),
        }
    )


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("unknown_flags", [False, True])
def test_lead_rows_keep_each_pairs_first_lead_row(seed: int, unknown_flags: bool) -> None:
    """:func:`ttc.evaluation.lead_rows` (positions from three columns, then one take) is the
    rule's first definition row for row, blanking included; so is the Arrow path of the
    summary's kept lead rows (:func:`experiments.summary.lead_rows.lead_table`) as pandas, with
    nullable integer columns and NaN beside null estimates."""
    import pyarrow as pa

    from experiments.summary.lead_rows import lead_table
    from ttc import evaluation as ev

    rows = random_rows(seed, unknown_flags)
    expected = spec_lead_rows(rows)
    assert (~expected["is_lead"].astype(bool)).any() and expected["is_lead"].astype(bool).any()
    pd.testing.assert_frame_equal(ev.lead_rows(rows), expected)
    table = pa.Table.from_pandas(rows, preserve_index=False)
    gaps = pa.array(rows["n_matches"].where(rows["frame"] != 3).astype("Int64"), pa.int64())
    table = table.set_column(table.schema.get_field_index("n_matches"), "n_matches", gaps)
    null_ttc = pa.array(rows["ttc_camera"].to_numpy(), mask=(rows["frame"] == 5).to_numpy())
    table = table.set_column(table.schema.get_field_index("ttc_camera"), "ttc_camera", null_ttc)
    pd.testing.assert_frame_equal(lead_table(table).to_pandas(), ev.lead_rows(table.to_pandas()))
    assert lead_table(table.slice(0, 0)).num_rows == 0


def test_kept_lead_rows_unreadable_duplicated_or_many_files(tmp_path, monkeypatch) -> None:
    """A kept file that cannot be read is left out (its fragments computed again); a
    fragment kept in two files is taken once; past ``MAX_KEPT_FILES`` files the rows used
    are kept as one file and the others removed."""
    from experiments import store
    from experiments.summary import kept_tables, lead_rows

    def add_run(run_id: str) -> None:
        rows = pd.DataFrame({"run_id": run_id, "frame": [1, 2], "is_lead": True,
                             "ttc_camera": [1.0, 2.0]})  # fmt: skip
        store.save_run(tmp_path, {"run_id": run_id, "status": "ok", "n_rows": 2}, rows)

    folder = tmp_path / lead_rows.CACHE_DIR
    add_run("r0")
    first = lead_rows.lead_rows(tmp_path)
    (kept,) = folder.glob("lead-*.parquet")
    copy = folder / "lead-copy.parquet"  # the same fragment in a second file
    copy.write_bytes(kept.read_bytes())
    pd.testing.assert_frame_equal(lead_rows.lead_rows(tmp_path), first)
    kept.write_bytes(b"PAR1 not a parquet file")
    copy.unlink()
    pd.testing.assert_frame_equal(lead_rows.lead_rows(tmp_path), first)  # computed again
    monkeypatch.setattr(kept_tables, "MAX_KEPT_FILES", 3)
    for i in range(1, 4):  # one kept file per summary that computed something
        add_run(f"r{i}")
        rows = lead_rows.lead_rows(tmp_path)
    assert sorted(rows["run_id"].unique()) == ["r0", "r1", "r2", "r3"]
    assert len(rows) == 8
    (whole,) = folder.glob("lead-*.parquet")  # 4 files -> 1
    pd.testing.assert_frame_equal(lead_rows.lead_rows(tmp_path), rows)
    assert list(folder.glob("lead-*.parquet")) == [whole]


def _sweep_of_runs(folder, n_runs: int) -> None:
    """A sweep folder of ``n_runs`` stored runs (three rows each, two detectors)."""
    from experiments import store

    for i in range(n_runs):
        rows = pd.DataFrame(
            {
                "run_id": f"r{i:03d}",
                "detector": ["fast", "orb"][i % 2],
                "descriptor": "brief",
                "frame": [1, 2, 3],
                "ttc_camera": [10.0 + i, 9.0 + i, 8.0 + i],
            }
        )
        store.save_run(folder, {"run_id": f"r{i:03d}", "status": "ok", "n_rows": 3}, rows)


def test_the_read_ahead_changes_no_row_and_hides_no_corrupt_file(tmp_path, monkeypatch) -> None:
    """Fragments read by threads ahead give the same rows, in the same order, as reading them
    one at a time; a corrupt fragment in the middle is named."""
    from experiments import store

    dataset = importlib.import_module("experiments.store.dataset")
    _sweep_of_runs(tmp_path, 30)
    ahead = store.read_table(tmp_path)
    monkeypatch.setattr(dataset, "READ_THREADS", 1)
    assert store.read_table(tmp_path).equals(ahead)
    assert ahead.column("run_id").to_pylist() == [f"r{i:03d}" for i in range(30) for _ in "abc"]

    monkeypatch.undo()
    bad = tmp_path / store.RUNS_DIR / "r017.parquet"
    bad.write_bytes(bad.read_bytes()[:40])
    with pytest.raises(store.StoreError, match="r017.parquet.*corrupt"):
        store.read_table(tmp_path)


def test_fragment_schemas_are_kept_and_a_new_type_still_unifies(tmp_path, monkeypatch) -> None:
    """The summary reads a fragment's schema once (kept by its SHA-256); a later fragment
    whose column has a wider type still promotes the kept rows' type; an unreadable schemas
    file is read again from the fragments."""
    from pathlib import Path

    from experiments import store
    from experiments.store import dataset
    from experiments.summary import lead_rows

    reads = []
    real = dataset.pq.read_schema

    def counted(path):
        if "runs" in Path(path).parts:  # a rows fragment's, not a kept file's
            reads.append(path)
        return real(path)

    monkeypatch.setattr(dataset.pq, "read_schema", counted)

    def add_run(run_id: str, ttc) -> None:
        rows = pd.DataFrame({"run_id": run_id, "frame": [1, 2], "is_lead": True, "ttc_camera": ttc})
        store.save_run(tmp_path, {"run_id": run_id, "status": "ok", "n_rows": 2}, rows)

    add_run("r0", [1, 2])  # int64
    lead_rows.lead_rows(tmp_path)
    assert len(reads) == 1
    add_run("r1", [1.5, 2.5])  # float64: the unified type
    rows = lead_rows.lead_rows(tmp_path)
    assert len(reads) == 2  # r1's only
    assert rows["ttc_camera"].tolist() == [1.0, 2.0, 1.5, 2.5]
    (tmp_path / lead_rows.CACHE_DIR / lead_rows.SCHEMAS_FILE).write_bytes(b"not a pickle")
    pd.testing.assert_frame_equal(lead_rows.lead_rows(tmp_path), rows)
    assert len(reads) == 4


def test_kept_lead_rows_come_back_in_the_datasets_fragment_order() -> None:
    """:func:`experiments.summary.kept_tables.in_fragment_order` (slices of the runs of equal keys) is
    the stable sort of the rows by their key's position, also where a key's rows are split
    into several runs, on random tables."""
    import numpy as np
    import pyarrow as pa

    from experiments.summary import kept_tables

    rng = np.random.default_rng(7)
    for _ in range(100):
        keys = [f"f{i}" for i in range(rng.integers(1, 7))]
        n = int(rng.integers(1, 50))
        names = rng.choice(keys, size=n)
        table = pa.table({kept_tables.FRAGMENT: names, "row": np.arange(n),
                          "text": [f"r{i}" for i in range(n)]})  # fmt: skip
        order = list(rng.permutation(keys))
        expected = np.argsort([order.index(k) for k in names], kind="stable")
        got = kept_tables.in_fragment_order(table, order)
        np.testing.assert_array_equal(got["row"].to_numpy(), expected)
        assert got["text"].to_pylist() == [f"r{i}" for i in expected]


def _summed(counts: dict[str, pd.DataFrame]) -> dict[str, pd.DataFrame]:
    """Stage-time counts as their readers see them: each (inputs, frame, ms)'s rows summed."""
    out = {}
    for name, table in counts.items():
        keys = [c for c in table.columns if c != "n"]
        out[name] = table.groupby(keys, dropna=False, sort=True)["n"].sum().reset_index()
    return out


def test_kept_counts_are_every_lead_rows_counts(tmp_path, monkeypatch) -> None:
    """The summary's computing-time counts kept (:func:`experiments.summary.run_metrics.lead_counts`)
    sum up as the counts of every lead row: a new fragment's rows alone counted; a run
    recomputed into another fragment, or a damaged file, counted again from every row."""
    from experiments import store
    from experiments.summary import run_metrics
    from experiments.summary.lead_rows import LeadRows
    from ttc.evaluation import stage_times

    def run(run_id: str, detector: str, ms: list[float], cached: list[bool]) -> pd.DataFrame:
        return pd.DataFrame({"run_id": run_id, "detector": detector, "frame": [1, 2, 3],
                             "is_lead": True, "ttc_camera": [9.0, 8.0, 7.0],
                             "ms_keypoints": ms, "cached_keypoints": cached})  # fmt: skip

    def save(batch: str, *runs: pd.DataFrame) -> None:
        records = [{"run_id": r["run_id"].iloc[0], "status": "ok", "n_rows": 3} for r in runs]
        store.save_batch(tmp_path, batch, records, pd.concat(runs, ignore_index=True))

    counted: list[int] = []
    real = stage_times.stage_time_counts
    monkeypatch.setattr(
        stage_times, "stage_time_counts", lambda f: counted.append(len(f)) or real(f)
    )

    def check() -> None:
        lead = LeadRows(tmp_path)
        whole = real(lead.frame(columns=run_metrics._count_columns(lead)))
        counted.clear()
        got = run_metrics.lead_counts(lead)
        for name, table in _summed(whole).items():
            pd.testing.assert_frame_equal(_summed(got)[name], table)

    save("batch-a", run("a", "fast", [5.0, 6.0, 7.0], [False] * 3),
         run("b", "orb", [1.0, 1.0, 2.0], [True, False, False]))  # fmt: skip
    check()
    assert counted == [6]
    save("batch-b", run("c", "fast", [9.0, 9.0, 9.0], [False] * 3))
    check()
    assert counted == [3]  # the new fragment alone
    check()
    assert counted == []  # nothing new
    save("batch-c", run("a", "fast", [1.0, 1.0, 1.0], [False] * 3))  # a recomputed
    check()
    assert counted == [9]  # every live lead row: a's old rows no longer counted
    (tmp_path / ".summary" / run_metrics.COUNTS_FILE).write_bytes(b"damaged")
    check()
    assert counted == [9]
