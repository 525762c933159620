"""``dataset=kitti_odometry`` on the shared sequence 04 (frames 0–40, official odometry
layout): the lidar sees the lead van where measured (22.1 m at frame 0, 20.5 m at 40), the
YOLO box of the van holds its projected points (``P2 · Tr``), ``dt`` is the ``times.txt``
difference, and a bad ``calib.txt`` names the file and key."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from experiments.configs.structured import (
    config_problems,
    frame_range_from_config,
    register_configs,
    run_id,
    settings_from_config,
)
from tests.conftest import PROJECT_ROOT
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting
from ttc.evaluation.lead_distance import rear_distance
from ttc.features.objects import ObjectDetectorParams, detect_objects
from ttc.io.calibration import load_calibration
from ttc.io.ego_motion import EGO_SPEED
from ttc.io.frames import FrameDataError, load_frame, read_frame_times
from ttc.steps.box_matching import points_in_rois
from ttc.steps.lidar import project_to_image


@pytest.fixture(scope="module")
def seq(data_dir: Path) -> Path:
    path = data_dir / "kitti_odometry" / "sequences" / "04"
    if not path.is_dir():
        pytest.fail(f"{path} not found (README of the data: kitti_odometry/)")
    return path


def van_points(points: np.ndarray) -> np.ndarray:
    """In-lane points above the ground, 5–40 m ahead: the van is the nearest object there."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    lane = points[(np.abs(y) < 1.0) & (x > 5) & (x < 40) & (z > -1.4)]
    return lane[lane[:, 0] < lane[:, 0].min() + 1.0]  # its rear, 1 m deep


@pytest.mark.parametrize(("frame", "metres"), [(0, 22.1), (40, 20.5)])
def test_the_lidar_sees_the_van_where_measured(seq, frame, metres) -> None:
    van = van_points(load_frame(seq, frame).scan.points)
    assert len(van) > 100
    assert rear_distance(van) == pytest.approx(metres, abs=0.10)


@pytest.mark.parametrize("frame", [0, 40])
def test_the_lead_box_holds_the_vans_projected_points(seq, frame) -> None:
    loaded = load_frame(seq, frame)
    calib = load_calibration(seq)
    assert loaded.image.shape == (370, 1226, 3) and calib.image_size == (1226, 370)
    uv = project_to_image(van_points(loaded.scan.points)[:, :3], calib.velo_to_image)
    boxes = detect_objects(loaded.image, ObjectDetectorParams()).roi
    inside = points_in_rois(uv, boxes)  # (points, boxes)
    best = int(np.argmax(inside.sum(axis=0)))
    # YOLO's box (37-46 px) is tighter than the van's lidar outline (roof, mirrors): it holds
    # the centre of the van's points and a good share of them, and no other box holds any.
    assert inside[:, best].mean() > 0.3
    assert points_in_rois(np.median(uv, axis=0)[None], boxes[best : best + 1]).all()
    assert inside.sum(axis=0).tolist().count(0) == len(boxes) - 1
    assert 30 <= boxes[best][2] <= 60  # the van's 37–46 px wide box


def composed(overrides: list[str]):
    register_configs()
    with initialize_config_dir(config_dir=str(PROJECT_ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def test_dt_is_the_times_txt_difference_and_ego_speed_from_the_poses(seq) -> None:
    cfg = composed(["dataset=kitti_odometry", "dataset.last=3"])
    assert config_problems(cfg) == []
    assert cfg.dataset.sequence == "kitti_odometry/sequences/04"
    rows = run_setting(settings_from_config(cfg), frame_range_from_config(cfg), StageCache(None))
    times = [float(line) for line in (seq / "times.txt").read_text().split()]
    assert len(times) == 271 and len(read_frame_times(seq)) == 271
    expected = rows["frame"].map(lambda k: round(times[k] - times[k - 1], 9))
    np.testing.assert_array_equal(rows["dt"], expected)
    assert sorted(rows["frame"].unique()) == [1, 2, 3]
    assert rows[EGO_SPEED].between(12.5, 14.0).all()  # the data README: 12.6–13.7 m/s
    whole = composed(["dataset=kitti_odometry"])
    assert frame_range_from_config(whole).last == 40  # last: null = the last frame on disk
    assert run_id(whole) != run_id(cfg)


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (lambda t: t.replace("Tr:", "Tx:"), "missing entry 'Tr'"),
        (lambda t: t.replace("P2: 7.070912000000e+02", "P2: 7.07O912e+02"), "'P2' has a non-numeric value '7.07O912e+02'"),
    ],
)  # fmt: skip
def test_calibration_errors_name_the_file_and_key(seq, tmp_path, edit, problem) -> None:
    copy = tmp_path / "sequences" / "04"
    copy.mkdir(parents=True)
    (copy / "image_2").symlink_to(seq / "image_2")
    shutil.copy(seq / "calib.txt", copy / "calib.txt")
    (copy / "calib.txt").write_text(edit((copy / "calib.txt").read_text()))
    with pytest.raises(FrameDataError) as info:
        load_calibration(copy)
    assert str(info.value) == f"{copy / 'calib.txt'}: {problem}"


