"""Every object judged (issue 30): each box's own lidar points, tracks, a reference per
object, ``reference_objects.csv`` and the lead left as it was. Real frames: drive 0009 frames
0–15 (parked cars on both sides, the ego at ≈ 10.7 m/s), drive 0052 frames 0–18."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir

from experiments.configs.structured import (
    frame_range_from_config,
    register_configs,
    settings_from_config,
)
from experiments.report.objects_report import reference_objects_table
from experiments.summary.references import recording_boxes
from tests.conftest import PROJECT_ROOT
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting
from ttc.evaluation.object_reference import REFERENCE_OBJECT_COLUMNS, object_reference
from ttc.steps.object_lidar import ObjectLidarParams, associate_objects, object_scan_mask
from ttc.steps.tracks import chain_tracks

DRIVE_0009 = "kitti_raw/2011_09_26/2011_09_26_drive_0009_sync"
FRAMES_0009 = 15  # last frame of drive 0009 these tests mean


def composed(overrides: list[str]):
    register_configs()
    with initialize_config_dir(config_dir=str(PROJECT_ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


# --- synthetic: exact checks ------------------------------------------------------------


def _face(x: float, y: tuple[float, float], z: tuple[float, float], step: float = 0.05):
    """Points on a vertical plane at forward distance ``x`` (m)."""
    ys, zs = np.meshgrid(np.arange(*y, step), np.arange(*z, step))
    return np.c_[np.full(ys.size, x), ys.ravel(), zs.ravel()]


def _side(x: tuple[float, float], y: float, z: tuple[float, float], step: float = 0.05):
    """Points on a vertical plane along the forward axis at lateral offset ``y`` (m)."""
    xs, zs = np.meshgrid(np.arange(*x, step), np.arange(*z, step))
    return np.c_[xs.ravel(), np.full(xs.size, y), zs.ravel()]


#: An identity camera looking along the lidar's x axis: u = 600 − 600 y / x, v = 200 − 600 z / x.
CAMERA = np.array([[600.0, -600.0, 0.0, 0.0], [200.0, 0.0, -600.0, 0.0], [1.0, 0.0, 0.0, 0.0]])


def test_the_nearest_face_of_a_car_with_a_car_and_a_wall_behind_it() -> None:
    """A box-shaped car 10 m ahead (rear face and side), another car 14 m and a wall 25 m
    behind it inside the same image box, and the road: the nearest face within 2 cm, none of
    the background points kept, one projection for all boxes."""
    rng = np.random.default_rng(0)
    car = np.r_[_face(10.0, (-0.9, 0.9), (-1.3, -0.2)), _side((10.0, 14.0), -0.9, (-1.3, -0.2))]
    car[:, 0] += rng.normal(0, 0.01, len(car))  # 1 cm range noise
    other = _face(15.5, (-1.2, 1.2), (-1.3, 0.0))
    wall = _face(25.0, (-4.0, 4.0), (-1.3, 0.9))
    road = np.c_[rng.uniform(4, 30, 3000), rng.uniform(-3, 3, 3000), np.full(3000, -1.73)]
    cloud = np.r_[car, other, wall, road]
    kind = np.repeat([0, 1, 2, 3], [len(car), len(other), len(wall), len(road)])
    keep = object_scan_mask(cloud, ObjectLidarParams())
    assert not keep[kind == 3].any()  # the road is below the height band
    roi = np.array([[526.0, 205.0, 160.0, 80.0]])  # the car's face: u 546–654, v 212–278 px
    found = associate_objects(cloud[keep], CAMERA, roi, 0.10)
    mine = kind[keep][found.owner == 0]
    assert len(mine) > 100 and set(mine.tolist()) == {0}
    assert abs(found.distance_m[0] - 10.0) <= 0.02
    assert found.n_frustum[0] > found.n_points[0]  # the background was in the frustum


def test_a_nearer_object_keeps_its_points_from_the_box_behind_it() -> None:
    """Two overlapping boxes: the near car's points go to the near box only; the far box gets
    the far car's own points (boxes are resolved nearest first)."""
    near = _face(8.0, (-0.5, 0.5), (-1.2, -0.3))
    far = _face(20.0, (-1.8, 0.2), (-1.2, -0.3))
    cloud = np.r_[near, far]
    roi = np.array([[520.0, 190.0, 160.0, 90.0], [580.0, 210.0, 120.0, 40.0]])
    found = associate_objects(cloud, CAMERA, roi, 0.0)
    assert found.distance_m[0] == pytest.approx(8.0, abs=0.01)
    assert found.distance_m[1] == pytest.approx(20.0, abs=0.01)
    assert not (found.owner[: len(near)] == 1).any()
    assert (found.owner[len(near) :][found.owner[len(near) :] >= 0] == 1).all()


