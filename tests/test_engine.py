"""The one FP.1–FP.4 runner (ttc.engine): a batch of settings sharing their stages reproduces the
committed FP.6 / FP.5 series of frames 0–18 (results/kitti_0_18, made by the earlier
one-setting pipeline), and a single run is the same rows as that setting inside a batch."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments.configs.structured import settings_from_config
from tests.conftest import PROJECT_ROOT
from tests.test_beyond_rubric import composed
from ttc.engine.cache import StageCache
from ttc.engine.runner import (
    member_keys,
    pair_detail,
    run_setting,
    run_settings,
    setting_keys,
    upstream_key,
)
from ttc.rows import MEMBER
from ttc.settings import FrameRange

COMMITTED = PROJECT_ROOT / "results" / "kitti_0_18"
#: FP.6 settings of the committed report (detector/descriptor/matcher/selector), the other
#: axes at the defaults of conf/config.yaml.
FP6_SETTINGS = ("akaze/akaze/bf/knn", "sift/sift/flann/nn", "shitomasi/brisk/bf/nn",
                "orb/orb/bf/knn", "harris/freak/flann/knn", "brisk/sift/bf/nn")  # fmt: skip
LIDAR_ESTIMATORS = ("closest", "quantile", "median", "quantile_band_mean", "cluster")


def _overrides(setting: str) -> list[str]:
    det, desc, matcher, selector = setting.split("/")
    return [f"detector={det}", f"descriptor={desc}", f"matcher={matcher}", f"selector={selector}"]


def _lead(rows: pd.DataFrame, member: int) -> pd.DataFrame:
    mine = rows[(rows[MEMBER] == member) & rows["is_lead"]]
    return mine.set_index("frame").sort_index()


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> StageCache:
    return StageCache(tmp_path_factory.mktemp("cache"))


def _counted(monkeypatch, name: str) -> list[int]:
    """A list growing by one per call of ``ttc.engine.pair_steps.<name>`` in this test, which
    gets a process memory of its own (nothing kept by an earlier test)."""
    from ttc.engine import cache as stage_cache
    from ttc.engine import pair_steps

    monkeypatch.setattr(stage_cache, "_RECENT", stage_cache.RecentArrays())
    calls: list[int] = []
    real = getattr(pair_steps, name)
    monkeypatch.setattr(pair_steps, name, lambda *a, **k: calls.append(1) or real(*a, **k))
    return calls


def _three_shrink_runs(data: list[str]) -> tuple[FrameRange, list]:
    """The frames of ``data``'s config and three settings of it: as composed, with the
    ``zscore`` keypoint filter (the same lidar work) and with ``lidar_shrink=0.2`` (its own)."""
    import dataclasses

    from experiments.configs.structured import prepared_frame_range

    base = settings_from_config(composed(data))
    zscore = dataclasses.replace(base.keypoint_filter, name="zscore")
    runs = [base, dataclasses.replace(base, keypoint_filter=zscore),
            dataclasses.replace(base, lidar_shrink=0.2)]  # fmt: skip
    return prepared_frame_range(composed(data)), runs


def test_batch_reproduces_the_committed_fp6_series(kitti_dir: Path, cache: StageCache) -> None:
    committed = pd.read_csv(COMMITTED / "fp6_camera_ttc.csv")
    settings = [settings_from_config(composed(_overrides(s))) for s in FP6_SETTINGS]
    rows, failed = run_settings(settings, FrameRange(kitti_dir, 0, 18), cache)
    assert not failed
    for member, name in enumerate(FP6_SETTINGS):
        want = committed[committed["setting"] == name].set_index("frame").sort_index()
        got = _lead(rows, member).loc[want.index]
        assert len(want) == 18, name
        np.testing.assert_allclose(got["camera_ratio"], want["camera_ratio"], rtol=1e-5)
        np.testing.assert_allclose(got["ttc_camera"], want["ttc_camera"], rtol=1e-4)
        assert got["camera_reason"].tolist() == want["camera_reason"].tolist(), name
        for column in ("keypoints_curr", "matches_total", "matches_in_box", "matches_kept"):
            assert got[column].tolist() == want[column].tolist(), (name, column)


def test_batch_reproduces_the_committed_fp5_series(kitti_dir: Path, cache: StageCache) -> None:
    committed = pd.read_csv(COMMITTED / "fp5_lidar_ttc.csv")
    settings = [settings_from_config(composed([f"lidar_ttc={e}"])) for e in LIDAR_ESTIMATORS]
    rows, failed = run_settings(settings, FrameRange(kitti_dir, 0, 18), cache)
    assert not failed
    for member, name in enumerate(LIDAR_ESTIMATORS):
        want = committed[committed["lidar_ttc"] == name].set_index("frame").sort_index()
        got = _lead(rows, member).loc[want.index]
        assert len(want) == 18, name
        for column in ("ttc_lidar", "d_prev", "d_curr"):
            np.testing.assert_allclose(got[column], want[column], rtol=1e-5, err_msg=name)
        assert got["lidar_points_curr"].tolist() == want["lidar_points_curr"].tolist()


def test_a_single_run_is_its_batch_members_rows(kitti_dir: Path, cache: StageCache) -> None:
    """What a setting shares with others in a batch does not change its rows (times and
    cache flags aside); an invalid member fails alone."""
    overrides = [_overrides(s) for s in FP6_SETTINGS[:3]]
    overrides += [["keypoint_filter=zscore"], ["fusion=kalman_ca"], ["camera_ttc=mean_ratio"]]
    overrides += [["detector=sift", "descriptor=orb"]]  # invalid: fails inside OpenCV
    settings = [settings_from_config(composed(o)) for o in overrides]
    frames = FrameRange(kitti_dir, 0, 6)
    rows, failed = run_settings(settings, frames, cache)
    assert list(failed) == [len(settings) - 1]
    untimed = [c for c in rows if c.startswith(("ms_", "cached_"))] + [MEMBER]
    for member, s in enumerate(settings[:-1]):
        alone = run_setting(s, frames, cache).drop(columns=untimed[:-1])
        inside = rows[rows[MEMBER] == member].drop(columns=untimed).reset_index(drop=True)
        pd.testing.assert_frame_equal(inside, alone)
    with pytest.raises(type(failed[len(settings) - 1])):
        run_setting(settings[-1], frames, cache)


def test_a_setting_whose_whole_run_columns_raise_fails_alone(
    kitti_dir: Path, cache: StageCache, monkeypatch
) -> None:
    """The columns made over a whole run (fused TTC, tracks) are made for a batch's members at
    once; a member whose fusion raises fails alone, the others keep their rows and order."""
    from ttc.engine import runner

    real = runner.fused_columns

    def broken(rows, params):
        if params.name == "kalman_ca":
            raise FloatingPointError("filter diverged")
        return real(rows, params)

    monkeypatch.setattr(runner, "fused_columns", broken)
    overrides = [[], ["fusion=kalman_ca"], ["fusion=kalman_cv"], ["keypoint_filter=zscore"]]
    settings = [settings_from_config(composed(o)) for o in overrides]
    frames = FrameRange(kitti_dir, 0, 6)
    rows, failed = run_settings(settings, frames, cache)
    assert list(failed) == [1] and "diverged" in str(failed[1])
    assert rows[MEMBER].tolist() == sorted(rows[MEMBER].tolist()) and 1 not in set(rows[MEMBER])
    untimed = [c for c in rows if c.startswith(("ms_", "cached_"))]
    for member in (0, 2, 3):
        alone = run_setting(settings[member], frames, cache).drop(columns=untimed)
        inside = rows[rows[MEMBER] == member].drop(columns=[*untimed, MEMBER])
        pd.testing.assert_frame_equal(inside.reset_index(drop=True), alone)
    assert rows.loc[rows[MEMBER] == 2, "ttc_fused"].notna().any()


def test_pair_detail_rows_are_the_runs_rows(kitti_dir: Path, cache: StageCache) -> None:
    s = settings_from_config(composed([]))
    frames = FrameRange(kitti_dir, 0, 18)
    detail = pair_detail(s, frames, 4, 5, cache)
    run = run_setting(s, FrameRange(kitti_dir, 4, 5), cache)
    untimed = [c for c in run if c.startswith(("ms_", "cached_"))]
    pd.testing.assert_frame_equal(detail.rows.drop(columns=untimed), run.drop(columns=untimed))
    lead = detail.rows[detail.rows["is_lead"]].iloc[0]
    assert lead["curr_box"] == detail.lead_box >= 0
    assert (
        len(detail.kept) == lead["matches_kept"] and len(detail.removed) == lead["matches_removed"]
    )
    owner = detail.lane_owner[5]
    assert (owner == detail.lead_box).sum() == lead["lidar_points_curr"]


def test_a_frames_lidar_association_is_kept_for_the_next_runs_of_the_process(
    data_dir: Path, tmp_path: Path, monkeypatch
) -> None:
    """Drive 0009 frames 0-4: a frame's association (every box's own points) is computed
    once per process for the runs that share its boxes, points and shrink; a run with another
    shrink gets its own; rows are those of a cache that keeps nothing in memory."""
    calls = _counted(monkeypatch, "associate_objects")
    frames, runs = _three_shrink_runs(["dataset=kitti_raw_0009", "dataset.last=4"])
    kept = StageCache(tmp_path)
    rows = [run_settings([s], frames, kept)[0] for s in runs]  # one job each, as workers do
    assert len(calls) == 2 * 5  # frames 0-4, once per shrink
    untimed = [c for c in rows[0] if c.startswith(("ms_", "cached_"))]
    for s, got in zip(runs, rows, strict=True):
        alone, _ = run_settings([s], frames, StageCache(tmp_path, memory_mb=0))
        pd.testing.assert_frame_equal(got.drop(columns=untimed), alone.drop(columns=untimed))
    assert not rows[2]["lidar_points_curr"].equals(rows[0]["lidar_points_curr"])


def test_pair_details_take_a_frames_lidar_association_kept_by_the_process(
    data_dir: Path, tmp_path: Path, monkeypatch
) -> None:
    """Drive 0009 frames 0-2, as a report asks: the details of two pairs sharing frame 1, on
    two settings sharing the lidar shrink, associate each frame once; a third setting with
    another shrink associates its own; every detail's rows and arrays are those of a cache that
    keeps nothing in memory."""
    calls = _counted(monkeypatch, "associate_objects")
    frames, runs = _three_shrink_runs(["dataset=kitti_raw_0009", "dataset.last=2"])
    kept = StageCache(tmp_path)
    details = [pair_detail(s, frames, p, p + 1, kept) for s in runs for p in (0, 1)]
    assert len(calls) == 3 + 3  # frames 0-2, once per shrink
    untimed = [c for c in details[0].rows if c.startswith(("ms_", "cached_"))]
    plain = StageCache(tmp_path, memory_mb=0)
    for got, (s, p) in zip(details, [(s, p) for s in runs for p in (0, 1)], strict=True):
        alone = pair_detail(s, frames, p, p + 1, plain)
        pd.testing.assert_frame_equal(got.rows.drop(columns=untimed),
                                      alone.rows.drop(columns=untimed))  # fmt: skip
        for name in ("lane_uv", "lane_owner"):
            mine, theirs = getattr(got, name), getattr(alone, name)
            assert mine.keys() == theirs.keys()
            assert all(np.array_equal(mine[i], theirs[i]) for i in mine)
        assert got.lead_box == alone.lead_box
    assert len(calls) == 6 + 2 * 6  # the plain cache's details each associate both frames
    assert not details[4].rows["lidar_points_curr"].equals(details[0].rows["lidar_points_curr"])


def test_a_box_pairs_lidar_ttc_is_kept_for_the_other_camera_stages_of_the_process(
    data_dir: Path, tmp_path: Path, monkeypatch
) -> None:
    """Drive 0009 frames 0-4: FP.2 of a box pair reads the lidar only, so runs on other
    detectors (other groups, other jobs) take it from the process's memory; another lidar
    estimator computes its own; rows are those of a cache that keeps nothing in memory."""
    from experiments.configs.structured import prepared_frame_range

    calls = _counted(monkeypatch, "lidar_ttc")
    data = ["dataset=kitti_raw_0009", "dataset.last=4", "descriptor=brief"]
    frames = prepared_frame_range(composed(data))
    runs = [settings_from_config(composed([*data, *extra]))
            for extra in (["detector=fast"], ["detector=orb"], ["detector=orb", "lidar_ttc=cluster"])]  # fmt: skip
    kept = StageCache(tmp_path)
    rows, counts = [], []
    for s in runs:  # one job each, as workers do
        rows.append(run_settings([s], frames, kept)[0])
        counts.append(len(calls))
    key = ["frame", "prev_box", "curr_box"]
    pairs = [r.loc[r["prev_box"] >= 0, key].drop_duplicates() for r in rows]
    assert counts[0] == len(pairs[0]) > 10
    own = pairs[1].merge(pairs[0], on=key, how="left_anti")  # orb's box pairs fast had not
    assert counts[1] - counts[0] == len(own) < len(pairs[1])  # the others from memory
    assert counts[2] - counts[1] == len(pairs[2])  # another estimator: all its own
    untimed = [c for c in rows[0] if c.startswith(("ms_", "cached_"))]
    for s, got in zip(runs, rows, strict=True):
        alone, _ = run_settings([s], frames, StageCache(tmp_path, memory_mb=0))
        pd.testing.assert_frame_equal(got.drop(columns=untimed), alone.drop(columns=untimed))


def test_ratio_statistics_share_their_pair_ratios(
    kitti_dir: Path, cache: StageCache, monkeypatch
) -> None:
    """Settings that differ only in the camera ratio statistic compute each box's pair ratios
    once (as many ratio computations as one of them alone), and each keeps the rows it has
    alone (times aside)."""
    from ttc.steps import camera_ttc as fp4

    calls, real = [], fp4.distance_ratios
    monkeypatch.setattr(fp4, "distance_ratios", lambda *a: calls.append(a) or real(*a))
    frames = FrameRange(kitti_dir, 0, 4)
    settings = [settings_from_config(composed([f"camera_ttc={n}"])) for n in ("median_ratio",
                                                                              "mean_ratio")]  # fmt: skip
    run_settings(settings[:1], frames, cache)
    alone = len(calls)
    rows, failed = run_settings(settings, frames, cache)
    assert not failed and alone > 0 and len(calls) == 2 * alone
    untimed = [c for c in rows if c.startswith(("ms_", "cached_"))]
    for member, s in enumerate(settings):
        mine = rows[rows[MEMBER] == member].drop(columns=[*untimed, MEMBER])
        expected = run_setting(s, frames, cache).drop(columns=untimed)
        pd.testing.assert_frame_equal(mine.reset_index(drop=True), expected)
    assert (rows.loc[rows[MEMBER] == 0, "ttc_camera"].to_numpy()
            != rows.loc[rows[MEMBER] == 1, "ttc_camera"].to_numpy()).any()  # fmt: skip


def test_members_with_the_same_box_pairs_share_their_chained_tracks(
    kitti_dir: Path, cache: StageCache, monkeypatch
) -> None:
    """Tracks are chained once per distinct sequence of box pairs: settings that differ only
    downstream of FP.1 (lidar estimator, fusion) share one chaining; each keeps the track ids
    it has alone."""
    from ttc.engine import runner

    calls, real = [], runner.chain_tracks
    monkeypatch.setattr(runner, "chain_tracks", lambda *a: calls.append(a) or real(*a))
    overrides = [[], ["lidar_ttc=cluster"], ["fusion=kalman_ca"], ["box_matching=greedy_matrix"],
                 ["selector=knn"]]  # fmt: skip
    settings = [settings_from_config(composed(o)) for o in overrides]
    frames = FrameRange(kitti_dir, 0, 6)
    rows, failed = run_settings(settings, frames, cache)
    pairs = ["prev_frame", "frame", "prev_box", "curr_box"]
    distinct = {rows.loc[rows[MEMBER] == m, pairs].to_numpy().tobytes() for m in range(5)}
    assert not failed and len(calls) == len(distinct) < len(settings)
    for member, s in enumerate(settings):
        mine = rows.loc[rows[MEMBER] == member, "track_id"].to_numpy()
        np.testing.assert_array_equal(mine, run_setting(s, frames, cache)["track_id"].to_numpy())


def test_setting_keys_are_each_settings_own_keys() -> None:
    """Keys made once per set of shared field objects are each setting's own keys: settings
    sharing objects, equal settings made apart, settings differing upstream or in a step."""
    base = settings_from_config(composed([]))
    others = [settings_from_config(composed(o)) for o in (
        ["keypoint_filter=zscore"], ["detector=orb", "descriptor=orb"], ["lidar_ttc=median"])]  # fmt: skip
    settings = [base, copy.deepcopy(base), *others, base, others[0]]
    upstream, steps = setting_keys(settings)
    assert upstream == [upstream_key(s) for s in settings]
    assert steps == [member_keys(s) for s in settings]
    assert upstream[0] == upstream[1] == upstream[2] != upstream[3]
    assert steps[0] == steps[1] != steps[2]
