"""dataset=ros2_bag on a real third-party bag: the shared KITTI raw drive 0009 converted by
kitti2mcap (installed --no-deps by .ci/run: its declared opencv-python-headless would
overwrite our OpenCV), once per session, then variants of it written with the mcap writer."""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader, make_reader
from mcap_ros2.decoder import DecoderFactory

from experiments.configs.structured import (
    config_problems,
    frame_range_from_config,
    settings_from_config,
)
from tests.conftest import data_root
from tests.ros2_bags import DRIVE, IMAGE, LIDAR, bag_config, composed, make_bag, rewrite
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting
from ttc.engine.stages import FrameStages
from ttc.io.calibration import load_calibration
from ttc.io.ego_motion import pair_ego_speeds
from ttc.io.frame_errors import FrameDataError
from ttc.io.frames import frame_clock_ns, frame_files, read_lidar_scan
from ttc.io.ros2_bag import BagSource, bag_index

pytest.importorskip("kitti2mcap", reason="installed by .ci/run (--no-deps)")


@pytest.fixture(scope="session")
def bag(tmp_path_factory) -> Path:
    """Drive 0009 frames 0-15 as kitti2mcap writes it (≈ 35 MB, ≈ 2 s)."""
    return make_bag(tmp_path_factory.mktemp("bag") / "0009.mcap")


@pytest.mark.slow
def test_the_bag_gives_the_kitti_loader_s_results_on_drive_0009(bag, tmp_path) -> None:
    """Same boxes, keypoints and matches (identical pixels), lidar distances within 1 cm,
    TTCs within 2 % of dataset=kitti_raw_0009 for the same setting; frame 0's points within
    1 px of the KITTI loader's projection."""
    cache = StageCache(tmp_path / "cache")
    kitti = composed(["dataset=kitti_raw_0009"])  # and its camera pair distance:
    pair_distance = [
        f"camera_ttc.{k}={kitti.camera_ttc[k]}" for k in ("min_dist", "min_box_fraction")
    ]
    ros = bag_config(bag, *pair_distance)
    assert config_problems(ros) == []
    settings = settings_from_config(kitti)
    assert settings == settings_from_config(ros)
    ranges = [frame_range_from_config(c) for c in (kitti, ros)]
    assert [r.indices for r in ranges] == [list(range(16))] * 2
    stages = [FrameStages(settings, r, cache) for r in ranges]
    for i in range(16):
        for stage in ("objects", "keypoints"):
            a, b = (cache.get(getattr(s, stage)(i)).arrays for s in stages)
            assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a), (stage, i)
    for i in range(15):
        a, b = (cache.get(s.matches(i, i + 1)).arrays for s in stages)
        assert all(np.array_equal(a[k], b[k]) for k in a), i
    rows = [run_setting(settings, r, cache) for r in ranges]
    keys = ["prev_frame", "frame", "prev_box", "curr_box"]
    assert (
        len(rows[0]) == len(rows[1]) > 15 and not (rows[1]["lidar_reason"] == "frame_error").any()
    )
    both = rows[0].merge(rows[1], on=keys, suffixes=("_k", "_b"), validate="one_to_one")
    for col in ("box_x", "box_y", "box_w", "box_h", "matches_in_box", "box_shared_matches"):
        assert (both[f"{col}_k"] == both[f"{col}_b"]).all(), col
    # kitti2mcap's camera frame is pykitti's, moved by P03 / fx along x only, not by the
    # baseline K^-1 · P[:, 3] (conf/dataset/kitti2mcap.yaml): points move up to 0.8 px (near
    # ones at the image edge), a point on a box edge may change sides and a nearest face
    # moves by 1-2 cm (3 of 74 on frames 0-15). The folder read with P_rect_02's last column
    # cut to pykitti's (P03, 0, 0) gives the bag's distances exactly: that is all of it.
    gap = (both["object_distance_m_k"] - both["object_distance_m_b"]).abs()
    assert (
        gap.max() < 0.02 and (gap <= 0.01).sum() >= 0.9 * both["object_distance_m_k"].notna().sum()
    )
    folder_calib = load_calibration(ranges[0].sequence_dir)
    cut_p = folder_calib.p_rect.copy()
    cut_p[1:, 3] = 0.0
    pykitti_like = dataclasses.replace(folder_calib, p_rect=cut_p)
    cut = run_setting(settings, ranges[0], cache, calibration=pykitti_like)
    pd.testing.assert_series_equal(cut["object_distance_m"], rows[1]["object_distance_m"])
    k, b = both["ttc_camera_k"], both["ttc_camera_b"]
    assert (np.isfinite(k) == np.isfinite(b)).all() and (
        abs(b / k - 1)[np.isfinite(k)] < 0.02
    ).all()
    # with the KITTI files' calibration the bag's rows are the folder's: the reader is exact
    same = run_setting(
        settings, ranges[1], cache, calibration=load_calibration(ranges[0].sequence_dir)
    )
    timed = ["dt", "ego_speed_mps", "ttc_camera", "ttc_lidar", "ttc_fused"]
    kept = [c for c in rows[0].columns if c not in timed and not c.startswith(("ms_", "cached_"))]
    pd.testing.assert_frame_equal(rows[0][kept], same[kept])
    for col in ("ttc_camera", "ttc_lidar"):  # dt: camera stamps here, lidar stamps there
        k, b = rows[0][col], same[col]
        finite = np.isfinite(k)
        assert (finite == np.isfinite(b)).all() and (abs(b / k - 1)[finite] < 0.002).all()
    assert both["ttc_camera_k"].notna().sum() > 10  # parked cars: real camera TTCs compared
    speed = both["ego_speed_mps_b"] / both["ego_speed_mps_k"]
    assert speed.between(0.98, 1.02).all()  # /tf ego pose against oxts vf
    calib = [load_calibration(r.sequence_dir) for r in ranges]
    points = read_lidar_scan(frame_files(ranges[0].sequence_dir, 0).scan).points
    xyz1 = np.c_[points[:, :3], np.ones(len(points))]
    y = [xyz1 @ c.velo_to_image.T for c in calib]
    uv = [p[:, :2] / p[:, 2:] for p in y]
    inside = (y[0][:, 2] > 0) & (uv[0] >= 0).all(axis=1) & (uv[0] < [1242, 375]).all(axis=1)
    assert inside.sum() > 10_000 and np.abs(uv[0] - uv[1])[inside].max() < 1.0
    y_cut = xyz1 @ pykitti_like.velo_to_image.T  # the bag's tf quaternions lose < 0.001 px
    assert np.abs(y_cut[:, :2] / y_cut[:, 2:] - uv[1])[inside].max() < 1e-3


