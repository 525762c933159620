"""Per-run metrics: the per-frame errors of :mod:`ttc.evaluation.errors` aggregated over the
frames of each run, per sensor and per regime.

Per run and sensor ``s`` (columns of ``metrics.parquet`` and ``fp6_ranking.csv``):

- ``{s}_mid_median``, ``{s}_mid_mean``: motion-in-depth error over every frame with a valid
  estimate; ``{s}_mid_median_<regime>`` for each regime of
  :data:`ttc.evaluation.reference.REGIMES` (NaN where the run has no valid frame of it);
- ``{s}_invalid`` (count) and ``{s}_invalid_rate`` (share of frames without an estimate);
- ``{s}_medae_rel``, ``{s}_meanae_rel``: median / mean relative TTC error over the judgeable
  frames of the ``approach`` regime;
- ``{s}_outlier_rate``: share of the judgeable frames whose TTC is invalid or an outlier;
- ``{s}_false_alarm_rate``: share of the no-collision-course frames with a false alarm;
- ``{s}_warn_precision``, ``{s}_warn_recall``: collision warning "TTC below τ" against the
  reference's (NaN when the estimate, resp. the reference, never warns);
- ``{s}_jitter_s``: median |change| (s) between consecutive finite TTCs;

and ``n_frames``, ``n_judged`` (frames with a judgeable reference TTC), ``n_uncertain``
(frames with a finite reference TTC too uncertain to judge), ``ms_per_frame``,
``ms_compute_per_frame`` and ``{ms_stage}_mean`` (ms).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ttc.evaluation.errors import (
    FALSE_ALARM_S,
    NOT_JUDGED_COLUMNS,
    OUTLIER_REL,
    WARNING_TTC_S,
    attach_reference,
    frame_errors,
    sensors_of,
)
from ttc.evaluation.reference import REGIMES
from ttc.evaluation.stage_times import stage_time_columns
from ttc.settings import AXES


def judged_frames(
    frames: pd.DataFrame,
    reference: pd.DataFrame,
    outlier_rel: float = OUTLIER_REL,
    false_alarm_s: float = FALSE_ALARM_S,
    warning_s: float = WARNING_TTC_S,
) -> pd.DataFrame:
    """One row per run × frame pair: the lead row with the reference and every per-frame
    error (:func:`ttc.evaluation.errors.frame_errors`)."""
    lead = attach_reference(frames, reference)
    return frame_errors(lead, outlier_rel, false_alarm_s, warning_s)


def _jitter(per_frame: pd.DataFrame, sensor: str, runs: pd.Series) -> pd.Series:
    """Median |change| (s) between consecutive finite TTCs of each run (frame order), by
    ``runs`` (each row's run code, :func:`_run_codes`)."""
    col = f"ttc_{sensor}"
    finite = per_frame.loc[np.isfinite(per_frame[col]), ["frame", col]].assign(run=runs)
    finite = finite.sort_values(["run", "frame"])
    change = finite.groupby("run")[col].diff().abs()
    return change.groupby(finite["run"]).median()


def _share(hit: pd.Series, among: pd.Series, runs: pd.Series) -> pd.Series:
    """Per run: share of the ``among`` rows where ``hit`` (NaN when there are none)."""
    counts = pd.DataFrame({"hit": hit & among, "among": among}).groupby(runs).sum()
    return (counts["hit"] / counts["among"].where(counts["among"] > 0)).astype(float)


def _sensor_metrics(t: pd.DataFrame, s: str, runs: pd.Series) -> pd.DataFrame:
    """The metrics of sensor ``s`` (module docstring), one row per run of ``t`` (by ``runs``,
    each row's run code)."""
    mid = t[f"{s}_mid"]
    approach = t["regime"] == "approach"
    out = pd.DataFrame(
        {
            f"{s}_mid_median": mid.groupby(runs).median(),
            f"{s}_mid_mean": mid.groupby(runs).mean(),
            **{
                f"{s}_mid_median_{r}": mid.where(t["regime"] == r).groupby(runs).median()
                for r in REGIMES
            },
            f"{s}_invalid": t[f"{s}_invalid"].groupby(runs).sum(),
            f"{s}_invalid_rate": t[f"{s}_invalid"].astype(float).groupby(runs).mean(),
            f"{s}_medae_rel": t[f"{s}_rel_err"].where(approach).groupby(runs).median(),
            f"{s}_meanae_rel": t[f"{s}_rel_err"].where(approach).groupby(runs).mean(),
            f"{s}_outlier_rate": t[f"{s}_outlier"].groupby(runs).mean(),
            f"{s}_false_alarm_rate": t[f"{s}_false_alarm"].groupby(runs).mean(),
            f"{s}_warn_precision": _share(t["ref_warns"], t[f"{s}_warns"], runs),
            f"{s}_warn_recall": _share(t[f"{s}_warns"], t["ref_warns"], runs),
        }
    )
    out[f"{s}_jitter_s"] = _jitter(t, s, runs)
    return out


def _run_codes(run_ids: pd.Series) -> tuple[pd.Series, pd.Index]:
    """(each row's run as an integer code, ``run_ids``' index; the run id of each code,
    sorted). The metrics group by the codes: grouping by the ids themselves factorises the
    strings again for each of ≈ 115 aggregations (0.77 s on ``grand`` 0–18's 604,800 lead
    rows); codes sorted as the ids keep every group in the order it had."""
    codes, uniques = pd.factorize(run_ids, sort=True)
    return pd.Series(codes, index=run_ids.index, name="run"), pd.Index(uniques, name="run_id")


def _named(table: pd.DataFrame, run_ids: pd.Index) -> pd.DataFrame:
    """``table`` (indexed by run code) indexed by run id."""
    return table.set_axis(run_ids.take(table.index.to_numpy()), axis=0)


def unread_columns(frames: pd.DataFrame) -> list[str]:
    """The columns of ``frames`` that judging them does not read, left out of the copies it
    makes: :data:`~ttc.evaluation.errors.NOT_JUDGED_COLUMNS`, and the axis columns (12
    strings a row: 0.1 GB a copy of ``grand``'s judged rows) once ``ms_compute_per_frame`` is
    known (without it the computing times are looked up by the stage axes,
    :func:`ttc.evaluation.stage_times.compute_times`)."""
    axes = [a for a in AXES if a in frames] if "ms_compute_per_frame" in frames else []
    return [*(c for c in NOT_JUDGED_COLUMNS if c in frames), *axes]


def run_metrics(
    frames: pd.DataFrame,
    reference: pd.DataFrame,
    outlier_rel: float = OUTLIER_REL,
    false_alarm_s: float = FALSE_ALARM_S,
    warning_s: float = WARNING_TTC_S,
) -> pd.DataFrame:
    """One row per ``run_id``: its axis columns and the metrics of the module docstring.

    ``outlier_rel`` is a fraction of the reference, ``false_alarm_s`` and ``warning_s``
    seconds.
    """
    axis_columns = [a for a in AXES if a in frames]  # a run's axes: taken from its rows
    t = judged_frames(frames.drop(columns=unread_columns(frames)), reference, outlier_rel,
                      false_alarm_s, warning_s)  # fmt: skip
    runs, run_ids = _run_codes(t["run_id"])
    parts = [_sensor_metrics(t, s, runs) for s in sensors_of(t)]
    finite_ref = np.isfinite(t["ttc_ref_s"]) & (t["ttc_ref_s"] > 0)
    totals = pd.DataFrame(
        {
            "n_frames": runs.groupby(runs).size(),
            "n_judged": t["judgeable"].groupby(runs).sum(),
            "n_uncertain": (finite_ref & ~t["judgeable"]).groupby(runs).sum(),
            "ms_per_frame": t["ms_per_frame"].groupby(runs).mean(),
            "ms_compute_per_frame": t["ms_compute_per_frame"].groupby(runs).mean(),
        }
    ).join(t[stage_time_columns(frames)].groupby(runs).mean().add_suffix("_mean"))
    unknown = t["ms_compute_per_frame"].isna().groupby(runs).any()
    totals.loc[unknown, "ms_compute_per_frame"] = np.nan
    axes = frames.groupby("run_id")[axis_columns].first()
    metrics = axes.join([_named(p, run_ids) for p in parts]).join(_named(totals, run_ids))
    return metrics.rename_axis("run_id").reset_index()
