"""A far box's lidar that does not flip (issue 50, item 5): depth groups that widen with range,
the object chosen by discounted support, and a nearest face that says when it is unsure.
Synthetic frusta for exact checks; drive 0009's real scans and YOLOv3-tiny boxes (frames
13–14, the 19-px box 31–34 m ahead the issue names) and its kitti2mcap bag for the rest."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from experiments.configs.structured import (
    config_problems,
    frame_range_from_config,
    settings_from_config,
)
from experiments.data import weights
from experiments.host import paths
from tests.ros2_bags import bag_config, composed, make_bag
from ttc.engine.cache import StageCache
from ttc.engine.stages import FrameStages
from ttc.features.model_files import SSD_MODEL, SSD_MODEL_DIR_ENV
from ttc.io.calibration import load_calibration
from ttc.io.frames import frame_files, read_lidar_scan
from ttc.steps.object_face import face_sensitivity
from ttc.steps.object_groups import depth_groups, nearest_face, object_group
from ttc.steps.object_lidar import ObjectLidarParams, associate_objects, object_scan_mask

PARAMS = ObjectLidarParams()
#: The options of ``objects`` the bag-and-folder test runs with: YOLOv3-tiny (the default)
#: and SSD-MobileNetV2 on its tiles, which boxes most far cars (4 s and 9 s here).
OBJECTS = ["yolov3_tiny", "ssd_mobilenet_v2"]

# --- synthetic: exact checks ------------------------------------------------------------


def test_a_far_cars_coarsely_sampled_side_is_one_group_and_two_near_cars_are_two() -> None:
    """Returns along a car's side 30 m ahead lie 0.6 m apart in x (HDL-64E azimuth steps seen
    obliquely): one group with the range-scaled gap (1.1 m there), four with a fixed 0.5 m.
    Two cars 10 m ahead with 1 m between them stay two groups (the gap there is 0.7 m)."""
    side = np.array([30.0, 30.6, 31.2, 31.8, 32.4])
    starts, _ = depth_groups(side, PARAMS)
    assert len(starts) == 1
    fixed = ObjectLidarParams(gap_per_m=0.0)
    assert len(depth_groups(side, fixed)[0]) == len(side)
    two = np.r_[np.linspace(10.0, 10.3, 20), np.linspace(11.3, 11.5, 20)]
    starts, stops = depth_groups(two, PARAMS)
    assert starts.tolist() == [0, 20] and stops.tolist() == [20, 40]


def test_a_post_in_front_of_a_car_does_not_take_its_box_and_a_far_wall_does_not_either() -> None:
    """Drive 0009 frame 13's geometry: 5 returns of a post 31.5 m ahead, 17 of the car 2.5 m
    behind it in the same box: the car is the object (the nearest-group rule took the post).
    A wall 10 m behind a car with 4 times the car's points does not take the car's box (with
    more than 5 times the car is under ``min_fraction`` of the largest group, as before)."""
    post = np.linspace(31.5, 31.6, 5)
    car = np.linspace(34.0, 34.2, 17)
    xs = np.r_[post, car]
    assert object_group(xs, PARAMS) == (5, 22)
    assert object_group(xs, ObjectLidarParams(support_scale_m=0.0)) == (0, 5)
    wall = np.linspace(44.0, 44.3, 4 * len(car))
    assert object_group(np.r_[car, wall], PARAMS) == (0, len(car))


def _brute_force(xs: np.ndarray, params: ObjectLidarParams) -> np.ndarray:
    """The object's face (m) with each point of ``xs`` (sorted) left out, one by one."""
    faces = []
    for i in range(len(xs)):
        rest = np.delete(xs, i)
        found = object_group(rest, params)
        faces.append(nearest_face(rest[found[0] : found[1]]) if found else np.nan)
    return np.asarray(faces)


def _let_in_brute_force(xs: np.ndarray, params, values: np.ndarray) -> np.ndarray:
    """The object's face (m) with each of ``values`` let in among ``xs`` (sorted), one by one."""
    faces = []
    for v in values:
        more = np.sort(np.r_[xs, v])
        found = object_group(more, params)
        faces.append(nearest_face(more[found[0] : found[1]]) if found else np.nan)
    return np.asarray(faces)


