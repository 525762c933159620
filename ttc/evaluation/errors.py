"""Per-frame errors of every estimate against the reference, and the time a frame cost.

Input is a sweep's ``frames`` table (one row per run × frame pair × box pair, see
``experiments/store/schema.py``) and a reference from :func:`ttc.evaluation.reference.reference_ttc`
(one row per frame pair, labelled at its current frame). Only the lead vehicle's row of each
frame pair is judged; a frame pair of a run without a lead row (no box held lane points)
counts as an invalid estimate of both sensors.

Per frame pair, for sensor ``s`` in :data:`SENSORS`:

- ``{s}_ratio``: the distance ratio ``r̂ = d(t_prev) / d(t_curr)`` the estimate rests on
  (lidar: ``d_prev / d_curr``, the distances the estimator chose; camera: ``camera_ratio``,
  the scale change of the keypoint pattern); ``{s}_invalid`` where it is not a positive
  number (the estimator gave none);
- ``{s}_mid``: motion-in-depth error ``MID_SCALE · |ln r̂ − ln r_ref|`` (10⁴ × the log-ratio
  error). Defined on every frame with a valid estimate, the stationary ones included
  (``r_ref = 1``), where a relative TTC error is not;
- ``{s}_rel_err``: ``|ttc − ref| / ref`` where the reference TTC is finite and ``judgeable``
  (known to within :data:`ttc.evaluation.reference.MAX_REF_REL_SD`) and the TTC is finite;
- ``{s}_outlier``: on those judgeable frames, the TTC is invalid (NaN, ±inf or ≤ 0) or more
  than ``outlier_rel`` off;
- ``{s}_false_alarm``: where the reference is +inf (no collision course), a finite TTC in
  ``(0, false_alarm_s)``;
- ``{s}_warns``: the estimate warns, ``0 < ttc < warning_s``; ``ref_warns``: the reference
  does (collision-warning precision and recall, :mod:`ttc.evaluation.metrics`).

Time: ``ms_per_frame`` is the sum of the lead row's stage times (:func:`stage_time_columns`,
ms). Stages that came from the stage cache count their cache-load time, so it is the time
this run took, which depends on what ran before it. ``ms_compute_per_frame`` replaces a
cached stage's time by the median time of the same stage computed (not cached) on the same
frame by any run of the table with the same stage inputs
(:data:`~ttc.evaluation.stage_times.CACHED_STAGE_INPUTS`), else on any frame; a stage that
no run of the table computed keeps its load time (the objects and lane points a sweep's
warm-up fills while the sweep is planned: the same entries for every setting of the sweep, so
they shift every setting's time alike and leave the order; :mod:`ttc.evaluation.stage_times`).
"""

from __future__ import annotations

from collections.abc import Collection
from collections.abc import Set as AbstractSet

import numpy as np
import pandas as pd

from ttc.evaluation.reference import MID_SCALE, two_frame_ttc
from ttc.evaluation.stage_times import compute_times, stage_time_columns, stage_time_counts

#: The estimates judged: camera (FP.4), lidar (FP.2) and their Kalman fusion (FP.7,
#: ``ttc_fused`` / ``fused_ratio``, present in sweeps made since the ``fusion`` axis exists).
SENSORS: tuple[str, ...] = ("camera", "lidar", "fused")
#: Relative error above which a TTC is an outlier.
OUTLIER_REL = 0.3
#: A finite TTC below this (s) where the reference says "no collision course" is a false
#: alarm. 10 s: while the cars of the KITTI sequence close, the reference is 6–15 s, so an
#: estimate under 10 s where they stand claims an approach as urgent as the real one.
FALSE_ALARM_S = 10.0
#: Collision-warning threshold τ (s): "TTC below τ" is a warning.
WARNING_TTC_S = 8.0
#: Columns of a sweep's rows that no metric reads (provenance and per-pair diagnostics of
#: the FP.5/FP.6 reports): a summary of a sweep of millions of rows leaves them unread.
NOT_JUDGED_COLUMNS: tuple[str, ...] = (
    "git_commit", "error", "scan_points_prev", "scan_dropped_curr", "lane_points_curr",
    "boxes_prev", "boxes_curr", "keypoints_prev", "described_curr", "matches_total",
    "box_class", "box_confidence", "box_x", "box_y", "lidar_points_prev",
    "lidar_outliers_prev", "lidar_outliers_curr", "lidar_closest_prev", "lidar_closest_curr",
    "lidar_median_prev", "camera_pairs", "box_shared_matches", "ttc_fused_sd", "fused_reason",
)  # fmt: skip
#: Reference columns joined onto each judged row.
REFERENCE_COLUMNS: tuple[str, ...] = (
    "ttc_ref_s",
    "collision_course",
    "ratio_ref",
    "mid_ref_sd",
    "ttc_ref_sd_s",
    "judgeable",
    "regime",
)


