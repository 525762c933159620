"""The FP.5 / FP.6 diagnosis rules of :mod:`ttc.evaluation` on small hand-made tables and
arrays: each rule fires on its evidence and only there, with the numbers in its text."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ttc import evaluation as ev
from ttc.features.matching import Matches
from ttc.rows import PairDetail
from ttc.steps.lidar_ttc import LidarTTCParams

# --------------------------------------------------------------------------- reason tables


def test_combine_reasons_joins_codes_and_texts() -> None:
    index = pd.Index([0, 1, 2])
    parts = {
        "code": pd.Series(["receding: moving away", "", ""], index=index),
        "noise_floor": pd.Series(["small step", "", "tiny"], index=index),
    }
    out = ev.combine_reasons(parts, index)
    assert out["reasons"].tolist() == ["receding;noise_floor", "", "noise_floor"]
    assert out["reason_text"].tolist() == ["receding: moving away. small step.", "", "tiny."]


def test_with_reasons_only_on_selected_rows_with_a_fallback() -> None:
    t = pd.DataFrame({"x": [1, 2, 3], "chosen": [True, True, False]})

    def rules(rows: pd.DataFrame) -> dict[str, pd.Series]:
        return {"big": ("x = " + rows["x"].astype(str)).where(rows["x"] > 1, "")}

    out = ev.with_reasons(
        t, "chosen", rules, "other", lambda rows: "no rule for " + rows["x"].astype(str)
    )
    assert out["reasons"].tolist() == ["other", "big", ""]
    assert out["reason_text"].tolist() == ["no rule for 1", "x = 2.", ""]


def test_setting_labels_show_the_varying_axes() -> None:
    t = pd.DataFrame({"detector": ["fast", "orb"], "descriptor": ["brief", "brief"],
                      "matcher": ["bf", "bf"], "selector": ["knn", "knn"]})  # fmt: skip
    assert ev.setting_labels(t, ["detector", "descriptor", "matcher"]).tolist() == ["fast", "orb"]
    same = t.iloc[[0, 0]]
    assert ev.setting_labels(same, list(t.columns)).tolist() == ["fast/brief/bf/knn"] * 2


# --------------------------------------------------------------------------- FP.5


def _lidar_row(**values) -> dict:
    row = dict(frame=5, prev_frame=4, lidar_reason="ok", scan_short=False, scan_points_curr=113000,
               scan_usual=113000.0, lidar_points_curr=300, lidar_median_curr=7.8,
               d_prev=7.90, d_curr=7.84, ref_d_prev=7.92, ref_d_curr=7.86,
               lidar_closest_prev=7.88, lidar_closest_curr=7.82, est_step=0.06, raw_step=0.06,
               ref_step=0.06, anomaly_prev=0.0, anomaly_curr=0.0, lead_before=0, prev_box=0,
               curr_box=0, box_w=170, box_h=140, w_before=170.0, h_before=140.0)  # fmt: skip
    row.update(values)
    return row


def _fired(**values) -> list[str]:
    table = pd.DataFrame([_lidar_row(**values)])
    return [name for name, text in ev.lidar_rules(table).items() if text.iloc[0]]


def test_lidar_rules_fire_on_their_evidence_only() -> None:
    assert _fired() == []
    # a point 20 cm in front of the rear that the estimate followed
    assert _fired(lidar_closest_curr=7.66, d_curr=7.66, anomaly_curr=-0.2) == ["points_ahead"]
    # the same point ignored by the estimator (its distance kept its usual offset): no reason
    assert _fired(lidar_closest_curr=7.66) == []
    assert _fired(est_step=0.01) == ["noise_floor"]
    assert _fired(scan_short=True, lidar_reason="receding") == ["scan_short", "code"]
    assert _fired(prev_box=1) == ["box_switch"]
    assert _fired(box_h=175) == ["box_jump"]
    assert _fired(raw_step=0.10, est_step=0.105) == ["measured_step"]


def test_lidar_reason_texts_carry_the_numbers() -> None:
    table = pd.DataFrame([_lidar_row(est_step=0.01), _lidar_row(scan_short=True,
                          scan_points_curr=69719, scan_usual=113000.0)])  # fmt: skip
    rules = ev.lidar_rules(table)
    assert "moved only 1.0 cm" in rules["noise_floor"].iloc[0]
    assert "69719 points, 62 % of the usual scan" in rules["scan_short"].iloc[1]


def test_lidar_reasons_fall_back_to_range_noise_and_take_other_objects() -> None:
    table = pd.DataFrame([_lidar_row(), _lidar_row(), _lidar_row(frame=6, prev_frame=5)])
    table["flagged"] = [True, True, False]
    other = pd.Series(["points of another object in the box (frame 5: ...)", "", ""])
    out = ev.lidar_reasons(table, other)
    assert out["reasons"].tolist() == ["other_object", "range_noise", ""]
    assert out["reason_text"].iloc[1].startswith("range noise: the estimate moved 6.0 cm")
    assert "other_object_text" not in out


def test_lidar_runs_prefer_the_camera_setting_most_estimators_share() -> None:
    base = dict(status="ok", dataset="d", detector="fast", descriptor="brief", matcher="bf",
                selector="knn", box_matching="m", keypoint_filter="f", camera_ttc="c",
                objects="o")  # fmt: skip
    runs = pd.DataFrame([
        {**base, "run_id": "a1", "lidar_ttc": "median", "detector": "akaze"},
        {**base, "run_id": "b1", "lidar_ttc": "median"},
        {**base, "run_id": "c1", "lidar_ttc": "closest"},
        {**base, "run_id": "d1", "lidar_ttc": "cluster", "status": "failed"},
    ])  # fmt: skip
    chosen = ev.lidar_runs(runs).set_index("lidar_ttc")["run_id"].to_dict()
    assert chosen == {"closest": "c1", "median": "b1"}  # fast is shared by two, akaze by one


def _box_with_other_object() -> np.ndarray:
    """50 points of a car's rear at x ≈ 8 m and 8 points of something 1.5 m nearer."""
    rng = np.random.default_rng(0)
    rear = np.column_stack([8.0 + rng.uniform(0, 0.05, 50), rng.uniform(-0.8, 0.8, 50),
                            rng.uniform(-0.5, 0.0, 50), np.full(50, 0.3)])  # fmt: skip
    near = np.column_stack([np.full(8, 6.5), np.linspace(-0.1, 0.1, 8), np.linspace(-0.3, -0.1, 8),
                            np.full(8, 0.3)])  # fmt: skip
    return np.vstack([rear, near])


