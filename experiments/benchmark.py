"""Sweep benchmark: cold, cache-off and warm wall times of ``fp6_grid`` against the compute floor.

Usage::

    python -m experiments.benchmark                 # full fp6_grid, frames 0-18 (~15 min)
    python -m experiments.benchmark --reduced       # CI: 2 detectors x 2 descriptors, 0-5

Figures (all wall-clock seconds on this machine, written to a JSON report):

* ``cold_s`` (a): the sweep with an empty stage cache, on all cores;
* ``floor_s`` (b): the compute floor, the summed time of the unique OpenCV work — each frame's
  YOLO once, each frame's keypoints once per detector, descriptors once per detector ×
  descriptor, each pair's matching once per setting — divided by the cores. It is measured
  in this process, one OpenCV thread, like a sweep worker. ``floor_unique_s`` counts matching
  once per detector × descriptor × matcher, the work the harness really has to do because NN
  and kNN share one k=2 query;
* ``nocache_s`` (c): the same sweep with ``cache.enabled=false``, every stage recomputed per
  setting as a per-setting script would;
* ``warm_filter_s`` (d): a re-run after changing only ``keypoint_filter`` (new settings, all
  expensive stages from the warm cache);
* ``peak_rss_mb``: the largest peak resident memory of one job's worker process.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from itertools import pairwise
from pathlib import Path
from typing import Any

import cv2
import pandas as pd

from experiments import store
from experiments.paths import PROJECT_ROOT, default_data_root
from experiments.provenance import code_version, machine, package_versions
from ttc.descriptors import (
    DESCRIPTORS,
    RUBRIC_DESCRIPTORS,
    describe_keypoints,
    is_binary,
    valid_pairs,
)
from ttc.frames import load_frame
from ttc.keypoints import DETECTORS, RUBRIC_DETECTORS, detect_keypoints
from ttc.matching import MatcherParams, knn_candidates
from ttc.objects import ObjectDetectorParams, detect_objects, load_detector

FULL = {"detectors": list(RUBRIC_DETECTORS), "descriptors": list(RUBRIC_DESCRIPTORS), "last": 18}
REDUCED = {"detectors": ["fast", "orb"], "descriptors": ["brief", "orb"], "last": 5}
TARGETS = {"cold_over_floor_max": 1.3, "nocache_over_cold_min": 5.0, "warm_filter_s_max": 10.0}


def sweep_args(grid: dict[str, Any], name: str) -> list[str]:
    """Command-line overrides of the fp6_grid experiment restricted to ``grid``."""
    return [
        "+experiment=fp6_grid",
        f"detector={','.join(grid['detectors'])}",
        f"descriptor={','.join(grid['descriptors'])}",
        f"dataset.last={grid['last']}",
        f"sweep_name={name}",
    ]


def timed_sweep(args: list[str], results: Path, cache: Path) -> tuple[float, pd.DataFrame]:
    """Run one sweep through the real command line; (wall seconds, its runs table)."""
    env = {**os.environ, "TTC_RESULTS_DIR": str(results), "TTC_CACHE_DIR": str(cache)}
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.run", *args],
        cwd=PROJECT_ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(f"sweep {args} failed:\n{proc.stderr[-4000:]}")
    name = next(a.split("=", 1)[1] for a in args if a.startswith("sweep_name="))
    return wall, pd.read_parquet(results / name / store.RUNS_FILE)


def sweep_breakdown(runs: pd.DataFrame, cores: int) -> dict[str, float]:
    """Where a sweep's wall time went (s): ``jobs_s`` the settings' own work (the run
    records' ``wall_s``, summed, divided by the cores), ``span_s`` first job start to last job
    end; the rest of the span is per-job launcher work (Hydra composes each job's config in the
    worker), the rest of the wall time start-up and the final merge + summary."""
    start, end = pd.to_datetime(runs["start"]), pd.to_datetime(runs["end"])
    return {
        "jobs_s": float(runs["wall_s"].sum()) / cores,
        "span_s": (end.max() - start.min()).total_seconds(),
        "jobs": len(runs),
    }


def hydra_compose_seconds(repeats: int = 5) -> float:
    """Median seconds Hydra takes to compose one job's config of ``fp6_grid`` (what the stock
    joblib launcher does in the worker before every job)."""
    from hydra import compose, initialize_config_dir  # noqa: PLC0415
    from hydra.core.global_hydra import GlobalHydra  # noqa: PLC0415

    from experiments.config import register_configs  # noqa: PLC0415

    register_configs()
    job = ["detector=orb", "descriptor=brisk", "matcher=flann", "selector=nn"]
    with initialize_config_dir(config_dir=str(PROJECT_ROOT / "conf"), version_base="1.3"):
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
            for matcher in ("bf", "flann"):
                params = MatcherParams(name=matcher)
                for a, b in pairwise(described):
                    totals["matching_unique"] += _ms(knn_candidates, a, b, is_binary(desc), params)[
                        1
                    ]
    totals["matching_per_setting"] = 2 * totals["matching_unique"]  # nn and knn settings
    totals["n_valid_pairs"] = len(pairs)
    return totals


def run_benchmark(
    grid: dict[str, Any], workdir: Path, skip_nocache: bool = False
) -> dict[str, Any]:
    """All four figures and their ratios for ``grid``."""
    sequence_dir = default_data_root()
    sequence_dir = sequence_dir / "kitti" / "2011_09_26"
    cores = os.cpu_count() or 1
    cache, results = workdir / "cache", workdir / "sweeps"
    report: dict[str, Any] = {"grid": grid, "cores": cores}

    cold_s, runs = timed_sweep(sweep_args(grid, "cold"), results, cache)
    report.update(cold_s=cold_s, settings=len(runs), status=runs["status"].value_counts().to_dict())
    report["peak_rss_mb"] = float(runs["peak_rss_mb"].max())

    warm_args = [*sweep_args(grid, "warm_filter"), "keypoint_filter=zscore"]
    report["warm_filter_s"], warm_runs = timed_sweep(warm_args, results, cache)
    report["warm_filter_breakdown"] = sweep_breakdown(warm_runs, cores)
    report["cold_breakdown"] = sweep_breakdown(runs, cores)
    report["hydra_compose_s_per_job"] = hydra_compose_seconds()

    floor = compute_floor(sequence_dir, grid)
    strict_ms = floor["objects"] + floor["keypoints"] + floor["descriptors"]
    report["floor_ms_by_stage"] = floor
    report["floor_s"] = (strict_ms + floor["matching_per_setting"]) / 1e3 / cores
    report["floor_unique_s"] = (strict_ms + floor["matching_unique"]) / 1e3 / cores
    report["cold_over_floor"] = cold_s / report["floor_s"]
    report["cold_over_floor_unique"] = cold_s / report["floor_unique_s"]

    if not skip_nocache:
        nocache_args = [*sweep_args(grid, "nocache"), "cache.enabled=false"]
        report["nocache_s"], _ = timed_sweep(nocache_args, results, workdir / "unused-cache")
        report["nocache_over_cold"] = report["nocache_s"] / cold_s
    report["targets"] = TARGETS
    report["meets"] = {
        "cold_over_floor": report["cold_over_floor"] <= TARGETS["cold_over_floor_max"],
        "warm_filter_s": report["warm_filter_s"] <= TARGETS["warm_filter_s_max"],
        **(
            {"nocache_over_cold": report["nocache_over_cold"] >= TARGETS["nocache_over_cold_min"]}
            if "nocache_s" in report
            else {}
        ),
    }
    return report


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reduced", action="store_true", help="small grid for CI")
    parser.add_argument("--skip-nocache", action="store_true", help="skip the cache-off sweep")
    parser.add_argument("--out", type=Path, help="JSON report path")
    parser.add_argument("--workdir", type=Path, help="cache + sweeps folder (default: temp)")
    args = parser.parse_args(argv)
    grid = REDUCED if args.reduced else FULL
    out = args.out or PROJECT_ROOT / "results" / "benchmark" / (
        "sweep_reduced.json" if args.reduced else "sweep_fp6_grid.json"
    )
    with tempfile.TemporaryDirectory(prefix="ttc-bench-") as tmp:
        workdir = args.workdir or Path(tmp)
        report = run_benchmark(grid, workdir, args.skip_nocache)
    report.update(
        date=time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        **code_version(),
        versions=package_versions(),
        machine=machine(),
    )
    store.write_json_atomic(report, out)
    keys = ("settings", "cold_s", "floor_s", "floor_unique_s", "cold_over_floor", "nocache_s",
            "nocache_over_cold", "warm_filter_s", "peak_rss_mb")  # fmt: skip
    for key in keys:
        if key in report:
            value = report[key]
            print(f"{key:>24}: {value:.2f}" if isinstance(value, float) else f"{key:>24}: {value}")
    for name in ("cold", "warm_filter"):
        b = report[f"{name}_breakdown"]
        print(f"{name + ' breakdown':>24}: jobs' own work {b['jobs_s']:.1f} s per core, "
              f"first job start to last end {b['span_s']:.1f} s ({b['jobs']} jobs)")  # fmt: skip
    print(f"{'hydra compose per job':>24}: {report['hydra_compose_s_per_job']:.3f} s")
    print(f"{'meets targets':>24}: {report['meets']}")
    print(f"report: {out}")


if __name__ == "__main__":
    main()
