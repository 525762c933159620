"""Rank intervals from the moving-block bootstrap: coverage on simulated settings whose errors
are autocorrelated, against the independent bootstrap it replaced."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from ttc import evaluation as ev
from ttc.evaluation.bootstrap import CHUNK_RUNS, replicate_medians


def ar1(rng: np.random.Generator, shape: tuple[int, int], rho: float) -> np.ndarray:
    """Standard-normal AR(1) series along the last axis with lag-1 correlation ``rho``."""
    e = rng.standard_normal(shape)
    z = np.empty(shape)
    z[:, 0] = e[:, 0]
    for t in range(1, shape[1]):
        z[:, t] = rho * z[:, t - 1] + np.sqrt(1.0 - rho**2) * e[:, t]
    return z


def simulated_errors(rng: np.random.Generator, rho: float, n: int = 77) -> np.ndarray:
    """MiD-like errors (8 settings × n frames): setting i's median is 10 · 1.1^i (its true
    rank is i + 1), with autocorrelated noise of its own and a share common to all settings
    (frames that are hard for everyone)."""
    mu = 10.0 * 1.1 ** np.arange(8)
    z = 0.6 * ar1(rng, (8, n), rho) + 0.5 * ar1(rng, (1, n), rho)
    return mu[:, None] * np.exp(z)


def coverage(rho: float, block: int | None, repeats: int = 100, n_boot: int = 300) -> float:
    """Share of (repeat, setting) whose 90 % rank interval holds the true rank."""
    rng = np.random.default_rng(1)
    true = np.arange(1, 9)
    hits = []
    for _ in range(repeats):
        mid = simulated_errors(rng, rho)
        invalid = np.zeros(mid.shape, dtype=bool)
        length = ev.block_length(mid, invalid) if block is None else block
        draws = ev.block_draws(mid.shape[1], n_boot, length, rng)
        lo, hi = ev.rank_interval(ev.rank_replicates(invalid, mid, np.ones(mid.shape), draws))
        hits.append((lo <= true) & (true <= hi))
    return float(np.mean(hits))


def test_block_bootstrap_covers_the_true_rank_where_the_independent_one_falls_short():
    block = coverage(rho=0.8, block=None)
    independent = coverage(rho=0.8, block=1)
    assert block >= 0.85
    assert independent < 0.80  # measured 0.76: frames are not independent draws
    assert block - independent > 0.05


def test_block_length_follows_the_autocorrelation():
    rng = np.random.default_rng(3)
    invalid = np.zeros((8, 77), dtype=bool)
    iid = ev.block_length(simulated_errors(rng, 0.0), invalid)
    correlated = ev.block_length(simulated_errors(rng, 0.8), invalid)
    assert iid <= 2 < 5 <= correlated <= 77 // 3


def test_block_draws_are_runs_of_consecutive_frames():
    draws = ev.block_draws(20, 50, 4, np.random.default_rng(0))
    assert draws.shape == (50, 20) and draws.min() >= 0 and draws.max() <= 19
    steps = np.diff(draws.reshape(50, 5, 4), axis=2)
    assert (steps == 1).all()
    assert (ev.block_draws(20, 5, 1, np.random.default_rng(0)) < 20).all()


def test_invalid_frames_rank_a_setting_behind_a_valid_one():
    mid = np.array([[1.0, 1.0, 1.0, 1.0], [50.0, 50.0, 50.0, 50.0]])
    invalid = np.array([[False, True, False, False], [False] * 4])
    draws = np.array([[0, 1, 2, 3], [0, 0, 2, 3]])  # the second replicate misses frame 1
    ranks = ev.rank_replicates(invalid, mid, np.ones(mid.shape), draws)
    assert ranks.tolist() == [[2, 1], [1, 2]]


def test_bootstrap_on_a_sweep_table_is_deterministic():
    from tests.test_metrics import REFERENCE, hand_table

    first = ev.bootstrap_rank_intervals(hand_table(), REFERENCE, n_boot=200, seed=4)
    again = ev.bootstrap_rank_intervals(hand_table(), REFERENCE, n_boot=200, seed=4)
    assert first.equals(again)
    assert (first["rank_lo"] <= first["rank"]).all() and (first["rank"] <= first["rank_hi"]).all()
    assert {"camera_invalid_rate_lo", "camera_mid_median_hi", "block_length"} <= set(first)
    assert ev.tied_for_first(first) >= 1


@pytest.mark.parametrize("rho", [0.0, 0.8])
def test_point_ranks_sit_inside_their_intervals(rho):
    rng = np.random.default_rng(5)
    mid = simulated_errors(rng, rho)
    invalid = np.zeros(mid.shape, dtype=bool)
    draws = ev.block_draws(mid.shape[1], 200, ev.block_length(mid, invalid), rng)
    lo, hi = ev.rank_interval(ev.rank_replicates(invalid, mid, np.ones(mid.shape), draws))
    point = ev.rank_replicates(invalid, mid, np.ones(mid.shape), np.arange(77)[None])[0]
    assert ((lo <= point) & (point <= hi)).all()


def test_replicate_medians_are_numpy_s_nanmedian_bit_for_bit() -> None:
    """Runs with NaN, ties, an all-NaN run and a replicate that draws only NaN frames: each
    replicate's median is ``np.nanmedian`` of the values it draws (NaN where none), in more
    runs than one chunk."""
    rng = np.random.default_rng(3)
    runs, frames, n_boot = CHUNK_RUNS + 7, 9, 40
    values = np.round(rng.gamma(2.0, 3.0, size=(runs, frames)), 1)  # rounded: ties
    values[rng.random(values.shape) < 0.3] = np.nan
    values[0] = np.nan
    values[1, 2:] = np.nan  # only frames 0 and 1 hold values
    draws = rng.integers(0, frames, size=(n_boot, frames))
    draws[0] = 5  # the first replicate draws frame 5 only: NaN for run 1
    got = replicate_medians(values, draws)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices
        expected = np.nanmedian(values[:, draws], axis=-1).T
    assert got.shape == (n_boot, runs)
    assert np.isnan(got[0, 1]) and np.isnan(got[:, 0]).all()
    assert np.array_equal(got, expected, equal_nan=True)
