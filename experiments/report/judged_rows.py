"""A sweep's rows for a report in bounded memory: of the rows (one per run × frame pair × box
pair) a report judges only each pair's lead row (:func:`ttc.evaluation.lead_rows`) on the
columns it reads (:func:`read_columns`), and the matched box pairs of one run per camera
setting (the "every object" report) on a few. The store is read a fragment at a time
(:func:`experiments.store.scan_sweep`) and each fragment is cut to those rows at once, so no
frame of every row and every column is built (``grand`` 0–18: 3.06 M rows, 2.4 GB as one
pandas frame; docs/benchmarks.md)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd
from pandas.api.extensions import ExtensionArray
from pandas.api.types import is_string_dtype

from experiments.identity import with_neutral_axes
from experiments.recordings import run_ids_by_recording, setting_of
from experiments.report.heap import release_freed_memory
from experiments.tools.schema import FRAME_COLUMNS
from ttc import evaluation as ev
from ttc.evaluation.errors import is_in
from ttc.evaluation.stage_times import group_codes
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


#: Columns of a sweep's rows that no report reads (provenance, the YOLO box's class and
#: position, counts of the intermediate steps, the lidar object): left unread, and the judged
#: rows are on the others (``grand`` 0–18: 21 of 87 columns, 105 of 390 MB of judged rows).
UNREAD_COLUMNS: tuple[str, ...] = (
    "sweep_id", "git_commit", "error", "scan_points_prev", "scan_dropped_curr",
    "lane_points_curr", "boxes_prev", "boxes_curr", "keypoints_prev", "described_curr",
    "object_distance_m", "object_spread_m", "object_points", "object_frustum_points",
    "box_class", "box_confidence", "box_x", "box_y", "box_shared_matches",
    "lidar_outliers_prev", "lidar_outliers_curr",
)  # fmt: skip
#: Fragments read (:func:`read_rows`), and columns stacked (:func:`stacked_columns`), between
#: two :func:`~experiments.report.heap.release_freed_memory` calls (``grand`` 0–18: 175
#: fragments; its load step peaked 0.28 GB higher without them, and a call after every
#: fragment costs ≈ 25 ms of system time each).
TRIM_EVERY = 16
#: Columns read only to count and look up the stage times (:data:`TIME_COLUMNS`), dropped
#: from the judged rows once ``ms_compute_per_frame`` is known (:func:`compute_times`).
COUNTED_ONLY: tuple[str, ...] = tuple(c for c in TIME_COLUMNS if c.startswith("cached_"))


def row_columns() -> list[str]:
    """Every column a sweep's rows may have, in the order the runner writes them."""
    return [c for c, *_ in FRAME_COLUMNS] + list(TRUTH_COLUMNS)


def read_columns() -> list[str]:
    """The columns of a sweep's rows a report reads: :func:`row_columns` but
    :data:`UNREAD_COLUMNS`."""
    return [c for c in row_columns() if c not in UNREAD_COLUMNS]


def judged_mask(keys: pd.DataFrame) -> np.ndarray:
    """Rows (n,) bool that :func:`ttc.evaluation.lead_rows` can pick: every ``is_lead`` row,
    and a pair's first row where the pair (``run_id``, ``frame``) has none."""
    lead = keys["is_lead"].astype(bool).to_numpy()
    coded = [pd.factorize(keys[c], use_na_sentinel=False)[0] for c in ("run_id", "frame")]
    pair = group_codes(coded)  # (n,) the pair of each row, numbered as first seen
    has_lead = np.bincount(pair, weights=lead).astype(bool)[pair]
    first = np.zeros(len(pair), dtype=bool)
    first[np.unique(pair, return_index=True)[1]] = True
    return lead | (~has_lead & first)


#: The last :func:`camera_runs` (its runs' fingerprint, its labels): the load step asks for
#: it (:func:`box_runs`) and the "every object" report again (≈ 9 s each for ``grand``).
_LAST_CAMERA_RUNS: list[tuple[tuple, pd.Series]] = []


