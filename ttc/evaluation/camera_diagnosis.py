"""FP.6 diagnosis: which camera TTCs are way off and why, the ranking of the camera settings.

A frame of a camera setting is **way off** when its relative error exceeds
:data:`WAY_OFF_REL`, its TTC is invalid where the reference is finite, or it is a false alarm.
Reasons come from the rows (:func:`camera_rules`) and, for a bounded number of the worst rows,
from the geometry of the lead box's kept matches (:func:`match_geometry` on a
:class:`~ttc.rows.PairDetail` the caller computed). Tables and arrays in, tables out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from ttc import reasons
from ttc.evaluation.bootstrap import N_BOOT, bootstrap_rank_intervals
from ttc.evaluation.diagnosis import (
    CAMERA_AXES,
    code_texts,
    fmt,
    judged_rows,
    setting_labels,
    text_before,
    with_reasons,
)
from ttc.evaluation.errors import rows_of_runs
from ttc.evaluation.metrics import run_metrics
from ttc.evaluation.ranking import rank_runs
from ttc.features.keypoints import X, Y
from ttc.rows import PairDetail
from ttc.steps.camera_ttc import distance_ratios

#: Camera TTC "way off": relative error above this (or invalid where the reference is finite).
WAY_OFF_REL = 0.5
#: Fewer kept matches than this in the box: few matches.
FEW_MATCHES = 20
#: Share of the box's matches removed by FP.3 above this: many outliers.
REMOVED_SHARE = 0.4
#: |r − 1| below this: a scale change too small to measure (TTC > dt / 0.002 = 50 s at 10 Hz).
RATIO_HAIR = 0.002
#: Share of pair ratios exactly 1 above this: integer keypoint positions freeze the ratio.
EXACT_SHARE = 0.3
#: A kept match moving this many pixels off the box's motion (median displacement): leaving.
#: The lead car moves ≈ 1 px per frame in the image, keypoints are located to ≈ 1 px.
LEAVE_PX = 2.0
LEAVE_SHARE = 0.2
#: Kept current keypoints within this fraction of the box size of its edge: on the border.
BORDER_FRAC = 0.1
BORDER_SHARE = 0.45
#: A keypoint whose nearest projected lidar point (within ``LIDAR_PX`` pixels) is this far
#: behind the lead car's rear sits on the background.
BACKGROUND_M = 1.0
LIDAR_PX = 4.0
BACKGROUND_SHARE = 0.2
#: Way-off rows examined per detector × descriptor pair at most (matcher variants mostly
#: repeat each other).
PER_PAIR = 2


# --------------------------------------------------------------------------- the frame table


def camera_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """One ok run per camera setting (its first run id) of the run records ``runs``: run_id,
    the camera axes and ``setting`` (a short label)."""
    ok = runs[runs["status"] == "ok"].sort_values("run_id")
    chosen = ok.drop_duplicates(list(CAMERA_AXES))[["run_id", *CAMERA_AXES]].copy()
    chosen["setting"] = setting_labels(chosen, [a for a in CAMERA_AXES if a != "dataset"])
    return chosen.reset_index(drop=True)


def camera_frame_table(
    frames: pd.DataFrame, runs: pd.DataFrame, reference: pd.DataFrame
) -> pd.DataFrame:
    """One row per (camera setting, frame) with the reference, errors, ``way_off`` and
    ``ratio_expected`` (the distance ratio the reference implies, 1 + dt / ttc_ref_s); empty
    without an ok run."""
    chosen = camera_runs(runs)
    if chosen.empty:
        return pd.DataFrame()
    table = judged_rows(frames, reference, chosen["run_id"])
    table = table.merge(chosen[["run_id", "setting"]], on="run_id")
    judged = table["judgeable"].astype(bool)  # finite reference TTC known to 10 %
    table["way_off"] = (
        table["camera_rel_err"].gt(WAY_OFF_REL)
        | (judged & ~(np.isfinite(table["ttc_camera"]) & table["ttc_camera"].gt(0)))
        | table["camera_false_alarm"].eq(1)
    )
    table["ratio_expected"] = 1.0 + table["dt"] / table["ttc_ref_s"]
    return table.sort_values(["dataset", "setting", "frame"], ignore_index=True)


# --------------------------------------------------------------------------- rules on rows


def camera_rules(t: pd.DataFrame) -> dict[str, pd.Series]:
    """Reason texts per rule for way-off FP.6 rows, from the rows alone ('' where a rule does
    not fire)."""
    ok = t["camera_reason"].eq(reasons.OK)
    few = (
        "few matches: " + t["matches_kept"].astype(str) + " kept in the box ("
        + t["matches_in_box"].astype(str) + " in it, " + t["keypoints_curr"].astype(str)
        + " keypoints in the frame)"
    ).where(t["matches_kept"] < FEW_MATCHES, "")  # fmt: skip
    share = t["matches_removed"] / t["matches_in_box"].where(t["matches_in_box"] > 0)
    removed = (
        "many outliers: " + t["matches_removed"].astype(str) + " of "
        + t["matches_in_box"].astype(str) + " matches in the box (" + fmt(100 * share, ".0f")
        + " %) removed by " + t["keypoint_filter"].astype(str)
    ).where(share > REMOVED_SHARE, "")  # fmt: skip
    hair = ok & (t["camera_ratio"] - 1).abs().lt(RATIO_HAIR)
    near = (
        "median ratio within a hair of 1: r = " + fmt(t["camera_ratio"], ".5f")
        + " (scale change " + fmt(100 * (t["camera_ratio"] - 1), ".2f")
        + " % where the reference implies " + fmt(100 * (t["ratio_expected"] - 1), ".2f")
        + " %): a tenth of a pixel over a 100 px pair moves the TTC by seconds"
    ).where(hair, "")  # fmt: skip
    alarm = (
        "false alarm: " + fmt(t["ttc_camera"], ".1f") + " s where the cars do not close"
    ).where(t["camera_false_alarm"].eq(1), "")
    return {
        "code": code_texts(t["camera_reason"].astype(str)),
        "false_alarm": alarm,
        "few_matches": few,
        "many_removed": removed,
        "ratio_near_one": near,
    }


def camera_fallback(t: pd.DataFrame) -> pd.Series:
    """The reason of a way-off row no rule explains: its scale error in pixels."""
    err = t["camera_ratio"] - t["ratio_expected"]
    return (
        "scale error: r = " + fmt(t["camera_ratio"], ".4f") + " against "
        + fmt(t["ratio_expected"], ".4f") + " implied by the reference, an error of "
        + fmt(100 * err, ".2f") + " % or " + fmt((err * t["box_w"]).abs(), ".1f")
        + " px across the " + t["box_w"].astype(str) + " px box: keypoint position noise"
    )  # fmt: skip


def camera_reasons(t: pd.DataFrame) -> pd.DataFrame:
    """``t`` with ``reasons`` / ``reason_text`` of the way-off rows from the rows alone."""
    return with_reasons(t, "way_off", camera_rules, "scale_error", camera_fallback)


# --------------------------------------------------------------------------- match geometry


@dataclass(frozen=True)
class MatchGeometry:
    """Measurements on the kept matches of a lead box (counts of matches; share 0–1)."""

    kept: int
    exact_share: float
    still: int
    leaving: int
    border: int
    with_depth: int
    background: int


def match_geometry(detail: PairDetail, min_dist: float, ref_distance: float) -> MatchGeometry:
    """Exact-1 ratio share, matches off the box's motion, on its border, on the background.

    Parameters
    ----------
    detail
        The frame pair's intermediate arrays (keypoints in pixels, lane points in metres).
    min_dist
        Least current pair distance (pixels) of a distance ratio (the FP.4 parameter).
    ref_distance
        The reference rear distance of the current frame (metres).
    """
    m, kept = detail.matches, np.asarray(detail.kept)
    prev = detail.keypoints[detail.prev][np.asarray(m.prev_idx)[kept]][:, [X, Y]]
    curr = detail.keypoints[detail.curr][np.asarray(m.curr_idx)[kept]][:, [X, Y]]
    if len(kept) == 0 or detail.lead_box < 0:
        return MatchGeometry(0, 0.0, 0, 0, 0, 0, 0)
    ratios = distance_ratios(prev, curr, min_dist)
    exact = float(np.mean(ratios == 1.0)) if len(ratios) else 0.0
    motion = curr - prev
    still = int(np.sum(np.all(motion == 0, axis=1)))
    leaving = int(np.sum(np.hypot(*(motion - np.median(motion, axis=0)).T) > LEAVE_PX))
    x, y, w, h = detail.objects[detail.curr]["roi"][detail.lead_box].astype(float)
    edge = np.minimum(np.minimum(curr[:, 0] - x, x + w - curr[:, 0]) / w,
                      np.minimum(curr[:, 1] - y, y + h - curr[:, 1]) / h)  # fmt: skip
    uv, depth = detail.lane_uv[detail.curr], detail.lane_points[detail.curr][:, 0]
    with_depth = background = 0
    finite = np.isfinite(uv).all(axis=1)
    if finite.any():
        dist, nearest = cKDTree(uv[finite]).query(curr, distance_upper_bound=LIDAR_PX)
        hit = np.isfinite(dist)
        far = depth[finite][nearest[hit]] > ref_distance + BACKGROUND_M
        with_depth, background = int(hit.sum()), int(far.sum())
    return MatchGeometry(len(kept), exact, still, leaving, int(np.sum(edge < BORDER_FRAC)),
                         with_depth, background)  # fmt: skip


def geometry_texts(g: MatchGeometry) -> dict[str, str]:
    """Reason texts the match geometry supports ('' where it does not), by reason code."""
    texts = dict.fromkeys(("exact_ratios", "leaving_object", "box_edge", "background"), "")
    if g.kept == 0:
        return texts
    if g.exact_share > EXACT_SHARE:
        texts["exact_ratios"] = (
            f"{100 * g.exact_share:.0f} % of the pair distance ratios are exactly 1 and "
            f"{g.still} of {g.kept} kept keypoints did not move at all (integer positions): "
            "the median ratio is pinned at or next to 1"
        )
    if g.leaving / g.kept > LEAVE_SHARE:
        texts["leaving_object"] = (
            f"matches leaving the object: {g.leaving} of {g.kept} kept matches move more than "
            f"{LEAVE_PX:.0f} px off the box's median motion (mismatches across object borders)"
        )
    if g.border / g.kept > BORDER_SHARE:
        texts["box_edge"] = (
            f"keypoints on the box edge: {g.border} of {g.kept} kept keypoints lie within "
            f"{BORDER_FRAC:.0%} of the box border (silhouette, background behind it)"
        )
    if g.with_depth >= 3 and g.background / g.with_depth > BACKGROUND_SHARE:
        texts["background"] = (
            f"keypoints on the background: {g.background} of {g.with_depth} kept keypoints "
            f"with a lidar point nearby are > {BACKGROUND_M:.0f} m behind the car's rear"
        )
    return texts


def with_geometry_reasons(
    reason_codes: str, reason_text: str, extra: dict[str, str]
) -> tuple[str, str]:
    """A row's (``reasons``, ``reason_text``) with the match-geometry reasons ``extra`` (code ->
    text, only those that fire) added; they replace the ``scale_error`` fallback."""
    if not extra:
        return reason_codes, reason_text
    codes = [c for c in reason_codes.split(";") if c and c != "scale_error"]
    text = "" if "scale_error" in reason_codes else reason_text
    return ";".join(codes + list(extra)), " ".join(
        [text, *(v + "." for v in extra.values())]
    ).strip()


def worst_order(t: pd.DataFrame, per_pair: int = PER_PAIR, turns: str = "primary") -> pd.DataFrame:
    """Way-off rows, worst first (invalid first), at most ``per_pair`` per detector ×
    descriptor pair (matcher variants mostly repeat each other), round-robin over the values
    of ``turns`` (``primary``: the first reason code, or an axis such as ``detector``)."""
    way = t["way_off"].to_numpy(dtype=bool)
    if not way.any():
        return t[way].copy()
    keys = ["camera_rel_err", "reasons", "setting", "frame", "dataset", "detector", "descriptor"]
    w = t.loc[way, [c for c in dict.fromkeys([*keys, turns]) if c in t]]  # ordered on these
    w["severity"] = w["camera_rel_err"].fillna(np.inf)
    w["primary"] = text_before(w["reasons"], ";")
    w = w.sort_values(["severity", "setting", "frame"], ascending=[0, 1, 1])
    w = w[w.groupby(["dataset", "detector", "descriptor"]).cumcount() < per_pair]
    w["turn"] = w.groupby(turns).cumcount()
    w = w.sort_values(["turn", "severity", "setting", "frame"], ascending=[1, 0, 1, 1])
    return t.loc[w.index].assign(severity=w["severity"], primary=w["primary"], turn=w["turn"])


# --------------------------------------------------------------------------- ranking


def camera_ranking(
    frames: pd.DataFrame, t: pd.DataFrame, reference: pd.DataFrame, n_boot: int = N_BOOT
) -> pd.DataFrame:
    """Per dataset: metrics, rank and bootstrap rank interval (``n_boot`` replicates, seed 0)
    of every camera setting of the frame table ``t``, with its label and way-off count."""
    parts = []
    for _, group in t.groupby("dataset", sort=True):
        ids = group["run_id"].unique()
        subset = rows_of_runs(frames, ids)
        metrics = run_metrics(subset, reference)
        ranked = rank_runs(metrics, "camera")
        ci = bootstrap_rank_intervals(subset, reference, n_boot=n_boot, seed=0, metrics=metrics)
        parts.append(ranked.merge(ci.drop(columns="rank"), on="run_id"))
    ranking = pd.concat(parts, ignore_index=True)
    labels = t.drop_duplicates("run_id").set_index("run_id")["setting"]
    ranking.insert(0, "setting", ranking["run_id"].map(labels))
    way = t.groupby("run_id")["way_off"].sum()
    ranking["way_off_frames"] = ranking["run_id"].map(way)
    return ranking.sort_values(["dataset", "rank"], ignore_index=True)


def pareto_front(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Indices of the points (x, y: (N,) each) not dominated in (x lower, y lower), by
    increasing x; points with a non-finite y are left out."""
    order = np.lexsort((y, x))
    best = np.minimum.accumulate(y[order])
    keep = np.r_[True, best[1:] < best[:-1]]
    return order[keep & np.isfinite(y[order])]
