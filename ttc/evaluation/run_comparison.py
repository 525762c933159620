"""Two sweeps' verdicts side by side: is a setting better, worse or the same in B than in A?"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from ttc.evaluation.ranking import RANKING_KEYS
from ttc.settings import AXES

#: Metrics whose change ``b − a`` :func:`compare_runs` reports (per sensor, then overall).
COMPARED_METRICS = (
    "invalid_rate",
    "mid_median",
    "outlier_rate",
    "medae_rel",
    "false_alarm_rate",
    "jitter_s",
)


def compare_runs(
    metrics_a: pd.DataFrame,
    metrics_b: pd.DataFrame,
    intervals_a: pd.DataFrame,
    intervals_b: pd.DataFrame,
    key: Sequence[str] | None = None,
    sensor: str = "camera",
) -> pd.DataFrame:
    """Settings present in both tables (joined on ``key``, default: the shared axis columns)
    with each metric's change ``b − a``, both ranks and a ``verdict``.

    The verdict follows the ranking rule's keys (:data:`~ttc.evaluation.ranking.RANKING_KEYS`)
    on *metric* intervals from :func:`~ttc.evaluation.bootstrap.bootstrap_rank_intervals`
    (ranks of two sweeps are relative to different sets of runs, so a setting's rank moves
    when others change): ``better`` when b's invalid-rate interval lies entirely below a's,
    ``worse`` when entirely above; when they overlap, the same test on the median MiD;
    ``same`` otherwise.
    """
    if key is None:
        key = [a for a in AXES if a in metrics_a and a in metrics_b]
    key = list(key)
    a = metrics_a.drop(columns="rank", errors="ignore").merge(intervals_a, on="run_id")
    b = metrics_b.drop(columns="rank", errors="ignore").merge(intervals_b, on="run_id")
    both = a.merge(b, on=key, suffixes=("_a", "_b"), validate="one_to_one")
    out = both[key + ["run_id_a", "run_id_b", "rank_a", "rank_b"]].copy()
    changed = [f"{sensor}_{m}" for m in COMPARED_METRICS] + ["ms_per_frame"]
    for col in changed:
        out[f"{col}_a"] = both[f"{col}_a"]
        out[f"{col}_b"] = both[f"{col}_b"]
        out[f"{col}_change"] = both[f"{col}_b"] - both[f"{col}_a"]

    conditions, choices = [], []
    for name in RANKING_KEYS:
        lo_a, hi_a = both[f"{sensor}_{name}_lo_a"], both[f"{sensor}_{name}_hi_a"]
        lo_b, hi_b = both[f"{sensor}_{name}_lo_b"], both[f"{sensor}_{name}_hi_b"]
        conditions += [(hi_b < lo_a).to_numpy(), (lo_b > hi_a).to_numpy()]
        choices += ["better", "worse"]
    out["verdict"] = np.select(conditions, choices, default="same")
    return out.reset_index(drop=True)