def test_the_ros_convention_misplaces_kitti2mcap_s_points(bag) -> None:
    """Read the ROS way (P · R · T), kitti2mcap's baseline counts twice: why kitti2mcap.yaml
    says camera_frame: rectified."""
    ros = load_calibration(BagSource(bag, camera_frame="optical")).velo_to_image
    ok = load_calibration(BagSource(bag, camera_frame="rectified")).velo_to_image
    x = np.array([10.0, 0.0, 0.0, 1.0])  # 10 m ahead of the Velodyne
    u = [(m @ x)[0] / (m @ x)[2] for m in (ros, ok)]
    assert 2.0 < u[0] - u[1] < 8.0  # baseline twice: +4.4 px at 10 m; R_rect_02: −2 px


@pytest.mark.slow
def test_a_compressed_image_bag_runs_and_one_without_tf_static_is_refused(bag, tmp_path) -> None:
    def compress(topic, name, msg):
        if topic != IMAGE:
            return name, msg
        rgb = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.width, 3)
        png = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))[1].tobytes()
        return "sensor_msgs/msg/CompressedImage", {
            "header": msg.header,
            "format": "png",
            "data": png,
        }

    small = rewrite(bag, tmp_path / "png.mcap", compress)
    cfg = bag_config(small, "dataset.last=2")
    assert config_problems(cfg) == []
    rows = run_setting(settings_from_config(cfg), frame_range_from_config(cfg), StageCache(None))
    assert set(rows["frame"]) == {1, 2} and not (rows["lidar_reason"] == "frame_error").any()
    assert rows["boxes_curr"].min() > 0

    no_tf = rewrite(
        bag, tmp_path / "no_tf.mcap", lambda t, n, m: None if t == "/tf_static" else (n, m)
    )
    problems = config_problems(bag_config(no_tf))
    assert len(problems) == 1 and "/tf_static" in problems[0] and "/kitti/imu" in problems[0]
    with pytest.raises(FrameDataError, match="/tf_static"):
        load_calibration(BagSource(no_tf))