def test_the_faces_with_one_point_left_out_or_let_in_are_exact() -> None:
    """:func:`face_sensitivity` leaves out (lets in) only the points that can change the face
    and lets one stand for the others of its group: on 300 random frusta of 1–4 objects with
    30 points just outside the box, its jackknife sd equals the brute-force one (every point
    left out in turn) and it is unsure exactly when the brute force says so (a point out or in
    moves the face by more than ``unsure_m`` or loses it, or a runner-up scores >= 2/3)."""
    rng = np.random.default_rng(50)
    tried = 0
    for _ in range(300):
        parts = [
            rng.normal(rng.uniform(5, 50), rng.uniform(0.01, 0.8), rng.integers(1, 40))
            for _ in range(rng.integers(1, 5))
        ]
        xs = np.sort(np.concatenate(parts))
        edge = rng.choice(np.r_[xs, rng.uniform(4, 52, 10)], 30) + rng.normal(0, 0.05, 30)
        found = object_group(xs, PARAMS)
        sd, unsure = face_sensitivity(xs, PARAMS, edge)
        if found is None:
            assert np.isnan(sd) and unsure
            continue
        tried += 1
        faces = _brute_force(xs, PARAMS)
        kept = faces[~np.isnan(faces)]
        if len(kept):  # else every point left out loses the object: NaN
            n = len(xs)
            want = np.sqrt((n - 1) / n * np.sum((kept - kept.mean()) ** 2))
            assert sd == pytest.approx(want, abs=1e-9)
        else:
            assert np.isnan(sd) and unsure
        face = nearest_face(xs[found[0] : found[1]])
        last = xs[found[1] - 1]
        reach = edge[edge <= last + PARAMS.gap_m + PARAMS.gap_per_m * last]
        moved = np.abs(np.r_[faces, _let_in_brute_force(xs, PARAMS, reach)] - face)
        score = _scores(xs, PARAMS)
        close = len(score) > 1 and score[-2] >= 2 / 3 * score[-1]
        assert unsure == (close or not np.all(moved <= PARAMS.unsure_m))
    assert tried > 200


def _scores(xs: np.ndarray, params) -> np.ndarray:
    """The qualifying groups' scores of ``xs`` (sorted), ascending: written out again."""
    starts, stops = depth_groups(xs, params)
    sizes = stops - starts
    ok = sizes >= max(params.min_points, params.min_fraction * sizes.max())
    near = xs[starts[ok]]
    return np.sort(sizes[ok] * np.exp(-(near - near.min()) / params.support_scale_m))


def test_a_clean_rear_face_is_sure_and_a_three_point_object_is_not() -> None:
    """A car's rear 20 m ahead (60 returns within 3 cm): sd below 1 cm, sure. Three returns:
    leaving one out loses the object, so it is unsure. No object: NaN and unsure."""
    rear = np.sort(20.0 + np.random.default_rng(0).uniform(0, 0.03, 60))
    sd, unsure = face_sensitivity(rear, PARAMS)
    assert sd < 0.01 and not unsure
    assert face_sensitivity(np.array([30.0, 30.1, 30.2]), PARAMS)[1]
    sd, unsure = face_sensitivity(np.array([30.0, 40.0]), PARAMS)
    assert np.isnan(sd) and unsure


# --- real drive 0009 --------------------------------------------------------------------

NAMED_FRAME = 13
NAMED_BOX = [665, 184, 19, 17]  # the 19-px box 31-34 m ahead the issue names (YOLOv3-tiny)
SAME_CAR_BOX = [654, 183, 16, 17]  # a second box on the same car's left part


def _boxes_and_scans(overrides: list[str], frames: list[int], cache_dir: Path, rois=None):
    """YOLO boxes (M × 4 px; ``rois`` when given), whole scans (N × 4), the calibration and
    the core settings of ``frames`` of the recording ``overrides`` compose."""
    cfg = bag_config(*overrides) if overrides[0].endswith(".mcap") else composed(overrides)
    settings, rng = settings_from_config(cfg), frame_range_from_config(cfg)
    if rois is None:
        cache = StageCache(cache_dir)
        stages = FrameStages(settings, rng, cache)
        rois = {i: cache.get(stages.objects(i)).arrays["roi"] for i in frames}
    scans = {i: read_lidar_scan(frame_files(rng.sequence_dir, i).scan).points for i in frames}
    return rois, scans, load_calibration(rng.sequence_dir, rng.projection), settings


def _associate(scan, calib, rois, settings, move=None):
    points = scan if move is None else np.c_[scan[:, :3] + move, scan[:, 3:]]
    params = settings.object_lidar
    keep = object_scan_mask(points, params)
    return associate_objects(points[keep], calib.velo_to_image, rois, settings.lidar_shrink, params)


def _moves(n: int) -> list[np.ndarray]:
    """Moves (m) of a scan of ``n`` points: ±2 cm uniform per coordinate (5 seeds, N × 3)
    and a 1.6 cm shift along each axis either way (3,)."""
    noise = [np.random.default_rng(seed).uniform(-0.02, 0.02, (n, 3)) for seed in range(5)]
    return noise + [0.016 * sign * np.eye(3)[axis] for axis in range(3) for sign in (1, -1)]


@pytest.fixture(scope="module")
def frames_13_14(tmp_path_factory):
    return _boxes_and_scans(["dataset=kitti_raw_0009"], [13, 14], tmp_path_factory.mktemp("c"))


