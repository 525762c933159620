"""Several drives in one sweep: ``-m dataset=kitti_raw dataset.drive=0052,0040`` over two
made-up drives (the shared frames 0–7, and 40–77 renumbered from 0: the stop and the
truncated last scan) merges into one sweep;
the report writes each drive's FP.5/FP.6 and the rankings per drive and pooled."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments import store
from experiments.report.report_command import build_report
from tests.test_kitti_raw import make_drive
from tests.test_sweep import hydra_run
from ttc import evaluation as ev

DRIVES = {"0052": list(range(8)), "0040": list(range(40, 78))}
NAMES = [f"2011_09_26_drive_{d}" for d in ("0040", "0052")]  # ids: CSVs and folders
SHOWN = ["drive 0040", "drive 0052"]  # what the pages call them


def test_stratified_blocks_stay_within_their_drive() -> None:
    strata = np.array(["a"] * 5 + ["b"] * 7)
    draws = ev.block_draws(12, 200, 3, np.random.default_rng(0), strata)
    assert draws.shape == (200, 12)
    assert (draws[:, :5] < 5).all() and (draws[:, 5:] >= 5).all()  # each drive's own frames
    blocks = draws[:, 5:].reshape(200, -1)[:, :6].reshape(200, 2, 3)  # whole blocks of b
    assert (np.diff(blocks, axis=2) == 1).all()  # consecutive frames, never across drives


@pytest.fixture(scope="module")
def two_drive_sweep(kitti_dir, tmp_path_factory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("drives")
    root = tmp / "data"
    for drive, frames in DRIVES.items():
        make_drive(kitti_dir, root, drive, frames)
    args = ["-m", "dataset=kitti_raw", f"dataset.root={root}", "dataset.drive=0052,0040",
            "lidar_ttc=median,closest", "sweep_name=drives"]  # fmt: skip
    result = hydra_run(args, tmp)
    assert result.returncode == 0, result.stderr[-3000:]
    return tmp / "sweeps" / "drives", root


@pytest.mark.slow  # ~30 s: a Hydra multirun in a subprocess, two drive reports
def test_a_two_drive_sweep_merges_and_reports_per_drive_and_pooled(two_drive_sweep, tmp_path):
    sweep_dir, root = two_drive_sweep
    runs = store.load_runs(sweep_dir)
    frames = store.load_sweep(sweep_dir)[0]
    assert len(runs) == 4 and (runs["status"] == "ok").all() and runs["run_id"].is_unique
    assert set(runs["dataset"]) == {"kitti_raw"}
    assert len(frames[frames["is_lead"]]) == 2 * (7 + 37)

    build_report([sweep_dir], tmp_path, root, sweep_dir.parent.parent / "cache",
                 pictures=False, html=False, log=lambda _: None)  # fmt: skip
    metrics = pd.read_parquet(sweep_dir / "metrics.parquet")
    assert sorted(metrics["drive"]) == sorted(NAMES * 2)  # each run against its own drive
    for name in NAMES:
        assert (tmp_path / name / "fp5_lidar.md").is_file()
        assert (tmp_path / name / "fp6_camera.md").is_file()
        assert (tmp_path / name / "reference.csv").is_file()

    table = pd.read_csv(tmp_path / "drives_ranking.csv")
    lidar = table[table["sensor"] == "lidar"]
    assert sorted(lidar["drive"].unique()) == sorted([ev.POOLED, *NAMES])
    assert (lidar.groupby("drive").size() == 2).all()  # two settings on every drive
    pooled = lidar[lidar["drive"] == ev.POOLED].set_index("setting")
    per_drive = lidar[lidar["drive"] != ev.POOLED]
    n_frames = per_drive.groupby("drive")["n_frames"].first()
    assert n_frames.to_dict() == {NAMES[0]: 37, NAMES[1]: 7}
    assert (pooled["n_frames"] == 44).all()
    # pooled rates are over the frames of both drives: their frame-weighted mean
    weighted = (per_drive["lidar_invalid_rate"] * per_drive["n_frames"]).groupby(
        per_drive["setting"]
    ).sum() / 44
    np.testing.assert_allclose(pooled["lidar_invalid_rate"], weighted.loc[pooled.index])
    assert ((pooled["rank_lo"] <= pooled["rank"]) & (pooled["rank"] <= pooled["rank_hi"])).all()
    assert set(pooled["lidar_ttc"]) == {"median", "closest"}
    text = (tmp_path / "drives.md").read_text()
    assert "## lidar: pooled" in text and f"## camera: {SHOWN[1]}" in text


@pytest.mark.slow  # uses the two-drive sweep above
def test_the_sweep_summary_and_tracking_judge_each_run_on_its_own_drive(
    two_drive_sweep, capsys
) -> None:
    """The end-of-sweep summary ranks a sweep over two drives pooled over both (it fell back
    to the interim camera-vs-lidar score), and the MLflow metrics judge each run against its
    own drive's reference (they failed: one reference for two recordings)."""
    from experiments.summary.collect import summarise_sweep
    from experiments.summary.recordings import recording_of
    from experiments.summary.references import sequence_reference
    from experiments.sweep.tracking import _metrics_of
    from ttc.engine.cache import StageCache

    sweep_dir, root = two_drive_sweep
    cache_dir = sweep_dir.parent.parent / "cache"
    frames, runs = store.load_sweep(sweep_dir)
    recording = recording_of(runs)
    per_drive = []
    for sequence in sorted(set(recording)):  # each drive alone, against its own reference
        mine = frames[frames["run_id"].isin(recording.index[recording == sequence])]
        reference = sequence_reference(root / sequence, StageCache(cache_dir))
        per_drive.append(ev.run_metrics(mine, reference))
    per_drive = pd.concat(per_drive, ignore_index=True).set_index("run_id")

    tracked = _metrics_of(frames, runs, root, cache_dir).set_index("run_id")
    assert sorted(tracked.index) == sorted(runs["run_id"])
    assert sorted(tracked["n_frames"]) == [7, 7, 37, 37]
    pd.testing.assert_series_equal(
        tracked["lidar_invalid_rate"].sort_index(), per_drive["lidar_invalid_rate"].sort_index()
    )

    table = summarise_sweep(sweep_dir, data_dir=root, cache_dir=cache_dir)
    printed = capsys.readouterr().out
    assert "pooled over 2 recordings" in printed and "interim score" not in printed
    assert "drives.md ranked per drive and pooled" in printed  # what the report will write
    assert len(table) == 2 and (table["n_frames"] == 44).all()
    assert set(table["lidar_ttc"]) == {"median", "closest"}
    for estimator, row in table.set_index("lidar_ttc").iterrows():
        mine = per_drive[per_drive["lidar_ttc"] == estimator]
        weighted = (mine["lidar_invalid_rate"] * mine["n_frames"]).sum() / 44
        assert row["lidar_invalid_rate"] == pytest.approx(weighted)
    assert sorted(table["rank"]) == [1, 2]


