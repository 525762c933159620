"""``ms_compute_per_frame`` from counted stage times (:mod:`ttc.evaluation.stage_times`): a
median over the counts is exactly pandas' median over the rows counted, and counting the rows
in parts gives the times counting them at once gives."""

from __future__ import annotations

import numpy as np
import pandas as pd

from ttc import evaluation as ev
from ttc.evaluation.stage_times import weighted_median


def test_weighted_median_is_the_median_of_the_rows_counted() -> None:
    # group a: 4 rows (even: the mean of the two middle ones), b: 3 rows (odd), c: a NaN key
    rows = pd.DataFrame({
        "axis": ["a", "a", "a", "a", "b", "b", "b", None],
        "ms": [1.0, 2.0, 2.0, 7.0, 0.1, 0.1, 0.3, 5.0],
    })  # fmt: skip
    counts = rows.groupby(["axis", "ms"], dropna=False).size().rename("n").reset_index()
    got = weighted_median(counts, ["axis"])
    assert got.to_dict() == {"a": 2.0, "b": 0.1}
    assert got.to_dict() == rows.groupby("axis")["ms"].median().to_dict()


def test_weighted_median_matches_pandas_on_many_random_tables() -> None:
    rng = np.random.default_rng(7)
    for _ in range(200):
        m = int(rng.integers(1, 30))
        rows = pd.DataFrame({"axis": rng.choice(["x", "y", "z"], m),
                             "frame": rng.integers(0, 3, m),
                             "ms": rng.choice([0.1, 0.2, 0.7, 1.3, 9.9], m)})  # fmt: skip
        counts = rows.groupby(["axis", "frame", "ms"]).size().rename("n").reset_index()
        for keys in (["axis", "frame"], ["axis"], ["frame"]):
            want = rows.groupby(keys)["ms"].median()
            got = weighted_median(counts, keys).reindex(want.index)
            assert np.array_equal(got.to_numpy(), want.to_numpy())  # bit for bit


def stage_rows(run: str, detector: str, ms: list[float], cached: list[bool]) -> dict:
    """One run's rows on frames 1..n: its keypoint time and cache flag per frame, two box rows
    per frame (the stage time is per frame pair, repeated on its rows)."""
    n = len(ms)
    frame = [f for f in range(1, n + 1) for _ in range(2)]
    twice = [v for v in ms for _ in range(2)]
    flags = [v for v in cached for _ in range(2)]
    return {"run_id": [run] * 2 * n, "frame": frame, "detector": [detector] * 2 * n,
            "ms_keypoints": twice, "cached_keypoints": flags, "ms_camera_ttc": [1.0] * 2 * n}  # fmt: skip


def test_counting_in_parts_gives_the_times_of_counting_at_once() -> None:
    a = pd.DataFrame(stage_rows("A", "fast", [4.0, 6.0, 8.0], [False, False, False]))
    b = pd.DataFrame(stage_rows("B", "fast", [0.5, 0.5, 0.5], [True, True, False]))
    c = pd.DataFrame(stage_rows("C", "orb", [0.2, 0.2, 0.2], [True, True, True]))
    rows = pd.concat([a, b, c], ignore_index=True)
    whole = ev.compute_times(rows, ev.stage_time_counts(rows))
    parts = ev.join_counts(ev.stage_time_counts(t) for t in (a, b, c))
    assert ev.compute_times(rows, parts).equals(whole)
    # B's cached frames 1, 2 take A's times there; C (orb) loaded everything: its load time
    assert whole[rows["run_id"] == "B"].tolist() == [5.0, 5.0, 7.0, 7.0, 1.5, 1.5]
    assert whole[rows["run_id"] == "C"].tolist() == [1.2] * 6


def test_times_looked_up_for_rows_whose_axes_are_categories_are_those_of_strings() -> None:
    """The report's judged rows hold their axes as categories (other categories, another
    order than the counts'): the times looked up are those of the same rows as strings."""
    a = pd.DataFrame(stage_rows("A", "fast", [4.0, 6.0, 8.0], [False, False, False]))
    b = pd.DataFrame(stage_rows("B", "fast", [0.5, 0.5, 0.5], [True, True, False]))
    c = pd.DataFrame(stage_rows("C", "orb", [0.2, 0.2, 0.2], [True, True, True]))
    rows = pd.concat([a, b, c], ignore_index=True)
    counts = ev.stage_time_counts(rows)
    as_text = ev.compute_times(rows, counts)
    coded = rows.assign(
        detector=pd.Categorical(rows["detector"], categories=["sift", "orb", "fast"])
    )
    pd.testing.assert_series_equal(ev.compute_times(coded, counts), as_text)
    assert as_text[rows["run_id"] == "B"].tolist() == [5.0, 5.0, 7.0, 7.0, 1.5, 1.5]
