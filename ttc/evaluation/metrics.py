"""Metrics per setting against the reference TTC, the ranking, bootstrap intervals, comparison.

Input is a sweep's ``frames`` table (one row per run × frame pair × box pair, see
``experiments/schema.py``) and a reference from :func:`ttc.reference.reference_ttc` (one row
per frame). Only the lead vehicle's row of each frame pair is judged; a frame pair of a run
without a lead row (no box held lane points) counts as an invalid TTC of both sensors.

Per-frame quantities, for sensor ``s`` in :data:`SENSORS` and the reference ``ref``:

- relative error ``|ttc − ref| / ref`` where ``ref`` and ``ttc`` are both finite;
- outlier: where ``ref`` is finite, the TTC is invalid (NaN, ±inf or ≤ 0) or its relative
  error exceeds ``outlier_rel``;
- false alarm: where ``ref`` is +inf (no collision course), a finite TTC in
  ``(0, false_alarm_s)``;
- time: ``ms_per_frame`` is the sum of the lead row's ``ms_*`` stage times (ms). Stages that
  came from the stage cache count their cache-load time, so it is the time this run took,
  which depends on what ran before it. ``ms_compute_per_frame`` replaces a cached stage's time
  by the median time of the same stage computed (not cached) on the same frame by any run of
  the table with the same stage inputs (:data:`CACHED_STAGE_INPUTS`); NaN when no run of the
  table computed it.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
import pandas as pd

from ttc.pipeline import AXES

SENSORS: tuple[str, ...] = ("camera", "lidar")
#: Relative error above which a TTC is an outlier.
OUTLIER_REL = 0.3
#: A finite TTC below this (s) where the reference says "no collision course" is a false
#: alarm. 10 s: while the cars of the KITTI sequence close, the reference is 6–15 s, so an
#: estimate under 10 s where they stand claims an approach as urgent as the real one.
FALSE_ALARM_S = 10.0

#: Cached stage → (time column, cache flag column, axes its cache key depends on besides the
#: frame). The lidar stage (scan load + lane crop) costs the same for every setting.
CACHED_STAGE_INPUTS: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "objects": ("ms_objects", "cached_objects", ("objects",)),
    "lidar": ("ms_lidar", "cached_lidar", ()),
    "keypoints": ("ms_keypoints", "cached_keypoints", ("detector",)),
    "descriptors": ("ms_descriptors", "cached_descriptors", ("detector", "descriptor")),
    "matches": ("ms_matching", "cached_matches", ("detector", "descriptor", "matcher")),
}

RANKING_RULE = (
    "Settings are ranked on one sensor's TTC by, in order: "
    "(1) outlier rate, lower first: the share of frames with a finite reference TTC where the "
    "TTC is invalid (NaN, +/-inf, <= 0) or more than outlier_rel (30 %) off the reference; "
    "(2) median absolute relative error over the frames where TTC and reference are finite, "
    "lower first; (3) mean computing time per frame (ms_compute_per_frame: cached stages at "
    "the time they took to compute, so the order in which runs filled the cache does not "
    "matter; ms_per_frame where unknown), lower first; (4) run_id, so that the order is "
    "deterministic for given times. A missing value (NaN) sorts last within its key. Ranks "
    "are 1..n without ties. Settings with identical TTC series are ordered by measured time, "
    "which varies from machine to machine and run to run."
)


def _ms_columns(frames: pd.DataFrame) -> list[str]:
    return [c for c in frames.columns if c.startswith("ms_")]


def lead_rows(frames: pd.DataFrame) -> pd.DataFrame:
    """One row per (run_id, frame): the lead row, else the pair's first row with NaN TTCs."""
    order = frames.sort_values(
        ["run_id", "frame", "is_lead"], ascending=[True, True, False], kind="stable"
    )
    lead = order.drop_duplicates(["run_id", "frame"]).reset_index(drop=True)
    ttc_cols = [f"ttc_{s}" for s in SENSORS if f"ttc_{s}" in lead]
    lead.loc[~lead["is_lead"].astype(bool), ttc_cols] = np.nan
    return lead


def attach_reference(
    frames: pd.DataFrame, reference: pd.DataFrame, lead_only: bool = True
) -> pd.DataFrame:
    """``frames`` with the reference's ``ttc_ref_s`` (s) and ``collision_course`` joined on
    ``frame``; by default only the lead rows (:func:`lead_rows`). Frames the reference does not
    cover get NaN and ``collision_course`` False."""
    table = lead_rows(frames) if lead_only else frames
    table = table.drop(columns=["ttc_ref_s", "collision_course"], errors="ignore")
    ref = reference[["frame", "ttc_ref_s", "collision_course"]]
    out = table.merge(ref, on="frame", how="left", validate="many_to_one")
    out["collision_course"] = out["collision_course"].fillna(False).astype(bool)
    return out