def _fingerprint(runs: pd.DataFrame) -> tuple:
    """What :func:`camera_runs` reads of ``runs``: its columns and the hash of its run ids
    (each names its setting's config), statuses and axes."""
    read = ["run_id", "status", *(a for a in AXES if a in runs)]
    hashed = pd.util.hash_pandas_object(runs[read], index=False).to_numpy()
    return tuple(runs.columns), len(runs), hashed.tobytes()


def camera_runs(runs: pd.DataFrame) -> pd.Series:
    """One ok run per camera setting (settings that differ only in a lidar or fused option
    give the same camera TTC: counted once, as in the cross-recording ranking), labelled by
    the axes that vary among them; a Series of labels by run id."""
    key = _fingerprint(runs)
    if _LAST_CAMERA_RUNS and _LAST_CAMERA_RUNS[0][0] == key:
        return _LAST_CAMERA_RUNS[0][1].copy()
    ok = runs[runs["status"] == "ok"]
    ok = ok[~setting_of(ok, "camera").duplicated().to_numpy()]
    other = {*only_sensor_axes("lidar"), *only_sensor_axes("fused"), "dataset"}
    labels = ev.setting_labels(ok, [a for a in AXES if a not in other])
    found = pd.Series(labels.to_numpy(), index=ok["run_id"].to_numpy())
    _LAST_CAMERA_RUNS[:] = [(key, found)]
    return found.copy()


def box_runs(runs: pd.DataFrame) -> set[str]:
    """The runs whose box pairs the "every object" report judges: :func:`camera_runs` of
    each recording."""
    if runs.empty:
        return set()
    by_recording = run_ids_by_recording(runs).values()
    return {i for ids in by_recording for i in camera_runs(runs[is_in(runs["run_id"], ids)]).index}


def read_rows(
    parts: Iterable[pd.DataFrame], runs: pd.DataFrame
) -> tuple[pd.DataFrame, pd.DataFrame, ev.StageCounts]:
    """(judged rows, box rows, stage time counts) of the runs ``runs`` of a sweep whose rows
    come as ``parts`` (:func:`experiments.store.scan_sweep`: a fragment at a time, on
    :func:`read_columns`; every row of a run is in one part): judged rows
    (:func:`judged_mask`) on those columns, the matched
    box pairs of :func:`box_runs` on :data:`BOX_COLUMNS`, and the computed stage times of
    every row counted (:func:`ttc.evaluation.stage_time_counts`: a few rows per stage, frame
    and value). Memory: what is kept, and one part."""
    ids, boxed_ids = set(runs["run_id"]), box_runs(runs)
    lead_parts, box_parts, counts = [], [], []
    for part in parts:
        mine = is_in(part["run_id"], ids)
        judged = judged_mask(part[list(KEY_COLUMNS)]) & mine
        boxed = (
            is_in(part["run_id"], boxed_ids)
            & (part["prev_box"] >= 0).to_numpy()
            & (part["curr_box"] >= 0).to_numpy()
            & mine
        )
        order = [c for c in read_columns() if c in part]
        lead_parts.append(cut(part, judged, order))
        box_parts.append(cut(part, boxed, [c for c in BOX_COLUMNS if c in part]))
        counts.append(ev.stage_time_counts(part.loc[mine, [c for c in TIME_COLUMNS if c in part]]))
        del part
        if len(lead_parts) % TRIM_EVERY == 0:  # the fragments' freed pages back as they go
            release_freed_memory()
    return stacked_columns(lead_parts), stacked_columns(box_parts), ev.join_counts(counts)


#: A table as its columns by name, each column its own array, no index (:func:`cut`).
Columns = dict[str, ExtensionArray]


def as_category(values: ExtensionArray) -> pd.Categorical:
    """An axis's values (strings: a few distinct values over thousands of rows) as a category:
    the same values in a fraction of the memory (``grand`` 0–18's judged rows 317 → 225 MiB);
    :func:`stacked_columns` sorts the categories of the stacked column, so that it sorts and
    groups as the strings."""
    codes, distinct = pd.factorize(values)
    return pd.Categorical.from_codes(codes, categories=distinct, validate=False)


