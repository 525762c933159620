"""The report in bounded memory (issue 32, :mod:`experiments.report.judged_rows`): a real sweep's
tables written by today's report and by the report at ``a6c2b20`` (which held every row of
every run in one frame) are byte-identical, the report's own provenance lines aside; and the
rows a report keeps are the ones :func:`ttc.evaluation.lead_rows` picks."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pyarrow as pa
import pytest

from experiments.configs.identity import with_neutral_axes
from experiments.report.judged_rows import (
    BOX_COLUMNS,
    COUNTED_ONLY,
    KEY_COLUMNS,
    TIME_COLUMNS,
    UNREAD_COLUMNS,
    as_frame,
    judged_mask,
    picked_rows,
    read_columns,
    row_columns,
    stacked,
)
from ttc import evaluation as ev


def test_judged_mask_keeps_the_rows_lead_rows_picks() -> None:
    # run a: pair 1 has its lead on the 2nd row; pair 2 has none (its first row is kept)
    keys = pd.DataFrame({
        "run_id": ["a", "a", "a", "a", "b", "a"],
        "frame": [1, 1, 2, 2, 1, 1],
        "is_lead": [False, True, False, False, True, False],
        "ttc_camera": [9.0, 1.0, 2.0, 3.0, 4.0, 5.0],
    })  # fmt: skip
    assert judged_mask(keys).tolist() == [False, True, True, False, True, False]
    picked = ev.lead_rows(keys[judged_mask(keys)])
    assert picked.equals(ev.lead_rows(keys))


@pytest.mark.parametrize("dtype", ["str", "object", "category", "string[pyarrow]"])
def test_run_ids_matched_as_pandas_matches_them(dtype: str) -> None:
    values = pd.Series(["a", "b", None, "c", "a"], dtype=dtype)
    assert ev.is_in(values, {"a", "c", "zz"}).tolist() == values.isin({"a", "c", "zz"}).tolist()
    assert ev.is_in(values, ["c", "zz"]).tolist() == values.isin(["c", "zz"]).tolist()
    assert ev.is_in(values, set()).tolist() == [False] * 5


def test_the_columns_left_unread_are_row_columns_no_step_needs() -> None:
    """A renamed column would leave its old name here, unread and unnoticed."""
    assert set(UNREAD_COLUMNS) <= set(row_columns())
    needed = {*KEY_COLUMNS, *TIME_COLUMNS, *BOX_COLUMNS}
    assert not needed & set(UNREAD_COLUMNS)
    assert set(COUNTED_ONLY) <= set(read_columns())


def _fragment(rng: np.random.Generator, detectors: list[str], n: int, holes: bool) -> pa.Table:
    """Rows as a fragment reads them: an axis and run ids (large strings, some missing), a
    float with NaN, and an integer and a flag column with a null in the first row when
    ``holes``."""
    detector = rng.choice(np.array([*detectors, None], dtype=object), n).tolist()
    frame = rng.integers(0, 18, n).tolist()
    lead = (rng.random(n) < 0.5).tolist()
    if holes:
        frame[0] = lead[0] = None
    return pa.table({
        "run_id": pa.array(rng.choice(["r1", "r2", "r3"], n).tolist(), pa.large_string()),
        "detector": pa.array(detector, pa.large_string()),
        "ttc_camera": np.where(rng.random(n) < 0.2, np.nan, rng.normal(10, 2, n)),
        "frame": pa.array(frame, pa.int64()),
        "is_lead": pa.array(lead, pa.bool_()),
    })  # fmt: skip


def _cut_and_stacked(tables: list[pa.Table], masks: list[np.ndarray]) -> pd.DataFrame:
    """What pandas gives: each fragment as a frame, its rows cut, the cuts stacked, the axis
    a category of sorted categories."""
    want = pd.concat([t.to_pandas()[m] for t, m in zip(tables, masks, strict=True)],
                     ignore_index=True)  # fmt: skip
    values = want["detector"]
    return want.assign(detector=pd.Categorical(values, categories=sorted(values.dropna().unique())))


@pytest.mark.parametrize("holes", [(False, False, False), (False, True, False)])
def test_rows_taken_in_arrow_are_the_frame_pandas_cuts_and_stacks(holes) -> None:
    """A fragment's null in the integer and flag columns makes them float and object in
    every fragment's frame, so in the stacked rows too, whether the rows kept hold it or not
    (its first row is never kept here)."""
    rng = np.random.default_rng(3)
    tables = [_fragment(rng, d, 40, h)
              for d, h in zip((["orb", "akaze"], ["sift"], ["orb", "fast"]), holes, strict=True)]  # fmt: skip
    masks = [(rng.random(40) < 0.6) & (np.arange(40) > 0) for _ in tables]
    nulls = {n for t in tables for n, c in zip(t.column_names, t.columns, strict=True)
             if c.null_count}  # fmt: skip
    parts = [picked_rows(t, t.column_names, m) for t, m in zip(tables, masks, strict=True)]
    got = as_frame(parts, nulls)
    want = _cut_and_stacked(tables, masks)
    assert not parts  # emptied
    assert list(got["detector"].cat.categories) == ["akaze", "fast", "orb", "sift"]
    assert got["detector"].cat.categories.dtype == want["detector"].cat.categories.dtype
    assert dict(got.dtypes) == dict(want.dtypes)
    assert got["frame"].dtype == (np.float64 if any(holes) else np.int64)
    pd.testing.assert_frame_equal(got, want, check_exact=True)
    assert got.groupby("detector").size().equals(want.groupby("detector").size())


def test_no_parts_are_an_empty_frame() -> None:
    assert as_frame([], set()).empty


def test_a_missing_axis_of_a_category_is_filled_with_its_off_value() -> None:
    rows = pd.DataFrame({"fusion": pd.Categorical(["kalman_cv", None], categories=["kalman_cv"])})
    filled = with_neutral_axes(rows)["fusion"]
    assert filled.tolist() == ["kalman_cv", "none"]
    assert list(filled.cat.categories) == ["kalman_cv", "none"]


def test_sweeps_stacked_keep_their_axes_as_one_category() -> None:
    """Two sweeps' judged rows (the report of several folders): the axis stays a category,
    its categories the sorted union, each row's value kept."""
    first = pd.DataFrame({"detector": pd.Categorical(["sift", "orb"]), "frame": [1, 2]})
    second = pd.DataFrame({"detector": pd.Categorical(["akaze", None]), "frame": [3, 4]})
    both = stacked([first, second])
    assert list(both["detector"].cat.categories) == ["akaze", "orb", "sift"]
    assert both["detector"].tolist()[:3] == ["sift", "orb", "akaze"]
    assert both["detector"].isna().tolist() == [False, False, False, True]
    assert both.index.tolist() == [0, 1, 2, 3] and both["frame"].tolist() == [1, 2, 3, 4]


