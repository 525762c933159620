"""FP.5 diagnosis: which lidar TTCs are implausible and why, from the frame table and the lead
box's points.

Flags come from the judged rows (an outlier, a false alarm or a truncated scan); reasons are
rules on the frame table (:func:`lidar_rules`, each a vectorised test with the thresholds
below, in metres), plus the measurement of other objects' clusters in a box
(:func:`other_object_text`) on the points a caller loads. Tables and arrays in, tables out.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from ttc.evaluation.diagnosis import (
    CAMERA_AXES,
    centimetres,
    code_texts,
    fmt,
    judged_rows,
    setting_key,
    with_reasons,
)
from ttc.evaluation.errors import rows_of_runs
from ttc.evaluation.lead_distance import euclidean_clusters
from ttc.evaluation.metrics import run_metrics
from ttc.steps.lidar_ttc import LIDAR_ESTIMATORS, LidarTTCParams
from ttc.steps.lidar_ttc import rear_distance as estimator_distance

#: Closest box point this far in front of the reference rear: points ahead of the bumper.
AHEAD_M = 0.10
#: The estimator's distance moved this far from its usual offset to the reference rear.
ANOMALY_M = 0.02
#: |Δd| per frame below this is within the lidar's range noise (HDL-64E: ≈ 2 cm per return).
NOISE_FLOOR_M = 0.03
#: The measured rear's step differs from the smoothed reference's by more than this while the
#: estimate follows the measured step within it: a step shared by every estimator.
SHARED_STEP_M = 0.015
#: A step of the estimate larger than this is not blamed on range noise.
MAX_NOISE_STEP_M = 0.5
#: A Euclidean cluster of at least this many box points, apart from the largest one (the
#: car's rear) by more than ``OTHER_GAP_M`` in x: points of another object in the box.
SECOND_CLUSTER_POINTS = 5
OTHER_GAP_M = 0.5
#: ... and they count when they move the estimator's distance by more than this (metres).
OTHER_EFFECT_M = 0.01
#: Relative change of the lead box's width or height between consecutive frames: box jump.
BOX_JUMP = 0.15


# --------------------------------------------------------------------------- the frame table


def lidar_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """One ok run per (dataset, lidar estimator) of the run records ``runs``: all on the
    camera setting shared by the most estimators (ties: the alphabetically first), else the
    estimator's first run id. Columns: dataset, lidar_ttc, run_id."""
    ok = runs[runs["status"] == "ok"].sort_values("run_id").copy()
    ok["camera_key"] = setting_key(ok, CAMERA_AXES)
    spread = ok.groupby(["dataset", "camera_key"])["lidar_ttc"].nunique().reset_index()
    spread = spread.sort_values(["dataset", "lidar_ttc", "camera_key"], ascending=[1, 0, 1])
    best = spread.drop_duplicates("dataset").set_index("dataset")["camera_key"]
    ok["preferred"] = ok["camera_key"].eq(ok["dataset"].map(best))
    ok = ok.sort_values(["dataset", "lidar_ttc", "preferred", "run_id"], ascending=[1, 1, 0, 1])
    return ok.drop_duplicates(["dataset", "lidar_ttc"])[["dataset", "lidar_ttc", "run_id"]]