def sensors_of(table: pd.DataFrame) -> tuple[str, ...]:
    """The :data:`SENSORS` whose TTC column ``ttc_{s}`` the table has."""
    return tuple(s for s in SENSORS if f"ttc_{s}" in table)


def is_in(values: pd.Series, ids: Collection[str]) -> np.ndarray:
    """(n,) bool: each of ``values`` (run ids, strings) is one of ``ids``; each distinct value
    looked up once. pandas' ``isin`` converts every id of ``ids`` to a scalar each call: on
    the string columns a sweep's rows have it took 0.1 s for ``grand``'s 33,600 run ids over
    504,000 judged rows (a report asks a few times), 0.3 s a fragment of 26,000 rows where
    the ids were Arrow strings (88 of that report's 300 s then)."""
    ids = ids if isinstance(ids, AbstractSet) else set(ids)
    codes, distinct = pd.factorize(values, use_na_sentinel=False)
    found = np.fromiter((v in ids for v in distinct), dtype=bool, count=len(distinct))
    return found[codes]


def rows_where(frames: pd.DataFrame, mask: np.ndarray) -> pd.DataFrame:
    """The rows of ``frames`` where ``mask`` ((n,) bool), index kept: ``frames`` itself when
    that is every row (a shallow copy, pandas copies on write: a report's judged rows are not
    copied whole for a selection of all of them)."""
    return frames.copy(deep=False) if mask.all() else frames[mask]


def rows_of_runs(frames: pd.DataFrame, run_ids) -> pd.DataFrame:
    """The rows of ``frames`` whose ``run_id`` is in ``run_ids`` (:func:`rows_where`)."""
    return rows_where(frames, is_in(frames["run_id"], run_ids))


#: The estimates of a lead row stand-in (a frame pair whose run has no lead row): blanked.
LEAD_BLANKED = ("ttc_camera", "ttc_lidar", "ttc_fused", "camera_ratio", "fused_ratio", "d_prev",
                "d_curr")  # fmt: skip