def test_categories_sorted_when_parts_list_them_in_another_order() -> None:
    """Fragments code an axis in the order its values first come; the same values in another
    order still give sorted categories (a category's dtype equal as a set is not recoded by
    ``astype``), for one sweep's fragments and for sweeps stacked."""
    values = (["orb", "sift", "akaze"], ["akaze", "orb"], ["sift", "akaze", "orb"])
    tables = [pa.table({"detector": pa.array(v, pa.large_string())}) for v in values]
    got = as_frame([picked_rows(t, ["detector"], np.ones(t.num_rows, dtype=bool)) for t in tables],
                   set())["detector"]  # fmt: skip
    assert list(got.cat.categories) == ["akaze", "orb", "sift"]
    assert got.tolist() == ["orb", "sift", "akaze", "akaze", "orb", "sift", "akaze", "orb"]
    frames = [pd.DataFrame({"detector": pd.Categorical(v, categories=v)}) for v in
              (["sift", "orb"], ["orb", "sift"])]  # fmt: skip
    assert list(stacked(frames)["detector"].cat.categories) == ["orb", "sift"]


def test_objects_made_before_the_call_leave_the_collector_only_inside_the_block() -> None:
    """A report keeps its loaded sweeps out of the garbage collector's passes
    (:func:`experiments.host.heap.long_lived`): frozen when it says so, collected again after the
    block; garbage already made is freed, not kept; after a caller's own freeze (the warm
    server's), what the block froze stays frozen."""
    import gc
    import weakref

    from experiments.host.heap import long_lived

    if gc.get_freeze_count():
        pytest.skip("this process holds frozen objects already")

    class Node:
        pass

    cycle = Node()
    cycle.me = cycle  # garbage only the collector frees
    gone = weakref.ref(cycle)
    del cycle
    with long_lived() as keep:
        kept = [[] for _ in range(1000)]
        assert gc.get_freeze_count() == 0
        keep()
        assert gone() is None and gc.get_freeze_count() >= len(kept)
    assert gc.get_freeze_count() == 0
    gc.freeze()
    try:
        own = gc.get_freeze_count()
        with long_lived(collect=False) as keep:
            more = [[] for _ in range(1000)]
            keep()
            assert gc.get_freeze_count() >= own + len(more)
        assert gc.get_freeze_count() >= own + len(more)  # not unfrozen: the caller's stays
    finally:
        gc.unfreeze()