def test_other_clusters_find_the_points_off_the_rear() -> None:
    points = _box_with_other_object()
    mask, text = ev.other_clusters(points)
    assert mask.sum() == 8 and mask[50:].all()
    assert text.startswith("8 at 6.50-6.50 m beside the rear cluster at 8.00-8.05 m")
    alone, none = ev.other_clusters(points[:50])
    assert not alone.any() and none == ""


def test_other_object_moves_the_closest_point_not_the_median() -> None:
    points = _box_with_other_object()
    shift, _ = ev.other_object_effect(points, LidarTTCParams(name="closest"))
    assert shift == pytest.approx(6.5 - points[:50, 0].min())
    text = ev.other_object_text({4: points[:50], 5: points}, LidarTTCParams(name="closest"))
    assert text.startswith("points of another object in the box (frame 5: 8 at 6.50")
    assert "frame 4" not in text
    # the median of 58 points barely moves (< 1 cm): no reason
    assert ev.other_object_text({5: points}, LidarTTCParams(name="median")) == ""


def test_estimator_marks_run_every_estimator() -> None:
    points = _box_with_other_object()
    marks = ev.estimator_marks(points)
    assert marks["closest"] == pytest.approx(6.5)
    assert 8.0 < marks["median"] < 8.05
    assert all(np.isnan(d) for d in ev.estimator_marks(np.empty((0, 4))).values())


