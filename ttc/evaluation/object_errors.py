"""Judging every object: each box pair of a run against its object's reference.

A run's row (``frame``, ``prev_box`` → ``curr_box``) is judged against the reference of the
object its current box is (:func:`ttc.evaluation.object_reference.object_reference`, joined
on ``frame`` and box). ``box_match_ok`` says whether the run's FP.1 paired the same boxes as
the reference's linking; a wrong pairing is judged all the same (its TTC is what the run
reports for that object). Relative TTC error ``|TTC − TTC_ref| / TTC_ref`` on the pairs with a
judgeable reference; an invalid estimate is one that is not a finite positive number.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.stats import kendalltau

from ttc.evaluation.difficulty import worse_level
from ttc.evaluation.errors import estimated_ratio, mid_error, rows_where
from ttc.evaluation.ranking import in_row_chunks
from ttc.evaluation.ttc_bins import OBJECT_TTC_BIN_EDGES_S, OBJECT_TTC_BINS, ttc_bin

#: Sensors judged per object (their TTC columns are ``ttc_<sensor>``).
OBJECT_SENSORS: tuple[str, ...] = ("camera", "lidar")
#: Columns of the reference carried onto each judged row.
_REFERENCE = ["frame", "box", "track_id", "role", "distance_m", "closing_speed_mps",
              "ratio_ref", "ttc_ref_s", "ttc_ref_sd_s", "judgeable", "bearing_deg",
              "difficulty"]  # fmt: skip


def judge_objects(rows: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """One row per matched box pair of ``rows`` (``run_id``, ``frame``, ``prev_box``,
    ``curr_box``, ``box_w``, ``ttc_camera``, ``ttc_lidar``) whose current box has a reference
    row: the reference's columns (``ref_track_id``, ``role``, ``distance_m``, ``ttc_ref_s``,
    ``judgeable``, ``bearing_deg``), ``box_match_ok``, ``ttc_bin`` (the object ranges
    :data:`ttc.evaluation.ttc_bins.OBJECT_TTC_BINS`), and per sensor ``{s}_rel_err`` (NaN
    unless judgeable and valid), ``{s}_invalid``, ``{s}_mid`` (the motion-in-depth error
    against the object's distance ratio, 10⁻⁴, as the lead's) and ``{s}_score`` (the relative error capped
    at 1, an invalid estimate 1: bounded, so a setting invalid on half the pairs is not tied
    with every other one at +inf; the all-object ranking takes its mean). With the reference's
    per-box ``difficulty`` (:mod:`ttc.evaluation.difficulty`), ``difficulty`` is the pair's:
    the worse level of its previous and its current box."""
    matched = ((rows["prev_box"] >= 0) & (rows["curr_box"] >= 0)).to_numpy(dtype=bool)
    pairs = rows_where(rows, matched)  # a report's are all matched pairs: not copied whole
    ref = reference[[c for c in _REFERENCE if c in reference]].rename(
        columns={"box": "curr_box", "track_id": "ref_track_id"}
    )
    out = pairs.merge(ref, on=["frame", "curr_box"], how="inner", validate="many_to_one")
    before = reference.set_index(["track_id", "frame"])["box"]
    key = pd.MultiIndex.from_arrays([out["ref_track_id"], out["prev_frame"]])
    out["box_match_ok"] = before.reindex(key).to_numpy() == out["prev_box"].to_numpy()
    if "difficulty" in out:
        level = reference.set_index(["frame", "box"])["difficulty"]
        prev = level.reindex(pd.MultiIndex.from_arrays([out["prev_frame"], out["prev_box"]]))
        out["difficulty"] = worse_level(prev.to_numpy(), out["difficulty"].to_numpy())
    out["ttc_bin"] = ttc_bin(out["ttc_ref_s"], OBJECT_TTC_BIN_EDGES_S, OBJECT_TTC_BINS)
    judged = out["judgeable"].astype(bool) & (out["ttc_bin"] != "")
    for s in OBJECT_SENSORS:
        ttc = out[f"ttc_{s}"].to_numpy(dtype=float)
        invalid = ~(np.isfinite(ttc) & (ttc > 0))
        with np.errstate(invalid="ignore", divide="ignore"):
            rel = np.abs(ttc - out["ttc_ref_s"].to_numpy(dtype=float)) / out["ttc_ref_s"]
        out[f"{s}_invalid"] = invalid
        out[f"{s}_mid"] = mid_error(estimated_ratio(out, s), out["ratio_ref"])
        out[f"{s}_rel_err"] = np.where(judged & ~invalid, rel, np.nan)
        capped = np.where(invalid, 1.0, np.minimum(rel, 1.0))
        out[f"{s}_score"] = np.where(judged, capped, np.nan)
    out["judged"] = judged
    return out


def _judged_pairs(judged: pd.DataFrame, columns: list[str]) -> pd.DataFrame:
    """The judged pairs of :func:`judge_objects`' table on ``columns`` only (no copy of the
    others: ``grand``'s table holds 0.6 M pairs on some 40 columns)."""
    return judged.loc[judged["judged"].to_numpy(dtype=bool), list(dict.fromkeys(columns))]


