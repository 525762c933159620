"""A sweep's rows for a report in bounded memory: of the rows (one per run × frame pair × box
pair) a report judges only each pair's lead row (:func:`ttc.evaluation.lead_rows`) on the
columns it reads (:func:`read_columns`), and the matched box pairs of one run per camera
setting (the "every object" report) on a few. The store is read a fragment at a time
and each fragment is cut to those rows at once (:func:`cut_fragment`), so no frame of every
row and every column is built (``grand`` 0–18: 3.06 M rows, 2.4 GB as one pandas frame;
docs/benchmarks.md); the cuts are kept (:mod:`experiments.report.kept_judged`)."""

from __future__ import annotations

from collections.abc import Set as AbstractSet
from dataclasses import dataclass

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from experiments.configs.identity import with_neutral_axes
from experiments.host.heap import release_freed_memory
from experiments.store.schema import FRAME_COLUMNS
from experiments.summary.recordings import run_ids_by_recording, setting_of
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


@dataclass
class Cut:
    """A fragment's rows as a report reads them (:func:`cut_fragment`)."""

    judged: pa.Table  #: the judged rows (:func:`judged_mask`) on :func:`read_columns`
    boxes: pa.Table  #: the matched box pairs of the boxed runs on :data:`BOX_COLUMNS`
    counts: ev.StageCounts  #: the computed stage times of every row of the runs judged
    with_nulls: set[str]  #: the columns with a null in the fragment (any run)


def cut_fragment(table: pa.Table, ids: AbstractSet[str], boxed_ids: AbstractSet[str]) -> Cut:
    """The :class:`Cut` of a fragment's rows ``table`` (:func:`experiments.store.dataset.iter_tables`
    on :func:`read_columns`, the sweep's unified schema) for a report that judges the runs
    ``ids`` and the box pairs of the runs ``boxed_ids`` (:func:`box_runs`): its judged rows
    (:func:`judged_mask`) on those columns, the matched box pairs (both boxes found) on
    :data:`BOX_COLUMNS`, and the computed stage times of the rows of ``ids`` counted
    (:func:`ttc.evaluation.stage_time_counts`: a few rows per stage, frame and value).

    The rows are picked in Arrow (one take of every column) and only the columns that pick
    them become pandas (:func:`key_frame`); stacked in the fragments' order, the picked rows
    become one frame at the end (:func:`as_frame`): the frame pandas gives of the fragments'
    frames cut and stacked, made of 2 Arrow calls a fragment instead of one pandas call per
    column and fragment (``grand`` 0–18: 175 fragments × 66 columns)."""
    names = table.column_names
    with_nulls = {n for n, c in zip(names, table.columns, strict=True) if c.null_count}
    keys = key_frame(table)
    mine = is_in(keys["run_id"], ids)
    judged = judged_mask(keys) & mine
    boxed = (
        is_in(keys["run_id"], boxed_ids)
        & (keys["prev_box"] >= 0).to_numpy()
        & (keys["curr_box"] >= 0).to_numpy()
        & mine
    )
    timed = table.select([c for c in TIME_COLUMNS if c in names]).filter(mine)
    return Cut(
        picked_rows(table, [c for c in read_columns() if c in names], judged),
        picked_rows(table, [c for c in BOX_COLUMNS if c in names], boxed),
        ev.stage_time_counts(timed.to_pandas()),
        with_nulls,
    )


def key_frame(table: pa.Table) -> pd.DataFrame:
    """The :data:`KEY_COLUMNS` of a fragment's rows as pandas, ``run_id`` a category (a few
    runs over thousands of rows: matched and grouped by its codes, not as strings)."""
    keys = table.select([c for c in KEY_COLUMNS if c in table.column_names])
    at = keys.schema.get_field_index("run_id")
    keys = keys.set_column(at, "run_id", pc.dictionary_encode(keys.column(at)))
    return keys.to_pandas()


def picked_rows(table: pa.Table, columns: list[str], rows: np.ndarray) -> pa.Table:
    """The rows ``rows`` ((n,) bool) of ``table`` on ``columns``, in a table of their own
    (no buffer of the fragment kept), the axes (:data:`ttc.settings.AXES`, strings)
    dictionary-encoded: a few distinct values over thousands of rows."""
    taken = table.select(columns).take(pa.array(np.flatnonzero(rows)))
    for i, field in enumerate(taken.schema):
        text = pa.types.is_string(field.type) or pa.types.is_large_string(field.type)
        if field.name in AXES and text:
            taken = taken.set_column(i, field.name, pc.dictionary_encode(taken.column(i)))
    return taken


def as_frame(parts: list[pa.Table], with_nulls: AbstractSet[str]) -> pd.DataFrame:
    """``parts`` (Arrow tables of one schema, emptied) one under the other as pandas, with the
    types pandas gives when each fragment becomes a frame before its rows are cut and the
    cuts are stacked: a column of integers or flags with a null in some fragment
    (``with_nulls``) is float or object in every one, whether the rows kept hold the null or
    not; the axes are categories with sorted categories, so that they sort and group as the
    strings (``grand`` 0–18's judged rows 317 → 225 MiB as categories). An empty list gives an
    empty frame."""
    if not parts:
        return pd.DataFrame()
    table = pa.concat_tables(parts)
    parts.clear()
    frame = table.to_pandas(self_destruct=True)
    del table
    release_freed_memory()  # the table's pages back (grand 0-77: its load peaked 0.45 GB higher)
    for name in frame.columns:
        column = frame[name]
        if isinstance(column.dtype, pd.CategoricalDtype):
            frame[name] = column.cat.set_categories(category_union([column.dtype]))
        elif name in with_nulls and column.dtype.kind in "iu":
            frame[name] = column.astype(np.float64)
        elif name in with_nulls and column.dtype.kind == "b":
            frame[name] = column.astype(object)
    return frame


def category_union(dtypes: list) -> pd.Index | None:
    """The categories of values stacked from parts of ``dtypes``: the sorted union of theirs,
    so that the stacked column sorts and groups as the strings; None unless every one is a
    category (pandas would fall back to one string object per row)."""
    if not dtypes or not all(isinstance(d, pd.CategoricalDtype) for d in dtypes):
        return None
    return pd.Index(sorted(set().union(*(d.categories for d in dtypes))))


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
    :func:`~experiments.configs.identity.with_neutral_axes`), looked up in ``counts``, the computed
    stage times of every row of the sweeps (:func:`ttc.evaluation.compute_times`), whose axes
    are filled here alike."""
    filled = {name: with_neutral_axes(table) for name, table in counts.items()}
    rows = frames[[c for c in TIME_COLUMNS if c in frames]]
    # the axes as the strings the counts hold (a merge of a category with strings: 2.5x slower)
    as_text = {
        c: t.categories.dtype for c, t in rows.dtypes.items() if isinstance(t, pd.CategoricalDtype)
    }
    return ev.compute_times(rows.astype(as_text), filled)