def test_most_flagged_frames_order() -> None:
    t = pd.DataFrame({"dataset": "d", "frame": [3, 3, 4, 5, 5], "lidar_ttc": list("abaab"),
                      "flagged": [True, True, True, True, False],
                      "lidar_rel_err": [0.5, np.nan, 2.0, 0.4, 9.0]})  # fmt: skip
    order = ev.most_flagged_frames(t, limit=2)
    assert order["frame"].tolist() == [3, 4]  # two estimators flagged, then the larger error
    assert order["n"].tolist() == [2, 1]


# --------------------------------------------------------------------------- FP.6


def test_camera_rules_and_fallback() -> None:
    row = dict(camera_reason="ok", camera_ratio=1.0074, ratio_expected=1.0074, ttc_camera=13.5,
               camera_false_alarm=np.nan, matches_kept=60, matches_in_box=70, matches_removed=10,
               keypoints_curr=1500, keypoint_filter="median_distance", box_w=170)  # fmt: skip
    table = pd.DataFrame(
        [
            row,
            {**row, "matches_kept": 5, "camera_ratio": 1.0005},
            {**row, "matches_removed": 40, "camera_reason": "too_few_pairs"},
        ]
    )
    fired = ev.combine_reasons(ev.camera_rules(table), table.index)["reasons"]
    assert fired.tolist() == ["", "few_matches;ratio_near_one", "too_few_pairs;many_removed"]
    assert "0.5 px" in ev.camera_fallback(table.iloc[[0]].assign(camera_ratio=1.0104)).iloc[0]


def _detail(prev_xy: np.ndarray, curr_xy: np.ndarray, roi=(0, 0, 100, 100)) -> PairDetail:
    """A pair detail whose lead box 0 keeps every match ``prev_xy[i] -> curr_xy[i]`` (pixels);
    no lane points."""
    n = len(prev_xy)
    keypoints = {p: np.zeros((n, 7)) for p in (0, 1)}
    keypoints[0][:, :2], keypoints[1][:, :2] = prev_xy, curr_xy
    idx = np.arange(n, dtype=np.int32)
    return PairDetail(
        prev=0, curr=1, images={}, keypoints=keypoints,
        objects={f: {"roi": np.array([roi]), "class_id": np.array([2]),
                     "confidence": np.array([0.9])} for f in (0, 1)},
        matches=Matches(idx, idx, np.zeros(n, np.float32)), box_matches=None,
        lane_points={f: np.empty((0, 4)) for f in (0, 1)},
        lane_uv={f: np.empty((0, 2)) for f in (0, 1)},
        lane_owner={f: np.empty(0, np.int64) for f in (0, 1)},
        lead_box=0, kept=idx, removed=idx[:0], rows=pd.DataFrame(),
    )  # fmt: skip


def test_match_geometry_sees_still_keypoints_and_leaving_matches() -> None:
    grid = np.array([[x, y] for x in (30.0, 50.0, 70.0) for y in (30.0, 50.0, 70.0)])
    still = ev.match_geometry(_detail(grid, grid), min_dist=10.0, ref_distance=8.0)
    assert (still.kept, still.still, still.exact_share, still.leaving) == (9, 9, 1.0, 0)
    texts = ev.geometry_texts(still)
    assert texts["exact_ratios"].startswith("100 % of the pair distance ratios are exactly 1")
    assert texts["leaving_object"] == "" and texts["box_edge"] == "" and texts["background"] == ""
    moved = grid + 1.0  # the box moves 1 px; three matches jump 10 px elsewhere
    moved[:3] += 10.0
    g = ev.match_geometry(_detail(grid, moved), min_dist=10.0, ref_distance=8.0)
    assert (g.still, g.leaving) == (0, 3)
    assert "3 of 9 kept matches move more than 2 px" in ev.geometry_texts(g)["leaving_object"]


