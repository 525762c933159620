"""Reference TTC: synthetic distance series with known kinematics, and the real sequence."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ttc.evaluation.reference import (
    REFERENCE_CAVEATS,
    lead_points,
    rear_distance,
    reference_for_sequence,
    reference_ttc,
)

DT = 0.1


def series(d: np.ndarray) -> pd.DataFrame:
    return pd.DataFrame({"frame": np.arange(len(d)), "distance_m": d})


# --- synthetic distance series ---------------------------------------------------------------


def test_decelerating_approach_matches_analytic_ttc_exactly_without_noise():
    t = np.arange(60) * DT
    a = 0.05  # m/s², closing speed 0.65 → 0.355 m/s
    d = 8.0 - 0.65 * t + 0.5 * a * t**2
    ref = reference_ttc(series(d))
    analytic = d / (0.65 - a * t)
    np.testing.assert_allclose(ref["closing_speed_mps"], 0.65 - a * t, rtol=1e-9)
    np.testing.assert_allclose(ref["ttc_ref_s"], analytic, rtol=1e-9)
    assert ref["collision_course"].all()
    assert not ref["distance_interpolated"].any()


def test_noisy_approach_within_two_percent_of_analytic_ttc_at_interior_frames():
    t = np.arange(60) * DT
    a = 0.02
    d = 8.0 - 0.65 * t + 0.5 * a * t**2
    noisy = d + np.random.default_rng(0).normal(0.0, 0.001, len(d))  # 1 mm
    ref = reference_ttc(series(noisy))
    interior = slice(4, -4)
    rel = np.abs(ref["ttc_ref_s"].to_numpy() / (d / (0.65 - a * t)) - 1.0)[interior]
    assert rel.max() < 0.02


def test_stop_gives_no_collision_course_and_inf():
    # constant 0.65 m/s until frame 30, then standing still
    k = np.arange(60)
    d = 8.0 - 0.065 * np.minimum(k, 30)
    ref = reference_ttc(series(d)).set_index("frame")
    # windows (±4 frames) entirely before the stop: exact d / v
    before = ref.loc[:26]
    np.testing.assert_allclose(before["ttc_ref_s"], before["distance_m"] / 0.65, rtol=1e-9)
    assert before["collision_course"].all()
    # windows entirely after it: zero closing speed
    after = ref.loc[34:]
    np.testing.assert_allclose(after["closing_speed_mps"], 0.0, atol=1e-12)
    assert np.isposinf(after["ttc_ref_s"]).all()
    assert not after["collision_course"].any()


def test_receding_is_no_collision_course():
    ref = reference_ttc(series(5.0 + 0.05 * np.arange(20)))
    assert np.isposinf(ref["ttc_ref_s"]).all() and not ref["collision_course"].any()
    np.testing.assert_allclose(ref["closing_speed_mps"], -0.5, rtol=1e-9)


def test_nan_in_the_middle_is_interpolated_and_flagged():
    d = 8.0 - 0.065 * np.arange(20)
    d_nan = d.copy()
    d_nan[10] = np.nan
    ref = reference_ttc(series(d_nan))
    assert ref["distance_interpolated"].tolist() == [i == 10 for i in range(20)]
    assert np.isnan(ref.loc[10, "distance_m"])
    assert ref.loc[10, "distance_smooth_m"] == pytest.approx(8.0 - 0.65)
    np.testing.assert_allclose(ref["ttc_ref_s"], d / 0.65, rtol=1e-9)


def test_missing_frame_and_trailing_nan_are_filled_and_flagged():
    d = pd.Series(8.0 - 0.065 * np.arange(20), index=np.arange(20))
    d[19] = np.nan  # truncated last scan
    ref = reference_ttc(d.drop(index=7))  # frame 7 absent altogether
    assert ref["frame"].tolist() == list(range(20))
    assert ref.loc[ref["distance_interpolated"], "frame"].tolist() == [7, 19]
    # held at 6.83 m before smoothing: the fit lands between the hold and the true 6.765 m
    assert d[18] - 0.065 < ref.loc[19, "distance_smooth_m"] < d[18]
    assert np.isfinite(ref["ttc_ref_s"]).all()


def test_extra_columns_are_kept_and_short_series_shrinks_the_window():
    table = series(8.0 - 0.065 * np.arange(5)).assign(n_points=[300, 301, 302, 303, 304])
    ref = reference_ttc(table, window=9)
    assert ref["n_points"].tolist() == [300, 301, 302, 303, 304]
    np.testing.assert_allclose(ref["closing_speed_mps"], 0.65, rtol=1e-9)


def test_all_nan_gives_nan_reference():
    ref = reference_ttc(series(np.full(10, np.nan)))
    assert ref["ttc_ref_s"].isna().all() and not ref["collision_course"].any()


# --- rear distance and lead points -----------------------------------------------------------


def bumper(x: float = 10.0) -> np.ndarray:
    """A flat rear at ``x`` metres: 5 × 4 points 0.1 m apart (y, z), reflectance 0.5."""
    y, z = np.meshgrid(np.linspace(-0.2, 0.2, 5), [-1.4, -1.3, -1.2, -1.1])
    return np.column_stack([np.full(y.size, x), y.ravel(), z.ravel(), np.full(y.size, 0.5)])


def test_rear_distance_ignores_three_stray_points_a_metre_ahead():
    strays = np.array([[9.0, -0.1, -1.2, 0.5], [9.0, 0.0, -1.2, 0.5], [9.0, 0.1, -1.2, 0.5]])
    points = np.vstack([strays, bumper(10.0)])  # 3 of 23 = 13 %: a 5 % trim alone fails
    assert rear_distance(points) == 10.0
    assert rear_distance(points[:, :3]) == 10.0


def test_rear_distance_averages_the_near_band():
    # 20 points at x = 10.00 … 10.19: band between the 5 % (10.0095) and 30 % (10.057)
    # quantiles holds x = 10.01 … 10.05 → mean 10.03
    points = bumper()
    points[:, 0] = 10.0 + 0.01 * np.arange(20)
    assert rear_distance(points) == pytest.approx(10.03, abs=1e-12)


def test_rear_distance_nan_with_too_few_points():
    assert np.isnan(rear_distance(bumper()[:4]))
    assert np.isnan(rear_distance(np.empty((0, 3))))


def test_lead_points_keeps_the_lead_car_not_the_truck_or_strays():
    truck = bumper(9.0)
    truck[:, 1] -= 3.5  # next lane
    stray = np.array([[9.0, 0.0, -1.2, 0.5]])
    scan = np.vstack([truck, stray, bumper(10.0)])
    lead = lead_points(scan)
    np.testing.assert_array_equal(lead, bumper(10.0))


def test_lead_points_rejects_a_flat_patch_far_ahead():
    # frame 77's situation: one return on the car, 15 returns of one ring on the road at 19.5 m
    ring = np.column_stack(
        [np.full(15, 19.5), np.linspace(1.2, 2.0, 15), np.full(15, -1.49), np.full(15, 0.3)]
    )
    scan = np.vstack([ring, [[4.8, 0.5, -0.91, 0.15]]])
    assert lead_points(scan).shape == (0, 4)
    assert np.isnan(rear_distance(lead_points(scan)))


def test_caveats_mention_the_shared_bias():
    assert "bias" in REFERENCE_CAVEATS and "constant-velocity" in REFERENCE_CAVEATS


# --- real sequence ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def kitti_reference(kitti_dir) -> pd.DataFrame:
    return reference_for_sequence(kitti_dir).set_index("frame")


def test_real_reference_is_plausible_on_the_rubric_frames(kitti_reference):
    ref = kitti_reference
    assert ref.index.tolist() == list(range(78))
    assert ref.loc[0, "distance_m"] == pytest.approx(8.0, abs=0.1)
    rubric = ref.loc[1:18, "ttc_ref_s"]
    assert np.isfinite(rubric).all()
    assert ((rubric > 5.0) & (rubric < 25.0)).all()
    assert ref.loc[1:18, "collision_course"].all()


def test_real_reference_has_no_collision_course_from_the_stop_on(kitti_reference):
    ref = kitti_reference
    stopped = ref.index[~ref["collision_course"]]
    onset = int(stopped.min())
    assert 52 <= onset <= 56  # cars stationary from about frame 53; measured onset: 54
    assert (stopped == np.arange(onset, 78)).all()  # stays stopped
    assert np.isposinf(ref.loc[56:, "ttc_ref_s"]).all()
    assert np.isfinite(ref.loc[: onset - 1, "ttc_ref_s"]).all()


def test_real_reference_handles_the_truncated_last_scan(kitti_reference):
    ref = kitti_reference
    last = ref.loc[77]
    assert last["scan_points"] == 69_719
    assert last["n_points"] < 5 and np.isnan(last["distance_m"])
    assert last["distance_interpolated"]
    assert last["distance_smooth_m"] == pytest.approx(4.42, abs=0.05)
    assert not ref.loc[:76, "distance_interpolated"].any()