def _compute_times(lead: pd.DataFrame) -> pd.Series:
    """Per-row ``ms_per_frame`` with cached stages' times replaced by computed ones (ms): the
    median computing time of the same stage inputs on the same frame, else on any frame."""
    if "ms_compute_per_frame" in lead:  # looked up beforehand (:func:`with_compute_times`)
        return lead["ms_compute_per_frame"]
    total = lead[_ms_columns(lead)].sum(axis=1)
    for ms, flag, inputs in CACHED_STAGE_INPUTS.values():
        if ms not in lead or flag not in lead:
            continue
        cached = lead[flag].astype(bool)
        own = lead[ms].where(~cached)
        stage = [lead[c] for c in inputs if c in lead]
        same_frame = own.groupby([*stage, lead["frame"]]).transform("median")
        any_frame = own.groupby(stage).transform("median") if stage else own.median()
        computed = same_frame.fillna(any_frame)
        total = total + (computed - lead[ms]).where(cached, 0.0)
    return total


def with_compute_times(frames: pd.DataFrame) -> pd.DataFrame:
    """``frames`` with ``ms_compute_per_frame`` per row, the cached stages' computing times
    looked up over every row of ``frames``. Call it on the union of sweeps before judging a
    subset of runs, so a stage computed by a run outside the subset still has its time."""
    return frames.assign(ms_compute_per_frame=_compute_times(frames))


def frame_errors(
    lead: pd.DataFrame, outlier_rel: float = OUTLIER_REL, false_alarm_s: float = FALSE_ALARM_S
) -> pd.DataFrame:
    """Per lead row: ``{s}_rel_err``, ``{s}_outlier``, ``{s}_false_alarm`` (1.0/0.0, NaN where
    not applicable), ``{s}_invalid`` (bool), ``ms_per_frame`` and ``ms_compute_per_frame``.

    ``lead`` comes from :func:`attach_reference`.
    """
    out = lead.copy()
    ref = out["ttc_ref_s"].to_numpy(dtype=float)
    ref_finite = np.isfinite(ref) & (ref > 0)
    no_course = np.isposinf(ref)
    for s in SENSORS:
        ttc = out[f"ttc_{s}"].to_numpy(dtype=float)
        finite = np.isfinite(ttc)
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.abs(ttc - ref) / ref
        rel = np.where(ref_finite & finite, rel, np.nan)
        outlier = ~(finite & (ttc > 0)) | (rel > outlier_rel)
        alarm = finite & (ttc > 0) & (ttc < false_alarm_s)
        out[f"{s}_rel_err"] = rel
        out[f"{s}_outlier"] = np.where(ref_finite, outlier, np.nan)
        out[f"{s}_false_alarm"] = np.where(no_course, alarm, np.nan)
        out[f"{s}_invalid"] = ~finite
    out["ms_per_frame"] = out[_ms_columns(lead)].sum(axis=1)
    out["ms_compute_per_frame"] = _compute_times(lead)
    return out


def _jitter(per_frame: pd.DataFrame, sensor: str) -> pd.Series:
    """Median |change| (s) between consecutive finite TTCs of each run (frame order)."""
    col = f"ttc_{sensor}"
    finite = per_frame.loc[np.isfinite(per_frame[col]), ["run_id", "frame", col]]
    finite = finite.sort_values(["run_id", "frame"])
    change = finite.groupby("run_id")[col].diff().abs()
    return change.groupby(finite["run_id"]).median()


def run_metrics(
    frames: pd.DataFrame,
    reference: pd.DataFrame,
    outlier_rel: float = OUTLIER_REL,
    false_alarm_s: float = FALSE_ALARM_S,
) -> pd.DataFrame:
    """One row per ``run_id``: its axis columns and, per sensor ``s``, ``{s}_medae_rel``,
    ``{s}_meanae_rel``, ``{s}_outlier_rate``, ``{s}_false_alarm_rate`` (NaN: no frame without a
    collision course), ``{s}_jitter_s`` (s), ``{s}_invalid`` (count of non-finite TTCs);
    ``n_frames``, ``ms_per_frame``, ``ms_compute_per_frame`` and ``{ms_stage}_mean`` (ms).

    Definitions in the module docstring; ``outlier_rel`` is a fraction of the reference,
    ``false_alarm_s`` seconds.
    """
    per_frame = frame_errors(attach_reference(frames, reference), outlier_rel, false_alarm_s)
    aggs: dict[str, tuple[str, str]] = {}
    for s in SENSORS:
        aggs[f"{s}_medae_rel"] = (f"{s}_rel_err", "median")
        aggs[f"{s}_meanae_rel"] = (f"{s}_rel_err", "mean")
        aggs[f"{s}_outlier_rate"] = (f"{s}_outlier", "mean")
        aggs[f"{s}_false_alarm_rate"] = (f"{s}_false_alarm", "mean")
        aggs[f"{s}_invalid"] = (f"{s}_invalid", "sum")
    aggs["n_frames"] = ("frame", "size")
    aggs["ms_per_frame"] = ("ms_per_frame", "mean")
    aggs["ms_compute_per_frame"] = ("ms_compute_per_frame", "mean")
    aggs |= {f"{c}_mean": (c, "mean") for c in _ms_columns(frames)}
    grouped = per_frame.groupby("run_id", sort=True)
    metrics = grouped.agg(**aggs)
    unknown = per_frame["ms_compute_per_frame"].isna().groupby(per_frame["run_id"]).any()
    metrics.loc[unknown, "ms_compute_per_frame"] = np.nan
    for s in SENSORS:
        metrics.insert(
            metrics.columns.get_loc(f"{s}_invalid"), f"{s}_jitter_s", _jitter(per_frame, s)
        )
    axes = grouped[[a for a in AXES if a in per_frame]].first()
    return axes.join(metrics).reset_index()


