"""Timing of the object stage: YOLOv3-tiny on one KITTI frame, and reading the network.

Skipped by default (``--benchmark-skip`` in the project's addopts); run with
``pytest tests/benchmarks/test_bench_objects.py --benchmark-enable``.
"""

from __future__ import annotations

from pathlib import Path

from ttc.features.objects import (
    ObjectDetectorParams,
    clear_detector_cache,
    detect_objects,
    load_detector,
)
from ttc.io.frames import frame_files, read_image


def test_bench_detect_objects_frame_0(benchmark, kitti_dir: Path) -> None:
    """One forward pass + decoding + NMS at 832 × 256, network already loaded."""
    image = read_image(frame_files(kitti_dir, 0).image)
    params = ObjectDetectorParams()
    net = load_detector(params)
    det = benchmark(detect_objects, image, params, net)
    assert len(det) > 0


def test_bench_load_detector(benchmark) -> None:
    """Reading cfg + weights (35 MB) from disk, what each worker process pays once."""
    params = ObjectDetectorParams()
    net = benchmark.pedantic(
        load_detector, args=(params,), setup=clear_detector_cache, rounds=5, iterations=1
    )
    assert not net.empty()
