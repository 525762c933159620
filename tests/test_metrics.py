"""Per-frame errors, per-run metrics, the ranking and comparison on hand-made sweep tables."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ttc import evaluation as ev
from ttc.settings import AXES

INF, NAN = np.inf, np.nan
DT = 0.1

#: Pairs labelled at frames 1–5: approaching at 10 s (1–2), decelerating with an uncertain
#: reference (3), standing (4–5).
REFERENCE = pd.DataFrame(
    {
        "frame": [1, 2, 3, 4, 5],
        "ratio_ref": [1.01, 1.01, 1.0125, 1.0, 1.0],
        "ttc_ref_s": [10.0, 10.0, 8.0, INF, INF],
        "collision_course": [True, True, True, False, False],
        "mid_ref_sd": [5.0, 5.0, 40.0, 0.0, 0.0],
        "ttc_ref_sd_s": [0.3, 0.3, 2.5, NAN, NAN],
        "judgeable": [True, True, False, False, False],
        "regime": ["approach", "approach", "stopping", "stationary", "stationary"],
    }
)


def ttc_of(ratio: float) -> float:
    """The camera TTC (s) of a distance ratio: dt / (r − 1); +inf for r ≤ 1, NaN for NaN."""
    if np.isnan(ratio):
        return NAN
    return DT / (ratio - 1.0) if ratio > 1.0 else INF


def rows(run_id: str, detector: str, camera: list[float], lidar_prev: list[float],
         cached_objects: bool) -> list[dict]:  # fmt: skip
    """Lead rows of one run over frames 1–5: camera ratios, lidar previous distances (the
    current one is 5 m), objects 10 ms computed / 1 ms cached."""
    out = []
    for frame, ratio, d_prev in zip(range(1, 6), camera, lidar_prev, strict=True):
        lidar_ratio = d_prev / 5.0
        out.append(
            {
                **{axis: "x" for axis in AXES},
                "run_id": run_id,
                "detector": detector,
                "frame": frame,
                "prev_frame": frame - 1,
                "dt": DT,
                "is_lead": True,
                "camera_ratio": ratio,
                "ttc_camera": ttc_of(ratio),
                "d_prev": d_prev,
                "d_curr": 5.0,
                "ttc_lidar": ttc_of(lidar_ratio),
                "ms_objects": 1.0 if cached_objects else 10.0,
                "ms_keypoints": 4.0,
                "ms_camera_ttc": 1.0,
                "cached_objects": cached_objects,
                "cached_keypoints": False,
            }
        )
    return out


EXACT_LIDAR = [5.05, 5.05, 5.0625, 5.0, 5.0]  # d_prev / 5 m = the reference ratios


def hand_table() -> pd.DataFrame:
    a = rows("A", "orb", [1.01, 1.02, 1.0125, 1.0, 1.002], EXACT_LIDAR, cached_objects=False)
    b = rows("B", "fast", [NAN, 1.01, 1.0, 1.0, 0.99], [5.05, 5.05, NAN, 5.0, 5.0], True)
    c = rows("C", "sift", [1.01, 1.0101, 1.0125, 1.0001, 1.0], EXACT_LIDAR, True)
    # A, frame 2: another box pair, not the lead: ignored
    other = dict(a[1], is_lead=False, camera_ratio=1.5, ttc_camera=0.2, ms_camera_ttc=2.0)
    # C, frame 5: no lead box at all; its only row is a non-lead row (no FP.2–FP.4 work)
    c[4].update(is_lead=False, ms_camera_ttc=0.0)
    return pd.DataFrame(a + [other] + b + c)


def mid(r: float, ref: float) -> float:
    return 1e4 * abs(np.log(r) - np.log(ref))


@pytest.fixture(scope="module")
def metrics() -> pd.DataFrame:
    return ev.run_metrics(hand_table(), REFERENCE, warning_s=9.0).set_index("run_id")


def test_attach_reference_keeps_one_lead_row_per_frame_and_blanks_a_missing_lead():
    lead = ev.attach_reference(hand_table(), REFERENCE)
    assert len(lead) == 15
    assert lead.loc[(lead.run_id == "A") & (lead.frame == 2), "camera_ratio"].item() == 1.02
    c5 = lead[(lead.run_id == "C") & (lead.frame == 5)]
    assert c5[["camera_ratio", "d_prev", "ttc_camera", "ttc_lidar"]].isna().all(axis=None)
    assert lead["regime"].tolist() == REFERENCE["regime"].tolist() * 3


def test_mid_is_defined_on_every_frame_with_an_estimate():
    t = ev.judged_frames(hand_table(), REFERENCE).set_index(["run_id", "frame"])
    expected_a = [0.0, mid(1.02, 1.01), 0.0, 0.0, mid(1.002, 1.0)]
    np.testing.assert_allclose(t.loc["A", "camera_mid"], expected_a, atol=1e-9)
    # stationary frames count: ratio 0.99 where the reference says 1
    assert t.loc[("B", 5), "camera_mid"] == pytest.approx(mid(0.99, 1.0))
    # no estimate: NaN and invalid; C frame 5 has no lead box
    assert np.isnan(t.loc[("B", 1), "camera_mid"]) and t.loc[("B", 1), "camera_invalid"]
    assert t.loc[("C", 5), "camera_invalid"] and t.loc[("C", 5), "lidar_invalid"]
    # lidar ratio from the distances the estimator chose
    assert t.loc[("A", 3), "lidar_ratio"] == pytest.approx(1.0125)
    assert t.loc["A", "lidar_mid"].max() == pytest.approx(0.0, abs=1e-9)


def test_camera_metrics_by_hand(metrics):
    a, b, c = metrics.loc["A"], metrics.loc["B"], metrics.loc["C"]
    assert a["camera_mid_median"] == pytest.approx(0.0, abs=1e-9)
    assert a["camera_mid_mean"] == pytest.approx((mid(1.02, 1.01) + mid(1.002, 1.0)) / 5)
    assert a["camera_mid_median_approach"] == pytest.approx(mid(1.02, 1.01) / 2)
    assert a["camera_mid_median_stopping"] == pytest.approx(0.0, abs=1e-9)
    assert a["camera_mid_median_stationary"] == pytest.approx(mid(1.002, 1.0) / 2)
    # B: frame 1 invalid; valid frames 2–5: MiD 0, 124 (ratio 1 against 1.0125), 0, 100.5
    assert b["camera_invalid"] == 1 and b["camera_invalid_rate"] == pytest.approx(0.2)
    assert b["camera_mid_median"] == pytest.approx(mid(0.99, 1.0) / 2)
    # relative TTC error: judgeable approach frames only (1, 2): A 0 and 0.5
    assert a["camera_medae_rel"] == pytest.approx(0.25)
    assert a["camera_meanae_rel"] == pytest.approx(0.25)
    # outlier: judgeable frames; A frame 2 is 50 % off; B frame 1 invalid
    assert a["camera_outlier_rate"] == pytest.approx(0.5)
    assert b["camera_outlier_rate"] == pytest.approx(0.5)
    assert c["camera_outlier_rate"] == pytest.approx(0.0)
    # false alarms where the reference is +inf (frames 4, 5): A's 50 s is none
    assert a["camera_false_alarm_rate"] == 0.0
    # warnings below 9 s: the reference warns at frame 3 (8 s); A warns at 2 (5 s) and 3
    assert a["camera_warn_precision"] == pytest.approx(0.5)
    assert a["camera_warn_recall"] == pytest.approx(1.0)
    assert np.isnan(b["camera_warn_precision"]) and b["camera_warn_recall"] == 0.0


def test_lidar_metrics_by_hand(metrics):
    assert metrics.loc["A", "lidar_mid_median"] == pytest.approx(0.0, abs=1e-9)
    assert metrics.loc["B", "lidar_invalid"] == 1
    assert metrics.loc["C", "lidar_invalid_rate"] == pytest.approx(0.2)


def test_counts_axes_and_times_by_hand(metrics):
    assert set(AXES) <= set(metrics.columns)
    assert metrics["n_frames"].tolist() == [5, 5, 5]
    assert metrics["n_judged"].tolist() == [2, 2, 2]
    assert metrics["n_uncertain"].tolist() == [1, 1, 1]
    assert metrics.loc["A", "ms_per_frame"] == pytest.approx(15.0)
    assert metrics.loc["B", "ms_per_frame"] == pytest.approx(6.0)
    # C frame 5 (non-lead row, no camera work): (6 × 4 + 5) / 5
    assert metrics.loc["C", "ms_per_frame"] == pytest.approx(5.8)
    # cached objects of B and C computed by A on the same frames: 10 ms
    assert metrics.loc["B", "ms_compute_per_frame"] == pytest.approx(15.0)


def test_ms_per_frame_after_the_compute_time_join_is_the_sum_of_the_stage_times():
    """The report joins compute times first; ms_per_frame must not add them in again."""
    joined = ev.with_compute_times(hand_table())
    m = ev.run_metrics(joined, REFERENCE).set_index("run_id")
    assert m.loc["A", "ms_per_frame"] == pytest.approx(10.0 + 4.0 + 1.0)
    assert m.loc["B", "ms_per_frame"] == pytest.approx(1.0 + 4.0 + 1.0)
    assert m.loc["B", "ms_compute_per_frame"] == pytest.approx(15.0)
    assert m.loc["A", "ms_objects_mean"] == pytest.approx(10.0)
    assert "ms_compute_per_frame_mean" not in m and "ms_per_frame_mean" not in m


def test_a_stage_no_run_computed_keeps_its_load_time():
    """The objects a sweep's warm-up computed while planning: every run loads them."""
    b = pd.DataFrame(rows("B", "fast", [1.01] * 5, EXACT_LIDAR, cached_objects=True))
    m = ev.run_metrics(b, REFERENCE)
    assert m.loc[0, "ms_compute_per_frame"] == m.loc[0, "ms_per_frame"] == 6.0