def _ranks(outlier: np.ndarray, medae: np.ndarray, ms: np.ndarray) -> np.ndarray:
    """Ranks (1..n, last axis) by :data:`RANKING_RULE`; inputs (..., n) in run_id order."""
    keys = [np.where(np.isnan(k), np.inf, k) for k in (outlier, medae, ms)]
    position = np.broadcast_to(np.arange(outlier.shape[-1]), outlier.shape)
    order = np.lexsort((position, keys[2], keys[1], keys[0]), axis=-1)
    ranks = np.empty(order.shape, dtype=np.int64)
    np.put_along_axis(ranks, order, position + 1, axis=-1)
    return ranks


def ranking_time(table: pd.DataFrame) -> pd.Series:
    """The time key of :data:`RANKING_RULE` (ms per frame): ``ms_compute_per_frame`` where
    known, else ``ms_per_frame``; works on run-level and frame-level tables."""
    if "ms_compute_per_frame" not in table:
        return table["ms_per_frame"]
    return table["ms_compute_per_frame"].fillna(table["ms_per_frame"])


def rank_runs(metrics: pd.DataFrame, sensor: str = "camera") -> pd.DataFrame:
    """``metrics`` with a ``rank`` column (1 = best) by :data:`RANKING_RULE`, sorted by it."""
    table = metrics.sort_values("run_id", kind="stable").reset_index(drop=True)
    table["rank"] = _ranks(
        table[f"{sensor}_outlier_rate"].to_numpy(dtype=float),
        table[f"{sensor}_medae_rel"].to_numpy(dtype=float),
        ranking_time(table).to_numpy(dtype=float),
    )
    return table.sort_values("rank", ignore_index=True)


