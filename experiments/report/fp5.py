"""FP.5 writer: ``fp5_lidar.md``, ``fp5_lidar_ttc.csv/.png`` and the top views of the flagged
frames, from the frame table and rules of :mod:`ttc.evaluation` (FP.5 diagnosis)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd

from experiments.report.encode import markdown_table, save_top_view, write_csv, write_text
from experiments.report.header import provenance_markdown
from experiments.report.load import Context, SweepData
from experiments.report.pictures import MAX_LIDAR_PICTURES, lidar_picture
from experiments.report.plots import plot_lidar_series, save_figure
from ttc import evaluation as ev

FP5_COLUMNS = [
    "dataset", "frame", "prev_frame", "lidar_ttc", "ttc_lidar", "lidar_reason", "ttc_ref_s",
    "lidar_rel_err", "flagged", "reasons", "d_prev", "d_curr", "ref_d_prev", "ref_d_curr",
    "est_step", "raw_step", "ref_step", "lidar_points_prev", "lidar_points_curr", "lidar_closest_prev",
    "lidar_closest_curr", "lidar_median_prev", "lidar_median_curr", "scan_points_curr",
    "scan_short", "prev_box", "curr_box", "box_w", "box_h", "run_id", "reason_text",
]  # fmt: skip


def picture_stem(dataset: str, frame: int) -> str:
    """The file name (without extension) of the top view of a flagged frame."""
    return f"{dataset}_frame_{int(frame):04d}"


def other_object_texts(t: pd.DataFrame, runs: pd.DataFrame, ctx: Context) -> pd.Series:
    """The ``other_object`` reason (:func:`ttc.evaluation.other_object_text`) of the flagged
    rows of the FP.5 table ``t``, measured on the lead box's points of one recomputed pair
    detail per flagged frame; '' elsewhere."""
    texts = pd.Series("", index=t.index, dtype=object)
    for idx, row in ev.other_object_pairs(t).iterrows():
        detail = ctx.detail(runs, row["detail_run"], int(row["prev_frame"]), int(row["frame"]))
        params = ctx.settings(runs, row["run_id"]).lidar_ttc
        texts[idx] = ev.other_object_text(ev.lead_clouds(detail), params)
    return texts


def fp5_table(data: SweepData, reference: pd.DataFrame, ctx: Context | None) -> pd.DataFrame:
    """The FP.5 table (:func:`ttc.evaluation.lidar_frame_table`) with flags and reasons; empty
    without an ok run. ``ctx`` None skips the reason that needs pair details (other
    objects)."""
    t = ev.lidar_frame_table(data.frames, data.runs, reference)
    if t.empty:
        return t
    other = other_object_texts(t, data.runs, ctx) if ctx is not None else None
    return ev.lidar_reasons(t, other)


def fp5_report(
    data: SweepData, reference: pd.DataFrame, ctx: Context, out: Path, pictures: bool = True
) -> pd.DataFrame | None:
    """Write ``fp5_lidar.md``, ``fp5_lidar_ttc.csv/.png`` and the flagged frames' top views;
    return the FP.5 table (None when the sweeps hold no ok run)."""
    t = fp5_table(data, reference, ctx)
    if t.empty:
        return None
    write_csv(t[FP5_COLUMNS], out / "fp5_lidar_ttc.csv")
    save_figure(plot_lidar_series(t, reference), out / "fp5_lidar_ttc.png")
    shutil.rmtree(out / "fp5_pictures", ignore_errors=True)
    drawn = []
    if pictures:
        for r in ev.most_flagged_frames(t, MAX_LIDAR_PICTURES).itertuples():
            path = out / "fp5_pictures" / f"{picture_stem(r.dataset, r.frame)}.png"
            image = lidar_picture(t, data.runs, ctx, r.dataset, r.frame, reference)
            drawn.append(save_top_view(image, path))
    write_text(fp5_markdown(data, t, reference, drawn, out), out / "fp5_lidar.md")
    return t


def _rules_paragraph() -> str:
    """What flags a frame and the rules that explain it, with their thresholds."""
    return (
        "Lidar TTC of the lead vehicle per frame for every lidar estimator in the sweeps, "
        "beside the reference TTC ([reference.md](reference.md)). A frame is **flagged** when "
        f"the TTC is invalid or more than {ev.OUTLIER_REL:.0%} off a finite reference known "
        f"to within {ev.MAX_REF_REL_SD:.0%} (frames with a more uncertain reference are listed "
        "in reference.md and not flagged on their TTC), "
        f"a finite TTC under {ev.FALSE_ALARM_S:.0f} s where the reference says no "
        "collision course, or the scan is truncated. Each flagged row gets the reasons the "
        "rules of `ttc/evaluation/lidar_diagnosis.py` find in the data: points ahead of the "
        f"bumper (closest point > {100 * ev.AHEAD_M:.0f} cm in front of the reference rear and "
        f"the estimate following it by > {100 * ev.ANOMALY_M:.0f} cm), a distance change (of "
        f"the estimate, or of the smoothed reference) below the {100 * ev.NOISE_FLOOR_M:.0f} cm "
        "noise floor, a truncated scan, points of another "
        f"object (clusters of >= {ev.SECOND_CLUSTER_POINTS} points more than {ev.OTHER_GAP_M} m "
        "off the rear cluster that move the estimator's distance by > "
        f"{100 * ev.OTHER_EFFECT_M:.0f} cm), a box "
        f"switch or a box size jump > {ev.BOX_JUMP:.0%}, a step of the measured rear itself (the "
        "estimate following a raw step the smoothed reference does not have); otherwise the "
        "estimate's deviation from its usual offset to the rear (range noise)."
    )


def fp5_markdown(
    data: SweepData, t: pd.DataFrame, reference: pd.DataFrame, pictures: list[Path], out: Path
) -> str:
    """The FP.5 markdown: per-frame table, estimator summary, flagged frames and pictures."""
    flagged = t[t["flagged"]].copy()
    flagged["ttc"] = flagged["ttc_lidar"].map(lambda v: format(v, ".2f"))
    flagged["ref"] = flagged["ttc_ref_s"].map(lambda v: format(v, ".2f"))
    listing = flagged[["dataset", "frame", "lidar_ttc", "ttc", "ref", "reasons", "reason_text"]]
    settings = t.groupby("lidar_ttc")["camera_settings"].first()
    parts = [
        provenance_markdown(data, "FP.5: implausible lidar TTC estimates"),
        _rules_paragraph(),
        "",
        ev.not_judged_text(reference),
        "",
        "Camera settings per estimator in the sweeps (the lidar TTC uses the first): "
        + ", ".join(f"{k}: {v}" for k, v in settings.items())
        + ".",
        "",
        "## Estimators",
        "",
        markdown_table(ev.lidar_metrics(data.frames, t, reference)),
        "",
        "## TTC per frame (s), flagged values marked `!`",
        "",
        "![lidar TTC](fp5_lidar_ttc.png)",
        "",
        markdown_table(ev.lidar_wide(t)),
        "",
        f"## Flagged frames ({len(flagged)} estimator x frame rows)",
        "",
        markdown_table(listing),
        "",
        "## Top views of flagged frames",
        "",
        "Lead box points from above (x forward), previous frame left, current right; lines: "
        "the distance each estimator picks and the reference rear.",
        "",
    ]
    parts += [f"![{p.stem}]({p.relative_to(out).as_posix()})" for p in pictures]
    return "\n".join(parts) + "\n"
