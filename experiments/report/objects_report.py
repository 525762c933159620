"""The "every object" report of one recording: ``reference_objects.csv`` (the reference of every
tracked object), ``objects.csv`` (each setting per role and TTC range) and ``objects.md``
(tracks, what was judged, the best settings on all objects beside the lead-only best, where
camera TTC breaks down). Thin: the tables come from :mod:`ttc.evaluation.object_reference`
and :mod:`ttc.evaluation.object_errors`."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from experiments.reference_store import object_references
from experiments.report.encode import markdown_table, write_csv, write_text
from experiments.report.header import provenance_markdown
from experiments.report.load import Context, SweepData, setting_of_run
from ttc import evaluation as ev
from ttc.evaluation.object_errors import (
    breakdown,
    judge_objects,
    object_metrics,
    ranking_agreement,
)
from ttc.evaluation.object_reference import REFERENCE_OBJECT_COLUMNS
from ttc.settings import AXES

#: Settings shown in each best-of table.
BEST = 5


def reference_objects_table(reference: pd.DataFrame) -> pd.DataFrame:
    """The rows of ``reference_objects.csv``: exactly :data:`REFERENCE_OBJECT_COLUMNS`, boxes
    in image pixels (left, top, width, height of the YOLO box), metres, m/s and seconds."""
    return reference[list(REFERENCE_OBJECT_COLUMNS)].sort_values(["frame", "track_id"])


def _labels(runs: pd.DataFrame) -> pd.Series:
    """Setting label by run id."""
    labels = ev.setting_labels(runs, [a for a in AXES if a != "dataset"])
    return pd.Series(labels.to_numpy(), index=runs["run_id"].to_numpy())


def objects_report(data: SweepData, reference: pd.DataFrame, out: Path) -> dict[str, Path]:
    """Write ``reference_objects.csv``, ``objects.csv`` and ``objects.md`` of the runs of
    ``data`` (one recording) judged against ``reference`` (its objects' reference) into
    ``out``; returns the paths written."""
    out.mkdir(parents=True, exist_ok=True)
    paths = {"reference": write_csv(reference_objects_table(reference),
                                    out / "reference_objects.csv")}  # fmt: skip
    ok = data.runs[data.runs["status"] == "ok"]
    judged = judge_objects(data.frames[data.frames["run_id"].isin(ok["run_id"])], reference)
    labels = _labels(ok)
    judged["setting"] = judged["run_id"].map(labels)
    per_range = object_metrics(judged, ["setting", "role", "ttc_bin"])
    paths["csv"] = write_csv(per_range, out / "objects.csv")
    overall = object_metrics(judged, ["setting"]).set_index("setting")
    lead = object_metrics(judged[judged["role"] == "lead"], ["setting"]).set_index("setting")
    tau = ranking_agreement(lead.get("camera_medae_rel", pd.Series(dtype=float)),
                            overall.get("camera_medae_rel", pd.Series(dtype=float)))  # fmt: skip
    paths["md"] = write_text(_page(data, reference, judged, overall, lead, tau), out / "objects.md")
    return paths


def _best(table: pd.DataFrame) -> pd.DataFrame:
    if table.empty:
        return table
    cols = ["n_pairs", "n_tracks", "camera_medae_rel", "camera_invalid_rate"]
    return table.sort_values(["camera_medae_rel", "camera_invalid_rate"])[cols].head(BEST)


def _page(data, reference, judged, overall, lead, tau: float) -> str:
    """The markdown of ``objects.md``."""
    tracks = reference.groupby("track_id")["role"].first().value_counts()
    one = judged.drop_duplicates(["frame", "curr_box", "ref_track_id"])
    counts = pd.crosstab(one["role"], one["ttc_bin"].where(one["judged"], "not judged"))
    lines = [
        provenance_markdown(data, "Every object: TTC judged per tracked vehicle"),
        "Every YOLO box gets its own lidar points (the nearest compact group of its frustum), "
        "boxes are linked frame to frame (IoU), and each track's nearest-face distances are "
        "smoothed like the lead's reference: TTC = distance to the object's plane / closing "
        "speed. A pair is judged where the reference TTC is known to 10 %.",
        "",
        f"## Tracks by role ({reference['track_id'].nunique()} tracks)",
        "",
        markdown_table(tracks.rename("tracks").rename_axis("role").reset_index()),
        "",
        "## Object pairs per role and reference-TTC range",
        "",
        markdown_table(counts.reset_index()),
        "",
        f"## Best {BEST} settings on all objects",
        "",
        markdown_table(_best(overall).reset_index()),
        "",
        f"## Best {BEST} settings on the lead only",
        "",
        markdown_table(_best(lead).reset_index()) if not lead.empty else "No lead pair judged.",
        "",
        f"Kendall's τ between the lead-only and the all-object ranking (median relative "
        f"camera TTC error): {tau:.2f}."
        if tau == tau
        else "Kendall's τ between the lead-only and the all-object ranking: not defined (fewer "
        "than three settings judged on both).",
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
    ]
    return "\n".join(lines)


def recording_objects_report(data: SweepData, ctx: Context, out: Path) -> dict[str, Path]:
    """:func:`objects_report` of the runs of one real recording (nothing for a generated one,
    which has no objects besides its lead), its reference from
    :func:`experiments.reference_store.object_references`."""
    refs = object_references(data.frames, data.runs,
                             lambda run_id: setting_of_run(data.runs, run_id, ctx.root),
                             ctx.root, ctx.cache)  # fmt: skip
    return objects_report(data, next(iter(refs.values())), out) if refs else {}
