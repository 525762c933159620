"""Which verdict a recording supports: the lead ranking where a lead vehicle was judged, else
the every-object ranking at the difficulty level whose reference the report stands behind.

A recording without a vehicle ahead in the ego lane (drive 0009) still gets an FP.6 ranking
of its lead estimates, but every setting has zero judged lead frames: its order is decided by
invalid rates and computing time alone, not by an error. The verdict there is the every-object
ranking (:mod:`ttc.evaluation.object_errors`), and of its levels (KITTI's ``easy`` /
``moderate`` / ``hard``, then ``all``) the strictest one with enough judged pairs: on boxes at
least 40 px high, fully visible and uncut by the image border both the camera's scale change
and the lidar reference are measurable, while tiny far boxes (13–25 px) are fragile for both
(checked against independent labels on drive 0009: on boxes ≥ 40 px the harness's ranking and
the labels' agree at Kendall's τ 0.88, on every box at 0.65).

Inputs are the report's tables (``fp6_ranking.csv``, ``objects_ranking.csv`` rows); outputs are
booleans, level names and sentences in the report's markdown.
"""

from __future__ import annotations

import pandas as pd

#: The every-object levels from the strictest to ``all`` (every box, no level required).
LEVELS: tuple[str, ...] = ("easy", "moderate", "hard", "all")
#: Fewest judged object pairs (per setting, the median over settings) a level needs before the
#: report stands behind its ranking: below it a rank interval spans most of the settings.
MIN_LEVEL_PAIRS = 20
#: Why the strictest level with enough pairs leads, in one sentence.
LEVEL_REASON = (
    "the strictest KITTI level with at least {n} judged pairs per setting leads: its boxes are "
    "at least 40 px high (easy) or 25 px (moderate, hard), so both the camera's scale change and "
    "the lidar reference are measurable there; on tiny far boxes both are fragile"
)
#: Why every box leads when no level has enough pairs.
ALL_REASON = (
    "no KITTI level (easy, moderate, hard) has {n} judged pairs per setting, so every box is "
    "ranked, tiny far boxes included, where both the camera's scale change and the lidar "
    "reference are fragile: read this ranking with care"
)


def has_lead(ranking: pd.DataFrame) -> bool:
    """Whether any setting of an FP.6 ranking (rows of one dataset, ``n_judged`` the lead
    frames judged against the reference) was judged on a lead frame."""
    return bool(len(ranking)) and bool((ranking["n_judged"].fillna(0) > 0).any())


def level_rows(objects_ranking: pd.DataFrame, level: str) -> pd.DataFrame:
    """The rows of one level of an every-object ranking (all rows when it has no
    ``difficulty`` column and ``level`` is ``all``; none for another level then)."""
    if "difficulty" not in objects_ranking:
        return objects_ranking if level == "all" else objects_ranking.iloc[:0]
    return objects_ranking[objects_ranking["difficulty"] == level]


def supported_level(objects_ranking: pd.DataFrame, min_pairs: int = MIN_LEVEL_PAIRS) -> str | None:
    """The strictest level of :data:`LEVELS` whose settings' median ``n_pairs`` is at least
    ``min_pairs``; ``all`` when none of the levels has that many but ``all`` has pairs; None
    when nothing was judged."""
    for level in LEVELS:
        rows = level_rows(objects_ranking, level)
        if len(rows) and rows["n_pairs"].median() >= min_pairs:
            return level
    rows = level_rows(objects_ranking, "all")
    return "all" if len(rows) and rows["n_pairs"].max() > 0 else None


def no_lead_sentence(dataset: str, ranking: pd.DataFrame) -> str:
    """The sentence a report leads with on a recording without a judged lead."""
    return (
        f"**{dataset}: no lead vehicle was judged**: none of the {len(ranking)} settings has a "
        "lead frame with a reference (no vehicle ahead in the ego lane), so the lead ranking "
        "below is ordered by invalid rate and computing time only, not by an error."
    )


def objects_verdict(objects_ranking: pd.DataFrame, min_pairs: int = MIN_LEVEL_PAIRS) -> str:
    """The every-object verdict in one sentence: the level it stands behind and why, how many
    settings are tied for first there and the best one with its score and rank interval."""
    level = supported_level(objects_ranking, min_pairs)
    if level is None:
        return "**Every object**: no object pair was judged."
    rows = level_rows(objects_ranking, level).sort_values("rank", kind="stable")
    tied = rows[rows["rank_lo"] <= 1]
    best = rows.iloc[0]
    return (
        f"**Every object, level `{level}`: {len(tied)} of {len(rows)} settings are tied for "
        f"first**; the first, `{best['setting']}`, has a score of {best['score']:.2f} (mean capped "
        f"relative camera TTC error, an invalid estimate 1; rank interval "
        f"{best['rank_lo']:.0f}–{best['rank_hi']:.0f}) over {int(best['n_pairs'])} judged pairs. "
        f"Why this level: {(ALL_REASON if level == 'all' else LEVEL_REASON).format(n=min_pairs)}."
    )