def _nanmedian_last(values: np.ndarray) -> np.ndarray:
    """Median over the last axis ignoring NaN (NaN when all are NaN), via one sort."""
    ordered = np.sort(values, axis=-1)  # NaN last
    n = np.count_nonzero(~np.isnan(values), axis=-1)
    lo = np.take_along_axis(ordered, np.maximum((n - 1) // 2, 0)[..., None], axis=-1)[..., 0]
    hi = np.take_along_axis(ordered, (n // 2)[..., None], axis=-1)[..., 0]
    return np.where(n > 0, (lo + hi) / 2, np.nan)


def _weighted_mean(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Mean of ``values`` (runs × frames, NaN: not applicable) under per-replicate frame
    ``weights`` (replicates × frames): replicates × runs, NaN where no weight applies."""
    present = ~np.isnan(values)
    total = weights @ np.where(present, values, 0.0).T
    count = weights @ present.T.astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(count > 0, total / count, np.nan)


def bootstrap_rank_intervals(
    frames: pd.DataFrame,
    reference: pd.DataFrame,
    n_boot: int = 500,
    seed: int = 0,
    sensor: str = "camera",
    ci: float = 0.9,
    outlier_rel: float = OUTLIER_REL,
    false_alarm_s: float = FALSE_ALARM_S,
) -> pd.DataFrame:
    """Paired bootstrap over frames of each run's rank and ranking metrics.

    Each replicate draws the frame set with replacement once and applies it to every run
    (the runs are judged on the same frames, so their correlation is kept); the outlier rate,
    median relative error, time per frame and rank (:data:`RANKING_RULE`) are recomputed
    from run × frame matrices built once. Returns per ``run_id``: the point ``rank``,
    ``rank_lo`` / ``rank_hi`` (the ``ci`` percentile interval, lower / higher order
    statistic), ``rank_median``, and the same interval of ``{sensor}_outlier_rate`` and
    ``{sensor}_medae_rel`` (``_lo`` / ``_hi``). Deterministic for a ``seed``.
    """
    per_frame = frame_errors(attach_reference(frames, reference), outlier_rel, false_alarm_s)
    per_frame["ms_rank"] = ranking_time(per_frame)

    def matrix(col: str) -> np.ndarray:
        return per_frame.pivot(index="run_id", columns="frame", values=col).to_numpy(float)

    runs = np.sort(per_frame["run_id"].unique())
    errors, outliers, ms = (
        matrix(f"{sensor}_rel_err"),
        matrix(f"{sensor}_outlier"),
        matrix("ms_rank"),
    )
    n_frames = errors.shape[1]
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, n_frames, size=(n_boot, n_frames))
    weights = np.zeros((n_boot, n_frames))
    np.add.at(weights, (np.arange(n_boot)[:, None], draws), 1.0)

    outlier_rate = _weighted_mean(outliers, weights)  # replicates × runs
    mean_ms = _weighted_mean(ms, weights)
    medae = _nanmedian_last(errors[:, draws]).T  # (runs, replicates, frames) → replicates × runs
    ranks = _ranks(outlier_rate, medae, mean_ms)

    q = [(1.0 - ci) / 2.0, 1.0 - (1.0 - ci) / 2.0]
    point = rank_runs(run_metrics(frames, reference, outlier_rel, false_alarm_s), sensor)
    out = pd.DataFrame({"run_id": runs})
    out = out.merge(point[["run_id", "rank"]], on="run_id", how="left")
    out["rank_lo"] = np.quantile(ranks, q[0], axis=0, method="lower")
    out["rank_hi"] = np.quantile(ranks, q[1], axis=0, method="higher")
    out["rank_median"] = np.median(ranks, axis=0)
    for name, values in (("outlier_rate", outlier_rate), ("medae_rel", medae)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN runs give NaN
            out[f"{sensor}_{name}_lo"] = np.nanquantile(values, q[0], axis=0, method="lower")
            out[f"{sensor}_{name}_hi"] = np.nanquantile(values, q[1], axis=0, method="higher")
    return out


#: Metrics whose change ``b − a`` :func:`compare_runs` reports (per sensor, then overall).
COMPARED_METRICS = ("outlier_rate", "medae_rel", "meanae_rel", "false_alarm_rate", "jitter_s")


def compare_runs(
    metrics_a: pd.DataFrame,
    metrics_b: pd.DataFrame,
    intervals_a: pd.DataFrame,
    intervals_b: pd.DataFrame,
    key: Sequence[str] | None = None,
    sensor: str = "camera",
) -> pd.DataFrame:
    """Settings present in both tables (joined on ``key``, default: the shared axis columns)
    with each metric's change ``b − a``, both ranks and a ``verdict``.

    The verdict follows :data:`RANKING_RULE` on *metric* intervals from
    :func:`bootstrap_rank_intervals` (ranks of two sweeps are relative to different sets of
    runs, so a setting's rank moves when others change): ``better`` when b's outlier-rate
    interval lies entirely below a's, ``worse`` when entirely above; when they overlap, the
    same test on the median relative error; ``same`` otherwise.
    """
    if key is None:
        key = [a for a in AXES if a in metrics_a and a in metrics_b]
    key = list(key)
    a = metrics_a.drop(columns="rank", errors="ignore").merge(intervals_a, on="run_id")
    b = metrics_b.drop(columns="rank", errors="ignore").merge(intervals_b, on="run_id")
    both = a.merge(b, on=key, suffixes=("_a", "_b"), validate="one_to_one")
    out = both[key + ["run_id_a", "run_id_b", "rank_a", "rank_b"]].copy()
    changed = [f"{sensor}_{m}" for m in COMPARED_METRICS] + ["ms_per_frame"]
    for col in changed:
        out[f"{col}_a"] = both[f"{col}_a"]
        out[f"{col}_b"] = both[f"{col}_b"]
        out[f"{col}_change"] = both[f"{col}_b"] - both[f"{col}_a"]

    def beyond(name: str) -> tuple[np.ndarray, np.ndarray]:
        lo_a, hi_a = both[f"{sensor}_{name}_lo_a"], both[f"{sensor}_{name}_hi_a"]
        lo_b, hi_b = both[f"{sensor}_{name}_lo_b"], both[f"{sensor}_{name}_hi_b"]
        return (hi_b < lo_a).to_numpy(), (lo_b > hi_a).to_numpy()

    out_better, out_worse = beyond("outlier_rate")
    err_better, err_worse = beyond("medae_rel")
    out["verdict"] = np.select(
        [out_better, out_worse, err_better, err_worse],
        ["better", "worse", "better", "worse"],
        default="same",
    )
    return out.reset_index(drop=True)
