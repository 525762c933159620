"""Judging TTC estimates: the reference, per-frame errors, per-run metrics, the ranking and its
intervals, and the FP.5 / FP.6 diagnosis rules. Tables and arrays in, tables out: no files,
no Hydra (the writers in :mod:`experiments.report` turn the tables into reports).

Use the names exported here (``from ttc import evaluation as ev; ev.run_metrics(...)``); the
submodules are the stages of judging:

- :mod:`~ttc.evaluation.reference`: the lead vehicle's distance from lidar alone, smoothed over
  the recording, and the reference TTC per frame pair;
- :mod:`~ttc.evaluation.errors`: per frame pair, each estimate's errors against it (the
  motion-in-depth error, the relative TTC error, outliers, false alarms, warnings) and time;
- :mod:`~ttc.evaluation.metrics`: those errors aggregated per run, per sensor and regime;
- :mod:`~ttc.evaluation.ranking`: the ranking rule;
- :mod:`~ttc.evaluation.bootstrap`: rank intervals from a moving-block bootstrap;
- :mod:`~ttc.evaluation.drives`: several drives in one sweep, per drive and pooled;
- :mod:`~ttc.evaluation.run_comparison`: one setting in two sweeps;
- :mod:`~ttc.evaluation.lead_status`: frames without one lead vehicle to judge against
  (``no_lead``, ``lead_change``), which split the reference into segments;
- :mod:`~ttc.evaluation.transfer`: how far a ranking carries from one recording to another
  (Kendall's τ, the best of one on the others, the top everywhere);
- :mod:`~ttc.evaluation.ttc_bins`: metrics per reference-TTC range (< 6, 6–12, 12–24,
  > 24 s) and the false alarms of a recording without a lead vehicle;
- :mod:`~ttc.evaluation.families`: learned features, dense flow, tracking and the scale fit
  against the best classic setting;
- :mod:`~ttc.evaluation.truth`: judging a generated recording against its exact truth, per
  target TTC, and its ranking's agreement with a real sequence's;
- :mod:`~ttc.evaluation.lead`: which box is the lead vehicle's (one rule for tables and
  pictures);
- :mod:`~ttc.evaluation.diagnosis`, :mod:`~ttc.evaluation.lidar_diagnosis`,
  :mod:`~ttc.evaluation.camera_diagnosis`: the FP.5 and FP.6 rules that find implausible
  frames and explain them, with their thresholds.
"""

from ttc.evaluation.bootstrap import (
    CI,
    N_BOOT,
    block_draws,
    block_length,
    bootstrap_rank_intervals,
    rank_interval,
    rank_replicates,
    tied_for_first,
)
from ttc.evaluation.camera_diagnosis import (
    BACKGROUND_M,
    BACKGROUND_SHARE,
    BORDER_FRAC,
    BORDER_SHARE,
    EXACT_SHARE,
    FEW_MATCHES,
    LEAVE_PX,
    LEAVE_SHARE,
    LIDAR_PX,
    PER_PAIR,
    RATIO_HAIR,
    REMOVED_SHARE,
    WAY_OFF_REL,
    MatchGeometry,
    camera_fallback,
    camera_frame_table,
    camera_ranking,
    camera_reasons,
    camera_rules,
    camera_runs,
    geometry_texts,
    match_geometry,
    pareto_front,
    with_geometry_reasons,
    worst_order,
)
from ttc.evaluation.diagnosis import (
    CAMERA_AXES,
    combine_reasons,
    judged_rows,
    setting_key,
    setting_labels,
    sweep_metrics,
    with_reasons,
)
from ttc.evaluation.drives import (
    DRIVE_FRAME_STRIDE,
    POOLED,
    drive_rankings,
    pooled_frames,
    stack_drives,
)
from ttc.evaluation.errors import (
    FALSE_ALARM_S,
    LEAD_BLANKED,
    NOT_JUDGED_COLUMNS,
    OUTLIER_REL,
    SENSORS,
    WARNING_TTC_S,
    attach_reference,
    frame_errors,
    is_in,
    lead_row_positions,
    lead_rows,
    mid_error,
    rows_of_runs,
)
from ttc.evaluation.families import FAMILIES, against_best_classic, family_of, verdict_sentence
from ttc.evaluation.lead import box_points, lead_box_of, lead_boxes, lead_clouds, lead_row
from ttc.evaluation.lead_distance import (
    euclidean_clusters,
    lead_distance_series,
    lead_points,
    rear_distance,
)
from ttc.evaluation.lead_status import (
    LEAD_CHANGE,
    LEAD_STATUSES,
    NO_LEAD,
    lead_segments,
    lead_status,
    not_judged_frames,
    not_judged_text,
)
from ttc.evaluation.lidar_diagnosis import (
    AHEAD_M,
    ANOMALY_M,
    BOX_JUMP,
    MAX_NOISE_STEP_M,
    NOISE_FLOOR_M,
    OTHER_EFFECT_M,
    OTHER_GAP_M,
    SECOND_CLUSTER_POINTS,
    SHARED_STEP_M,
    estimator_marks,
    lidar_fallback,
    lidar_frame_table,
    lidar_metrics,
    lidar_reasons,
    lidar_rules,
    lidar_runs,
    lidar_wide,
    most_flagged_frames,
    other_clusters,
    other_object_effect,
    other_object_pairs,
    other_object_text,
)
from ttc.evaluation.metrics import judged_frames, run_metrics
from ttc.evaluation.ranking import RANKING_KEYS, RANKING_RULE, rank_runs, ranking_time
from ttc.evaluation.reference import (
    MAX_REF_REL_SD,
    MID_SCALE,
    MIN_CLOSING_SPEED_MPS,
    REFERENCE_CAVEATS,
    REFERENCE_SUMMARY,
    REGIMES,
    find_stop,
    reference_for_sequence,
    reference_ttc,
)
from ttc.evaluation.run_comparison import COMPARED_METRICS, compare_runs
from ttc.evaluation.stage_times import (
    CACHED_STAGE_INPUTS,
    StageCounts,
    compute_times,
    join_counts,
    stage_time_columns,
    stage_time_counts,
    with_compute_times,
)
from ttc.evaluation.transfer import (
    best_elsewhere,
    recording_agreement,
    top_everywhere,
    transfer_sentence,
)
from ttc.evaluation.truth import (
    ALL_TARGETS,
    TRUTH_METRICS,
    has_truth,
    ranking_agreement,
    target_label,
    truth_metrics,
    truth_reference,
)
from ttc.evaluation.ttc_bins import (
    TTC_BIN_EDGES_S,
    TTC_BINS,
    binned_metrics,
    no_lead_pairs,
    no_lead_reports,
    ttc_bin,
)