def test_step_two_pairs_get_the_reference_of_their_own_frames():
    ref = REFERENCE.assign(
        distance_smooth_m=[4.95, 4.9, 4.84, 4.84, 4.84], distance_sd_m=[0.001] * 5
    )
    table = pd.DataFrame(rows("S", "sift", [1.01] * 5, EXACT_LIDAR, False))
    table = table[table["frame"].isin([3, 5])].assign(prev_frame=lambda t: t.frame - 2, dt=0.2)
    lead = ev.attach_reference(table, ref).set_index("frame")
    assert lead.loc[3, "ratio_ref"] == pytest.approx(4.95 / 4.84)
    assert lead.loc[3, "ttc_ref_s"] == pytest.approx(4.84 * 0.2 / 0.11)
    assert lead.loc[3, "judgeable"] and lead.loc[3, "regime"] == "stopping"
    assert lead.loc[5, "ratio_ref"] == 1.0 and np.isposinf(lead.loc[5, "ttc_ref_s"])


def test_thresholds_are_parameters():
    loose = ev.run_metrics(hand_table(), REFERENCE, outlier_rel=0.6).set_index("run_id")
    assert loose.loc["A", "camera_outlier_rate"] == 0.0
    strict = ev.run_metrics(hand_table(), REFERENCE, false_alarm_s=60.0).set_index("run_id")
    assert strict.loc["A", "camera_false_alarm_rate"] == 0.5


