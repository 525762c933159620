"""Timing of the feature stages on the real KITTI frame 0 (and pair 0 → 1).

Skipped in a plain run (addopts has ``--benchmark-skip``); run with
``pytest tests/benchmarks --benchmark-enable -p no:cacheprovider``. OpenCV runs single-threaded
here, as in a sweep job (``cv_threads = 1``), so the numbers are per-job costs.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from ttc.features.descriptors import DESCRIPTORS, describe_keypoints, is_binary
from ttc.features.keypoints import (
    DETECTORS,
    array_to_keypoints,
    detect_keypoints,
    keypoints_to_array,
)
from ttc.features.matching import MatcherParams, SelectorParams, knn_candidates, select_matches
from ttc.io.frames import read_image

#: Descriptor → the detector whose keypoints it is timed on.
NATURAL_DETECTOR = {
    "brisk": "brisk",
    "brief": "fast",
    "orb": "orb",
    "freak": "fast",
    "akaze": "akaze",
    "sift": "sift",
}
#: One binary and one float descriptor for the matchers.
MATCH_CASES = [("orb", "orb"), ("sift", "sift")]


@pytest.fixture(scope="module", autouse=True)
def single_thread():
    previous = cv2.getNumThreads()
    cv2.setNumThreads(1)
    yield
    cv2.setNumThreads(previous)


@pytest.fixture(scope="module")
def grays(kitti_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    paths = [kitti_dir / "image_02" / "data" / f"{i:010d}.png" for i in (0, 1)]
    return tuple(cv2.cvtColor(read_image(p), cv2.COLOR_BGR2GRAY) for p in paths)


def _describe(grays, detector: str, descriptor: str) -> list[tuple[np.ndarray, np.ndarray]]:
    params = DESCRIPTORS[descriptor]()
    return [
        describe_keypoints(g, detect_keypoints(g, DETECTORS[detector]()), detector, params)
        for g in grays
    ]


@pytest.mark.parametrize("detector", list(DETECTORS))
def test_bench_detect(benchmark, grays, detector: str) -> None:
    benchmark.group = "detect"
    kps = benchmark(detect_keypoints, grays[0], DETECTORS[detector]())
    assert len(kps) > 0


@pytest.mark.parametrize("descriptor", list(DESCRIPTORS))
def test_bench_describe(benchmark, grays, descriptor: str) -> None:
    benchmark.group = "describe"
    detector = NATURAL_DETECTOR[descriptor]
    kps = detect_keypoints(grays[0], DETECTORS[detector]())
    kept, desc = benchmark(describe_keypoints, grays[0], kps, detector, DESCRIPTORS[descriptor]())
    assert len(kept) == len(desc) > 0


@pytest.mark.parametrize("matcher", ["bf", "flann"])
@pytest.mark.parametrize(("detector", "descriptor"), MATCH_CASES)
def test_bench_knn_candidates(benchmark, grays, detector, descriptor, matcher) -> None:
    benchmark.group = "match (k=2 query)"
    (_, d0), (_, d1) = _describe(grays, detector, descriptor)
    params = MatcherParams(name=matcher)
    idx, _ = benchmark(knn_candidates, d0, d1, is_binary(descriptor), params)
    assert len(idx) == len(d0) and idx[:, 0].min() >= 0


@pytest.mark.parametrize("selector", ["nn", "knn"])
def test_bench_select(benchmark, grays, selector: str) -> None:
    benchmark.group = "select"
    (_, d0), (_, d1) = _describe(grays, "orb", "orb")
    idx, dist = knn_candidates(d0, d1, True, MatcherParams())
    matches = benchmark(select_matches, idx, dist, SelectorParams(name=selector))
    assert len(matches) > 0


def test_bench_keypoints_to_array(benchmark, grays) -> None:
    benchmark.group = "opencv boundary"
    kps = array_to_keypoints(detect_keypoints(grays[0], DETECTORS["brisk"]()))
    assert len(benchmark(keypoints_to_array, kps)) == len(kps)


def test_bench_array_to_keypoints(benchmark, grays) -> None:
    benchmark.group = "opencv boundary"
    arr = detect_keypoints(grays[0], DETECTORS["brisk"]())
    assert len(benchmark(array_to_keypoints, arr)) == len(arr)