def with_reference_distances(table: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """``table`` with the reference rear distance (raw, m; NaN where interpolated) of the
    previous and current frame (``ref_d_prev``, ``ref_d_curr``) and the per-frame steps (m):
    smoothed reference ``ref_step``, measured rear ``raw_step``, estimate ``est_step``."""
    ref = reference.set_index("frame")
    raw = ref["distance_m"].where(~ref["distance_interpolated"].astype(bool))
    out = table.copy()
    out["ref_d_prev"] = out["prev_frame"].map(raw)
    out["ref_d_curr"] = out["frame"].map(raw)
    out["ref_step"] = out["prev_frame"].map(ref["distance_smooth_m"]) - out["frame"].map(
        ref["distance_smooth_m"]
    )
    out["raw_step"] = out["ref_d_prev"] - out["ref_d_curr"]
    out["est_step"] = out["d_prev"] - out["d_curr"]
    return out


def with_history(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` sorted by run and frame with the lead box of each run's previous frame pair
    (``lead_before``, ``w_before``, ``h_before`` px; −1/NaN if none), each estimate's offset
    to the reference rear less its usual (median) offset (``anomaly_prev``,
    ``anomaly_curr``, m) and the run's median scan size (``scan_usual``, points)."""
    out = table.sort_values(["run_id", "frame"]).copy()
    before = out.groupby("run_id")[["frame", "curr_box", "box_w", "box_h"]].shift(1)
    follows = before["frame"].eq(out["prev_frame"])
    out["lead_before"] = before["curr_box"].where(follows, -1).astype(int)
    out["w_before"] = before["box_w"].where(follows & before["curr_box"].ge(0))
    out["h_before"] = before["box_h"].where(follows & before["curr_box"].ge(0))
    off_prev = out["d_prev"] - out["ref_d_prev"]
    off_curr = out["d_curr"] - out["ref_d_curr"]
    usual = off_curr.groupby(out["run_id"]).transform("median")
    out["anomaly_prev"] = off_prev - usual
    out["anomaly_curr"] = off_curr - usual
    out["scan_usual"] = out.groupby("run_id")["scan_points_curr"].transform("median")
    return out


def lidar_frame_table(
    frames: pd.DataFrame, runs: pd.DataFrame, reference: pd.DataFrame
) -> pd.DataFrame:
    """One row per (dataset, frame, lidar estimator) of :func:`lidar_runs` with the reference,
    errors, the derived quantities above and ``flagged`` (outlier, false alarm or truncated
    scan); empty without an ok run."""
    chosen = lidar_runs(runs)
    if chosen.empty:
        return pd.DataFrame()
    table = judged_rows(frames, reference, chosen["run_id"])
    table = with_history(with_reference_distances(table, reference))
    table["flagged"] = (
        table["lidar_outlier"].eq(1) | table["lidar_false_alarm"].eq(1) | table["scan_short"]
    )
    n_settings = runs[runs["status"] == "ok"].groupby(["dataset", "lidar_ttc"]).size()
    table["camera_settings"] = pd.MultiIndex.from_frame(table[["dataset", "lidar_ttc"]]).map(
        n_settings
    )
    return table.sort_values(["dataset", "frame", "lidar_ttc"], ignore_index=True)


# --------------------------------------------------------------------------- rules


def _ahead_text(t: pd.DataFrame, which: str, effect: str) -> pd.Series:
    closest, ref = t[f"lidar_closest_{which}"], t[f"ref_d_{which}"]
    fires = (closest < ref - AHEAD_M) & (t[f"anomaly_{which}"] < -ANOMALY_M)
    frame = t["frame"] if which == "curr" else t["prev_frame"]
    text = (
        "points ahead of the bumper in frame " + frame.astype(str) + ": closest point "
        + fmt(closest, ".2f") + " m, " + centimetres(ref - closest) + " in front of the rear at "
        + fmt(ref, ".2f") + " m, and the chosen distance " + fmt(t[f"d_{which}"], ".2f")
        + " m followed them (" + effect + ")"
    )  # fmt: skip
    return text.where(fires, "")


def _noise_text(t: pd.DataFrame) -> pd.Series:
    floor = f"{100 * NOISE_FLOOR_M:.0f} cm"
    est_small = t["est_step"].abs() < NOISE_FLOOR_M
    true_small = ~est_small & (t["ref_step"].abs() < NOISE_FLOOR_M)
    true_small &= t["est_step"].abs() < MAX_NOISE_STEP_M
    noise_est = (
        "distance change below the noise floor: the estimate moved only "
        + centimetres(t["est_step"]) + " (measured rear " + centimetres(t["raw_step"])
        + ", smoothed reference " + centimetres(t["ref_step"]) + "), under the lidar's ~"
        + floor + " range noise, so TTC = d dt / delta-d is huge or unstable"
    ).where(est_small, "")  # fmt: skip
    noise_true = (
        "the cars close by only " + centimetres(t["ref_step"]) + " per frame (smoothed "
        + "reference; measured rear " + centimetres(t["raw_step"]) + "), below the ~" + floor
        + " noise floor: the estimate's " + centimetres(t["est_step"]) + " step is noise or a "
        + "change in the sampled points, and any such step gives a finite TTC"
    ).where(true_small & t["est_step"].notna(), "")  # fmt: skip
    return noise_est + noise_true


def _box_texts(t: pd.DataFrame) -> tuple[pd.Series, pd.Series]:
    """Box switch and box size jump texts."""
    switch = t["lead_before"].ge(0) & t["prev_box"].ge(0) & t["prev_box"].ne(t["lead_before"])
    switched = (
        "box switch: FP.1 paired lead box #" + t["curr_box"].astype(str) + " with box #"
        + t["prev_box"].astype(str) + " of frame " + t["prev_frame"].astype(str)
        + ", whose lead box was #" + t["lead_before"].astype(str)
    ).where(switch, "")  # fmt: skip
    jump = (t["box_w"] / t["w_before"] - 1).abs().gt(BOX_JUMP) | (
        t["box_h"] / t["h_before"] - 1
    ).abs().gt(BOX_JUMP)
    jumped = (
        "box size jump: " + fmt(t["w_before"], ".0f") + "x" + fmt(t["h_before"], ".0f")
        + " -> " + t["box_w"].astype(str) + "x" + t["box_h"].astype(str)
        + " px, the box takes in other points"
    ).where(jump, "")  # fmt: skip
    return switched, jumped


def lidar_rules(t: pd.DataFrame) -> dict[str, pd.Series]:
    """Reason texts per rule for FP.5 rows of :func:`lidar_frame_table` ('' where the rule
    does not fire). An ``other_object_text`` column, when present, is the ``other_object``
    rule (:func:`other_object_text`, measured on the points)."""
    short = (
        "truncated scan: frame " + t["frame"].astype(str) + " has "
        + t["scan_points_curr"].astype(str) + " points, "
        + fmt(100 * t["scan_points_curr"] / t["scan_usual"], ".0f")
        + " % of the usual scan; the box holds " + t["lidar_points_curr"].astype(str)
        + " points (median x " + fmt(t["lidar_median_curr"], ".2f") + " m)"
    ).where(t["scan_short"], "")  # fmt: skip
    ahead_curr = _ahead_text(t, "curr", "distance too short: TTC too small")
    ahead_prev = _ahead_text(t, "prev", "previous distance too short: TTC too large or receding")
    ahead = ahead_curr + np.where(ahead_curr.ne("") & ahead_prev.ne(""), "; ", "") + ahead_prev
    switched, jumped = _box_texts(t)
    other = t.get("other_object_text", pd.Series("", index=t.index))
    shared = (t["raw_step"] - t["ref_step"]).abs().gt(SHARED_STEP_M) & (
        t["est_step"] - t["raw_step"]
    ).abs().lt(SHARED_STEP_M)
    measured = (
        "the measured rear itself moved " + centimetres(t["raw_step"]) + " where the smoothed "
        + "reference moves " + centimetres(t["ref_step"]) + ", and the estimate followed it ("
        + centimetres(t["est_step"]) + "): a one-frame step every rear estimate shares (a speed "
        + "change within 0.1 s or noise of the whole rear surface), which the 0.9 s smoothing "
        + "of the reference does not follow"
    ).where(shared, "")  # fmt: skip
    return {
        "scan_short": short,
        "code": code_texts(t["lidar_reason"].astype(str)),
        "points_ahead": ahead,
        "noise_floor": _noise_text(t),
        "other_object": other,
        "measured_step": measured,
        "box_switch": switched,
        "box_jump": jumped,
    }


def lidar_fallback(t: pd.DataFrame) -> pd.Series:
    """The reason of a flagged row no rule explains: the distances' deviation (range noise)."""
    return (
        "range noise: the estimate moved " + centimetres(t["est_step"]) + ", the measured rear "
        + centimetres(t["raw_step"]) + ", the smoothed reference " + centimetres(t["ref_step"])
        + "; the estimate's distances are "
        + centimetres(t["anomaly_prev"]) + " (frame " + t["prev_frame"].astype(str) + ") and "
        + centimetres(t["anomaly_curr"]) + " (frame " + t["frame"].astype(str)
        + ") off their usual offset to the rear"
    )  # fmt: skip


def lidar_reasons(t: pd.DataFrame, other_object: pd.Series | None = None) -> pd.DataFrame:
    """``t`` with ``reasons`` / ``reason_text`` on its flagged rows ('' elsewhere).

    ``other_object``: the ``other_object`` rule's texts over ``t.index``
    (:func:`other_object_text` of the rows' points); None leaves that rule out.
    """
    t = t.copy()
    if other_object is not None:
        t["other_object_text"] = other_object
    t = with_reasons(t, "flagged", lidar_rules, "range_noise", lidar_fallback)
    return t.drop(columns=["other_object_text"], errors="ignore")


# --------------------------------------------------------------------------- other objects


def other_clusters(points: np.ndarray) -> tuple[np.ndarray, str]:
    """Clusters of another object among a box's points.

    Parameters
    ----------
    points
        (N, ≥3) box points, metres.

    Returns
    -------
    (N,) bool mask of the points in Euclidean clusters of at least
    :data:`SECOND_CLUSTER_POINTS` points more than :data:`OTHER_GAP_M` in x off the largest
    cluster (the car's rear), and a description of them ('' when there are none).
    """
    none = np.zeros(len(points), dtype=bool)
    if len(points) < 2 * SECOND_CLUSTER_POINTS:
        return none, ""
    labels = euclidean_clusters(points[:, :3].astype(np.float64))
    x = pd.Series(points[:, 0]).groupby(labels).agg(["size", "min", "max"])
    main = x.loc[x["size"].idxmax()]
    apart = (x["max"] < main["min"] - OTHER_GAP_M) | (x["min"] > main["max"] + OTHER_GAP_M)
    other = x[apart & (x["size"] >= SECOND_CLUSTER_POINTS)]
    if other.empty:
        return none, ""
    found = ", ".join(f"{r.size} at {r.min:.2f}-{r.max:.2f} m" for r in other.itertuples())
    text = f"{found} beside the rear cluster at {main['min']:.2f}-{main['max']:.2f} m"
    return np.isin(labels, other.index.to_numpy()), text


def other_object_effect(points: np.ndarray, params: LidarTTCParams) -> tuple[float, str]:
    """How far (m) the other clusters of a box (N × ≥3 points, metres) move the estimator's
    distance (with − without them), and their description; (0, '') when there are none."""
    other, text = other_clusters(points)
    if not other.any():
        return 0.0, ""
    with_them = estimator_distance(points, params).distance
    without = estimator_distance(points[~other], params).distance
    return float(with_them - without), text


def other_object_text(clouds: dict[int, np.ndarray], params: LidarTTCParams) -> str:
    """The ``other_object`` reason of one estimator on the lead box's points per frame
    (``{frame: N × ≥3 points, metres}``): the frames whose other clusters move its distance by
    more than :data:`OTHER_EFFECT_M`; '' when none does."""
    found = []
    for frame, points in clouds.items():
        shift, text = other_object_effect(points, params)
        if abs(shift) > OTHER_EFFECT_M:
            found.append(f"frame {frame}: {text} move the distance by {100 * shift:+.1f} cm")
    return "points of another object in the box (" + "; ".join(found) + ")" if found else ""


def other_object_pairs(t: pd.DataFrame) -> pd.DataFrame:
    """The flagged rows with a previous box whose points :func:`other_object_text` examines,
    and per (dataset, frame) the run whose pair detail stands for them (its first row):
    the rows with an added ``detail_run`` column."""
    flagged = t[t["flagged"] & t["prev_box"].ge(0)]
    first = flagged.groupby(["dataset", "frame"], sort=True)["run_id"].transform("first")
    return flagged.assign(detail_run=first).sort_values(["dataset", "frame"], kind="stable")


def estimator_marks(points: np.ndarray, params: LidarTTCParams | None = None) -> dict[str, float]:
    """The distance (metres, NaN if none) every estimator of
    :data:`~ttc.steps.lidar_ttc.LIDAR_ESTIMATORS` picks on one box's points (N × ≥3, metres), with
    the other parameters of ``params`` (default :class:`~ttc.steps.lidar_ttc.LidarTTCParams`)."""
    params = params or LidarTTCParams()
    return {
        name: estimator_distance(points, dataclasses.replace(params, name=name)).distance
        for name in LIDAR_ESTIMATORS
    }


# --------------------------------------------------------------------------- summaries


def most_flagged_frames(t: pd.DataFrame, limit: int) -> pd.DataFrame:
    """The flagged (dataset, frame)s, most estimators flagged first, then the largest error,
    then frame order; at most ``limit``. Columns: dataset, frame, n, err."""
    flagged = t[t["flagged"]].assign(err=t["lidar_rel_err"].fillna(np.inf))
    per = flagged.groupby(["dataset", "frame"]).agg(n=("lidar_ttc", "size"), err=("err", "max"))
    per = per.reset_index().sort_values(["n", "err", "dataset", "frame"], ascending=[0, 0, 1, 1])
    return per.head(limit)


def lidar_wide(t: pd.DataFrame) -> pd.DataFrame:
    """Frame × estimator table of TTCs (s, text) beside the reference; flagged values marked
    '!'."""
    text = fmt(t["ttc_lidar"], ".2f") + np.where(t["flagged"], " !", "")
    wide = t.assign(v=text).pivot_table(
        index=["dataset", "frame"], columns="lidar_ttc", values="v", aggfunc="first"
    )
    ref = t.groupby(["dataset", "frame"])["ttc_ref_s"].first().map(lambda v: f"{v:.2f}")
    wide.insert(0, "reference", ref)
    return wide.reset_index()


def lidar_metrics(frames: pd.DataFrame, t: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """Per (dataset, estimator): lidar metrics of the run :func:`lidar_runs` chose and its
    number of flagged frames."""
    ids = t["run_id"].unique()
    m = run_metrics(rows_of_runs(frames, ids), reference)
    cols = ["dataset", "lidar_ttc", "lidar_invalid_rate", "lidar_mid_median",
            "lidar_mid_median_approach", "lidar_mid_median_stopping",
            "lidar_mid_median_stationary", "lidar_outlier_rate", "lidar_medae_rel",
            "lidar_false_alarm_rate", "lidar_warn_precision", "lidar_warn_recall",
            "lidar_jitter_s", "n_frames", "n_judged"]  # fmt: skip
    flags = t.groupby("run_id")["flagged"].sum().rename("flagged")
    out = m.merge(flags, on="run_id")[[*cols, "flagged"]]
    return out.sort_values(["dataset", "lidar_ttc"], ignore_index=True)
