"""TTC ranges, a following regime and a recording without a lead vehicle (issue #22), on
constructed series with known answers."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ttc import evaluation as ev
from ttc.evaluation.ttc_bins import TTC_BINS, binned_metrics, no_lead_reports, ttc_bin

DT = 0.1


def test_ttc_bins_by_reference_ttc() -> None:
    ttc = [0.5, 5.99, 6.0, 11.9, 12.0, 23.9, 24.0, 50.0, np.inf, np.nan, -3.0]
    assert ttc_bin(ttc).tolist() == ["<6s", "<6s", "6-12s", "6-12s", "12-24s", "12-24s",
                                     ">24s", ">24s", "", "", ""]  # fmt: skip


def test_following_at_a_steady_gap_has_a_finite_reference_within_one_percent() -> None:
    """Constant gap closing at 0.4 m/s from 22 m (sequence 04's regime): the reference TTC
    of each pair is the exact two-frame TTC d_k · dt / (d_{k-1} − d_k) within 1 %."""
    d = 22.0 - 0.4 * DT * np.arange(41)
    ref = ev.reference_ttc(pd.DataFrame({"frame": np.arange(41), "distance_m": d}), DT)
    exact = d[1:] * DT / (d[:-1] - d[1:])
    got = ref["ttc_ref_s"].to_numpy()[1:]
    assert np.isfinite(got).all() and (ref["regime"].iloc[1:] == "approach").all()
    np.testing.assert_allclose(got, exact, rtol=0.01)
    assert (ttc_bin(got) == ">24s").all()


def _judged(ttc_ref: list[float], mid: list[float], run: str = "a") -> pd.DataFrame:
    n = len(ttc_ref)
    return pd.DataFrame({
        "run_id": run, "frame": np.arange(1, n + 1), "ttc_ref_s": ttc_ref,
        "judgeable": True, "camera_mid": mid, "camera_rel_err": np.full(n, 0.1),
        "camera_invalid": [False] * (n - 1) + [True], "camera_outlier": np.zeros(n),
        "ttc_camera": np.full(n, 5.0),
    })  # fmt: skip


def test_binned_metrics_per_range() -> None:
    t = _judged([3.0, 4.0, 8.0, 30.0, 40.0, np.inf], [10.0, 30.0, 5.0, 100.0, 200.0, 7.0])
    out = binned_metrics(t).set_index("ttc_bin")
    assert list(out.index) == ["<6s", "6-12s", ">24s"]
    assert out["n_frames"].tolist() == [2, 1, 2]
    assert out.loc["<6s", "camera_mid_median"] == 20.0
    assert out.loc[">24s", "camera_mid_median"] == 150.0
    assert set(out.index) <= set(TTC_BINS)


def test_a_recording_without_a_lead_judges_nothing_and_counts_false_alarms() -> None:
    """No lead cluster in any complete scan: every frame is ``no_lead``, no pair is judged,
    and a setting that reports a TTC there has false alarms; one that reports none has none."""
    n = 11
    series = pd.DataFrame({"frame": np.arange(n), "distance_m": np.nan,
                           "scan_points": np.full(n, 120_000)})  # fmt: skip
    ref = ev.reference_ttc(series, DT)
    assert (ref["lead"] == "no_lead").all() and not ref["judgeable"].any()
    lead = pd.DataFrame({
        "run_id": ["quiet"] * 10 + ["alarming"] * 10,
        "prev_frame": [*range(10)] * 2, "frame": [*range(1, 11)] * 2,
        "ttc_camera": [np.nan] * 10 + [3.0, 20.0, np.inf, -4.0, 7.9, 9.0, np.nan, 1.0, 50.0, 8.0],
        "ttc_lidar": np.nan,
    })  # fmt: skip
    ratio = 1.0 + DT / lead["ttc_camera"]
    judged = ev.judged_frames(
        lead.assign(is_lead=True, dt=DT, camera_ratio=ratio, d_prev=np.nan, d_curr=np.nan), ref
    )
    assert not judged["judgeable"].any()
    out = no_lead_reports(lead, ref, warning_s=8.0).set_index("run_id")
    assert out.loc["quiet"].tolist() == [10, 0, 0, 0, 0]
    assert out.loc["alarming", "n_no_lead"] == 10
    assert out.loc["alarming", "camera_reported"] == 7  # finite and positive
    assert out.loc["alarming", "camera_warnings"] == 3  # 3.0, 7.9, 1.0 s
    assert out.loc["alarming", "lidar_reported"] == 0


@pytest.mark.parametrize("frames_with_lead", [[0, 1, 2, 3, 4, 5]])
def test_pairs_touching_an_empty_lane_are_no_lead(frames_with_lead: list[int]) -> None:
    d = np.full(11, np.nan)
    d[frames_with_lead] = 20.0 - 0.04 * np.asarray(frames_with_lead)
    series = pd.DataFrame({"frame": np.arange(11), "distance_m": d,
                           "scan_points": np.full(11, 120_000)})  # fmt: skip
    ref = ev.reference_ttc(series, DT)
    lead = pd.DataFrame({"run_id": "a", "prev_frame": range(10), "frame": range(1, 11),
                         "ttc_camera": 4.0})  # fmt: skip
    out = no_lead_reports(lead, ref).set_index("run_id")
    assert out.loc["a", "n_no_lead"] == 5  # pairs 5->6 ... 9->10
    assert out.loc["a", "camera_warnings"] == 5
