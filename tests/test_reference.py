"""Reference TTC: synthetic distance series with known kinematics, and the real sequence."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from experiments.summary.references import recording_scans
from ttc.evaluation.errors import mid_error
from ttc.evaluation.lead_distance import lead_points, rear_distance
from ttc.evaluation.reference import REFERENCE_CAVEATS, reference_for_sequence, reference_ttc

DT = 0.1


def series(d: np.ndarray) -> pd.DataFrame:
    return pd.DataFrame({"frame": np.arange(len(d)), "distance_m": d})


# --- synthetic distance series ---------------------------------------------------------------


def braking(v0: float, a: float, n: int, d0: float = 8.0) -> tuple[np.ndarray, float]:
    """Distances (m) of a car closing at ``v0`` m/s, braking at ``a`` m/s² to a standstill
    and then standing, sampled every ``DT``; and the stop instant (s)."""
    stop = v0 / a
    t = np.minimum(np.arange(n) * DT, stop)
    return d0 - v0 * t + 0.5 * a * t**2, stop


def two_frame_ttc(d: np.ndarray, dt: float = DT) -> np.ndarray:
    """What a two-frame constant-velocity estimator outputs from exact distances, per pair."""
    with np.errstate(divide="ignore"):
        return np.r_[np.nan, d[1:] * dt / (d[:-1] - d[1:])]


@pytest.mark.parametrize(("v0", "a"), [(0.8, 0.25), (0.9, 0.7), (0.6, 0.3)])
def test_braking_to_a_stop_matches_the_two_frame_estimator_and_finds_the_stop(v0, a):
    d, stop = braking(v0, a, 60)
    ref = reference_ttc(series(d))
    exact = two_frame_ttc(d)
    approaching = ref["collision_course"].to_numpy()
    assert approaching.sum() >= 8
    np.testing.assert_allclose(ref["ttc_ref_s"][approaching], exact[approaching], rtol=0.005)
    # the stop: the first standing frame is the first sample at or after the stop instant
    first_standing = int(np.ceil(stop / DT - 1e-9))
    stationary = ref.loc[ref["regime"] == "stationary", "frame"]
    assert abs(int(stationary.min()) - 1 - first_standing) <= 1
    assert (ref.loc[stationary.index, "ratio_ref"] == 1.0).all()
    assert np.isposinf(ref.loc[stationary.index, "ttc_ref_s"]).all()
    assert set(ref["regime"]) == {"approach", "stopping", "stationary"}


def test_a_perfect_estimator_has_zero_mid_in_every_regime():
    d, _ = braking(0.8, 0.25, 60)
    ref = reference_ttc(series(d))
    mid = mid_error(d[:-1] / d[1:], ref["ratio_ref"].to_numpy()[1:])
    per_regime = pd.Series(mid).groupby(ref["regime"].to_numpy()[1:]).max()
    assert set(per_regime.index) == {"approach", "stopping", "stationary"}
    assert (per_regime < 1e-6).all()


def test_noisy_braking_stays_close_with_honest_uncertainty():
    d, stop = braking(0.8, 0.25, 78)
    rng = np.random.default_rng(0)
    noisy = d + rng.normal(0.0, 0.005, len(d))  # 5 mm
    ref = reference_ttc(series(noisy))
    assert ref["noise_sd_m"].iloc[0] == pytest.approx(0.005, rel=0.3)
    stationary = ref.loc[ref["regime"] == "stationary", "frame"]
    # two frames before the stop the car is a/2 (0.2 s)² = 5 mm (one sigma) from standing:
    # the data cannot place the stop closer than that
    assert abs(int(stationary.min()) - 1 - int(np.ceil(stop / DT))) <= 2
    judged = ref["judgeable"].to_numpy()
    assert judged.sum() >= 10
    err = np.abs(ref["ttc_ref_s"].to_numpy()[judged] / two_frame_ttc(d)[judged] - 1.0)
    assert np.median(err) < 0.05
    # the stated uncertainty covers the error on most judged frames (2 sigma)
    sd = (ref["ttc_ref_sd_s"] / ref["ttc_ref_s"]).to_numpy()[judged]
    assert np.mean(err <= 2 * sd) >= 0.8
    assert (ref.loc[~ref["judgeable"] & ref["collision_course"], "ttc_ref_sd_s"] > 0).all()


def test_steady_approach_has_no_stop():
    d = 8.0 - 0.065 * np.arange(40)
    ref = reference_ttc(series(d))
    assert (ref["regime"] == "approach").all()
    np.testing.assert_allclose(ref["ttc_ref_s"][1:], two_frame_ttc(d)[1:], rtol=1e-9)
    np.testing.assert_allclose(ref["closing_speed_mps"][1:], 0.65, rtol=1e-9)


def test_real_frame_times_set_each_pairs_dt():
    d = 8.0 - 0.065 * np.arange(30)
    times = np.cumsum(np.r_[0.0, np.where(np.arange(29) % 2, 0.1, 0.2)])
    ref = reference_ttc(series(d), times=times)
    np.testing.assert_allclose(ref["dt_s"][1:], np.diff(times))
    # the same distance step over twice the time: twice the TTC
    np.testing.assert_allclose(ref["ttc_ref_s"][1:], d[1:] * np.diff(times) / 0.065, rtol=1e-9)


def test_receding_is_no_collision_course():
    ref = reference_ttc(series(5.0 + 0.05 * np.arange(20)))
    assert np.isposinf(ref["ttc_ref_s"][1:]).all() and not ref["collision_course"].any()
    np.testing.assert_allclose(ref["closing_speed_mps"][1:], -0.5, rtol=1e-9)


def test_nan_in_the_middle_is_interpolated_and_flagged():
    d = 8.0 - 0.065 * np.arange(20)
    d_nan = d.copy()
    d_nan[10] = np.nan
    ref = reference_ttc(series(d_nan))
    assert ref["distance_interpolated"].tolist() == [i == 10 for i in range(20)]
    assert np.isnan(ref.loc[10, "distance_m"])
    assert ref.loc[10, "distance_smooth_m"] == pytest.approx(8.0 - 0.65)
    np.testing.assert_allclose(ref["ttc_ref_s"][1:], d[1:] / 0.65, rtol=1e-9)


def test_missing_frame_and_trailing_nan_are_filled_and_flagged():
    d = pd.Series(8.0 - 0.065 * np.arange(20), index=np.arange(20))
    d[19] = np.nan  # truncated last scan
    ref = reference_ttc(d.drop(index=7))  # frame 7 absent altogether
    assert ref["frame"].tolist() == list(range(20))
    assert ref.loc[ref["distance_interpolated"], "frame"].tolist() == [7, 19]
    # held at 6.83 m before smoothing: the fit lands between the hold and the true 6.765 m
    assert d[18] - 0.065 < ref.loc[19, "distance_smooth_m"] < d[18]
    assert np.isfinite(ref["ttc_ref_s"][1:]).all()


def test_extra_columns_are_kept_and_short_series_shrinks_the_window():
    table = series(8.0 - 0.065 * np.arange(5)).assign(n_points=[300, 301, 302, 303, 304])
    ref = reference_ttc(table, window=9)
    assert ref["n_points"].tolist() == [300, 301, 302, 303, 304]
    np.testing.assert_allclose(ref["closing_speed_mps"][1:], 0.65, rtol=1e-9)


def test_all_nan_gives_nan_reference():
    ref = reference_ttc(series(np.full(10, np.nan)))
    assert ref["ttc_ref_s"].isna().all() and not ref["collision_course"].any()
    assert not ref["judgeable"].any()


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
    return reference_for_sequence(recording_scans(kitti_dir, 77)).set_index("frame")


def test_real_reference_is_plausible_on_the_rubric_frames(kitti_reference):
    ref = kitti_reference
    assert ref.index.tolist() == list(range(78))
    assert ref.loc[0, "distance_m"] == pytest.approx(8.0, abs=0.1)
    rubric = ref.loc[1:18, "ttc_ref_s"]
    assert np.isfinite(rubric).all()
    assert ((rubric > 5.0) & (rubric < 25.0)).all()
    assert ref.loc[1:18, "collision_course"].all()


def test_real_reference_finds_the_stop_where_the_rear_distance_goes_flat(kitti_reference):
    ref = kitti_reference
    stationary = ref.index[ref["regime"] == "stationary"]
    first_standing = int(stationary.min()) - 1
    assert 51 <= first_standing <= 53  # raw rear distance flat from frame 52 (4.404 m)
    assert (stationary == np.arange(first_standing + 1, 78)).all()  # stays stopped
    assert (ref.loc[stationary, "ratio_ref"] == 1.0).all()
    assert np.isposinf(ref.loc[stationary, "ttc_ref_s"]).all()
    # the smoothing does not lag the stop: no finite reference TTC after it
    assert not ref.loc[first_standing + 1 :, "collision_course"].any()
    assert set(ref.loc[45:first_standing, "regime"]) <= {"approach", "stopping"}
    assert (ref.loc[1:40, "regime"] == "approach").all()


def test_real_reference_uncertainty_is_small_while_closing(kitti_reference):
    ref = kitti_reference
    assert 0.003 < ref["noise_sd_m"].iloc[0] < 0.02  # about 1 cm of rear-distance noise
    rel = (ref["ttc_ref_sd_s"] / ref["ttc_ref_s"]).loc[1:40]
    assert (rel < 0.1).all() and ref.loc[1:40, "judgeable"].all()


def test_real_reference_handles_the_truncated_last_scan(kitti_reference):
    ref = kitti_reference
    last = ref.loc[77]
    assert last["scan_points"] == 69_719
    assert last["n_points"] < 5 and np.isnan(last["distance_m"])
    assert last["distance_interpolated"]
    assert last["distance_smooth_m"] == pytest.approx(4.42, abs=0.05)
    assert not ref.loc[:76, "distance_interpolated"].any()


def test_stored_reference_is_read_back_not_recomputed(kitti_dir, kitti_reference, tmp_path):
    """The reference kept in the stage cache loads in a fresh cache (no in-memory copy) as
    it was computed: text columns stored as strings, so the entry is not discarded."""
    from experiments.summary.references import sequence_reference  # noqa: PLC0415
    from ttc.engine.cache import StageCache  # noqa: PLC0415

    first = sequence_reference(kitti_dir, StageCache(tmp_path, memory_mb=0))
    fresh = StageCache(tmp_path, memory_mb=0)
    again = sequence_reference(kitti_dir, fresh)
    assert fresh.corrupt_entries == 0
    assert fresh.load("reference", next(tmp_path.glob("reference/*/*.arr")).stem) is not None
    pd.testing.assert_frame_equal(again, first)
    assert again["regime"].tolist() == kitti_reference["regime"].tolist()
