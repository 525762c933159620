"""Timing of the learned features and dense flow on the real KITTI frames 0 → 1 (issue 23).

Skipped in a plain run (``--benchmark-skip``); run with
``pytest tests/benchmarks/test_bench_learned.py --benchmark-enable -p no:cacheprovider``. CPU,
one torch and one OpenCV thread, as in a sweep job; ``experiments/tools/learned_timing.py`` times the
same stages on CUDA too.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from ttc.features.dense_flow import DenseFlowParams, flow_keypoints
from ttc.features.keypoints import FastParams, detect_keypoints
from ttc.features.learned_params import LEARNED_DETECTORS, GlueParams
from ttc.io.frames import read_image

pytest.importorskip("torch")
from ttc.features import learned  # noqa: E402

GLUE = {"xfeat": "lighterglue", "aliked": "lightglue", "disk": "lightglue"}


@pytest.fixture(scope="module")
def grays(kitti_dir: Path) -> list[np.ndarray]:
    cv2.setNumThreads(1)
    paths = [kitti_dir / "image_02" / "data" / f"{i:010d}.png" for i in (0, 1)]
    return [cv2.cvtColor(read_image(p), cv2.COLOR_BGR2GRAY) for p in paths]


@pytest.mark.parametrize("name", list(GLUE))
def test_bench_learned_features_per_frame(benchmark, grays, name: str) -> None:
    params = LEARNED_DETECTORS[name]()
    kps, _ = benchmark.pedantic(learned.extract, (grays[0], params),
                                setup=learned.forget_recent, rounds=3, warmup_rounds=1)  # fmt: skip
    assert len(kps) > 500


@pytest.mark.parametrize("name", list(GLUE))
def test_bench_learned_matcher_per_pair(benchmark, grays, name: str) -> None:
    feats = [learned.extract(g, LEARNED_DETECTORS[name]()) for g in grays]
    size = grays[0].shape[::-1]
    idx, _ = benchmark.pedantic(learned.glue_candidates,
                                (*feats[0], *feats[1], size, name, GlueParams(GLUE[name])),
                                rounds=3, warmup_rounds=1)  # fmt: skip
    assert (idx[:, 0] >= 0).sum() > 300


@pytest.mark.parametrize("name", ["dis", "farneback"])
def test_bench_dense_flow_per_pair(benchmark, grays, name: str) -> None:
    kps = detect_keypoints(grays[0], FastParams())
    tracks = benchmark(flow_keypoints, grays[0], grays[1], kps, DenseFlowParams(name))
    assert len(tracks) > 0.5 * len(kps)