__all__ = [
    "FAMILIES",
    "against_best_classic",
    "family_of",
    "verdict_sentence",
    "best_elsewhere",
    "recording_agreement",
    "top_everywhere",
    "transfer_sentence",
    "TTC_BIN_EDGES_S",
    "TTC_BINS",
    "binned_metrics",
    "no_lead_pairs",
    "no_lead_reports",
    "ttc_bin",
    "CACHED_STAGE_INPUTS",
    "COMPARED_METRICS",
    "FALSE_ALARM_S",
    "OUTLIER_REL",
    "RANKING_RULE",
    "REFERENCE_CAVEATS",
    "REFERENCE_SUMMARY",
    "SENSORS",
    "attach_reference",
    "bootstrap_rank_intervals",
    "compare_runs",
    "frame_errors",
    "lead_distance_series",
    "lead_points",
    "NOT_JUDGED_COLUMNS",
    "LEAD_BLANKED",
    "lead_row_positions",
    "lead_rows",
    "DRIVE_FRAME_STRIDE",
    "POOLED",
    "drive_rankings",
    "pooled_frames",
    "stack_drives",
    "LEAD_CHANGE",
    "LEAD_STATUSES",
    "NO_LEAD",
    "lead_segments",
    "lead_status",
    "not_judged_frames",
    "not_judged_text",
    "rank_runs",
    "ranking_time",
    "rear_distance",
    "reference_for_sequence",
    "reference_ttc",
    "run_metrics",
    "with_compute_times",
    "rows_of_runs",
    "is_in",
    "compute_times",
    "join_counts",
    "StageCounts",
    "stage_time_counts",
    "CI",
    "N_BOOT",
    "MAX_REF_REL_SD",
    "MID_SCALE",
    "RANKING_KEYS",
    "REGIMES",
    "WARNING_TTC_S",
    "block_draws",
    "block_length",
    "find_stop",
    "judged_frames",
    "mid_error",
    "rank_interval",
    "rank_replicates",
    "stage_time_columns",
    "tied_for_first",
    # appended: the reference's cluster rule and speed floor, the diagnoses
    "MIN_CLOSING_SPEED_MPS",
    "euclidean_clusters",
    "CAMERA_AXES",
    "combine_reasons",
    "judged_rows",
    "setting_key",
    "setting_labels",
    "sweep_metrics",
    "with_reasons",
    "box_points",
    "lead_box_of",
    "lead_boxes",
    "lead_clouds",
    "lead_row",
    "AHEAD_M",
    "ANOMALY_M",
    "BOX_JUMP",
    "MAX_NOISE_STEP_M",
    "NOISE_FLOOR_M",
    "OTHER_EFFECT_M",
    "OTHER_GAP_M",
    "SECOND_CLUSTER_POINTS",
    "SHARED_STEP_M",
    "estimator_marks",
    "lidar_fallback",
    "lidar_frame_table",
    "lidar_metrics",
    "lidar_reasons",
    "lidar_rules",
    "lidar_runs",
    "lidar_wide",
    "most_flagged_frames",
    "other_clusters",
    "other_object_effect",
    "other_object_pairs",
    "other_object_text",
    "BACKGROUND_M",
    "BACKGROUND_SHARE",
    "BORDER_FRAC",
    "BORDER_SHARE",
    "EXACT_SHARE",
    "FEW_MATCHES",
    "LEAVE_PX",
    "LEAVE_SHARE",
    "LIDAR_PX",
    "PER_PAIR",
    "RATIO_HAIR",
    "REMOVED_SHARE",
    "WAY_OFF_REL",
    "MatchGeometry",
    "camera_fallback",
    "camera_frame_table",
    "camera_ranking",
    "camera_reasons",
    "camera_rules",
    "camera_runs",
    "geometry_texts",
    "match_geometry",
    "pareto_front",
    "with_geometry_reasons",
    "worst_order",
    # exact truth (generated recordings)
    "ALL_TARGETS",
    "TRUTH_METRICS",
    "has_truth",
    "ranking_agreement",
    "target_label",
    "truth_metrics",
    "truth_reference",
]
