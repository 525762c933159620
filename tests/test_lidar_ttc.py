"""FP.2 lidar TTC: exact synthetic planes, injected outliers, every degenerate case."""

from __future__ import annotations

import numpy as np
import pytest

from ttc import reasons
from ttc.steps.lidar_ttc import (
    LIDAR_ESTIMATORS,
    LidarTTCParams,
    lidar_ttc,
    rear_distance,
    ttc_from_distances,
)

ESTIMATORS = sorted(LIDAR_ESTIMATORS)
DT = 0.1  # s, 10 Hz
D_PREV = 8.0  # m
SPEED = 2.0  # m/s closing
D_CURR = D_PREV - SPEED * DT
TRUE_TTC = D_CURR / SPEED  # 3.9 s


def plane(x: float, width: float = 1.5, height: float = 1.0, step: float = 0.05) -> np.ndarray:
    """A vertical grid of points (metres) at distance ``x``: width across y, height in z."""
    y = np.arange(-width / 2, width / 2 + 1e-9, step)
    z = np.arange(-1.5, -1.5 + height + 1e-9, step)
    yy, zz = np.meshgrid(y, z)
    return np.column_stack([np.full(yy.size, x), yy.ravel(), zz.ravel()])


def bumper(x: float, rng: np.random.Generator, noise: float = 0.005) -> np.ndarray:
    """A curved rear (corners 10 cm behind the centre) with Gaussian range noise (metres)."""
    pts = plane(x)
    pts[:, 0] += 0.10 * (pts[:, 1] / 0.75) ** 2 + rng.normal(0.0, noise, len(pts))
    return pts


@pytest.mark.parametrize("name", ESTIMATORS)
def test_approaching_plane_gives_exact_ttc(name: str) -> None:
    res = lidar_ttc(plane(D_PREV), plane(D_CURR), DT, LidarTTCParams(name=name))
    assert res.reason == reasons.OK
    assert res.ttc == pytest.approx(TRUE_TTC, rel=1e-9)
    assert res.d_prev == pytest.approx(D_PREV, abs=1e-12)
    assert res.d_curr == pytest.approx(D_CURR, abs=1e-12)
    assert res.outliers_prev == res.outliers_curr == 0


@pytest.mark.parametrize("name", ESTIMATORS)
def test_ttc_scales_with_dt(name: str) -> None:
    """Skipping frames: twice the interval and twice the distance change, same TTC."""
    d_curr = D_PREV - SPEED * 2 * DT
    res = lidar_ttc(plane(D_PREV), plane(d_curr), 2 * DT, LidarTTCParams(name=name))
    assert res.ttc == pytest.approx(d_curr / SPEED, rel=1e-9)


def test_points_ahead_of_the_bumper_move_closest_only() -> None:
    rng = np.random.default_rng(0)
    prev, curr = bumper(D_PREV, rng), bumper(D_CURR, rng)
    ghosts = np.array(
        [[D_CURR - 1.0, -0.1, -1.0], [D_CURR - 1.0, 0.0, -1.0], [D_CURR - 0.95, 0.1, -1.0]]
    )
    curr = np.vstack([curr, ghosts])
    results = {n: lidar_ttc(prev, curr, DT, LidarTTCParams(name=n)) for n in ESTIMATORS}
    assert results["closest"].ttc < 0.25 * TRUE_TTC  # 1 m ahead: ~0.6 s instead of 3.9 s
    for name in ("median", "quantile_band_mean", "cluster"):
        assert results[name].reason == reasons.OK
        assert results[name].ttc == pytest.approx(TRUE_TTC, rel=0.05), name
    assert results["closest"].outliers_curr == 0
    assert results["cluster"].outliers_curr == 3
    assert results["cluster"].outliers_prev == 0
    assert results["median"].outliers_curr >= 3
    n = len(curr)
    assert results["quantile_band_mean"].outliers_curr == pytest.approx(0.75 * n, abs=3)
    assert results["quantile"].outliers_curr == int(np.sum(curr[:, 0] < results["quantile"].d_curr))


def test_outlier_counts_on_a_known_sample() -> None:
    x = np.arange(1.0, 11.0)
    pts = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    assert rear_distance(pts, LidarTTCParams(name="closest")) == (1.0, 0)
    d, n_out = rear_distance(pts, LidarTTCParams(name="quantile", quantile=0.1))
    assert d == pytest.approx(1.9) and n_out == 1  # linear interpolation: 1 + 0.9 · (2 − 1)
    # band ends are order statistics: 5 % -> 1st (lower), 30 % -> 4th (higher): mean 2.5
    assert rear_distance(pts, LidarTTCParams(name="quantile_band_mean")) == (2.5, 6)
    assert rear_distance(pts, LidarTTCParams(name="median")) == (5.5, 0)
    with_far = np.vstack([pts, [[100.0, 0.0, 0.0]]])
    # median 6, MAD 3: |100 - 6| / (1.4826 * 3) = 21 > 3.5, the rest < 1.2
    assert rear_distance(with_far, LidarTTCParams(name="median")) == (6.0, 1)
    # 1 m apart: no link at 0.2 m, every point its own cluster
    assert np.isnan(rear_distance(pts, LidarTTCParams(name="cluster")).distance)
    assert rear_distance(pts, LidarTTCParams(name="cluster", cluster_tolerance=1.01)) == (1.0, 0)
    assert rear_distance(with_far, LidarTTCParams(name="cluster", cluster_tolerance=1.01)) == (
        1.0,
        1,
    )