def test_tracks_chain_box_matches_and_end_where_a_box_is_not_matched() -> None:
    prev_frame = np.array([0, 0, 1, 1, 2, 2])
    frame = np.array([1, 1, 2, 2, 3, 3])
    prev_box = np.array([0, 1, 1, -1, 0, 1])
    curr_box = np.array([1, 0, 0, 1, 1, -1])
    ids = chain_tracks(prev_frame, frame, prev_box, curr_box)
    # 0:0 → 1:1 → 2:0 → 3:1; 0:1 → 1:0, not matched on; 2:1 starts; no current box: −1
    assert ids.tolist() == [0, 1, 0, 2001, 0, -1]


# --- real drive 0009 --------------------------------------------------------------------


def _oxts_columns(seq: Path) -> list[str]:
    """The oxts packet's column names, in order (the raw layout's dataformat.txt)."""
    lines = (seq / "oxts" / "dataformat.txt").read_text().splitlines()
    return [line.split(":")[0].strip() for line in lines if line.strip()]


def _oxts_forward_speed(seq: Path, frames: range) -> np.ndarray:
    """``vf`` (m/s) of the oxts packet of each frame (the raw layout's data/NNNNNNNNNN.txt)."""
    column = _oxts_columns(seq).index("vf")
    return np.array([
        float((seq / "oxts" / "data" / f"{i:010d}.txt").read_text().split()[column])
        for i in frames
    ])  # fmt: skip


@pytest.fixture(scope="module")
def reference_0009(data_dir: Path, tmp_path_factory) -> pd.DataFrame:
    cfg = composed(["dataset=kitti_raw_0009", f"dataset.last={FRAMES_0009}"])
    cache = StageCache(tmp_path_factory.mktemp("cache"))
    seq = data_dir / DRIVE_0009
    boxes, times, width = recording_boxes(seq, settings_from_config(cfg), cache)
    vf = _oxts_forward_speed(seq, range(len(boxes["frame"].unique())))
    ego = np.full(len(times), np.nan)
    ego[: len(vf)] = vf
    return object_reference(boxes, times, width, ego).assign(recording="drive 0009")


def test_parked_cars_are_tracked_static_and_close_at_the_ego_speed(reference_0009, data_dir):
    """Drive 0009 frames 0–15: the parked cars are tracked over ≥ 8 consecutive pairs, every
    box of theirs has lidar points, their role is ``static`` and their reference closing
    speed is within 5 % of the oxts forward speed."""
    ref = reference_0009
    vf = _oxts_forward_speed(data_dir / DRIVE_0009, range(FRAMES_0009 + 1))
    assert 10.0 < vf.mean() < 11.5
    spans = ref.groupby("track_id")["frame"].agg(["min", "max", "size"])
    spans["distance"] = ref.groupby("track_id")["distance_raw_m"].median()
    long = spans[(spans["size"] >= 9) & (spans["max"] - spans["min"] == spans["size"] - 1)]
    assert len(long) >= 5, spans
    long = long[long["distance"] < 40]  # a car 42-45 m ahead has 0-11 points a scan
    assert len(long) >= 4, spans  # 4 cars 3-35 m ahead over 10-13 frames
    for tid in long.index:
        track = ref[ref["track_id"] == tid]
        assert (track["object_points"] > 0).all(), track
        assert (track["role"] == "static").all()
        judged = track[track["judgeable"]]
        closing = judged["closing_speed_mps"].median()
        ego = vf[judged["frame"].to_numpy()].mean()
        assert abs(closing - ego) <= 0.05 * ego, (tid, closing, ego)


