"""A sweep's rows for a report in bounded memory: of the rows (one per run × frame pair × box
pair) a report judges only each pair's lead row (:func:`ttc.evaluation.lead_rows`) on every
column, and the matched box pairs of one run per camera setting (the "every object" report)
on a few. The store is read a fragment at a time (:func:`experiments.store.scan_sweep`) and
each fragment is cut to those rows at once, so no frame of every row and every column is built
(``grand`` 0–18: 3.06 M rows, 2.4 GB as one pandas frame; docs/benchmarks.md)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from experiments.identity import with_neutral_axes
from experiments.recordings import run_ids_by_recording, setting_of
from experiments.tools.schema import FRAME_COLUMNS
from ttc import evaluation as ev
from ttc.io.frames import TRUTH_COLUMNS
from ttc.settings import AXES, CACHED_STAGES, only_sensor_axes

#: Columns that pick the rows: the pair (run, frame), its lead flag and its box pair.
KEY_COLUMNS: tuple[str, ...] = ("run_id", "frame", "is_lead", "prev_box", "curr_box")
#: Columns :func:`ttc.evaluation.stage_time_counts` reads on every row.
TIME_COLUMNS: tuple[str, ...] = (
    "frame",
    *dict.fromkeys(a for s in CACHED_STAGES for a in s.axes),
    *(c for c, *_ in FRAME_COLUMNS if c.startswith(("ms_", "cached_"))),
)
#: Columns of the matched box pairs the "every object" report judges
#: (:func:`ttc.evaluation.object_errors.judge_objects`).
BOX_COLUMNS: tuple[str, ...] = (
    "run_id", "prev_frame", "frame", "prev_box", "curr_box", "box_w", "box_h", "ttc_lidar",
    "d_prev", "d_curr", "ttc_camera", "camera_ratio",
)  # fmt: skip


def row_columns() -> list[str]:
    """Every column a sweep's rows may have, in the order the runner writes them."""
    return [c for c, *_ in FRAME_COLUMNS] + list(TRUTH_COLUMNS)


def judged_mask(keys: pd.DataFrame) -> np.ndarray:
    """Rows (n,) bool that :func:`ttc.evaluation.lead_rows` can pick: every ``is_lead`` row,
    and a pair's first row where the pair (``run_id``, ``frame``) has none."""
    lead = keys["is_lead"].astype(bool).to_numpy()
    pair = [keys["run_id"], keys["frame"]]
    has_lead = pd.Series(lead).groupby(pair, sort=False).transform("any").to_numpy()
    first = ~keys.duplicated(["run_id", "frame"]).to_numpy()
    return lead | (~has_lead & first)


def camera_runs(runs: pd.DataFrame) -> pd.Series:
    """One ok run per camera setting (settings that differ only in a lidar or fused option
    give the same camera TTC: counted once, as in the cross-recording ranking), labelled by
    the axes that vary among them; a Series of labels by run id."""
    ok = runs[runs["status"] == "ok"]
    ok = ok[~setting_of(ok, "camera").duplicated().to_numpy()]
    other = {*only_sensor_axes("lidar"), *only_sensor_axes("fused"), "dataset"}
    labels = ev.setting_labels(ok, [a for a in AXES if a not in other])
    return pd.Series(labels.to_numpy(), index=ok["run_id"].to_numpy())


def box_runs(runs: pd.DataFrame) -> set[str]:
    """The runs whose box pairs the "every object" report judges: :func:`camera_runs` of
    each recording."""
    if runs.empty:
        return set()
    by_recording = run_ids_by_recording(runs).values()
    return {i for ids in by_recording for i in camera_runs(runs[runs["run_id"].isin(ids)]).index}


def read_rows(
    parts: Iterable[pd.DataFrame], runs: pd.DataFrame
) -> tuple[pd.DataFrame, pd.DataFrame, ev.StageCounts]:
    """(judged rows, box rows, stage time counts) of the runs ``runs`` of a sweep whose rows
    come as ``parts`` (:func:`experiments.store.scan_sweep`: a fragment at a time; every row
    of a run is in one part): judged rows (:func:`judged_mask`) on every column, the matched
    box pairs of :func:`box_runs` on :data:`BOX_COLUMNS`, and the computed stage times of
    every row counted (:func:`ttc.evaluation.stage_time_counts`: a few rows per stage, frame
    and value). Memory: what is kept, and one part."""
    ids, boxed_ids = set(runs["run_id"]), box_runs(runs)
    lead_parts, box_parts, counts = [], [], []
    for part in parts:
        mine = part["run_id"].isin(ids).to_numpy()
        judged = judged_mask(part[list(KEY_COLUMNS)]) & mine
        boxed = (
            part["run_id"].isin(boxed_ids).to_numpy()
            & (part["prev_box"] >= 0).to_numpy()
            & (part["curr_box"] >= 0).to_numpy()
            & mine
        )
        order = [c for c in row_columns() if c in part]
        lead_parts.append(part.loc[judged, order])
        box_parts.append(part.loc[boxed, [c for c in BOX_COLUMNS if c in part]])
        counts.append(ev.stage_time_counts(part.loc[mine, [c for c in TIME_COLUMNS if c in part]]))
        del part
    return _stacked(lead_parts), _stacked(box_parts), ev.join_counts(counts)


def _stacked(parts: list[pd.DataFrame]) -> pd.DataFrame:
    """``parts`` one under the other with a new index (an empty frame for none)."""
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def compute_times(frames: pd.DataFrame, counts: ev.StageCounts) -> pd.Series:
    """``ms_compute_per_frame`` (ms) of the judged rows ``frames`` (their axes filled:
    :func:`~experiments.identity.with_neutral_axes`), looked up in ``counts``, the computed
    stage times of every row of the sweeps (:func:`ttc.evaluation.compute_times`), whose axes
    are filled here alike."""
    filled = {name: with_neutral_axes(table) for name, table in counts.items()}
    return ev.compute_times(frames[[c for c in TIME_COLUMNS if c in frames]], filled)