@pytest.mark.slow  # uses the two-drive sweep above
def test_without_a_reference_the_summary_ranks_nothing_and_says_why(
    two_drive_sweep, tmp_path, capsys
) -> None:
    """The summary ranks by ttc.evaluation's rule only: a data root without the recordings
    (no reference can be built) gives no ranking and the reason, not a second score."""
    from experiments.summary.collect import summarise_sweep

    sweep_dir, _ = two_drive_sweep
    table = summarise_sweep(sweep_dir, data_dir=tmp_path / "empty", cache_dir=tmp_path / "c")
    printed = capsys.readouterr().out
    assert table.empty
    assert "no ranking: no reference TTC to judge against" in printed
    assert "best " not in printed and "sweep dataset:" in printed


@pytest.mark.slow  # uses the two-drive sweep above
def test_the_cross_recording_page(two_drive_sweep, tmp_path) -> None:
    """recordings.md / .csv / html: each setting's rank per recording equals the drives
    ranking's, Kendall's tau between the two drives' rankings is the one of those ranks. The
    sweep varies only ``lidar_ttc``: the camera ranks one setting per drive (same camera TTC)."""
    from scipy.stats import kendalltau

    sweep_dir, root = two_drive_sweep
    summary = build_report([sweep_dir], tmp_path, root, sweep_dir.parent.parent / "cache",
                           pictures=False, html=False, log=lambda _: None)  # fmt: skip
    table = pd.read_csv(tmp_path / "drives_ranking.csv")
    wide = pd.read_csv(tmp_path / "recordings.csv")
    camera = wide[wide["sensor"] == "camera"]
    assert len(camera) == 1 and (camera[[f"rank_{n}" for n in NAMES]] == 1).all(axis=None)
    for sensor in ("lidar",):
        mine = table[(table["sensor"] == sensor) & (table["drive"] != ev.POOLED)]
        ranks = mine.pivot(index="setting", columns="drive", values="rank")
        got = wide[wide["sensor"] == sensor].set_index("lidar_ttc")
        ranks = ranks.rename(
            index=mine.drop_duplicates("setting").set_index("setting")["lidar_ttc"]
        )
        for name in NAMES:
            assert got[f"rank_{name}"].to_dict() == ranks[name].to_dict()
        tau = kendalltau(ranks[NAMES[1]], ranks[NAMES[0]]).statistic
        text = (tmp_path / "recordings.md").read_text()
        assert f"| {SHOWN[0]} | {SHOWN[1]} | 2 | {tau:.3g} |" in text
    assert summary["recordings"].startswith("Kendall's τ between the recordings' rankings is")
    lidar = text.split("## lidar")[1]
    assert "best (median)" in lidar or "best (closest)" in lidar
    assert "## false alarms without a lead vehicle" in text
    assert (tmp_path / "html" / "recordings.html").is_file()