def object_metrics(judged: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """Per group of ``by`` (e.g. ``["run_id", "role", "ttc_bin"]``) over the judged pairs of
    :func:`judge_objects`: ``n_pairs``, ``n_tracks`` and per sensor ``{s}_medae_rel`` (median
    relative error of the valid estimates), ``{s}_invalid_rate`` (0–1) and ``{s}_score`` (the
    mean capped error, an invalid estimate 1: the ranking key, 0–1, lower is better) and
    ``{s}_mid_median`` (10⁻⁴)."""
    measured = [f"{s}_{m}" for s in OBJECT_SENSORS for m in ("rel_err", "invalid", "score", "mid")]
    t = _judged_pairs(judged, [*by, "ref_track_id", *measured])
    g = t.groupby(by, observed=True)
    out = pd.DataFrame({"n_pairs": g.size(), "n_tracks": g["ref_track_id"].nunique()})
    for s in OBJECT_SENSORS:
        out[f"{s}_medae_rel"] = g[f"{s}_rel_err"].median()
        out[f"{s}_invalid_rate"] = g[f"{s}_invalid"].mean()
        out[f"{s}_score"] = g[f"{s}_score"].mean()
        out[f"{s}_mid_median"] = g[f"{s}_mid"].median()
    return out.reset_index()


def ranking_agreement(a: pd.Series, b: pd.Series) -> float:
    """Kendall's τ between two scores of the same settings (indexed by setting; lower is
    better), over the settings both score; NaN with fewer than three."""
    both = pd.concat([a, b], axis=1, join="inner").dropna()
    if len(both) < 3:
        return float("nan")
    return float(kendalltau(both.iloc[:, 0], both.iloc[:, 1]).statistic)


#: Edges of the breakdown tables (:func:`breakdown`): distance (m), box width (px), bearing
#: (degrees off the forward axis, absolute).
BREAKDOWN_EDGES: dict[str, tuple[float, ...]] = {
    "distance_m": (0.0, 5.0, 10.0, 20.0, 40.0, np.inf),
    "box_w": (0.0, 25.0, 50.0, 100.0, 200.0, np.inf),
    "bearing_deg": (0.0, 5.0, 10.0, 20.0, 45.0),
}


def breakdown(judged: pd.DataFrame, sensor: str = "camera") -> pd.DataFrame:
    """Where an estimate breaks down: per quantity (``distance_m``, ``box_w``,
    ``bearing_deg``, ``ttc_bin``) and range, ``n_pairs``, the median relative error and the
    invalid rate of ``sensor`` over the judged pairs of every run."""
    t = _judged_pairs(judged, [*BREAKDOWN_EDGES, "ttc_bin", "camera_rel_err", "camera_invalid"])
    t["bearing_deg"] = t["bearing_deg"].abs()
    parts = []
    for quantity, edges in BREAKDOWN_EDGES.items():
        parts.append(_summary(t, pd.cut(t[quantity], list(edges), right=False), quantity))
    ranges = pd.Categorical(t["ttc_bin"], categories=OBJECT_TTC_BINS, ordered=True)
    parts.append(_summary(t, pd.Series(ranges, index=t.index), "ttc_bin"))
    return pd.concat(parts, ignore_index=True)


def _summary(t: pd.DataFrame, key: pd.Series, quantity: str, sensor: str = "camera"):
    """One row per range of ``key`` (a categorical, in its order; empty ranges left out)."""
    g = t.groupby(key, observed=True, sort=True)
    out = pd.DataFrame({"n_pairs": g.size(), "medae_rel": g[f"{sensor}_rel_err"].median(),
                        "invalid_rate": g[f"{sensor}_invalid"].mean()})  # fmt: skip
    out.index = out.index.astype(str)
    out.index.name = "range"
    return out.reset_index().assign(quantity=quantity)[
        ["quantity", "range", "n_pairs", "medae_rel", "invalid_rate"]
    ]


#: Replicates, confidence level and seed of the all-object rank intervals.
N_BOOT = 500
CI = 0.9
SEED = 0


def min_ranks(scores: np.ndarray) -> np.ndarray:
    """(r, n) float: each row's ranks of ``scores`` (r, n), 1 for the least, ties given their
    least rank: ``pd.DataFrame(scores).rank(axis=1, method="min")`` (NaN: NaN; it sorts last,
    after every value it would otherwise share a rank with), by one sort of every row (500
    rows of 6,720 settings: 0.28 s against pandas' 0.43 s), a few rows at a time
    (:func:`~ttc.evaluation.ranking.in_row_chunks`)."""
    return in_row_chunks(_min_ranks, scores)


def _min_ranks(scores: np.ndarray) -> np.ndarray:
    """:func:`min_ranks` of some rows at once."""
    order = np.argsort(scores, axis=1, kind="stable")
    ordered = np.take_along_axis(scores, order, axis=1)
    position = np.broadcast_to(np.arange(scores.shape[1]), scores.shape)
    first = np.ones(scores.shape, dtype=bool)
    first[:, 1:] = ordered[:, 1:] != ordered[:, :-1]  # a new value: its first place
    least = np.maximum.accumulate(np.where(first, position, 0), axis=1)
    out = np.empty(scores.shape, dtype=float)
    np.put_along_axis(out, order, least + 1.0, axis=1)
    out[np.isnan(scores)] = np.nan
    return out


def track_bootstrap_ranks(
    judged: pd.DataFrame,
    sensor: str = "camera",
    n_boot: int = N_BOOT,
    seed: int = SEED,
    role: str | None = None,
) -> pd.DataFrame:
    """The all-object ranking of the settings (``setting`` column of :func:`judge_objects`'s
    judged pairs) by the mean ``{sensor}_score``, with rank intervals from a bootstrap whose
    blocks are tracks (``ref_track_id``): a replicate draws as many tracks as there are, with
    replacement, and keeps every judged pair of each (errors along one track are correlated).
    Columns: ``setting``, ``score``, ``rank`` (1: best), ``rank_lo``, ``rank_hi``
    (:data:`CI` interval), ``n_pairs``. ``role`` (e.g. ``"lead"``): the pairs of that role
    only."""
    by_role = [] if role is None else ["role"]
    t = _judged_pairs(judged, ["setting", "ref_track_id", *by_role, f"{sensor}_score"])
    if role is not None:
        t = t[t["role"].eq(role).to_numpy(dtype=bool)]
    tracks = np.sort(t["ref_track_id"].unique())
    settings = sorted(t["setting"].unique())
    if not len(tracks) or not settings:
        return pd.DataFrame(columns=["setting", "score", "rank", "rank_lo", "rank_hi", "n_pairs"])
    rng = np.random.default_rng(seed)
    counts = np.stack([np.bincount(rng.integers(0, len(tracks), len(tracks)),
                                   minlength=len(tracks)) for _ in range(n_boot)])  # fmt: skip
    scores = np.full((n_boot, len(settings)), np.inf)
    point = np.full(len(settings), np.inf)
    n_pairs = np.zeros(len(settings), dtype=np.int64)
    # each setting's pairs in the table's order (as a stable group-by gives them)
    code = pd.factorize(t["setting"], sort=True)[0]
    order = np.argsort(code, kind="stable")
    ends = np.cumsum(np.bincount(code, minlength=len(settings)))
    all_values = t[f"{sensor}_score"].to_numpy(dtype=float)[order]
    all_tracks = np.searchsorted(tracks, t["ref_track_id"].to_numpy()[order])
    for j, (start, end) in enumerate(zip(np.r_[0, ends[:-1]], ends, strict=True)):
        values = all_values[start:end]
        weight = counts[:, all_tracks[start:end]]
        n_pairs[j] = len(values)
        point[j] = values.mean()
        total = weight.sum(axis=1)  # (n_boot,): pairs of this setting in each replicate
        drawn = total > 0
        scores[drawn, j] = (weight @ values)[drawn] / total[drawn]
    ranks = min_ranks(scores)
    lo, hi = np.quantile(ranks, [(1 - CI) / 2, (1 + CI) / 2], axis=0)
    out = pd.DataFrame({"setting": settings, "score": point, "n_pairs": n_pairs,
                        "rank": pd.Series(point).rank(method="min").to_numpy(),
                        "rank_lo": lo, "rank_hi": hi})  # fmt: skip
    return out.sort_values(["rank", "setting"], ignore_index=True)


def track_table(judged: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """Per judged track (``ref_track_id``): ``role``, ``class``, its frames, the reference
    distance range (m), the pairs judged (each setting's), the median relative camera TTC error
    and motion-in-depth error (10⁻⁴) over every setting, and the invalid rate; nearest first."""
    t = _judged_pairs(judged, ["ref_track_id", "camera_rel_err", "camera_mid", "camera_invalid"])
    if t.empty:
        return pd.DataFrame()
    ref = reference.groupby("track_id").agg(
        role=("role", "first"), cls=("class", "first"), first=("frame", "min"),
        last=("frame", "max"), d_min=("distance_m", "min"), d_max=("distance_m", "max"),
    )  # fmt: skip
    g = t.groupby("ref_track_id")
    out = pd.DataFrame({"pairs": g.size(), "camera_medae_rel": g["camera_rel_err"].median(),
                        "camera_mid_median": g["camera_mid"].median(),
                        "camera_invalid_rate": g["camera_invalid"].mean()})  # fmt: skip
    out = ref.join(out, how="inner").rename(columns={"cls": "class"})
    out.index.name = "track_id"
    return out.sort_values("d_min").reset_index()
