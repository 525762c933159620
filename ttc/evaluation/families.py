"""Learned features, dense flow, tracking and the scale fit against the best classic setting.

A camera setting belongs to one *family*, the first that applies:

- ``learned``: a learned detector or descriptor (XFeat, ALIKED, DISK) or a learned matcher
  (LightGlue, LighterGlue);
- ``dense flow``: ``matcher`` DIS or Farnebäck (keypoints followed through a dense flow field);
- ``tracking``: ``matcher`` KLT;
- ``scale fit``: a classic descriptor setting with ``camera_ttc=similarity_fit``;
- ``classic``: a descriptor detector × descriptor × BF/FLANN matcher with a ratio estimator.

:func:`against_best_classic` puts every non-classic setting of a ranking beside the best
classic one of the same dataset (the lowest rank) with a verdict that needs no test of its own:
``better`` / ``worse`` when the two 90 % bootstrap intervals of the median MiD do not overlap,
``within interval`` when they do.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ttc.features.dense_flow import DENSE_FLOW_MATCHERS
from ttc.features.learned_params import LEARNED_DESCRIPTORS, LEARNED_DETECTORS, LEARNED_MATCHERS

FAMILIES = ("classic", "learned", "dense flow", "tracking", "scale fit")
#: Columns of :func:`against_best_classic` besides the verdict and the best classic setting.
SHOWN = ["dataset", "family", "setting", "rank", "rank_lo", "rank_hi",
         "camera_mid_median", "camera_mid_median_lo", "camera_mid_median_hi",
         "camera_invalid_rate", "ms_per_frame"]  # fmt: skip


def family_of(ranking: pd.DataFrame) -> pd.Series:
    """The family (:data:`FAMILIES`) of each row of a ranking with the columns ``detector``,
    ``descriptor``, ``matcher`` and ``camera_ttc``."""
    learned = (
        ranking["detector"].isin(list(LEARNED_DETECTORS))
        | ranking["descriptor"].isin(list(LEARNED_DESCRIPTORS))
        | ranking["matcher"].isin(list(LEARNED_MATCHERS))
    )
    choices = [
        learned,
        ranking["matcher"].isin(list(DENSE_FLOW_MATCHERS)),
        ranking["matcher"].eq("klt"),
        ranking["camera_ttc"].eq("similarity_fit"),
    ]
    return pd.Series(
        np.select(choices, FAMILIES[1:], default=FAMILIES[0]), index=ranking.index, name="family"
    )


def _verdict(lo: pd.Series, hi: pd.Series, best_lo: float, best_hi: float) -> pd.Series:
    """``better`` / ``worse`` / ``within interval`` from the rows' MiD intervals (lower MiD is
    better) against the best classic setting's."""
    out = np.where(hi < best_lo, "better", np.where(lo > best_hi, "worse", "within interval"))
    return pd.Series(out, index=lo.index)


def against_best_classic(ranking: pd.DataFrame) -> pd.DataFrame:
    """Per dataset, the best classic setting (first row, family ``classic``) and every
    non-classic setting in rank order, with ``verdict`` against that best classic one
    (``best classic`` on its own row). Columns :data:`SHOWN` + ``verdict``. Empty when the
    ranking has no non-classic setting or no classic one to compare with."""
    r = ranking.assign(family=family_of(ranking))
    parts = []
    for _, group in r.groupby("dataset", sort=True):
        classic = group[group["family"] == "classic"].sort_values("rank")
        others = group[group["family"] != "classic"].sort_values("rank")
        if classic.empty or others.empty:
            continue
        best = classic.iloc[0]
        verdict = _verdict(others["camera_mid_median_lo"], others["camera_mid_median_hi"],
                           best["camera_mid_median_lo"], best["camera_mid_median_hi"])  # fmt: skip
        parts += [classic.head(1)[SHOWN].assign(verdict="best classic"),
                  others[SHOWN].assign(verdict=verdict)]  # fmt: skip
    if not parts:
        return pd.DataFrame(columns=[*SHOWN, "verdict"])
    return pd.concat(parts, ignore_index=True)


def verdict_sentence(table: pd.DataFrame) -> list[str]:
    """Per dataset, one sentence: whether any non-classic setting beats the best classic one
    beyond its interval, and the best of each family."""
    out = []
    for dataset, group in table.groupby("dataset", sort=True):
        best = group.iloc[0]
        others = group.iloc[1:]
        better = others[others["verdict"] == "better"]
        lead = (
            f"{len(better)} setting(s) beat it beyond the intervals: {', '.join(better['setting'])}"
            if len(better)
            else "no other setting beats it beyond the intervals"
        )
        firsts = others.groupby("family", sort=False).head(1)
        per_family = "; ".join(
            f"best {f['family']}: {f['setting']} rank {int(f['rank'])}, "
            f"median MiD {f['camera_mid_median']:.2f}, {f['verdict']}"
            for _, f in firsts.iterrows()
        )
        out.append(
            f"**{dataset}**: best classic setting {best['setting']} (rank {int(best['rank'])}, "
            f"median MiD {best['camera_mid_median']:.2f} [{best['camera_mid_median_lo']:.2f}, "
            f"{best['camera_mid_median_hi']:.2f}]); {lead}. {per_family[:1].upper()}{per_family[1:]}."
        )
    return out