def cut(part: pd.DataFrame, rows: np.ndarray, columns: list[str]) -> Columns:
    """The rows ``rows`` ((n,) bool) of ``part`` on ``columns``, each column copied into its
    own array without an index (:func:`stacked_columns` frees them one by one), the axes
    (:data:`ttc.settings.AXES`) as categories (:func:`as_category`; the other string columns,
    run ids and reason codes, stay strings: their readers map them to other values)."""
    at = np.flatnonzero(rows)  # positions: a take is twice as fast as a mask per column
    return {
        column: as_category(part[column].array.take(at))
        if column in AXES and is_string_dtype(part[column].dtype)
        else part[column].array.take(at)
        for column in columns
    }


def category_union(dtypes: list) -> pd.Index | None:
    """The categories of values stacked from parts of ``dtypes``: the sorted union of theirs,
    so that the stacked column sorts and groups as the strings; None unless every one is a
    category (pandas would fall back to one string object per row)."""
    if not dtypes or not all(isinstance(d, pd.CategoricalDtype) for d in dtypes):
        return None
    return pd.Index(sorted(set().union(*(d.categories for d in dtypes))))


def stacked_columns(parts: list[Columns]) -> pd.DataFrame:
    """``parts`` (each with the same columns) one under the other with a new index, built a
    column at a time, each column of the parts freed once stacked: memory of the parts and
    one column, not twice the parts (``grand`` 0–18's load step 0.2 GB lower). ``parts`` is
    emptied. A category in every part stays one (:func:`category_union`)."""
    out: dict[str, pd.Series] = {}
    for i, column in enumerate(list(parts[0]) if parts else []):
        if i % TRIM_EVERY == TRIM_EVERY - 1:  # the freed pieces (small: glibc's heap) back
            release_freed_memory()
        pieces = [pd.Series(p.pop(column), copy=False) for p in parts]
        union = category_union([s.dtype for s in pieces])
        if union is not None:  # recoded (astype keeps a category equal as a set as it is)
            pieces = [s.cat.set_categories(union) for s in pieces]
        out[column] = pd.concat(pieces, ignore_index=True)
        del pieces
    return pd.DataFrame(out, copy=False)  # not consolidated: no copy of every column


def stacked(parts: list[pd.DataFrame]) -> pd.DataFrame:
    """``parts`` one under the other with a new index (an empty frame for none); a category
    in every part stays one (:func:`category_union`)."""
    if len(parts) < 2:  # one sweep's rows as they are: no copy
        return parts[0].reset_index(drop=True) if parts else pd.DataFrame()
    unions = {c: category_union([p[c].dtype if c in p else None for p in parts])
              for c in parts[0].columns}  # fmt: skip
    union = {c: v for c, v in unions.items() if v is not None}
    recoded = [p.assign(**{c: p[c].cat.set_categories(v) for c, v in union.items()}) for p in parts]
    return pd.concat(recoded, ignore_index=True)


def compute_times(frames: pd.DataFrame, counts: ev.StageCounts) -> pd.Series:
    """``ms_compute_per_frame`` (ms) of the judged rows ``frames`` (their axes filled:
    :func:`~experiments.identity.with_neutral_axes`), looked up in ``counts``, the computed
    stage times of every row of the sweeps (:func:`ttc.evaluation.compute_times`), whose axes
    are filled here alike."""
    filled = {name: with_neutral_axes(table) for name, table in counts.items()}
    rows = frames[[c for c in TIME_COLUMNS if c in frames]]
    # the axes as the strings the counts hold (a merge of a category with strings: 2.5x slower)
    as_text = {
        c: t.categories.dtype for c, t in rows.dtypes.items() if isinstance(t, pd.CategoricalDtype)
    }
    return ev.compute_times(rows.astype(as_text), filled)
