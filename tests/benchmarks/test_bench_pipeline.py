"""Lidar association of a full scan, the lead's and every object's (budget: 10 ms each), and
the pure-Python share.

The pure-Python share of a frame is everything the pipeline does besides the OpenCV calls:
with every expensive stage in a warm cache, one frame pair costs the cache loads, the lidar
projection/assignment and FP.1–FP.4 for every matched box. Run with
``pytest tests/benchmarks --benchmark-only -n 0``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting
from ttc.features.descriptors import DESCRIPTORS
from ttc.features.keypoints import DETECTORS
from ttc.features.objects import ObjectDetectorParams, detect_objects
from ttc.io.calibration import load_calibration
from ttc.io.frames import load_frame
from ttc.settings import FrameRange, Settings
from ttc.steps.lidar import LaneCropParams, associate_lead, crop_to_lane
from ttc.steps.object_lidar import ObjectLidarParams, associate_objects, object_scan_mask


@pytest.fixture(scope="module")
def scan_and_boxes(kitti_dir: Path):
    frame = load_frame(kitti_dir, 0)
    detections = detect_objects(frame.image, ObjectDetectorParams())
    calib = load_calibration(kitti_dir)
    return frame.scan.points, calib.velo_to_image, detections.roi


def test_bench_lidar_association_full_scan(benchmark, scan_and_boxes) -> None:
    points, velo_to_image, rois = scan_and_boxes
    assert len(points) > 110_000 and len(rois) >= 6

    def associate():
        return associate_lead(crop_to_lane(points, LaneCropParams()), velo_to_image, rois)

    result = benchmark(associate)
    assert np.sum(result.owner == result.lead) > 100
    assert benchmark.stats["median"] < 10e-3


def test_bench_python_share_per_frame_pair(benchmark, kitti_dir: Path, tmp_path_factory) -> None:
    """18 frame pairs with every OpenCV stage cached; reported per run of 18 pairs."""
    settings = Settings(detector=DETECTORS["fast"](), descriptor=DESCRIPTORS["brief"]())
    frames = FrameRange(kitti_dir, 0, 18)
    cache = StageCache(tmp_path_factory.mktemp("warm-cache"))
    run_setting(settings, frames, cache)  # fill
    rows = benchmark(run_setting, settings, frames, cache)
    assert rows.filter(like="cached_").to_numpy().all()
    benchmark.extra_info["pairs"] = 18
    benchmark.extra_info["ms_per_pair_median"] = 1e3 * benchmark.stats["median"] / 18


@pytest.fixture(scope="module")
def drive_0009_scan(data_dir: Path):
    """Frame 0 of drive 0009 (6-9 parked cars in view): its scan, projection and boxes."""
    seq = data_dir / "kitti_raw/2011_09_26/2011_09_26_drive_0009_sync"
    frame = load_frame(seq, 0)
    detections = detect_objects(frame.image, ObjectDetectorParams())
    return frame.scan.points, load_calibration(seq).velo_to_image, detections.roi


def test_bench_object_association_full_scan(benchmark, drive_0009_scan) -> None:
    """Every box's own points from a full scan (the object range mask, one projection, the
    nearest compact group of every frustum): budget 10 ms for all boxes of a scan."""
    points, velo_to_image, rois = drive_0009_scan
    assert len(rois) >= 6
    params = ObjectLidarParams()

    def associate():
        near = points[object_scan_mask(points, params)]
        return associate_objects(near, velo_to_image, rois, 0.10, params)

    result = benchmark(associate)
    assert (result.n_points > 0).sum() >= 6
    benchmark.extra_info["boxes"] = len(rois)
    assert benchmark.stats["median"] < 10e-3
