"""Judging TTC estimates: the reference, per-frame errors, per-run metrics, the ranking and its
intervals, and the FP.5 / FP.6 diagnosis rules. Tables and arrays in, tables out: no files,
no Hydra (the writers in :mod:`experiments.report` turn the tables into reports).

Use the names exported here (``from ttc import evaluation as ev; ev.run_metrics(...)``); the
submodules are the stages of judging:

- :mod:`~ttc.evaluation.reference`: the lead vehicle's distance from lidar alone, smoothed over
  the recording, and the reference TTC per frame pair;
- :mod:`~ttc.evaluation.metrics`: per-frame errors against the reference, per-run metrics,
  the ranking rule and its bootstrap rank intervals, comparison of two sweeps.
"""

from ttc.evaluation.metrics import (
    CACHED_STAGE_INPUTS,
    COMPARED_METRICS,
    FALSE_ALARM_S,
    OUTLIER_REL,
    RANKING_RULE,
    SENSORS,
    attach_reference,
    bootstrap_rank_intervals,
    compare_runs,
    frame_errors,
    lead_rows,
    rank_runs,
    ranking_time,
    run_metrics,
    with_compute_times,
)
from ttc.evaluation.reference import (
    REFERENCE_CAVEATS,
    lead_distance_series,
    lead_points,
    rear_distance,
    reference_for_sequence,
    reference_ttc,
)

__all__ = [
    "CACHED_STAGE_INPUTS",
    "COMPARED_METRICS",
    "FALSE_ALARM_S",
    "OUTLIER_REL",
    "RANKING_RULE",
    "REFERENCE_CAVEATS",
    "SENSORS",
    "attach_reference",
    "bootstrap_rank_intervals",
    "compare_runs",
    "frame_errors",
    "lead_distance_series",
    "lead_points",
    "lead_rows",
    "rank_runs",
    "ranking_time",
    "rear_distance",
    "reference_for_sequence",
    "reference_ttc",
    "run_metrics",
    "with_compute_times",
]