def test_far_boxes_of_drive_0009_move_by_centimetres_or_say_they_are_unsure(frames_13_14) -> None:
    """Drive 0009 frames 13–14, every box beyond 20 m with >= min_points points: the scan moved
    by ±2 cm (uniform per coordinate, 5 seeds) or shifted by 1.6 cm along each axis. A sure
    box's nearest face moves by < 5 cm every time; a box whose face moves more was unsure.
    The box the issue names keeps the car behind the post (the face of that car's other box,
    within 5 cm) every time: the nearest-group rule of issue 30 moved it 2.4 m."""
    rois, scans, calib, settings = frames_13_14
    checked = 0
    for frame in (13, 14):
        base = _associate(scans[frame], calib, rois[frame], settings)
        far = np.flatnonzero((base.n_points >= PARAMS.min_points) & (base.distance_m > 20))
        assert len(far) >= 4, base.distance_m
        for move in _moves(len(scans[frame])):
            moved = _associate(scans[frame], calib, rois[frame], settings, move)
            shift = np.abs(moved.distance_m[far] - base.distance_m[far])
            big = ~(shift < 0.05)
            assert base.unsure[far][big].all(), (frame, far[big], shift[big])
            checked += len(far)
    assert checked >= 100
    named = rois[NAMED_FRAME].tolist().index(NAMED_BOX)
    same_car = rois[NAMED_FRAME].tolist().index(SAME_CAR_BOX)
    base = _associate(scans[NAMED_FRAME], calib, rois[NAMED_FRAME], settings)
    assert abs(base.distance_m[named] - base.distance_m[same_car]) < 0.05
    for move in _moves(len(scans[NAMED_FRAME])):
        moved = _associate(scans[NAMED_FRAME], calib, rois[NAMED_FRAME], settings, move)
        assert abs(moved.distance_m[named] - base.distance_m[named]) < 0.05


@pytest.mark.parametrize("objects", OBJECTS)
def test_the_bag_and_the_folder_give_the_same_far_box_distances(
    objects, tmp_path, monkeypatch
) -> None:
    """Drive 0009 frames 0–15 as the folder (``dataset=kitti_raw_0009``) and as kitti2mcap's
    bag (its calibration moves points by up to 0.8 px, tests/test_ros2_bag.py): every box
    beyond 20 m with a distance in both has the same one within 5 cm unless it is unsure in
    both (the nearest-group rule of issue 30 differed by 2.4 m on frame 13; measured: YOLOv3-
    tiny 0 of 40 differ, SSD on 4 tiles 1 of 83, unsure); a box with a distance in one only is
    unsure there (3 points: one point in or out decides)."""
    pytest.importorskip("kitti2mcap", reason="installed by .ci/run (--no-deps)")
    if objects == "ssd_mobilenet_v2":  # the files through the real resolver, as a run finds them
        folder = weights.resolve_model_dir(model=SSD_MODEL, cache_dir=paths.default_cache_dir())
        monkeypatch.setenv(SSD_MODEL_DIR_ENV, str(folder))
    bag = make_bag(tmp_path / "0009.mcap")
    frames = list(range(16))
    folder = _boxes_and_scans(["dataset=kitti_raw_0009", f"objects={objects}"], frames,
                              tmp_path / "cache")  # fmt: skip
    # the bag's images are the folder's: the same boxes (tests/test_ros2_bag.py)
    ros = _boxes_and_scans([str(bag), f"objects={objects}"], frames, tmp_path, folder[0])
    compared = differ = 0
    for i in frames:
        assert np.array_equal(folder[1][i], ros[1][i])
        a = _associate(folder[1][i], folder[2], folder[0][i], folder[3])
        b = _associate(ros[1][i], ros[2], ros[0][i], ros[3])
        far = (a.distance_m > 20) | (b.distance_m > 20)
        both = far & np.isfinite(a.distance_m) & np.isfinite(b.distance_m)
        apart = both & ~(np.abs(a.distance_m - b.distance_m) < 0.05)
        assert (a.unsure & b.unsure)[apart].all(), (i, np.flatnonzero(apart))
        assert a.unsure[far & np.isnan(b.distance_m)].all()
        assert b.unsure[far & np.isnan(a.distance_m)].all()
        compared, differ = compared + both.sum(), differ + apart.sum()
    assert compared >= 40 and differ <= 0.05 * compared, (compared, differ)


@pytest.mark.parametrize(
    "override", ["gap_per_m=-0.01", "support_scale_m=-1", "unsure_m=0", "min_fraction=1.5"]
)
def test_a_bad_object_lidar_value_is_one_problem_naming_it(override: str) -> None:
    """``lidar.objects.<key>=<bad>`` is refused before a run with one problem naming the entry
    and the value."""
    key, value = override.split("=")
    problems = [p for p in config_problems(composed([f"lidar.objects.{override}"])) if "lidar" in p]
    assert len(problems) == 1 and "lidar.objects" in problems[0]
    assert f"{key}={value}" in problems[0] or f"{key}={float(value)}" in problems[0]
