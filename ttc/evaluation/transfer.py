"""How far a ranking carries from one recording to another.

Input: the per-drive rankings of :func:`ttc.evaluation.drive_rankings` (one row per setting
and drive: ``drive``, ``setting``, ``rank``, the ranking keys). A drive where no setting has
a finite first ranking key (no frame could be judged, e.g. a drive without a lead vehicle)
ranks nothing and is left out.

- :func:`recording_agreement`: Kendall's τ between the rankings of every pair of drives, over
  the settings ranked on both (τ-b: ties in rank allowed);
- :func:`best_elsewhere`: the best ``k`` settings of each drive and their ranks on the others;
- :func:`top_everywhere`: the settings in the top ``k`` of every drive;
- :func:`transfer_sentence`: the finding in one sentence a reader can check in the tables.
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd

from ttc.evaluation.drives import POOLED


def ranked_drives(table: pd.DataFrame, key: str) -> pd.DataFrame:
    """The rows of ``table`` on a real drive (not :data:`POOLED`) whose drive ranks something:
    at least one setting with a finite ``key`` (the first ranking key, e.g.
    ``camera_mid_median``); rows with a NaN ``key`` are left out."""
    rows = table[(table["drive"] != POOLED) & np.isfinite(table[key].astype(float))]
    return rows[["drive", "setting", "rank", key]]


def _ranks(table: pd.DataFrame, key: str) -> pd.DataFrame:
    """Setting × drive matrix of ranks (drives in table order)."""
    rows = ranked_drives(table, key)
    order = list(dict.fromkeys(rows["drive"]))
    return rows.pivot(index="setting", columns="drive", values="rank")[order]


def recording_agreement(table: pd.DataFrame, key: str) -> pd.DataFrame:
    """Per pair of ranked drives: ``drive_a``, ``drive_b``, ``n_settings`` (ranked on both)
    and ``kendall_tau`` (NaN with fewer than 2 settings)."""
    from scipy.stats import kendalltau  # noqa: PLC0415 (slow to import)

    ranks = _ranks(table, key)
    rows = []
    for a, b in itertools.combinations(ranks.columns, 2):
        both = ranks[[a, b]].dropna()
        tau = kendalltau(both[a], both[b]).statistic if len(both) >= 2 else np.nan
        rows.append({"drive_a": a, "drive_b": b, "n_settings": len(both),
                     "kendall_tau": float(tau)})  # fmt: skip
    return pd.DataFrame(rows, columns=["drive_a", "drive_b", "n_settings", "kendall_tau"])


def best_elsewhere(table: pd.DataFrame, key: str, k: int = 5) -> pd.DataFrame:
    """For every ranked drive, its best ``k`` settings (``best_on``, ``setting``) with their
    rank on every ranked drive (one column per drive; NaN: not ranked there) and the number of
    settings ranked on each (``n_<drive>``)."""
    ranks = _ranks(table, key)
    parts = []
    for drive in ranks.columns:
        best = ranks[drive].dropna().sort_values(kind="stable").head(k)
        part = ranks.loc[best.index].reset_index()
        parts.append(part.assign(best_on=drive))
    out = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()
    for drive in ranks.columns:
        out[f"n_{drive}"] = int(ranks[drive].notna().sum())
    return out[["best_on", "setting", *ranks.columns, *[f"n_{d}" for d in ranks.columns]]]


def top_everywhere(table: pd.DataFrame, key: str, k: int = 10) -> list[str]:
    """The settings ranked in the top ``k`` on every ranked drive (sorted)."""
    ranks = _ranks(table, key)
    if ranks.empty:
        return []
    return sorted(ranks.index[(ranks <= k).all(axis=1)])


def transfer_sentence(table: pd.DataFrame, key: str, k: int = 10) -> str:
    """How far the ranking carries, in one sentence with the numbers of the tables: the range
    of Kendall's τ over the pairs of ranked drives, where each drive's best setting ranks on
    the others, and how many settings are in the top ``k`` everywhere."""
    ranks = _ranks(table, key)
    if ranks.shape[1] < 2:
        return f"Only {ranks.shape[1]} recording ranks any setting: nothing to carry over."
    agreement = recording_agreement(table, key)
    taus = agreement["kendall_tau"].dropna()
    tau = f"{taus.min():.2f}" if taus.min() == taus.max() else f"{taus.min():.2f}–{taus.max():.2f}"
    moves = []
    for drive in ranks.columns:
        best = ranks[drive].dropna().sort_values(kind="stable").index[0]
        elsewhere = [
            f"{int(ranks.loc[best, other])} of {int(ranks[other].notna().sum())} on {other}"
            for other in ranks.columns
            if other != drive and np.isfinite(ranks.loc[best, other])
        ]
        moves.append(f"{drive}'s best ({best}) ranks {', '.join(elsewhere) or 'nowhere else'}")
    everywhere = top_everywhere(table, key, k)
    return (
        f"Kendall's τ between the recordings' rankings is {tau}; " + "; ".join(moves) + "; "
        f"{len(everywhere)} setting(s) are in the top {k} on every recording."
    )