def lead_row_positions(
    run_id: np.ndarray, frame: np.ndarray, is_lead: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Which rows :func:`lead_rows` keeps, from three (N,) columns of a rows table (run ids,
    integer frame numbers, the ``is_lead`` flags: bool, or object with None for unknown).

    Returns the positions (M,) of one row per (run_id, frame), in (run_id, frame) order: the
    pair's first row flagged ``is_lead``, else its first row (first in the table's order);
    and (M,) bool, True where the kept row is not a lead row (its estimates are blanked,
    :data:`LEAD_BLANKED`). The one rule for pandas frames and Arrow tables alike."""
    n = len(run_id)
    runs = pd.factorize(np.asarray(run_id), sort=True)[0]  # sorted as pandas sorts the ids
    flags = np.asarray(is_lead)
    known = ~pd.isna(flags)
    lead = np.zeros(n, dtype=bool)
    lead[known] = flags[known].astype(bool)
    rank = np.where(lead, 0, np.where(known, 1, 2))  # lead rows first, unknown flags last
    frames = np.asarray(frame)
    order = np.lexsort((rank, frames, runs))  # stable: ties keep the table's order
    ordered_runs, ordered_frames = runs[order], frames[order]
    first = np.ones(n, dtype=bool)
    first[1:] = (ordered_runs[1:] != ordered_runs[:-1]) | (
        ordered_frames[1:] != ordered_frames[:-1]
    )
    positions = order[first]
    return positions, ~lead[positions]


def lead_rows(frames: pd.DataFrame) -> pd.DataFrame:
    """One row per (run_id, frame), in that order (:func:`lead_row_positions`): the lead row,
    else the pair's first row with its estimates blanked (NaN TTCs and ratios: the run has no
    estimate of the lead vehicle there)."""
    positions, blank = lead_row_positions(
        frames["run_id"].to_numpy(), frames["frame"].to_numpy(), frames["is_lead"].to_numpy()
    )
    lead = frames.iloc[positions].reset_index(drop=True)
    lead.loc[blank, [c for c in LEAD_BLANKED if c in lead]] = np.nan
    return lead


def _pair_reference(table: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """The reference of each row's own frame pair (``prev_frame``, ``frame``) when it is not
    (frame − 1, frame), e.g. a sweep with ``dataset.step`` > 1: ratio and TTC from the
    smoothed distances of the two frames; ``mid_ref_sd`` bounded by the sum of the two
    distances' relative standard deviations (it holds whatever their correlation)."""
    ref = reference.set_index("frame")
    prev, curr = table["prev_frame"].to_numpy(), table["frame"].to_numpy()
    d_prev = ref["distance_smooth_m"].reindex(prev).to_numpy()
    d_curr = ref["distance_smooth_m"].reindex(curr).to_numpy()
    with np.errstate(divide="ignore", invalid="ignore"):
        rel_sd = (
            ref["distance_sd_m"].reindex(prev).to_numpy() / d_prev
            + ref["distance_sd_m"].reindex(curr).to_numpy() / d_curr
        )
    if "lead_segment" in ref:  # a pair spanning an empty lane or a change of lead: no ratio
        seg_prev = ref["lead_segment"].reindex(prev).to_numpy()
        seg_curr = ref["lead_segment"].reindex(curr).to_numpy()
        d_prev = np.where((seg_prev == seg_curr) & (seg_curr >= 0), d_prev, np.nan)
    pair = two_frame_ttc(d_prev, d_curr, table["dt"].to_numpy(dtype=float), rel_sd)
    return pd.DataFrame(
        {
            "ttc_ref_s": pair["ttc"],
            "collision_course": pair["closing"] & np.isfinite(pair["ttc"]),
            "ratio_ref": pair["ratio"],
            "mid_ref_sd": MID_SCALE * rel_sd,
            "ttc_ref_sd_s": pair["ttc_sd"],
            "judgeable": pair["judgeable"],
            "regime": np.where(pair["ratio"] == 1.0, "stationary", table["regime"].to_numpy()),
        },
        index=table.index,
    )


def attach_reference(
    frames: pd.DataFrame, reference: pd.DataFrame, lead_only: bool = True
) -> pd.DataFrame:
    """``frames`` with the reference's :data:`REFERENCE_COLUMNS` of each row's frame pair;
    by default only the lead rows (:func:`lead_rows`). Frames the reference does not cover get
    NaN, ``collision_course`` and ``judgeable`` False and an empty ``regime``."""
    table = lead_rows(frames) if lead_only else frames
    table = table.drop(columns=list(REFERENCE_COLUMNS), errors="ignore")
    cols = [c for c in REFERENCE_COLUMNS if c in reference]
    out = table.merge(reference[["frame", *cols]], on="frame", how="left", validate="many_to_one")
    if "prev_frame" in out and "distance_smooth_m" in reference:
        other = out["prev_frame"] != out["frame"] - 1
        if other.any():
            out.loc[other, cols] = _pair_reference(out[other], reference)[cols]
    for flag in ("collision_course", "judgeable"):
        if flag in out:
            out[flag] = out[flag].fillna(False).astype(bool)
    if "regime" in out:
        out["regime"] = out["regime"].fillna("")
    return out


