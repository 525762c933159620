"""The compute floor of a sweep: the unique work its settings need, measured in this process with
one OpenCV thread, like a sweep worker (milliseconds, summed; the benchmark divides by the
cores).

* :func:`compute_floor`: the OpenCV work: each frame's YOLO once, each frame's keypoints once
  per detector, descriptors once per detector × descriptor, each pair's k=2 matching once per
  detector × descriptor × matcher (``matching_unique``; ``matching_per_setting`` counts it for
  the NN and the kNN setting);
* :func:`steps_floor_ms`: FP.1–FP.4 at their shared minimum: every setting of the grid in one
  batch of the engine over the warm stage cache, less the time that batch spends reading the
  cache (each group's stream alone);
* :func:`hydra_compose_seconds`: what one Hydra composition of a job costs (the per-job cost
  the stock launcher pays and the composer avoids).
"""

from __future__ import annotations

import dataclasses
import time
from itertools import pairwise
from pathlib import Path
from typing import Any

import cv2

from experiments.host.paths import CONF_DIR
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_settings, upstream_key
from ttc.engine.stages import stream
from ttc.features.descriptors import DESCRIPTORS, describe_keypoints, is_binary, valid_pairs
from ttc.features.keypoints import DETECTORS, detect_keypoints
from ttc.features.matching import MatcherParams, knn_candidates
from ttc.features.objects import ObjectDetectorParams, detect_objects, load_detector
from ttc.io.frames import load_frame
from ttc.settings import FrameRange, Settings

#: Matchers and selectors of the fp6 grid.
GRID_MATCHERS = ("bf", "flann")
GRID_SELECTORS = ("nn", "knn")


def _ms(fn, *args) -> tuple[Any, float]:
    start = time.perf_counter()
    out = fn(*args)
    return out, 1e3 * (time.perf_counter() - start)


def compute_floor(sequence_dir: Path, grid: dict[str, Any]) -> dict[str, float]:
    """Summed milliseconds of the unique OpenCV work of the grid, by stage (one thread)."""
    cv2.setNumThreads(1)
    frames = [load_frame(sequence_dir, i) for i in range(grid["last"] + 1)]
    grays = [f.gray for f in frames]
    objects = ObjectDetectorParams()
    net = load_detector(objects)
    totals = {"objects": 0.0, "keypoints": 0.0, "descriptors": 0.0, "matching_unique": 0.0}
    for frame in frames:
        totals["objects"] += _ms(detect_objects, frame.image, objects, net)[1]
    pairs = [
        (d, e) for d, e in valid_pairs() if d in grid["detectors"] and e in grid["descriptors"]
    ]
    for det in grid["detectors"]:
        keypoints = []
        for gray in grays:
            kps, ms = _ms(detect_keypoints, gray, DETECTORS[det]())
            keypoints.append(kps)
            totals["keypoints"] += ms
        for d, desc in pairs:
            if d != det:
                continue
            described = []
            for gray, kps in zip(grays, keypoints, strict=True):
                out, ms = _ms(describe_keypoints, gray, kps, det, DESCRIPTORS[desc]())
                described.append(out[1])
                totals["descriptors"] += ms
            for matcher in GRID_MATCHERS:
                params = MatcherParams(name=matcher)
                for a, b in pairwise(described):
                    totals["matching_unique"] += _ms(knn_candidates, a, b, is_binary(desc), params)[
                        1
                    ]
    totals["matching_per_setting"] = len(GRID_SELECTORS) * totals["matching_unique"]
    totals["n_valid_pairs"] = len(pairs)
    return totals


def grid_settings(grid: dict[str, Any]) -> list[Settings]:
    """The valid settings of the fp6 grid restricted to ``grid`` (detectors, descriptors), each
    option's parameters as its YAML sets them (one Hydra composition per option)."""
    from hydra import compose, initialize_config_dir  # noqa: PLC0415

    from experiments.configs.structured import register_configs, settings_from_config  # noqa: PLC0415

    register_configs()
    options = {"matcher": GRID_MATCHERS, "selector": GRID_SELECTORS,
               "detector": grid["detectors"], "descriptor": grid["descriptors"]}  # fmt: skip
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        base = settings_from_config(compose(config_name="config"))
        params = {
            (axis, value): getattr(
                settings_from_config(compose(config_name="config", overrides=[f"{axis}={value}"])),
                axis,
            )
            for axis, values in options.items()
            for value in values
        }
    return [
        dataclasses.replace(
            base,
            detector=params["detector", d],
            descriptor=params["descriptor", e],
            matcher=params["matcher", m],
            selector=params["selector", s],
        )  # fmt: skip
        for d, e in valid_pairs()
        if d in grid["detectors"] and e in grid["descriptors"]
        for m in GRID_MATCHERS
        for s in GRID_SELECTORS
    ]


def steps_floor_ms(sequence_dir: Path, grid: dict[str, Any], cache_dir: Path) -> float:
    """Milliseconds of FP.1–FP.4 (with the rows they make) at their shared minimum: the
    grid's settings in one :func:`ttc.engine.runner.run_settings` batch over the stage cache
    ``cache_dir`` (warm: a cold sweep filled it), less the same groups' streams of cached
    stages alone."""
    cv2.setNumThreads(1)
    settings = grid_settings(grid)
    frames = FrameRange(Path(sequence_dir), 0, grid["last"])
    cache = StageCache(cache_dir)
    start = time.perf_counter()
    run_settings(settings, frames, cache)
    batch_ms = 1e3 * (time.perf_counter() - start)
    firsts = {upstream_key(s): s for s in reversed(settings)}.values()
    start = time.perf_counter()
    for first in firsts:
        for _ in stream(first, frames, cache, frames.indices):
            pass
    return batch_ms - 1e3 * (time.perf_counter() - start)


def hydra_compose_seconds(repeats: int = 5) -> float:
    """Median seconds Hydra takes to compose one job's config of ``fp6_grid`` (what the stock
    joblib launcher does in the worker before every job)."""
    from hydra import compose, initialize_config_dir  # noqa: PLC0415
    from hydra.core.global_hydra import GlobalHydra  # noqa: PLC0415

    from experiments.configs.structured import register_configs  # noqa: PLC0415

    register_configs()
    job = ["detector=orb", "descriptor=brisk", "matcher=flann", "selector=nn"]
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        master = compose(
            config_name="config", overrides=["+experiment=fp6_grid"], return_hydra_config=True
        )
        loader = GlobalHydra.instance().config_loader()
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            loader.load_sweep_config(master, job)
            times.append(time.perf_counter() - start)
    return float(sorted(times)[len(times) // 2])
