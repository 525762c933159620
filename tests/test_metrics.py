"""Metrics, ranking, bootstrap and comparison on hand-made sweep tables."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ttc.evaluation.metrics import (
    AXES,
    RANKING_RULE,
    attach_reference,
    bootstrap_rank_intervals,
    compare_runs,
    rank_runs,
    run_metrics,
    with_compute_times,
)

INF, NAN = np.inf, np.nan

#: frames 1–5: closing for 1–3, no collision course for 4–5
REFERENCE = pd.DataFrame(
    {
        "frame": [1, 2, 3, 4, 5],
        "ttc_ref_s": [10.0, 10.0, 8.0, INF, INF],
        "collision_course": [True, True, True, False, False],
    }
)


def rows(run_id: str, detector: str, camera, lidar, cached_objects: bool) -> list[dict]:
    """Lead rows of one run over frames 1–5 (objects 10 ms computed / 1 ms cached)."""
    return [
        {
            "run_id": run_id,
            "frame": frame,
            "prev_frame": frame - 1,
            "is_lead": True,
            "ttc_camera": cam,
            "ttc_lidar": lid,
            "ms_objects": 1.0 if cached_objects else 10.0,
            "ms_keypoints": 4.0,
            "ms_camera_ttc": 1.0,
            "cached_objects": cached_objects,
            "cached_keypoints": False,
            **{axis: "x" for axis in AXES},
            "detector": detector,
        }
        for frame, cam, lid in zip(range(1, 6), camera, lidar, strict=True)
    ]


LIDAR = [10.0, 10.0, 8.0, INF, INF]


def hand_table() -> pd.DataFrame:
    a = rows("A", "orb", [11.0, 9.0, 8.0, INF, 50.0], LIDAR, cached_objects=False)
    b = rows("B", "fast", [NAN, 14.0, 6.0, 5.0, -3.0], [10, 10, NAN, INF, INF], True)
    c = rows("C", "sift", [10.0, -10.0, 12.0, 9.0, 0.0], LIDAR, True)
    # A, frame 2: another box pair, not the lead: ignored
    other = dict(a[1], is_lead=False, ttc_camera=1.0, ttc_lidar=1.0, ms_camera_ttc=2.0)
    # C, frame 5: no lead box at all; its only row is a non-lead row (no FP.2–FP.4 work)
    c[4].update(is_lead=False, ttc_camera=9.0, ttc_lidar=9.0, ms_camera_ttc=0.0)
    return pd.DataFrame(a + [other] + b + c)


@pytest.fixture(scope="module")
def metrics() -> pd.DataFrame:
    return run_metrics(hand_table(), REFERENCE).set_index("run_id")


def test_attach_reference_keeps_one_lead_row_per_frame_and_fills_missing():
    lead = attach_reference(hand_table(), REFERENCE)
    assert len(lead) == 15
    assert lead.loc[(lead.run_id == "A") & (lead.frame == 2), "ttc_camera"].item() == 9.0
    c5 = lead[(lead.run_id == "C") & (lead.frame == 5)]
    assert c5["ttc_camera"].isna().item() and c5["ttc_lidar"].isna().item()
    assert lead["collision_course"].tolist() == [True, True, True, False, False] * 3

    beyond = hand_table().iloc[:1].assign(frame=6)
    out = attach_reference(beyond, REFERENCE)
    assert np.isnan(out["ttc_ref_s"].item())
    assert out["collision_course"].dtype == bool and not out["collision_course"].item()


def test_camera_metrics_by_hand(metrics):
    m = metrics
    # A: rel errors 0.1, 0.1, 0.0; no outlier; 50 s is no false alarm (≥ 10 s);
    #    finite series 11, 9, 8, 50 → changes 2, 1, 42; invalid: inf
    # B: rel errors (NaN skipped) 0.4, 0.25; outliers NaN, 0.4 of 3; false alarm 5 s of
    #    (5, −3); finite 14, 6, 5, −3 → changes 8, 1, 8; invalid: NaN
    # C: rel errors 0, 2.0 (−10 s), 0.5; outliers −10 s, 0.5 of 3; false alarm 9 s of
    #    (9, missing lead); finite 10, −10, 12, 9 → changes 20, 22, 3; invalid: missing lead
    expected = {
        "camera_medae_rel": [0.1, 0.325, 0.5],
        "camera_meanae_rel": [0.2 / 3, 0.325, 2.5 / 3],
        "camera_outlier_rate": [0.0, 2 / 3, 2 / 3],
        "camera_false_alarm_rate": [0.0, 0.5, 0.5],
        "camera_jitter_s": [2.0, 8.0, 20.0],
        "camera_invalid": [1, 1, 1],
    }
    for col, values in expected.items():
        np.testing.assert_allclose(m.loc[["A", "B", "C"], col], values, rtol=1e-12, err_msg=col)


def test_lidar_metrics_by_hand(metrics):
    m = metrics
    # all exact where valid; B misses frame 3 (outlier 1 of 3); C misses frame 5 (no lead)
    expected = {
        "lidar_medae_rel": [0.0, 0.0, 0.0],
        "lidar_meanae_rel": [0.0, 0.0, 0.0],
        "lidar_outlier_rate": [0.0, 1 / 3, 0.0],
        "lidar_false_alarm_rate": [0.0, 0.0, 0.0],
        "lidar_jitter_s": [1.0, 0.0, 1.0],  # 10, 10, 8 → 0, 2;  B: 10, 10 → 0
        "lidar_invalid": [2, 3, 2],
    }
    for col, values in expected.items():
        np.testing.assert_allclose(m.loc[["A", "B", "C"], col], values, rtol=1e-12, err_msg=col)


def test_counts_axes_and_times_by_hand(metrics):
    m = metrics
    assert m["n_frames"].tolist() == [5, 5, 5]
    assert m["detector"].tolist() == ["orb", "fast", "sift"]
    assert set(AXES) <= set(m.columns)
    # lead row sums: A 10 + 4 + 1; B 1 + 4 + 1; C 4 × 6 and 1 + 4 + 0 on frame 5
    np.testing.assert_allclose(m["ms_per_frame"], [15.0, 6.0, 29 / 5])
    # cached objects (1 ms) replaced by A's computed 10 ms on the same frame
    np.testing.assert_allclose(m["ms_compute_per_frame"], [15.0, 15.0, 74 / 5])
    np.testing.assert_allclose(m["ms_objects_mean"], [10.0, 1.0, 1.0])
    np.testing.assert_allclose(m["ms_camera_ttc_mean"], [1.0, 1.0, 0.8])


def test_compute_time_unknown_when_no_run_computed_the_stage():
    table = hand_table().assign(cached_objects=True)
    m = run_metrics(table, REFERENCE).set_index("run_id")
    assert m["ms_compute_per_frame"].isna().all()
    np.testing.assert_allclose(m["ms_per_frame"], [15.0, 6.0, 29 / 5])


def test_compute_time_of_a_stage_computed_on_another_frame_or_by_another_sweep():
    table = hand_table()
    # frame 1's objects were computed (10 ms) by A only: with A's frame-1 rows cached too,
    # frame 1 falls back to the stage's median over the frames where it was computed
    a = table["run_id"].eq("A")
    on_1 = table.assign(cached_objects=table["cached_objects"] | (a & table["frame"].eq(1)))
    known = run_metrics(on_1, REFERENCE).set_index("run_id")
    assert known["ms_compute_per_frame"].notna().all()
    # a subset of runs keeps the times looked up over the whole table
    whole = with_compute_times(table)
    subset = run_metrics(whole[~a], REFERENCE).set_index("run_id")
    alone = run_metrics(table[~a], REFERENCE).set_index("run_id")
    full = run_metrics(table, REFERENCE).set_index("run_id")
    np.testing.assert_allclose(
        subset["ms_compute_per_frame"], full.loc[["B", "C"], "ms_compute_per_frame"]
    )
    assert alone["ms_compute_per_frame"].isna().all()


def test_false_alarm_rate_nan_without_a_no_collision_frame():
    table = hand_table()
    m = run_metrics(table[table.frame <= 3], REFERENCE)
    assert m["camera_false_alarm_rate"].isna().all()


def test_thresholds_are_parameters():
    m = run_metrics(hand_table(), REFERENCE, outlier_rel=0.45, false_alarm_s=6.0)
    m = m.set_index("run_id")
    np.testing.assert_allclose(m["camera_outlier_rate"], [0.0, 1 / 3, 2 / 3])
    np.testing.assert_allclose(m["camera_false_alarm_rate"], [0.0, 0.5, 0.0])


# --- ranking -----------------------------------------------------------------------------------


def test_rank_follows_the_rule():
    metrics = pd.DataFrame(
        {
            "run_id": ["r1", "r2", "r3", "r4", "r5", "r6"],
            "camera_outlier_rate": [0.2, 0.0, 0.2, 0.2, NAN, 0.2],
            "camera_medae_rel": [0.1, 0.3, 0.05, 0.1, 0.01, 0.1],
            "lidar_outlier_rate": [0.0, 0.5, 0.0, 0.0, 0.0, 0.0],
            "lidar_medae_rel": [0.3, 0.0, 0.2, 0.1, 0.1, 0.1],
            "ms_per_frame": [5.0, 9.0, 7.0, 3.0, 1.0, 3.0],
        }
    )
    ranked = rank_runs(metrics)
    # outlier rate first (NaN last), then median error, then time, then run_id
    assert ranked["run_id"].tolist() == ["r2", "r3", "r4", "r6", "r1", "r5"]
    assert ranked["rank"].tolist() == [1, 2, 3, 4, 5, 6]
    lidar = rank_runs(metrics, sensor="lidar")
    assert lidar["run_id"].tolist() == ["r5", "r4", "r6", "r3", "r1", "r2"]
    assert "outlier rate" in RANKING_RULE and "median" in RANKING_RULE


def test_rank_breaks_ties_by_computing_time_not_cache_order():
    # identical TTC series: r1 filled the cache (slow as measured), r2 loaded from it
    metrics = pd.DataFrame(
        {
            "run_id": ["r1", "r2", "r3"],
            "camera_outlier_rate": [0.1, 0.1, 0.1],
            "camera_medae_rel": [0.2, 0.2, 0.2],
            "ms_per_frame": [150.0, 3.0, 2.0],
            "ms_compute_per_frame": [150.2, 150.0, NAN],
        }
    )
    ranked = rank_runs(metrics)
    # r3's computing time is unknown: its own 2 ms counts
    assert ranked["run_id"].tolist() == ["r3", "r2", "r1"]


def test_hand_table_ranking(metrics):
    ranked = rank_runs(metrics.reset_index())
    assert ranked["run_id"].tolist() == ["A", "B", "C"]  # B and C tie on outliers; B's error lower


# --- bootstrap ---------------------------------------------------------------------------------


def test_bootstrap_is_deterministic_and_contains_the_point_rank():
    table = hand_table()
    first = bootstrap_rank_intervals(table, REFERENCE, n_boot=300, seed=3)
    again = bootstrap_rank_intervals(table, REFERENCE, n_boot=300, seed=3)
    pd.testing.assert_frame_equal(first, again)
    iv = first.set_index("run_id")
    assert iv["rank"].tolist() == [1, 2, 3]
    assert ((iv["rank_lo"] <= iv["rank"]) & (iv["rank"] <= iv["rank_hi"])).all()
    assert iv["rank_lo"].min() >= 1 and iv["rank_hi"].max() <= 3
    # A never has an outlier; B's median error always lies between its errors 0.25 and 0.4
    assert iv.loc["A", ["camera_outlier_rate_lo", "camera_outlier_rate_hi"]].tolist() == [0, 0]
    assert 0.25 <= iv.loc["B", "camera_medae_rel_lo"] <= iv.loc["B", "camera_medae_rel_hi"] <= 0.4


def frames_from(camera: dict[str, list[float]], reference: pd.DataFrame) -> pd.DataFrame:
    """Lead rows with the given camera TTCs per run over the reference's frames."""
    out = []
    for i, (run_id, values) in enumerate(camera.items()):
        out += [
            {
                "run_id": run_id,
                "frame": f,
                "is_lead": True,
                "ttc_camera": v,
                "ttc_lidar": 10.0,
                "ms_objects": 1.0,
                **{axis: "x" for axis in AXES},
                "detector": f"det{i}",
            }
            for f, v in zip(reference["frame"], values, strict=True)
        ]
    return pd.DataFrame(out)