def estimated_ratio(table: pd.DataFrame, sensor: str) -> np.ndarray:
    """The distance ratio ``d_prev / d_curr`` (n,) an estimate of ``sensor`` rests on (the
    fusion: its state's, ``fused_ratio``)."""
    if sensor in ("camera", "fused"):
        return table[f"{sensor}_ratio"].to_numpy(dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return table["d_prev"].to_numpy(dtype=float) / table["d_curr"].to_numpy(dtype=float)


def mid_error(ratio: np.ndarray, ratio_ref: np.ndarray) -> np.ndarray:
    """Motion-in-depth error ``MID_SCALE · |ln r̂ − ln r_ref|`` (n,); NaN where either ratio
    is not a positive number."""
    r, ref = np.asarray(ratio, dtype=float), np.asarray(ratio_ref, dtype=float)
    valid = np.isfinite(r) & (r > 0) & np.isfinite(ref) & (ref > 0)
    out = np.full(r.shape, np.nan)
    out[valid] = MID_SCALE * np.abs(np.log(r[valid]) - np.log(ref[valid]))
    return out


def _compute_times(lead: pd.DataFrame) -> pd.Series:
    """Per-row ``ms_compute_per_frame`` (ms): looked up beforehand
    (:func:`~ttc.evaluation.stage_times.with_compute_times`), else over ``lead`` itself."""
    if "ms_compute_per_frame" in lead:
        return lead["ms_compute_per_frame"]
    return compute_times(lead, stage_time_counts(lead))


def frame_errors(
    lead: pd.DataFrame,
    outlier_rel: float = OUTLIER_REL,
    false_alarm_s: float = FALSE_ALARM_S,
    warning_s: float = WARNING_TTC_S,
) -> pd.DataFrame:
    """Per lead row (from :func:`attach_reference`), for each sensor ``s``: ``{s}_ratio``,
    ``{s}_invalid`` (bool), ``{s}_mid``, ``{s}_rel_err``, ``{s}_outlier`` and
    ``{s}_false_alarm`` (1.0/0.0, NaN where not applicable), ``{s}_warns`` (bool); and
    ``ref_warns``, ``ms_per_frame``, ``ms_compute_per_frame`` (ms). Definitions in the module
    docstring; ``outlier_rel`` a fraction, ``false_alarm_s`` and ``warning_s`` seconds.
    ``lead`` is left as it is (pandas copies on write: its columns are not copied here)."""
    out = lead.copy(deep=False)
    ref = out["ttc_ref_s"].to_numpy(dtype=float)
    judged = out["judgeable"].to_numpy(dtype=bool) & np.isfinite(ref) & (ref > 0)
    no_course = np.isposinf(ref)
    out["ref_warns"] = np.isfinite(ref) & (ref > 0) & (ref < warning_s)
    for s in sensors_of(out):
        ratio = estimated_ratio(out, s)
        ttc = out[f"ttc_{s}"].to_numpy(dtype=float)
        finite = np.isfinite(ttc)
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.abs(ttc - ref) / ref
        rel = np.where(judged & finite, rel, np.nan)
        outlier = ~(finite & (ttc > 0)) | (rel > outlier_rel)
        warns = finite & (ttc > 0)
        out[f"{s}_ratio"] = ratio
        out[f"{s}_invalid"] = ~(np.isfinite(ratio) & (ratio > 0))
        out[f"{s}_mid"] = mid_error(ratio, out["ratio_ref"].to_numpy(dtype=float))
        out[f"{s}_rel_err"] = rel
        out[f"{s}_outlier"] = np.where(judged, outlier, np.nan)
        out[f"{s}_false_alarm"] = np.where(no_course, warns & (ttc < false_alarm_s), np.nan)
        out[f"{s}_warns"] = warns & (ttc < warning_s)
    out["ms_per_frame"] = out[stage_time_columns(lead)].sum(axis=1)
    out["ms_compute_per_frame"] = _compute_times(lead)
    return out