def metric_rows(**columns) -> pd.DataFrame:
    n = len(next(iter(columns.values())))
    base = {"run_id": [f"r{i}" for i in range(n)], "ms_per_frame": [1.0] * n}
    return pd.DataFrame(base | columns)


def test_rank_follows_the_rule():
    m = metric_rows(
        camera_invalid_rate=[0.0, 0.0, 0.1, 0.0, NAN],
        camera_mid_median=[30.0, 10.0, 1.0, 10.0, 0.0],
        ms_per_frame=[1.0, 5.0, 1.0, 2.0, 1.0],
    )
    ranked = ev.rank_runs(m, "camera")
    # validity first, then MiD, then time; NaN last
    assert ranked["run_id"].tolist() == ["r3", "r1", "r0", "r2", "r4"]
    assert ranked["rank"].tolist() == [1, 2, 3, 4, 5]
    assert "invalid rate" in ev.RANKING_RULE and "motion-in-depth" in ev.RANKING_RULE


def test_rank_breaks_ties_by_computing_time_not_cache_order():
    m = metric_rows(
        camera_invalid_rate=[0.0, 0.0],
        camera_mid_median=[10.0, 10.0],
        ms_per_frame=[1.0, 9.0],  # r0 loaded its stages from the cache
        ms_compute_per_frame=[9.5, 9.0],
    )
    assert ev.rank_runs(m, "camera")["run_id"].tolist() == ["r1", "r0"]