def test_the_reference_covers_every_frame_of_an_odometry_sequence(seq, tmp_path) -> None:
    """The reference (summary, report) finds the frames of the odometry layout (it counted
    files under velodyne_points/data only and raised)."""
    from experiments.summary.references import sequence_reference

    reference = sequence_reference(seq, StageCache(tmp_path))
    assert reference["frame"].tolist() == list(range(41))
    assert np.isfinite(reference["time_s"]).all()


def test_the_reference_follows_the_van_and_finds_no_lead_on_drive_0009(
    seq, data_dir, tmp_path
) -> None:
    """The reference's crop reaches the van 22 m ahead (the Udacity 20 m found no lead on 40
    of 41 frames) and still finds nothing ahead on drive 0009."""
    from experiments.summary.references import sequence_reference

    reference = sequence_reference(seq, StageCache(tmp_path)).set_index("frame")
    assert (reference["lead"] == "ok").sum() >= 40
    assert reference.loc[0, "distance_m"] == pytest.approx(22.1, abs=0.1)
    judged = reference["judgeable"] & np.isfinite(reference["ttc_ref_s"])
    assert judged.sum() >= 10 and (reference.loc[judged, "ttc_ref_s"] > 24).all()
    drive = data_dir / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0009_sync"
    empty = sequence_reference(drive, StageCache(tmp_path))
    assert (empty["lead"] == "no_lead").all() and not empty["judgeable"].any()


def test_the_recordings_own_settings_find_the_van_on_every_pair(seq) -> None:
    """``dataset=kitti_odometry`` sets its lidar crop (its YAML says why) and keeps every
    recording's camera pair rule (a fraction of the box width): with drive 0052's crop and
    the rubric's 100 px (20 m, z ≤ −0.9 m) the van was the lead on 9 of 40 pairs and no camera
    pair qualified; with its own crop it is the lead on every pair, its lidar rear is where
    measured, and the camera finds pairs in its 37-46 px box."""
    cfg = composed(["dataset=kitti_odometry", "dataset.last=10"])
    assert (cfg.lidar.crop.max_x, cfg.lidar.crop.max_z) == (40.0, 0.0)
    assert cfg.camera_ttc == composed(["dataset.last=10"]).camera_ttc  # no rule of its own
    assert cfg.camera_ttc.min_box_fraction > 0
    rows = run_setting(settings_from_config(cfg), frame_range_from_config(cfg), StageCache(None))
    lead = rows[rows["is_lead"]].set_index("frame")
    assert lead.index.tolist() == list(range(1, 11))
    assert lead["d_curr"].between(21.9, 22.4).all()  # 22.1 m at frame 0 (lidar, measured)
    assert (lead["lidar_points_curr"] >= 50).all()
    assert (lead["box_w"] < 60).all() and (lead["camera_pairs"] > 0).all()
    udacity = composed(["dataset=kitti_odometry", "dataset.last=10", "lidar.crop.max_z=-0.9",
                        "lidar.crop.max_x=20", "+camera_pairs=rubric"])  # fmt: skip
    old = run_setting(settings_from_config(udacity), frame_range_from_config(udacity),
                      StageCache(None))  # fmt: skip
    assert not old["is_lead"].any()
    assert composed(["lidar.crop.max_x=30", "dataset=kitti_odometry"]).lidar.crop.max_x == 30
    default = composed([])  # drive 0052's crop stays
    assert (default.lidar.crop.max_x, default.lidar.crop.max_z) == (20.0, -0.9)
