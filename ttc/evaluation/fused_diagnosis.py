"""FP.7 diagnosis: how the fused TTC compares with the two estimates it fuses, which fused
TTCs are implausible and why.

The runs judged are the ok runs with a Kalman fusion (``fusion`` other than ``none``): each
carries, per frame, its own lidar TTC (FP.2), camera TTC (FP.4) and the fused TTC
(:mod:`ttc.steps.fusion`, ``ttc_fused`` with the filter's ``fused_reason``). A fused frame is
**flagged** when it is an outlier (invalid, or more than ``OUTLIER_REL`` off a judgeable
reference) or a false alarm, like the sensors' frames. Its reasons are rules on the same row
(:func:`fused_rules`), each naming what the filter was given:

* ``start``: the filter began fewer than :data:`START_FRAMES` frames before (its closing speed
  still rests on the first few measurements);
* ``one_sensor``: only one sensor, or none, updated the filter at that frame (the other was
  missing or rejected by the innovation gate; the filter's own ``fused_reason``);
* ``receding``: the fused closing speed is <= 0 (TTC +inf) while the reference approaches;
* ``lidar_off`` / ``camera_off``: that input is itself off the reference by more than
  ``OUTLIER_REL`` on the same side as the fused TTC, or invalid: the fusion followed it;

and when none fires, ``lag``: both inputs are within ``OUTLIER_REL`` (or one is missing) yet
the fused TTC is off: the filter's state trails a change the measurements already show.
Tables in, tables out: no files.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ttc.evaluation.diagnosis import (
    CAMERA_AXES,
    fmt,
    judged_rows,
    setting_labels,
    with_reasons,
)
from ttc.evaluation.errors import OUTLIER_REL, rows_of_runs
from ttc.evaluation.metrics import run_metrics
from ttc.evaluation.ranking import rank_runs
from ttc.steps import fusion

#: Frames after the filter's first estimate during which a flagged frame is blamed on its start.
START_FRAMES = 3
#: ``fused_reason`` codes of a frame updated by one sensor or none.
ONE_SENSOR = (fusion.LIDAR_ONLY, fusion.CAMERA_ONLY, fusion.PREDICTED)
#: Columns of :func:`fusion_vs_inputs` per sensor, in the order shown.
COMPARED = ("invalid_rate", "mid_median", "outlier_rate", "medae_rel")


def fused_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """The ok runs of ``runs`` (run records) with a fusion other than ``none``."""
    if "fusion" not in runs:
        return runs.iloc[0:0]
    return runs[(runs["status"] == "ok") & (runs["fusion"].astype(str) != "none")]


def fused_frame_table(
    frames: pd.DataFrame, runs: pd.DataFrame, reference: pd.DataFrame
) -> pd.DataFrame:
    """One row per frame of every fused run (:func:`fused_runs`) with the reference, the
    errors of the three estimates (:func:`ttc.evaluation.frame_errors`), ``setting`` (a short
    label of its axes that vary), ``since_start`` (frames since the filter's first finite
    estimate, -1 before it) and ``flagged``; sorted by setting and frame. Empty without a
    fused run."""
    chosen = fused_runs(runs)
    if chosen.empty or "ttc_fused" not in frames:
        return pd.DataFrame()
    t = judged_rows(frames, reference, chosen["run_id"])
    t = t.sort_values(["run_id", "frame"], ignore_index=True)
    t["setting"] = setting_labels(t, [*CAMERA_AXES, "lidar_ttc", "fusion"])
    started = np.isfinite(t["ttc_fused"].to_numpy(float)) | t["fused_reason"].isin(
        [fusion.RECEDING]
    )
    begun = pd.Series(started, index=t.index).groupby(t["run_id"]).cummax()
    t["since_start"] = begun.astype(int).groupby(t["run_id"]).cumsum() - 1
    t["flagged"] = t["fused_outlier"].eq(1) | t["fused_false_alarm"].eq(1)
    return t.sort_values(["setting", "frame"], ignore_index=True)


def _side(t: pd.DataFrame, sensor: str) -> pd.Series:
    """+1 where ``sensor``'s TTC is above the reference, -1 below, 0 when not finite."""
    diff = t[f"ttc_{sensor}"].astype(float) - t["ttc_ref_s"].astype(float)
    return np.sign(diff).where(np.isfinite(diff), 0.0)


