"""The time a frame cost: ``ms_per_frame`` (the sum of a row's stage times) and
``ms_compute_per_frame`` (cached stages' load times replaced by the median time of computing
them; definition in :mod:`ttc.evaluation.errors`).

The medians come from a small table per cached stage, the times it was computed (not loaded
from the cache) counted by stage inputs, frame and value (:func:`stage_time_counts`), so the
rows of a sweep too large for one frame can be counted a part at a time, the counts put
together (:func:`join_counts`) and looked up for the judged rows only (:func:`compute_times`).
A median over the counts is the median over the rows they count (:func:`weighted_median`).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from ttc.settings import CACHED_STAGES

#: Time columns derived from the stage times, never summed into them.
DERIVED_TIME_COLUMNS: tuple[str, ...] = ("ms_per_frame", "ms_compute_per_frame")
#: Cached stage → (time column, cache flag column, axes its cache key depends on besides the
#: frame), from :data:`ttc.settings.CACHED_STAGES`.
CACHED_STAGE_INPUTS: dict[str, tuple[str, str, tuple[str, ...]]] = {
    s.name: (s.time_column, s.cached_column, s.axes) for s in CACHED_STAGES
}
#: Columns of a count table after the stage's axes: frame, a computed time (ms), rows (n).
COUNT_COLUMNS: tuple[str, ...] = ("frame", "ms", "n")

StageCounts = dict[str, pd.DataFrame]


def stage_time_columns(frames: pd.DataFrame) -> list[str]:
    """The per-stage time columns (``ms_*``, ms) of ``frames``: not the derived totals."""
    return [c for c in frames.columns if c.startswith("ms_") and c not in DERIVED_TIME_COLUMNS]


def stage_time_counts(frames: pd.DataFrame) -> StageCounts:
    """Per cached stage whose time and flag columns ``frames`` has: its computed times (rows
    whose flag is false and time not NaN) counted, one row per (stage axes ``frames`` has,
    ``frame``, ``ms``) with ``n`` the rows (NaN axis values kept as a value), in the order of
    each one's first row. Each column is coded once (:func:`pandas.factorize`) for every
    stage, and the counting is on the codes (``grand`` 0–18: 3.7 M rows, 4 s as a group-by of
    the string columns per stage)."""
    out = {}
    codes: dict[str, np.ndarray] = {}

    def coded(column: str) -> np.ndarray:
        if column not in codes:
            codes[column] = pd.factorize(frames[column], use_na_sentinel=False)[0]
        return codes[column]

    for name, (ms, flag, inputs) in CACHED_STAGE_INPUTS.items():
        if ms not in frames or flag not in frames:
            continue
        keys = [c for c in inputs if c in frames]
        computed = ~frames[flag].astype(bool).to_numpy() & frames[ms].notna().to_numpy()
        rows = np.flatnonzero(computed)
        first, n = _first_rows([coded(c)[rows] for c in [*keys, "frame", ms]] if len(rows) else [])
        taken = {c: frames[c].take(rows[first]) for c in keys + ["frame"]}
        table = pd.DataFrame({**taken, "ms": frames[ms].take(rows[first]), "n": n})
        out[name] = table.reset_index(drop=True)
    return out


def group_codes(codes: list[np.ndarray]) -> np.ndarray:
    """(n,) int64: each row's distinct combination of ``codes`` (each (n,) int ≥ 0, e.g.
    :func:`pandas.factorize` of a column), numbered 0, 1, ... in the order first seen."""
    group = np.zeros(len(codes[0]) if codes else 0, dtype=np.int64)
    for c in codes:  # (group, code) pairs renumbered: the numbers stay below n²
        group = pd.factorize(group * (int(c.max(initial=0)) + 1) + c)[0]
    return group


def _first_rows(codes: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(the first row of each distinct combination of ``codes`` (:func:`group_codes`), in the
    order first seen; (groups,) int64 how many rows have it)."""
    group = group_codes(codes)
    _, first = np.unique(group, return_index=True)  # groups numbered as first seen
    return first, np.bincount(group).astype(np.int64)