def test_paired_bootstrap_keeps_a_uniformly_better_run_ahead():
    ref = pd.DataFrame({"frame": range(1, 7), "ttc_ref_s": 10.0, "collision_course": True})
    x = [10.0, 10.5, 11.0, 11.5, 12.0, 12.5]  # rel errors 0 … 0.25
    y = [v + 0.4 for v in x]  # 0.04 worse on every frame
    iv = bootstrap_rank_intervals(frames_from({"X": x, "Y": y}, ref), ref, n_boot=500)
    iv = iv.set_index("run_id")
    assert iv[["rank_lo", "rank_hi", "rank_median"]].values.tolist() == [[1, 1, 1], [2, 2, 2]]


def test_bootstrap_scales_to_a_sweep():
    rng = np.random.default_rng(0)
    ref = pd.DataFrame({"frame": range(1, 19), "ttc_ref_s": 12.0, "collision_course": True})
    camera = {f"r{i:03d}": list(12.0 * (1 + rng.normal(0, 0.2, 18))) for i in range(170)}
    table = frames_from(camera, ref)
    iv = bootstrap_rank_intervals(table, ref, n_boot=500)
    assert len(iv) == 170 and sorted(iv["rank"]) == list(range(1, 171))
    assert (iv["rank_lo"] <= iv["rank_hi"]).all()


