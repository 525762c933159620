"""Judging by how far the collision is, and what a setting reports where there is nothing ahead.

Per-regime metrics (:mod:`ttc.evaluation.metrics`) say how a setting does while the lead car
approaches, stops or stands; a recording that follows a car at a steady gap (KITTI odometry
sequence 04: ≈ 21 m, closing at ≈ 0.4 m/s, TTC ≈ 50 s) is all ``approach``. Binning the
judged frames by the reference TTC (TSTTC-style ranges: < 6 s, 6–12 s, 12–24 s, > 24 s)
separates the imminent collisions, where an estimate matters, from steady following, where
two-frame camera TTC is at the limit of keypoint precision (:func:`binned_metrics`).

A recording without a vehicle ahead (KITTI raw drive 0009, frames 0–10) has no reference TTC
to judge against: there a setting is judged on what it wrongly reports
(:func:`no_lead_reports`): any finite TTC on a frame pair without a lead vehicle, and any
collision warning (TTC < τ), are false alarms.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ttc.evaluation.errors import WARNING_TTC_S, sensors_of
from ttc.evaluation.lead_status import NO_LEAD

#: Edges (s) of the reference-TTC ranges, and their names.
TTC_BIN_EDGES_S: tuple[float, ...] = (0.0, 6.0, 12.0, 24.0, np.inf)
TTC_BINS: tuple[str, ...] = ("<6s", "6-12s", "12-24s", ">24s")


#: The finer ranges every object is judged in (:mod:`ttc.evaluation.object_errors`): the
#: critical range below 6 s split at 3 s.
OBJECT_TTC_BIN_EDGES_S: tuple[float, ...] = (0.0, 3.0, 6.0, 12.0, 24.0, np.inf)
OBJECT_TTC_BINS: tuple[str, ...] = ("<3s", "3-6s", "6-12s", "12-24s", ">24s")


#: Upper edges (m) of the lidar distance bands boxes are counted in, and their names.
DISTANCE_BANDS: tuple[float, ...] = (10.0, 20.0, 30.0, 45.0, np.inf)
DISTANCE_BAND_NAMES: tuple[str, ...] = ("<10 m", "10-20 m", "20-30 m", "30-45 m", ">45 m")


def band_counts(distance_m: np.ndarray) -> dict[str, int]:
    """Boxes per lidar distance band (:data:`DISTANCE_BAND_NAMES`; ``distance_m`` in metres,
    one per box) and those without a lidar distance (NaN: ``no lidar``)."""
    distance_m = np.asarray(distance_m, dtype=float)
    index = np.searchsorted(DISTANCE_BANDS, distance_m[np.isfinite(distance_m)], side="right")
    counts = {name: int((index == i).sum()) for i, name in enumerate(DISTANCE_BAND_NAMES)}
    return counts | {"no lidar": int(np.isnan(distance_m).sum())}


def ttc_bin(
    ttc_ref_s: np.ndarray | pd.Series,
    edges: tuple[float, ...] = TTC_BIN_EDGES_S,
    names: tuple[str, ...] = TTC_BINS,
) -> np.ndarray:
    """Range name (``names``, default :data:`TTC_BINS`, between ``edges`` in s) of each
    reference TTC (s); ``""`` where it is not a finite positive number (no collision course,
    no reference)."""
    ttc = np.asarray(ttc_ref_s, dtype=float)
    ok = np.isfinite(ttc) & (ttc > 0)
    index = np.searchsorted(edges, np.where(ok, ttc, 0.0), side="right") - 1
    named = np.asarray(names, dtype=object)[np.clip(index, 0, len(names) - 1)]
    return np.where(ok, named, "")


def binned_metrics(judged: pd.DataFrame) -> pd.DataFrame:
    """Per run and reference-TTC range (``run_id``, ``ttc_bin``): ``n_frames`` (judgeable
    frames in the range) and, per sensor ``s``, ``{s}_mid_median`` (motion-in-depth error,
    10⁻⁴), ``{s}_medae_rel`` (median relative TTC error), ``{s}_invalid_rate`` and
    ``{s}_outlier_rate`` (fractions). ``judged``: :func:`ttc.evaluation.judged_frames`."""
    t = judged[judged["judgeable"].astype(bool)].copy()
    t["ttc_bin"] = ttc_bin(t["ttc_ref_s"])
    t = t[t["ttc_bin"] != ""]
    keys = [t["run_id"], t["ttc_bin"]]
    out = pd.DataFrame({"n_frames": t.groupby(keys).size()})
    for s in sensors_of(t):
        out[f"{s}_mid_median"] = t[f"{s}_mid"].groupby(keys).median()
        out[f"{s}_medae_rel"] = t[f"{s}_rel_err"].groupby(keys).median()
        out[f"{s}_invalid_rate"] = t[f"{s}_invalid"].astype(float).groupby(keys).mean()
        out[f"{s}_outlier_rate"] = t[f"{s}_outlier"].astype(float).groupby(keys).mean()
    out = out.reset_index()
    out["ttc_bin"] = pd.Categorical(out["ttc_bin"], categories=TTC_BINS, ordered=True)
    return out.sort_values(["run_id", "ttc_bin"], ignore_index=True)


def no_lead_pairs(lead: pd.DataFrame, reference: pd.DataFrame) -> np.ndarray:
    """(n,) bool over the rows of ``lead`` (``prev_frame``, ``frame``): the pairs with a frame
    the reference found no vehicle ahead in (its ``lead`` column, ``no_lead``)."""
    if "lead" not in reference:
        return np.zeros(len(lead), dtype=bool)
    empty = set(reference.loc[reference["lead"] == NO_LEAD, "frame"].astype(int))
    prev = lead["prev_frame"].isin(empty).to_numpy()
    return prev | lead["frame"].isin(empty).to_numpy()


def no_lead_reports(
    lead: pd.DataFrame, reference: pd.DataFrame, warning_s: float = WARNING_TTC_S
) -> pd.DataFrame:
    """Per run: ``n_no_lead`` (frame pairs without a vehicle ahead, :func:`no_lead_pairs`)
    and per sensor ``s`` the false alarms there: ``{s}_reported`` (pairs with a finite
    positive lead TTC) and ``{s}_warnings`` (of those, TTC < ``warning_s`` seconds).

    ``lead``: one row per run × frame pair (:func:`ttc.evaluation.lead_rows`)."""
    empty = no_lead_pairs(lead, reference)
    runs = lead["run_id"]
    out = pd.DataFrame({"n_no_lead": pd.Series(empty, index=lead.index).groupby(runs).sum()})
    for s in sensors_of(lead):
        ttc = lead[f"ttc_{s}"].to_numpy(dtype=float)
        reported = empty & np.isfinite(ttc) & (ttc > 0)
        out[f"{s}_reported"] = pd.Series(reported, index=lead.index).groupby(runs).sum()
        warns = reported & (ttc < warning_s)
        out[f"{s}_warnings"] = pd.Series(warns, index=lead.index).groupby(runs).sum()
    return out.rename_axis("run_id").reset_index()