def _input_off(t: pd.DataFrame, sensor: str) -> pd.Series:
    """Reason text where the run's ``sensor`` TTC is off on the fused TTC's side, or invalid
    while the fused TTC is invalid too."""
    invalid = t[f"{sensor}_invalid"].astype(bool)
    off = (t[f"{sensor}_rel_err"] > OUTLIER_REL) & (_side(t, sensor) == _side(t, "fused"))
    both_invalid = invalid & t["fused_invalid"].astype(bool)
    text = (
        f"the {sensor} TTC is off too: "
        + fmt(t[f"ttc_{sensor}"], ".2f")
        + " s against "
        + fmt(t["ttc_ref_s"], ".2f")
        + " s ("
        + fmt(100 * t[f"{sensor}_rel_err"], ".0f")
        + " %)"
    )
    text = text.where(~invalid, f"the {sensor} TTC is invalid at this frame")
    return text.where(off | both_invalid, "")


def fused_rules(t: pd.DataFrame) -> dict[str, pd.Series]:
    """Reason texts per rule (module docstring) over the rows of ``t``; '' where a rule does
    not fire."""
    start = t["since_start"].between(0, START_FRAMES - 1)
    one = t["fused_reason"].isin(ONE_SENSOR)
    receding = t["fused_reason"].eq(fusion.RECEDING) & np.isfinite(t["ttc_ref_s"])
    return {
        "start": ("the filter started " + t["since_start"].astype(str) + " frame(s) before").where(
            start, ""
        ),
        "one_sensor": t["fused_reason"].map(fusion.REASONS).fillna("").where(one, ""),
        "receding": pd.Series("the fused closing speed is <= 0 (+inf)", index=t.index).where(
            receding, ""
        ),
        "lidar_off": _input_off(t, "lidar"),
        "camera_off": _input_off(t, "camera"),
    }


def _lag_text(t: pd.DataFrame) -> pd.Series:
    """The fallback reason: the inputs agree with the reference, the filter's state does not."""
    return (
        "lidar "
        + fmt(t["ttc_lidar"], ".2f")
        + " s and camera "
        + fmt(t["ttc_camera"], ".2f")
        + " s are within "
        + f"{OUTLIER_REL:.0%} of the reference "
        + fmt(t["ttc_ref_s"], ".2f")
        + " s (or missing), the fused "
        + fmt(t["ttc_fused"], ".2f")
        + " s is not: the filter's state trails them"
    )


def fused_reasons(t: pd.DataFrame) -> pd.DataFrame:
    """``t`` (:func:`fused_frame_table`) with ``reasons`` and ``reason_text`` on the flagged
    rows (:func:`ttc.evaluation.diagnosis.with_reasons`)."""
    if t.empty:
        return t.assign(reasons="", reason_text="")
    return with_reasons(t, "flagged", fused_rules, "lag", _lag_text)


def fusion_vs_inputs(
    frames: pd.DataFrame, t: pd.DataFrame, reference: pd.DataFrame
) -> pd.DataFrame:
    """One row per fused run of ``t``: its ``setting``, rank on the fused TTC
    (:func:`ttc.evaluation.rank_runs`), and for each of fused, lidar and camera the metrics
    :data:`COMPARED` (:func:`ttc.evaluation.run_metrics` of the run's own rows); plus
    ``beats_inputs``: the fused median MiD is below both inputs' (a NaN input counts as
    beaten). Sorted by fused rank."""
    if t.empty:
        return pd.DataFrame()
    subset = rows_of_runs(frames, t["run_id"])
    ranked = rank_runs(run_metrics(subset, reference), "fused")
    labels = t.drop_duplicates("run_id").set_index("run_id")["setting"]
    columns = [f"{s}_{m}" for s in ("fused", "lidar", "camera") for m in COMPARED]
    out = ranked[["rank", "run_id", *[c for c in columns if c in ranked]]].copy()
    out.insert(1, "setting", out["run_id"].map(labels))
    fused = out["fused_mid_median"]
    out["beats_inputs"] = fused.notna() & ~(
        (out["lidar_mid_median"] <= fused) | (out["camera_mid_median"] <= fused)
    )
    return out.sort_values(["rank", "run_id"], ignore_index=True)
