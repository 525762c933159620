"""FP.6 writer: ``fp6_camera.md``, ``fp6_camera_ttc.csv``, ``fp6_ranking.csv``, the plots and
the match pictures of the worst frames, from the frame table, rules and ranking of
:mod:`ttc.evaluation` (FP.6 diagnosis)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from experiments.report.encode import markdown_table, save_webp, write_csv, write_text
from experiments.report.header import provenance_markdown
from experiments.report.load import Context, SweepData
from experiments.report.pictures import MAX_CAMERA_PICTURES, camera_picture
from experiments.report.plots import (
    plot_heatmap,
    plot_pareto,
    plot_rank_intervals,
    plot_top_bottom,
    save_figure,
)
from ttc import evaluation as ev
from ttc.evaluation.verdict import has_lead, no_lead_sentence

#: Way-off camera cases whose intermediate arrays are examined (≈ 30 ms each).
MAX_EXAMINED = 60

RANKING_COLUMNS = [
    "dataset", "rank", "rank_lo", "rank_hi", "rank_median", "setting", *ev.CAMERA_AXES[:-1],
    "camera_invalid_rate", "camera_invalid_rate_lo", "camera_invalid_rate_hi",
    "camera_mid_median", "camera_mid_median_lo", "camera_mid_median_hi", "camera_mid_mean",
    *(f"camera_mid_median_{r}" for r in ev.REGIMES),
    "camera_outlier_rate", "camera_outlier_rate_lo", "camera_outlier_rate_hi",
    "camera_medae_rel", "camera_medae_rel_lo", "camera_medae_rel_hi", "camera_meanae_rel",
    "camera_false_alarm_rate", "camera_warn_precision", "camera_warn_recall",
    "camera_jitter_s", "camera_invalid", "way_off_frames", "n_frames", "n_judged",
    "n_uncertain", "block_length", "ms_per_frame", "ms_compute_per_frame", "run_id",
]  # fmt: skip
#: Columns of ``fp6_camera_ttc.csv``. Two are left out because the file is the largest of a
#: report (10,780 rows for 0-77) and they follow from others: the run id (``fp6_ranking.csv``
#: has it per dataset and setting) and the ratio the reference implies, 1 + dt / ttc_ref_s
#: with dt = (frame - prev_frame) / 10 Hz.
FP6_COLUMNS = [
    "dataset", "setting", "frame", "prev_frame", "ttc_camera", "camera_reason", "ttc_ref_s",
    "camera_rel_err", "way_off", "reasons", "camera_ratio", "camera_pairs",
    "keypoints_curr", "matches_total", "matches_in_box", "matches_kept", "matches_removed",
    "box_w", "box_h", "detector", "descriptor", "examined", "reason_text",
]  # fmt: skip


def picture_stem(setting: str, frame: int) -> str:
    """The file name (without extension) of the match picture of a setting's frame."""
    return f"{setting.replace('/', '_')}_frame_{int(frame):04d}"


def examine_worst(
    t: pd.DataFrame, runs: pd.DataFrame, reference: pd.DataFrame, ctx: Context, limit: int
) -> pd.DataFrame:
    """``t`` with the match-geometry reasons (:func:`ttc.evaluation.match_geometry` on the
    recomputed pair detail) of its ``limit`` worst way-off rows added and ``examined`` (``t``
    left as it is: a shallow copy, pandas copies on write the columns set here)."""
    t = t.copy(deep=False)
    t["examined"] = False
    # a generated recording's truth has no rear distance: background keypoints go uncounted
    ref = reference.set_index("frame").get("distance_smooth_m", pd.Series(dtype=float))
    for idx, row in ev.worst_order(t).head(limit).iterrows():
        detail = ctx.detail(runs, row["run_id"], int(row["prev_frame"]), int(row["frame"]))
        min_dist = ctx.settings(runs, row["run_id"]).camera_ttc.min_dist
        geometry = ev.match_geometry(detail, min_dist, float(ref.get(row["frame"], np.nan)))
        extra = {k: v for k, v in ev.geometry_texts(geometry).items() if v}
        t.at[idx, "examined"] = True
        t.at[idx, "reasons"], t.at[idx, "reason_text"] = ev.with_geometry_reasons(
            str(t.at[idx, "reasons"]), t.at[idx, "reason_text"], extra
        )
    return t


