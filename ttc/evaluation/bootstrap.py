"""Rank intervals: a paired moving-block bootstrap over the frames of a recording.

Errors of consecutive frames are correlated: a box switch, a bad detection or a stretch of
integer-pinned keypoints lasts several frames. Resampling single frames treats 77 correlated
frames as 77 independent ones and gives intervals that are too narrow. A replicate here
concatenates blocks of ``block_length`` consecutive frames, starting at random positions
(Künsch's moving-block bootstrap), until it holds as many frames as the recording (over
several drives: within each drive, :mod:`ttc.evaluation.drives`); the same
frames are applied to every run (paired), so runs judged on the same hard frames stay
comparable.

Block length. :func:`block_length` reads it off the errors themselves: Politis & White's
automatic block length on the mean autocorrelation, over the runs, of each run's per-frame
error ranks (an invalid estimate is the worst rank), clipped to ``1..n/3`` frames. Errors
without autocorrelation give 1: the ordinary bootstrap. A fixed integer can be given
instead.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ttc.evaluation.metrics import judged_frames, run_metrics, unread_columns
from ttc.evaluation.ranking import rank_runs, ranking_time, ranks

#: Replicates, confidence level and seed of the reports' rank intervals.
N_BOOT = 500
CI = 0.9
SEED = 0
#: Runs whose (runs × replicates × frames) medians are computed at once: bounds the memory.
CHUNK_RUNS = 256


def _error_ranks(mid: np.ndarray, invalid: np.ndarray) -> np.ndarray:
    """Per run (rows), the rank of each frame's error (columns); invalid frames rank worst."""
    worst = np.where(invalid, np.inf, np.where(np.isnan(mid), -np.inf, mid))
    return np.argsort(np.argsort(worst, axis=1, kind="stable"), axis=1).astype(float)


def mean_autocorrelation(mid: np.ndarray, invalid: np.ndarray, max_lag: int) -> np.ndarray:
    """Autocorrelation (lags 0..max_lag) of each run's per-frame error ranks, averaged over
    the runs whose errors vary: ``mid`` (runs × frames, NaN: none), ``invalid`` (bool, the
    worst rank)."""
    x = _error_ranks(mid, invalid)
    x = x - x.mean(axis=1, keepdims=True)
    var = np.sum(x**2, axis=1)
    x, var = x[var > 0], var[var > 0]
    if not len(x):
        return np.r_[1.0, np.zeros(max_lag)]
    lags = range(1, max_lag + 1)
    return np.r_[1.0, [np.mean(np.sum(x[:, k:] * x[:, :-k], axis=1) / var) for k in lags]]