def test_a_setting_spans_recordings_where_an_options_value_is_the_recordings() -> None:
    """``camera_ttc=vertical_ratio`` (min_dist 20 px) beside ``median_ratio`` (100 px) on drive
    0052, both at 0 px on sequence 04 (its dataset config sets it): each choice is one
    setting on both recordings; a value swept within one choice stays the setting's."""
    import json

    from experiments.summary.recordings import setting_of

    def config(seq: str, camera: str, min_dist: float, z: float) -> str:
        return json.dumps({"dataset": {"sequence": seq},
                           "camera_ttc": {"name": camera, "min_dist": min_dist},
                           "keypoint_filter": {"name": "zscore", "z": z}})  # fmt: skip

    rows = [(f"r{i}", config(seq, cam, dist if seq == "kitti/2011_09_26" else 0.0, z))
            for i, (seq, (cam, dist), z) in enumerate(
                (s, c, z) for s in ("kitti/2011_09_26", "kitti_odometry/sequences/04")
                for c in (("median_ratio", 100.0), ("vertical_ratio", 20.0)) for z in (2.0, 3.0)
            )]  # fmt: skip
    runs = pd.DataFrame(rows, columns=["run_id", "config"])
    ids = setting_of(runs)
    assert ids.nunique() == 4  # 2 camera choices x 2 z values, each on both recordings
    assert (ids.iloc[:4].to_numpy() == ids.iloc[4:].to_numpy()).all()