def test_cluster_keeps_the_largest_component() -> None:
    """A dense far cluster beats a sparse near one; its closest point is the distance."""
    near = plane(6.0, width=0.3, height=0.1)  # 7 × 3 = 21 points
    far = plane(9.0)  # 651 points
    res = rear_distance(np.vstack([near, far]), LidarTTCParams(name="cluster"))
    assert res == (9.0, len(near))


def test_accepts_reflectance_column_and_float32() -> None:
    prev = np.column_stack([plane(D_PREV), np.full(len(plane(D_PREV)), 0.5)]).astype(np.float32)
    curr = np.column_stack([plane(D_CURR), np.full(len(plane(D_CURR)), 0.5)]).astype(np.float32)
    res = lidar_ttc(prev, curr, DT, LidarTTCParams(name="median"))
    assert res.ttc == pytest.approx(TRUE_TTC, rel=1e-5)


# -- degenerate cases ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", ESTIMATORS)
def test_empty_boxes(name: str) -> None:
    p = LidarTTCParams(name=name)
    empty = np.empty((0, 3))
    res = lidar_ttc(empty, plane(D_CURR), DT, p)
    assert np.isnan(res.ttc) and res.reason == reasons.NO_LIDAR_POINTS_PREV
    assert np.isnan(res.d_prev) and res.d_curr == pytest.approx(D_CURR)
    res = lidar_ttc(plane(D_PREV), empty, DT, p)
    assert np.isnan(res.ttc) and res.reason == reasons.NO_LIDAR_POINTS_CURR
    assert np.isnan(res.d_curr) and res.d_prev == pytest.approx(D_PREV)
    res = lidar_ttc(np.empty((0, 4)), [], DT, p)
    assert np.isnan(res.ttc) and res.reason == reasons.NO_LIDAR_POINTS_PREV
    assert res.outliers_prev == res.outliers_curr == 0


@pytest.mark.parametrize("name", ESTIMATORS)
def test_no_distance_change_is_inf(name: str) -> None:
    res = lidar_ttc(plane(D_PREV), plane(D_PREV), DT, LidarTTCParams(name=name))
    assert res.ttc == np.inf and res.reason == reasons.NO_DISTANCE_CHANGE


@pytest.mark.parametrize("name", ESTIMATORS)
def test_receding_is_inf_with_distances_kept(name: str) -> None:
    res = lidar_ttc(plane(D_CURR), plane(D_PREV), DT, LidarTTCParams(name=name))
    assert res.ttc == np.inf and res.reason == reasons.RECEDING
    raw = ttc_from_distances(res.d_prev, res.d_curr, DT)
    assert raw == pytest.approx(-D_PREV / SPEED, rel=1e-9)


def test_no_cluster_reasons() -> None:
    sparse = np.column_stack([8.0 + np.arange(5.0), np.zeros(5), np.zeros(5)])  # 1 m apart
    p = LidarTTCParams(name="cluster")
    res = lidar_ttc(sparse, plane(D_CURR), DT, p)
    assert np.isnan(res.ttc) and res.reason == reasons.NO_CLUSTER_PREV
    assert res.outliers_prev == 5 and res.d_curr == pytest.approx(D_CURR)
    res = lidar_ttc(plane(D_PREV), sparse, DT, p)
    assert np.isnan(res.ttc) and res.reason == reasons.NO_CLUSTER_CURR


@pytest.mark.parametrize("name", ESTIMATORS)
def test_single_point_per_frame(name: str) -> None:
    p = LidarTTCParams(name=name, min_cluster_size=1)
    res = lidar_ttc([[D_PREV, 0.0, -1.0]], [[D_CURR, 0.0, -1.0]], DT, p)
    assert res.reason == reasons.OK and res.ttc == pytest.approx(TRUE_TTC, rel=1e-9)


@pytest.mark.parametrize("dt", [0.0, -0.1, np.nan, np.inf])
def test_bad_dt_raises(dt: float) -> None:
    with pytest.raises(ValueError, match="dt"):
        lidar_ttc(plane(D_PREV), plane(D_CURR), dt, LidarTTCParams())


def test_bad_point_shape_raises() -> None:
    with pytest.raises(ValueError, match="N, >=3"):
        lidar_ttc(np.zeros((4, 2)), plane(D_CURR), DT, LidarTTCParams())


@pytest.mark.parametrize(
    "kwargs",
    [
        {"name": "mean"},
        {"quantile": 1.5},
        {"band_low": 0.3, "band_high": 0.3},
        {"band_high": 1.2},
        {"cluster_tolerance": 0.0},
        {"min_cluster_size": 0},
    ],
)
def test_params_validation(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        LidarTTCParams(**kwargs)