def fp6_tables(
    data: SweepData, reference: pd.DataFrame, ctx: Context | None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The FP.6 frame table with way-off reasons and the ranking (both empty without an ok
    run). ``ctx`` None skips the match-geometry examination of the worst frames."""
    t = ev.camera_frame_table(data.frames, data.runs, reference)
    if t.empty:
        return t, pd.DataFrame()
    t = ev.camera_reasons(t)
    if ctx is not None:
        t = examine_worst(t, data.runs, reference, ctx, MAX_EXAMINED)
    else:
        t["examined"] = False
    return t, ev.camera_ranking(data.frames, t, reference, ev.N_BOOT)


#: What the camera TTCs are judged against, in ``fp6_camera.md``: the reference TTC, or a
#: generated recording's exact truth.
AGAINST_REFERENCE = "the reference TTC ([reference.md](reference.md))"
AGAINST_TRUTH = (
    "the exact truth of the generated pairs (`ttc_true`, [truth.md](truth.md)); a generated "
    "pair has no measured rear distance, so keypoints on the background are not counted"
)


def fp6_report(
    data: SweepData,
    reference: pd.DataFrame,
    ctx: Context,
    out: Path,
    pictures: bool = True,
    against: str = AGAINST_REFERENCE,
) -> tuple[pd.DataFrame, pd.DataFrame] | None:
    """Write ``fp6_camera.md``, ``fp6_camera_ttc.csv``, ``fp6_ranking.csv``, the plots and
    the worst frames' match pictures; return (frame table, ranking). ``against``: what
    ``reference`` is, in words (:data:`AGAINST_REFERENCE`, :data:`AGAINST_TRUTH`)."""
    t, ranking = fp6_tables(data, reference, ctx)
    if t.empty:
        return None
    write_csv(t[FP6_COLUMNS], out / "fp6_camera_ttc.csv")
    write_csv(ranking[RANKING_COLUMNS], out / "fp6_ranking.csv")
    beyond = ev.against_best_classic(ranking)
    (out / "fp6_beyond_classic.csv").unlink(missing_ok=True)
    if not beyond.empty:
        write_csv(beyond, out / "fp6_beyond_classic.csv")
    save_figure(plot_heatmap(ranking), out / "fp6_heatmap.png")
    save_figure(plot_top_bottom(t, ranking, reference), out / "fp6_ttc_series.png")
    save_figure(plot_pareto(ranking), out / "fp6_pareto.png")
    save_figure(plot_rank_intervals(ranking), out / "fp6_rank_intervals.png")
    shutil.rmtree(out / "fp6_pictures", ignore_errors=True)
    drawn = []
    if pictures:
        worst = ev.worst_order(t, per_pair=1, turns="detector").head(MAX_CAMERA_PICTURES)
        for _, row in worst.iterrows():
            name = picture_stem(row["setting"], row["frame"]) + ".webp"
            image = camera_picture(row, data.runs, ctx)
            drawn.append((row, save_webp(image, out / "fp6_pictures" / name)))
    text = fp6_markdown(data, t, ranking, drawn, out, against, beyond)
    write_text(text, out / "fp6_camera.md")
    return t, ranking


def _intervals_paragraph(ranking: pd.DataFrame) -> str:
    """How the rank intervals were made: block length, replicates, frames judged."""
    blocks = ", ".join(sorted({str(int(b)) for b in ranking["block_length"]}))
    uncertain = int(ranking["n_uncertain"].max()) if len(ranking) else 0
    return (
        f"Rank intervals: 90 % paired moving-block bootstrap over frames ({ev.N_BOOT} "
        f"replicates, seed 0, blocks of {blocks} consecutive frames chosen from the errors' "
        "autocorrelation: errors of neighbouring frames are correlated, so resampling single "
        "frames would give intervals that are too narrow). Every frame pair with an estimate "
        "counts in the median MiD, the stationary ones included; the relative TTC error and "
        "the outlier rate use the frames with a judgeable reference"
        + (
            f", {uncertain} frame pair(s) with a finite reference TTC too uncertain to judge "
            "(see reference.md) are left out of them."
            if uncertain
            else "."
        )  # fmt: skip
    )


def _tied_sentences(ranking: pd.DataFrame) -> list[str]:
    """Per dataset, one checkable sentence: how many settings are tied for first."""
    out = []
    for dataset, group in ranking.groupby("dataset", sort=True):
        if not has_lead(group):  # no error to rank by: said first, by _no_lead_sentences
            continue
        tied = group[group["rank_lo"] <= 1]
        out.append(
            f"**{dataset}: {len(tied)} of {len(group)} settings are statistically tied for "
            "first**: their 90 % rank interval includes rank 1 (`rank_lo` = 1 in "
            f"`fp6_ranking.csv`): {', '.join(tied['setting'])}."
        )
    return out


def _no_lead_sentences(ranking: pd.DataFrame) -> list[str]:
    """Per dataset without a judged lead, the sentence the report leads with: no error ranks
    its settings, and the verdict it supports is the every-object ranking."""
    return [
        no_lead_sentence(str(dataset), group)
        + " The verdict this recording supports is the every-object ranking: "
        "[objects.md](objects.md)."
        for dataset, group in ranking.groupby("dataset", sort=True)
        if not has_lead(group)
    ]


def _way_off_paragraph(t: pd.DataFrame) -> str:
    """What makes a frame way off and the rules that explain it, with their thresholds."""
    return (
        f"Way off: relative error > {ev.WAY_OFF_REL:.0%}, an invalid TTC where the reference is "
        "finite and judgeable, or a false alarm. Reasons from the rows: the TTC's reason code, fewer than "
        f"{ev.FEW_MATCHES} kept matches, > {ev.REMOVED_SHARE:.0%} of the box's matches removed, "
        f"|r - 1| < {ev.RATIO_HAIR}; otherwise the scale error in pixels. For the "
        f"{int(t['examined'].sum())} worst (at most {ev.PER_PAIR} per detector x descriptor "
        "pair, round-robin over reasons) the match geometry is measured too: pair ratios exactly "
        f"1 (> {ev.EXACT_SHARE:.0%}), matches leaving the object (> {ev.LEAVE_SHARE:.0%} more "
        f"than {ev.LEAVE_PX:.0f} px off the median motion), keypoints on the box edge "
        f"(> {ev.BORDER_SHARE:.0%} within {ev.BORDER_FRAC:.0%} of the border) or on the "
        "background (lidar depth > 1 m behind the rear). All rows: `fp6_camera_ttc.csv` (run "
        "ids per setting in `fp6_ranking.csv`; the ratio the reference implies is 1 + dt / "
        "ttc_ref_s)."
    )


def _beyond_classic_lines(beyond: pd.DataFrame | None) -> list[str]:
    """The section on learned features, dense flow, tracking and the scale fit (none when the
    sweeps hold no such setting)."""
    if beyond is None or beyond.empty:
        return []
    return [
        "## Learned features, dense flow, tracking and the scale fit against the best classic "
        "setting",
        "",
        "Families and verdict: `ttc.evaluation.families` (`better` / `worse`: the 90 % "
        "intervals of the median MiD do not overlap). `ms_per_frame` is the sweep's recorded "
        "time per frame; settings sharing a cached stage charge it to the one that computed "
        "it. All rows: `fp6_beyond_classic.csv`.",
        "",
        *ev.verdict_sentence(beyond),
        "",
        markdown_table(beyond),
        "",
    ]


def fp6_markdown(
    data: SweepData,
    t: pd.DataFrame,
    ranking: pd.DataFrame,
    pictures: list[tuple[pd.Series, Path]],
    out: Path,
    against: str = AGAINST_REFERENCE,
    beyond: pd.DataFrame | None = None,
) -> str:
    """The FP.6 markdown: ranking, best settings, the non-classic settings against the best
    classic one (``beyond``, :func:`ttc.evaluation.against_best_classic`; left out when empty),
    way-off frames with reasons, pictures; ``against``: what the TTCs are judged against."""
    show = ["rank", "rank_lo", "rank_hi", "setting", "camera_invalid_rate", "camera_mid_median",
            *(f"camera_mid_median_{r}" for r in ev.REGIMES), "camera_outlier_rate",
            "camera_medae_rel", "way_off_frames", "ms_compute_per_frame"]  # fmt: skip
    tied = ranking[ranking["rank_lo"] <= 1]
    way = t.loc[t["way_off"].to_numpy(dtype=bool), ["reasons"]]
    codes = way["reasons"].str.split(";").explode().value_counts().rename_axis("reason")
    worst = ev.worst_order(t).head(40)
    worst = worst.assign(ttc=worst["ttc_camera"].map(lambda v: format(v, ".2f")),
                         ref=worst["ttc_ref_s"].map(lambda v: format(v, ".2f")))  # fmt: skip
    parts = [
        provenance_markdown(data, "FP.6: camera TTC across detector / descriptor settings"),
        *(f"{line}\n" for line in _no_lead_sentences(ranking)),
        "Camera TTC of the lead vehicle per frame for every camera setting in the sweeps, "
        f"judged against {against}.",
        "",
        f"**Ranking rule** (`ttc.evaluation.RANKING_RULE`): {ev.RANKING_RULE}",
        "",
        _intervals_paragraph(ranking),
        "",
        *_tied_sentences(ranking),
        "",
        f"## Best settings ({len(tied)} whose rank interval includes 1)",
        "",
        markdown_table(ranking[show].head(max(10, min(len(tied), 25)))),
        "",
        "![rank intervals](fp6_rank_intervals.png)",
        "",
        "![heatmap](fp6_heatmap.png)",
        "",
        "![series](fp6_ttc_series.png)",
        "",
        "![pareto](fp6_pareto.png)",
        "",
        *_beyond_classic_lines(beyond),
        f"## Frames where the camera TTC is way off ({len(way)} of {len(t)} setting x frame rows)",
        "",
        _way_off_paragraph(t),
        "",
        markdown_table(codes.reset_index()),
        "",
        "### The worst 40",
        "",
        markdown_table(worst[["setting", "frame", "ttc", "ref", "reasons", "reason_text"]]),
        "",
        "## Matches of the worst frames",
        "",
    ]
    for row, path in pictures:
        parts += [f"**{row['setting']}, frame {int(row['frame'])}**: {row['reason_text']}", "",
                  f"![{path.stem}]({path.relative_to(out).as_posix()})", ""]  # fmt: skip
    return "\n".join(parts) + "\n"
