"""The ranking rule: which setting is best on one sensor, in one documented place."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

RANKING_RULE = (
    "Settings are ranked on one sensor by, in order: "
    "(1) invalid rate, lower first: the share of frame pairs without an estimate (no distance "
    "ratio: too few points or matches, no lead box); "
    "(2) median motion-in-depth error (MiD = 10^4 x |ln r - ln r_ref|, r the distance ratio "
    "between the two frames) over every frame pair with an estimate, approach, stopping and "
    "stationary alike, lower first; "
    "(3) mean computing time per frame (ms_compute_per_frame: cached stages at the time they "
    "took to compute, so the order in which runs filled the cache does not matter; a stage no "
    "run computed, such as the objects and lane points a sweep's warm-up fills, at its load "
    "time), lower first; (4) run_id, so that the order is deterministic "
    "for given times. A missing value (NaN) sorts last within its key. Ranks are 1..n without "
    "ties. Settings with identical estimates are ordered by measured time, which varies from "
    "machine to machine and run to run."
)
#: The metric columns (per sensor, ``{sensor}_<key>``) of the rule's first two keys.
RANKING_KEYS: tuple[str, ...] = ("invalid_rate", "mid_median")


#: Rows (bootstrap replicates) a ranking of many rows orders at once
#: (:func:`in_row_chunks`): a sort's temporaries, several arrays the size of the rows taken,
#: stay small (500 replicates of 5,600 settings at once held ≈ 0.15–0.3 GB more through a
#: report's peak).
RANK_ROWS = 64


def in_row_chunks(rank: Callable[..., np.ndarray], *arrays: np.ndarray) -> np.ndarray:
    """``rank(*arrays)`` for arrays (r, n) that ``rank`` ranks row by row (each row on its
    own), :data:`RANK_ROWS` rows at a time: the same result, one output array."""
    r = arrays[0].shape[0]
    if r <= RANK_ROWS:
        return rank(*arrays)
    first = rank(*(a[:RANK_ROWS] for a in arrays))
    out = np.empty((r, *first.shape[1:]), dtype=first.dtype)
    out[:RANK_ROWS] = first
    for start in range(RANK_ROWS, r, RANK_ROWS):
        rows = slice(start, start + RANK_ROWS)
        out[rows] = rank(*(a[rows] for a in arrays))
    return out


def ranks(invalid: np.ndarray, mid: np.ndarray, ms: np.ndarray) -> np.ndarray:
    """Ranks (1..n, last axis) by :data:`RANKING_RULE` from arrays (n,) or (r, n) (each row
    ranked on its own, :func:`in_row_chunks`) in run_id order: invalid rate, median MiD,
    time (ms)."""
    if invalid.ndim == 2:
        return in_row_chunks(_ranks, invalid, mid, ms)
    return _ranks(invalid, mid, ms)


def _ranks(invalid: np.ndarray, mid: np.ndarray, ms: np.ndarray) -> np.ndarray:
    """:func:`ranks` of all rows at once."""
    keys = [np.where(np.isnan(k), np.inf, k) for k in (invalid, mid, ms)]
    position = np.broadcast_to(np.arange(invalid.shape[-1]), invalid.shape)
    order = np.lexsort((position, keys[2], keys[1], keys[0]), axis=-1)
    out = np.empty(order.shape, dtype=np.int64)
    np.put_along_axis(out, order, position + 1, axis=-1)
    return out


def ranking_time(table: pd.DataFrame) -> pd.Series:
    """The time key of :data:`RANKING_RULE` (ms per frame): ``ms_compute_per_frame`` where
    known, else ``ms_per_frame``; works on run-level and frame-level tables."""
    if "ms_compute_per_frame" not in table:
        return table["ms_per_frame"]
    return table["ms_compute_per_frame"].fillna(table["ms_per_frame"])


def rank_runs(metrics: pd.DataFrame, sensor: str = "camera") -> pd.DataFrame:
    """``metrics`` (:func:`ttc.evaluation.metrics.run_metrics`) with a ``rank`` column
    (1 = best on ``sensor``) by :data:`RANKING_RULE`, sorted by it."""
    table = metrics.sort_values("run_id", kind="stable").reset_index(drop=True)
    table["rank"] = ranks(
        *(table[f"{sensor}_{k}"].to_numpy(dtype=float) for k in RANKING_KEYS),
        ranking_time(table).to_numpy(dtype=float),
    )
    return table.sort_values("rank", ignore_index=True)
