"""The "every object" report of one recording: ``reference_objects.csv`` (the reference of every
tracked object, each box's KITTI difficulty level), ``objects.csv`` (each setting per level, role
and TTC range), ``objects_levels.csv`` (each setting per level), ``objects_ranking.csv`` (the
ranking per level: ``easy``, ``moderate``, ``hard``, ``all``) and ``objects.md`` (tracks, what
was judged per level, the best settings on all objects beside the lead-only best and per level,
Kendall's τ between levels, where camera TTC breaks down). Thin: the tables come from
:mod:`ttc.evaluation.object_reference`, :mod:`ttc.evaluation.object_errors` and
:mod:`ttc.evaluation.object_levels`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from experiments.report.encode import markdown_table, write_csv, write_text
from experiments.report.header import provenance_markdown
from experiments.report.judged_rows import camera_runs
from experiments.report.load import Context, SweepData
from experiments.report.plots import plot_breakdown, plot_objects, save_figure
from experiments.summary.references import object_references
from ttc.evaluation.difficulty import RANKING_LEVELS
from ttc.evaluation.errors import rows_of_runs
from ttc.evaluation.object_errors import (
    breakdown,
    judge_objects,
    ranking_agreement,
    track_bootstrap_ranks,
    track_table,
)
from ttc.evaluation.object_levels import (
    level_agreement,
    level_counts,
    level_metrics,
    level_rankings,
)
from ttc.evaluation.object_reference import REFERENCE_OBJECT_COLUMNS
from ttc.evaluation.ttc_bins import OBJECT_TTC_BINS, band_counts
from ttc.evaluation.verdict import objects_verdict

#: Settings shown in each best-of table.
BEST = 5


def reference_objects_table(reference: pd.DataFrame) -> pd.DataFrame:
    """The rows of ``reference_objects.csv``: exactly :data:`REFERENCE_OBJECT_COLUMNS`, boxes
    in image pixels (left, top, width, height of the YOLO box), metres, m/s and seconds."""
    return reference[list(REFERENCE_OBJECT_COLUMNS)].sort_values(["frame", "track_id"])


def objects_report(data: SweepData, reference: pd.DataFrame, out: Path) -> pd.DataFrame:
    """Write ``reference_objects.csv``, ``objects.csv``, ``objects_levels.csv``,
    ``objects_ranking.csv``, ``objects.md``, ``objects.png`` and ``objects_breakdown.png`` of
    the runs of ``data`` (one recording) judged against ``reference`` (its objects' reference)
    into ``out``; returns the every-object ranking per level
    (:func:`ttc.evaluation.object_levels.level_rankings`: a ``difficulty`` column, its ``all``
    rows the ranking of every judged pair)."""
    out.mkdir(parents=True, exist_ok=True)
    write_csv(reference_objects_table(reference), out / "reference_objects.csv")
    labels = camera_runs(data.runs)
    # the box pairs of those runs: all of them as the load keeps them (not copied then)
    judged = judge_objects(rows_of_runs(data.boxes, labels.index), reference)
    judged["setting"] = judged["run_id"].map(labels)
    write_csv(level_metrics(judged, ["setting", "role", "ttc_bin"]), out / "objects.csv")
    write_csv(level_metrics(judged, ["setting"]), out / "objects_levels.csv")
    rankings = level_rankings(judged)
    ranking = rankings[rankings["difficulty"] == "all"].drop(columns="difficulty")
    lead = track_bootstrap_ranks(judged, role="lead")
    write_csv(rankings, out / "objects_ranking.csv")
    tau = ranking_agreement(lead.set_index("setting")["score"],
                            ranking.set_index("setting")["score"])  # fmt: skip
    levels = _levels_section(reference, judged, rankings)
    write_text(_page(data, reference, judged, rankings, lead, tau, levels), out / "objects.md")
    save_figure(plot_objects(reference, judged, ranking), out / "objects.png")
    if judged["judged"].any():
        save_figure(plot_breakdown(breakdown(judged)), out / "objects_breakdown.png")
    return rankings


def _levels_section(reference: pd.DataFrame, judged: pd.DataFrame, rankings: pd.DataFrame) -> str:
    """The per-level part of ``objects.md``: boxes per level, pairs judged per level and TTC
    range, the best settings per level and Kendall's τ between levels."""
    boxes = reference["difficulty"].value_counts().reindex([*RANKING_LEVELS[:-1], "none"])
    best = [
        f"### `{level}`\n\n" + markdown_table(rankings[rankings["difficulty"] == level]
                                              .drop(columns="difficulty").head(BEST))
        for level in RANKING_LEVELS
    ]  # fmt: skip
    lines = [
        "## Difficulty levels (KITTI)",
        "",
        "Each box's level as in KITTI's object benchmark: `easy` at least 40 px high, fully "
        "visible (at most 10 % of it covered by the boxes of nearer objects, by lidar "
        "distance) and not touching the image border; `moderate` at least 25 px, at most half "
        "covered, not at the border; `hard` at least 25 px, any cover or at the border (the "
        "part cut off cannot be measured: a box at the border is `hard` at best); below 25 px "
        "no level (`none`, counted in `all` only). A pair takes the worse level of its two "
        "boxes; the levels are cumulative (`moderate` holds `easy`, `hard` both).",
        "",
        markdown_table(boxes.fillna(0).astype(int).rename("boxes").rename_axis("difficulty")
                       .reset_index()),
        "",
        "## Object pairs judged per level and reference-TTC range (distinct boxes)",
        "",
        markdown_table(level_counts(judged)) if judged["judged"].any() else "Nothing judged.",
        "",
        f"## Best {BEST} settings per level",
        "",
        "The all-object score (mean capped relative camera TTC error, an invalid estimate 1) "
        "over the pairs of each level, with 90 % rank intervals from a bootstrap over tracks.",
        "",
        *[b + "\n" for b in best],
        "## Kendall's τ between levels",
        "",
        "How far the order of the settings on one level carries to another (over the settings "
        "both ranked).",
        "",
        markdown_table(level_agreement(rankings)),
        "",
    ]  # fmt: skip
    return "\n".join(lines)


def _tau_line(tau: float) -> str:
    """The sentence on Kendall's τ between the lead-only and the all-object ranking."""
    if np.isnan(tau):
        return ("Kendall's τ between the lead-only and the all-object ranking: not defined "
                "(fewer than three settings judged on both).")  # fmt: skip
    return f"Kendall's τ between the lead-only and the all-object ranking: {tau:.2f}."


def _page(
    data: SweepData,
    reference: pd.DataFrame,
    judged: pd.DataFrame,
    rankings: pd.DataFrame,
    lead: pd.DataFrame,
    tau: float,
    levels: str = "",
) -> str:
    """The markdown of ``objects.md``: the verdict (:func:`ttc.evaluation.verdict.objects_verdict`
    of the per-level ``rankings``) first, then tracks, boxes per frame by distance band, pairs
    judged, the rankings (``levels``: the per-level part, after the pairs judged per role and
    range)."""
    ranking = rankings[rankings["difficulty"] == "all"].drop(columns="difficulty")
    n_frames = max(int(reference["frame"].nunique()), 1)
    bands = pd.DataFrame([{k: v / n_frames for k, v in
                           band_counts(reference["distance_m"].to_numpy(dtype=float)).items()}])  # fmt: skip
    tracks = reference.groupby("track_id")["role"].first().value_counts()
    one = judged.drop_duplicates(["frame", "curr_box", "ref_track_id"])
    counts = pd.crosstab(one["role"], one["ttc_bin"].where(one["judged"], "not judged"))
    order = [c for c in (*OBJECT_TTC_BINS, "not judged") if c in counts.columns]
    counts = counts[order]
    lines = [
        provenance_markdown(data, "Every object: TTC judged per tracked vehicle"),
        objects_verdict(rankings),
        "",
        "Every detector box gets its own lidar points (the best-supported depth group of its "
        "frustum, split where the depth jumps by more than a gap that grows with range), boxes "
        "are linked frame to frame (IoU), and each track's nearest-face distances are smoothed "
        "like the lead's reference, with one-sided fits at the track's ends: TTC = distance to "
        "the object's plane / closing speed. A pair is judged where the reference TTC is known "
        "to 10 %.",
        "",
        f"## Tracks by role ({reference['track_id'].nunique()} tracks)",
        "",
        markdown_table(tracks.rename("tracks").rename_axis("role").reset_index()),
        "",
        f"## Boxes per frame by lidar distance ({n_frames} frames with boxes)",
        "",
        "The detector's boxes per frame by the forward distance of their object's nearest face "
        "(`no lidar`: too few points of their own).",
        "",
        markdown_table(bands),
        "",
        "## Object pairs per role and reference-TTC range (distinct boxes)",
        "",
        markdown_table(counts.reset_index()),
        "",
        levels,
        f"## Best {BEST} settings on all objects",
        "",
        "Ranked by the score: the mean over every judged object pair of the relative camera "
        "TTC error capped at 1, an invalid estimate counting 1 (0 is perfect), with 90 % rank "
        "intervals from a bootstrap whose blocks are tracks.",
        "",
        markdown_table(ranking.head(BEST)) if not ranking.empty else "Nothing judged.",
        "",
        f"## Best {BEST} settings on the lead only",
        "",
        markdown_table(lead.head(BEST)) if not lead.empty else "No lead pair judged.",
        "",
        _tau_line(tau),
        "",
        "## Per track",
        "",
        "Every judged track: its reference distance range (m), the pairs judged over every "
        "setting, their median relative camera TTC error, median motion-in-depth error "
        "(10⁻⁴) and invalid rate; nearest first.",
        "",
        markdown_table(track_table(judged, reference)) if judged["judged"].any() else "None.",
        "",
        "## Where camera TTC breaks down",
        "",
        "Median relative error and invalid rate of every setting's camera TTC, by the "
        "object's distance (m), box width (px), bearing (degrees off the forward axis) and "
        "reference TTC range. A parked car seen obliquely shows its side, whose image extent "
        "does not scale like the distance of its nearest face.",
        "",
        markdown_table(breakdown(judged)) if judged["judged"].any() else "Nothing judged.",
        "",
        "![where camera TTC breaks down](objects_breakdown.png)" if judged["judged"].any() else "",
        "",
        "![every track](objects.png)",
        "",
    ]
    return "\n".join(lines)


def recording_objects_report(data: SweepData, ctx: Context, out: Path) -> pd.DataFrame | None:
    """:func:`objects_report` of the runs of one real recording (nothing for a generated one,
    which has no objects besides its lead: None), its reference from
    :func:`experiments.summary.references.object_references`."""
    refs = object_references(data.frames, data.runs,
                             lambda run_id: ctx.detector_setup(data.runs, run_id),
                             ctx.root, ctx.cache)  # fmt: skip
    return objects_report(data, next(iter(refs.values())), out) if refs else None


def _all_level(ranking: pd.DataFrame) -> pd.DataFrame:
    """The ``all`` rows of a ranking per level (the ranking itself when it has no levels)."""
    if "difficulty" not in ranking:
        return ranking
    return ranking[ranking["difficulty"] == "all"].drop(columns="difficulty")


def cross_recording_objects(rankings: dict[str, pd.DataFrame | None], out: Path) -> Path | None:
    """``objects_recordings.md`` / ``.csv``: how far the all-object ranking carries between
    recordings (Kendall's τ of every pair of recordings over the settings both judged), from
    each recording's :func:`objects_report` ranking by recording name; None with fewer than
    two recordings. With rankings per level, ``objects_recordings_levels.csv`` holds τ per
    level too (the ``.md`` a table of it)."""
    levels = levels_tau({n: r for n, r in rankings.items() if r is not None})
    rankings = {n: _all_level(r) for n, r in rankings.items() if r is not None}
    names = [n for n, r in rankings.items() if not r.empty]
    if len(names) < 2:
        return None
    if not levels.empty:
        write_csv(levels, out / "objects_recordings_levels.csv")
    scores = {n: rankings[n].set_index("setting")["score"] for n in names}
    pairs = [(a, b, ranking_agreement(scores[a], scores[b]))
             for i, a in enumerate(names) for b in names[i + 1 :]]  # fmt: skip
    table = pd.DataFrame(pairs, columns=["recording_a", "recording_b", "kendall_tau"])
    write_csv(table, out / "objects_recordings.csv")
    best = pd.DataFrame({n: rankings[n]["setting"].head(BEST).tolist() +
                         [""] * (BEST - min(BEST, len(rankings[n]))) for n in names})  # fmt: skip
    text = "\n".join([
        "# Every object: how far a ranking carries between recordings",
        "",
        "Kendall's τ between the all-object rankings (mean capped relative camera TTC error, "
        "an invalid estimate 1) of two recordings, over the settings both judged.",
        "",
        markdown_table(table),
        "",
        f"## Best {BEST} on all objects, per recording",
        "",
        markdown_table(best),
        "",
        *(["## Kendall's τ between recordings per difficulty level", "",
           markdown_table(levels), ""] if not levels.empty else []),
    ])  # fmt: skip
    return write_text(text, out / "objects_recordings.md")


def levels_tau(rankings: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """Kendall's τ between every two recordings' rankings of each level (rankings with a
    ``difficulty`` column only): ``difficulty``, ``recording_a``, ``recording_b``,
    ``n_settings``, ``kendall_tau``."""
    names = [n for n, r in rankings.items() if "difficulty" in r and not r.empty]
    rows = []
    for level in RANKING_LEVELS:
        scores = {n: rankings[n][rankings[n]["difficulty"] == level].set_index("setting")["score"]
                  for n in names}  # fmt: skip
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                both = scores[a].index.intersection(scores[b].index)
                rows.append((level, a, b, len(both), ranking_agreement(scores[a], scores[b])))
    columns = ["difficulty", "recording_a", "recording_b", "n_settings", "kendall_tau"]
    return pd.DataFrame(rows, columns=columns)
