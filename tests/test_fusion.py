"""Fused TTC (FP.7): Kalman filters over a synthetic constant-deceleration approach with noisy
lidar and camera measurements of known variance, missing sensors, and the per-row output."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ttc.steps import fusion
from ttc.steps.fusion import FusionParams, fused_columns, kalman_fuse, noise_sds

N, DT = 60, 0.1  # frame pairs, s
D0, V0, ACCEL = 8.0, 1.0, -0.1  # m, closing m/s, closing m/s² (the lead car brakes less)
LIDAR_SD, CAMERA_SD = 0.05, 0.004  # m; ln-ratio units (≈ 0.4 % scale noise)
SKIP = 10  # frames the filter may take to settle before it is judged


def approach(seed: int) -> dict[str, np.ndarray]:
    """True distances/TTC at frames 1..N and noisy measurements of known variance."""
    rng = np.random.default_rng(seed)
    t = np.arange(N + 1) * DT
    d = D0 - V0 * t - 0.5 * ACCEL * t**2
    v = V0 + ACCEL * t
    lidar = d + rng.normal(0.0, LIDAR_SD, N + 1)
    ratio = np.exp(np.log(d[:-1] / d[1:]) + rng.normal(0.0, CAMERA_SD, N))
    return {
        "ttc": d[1:] / v[1:],
        "d": d[1:],
        "lidar0": lidar[0],
        "lidar": lidar[1:],
        "ratio": ratio,
        "ttc_lidar": lidar[1:] * DT / (lidar[:-1] - lidar[1:]),  # FP.2's constant velocity
        "ttc_camera": DT / (ratio - 1.0),  # FP.4's
    }


def median_rel_error(ttc: np.ndarray, true: np.ndarray) -> float:
    """Median |ttc − true| / true after the settling frames; an invalid TTC counts as 100 %."""
    err = np.abs(ttc - true) / true
    err[~np.isfinite(ttc) | (ttc <= 0)] = 1.0
    return float(np.median(err[SKIP:]))


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("known", [True, False], ids=["known_noise", "noise_from_run"])
def test_kalman_ca_beats_both_sensors(seed: int, known: bool) -> None:
    a = approach(seed)
    params = FusionParams(name="kalman_ca", lidar_sd=LIDAR_SD if known else 0.0,
                          camera_sd=CAMERA_SD if known else 0.0)  # fmt: skip
    track = kalman_fuse(np.full(N, DT), a["lidar"], a["ratio"], params, a["lidar0"])
    fused = median_rel_error(track.ttc, a["ttc"])
    lidar = median_rel_error(a["ttc_lidar"], a["ttc"])
    camera = median_rel_error(a["ttc_camera"], a["ttc"])
    assert fused < min(lidar, camera)
    assert fused < 0.5 * min(lidar, camera)  # clearly, not by a hair
    assert set(track.reason) == {fusion.FUSED}
    assert np.all(np.isfinite(track.ttc_sd[SKIP:])) and np.all(track.ttc_sd[SKIP:] > 0)
    # The distance ratio it reports is the state's d_prev / d: near the truth's.
    ratio_true = np.r_[D0, a["d"][:-1]] / a["d"]
    mid = 1e4 * np.abs(np.log(track.ratio) - np.log(ratio_true))[SKIP:]
    mid_camera = 1e4 * np.abs(np.log(a["ratio"]) - np.log(ratio_true))[SKIP:]
    assert np.median(mid) < np.median(mid_camera)


def test_kalman_cv_also_fuses_and_ca_tracks_the_deceleration() -> None:
    a = approach(4)
    cv = kalman_fuse(np.full(N, DT), a["lidar"], a["ratio"], FusionParams(name="kalman_cv"),
                     a["lidar0"])  # fmt: skip
    ca = kalman_fuse(np.full(N, DT), a["lidar"], a["ratio"], FusionParams(name="kalman_ca"),
                     a["lidar0"])  # fmt: skip
    camera = median_rel_error(a["ttc_camera"], a["ttc"])
    assert median_rel_error(cv.ttc, a["ttc"]) < camera
    assert cv.state.shape == (N, 2) and ca.state.shape == (N, 3)
    assert abs(np.median(ca.state[SKIP:, 2]) - ACCEL) < 0.2  # m/s²


def test_missing_sensors_keep_the_estimates_coming() -> None:
    a = approach(5)
    lidar, ratio = a["lidar"].copy(), a["ratio"].copy()
    lidar[15:25] = np.nan  # lidar lost for a second
    ratio[30:40] = np.nan  # camera lost for a second
    ratio[45] = -1.0  # a nonsense ratio is no measurement
    lidar[50:52], ratio[50:52] = np.nan, np.nan  # both lost
    track = kalman_fuse(np.full(N, DT), lidar, ratio, FusionParams(name="kalman_ca"), a["lidar0"])
    assert np.all(np.isfinite(track.ttc))
    assert set(track.reason[15:25]) == {fusion.CAMERA_ONLY}
    assert set(track.reason[30:40]) == {fusion.LIDAR_ONLY} and track.reason[45] == "lidar_only"
    assert set(track.reason[50:52]) == {fusion.PREDICTED}
    camera = median_rel_error(a["ttc_camera"], a["ttc"])
    assert median_rel_error(track.ttc, a["ttc"]) < camera
    assert track.ttc_sd[51] > track.ttc_sd[49]  # uncertainty grows without measurements


def test_filter_starts_at_the_first_lidar_distance() -> None:
    a = approach(6)
    lidar = a["lidar"].copy()
    lidar[:5] = np.nan
    track = kalman_fuse(np.full(N, DT), lidar, a["ratio"], FusionParams(name="kalman_cv"))
    assert set(track.reason[:5]) == {fusion.NO_LIDAR_YET} and np.all(np.isnan(track.ttc[:5]))
    assert np.all(np.isfinite(track.ttc[5:]))


def test_receding_gives_inf_and_an_outlier_is_gated() -> None:
    d = 8.0 + 0.05 * np.arange(1, N + 1)  # moving away at 0.5 m/s
    ratio = np.r_[8.0, d[:-1]] / d
    ratio[30] = 1.5  # a wild camera ratio
    track = kalman_fuse(np.full(N, DT), d, ratio, FusionParams(name="kalman_cv"), 8.0)
    assert np.all(np.isinf(track.ttc[SKIP:])) and set(track.reason[SKIP:]) == {fusion.RECEDING}
    assert abs(track.state[30, 1] + 0.5) < 0.1  # the wild ratio did not move the speed


def test_noise_from_the_run_is_near_the_true_noise() -> None:
    a = approach(7)
    lidar_sd, camera_sd = noise_sds(np.r_[a["lidar0"], a["lidar"]], np.log(a["ratio"]),
                                    FusionParams(name="kalman_ca"))  # fmt: skip
    assert lidar_sd == pytest.approx(LIDAR_SD, rel=0.35)
    assert camera_sd == pytest.approx(CAMERA_SD, rel=0.35)
    pinned = np.zeros(40)  # integer keypoints: every ratio exactly 1, zero spread
    assert noise_sds(np.full(40, 8.0), pinned, FusionParams(name="kalman_cv")) == (0.02, 0.002)


def test_fused_columns_fuse_the_lead_rows_in_frame_order() -> None:
    a = approach(8)
    lead = pd.DataFrame({"frame": np.arange(1, N + 1), "is_lead": True, "dt": DT,
                         "d_prev": np.r_[a["lidar0"], a["lidar"][:-1]], "d_curr": a["lidar"],
                         "camera_ratio": a["ratio"]})  # fmt: skip
    other = lead.assign(is_lead=False, d_curr=3.0)
    rows = pd.concat([lead.iloc[::-1], other], ignore_index=True)  # shuffled frame order
    out = pd.DataFrame(fused_columns(rows, FusionParams(name="kalman_ca")))
    assert list(out.columns) == list(fusion.FUSED_COLUMNS)
    fused = out[rows["is_lead"]].set_axis(rows.loc[rows["is_lead"], "frame"]).sort_index()
    direct = kalman_fuse(np.full(N, DT), a["lidar"], a["ratio"], FusionParams(name="kalman_ca"),
                         a["lidar0"])  # fmt: skip
    np.testing.assert_allclose(fused["ttc_fused"], direct.ttc)
    assert (fused["fused_reason"] != fusion.NOT_LEAD).all()
    assert (out.loc[~rows["is_lead"], "fused_reason"] == fusion.NOT_LEAD).all()
    assert out.loc[~rows["is_lead"], "ttc_fused"].isna().all()
    off = pd.DataFrame(fused_columns(rows[[]], FusionParams()))  # fusion none reads no column
    assert (off["fused_reason"] == fusion.OFF).all() and off["ttc_fused"].isna().all()
    assert len(off) == len(rows)


def test_params_are_checked() -> None:
    with pytest.raises(ValueError, match="fusion name"):
        FusionParams(name="kalman")
    with pytest.raises(ValueError, match="accel_sd"):
        FusionParams(name="kalman_cv", accel_sd=0.0)
    with pytest.raises(ValueError, match="none"):
        kalman_fuse(np.full(3, DT), np.ones(3), np.ones(3), FusionParams())