@pytest.mark.slow
def test_a_camera_message_without_a_scan_is_a_frame_error_of_its_pairs(bag, tmp_path) -> None:
    """Scan 2 dropped: frame 2's nearest scan is 100 ms away, beyond half a period."""
    count = {"n": 0}

    def drop(topic, name, msg):
        if topic == LIDAR:
            count["n"] += 1
            if count["n"] == 3:
                return None
        return name, msg

    cut = rewrite(bag, tmp_path / "gap.mcap", drop)
    cfg = bag_config(cut, "dataset.last=3")
    assert config_problems(cfg) == []
    rows = run_setting(settings_from_config(cfg), frame_range_from_config(cfg), StageCache(None))
    errors = rows[rows["lidar_reason"] == "frame_error"]
    assert set(zip(errors["prev_frame"], errors["frame"], strict=True)) == {(1, 2), (2, 3)}
    assert len(errors) == 2 and errors["error"].str.contains("no /kitti/velodyne_points scan").all()
    assert (rows[rows["frame"] == 1]["lidar_reason"] != "frame_error").all()


@pytest.mark.slow
def test_a_lidar_frame_published_on_tf_gives_the_static_bag_s_results(bag, tmp_path) -> None:
    """base_link -> velodyne moved from /tf_static to /tf, published with each ego pose at
    its stamp (as a lidar on a moving mount is): the lidar -> camera chain now goes through
    /tf; calibration, ego speed and every row of frames 0-2 are the static bag's."""
    moved = {}

    def to_tf(topic, name, msg):
        if topic == "/tf_static":
            moved["velodyne"] = next(t for t in msg.transforms if t.child_frame_id == "velodyne")
            msg.transforms = [t for t in msg.transforms if t.child_frame_id != "velodyne"]
        elif topic == "/tf":
            lidar = moved["velodyne"]
            stamp = msg.transforms[0].header.stamp
            header = {"stamp": stamp, "frame_id": lidar.header.frame_id}
            msg.transforms.append(
                {"header": header, "child_frame_id": "velodyne", "transform": lidar.transform}
            )
        return name, msg

    on_tf = rewrite(bag, tmp_path / "on_tf.mcap", to_tf)
    with on_tf.open("rb") as f:
        static = [d for *_, d in make_reader(f, decoder_factories=[DecoderFactory()])
                  .iter_decoded_messages(topics=["/tf_static"])]  # fmt: skip
    assert [t.child_frame_id for t in static[0].transforms] == ["camera_color_left"]
    a, b = (load_calibration(BagSource(p, camera_frame="rectified")) for p in (bag, on_tf))
    assert np.array_equal(a.velo_to_image, b.velo_to_image)
    rows = []
    for path in (bag, on_tf):
        cfg = bag_config(path, "dataset.last=2")
        assert config_problems(cfg) == []
        rows.append(
            run_setting(settings_from_config(cfg), frame_range_from_config(cfg), StageCache(None))
        )
    kept = [c for c in rows[0].columns if not c.startswith(("ms_", "cached_"))]
    assert len(rows[0]) > 4 and rows[0]["ego_speed_mps"].between(1.0, 30.0).all()
    pd.testing.assert_frame_equal(rows[0][kept], rows[1][kept])


def test_ego_speed_from_an_odometry_topic_is_the_tf_pose_s(bag, tmp_path) -> None:
    """The ego pose as nav_msgs/msg/Odometry on /odom instead of /tf (each map -> base_link
    transform as a pose, same stamp): every pair's ego_speed_mps of frames 0-15 is the /tf
    bag's within 2 %, and the oxts speed of the KITTI folder within 2 %."""

    def to_odometry(topic, name, msg):
        if topic != "/tf":
            return name, msg
        (t,) = msg.transforms
        v, q = t.transform.translation, t.transform.rotation
        pose = {"position": {"x": v.x, "y": v.y, "z": v.z}, "orientation": q}
        odom = {"header": t.header, "child_frame_id": t.child_frame_id, "pose": {"pose": pose}}
        return [("/odom", "nav_msgs/msg/Odometry", odom)]

    odometry = rewrite(bag, tmp_path / "odom.mcap", to_odometry)
    index = bag_index(odometry)
    assert "/tf" not in index.topics and index.of_type("nav_msgs/msg/Odometry") == ["/odom"]
    pairs = pd.DataFrame({"prev_frame": range(15), "frame": range(1, 16)})
    speeds = [pair_ego_speeds(BagSource(p), None, pairs) for p in (bag, odometry)]
    folder = data_root() / DRIVE
    oxts = pair_ego_speeds(folder, frame_clock_ns(folder), pairs)
    assert np.isfinite(speeds[1]).all() and (speeds[1] > 1.0).all()
    assert np.allclose(speeds[1], speeds[0], rtol=0.02) and np.allclose(speeds[1], oxts, rtol=0.02)


