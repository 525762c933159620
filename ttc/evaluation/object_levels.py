"""Every object judged per KITTI difficulty level (:mod:`ttc.evaluation.difficulty`).

A judged pair (:func:`ttc.evaluation.object_errors.judge_objects`) carries the worse level
of its two boxes in ``difficulty``; the levels are cumulative as in KITTI (``moderate`` holds
the ``easy`` pairs, ``hard`` both) and ``all`` holds every pair, a level or not, so its rows
are exactly those of the ranking without levels. Tables and arrays in, tables out.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ttc.evaluation.difficulty import RANKING_LEVELS, in_level
from ttc.evaluation.errors import rows_where
from ttc.evaluation.object_errors import object_metrics, ranking_agreement, track_bootstrap_ranks
from ttc.evaluation.ttc_bins import OBJECT_TTC_BINS


def level_pairs(judged: pd.DataFrame, level: str) -> pd.DataFrame:
    """The pairs of ``judged`` (a ``difficulty`` column: each pair's level) counted in
    ``level`` (:data:`~ttc.evaluation.difficulty.RANKING_LEVELS`, cumulative); ``judged``
    itself (not copied) for ``all``."""
    if level == "all":
        return rows_where(judged, np.ones(len(judged), dtype=bool))
    return rows_where(judged, in_level(judged["difficulty"], level))


def judged_in_level(judged: pd.DataFrame, level: str) -> pd.DataFrame:
    """``judged`` (every pair, not copied) with its ``judged`` flag (N,) kept on the pairs
    counted in ``level`` only: to a table that reads the judged pairs alone
    (:func:`~ttc.evaluation.object_errors.object_metrics`,
    :func:`~ttc.evaluation.object_errors.track_bootstrap_ranks`), the level's pairs in their
    order, as :func:`level_pairs` gives them, without a copy of every column of them
    (``grand`` 0–18: 170 MB a level)."""
    flag = judged["judged"].to_numpy(dtype=bool) & in_level(judged["difficulty"], level)
    return judged.assign(judged=flag)


def _per_level(judged: pd.DataFrame, table) -> pd.DataFrame:
    """``table(pairs)`` of every level's judged pairs (:func:`judged_in_level`), stacked with a
    leading ``difficulty`` column."""
    parts = [table(judged_in_level(judged, level)).assign(difficulty=level)
             for level in RANKING_LEVELS]  # fmt: skip
    out = pd.concat(parts, ignore_index=True)
    return out[["difficulty", *[c for c in out.columns if c != "difficulty"]]]


def level_metrics(judged: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """:func:`~ttc.evaluation.object_errors.object_metrics` per level and group of ``by``
    (e.g. ``["setting", "role", "ttc_bin"]``): pairs, tracks, median relative error, invalid
    rate, score and median motion-in-depth error per sensor, with a ``difficulty`` column."""
    return _per_level(judged, lambda pairs: object_metrics(pairs, by))


def level_rankings(judged: pd.DataFrame, sensor: str = "camera") -> pd.DataFrame:
    """The every-object ranking (:func:`~ttc.evaluation.object_errors.track_bootstrap_ranks`)
    of each level, stacked with a leading ``difficulty`` column (levels in the order of
    :data:`~ttc.evaluation.difficulty.RANKING_LEVELS`); the ``all`` rows are the ranking of
    every judged pair."""
    return _per_level(judged, lambda pairs: track_bootstrap_ranks(pairs, sensor))


def level_agreement(rankings: pd.DataFrame) -> pd.DataFrame:
    """Kendall's τ between the scores of every two levels of :func:`level_rankings`' table,
    over the settings both rank: ``level_a``, ``level_b``, ``n_settings``, ``kendall_tau``
    (NaN with fewer than three)."""
    scores = {lv: g.set_index("setting")["score"] for lv, g in rankings.groupby("difficulty")}
    levels = [lv for lv in RANKING_LEVELS if lv in scores]
    rows = []
    for i, a in enumerate(levels):
        for b in levels[i + 1 :]:
            both = scores[a].index.intersection(scores[b].index)
            rows.append((a, b, len(both), ranking_agreement(scores[a], scores[b])))
    return pd.DataFrame(rows, columns=["level_a", "level_b", "n_settings", "kendall_tau"])


def level_counts(judged: pd.DataFrame) -> pd.DataFrame:
    """Distinct judged boxes (a pair's current box, once however many settings judged it)
    per level (rows, :data:`~ttc.evaluation.difficulty.RANKING_LEVELS`) and reference-TTC
    range (columns, :data:`~ttc.evaluation.ttc_bins.OBJECT_TTC_BINS`)."""
    keys = ["frame", "curr_box", "ref_track_id"]
    mask = judged["judged"].to_numpy(dtype=bool)
    one = judged.loc[mask, [*keys, "ttc_bin", "difficulty"]].drop_duplicates(keys)
    rows = {}
    for level in RANKING_LEVELS:
        mine = level_pairs(one, level)
        rows[level] = mine["ttc_bin"].value_counts().reindex(list(OBJECT_TTC_BINS), fill_value=0)
    out = pd.DataFrame(rows).T.rename_axis("difficulty")
    out["total"] = out.sum(axis=1)
    return out.reset_index()
