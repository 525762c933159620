"""Judging against an exact truth (a generated recording, :mod:`ttc.io.scaled_pairs`) instead of
the lidar reference: the truth as a reference table, metrics per target TTC and overall, and
how a ranking on the truth agrees with the ranking of the same settings on a real sequence.

The rows of a generated recording carry the truth columns (:data:`ttc.io.frames.TRUTH_COLUMNS`).
:func:`truth_reference` turns them into the reference's columns (every pair judgeable, on a
collision course, regime ``approach``, no uncertainty), so the errors, metrics, ranking and
bootstrap of :mod:`ttc.evaluation` apply unchanged: MiD = 10⁴ · |ln r̂ − ln ratio_true|, the
relative TTC error against ``ttc_true``, the invalid rate.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from ttc.evaluation.metrics import run_metrics

#: Metrics (per sensor ``{s}_<name>``) reported per target TTC by :func:`truth_metrics`.
TRUTH_METRICS = ("invalid_rate", "mid_median", "mid_mean", "medae_rel", "outlier_rate")
#: The ``target`` label of the metrics over every pair.
ALL_TARGETS = "all"


def has_truth(frames: pd.DataFrame) -> bool:
    """True when ``frames`` (a sweep's rows) carry a truth (``ttc_true`` on some row)."""
    return "ttc_true" in frames and bool(frames["ttc_true"].notna().any())


def truth_reference(frames: pd.DataFrame) -> pd.DataFrame:
    """One row per ``frame`` with the reference's :data:`~ttc.evaluation.errors.REFERENCE_COLUMNS`
    taken from the truth: ``ttc_ref_s`` = ``ttc_true`` (s), ``ratio_ref`` = ``ratio_true``,
    judgeable, on a collision course, regime ``approach``, zero uncertainty; and
    ``ttc_target`` (s)."""
    truth = frames.drop_duplicates("frame")[["frame", "ttc_true", "ratio_true", "ttc_target"]]
    truth = truth.dropna(subset=["ttc_true"]).sort_values("frame", ignore_index=True)
    out = pd.DataFrame(
        {
            "frame": truth["frame"].to_numpy(),
            "ttc_ref_s": truth["ttc_true"].to_numpy(float),
            "collision_course": True,
            "ratio_ref": truth["ratio_true"].to_numpy(float),
            "mid_ref_sd": 0.0,
            "ttc_ref_sd_s": 0.0,
            "judgeable": True,
            "regime": "approach",
            "ttc_target": truth["ttc_target"].to_numpy(float),
        }
    )
    return out


def target_label(ttc_s: float) -> str:
    """``"3 s"`` for a target of 3.0 s (the ``target`` column of :func:`truth_metrics`)."""
    return f"{ttc_s:g} s"


def truth_metrics(
    frames: pd.DataFrame, sensors: Sequence[str] = ("camera", "lidar")
) -> pd.DataFrame:
    """Per run and target: ``run_id``, ``target`` (:data:`ALL_TARGETS` or ``"<T> s"``),
    ``ttc_target`` (s, NaN for all), ``n_frames`` and ``{s}_<m>`` for each sensor ``s`` and
    metric ``m`` of :data:`TRUTH_METRICS`, judged against the truth
    (:func:`truth_reference`). Rows: every run × (all, then each target in increasing order)."""
    reference = truth_reference(frames)
    cols = [f"{s}_{m}" for s in sensors for m in TRUTH_METRICS]
    parts = []
    groups = [(ALL_TARGETS, np.nan, reference)] + [
        (target_label(t), t, group) for t, group in reference.groupby("ttc_target", sort=True)
    ]
    for label, target, ref in groups:
        subset = frames[frames["frame"].isin(ref["frame"])]
        m = run_metrics(subset, ref)
        keep = ["run_id", *[c for c in cols if c in m], "n_frames"]
        parts.append(m[keep].assign(target=label, ttc_target=target))
    out = pd.concat(parts, ignore_index=True)
    front = ["run_id", "target", "ttc_target", "n_frames"]
    return out[front + [c for c in out.columns if c not in front]]


def ranking_agreement(
    synthetic: pd.DataFrame, real: pd.DataFrame, key: Sequence[str], top: int = 10
) -> tuple[dict[str, float], pd.DataFrame]:
    """How a ranking on the truth agrees with the real sequence's ranking of the same settings.

    Parameters
    ----------
    synthetic, real
        Rankings (one row per setting) with ``rank``, ``rank_lo``, ``rank_hi`` and the ``key``
        columns (e.g. ``fp6_ranking.csv`` of each).
    key
        The columns naming a setting (the camera axes both share).
    top
        How many of the best settings of each ranking the interval widths are averaged over.

    Returns
    -------
    (summary, moves): ``summary`` holds ``n_settings`` (settings in both), ``kendall_tau`` and
    ``kendall_p`` (scipy's tau-b between the two ranks, re-ranked 1..n among the shared
    settings), and ``top_width_synthetic`` / ``top_width_real``: the mean width
    (``rank_hi − rank_lo``) of the ``top`` best settings' rank intervals, each relative to its
    own ranking's number of settings (0–1). ``moves``: the shared settings with both ranks,
    both intervals and ``move`` = synthetic rank − real rank (among the shared), largest
    ``|move|`` first.
    """
    key = list(key)
    cols = ["rank", "rank_lo", "rank_hi"]
    both = synthetic[key + cols].merge(
        real[key + cols], on=key, suffixes=("_synthetic", "_real"), validate="one_to_one"
    )
    for side in ("synthetic", "real"):
        both[f"shared_rank_{side}"] = both[f"rank_{side}"].rank(method="first").astype(int)
    both["move"] = both["shared_rank_synthetic"] - both["shared_rank_real"]
    # imported here: scipy.stats takes ~0.4 s to import, paid by every sweep summary otherwise
    from scipy import stats  # noqa: PLC0415

    tau, p_value = (
        stats.kendalltau(both["rank_synthetic"], both["rank_real"])
        if len(both) >= 2
        else (np.nan, np.nan)
    )

    def width(table: pd.DataFrame) -> float:
        best = table.nsmallest(top, "rank")
        return float(((best["rank_hi"] - best["rank_lo"]) / len(table)).mean())

    summary = {
        "n_settings": float(len(both)),
        "kendall_tau": float(tau),
        "kendall_p": float(p_value),
        "top_width_synthetic": width(synthetic),
        "top_width_real": width(real),
    }
    order = both["move"].abs().sort_values(ascending=False, kind="stable").index
    return summary, both.loc[order].reset_index(drop=True)