def join_counts(parts: Iterable[StageCounts]) -> StageCounts:
    """The counts of several parts of the rows as one (stage axes a part lacks: NaN)."""
    tables: dict[str, list[pd.DataFrame]] = {}
    for counts in parts:
        for name, table in counts.items():
            tables.setdefault(name, []).append(table)
    return {name: pd.concat(t, ignore_index=True) for name, t in tables.items()}


def weighted_median(counts: pd.DataFrame, keys: list[str]) -> pd.Series:
    """The median of ``ms`` over the rows ``counts`` counts (value ``ms`` ``n`` times) per
    group of ``keys`` (one or more; a Series indexed by them, groups with a NaN key left out).
    Exactly pandas' median of the rows themselves: the middle value, or the mean of the two
    middle ones for an even count."""
    summed = counts.groupby([*keys, "ms"], sort=True)["n"].sum()  # each group's values ascending
    groups = summed.index.droplevel("ms")
    if summed.empty:
        return pd.Series([], index=groups, dtype=float)
    n = summed.to_numpy(dtype=np.int64)
    value = summed.index.get_level_values("ms").to_numpy(dtype=float)
    end = np.cumsum(n)  # the rows counted, all groups one after the other
    firsts = np.flatnonzero(np.r_[True, np.diff(pd.factorize(groups)[0]) != 0])
    total, before = np.add.reduceat(n, firsts), end[firsts] - n[firsts]
    lo = np.searchsorted(end, before + (total - 1) // 2, side="right")  # the middle rows
    hi = np.searchsorted(end, before + total // 2, side="right")
    return pd.Series((value[hi] + value[lo]) / 2, index=groups[firsts])


def _looked_up(rows: pd.DataFrame, medians: pd.Series, keys: list[str]) -> pd.Series:
    """``medians`` (indexed by ``keys``) at each row of ``rows`` (NaN where none), rows' index."""
    right = medians.rename("median").reset_index()
    right.columns = [*keys, "median"]
    found = rows[keys].merge(right, on=keys, how="left", validate="many_to_one")
    return pd.Series(found["median"].to_numpy(), index=rows.index)


def compute_times(rows: pd.DataFrame, counts: StageCounts) -> pd.Series:
    """``ms_compute_per_frame`` (ms) of each row of ``rows``: its ``ms_per_frame`` with a
    cached stage's time replaced by the median computed time of the same stage inputs on the
    same frame, else on any frame, in ``counts`` (:func:`stage_time_counts` of the rows to look
    up over, which may be many more than ``rows``), else kept (nothing computed it)."""
    total = rows[stage_time_columns(rows)].sum(axis=1)
    for name, (ms, flag, inputs) in CACHED_STAGE_INPUTS.items():
        if ms not in rows or flag not in rows:
            continue
        keys = [c for c in inputs if c in rows]
        table = counts.get(name, pd.DataFrame(columns=[*keys, *COUNT_COLUMNS]))
        table = table.reindex(columns=[*keys, *COUNT_COLUMNS])
        cached = rows[flag].astype(bool)
        same_frame = _looked_up(rows, weighted_median(table, [*keys, "frame"]), [*keys, "frame"])
        if keys:
            any_frame = _looked_up(rows, weighted_median(table, keys), keys)
        else:
            overall = weighted_median(table.assign(all=0), ["all"])
            any_frame = overall.iloc[0] if len(overall) else np.nan
        computed = same_frame.fillna(any_frame)
        total = total + (computed - rows[ms]).where(cached & computed.notna(), 0.0)
    return total


def with_compute_times(frames: pd.DataFrame) -> pd.DataFrame:
    """``frames`` with ``ms_compute_per_frame`` per row, the cached stages' computing times
    looked up over every row of ``frames``. Call it on the union of sweeps before judging a
    subset of runs, so a stage computed by a run outside the subset still has its time."""
    return frames.assign(ms_compute_per_frame=compute_times(frames, stage_time_counts(frames)))