def test_configs_flattened_once_per_process_give_each_call_its_own_table() -> None:
    """:func:`~experiments.store.flat_configs.config_table` keeps every config it flattened (the
    report asks for each recording's runs, then for all of them): a later call on other,
    overlapping or missing configs gets exactly its own keys and leaves, by its own index."""
    import json

    from experiments.store import flat_configs
    from experiments.summary import recordings

    one = json.dumps({"dataset": {"sequence": "a"}, "k": {"z": 2.0, "tags": [1, 2]}})
    two = json.dumps({"dataset": {"sequence": "b"}, "k": {"z": 3}, "extra": {}})
    three = json.dumps({"dataset": {"sequence": "a"}, "other": "x"})
    flat_configs._FLAT_CONFIGS.clear()
    first = flat_configs.config_table(pd.Series([one, two], index=[10, 11]))
    assert first.to_dict("index") == {
        10: {"dataset.sequence": '"a"', "k.z": "2.0", "k.tags": "[1, 2]", "extra": np.nan},
        11: {"dataset.sequence": '"b"', "k.z": "3", "k.tags": np.nan, "extra": "{}"},
    }
    later = flat_configs.config_table(pd.Series([three, None, one], index=["x", "y", "z"]))
    assert sorted(later.columns) == ["dataset.sequence", "k.tags", "k.z", "other"]
    assert later.loc["x"].to_dict() == {
        "dataset.sequence": '"a"', "k.tags": np.nan, "k.z": np.nan, "other": '"x"'
    }  # fmt: skip
    assert later.loc["y"].isna().all()
    assert later.loc["z", "k.tags"] == "[1, 2]"
    assert len(flat_configs._FLAT_CONFIGS[0][1]) == 3  # each text flattened once
    runs = pd.DataFrame({"run_id": ["r1", "r2"], "config": [three, two]})
    parsed = recordings._sequence.cache_info().misses
    assert recordings.recording_of(runs).to_dict() == {"r1": "a", "r2": "b"}
    assert recordings._sequence.cache_info().misses == parsed  # from the flattened table
    unseen = json.dumps({"dataset": {"sequence": "c"}})
    runs = pd.DataFrame({"run_id": ["r1", "r3"], "config": [three, unseen]})
    assert recordings.recording_of(runs).to_dict() == {"r1": "a", "r3": "c"}


def test_a_configs_recording_is_read_as_json_reads_it() -> None:
    """:func:`experiments.store.flat_configs.entry_leaves` (the summary reads each run's
    ``dataset`` entry without parsing the whole config) gives the leaves
    :func:`json.loads` gives, each text read twice (the second cut as the first's keys say):
    stored configs one after another, other spacing, a nested key of the same name, one
    that makes a cut land inside an entry, a key given twice (the last wins), escapes; a
    missing key gives no leaf."""
    import json

    from experiments.store.flat_configs import _flat, entry_leaves

    def expected(text: str) -> dict[str, str]:
        flat = _flat(json.loads(text))
        return {k: v for k, v in flat.items() if k == "dataset" or k.startswith("dataset.")}

    stored = [json.dumps({"box_matching": {"dataset": "x"}, "camera_ttc": [1, {"a": None}],
                          "dataset": {"sequence": f"kitti/{d}", "last": 18},
                          "detector": {"dataset": "y"}}, sort_keys=True) for d in "abc"]  # fmt: skip
    inside = json.dumps({"box_matching": {"dataset": "x"},
                         "camera_ttc": {"a": 1, "dataset": {"sequence": "no"}, "detector": 2},
                         "dataset": {"sequence": "yes"}, "detector": 3})  # fmt: skip
    texts = [
        *stored,
        inside,
        *stored,
        json.dumps(json.loads(stored[0]), indent=2),
        json.dumps(json.loads(stored[0]), separators=(",", ":")),
        ' { "dataset" : 1 , "dataset" : {"sequence": "b\\"q\\u00e9"} } ',
        '{"a": "\\"dataset\\": 3", "dataset": [1, 2]}',
        '{"dataset": {}, "z": {"dataset": 5}}',
        '{"detector": {"dataset": 1}}',
    ]
    for text in texts:
        assert entry_leaves(text, "dataset") == expected(text), text
        assert entry_leaves(text, "dataset") == expected(text), text
    assert entry_leaves(inside, "dataset") == {"dataset.sequence": '"yes"'}
    assert entry_leaves('{"detector": {"dataset": 1}}', "dataset") == {}