def block_length(mid: np.ndarray, invalid: np.ndarray) -> int:
    """Moving-block length (frames) for errors ``mid`` (runs × frames, NaN: none) with
    ``invalid`` (runs × frames, bool): Politis & White's (2004) automatic choice, with
    Patton, Politis & White's (2009) constant for the moving-block bootstrap, applied to the
    runs' mean autocorrelation (:func:`mean_autocorrelation`); clipped to ``1..n // 3``.

    The autocorrelation is cut where it falls inside ±2/√n (lag ``m``) and tapered by the
    flat-top kernel over ``2m`` lags; ``L = (2 G² / D)^{1/3} n^{1/3}`` with
    ``G = Σ λ(k/2m) |k| ρ(k)`` and ``D = 4/3 (Σ λ(k/2m) ρ(k))²``. (The ``arch`` package has the
    same estimator, but would bring statsmodels along for fifteen lines.)
    """
    n = mid.shape[1]
    if n < 4:
        return 1
    rho = mean_autocorrelation(mid, invalid, n // 3)
    inside = np.nonzero(np.abs(rho[1:]) < 2.0 / np.sqrt(n))[0]
    m = int(inside[0]) + 1 if len(inside) else n // 3
    k = np.arange(1, min(2 * m, n // 3) + 1)
    taper = np.clip(2.0 * (1.0 - k / (2 * m)), 0.0, 1.0)
    g = 2.0 * np.sum(taper * k * rho[k])
    d = 4.0 / 3.0 * (1.0 + 2.0 * np.sum(taper * rho[k])) ** 2
    length = (2.0 * g**2 / d) ** (1.0 / 3.0) * n ** (1.0 / 3.0) if d > 0 else 1.0
    return int(np.clip(np.ceil(length), 1, n // 3))


def block_draws(
    n: int,
    n_boot: int,
    length: int,
    rng: np.random.Generator,
    strata: np.ndarray | None = None,
) -> np.ndarray:
    """Frame positions (n_boot × n) of moving-block replicates: blocks of ``length``
    consecutive positions from uniformly drawn starts, concatenated and cut to ``n``.
    ``length`` 1 is the ordinary (independent) bootstrap. ``strata`` (n,), e.g. the drive of
    each position: each stratum is resampled on its own from its own positions (a block never
    spans two) and keeps its number of positions (:mod:`ttc.evaluation.drives`)."""
    if strata is not None:
        strata = np.asarray(strata)
        parts = []
        for value in pd.unique(strata):
            own = np.flatnonzero(strata == value)
            parts.append(own[block_draws(len(own), n_boot, length, rng)])
        return np.concatenate(parts, axis=1)
    length = int(np.clip(length, 1, n))
    blocks = -(-n // length)
    starts = rng.integers(0, n - length + 1, size=(n_boot, blocks))
    draws = starts[:, :, None] + np.arange(length)
    return draws.reshape(n_boot, -1)[:, :n]


def replicate_medians(values: np.ndarray, draws: np.ndarray) -> np.ndarray:
    """Median of ``values`` (runs × frames, NaN ignored; NaN where a replicate draws no
    value) over each replicate's frames (``draws``, replicates × n frame indices):
    replicates × runs, computed in chunks of :data:`CHUNK_RUNS` runs.

    Each run's values are sorted once; a replicate draws each sorted value as often as it
    draws its frame, so the cumulated counts along the sorted values locate the two middle
    positions: the values ``np.nanmedian`` of the drawn values gives, bit for bit, without
    sorting each replicate's draws (``grand`` 0–18's FP.6 ranking, 5,600 runs × 500
    replicates × 18 frames: 0.69 → 0.26 s)."""
    n_boot, n_frames = draws.shape[0], values.shape[1]
    counts = np.zeros((n_boot, n_frames), dtype=np.int16 if draws.shape[1] < 2**15 else np.int64)
    np.add.at(counts, (np.arange(n_boot)[:, None], draws), 1)  # replicates × frames drawn
    order = np.argsort(values, axis=1)  # NaN last
    ordered = np.take_along_axis(values, order, axis=1)
    out = np.empty((n_boot, values.shape[0]))
    for start in range(0, values.shape[0], CHUNK_RUNS):
        part = slice(start, start + CHUNK_RUNS)
        drawn = counts[:, order[part]] * ~np.isnan(ordered[part])  # replicates × runs × frames
        cum = np.cumsum(drawn, axis=-1, dtype=counts.dtype)
        n = cum[..., -1]  # values drawn
        lo, hi = (
            np.minimum(np.count_nonzero(cum <= k[..., None], axis=-1), n_frames - 1)
            for k in ((n - 1) // 2, n // 2)
        )
        runs = np.arange(ordered[part].shape[0])[None, :]
        middle = (ordered[part][runs, lo] + ordered[part][runs, hi]) / 2
        out[:, part] = np.where(n > 0, middle, np.nan)
    return out


def replicate_means(values: np.ndarray, draws: np.ndarray) -> np.ndarray:
    """Mean of ``values`` (runs × frames, NaN: not applicable) over each replicate's frames
    (``draws``, replicates × n): replicates × runs, NaN where nothing applies."""
    weights = np.zeros((draws.shape[0], values.shape[1]))
    np.add.at(weights, (np.arange(draws.shape[0])[:, None], draws), 1.0)
    present = ~np.isnan(values)
    total = weights @ np.where(present, values, 0.0).T
    count = weights @ present.T.astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(count > 0, total / count, np.nan)


def replicate_metrics(
    invalid: np.ndarray, mid: np.ndarray, ms: np.ndarray, draws: np.ndarray
) -> dict[str, np.ndarray]:
    """The ranking rule's keys (replicates × runs) on each replicate's frames (``draws``):
    ``invalid_rate``, ``mid_median`` and ``ms`` (mean time) from per-frame ``invalid``
    (bool), ``mid`` and ``ms`` (runs × frames)."""
    return {
        "invalid_rate": replicate_means(invalid.astype(float), draws),
        "mid_median": replicate_medians(np.where(invalid, np.nan, mid), draws),
        "ms": replicate_means(ms, draws),
    }


def rank_replicates(
    invalid: np.ndarray, mid: np.ndarray, ms: np.ndarray, draws: np.ndarray
) -> np.ndarray:
    """Ranks (replicates × runs) by :data:`~ttc.evaluation.ranking.RANKING_RULE` on each
    replicate's frames (:func:`replicate_metrics`)."""
    keys = replicate_metrics(invalid, mid, ms, draws)
    return ranks(keys["invalid_rate"], keys["mid_median"], keys["ms"])


def rank_interval(replicate_ranks: np.ndarray, ci: float = CI) -> tuple[np.ndarray, np.ndarray]:
    """The ``ci`` percentile interval (lower, higher order statistic) of each run's rank
    over the replicates (replicates × runs)."""
    q = (1.0 - ci) / 2.0
    return (
        np.quantile(replicate_ranks, q, axis=0, method="lower"),
        np.quantile(replicate_ranks, 1.0 - q, axis=0, method="higher"),
    )


def bootstrap_rank_intervals(
    frames: pd.DataFrame,
    reference: pd.DataFrame,
    n_boot: int = N_BOOT,
    seed: int = SEED,
    sensor: str = "camera",
    ci: float = CI,
    block: int | str = "auto",
    metrics: pd.DataFrame | None = None,
    **thresholds: float,
) -> pd.DataFrame:
    """Paired moving-block bootstrap over frames of each run's rank and ranking metrics.

    Returns per ``run_id``: the point ``rank``, ``rank_lo`` / ``rank_hi`` (the ``ci``
    interval), ``rank_median``, ``block_length`` (frames; ``block="auto"``:
    :func:`block_length`, or the integer given), and the ``ci`` interval (``_lo`` / ``_hi``)
    of ``{sensor}_invalid_rate``, ``{sensor}_mid_median``, ``{sensor}_outlier_rate`` and
    ``{sensor}_medae_rel``. ``thresholds`` go to :func:`~ttc.evaluation.metrics.run_metrics`
    (``outlier_rel``, ``false_alarm_s``, ``warning_s``). Deterministic for a ``seed``.
    ``metrics``: that :func:`~ttc.evaluation.metrics.run_metrics` of ``frames`` (with the same
    thresholds) when the caller has it, for the point ranks (else computed here).
    """
    t = judged_frames(frames.drop(columns=unread_columns(frames)), reference, **thresholds)
    t["ms_rank"] = ranking_time(t)
    t[f"{sensor}_approach_rel_err"] = t[f"{sensor}_rel_err"].where(t["regime"] == "approach")

    def matrix(col: str, table: pd.DataFrame = t) -> np.ndarray:
        return table.pivot(index="run_id", columns="frame", values=col).to_numpy(float)

    runs = np.sort(t["run_id"].unique())
    invalid = matrix(f"{sensor}_invalid") > 0.5
    mid, ms = matrix(f"{sensor}_mid"), matrix("ms_rank")
    length = block_length(mid, invalid) if block == "auto" else int(block)
    strata = None  # several drives (stacked, :mod:`ttc.evaluation.drives`): within each
    if "drive" in t:
        columns = t.pivot(index="run_id", columns="frame", values="frame").columns
        strata = t.groupby("frame")["drive"].first().reindex(columns).to_numpy()
    draws = block_draws(mid.shape[1], n_boot, length, np.random.default_rng(seed), strata)
    values = replicate_metrics(invalid, mid, ms, draws)
    replicate_ranks = ranks(values["invalid_rate"], values["mid_median"], values.pop("ms"))
    values["outlier_rate"] = replicate_means(matrix(f"{sensor}_outlier"), draws)
    values["medae_rel"] = replicate_medians(matrix(f"{sensor}_approach_rel_err"), draws)
    del t, matrix  # the judged rows (also the default of matrix): freed before run_metrics

    if metrics is None:
        metrics = run_metrics(frames, reference, **thresholds)
    point = rank_runs(metrics, sensor)
    out = pd.DataFrame({"run_id": runs}).merge(point[["run_id", "rank"]], on="run_id")
    out["rank_lo"], out["rank_hi"] = rank_interval(replicate_ranks, ci)
    out["rank_median"] = np.median(replicate_ranks, axis=0)
    out["block_length"] = length
    q = [(1.0 - ci) / 2.0, 1.0 - (1.0 - ci) / 2.0]
    for name, v in values.items():
        out[f"{sensor}_{name}_lo"], out[f"{sensor}_{name}_hi"] = nan_interval(v, q[0], q[1])
    return out


def nan_interval(values: np.ndarray, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """``np.nanquantile(values, lo, axis=0, method="lower")`` and ``(…, hi, …,
    method="higher")`` of ``values`` (replicates × runs; NaN where a run's replicate has
    none): the same order statistics from one sort of all columns, not a call per column
    (numpy's ``apply_along_axis``: 1.5 s for ``grand``'s 5,600 runs); NaN for an all-NaN
    run."""
    ordered = np.sort(values, axis=0)  # NaN last
    n = np.count_nonzero(~np.isnan(values), axis=0)

    def at(index: np.ndarray) -> np.ndarray:
        picked = np.take_along_axis(ordered, np.maximum(index, 0)[None, :], axis=0)[0]
        return np.where(n > 0, picked, np.nan)

    below = np.floor((n - 1) * np.float64(lo)).astype(np.intp)  # numpy's "lower" index
    above = np.ceil((n - 1) * np.float64(hi)).astype(np.intp)  # and its "higher" one
    return at(below), at(above)


def tied_for_first(intervals: pd.DataFrame) -> int:
    """How many settings cannot be told from the best: their rank interval includes 1."""
    return int((intervals["rank_lo"] <= 1).sum())