@pytest.mark.slow
def test_a_bag_cut_short_is_read_up_to_its_last_whole_message(bag, tmp_path) -> None:
    """Cut in the middle of the chunk holding scan 3, as a recorder killed mid-write leaves
    it (no summary, no index): camera messages 0-3 are whole, so frames 0-3 are the
    recording; frame 3 lost its scan: pair (2, 3) is a frame_error, pairs (0, 1) and (1, 2)
    are the whole bag's; a frame past the cut is not in the range (dataset.last=4 refused)."""
    with bag.open("rb") as f:
        summary = make_reader(f).get_summary()
    lidar = {c.id for c in summary.channels.values() if c.topic == LIDAR}
    chunk = [c for c in summary.chunk_indexes if lidar & c.message_index_offsets.keys()][3]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bag.read_bytes()[: chunk.chunk_start_offset + chunk.chunk_length // 2])
    whole = []  # what the mcap library's streaming reader reads before the cut
    with cut.open("rb") as f, contextlib.suppress(EndOfFile):
        for _, channel, _ in NonSeekingReader(f).iter_messages(log_time_order=False):
            whole.append(channel.topic)
    assert whole.count(IMAGE) == 4 and whole.count(LIDAR) == 3

    cfg = bag_config(cut, "dataset.last=null")
    with pytest.warns(RuntimeWarning) as caught:
        assert config_problems(cfg) == []
    assert [str(w.message).count(str(cut)) for w in caught] == [1]
    assert f"read its {len(whole)} whole messages" in str(caught[0].message)
    frames = frame_range_from_config(cfg)
    assert frames.indices == [0, 1, 2, 3]
    rows = run_setting(settings_from_config(cfg), frames, StageCache(None))
    errors = rows[rows["lidar_reason"] == "frame_error"]
    assert (
        set(errors["frame"]) == {3}
        and (rows[rows["frame"] == 3]["lidar_reason"] == "frame_error").all()
    )
    assert errors["error"].str.contains(f"no {LIDAR} scan").all()
    full = bag_config(bag, "dataset.last=2")
    expected = run_setting(
        settings_from_config(full), frame_range_from_config(full), StageCache(None)
    )
    kept = [
        "prev_frame",
        "frame",
        "prev_box",
        "curr_box",
        "object_distance_m",
        "ttc_lidar",
        "ttc_camera",
    ]
    pd.testing.assert_frame_equal(
        rows[rows["frame"] < 3][kept].reset_index(drop=True), expected[kept].reset_index(drop=True)
    )
    problems = config_problems(bag_config(cut, "dataset.last=4"))
    assert len(problems) == 1 and "past the recording's last frame" in problems[0]


@pytest.mark.slow
def test_bad_bags_are_refused_with_one_message_naming_the_file_or_topic(bag, tmp_path) -> None:
    stub = tmp_path / "stub.mcap"  # cut inside the first chunk: not one whole message
    stub.write_bytes(bag.read_bytes()[:500_000])
    problems = config_problems(bag_config(stub))
    assert len(problems) == 1 and str(stub) in problems[0] and "no whole message" in problems[0]

    def no_xyz(topic, name, msg):
        if topic == LIDAR:
            for field in msg.fields:
                field.name = {"x": "a", "y": "b", "z": "c"}.get(field.name, field.name)
        return name, msg

    problems = config_problems(bag_config(rewrite(bag, tmp_path / "xyz.mcap", no_xyz)))
    assert len(problems) == 1 and LIDAR in problems[0] and "x, y, z" in problems[0]

    def wider(topic, name, msg):
        if topic.endswith("camera_info"):
            msg.width = 1240
        return name, msg

    problems = config_problems(bag_config(rewrite(bag, tmp_path / "size.mcap", wider)))
    assert len(problems) == 1 and IMAGE in problems[0] and "1242 × 375" in problems[0]


def test_a_run_on_the_bag_reads_the_scan_frames_of_the_folder(bag) -> None:
    """Sanity of the pairing: every frame's scan is the drive's scan of the same index."""
    source = frame_range_from_config(bag_config(bag)).sequence_dir
    raw = data_root() / DRIVE
    for i in (0, 7, 15):
        a = read_lidar_scan(frame_files(source, i).scan).points
        assert np.array_equal(a, read_lidar_scan(frame_files(raw, i).scan).points)
