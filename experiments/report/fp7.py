"""FP.7 writer (fused TTC, beyond the rubric): ``fp7_fusion.md``, ``fp7_fusion_ttc.csv``,
``fp7_fusion.csv`` and ``fp7_fusion_ttc.png``, from the fused-TTC tables and rules of
:mod:`ttc.evaluation.fused_diagnosis`. Written when the sweeps hold a run with a Kalman
fusion (``fusion=kalman_cv|kalman_ca``, e.g. ``+experiment=fusion``)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from experiments.report.encode import markdown_table, write_csv, write_text
from experiments.report.header import provenance_markdown
from experiments.report.load import SweepData
from experiments.report.plots import plot_fused_series, save_figure
from ttc import evaluation as ev
from ttc.evaluation import fused_diagnosis as fd
from ttc.steps import fusion

#: Columns of ``fp7_fusion_ttc.csv`` (one row per fused setting × frame).
FP7_COLUMNS = [
    "dataset", "setting", "frame", "prev_frame", "ttc_fused", "ttc_fused_sd", "fused_reason",
    "ttc_lidar", "ttc_camera", "ttc_ref_s", "fused_rel_err", "lidar_rel_err", "camera_rel_err",
    "since_start", "flagged", "reasons", "reason_text", "run_id",
]  # fmt: skip
#: Most flagged rows listed in the markdown (all are in the CSV).
MAX_LISTED = 40


def fp7_report(
    data: SweepData, reference: pd.DataFrame, out: Path
) -> tuple[pd.DataFrame, pd.DataFrame] | None:
    """Write the FP.7 files (module docstring); return the frame table with reasons and the
    comparison table (:func:`ttc.evaluation.fused_diagnosis.fusion_vs_inputs`), None without
    a fused run."""
    t = fd.fused_reasons(fd.fused_frame_table(data.frames, data.runs, reference))
    if t.empty:
        return None
    compared = fd.fusion_vs_inputs(data.frames, t, reference)
    write_csv(t[[c for c in FP7_COLUMNS if c in t]], out / "fp7_fusion_ttc.csv")
    write_csv(compared, out / "fp7_fusion.csv")
    best = compared["run_id"].iloc[0]
    save_figure(plot_fused_series(t[t["run_id"] == best], reference), out / "fp7_fusion_ttc.png")
    write_text(fp7_markdown(data, t, compared, reference), out / "fp7_fusion.md")
    return t, compared


def _intro() -> str:
    """What is judged and what flags a frame."""
    reasons = "; ".join(f"`{k}`: {v}" for k, v in fusion.REASONS.items())
    return (
        "The fused TTC of every run with a Kalman fusion (`ttc/steps/fusion.py`: the lead vehicle's "
        "distance and closing speed, fed by the run's own lidar distance and camera scale "
        "ratio) against the reference ([reference.md](reference.md)), beside the two "
        "estimates it fuses. A frame is **flagged** like a sensor's: an invalid fused TTC, one "
        f"more than {ev.OUTLIER_REL:.0%} off a judgeable reference, or a false alarm. Reasons "
        "(`ttc/evaluation/fused_diagnosis.py`): `start` (the filter began fewer than "
        f"{fd.START_FRAMES} frames before), `one_sensor` (only one measurement, or none, "
        "updated the filter), `receding` (fused closing speed <= 0), `lidar_off` / "
        "`camera_off` (that input is off on the same side, or invalid: the filter followed "
        "it), else `lag` (both inputs near the reference, the filter's state trails them). "
        f"The filter's own code per frame (`fused_reason`): {reasons}."
    )


def fp7_markdown(
    data: SweepData, t: pd.DataFrame, compared: pd.DataFrame, reference: pd.DataFrame
) -> str:
    """The FP.7 markdown: fused against its inputs per setting, the best setting's series,
    the flagged frames with their reasons."""
    flagged = t[t["flagged"]]
    beats = int(compared["beats_inputs"].sum())
    counts = flagged["reasons"].str.split(";").explode().value_counts()
    listing = flagged.sort_values(["setting", "frame"]).head(MAX_LISTED)
    listing = listing[["setting", "frame", "ttc_fused", "ttc_lidar", "ttc_camera", "ttc_ref_s",
                       "fused_reason", "reasons", "reason_text"]]  # fmt: skip
    parts = [
        provenance_markdown(data, "FP.7: fused TTC against its lidar and camera inputs"),
        _intro(),
        "",
        ev.not_judged_text(reference),
        "",
        "## Fused against its inputs",
        "",
        f"The fused median MiD is below both of its inputs' on **{beats} of {len(compared)}** "
        "fused settings (`beats_inputs`). Ranked on the fused TTC "
        "(`ttc.evaluation.RANKING_RULE`); every metric is over the run's own frames.",
        "",
        markdown_table(compared.drop(columns=["run_id"])),
        "",
        f"## TTC per frame (s): the best fused setting, {compared['setting'].iloc[0]}",
        "",
        "![fused TTC](fp7_fusion_ttc.png)",
        "",
        f"## Flagged frames ({len(flagged)} setting x frame rows of {len(t)})",
        "",
        "Reasons: " + ", ".join(f"`{k}` {v}" for k, v in counts.items()) + "."
        if len(counts)
        else "No flagged frame.",
        "",
        markdown_table(listing),
        "",
        f"(first {MAX_LISTED} by setting and frame; all in `fp7_fusion_ttc.csv`)"
        if len(flagged) > MAX_LISTED
        else "",
    ]
    return "\n".join(parts) + "\n"