def _oxts_planar_poses(seq: Path, frames: range) -> tuple[np.ndarray, np.ndarray]:
    """Ego position (F × 2, m, Mercator east/north scaled at the first packet) and yaw (F,
    rad) of each frame's oxts packet: the raw layout's lat, lon (degrees) and yaw columns."""
    names = _oxts_columns(seq)
    cols = [names.index(c) for c in ("lat", "lon", "yaw")]
    packets = np.array([
        [float(v) for v in (seq / "oxts" / "data" / f"{i:010d}.txt").read_text().split()]
        for i in frames
    ])[:, cols]  # fmt: skip
    lat, lon = np.radians(packets[:, 0]), np.radians(packets[:, 1])
    scale = 6378137.0 * np.cos(lat[0])
    east, north = scale * lon, scale * np.log(np.tan(np.pi / 4 + lat / 2))
    return np.c_[east, north], packets[:, 2]


def test_nearest_faces_of_parked_cars_follow_the_ego_motion(reference_0009, data_dir) -> None:
    """A parked car does not move: its reference nearest face (forward distance, with its
    bearing for the lateral offset) put into the world by the oxts pose of each frame lands on
    one spot. Against that spot, the reference distance of the parked cars with >= 20 points and
    a nearest face >= 3 m ahead (the cars the human labels judge) is within 15 cm on >= 90 % of
    their frames (measured: 32 of 35, 31 of 34 before issue 50's object lidar; the rest: one
    car's last frames at 30-34 deg bearing)."""
    ref = reference_0009
    seq = data_dir / DRIVE_0009
    position, yaw = _oxts_planar_poses(seq, range(FRAMES_0009 + 1))
    judged = ref[(ref["role"] == "static") & (ref["object_points"] >= 20)
                 & (ref["distance_raw_m"] >= 3) & ref["distance_m"].notna()]  # fmt: skip
    errors = []
    for _, car in judged.groupby("track_id"):
        f = car["frame"].to_numpy()
        x = car["distance_m"].to_numpy()
        y = x * np.tan(np.radians(car["bearing_deg"].to_numpy()))
        c, s = np.cos(yaw[f]), np.sin(yaw[f])
        world = position[f] + np.c_[c * x - s * y, s * x + c * y]
        spot = np.median(world, axis=0)
        expected = c * (spot[0] - position[f, 0]) + s * (spot[1] - position[f, 1])
        errors += np.abs(x - expected).tolist()
    errors = np.array(errors)
    assert len(errors) >= 25, judged  # 7 parked cars, 35 frames
    assert (errors <= 0.15).mean() >= 0.9, np.sort(errors)


def test_reference_objects_csv_has_the_documented_columns(reference_0009) -> None:
    table = reference_objects_table(reference_0009)
    assert tuple(table.columns) == REFERENCE_OBJECT_COLUMNS
    assert (table["recording"] == "drive 0009").all()
    assert table["box_w"].gt(0).all() and table["track_id"].ge(0).all()
    near = table[(table["distance_m"] >= 3) & table["ttc_ref_s"].notna()]
    assert (near["ttc_ref_s"] < 6).mean() > 0.5  # the range never judged before


# --- drive 0052: the lead as it was -----------------------------------------------------


def test_the_lead_of_drive_0052_is_unchanged_against_the_committed_report() -> None:
    """``results/kitti_0_18/fp6_camera_ttc.csv`` (the committed report) holds the lead's
    camera TTC of akaze/akaze/bf/knn on frames 0–18: a run now gives the same values."""
    committed = pd.read_csv(PROJECT_ROOT / "results/kitti_0_18/fp6_camera_ttc.csv")
    mine = committed[committed["setting"] == "akaze/akaze/bf/knn"].set_index("frame")
    cfg = composed(["dataset=kitti_0_18", "detector=akaze", "descriptor=akaze", "matcher=bf",
                    "selector=knn"])  # fmt: skip
    rows = run_setting(settings_from_config(cfg), frame_range_from_config(cfg), StageCache(None))
    lead = rows[rows["is_lead"]].set_index("frame")
    np.testing.assert_allclose(
        lead.loc[mine.index, "ttc_camera"], mine["ttc_camera"], rtol=1e-5, equal_nan=True
    )
    assert (lead["track_id"] >= 0).all()
    non_lead = rows[~rows["is_lead"] & (rows["prev_box"] >= 0)]
    assert (non_lead["object_points"] > 0).any()  # other boxes now have their own points