# --- comparison --------------------------------------------------------------------------------


def test_compare_runs_flags_improved_worse_and_unchanged_settings():
    ref = pd.DataFrame({"frame": range(1, 13), "ttc_ref_s": 10.0, "collision_course": True})
    good = [10.0, 10.2, 9.9, 10.1, 9.8, 10.3, 10.0, 9.7, 10.1, 10.2, 9.9, 10.0]
    bad = [15.0] * 8 + [10.0] * 4  # 8 of 12 frames 50 % off
    before = frames_from({"a0": bad, "a1": good, "a2": good}, ref)
    after = frames_from({"b0": good, "b1": good, "b2": bad}, ref)
    m_a, m_b = run_metrics(before, ref), run_metrics(after, ref)
    iv_a = bootstrap_rank_intervals(before, ref, n_boot=300)
    iv_b = bootstrap_rank_intervals(after, ref, n_boot=300)
    cmp = compare_runs(m_a, m_b, iv_a, iv_b).set_index("detector")
    assert cmp["verdict"].to_dict() == {"det0": "better", "det1": "same", "det2": "worse"}
    assert cmp.loc["det0", "camera_outlier_rate_change"] == pytest.approx(-8 / 12)
    assert cmp.loc["det1", "camera_medae_rel_change"] == 0.0
    assert cmp.loc["det0", ["run_id_a", "run_id_b"]].tolist() == ["a0", "b0"]


def test_compare_runs_uses_the_error_interval_when_outlier_rates_overlap():
    ref = pd.DataFrame({"frame": range(1, 7), "ttc_ref_s": 10.0, "collision_course": True})
    before = frames_from({"a": [12.0, 11.8, 12.2, 12.0, 11.9, 12.1]}, ref)  # ≈ 20 % off
    after = frames_from({"b": [10.1, 9.9, 10.0, 10.1, 10.0, 9.9]}, ref)  # ≤ 1 % off
    cmp = compare_runs(
        run_metrics(before, ref),
        run_metrics(after, ref),
        bootstrap_rank_intervals(before, ref, n_boot=200),
        bootstrap_rank_intervals(after, ref, n_boot=200),
    )
    assert cmp["verdict"].tolist() == ["better"]
    assert cmp["camera_outlier_rate_change"].tolist() == [0.0]