def test_replicate_ranks_are_each_replicates_own_ranking():
    """:func:`ttc.evaluation.ranking.ranks` of many replicates (rows, ranked a few at a time)
    are each row ranked on its own by the rule: invalid rate, median MiD (NaN last), time,
    then position; checked against Python's sort of each row's keys."""
    from ttc.evaluation.ranking import RANK_ROWS, ranks

    rng = np.random.default_rng(1)
    shape = (3 * RANK_ROWS + 5, 40)  # a last chunk of 5 rows
    invalid = rng.integers(0, 3, shape) / 2.0
    mid = rng.integers(0, 5, shape).astype(float)
    mid[mid == 4] = np.nan
    ms = rng.integers(0, 3, shape).astype(float)
    got = ranks(invalid, mid, ms)
    assert got.shape == shape and got.dtype == np.int64
    for i in range(shape[0]):
        keys = [(invalid[i, j], np.inf if np.isnan(mid[i, j]) else mid[i, j], ms[i, j], j)
                for j in range(shape[1])]  # fmt: skip
        order = sorted(range(shape[1]), key=keys.__getitem__)
        want = np.empty(shape[1], dtype=np.int64)
        want[order] = np.arange(1, shape[1] + 1)
        assert np.array_equal(got[i], want), i
    assert ranks(invalid[:0], mid[:0], ms[:0]).shape == (0, shape[1])


def test_hand_table_ranking(metrics):
    ranked = ev.rank_runs(metrics.reset_index(), "camera")
    # A and C have no invalid frame and MiD median 0; B one invalid frame
    assert ranked["run_id"].tolist()[2] == "B"


def interval_rows(run: str, invalid: tuple[float, float], mid: tuple[float, float]) -> dict:
    return {
        "run_id": run,
        "rank": 1,
        "camera_invalid_rate_lo": invalid[0],
        "camera_invalid_rate_hi": invalid[1],
        "camera_mid_median_lo": mid[0],
        "camera_mid_median_hi": mid[1],
    }


def test_compare_runs_flags_better_worse_and_unchanged_settings():
    metric_cols = [f"camera_{m}" for m in ev.COMPARED_METRICS] + ["ms_per_frame"]
    a = pd.DataFrame({"run_id": ["a1", "a2", "a3"], "detector": ["orb", "sift", "fast"]})
    b = pd.DataFrame({"run_id": ["b1", "b2", "b3"], "detector": ["orb", "sift", "fast"]})
    for m in (a, b):
        for col in metric_cols:
            m[col] = 0.0
    ia = pd.DataFrame([interval_rows("a1", (0.2, 0.3), (10, 20)),
                       interval_rows("a2", (0.0, 0.1), (10, 20)),
                       interval_rows("a3", (0.0, 0.0), (10, 20))])  # fmt: skip
    ib = pd.DataFrame([interval_rows("b1", (0.0, 0.1), (30, 40)),   # fewer invalid: better
                       interval_rows("b2", (0.0, 0.1), (25, 30)),   # same validity, worse MiD
                       interval_rows("b3", (0.0, 0.0), (15, 25))])  # fmt: skip
    verdicts = ev.compare_runs(a, b, ia, ib, key=["detector"])
    assert verdicts.set_index("detector")["verdict"].to_dict() == {
        "orb": "better",
        "sift": "worse",
        "fast": "same",
    }


def test_the_fused_estimate_is_judged_like_the_other_sensors():
    table = hand_table()
    fused = {"A": [1.01, 1.01, 1.0125, 1.0, 1.0], "B": [NAN, 1.02, 1.0125, 1.0, 1.001]}
    table["fused_ratio"] = NAN
    for run, ratios in fused.items():
        lead = (table["run_id"] == run) & table["is_lead"]
        table.loc[lead, "fused_ratio"] = ratios
    table["ttc_fused"] = table["fused_ratio"].map(ttc_of)
    m = ev.run_metrics(table, REFERENCE).set_index("run_id")
    assert m.loc["A", "fused_mid_median"] == pytest.approx(0.0, abs=1e-9)
    assert m.loc["A", "fused_invalid_rate"] == 0.0 and m.loc["C", "fused_invalid_rate"] == 1.0
    assert m.loc["B", "fused_mid_median"] == pytest.approx(mid(1.001, 1.0) / 2)
    assert m.loc["B", "fused_outlier_rate"] == 1.0  # frame 1 invalid, frame 2 50 % off
    ranked = ev.rank_runs(m.reset_index(), "fused")
    assert ranked["run_id"].tolist() == ["A", "B", "C"]
    # sweeps made before the fusion axis have no fused columns: nothing is made up
    assert "fused_mid_median" not in ev.run_metrics(hand_table(), REFERENCE)