def test_match_geometry_on_the_box_edge() -> None:
    edge = np.array([[1.0, 50.0], [99.0, 50.0], [50.0, 2.0], [50.0, 98.0], [50.0, 50.0]])
    g = ev.match_geometry(_detail(edge, edge * 1.01), min_dist=1.0, ref_distance=8.0)
    assert g.border == 4
    assert ev.geometry_texts(g)["box_edge"].startswith("keypoints on the box edge: 4 of 5")


def test_geometry_reasons_replace_the_scale_error_fallback() -> None:
    extra = {"box_edge": "keypoints on the box edge"}
    assert ev.with_geometry_reasons("scale_error", "scale error: r = 1.01", extra) == (
        "box_edge", "keypoints on the box edge."
    )  # fmt: skip
    assert ev.with_geometry_reasons("few_matches", "few matches: 5.", extra) == (
        "few_matches;box_edge", "few matches: 5. keypoints on the box edge."
    )  # fmt: skip
    assert ev.with_geometry_reasons("few_matches", "few.", {}) == ("few_matches", "few.")


def test_worst_order_bounds_each_detector_descriptor_pair() -> None:
    t = pd.DataFrame({
        "dataset": "d", "detector": ["fast"] * 4 + ["orb"], "descriptor": "brief",
        "setting": ["fast/bf", "fast/bf", "fast/flann", "fast/flann", "orb"],
        "frame": [1, 2, 1, 2, 1], "way_off": [True, True, True, False, True],
        "camera_rel_err": [0.6, np.nan, 0.9, 0.1, 0.7],
        "reasons": ["scale_error", "code", "few_matches", "", "scale_error"],
    })  # fmt: skip
    w = ev.worst_order(t, per_pair=2, turns="detector")
    # fast: the invalid one (NaN error) and 0.9; orb gets its turn before fast's second
    assert list(zip(w["setting"], w["frame"], strict=True)) == [
        ("fast/bf", 2), ("orb", 1), ("fast/flann", 1)
    ]  # fmt: skip


def test_pareto_front_keeps_only_undominated_points() -> None:
    ms = np.array([10.0, 5.0, 20.0, 5.0, 30.0])
    err = np.array([0.2, 0.5, 0.1, 0.4, 0.1])
    assert ev.pareto_front(ms, err).tolist() == [3, 0, 2]


# --------------------------------------------------------------------------- lead


def test_lead_box_holds_most_lane_points() -> None:
    assert ev.lead_box_of(np.array([-1, 2, 2, 0, 2, 0]), 3) == 2
    assert ev.lead_box_of(np.array([-1, -1]), 3) == -1
    assert ev.lead_box_of(np.empty(0, np.int64), 0) == -1


@pytest.mark.parametrize("dtype", ["str", object, "category"])
def test_the_text_before_a_separator_is_pandas_split_each_distinct_text_once(dtype) -> None:
    """:func:`ttc.evaluation.diagnosis.text_before` gives ``.str.split(sep).str[0]``: the same
    values (missing ones as pandas leaves them), object dtype, the index kept."""
    from ttc.evaluation.diagnosis import text_before

    values = ["a;b", "c", None, "", "x;y;z", "c", "a;b", ";lead"]
    texts = pd.Series(values, dtype=dtype, index=[f"r{i}" for i in range(len(values))])
    want = texts.astype(object if dtype == "category" else dtype).str.split(";").str[0]
    pd.testing.assert_series_equal(text_before(texts, ";"), want)
    mixed = pd.Series([1.5, "k:v", None, "k"], dtype=object)
    pd.testing.assert_series_equal(text_before(mixed, ":"), mixed.str.split(":").str[0])
    empty = pd.Series([], dtype="str")
    pd.testing.assert_series_equal(text_before(empty, ";"), empty.str.split(";").str[0])