# --- the camera remedy and the all-object ranking: exact checks -------------------------


def test_vertical_ratio_is_exact_on_a_side_surface_where_median_ratio_is_not() -> None:
    """A car's side seen obliquely: points along it at depths 10–14 m, the ego 1 m closer in
    the current frame. Vertical pairs (one depth) scale exactly with their depth; the pair
    distances across depths do not scale like any one depth."""
    from ttc.steps.camera_ttc import CameraTTCParams, camera_ttc, vertical_ratios

    f, lateral = 700.0, -3.0
    depth = np.repeat(np.arange(10.0, 14.01, 0.5), 2)  # two heights per depth
    height = np.tile([-0.5, 0.5], len(depth) // 2)

    def project(z):
        return np.c_[600 - f * lateral / z, 200 - f * height / z]

    prev, curr = project(depth + 1.0), project(depth)
    truth = (depth + 1.0) / depth  # each point's own depth ratio: 1.071-1.1
    ratios = vertical_ratios(prev, curr, 1.0)
    assert len(ratios) >= len(depth) // 2  # at least the pair above one another at each depth
    assert truth.min() - 1e-12 <= ratios.min() and ratios.max() <= truth.max() + 1e-12
    vertical = camera_ttc(prev, curr, 0.1, CameraTTCParams(name="vertical_ratio", min_dist=1.0))
    distance = camera_ttc(prev, curr, 0.1, CameraTTCParams(name="median_ratio", min_dist=1.0))
    assert truth.min() <= vertical.ratio <= truth.max()
    assert distance.ratio > truth.max()  # across depths, distances grow faster than any depth


def test_the_all_object_ranking_takes_tracks_as_bootstrap_blocks() -> None:
    """Two settings over three tracks: ``a`` better on every pair ranks first with an interval
    [1, 1]; the score is the mean capped error (an invalid estimate 1)."""
    from ttc.evaluation.object_errors import track_bootstrap_ranks

    judged = pd.DataFrame({
        "setting": ["a"] * 6 + ["b"] * 6,
        "ref_track_id": [1, 1, 2, 2, 3, 3] * 2,
        "camera_score": [0.1, 0.1, 0.2, 0.2, 0.0, 0.0, 1.0, 0.5, 0.3, 0.3, 0.2, 0.2],
        "judged": True,
    })  # fmt: skip
    out = track_bootstrap_ranks(judged, n_boot=200)
    assert out["setting"].tolist() == ["a", "b"]
    assert out["score"].tolist() == pytest.approx([0.1, 2.5 / 6])
    assert out.loc[0, ["rank", "rank_lo", "rank_hi"]].tolist() == [1, 1, 1]


def test_bootstrap_ranks_are_pandas_min_ranks() -> None:
    """:func:`ttc.evaluation.object_errors.min_ranks` ranks each replicate as pandas does
    (``method="min"``): ties (0.0 and -0.0 among them) share their least rank, settings a
    replicate did not draw (+inf) rank last together, NaN stays NaN."""
    from ttc.evaluation.object_errors import min_ranks

    rng = np.random.default_rng(0)
    scores = rng.integers(0, 30, (200, 60)).astype(float)
    scores[scores > 26] = np.inf
    scores[scores == 3] = -0.0
    scores[scores == 4] = 0.0
    want = pd.DataFrame(scores).rank(axis=1, method="min").to_numpy()
    assert np.array_equal(min_ranks(scores), want)
    assert min_ranks(np.zeros((0, 5))).shape == (0, 5)
    scores[1, 2] = np.nan
    want = pd.DataFrame(scores).rank(axis=1, method="min").to_numpy()
    assert np.array_equal(min_ranks(scores), want, equal_nan=True)
