"""Sweep benchmark: wall times of ``fp6_grid``, ``grand`` and a small sweep, cold and warm,
against the compute floor.

Usage::

    python -m experiments.tools.benchmark                 # every figure (long: see --parts)
    python -m experiments.tools.benchmark --parts fp6,small --skip-nocache
    python -m experiments.tools.benchmark --reduced       # CI: 2 detectors x 2 descriptors, 0-5

Figures (all wall-clock seconds on this machine, written to a JSON report):

* ``cold_s`` (a): ``fp6_grid`` with an empty stage cache, on all cores;
* ``floor_s`` (b): the compute floor, the summed time of the unique OpenCV work — each frame's
  YOLO once, each frame's keypoints once per detector, descriptors once per detector ×
  descriptor, each pair's matching once per setting — divided by the cores. It is measured
  in this process, one OpenCV thread, like a sweep worker. ``floor_unique_s`` counts matching
  once per detector × descriptor × matcher, the work the harness really has to do because NN
  and kNN share one k=2 query; ``cold_over_floor_unique`` is the figure of issue #11;
  ``floor_engine_s`` adds FP.1–FP.4 at their shared minimum
  (:func:`experiments.tools.floor.steps_floor_ms`): ``cold_over_floor_engine`` is the overhead;
* ``cold_fixed_s`` / ``warm_filter_fixed_s``: the time of a cold / warm sweep before its first
  job and after its last (start-up, planning, merge, summary: ``lead_in_s + tail_s`` of the
  breakdowns);
* ``nocache_s`` (c): the same sweep with ``cache.enabled=false``;
* ``warm_filter_s`` (d): a re-run after changing only ``keypoint_filter``, into the same sweep
  folder as a user's changed command goes (new settings, expensive stages from the cache);
* ``rerun_s``: the finished ``fp6_grid`` command again (nothing to compute);
* ``small_cold_s`` / ``small_rerun_s``: 8 settings on frames 0-3, cold, then again;
* ``grand_cold_s``, ``grand_warm_s``: ``+experiment=grand`` on frames 0-18 (28,000 valid
  settings) with an empty cache, then after changing one downstream axis
  (``keypoint_filter=zscore keypoint_filter.z=2.5``: 5,600 new settings, warm cache);
  ``grand_peak_rss_mb``: the largest summed resident memory of the sweep's processes (pages
  shared between processes, e.g. the libraries, counted once per process);
  ``grand_peak_pss_mb``: the same with shared pages split between the processes sharing them
  (proportional set size: the memory the sweep holds; the figure judged against 2 GB);
  ``grand_main_peak_rss_mb``: the main process alone;
* ``long_cold_s``: ``fp6_grid`` on frames 0-77 with an empty cache;
* ``peak_rss_mb``: the largest peak resident memory of one job's worker process.

``--parts`` picks the groups (``fp6``, ``small``, ``grand``, ``long``); a figure of a group
not run is absent from the report and listed under ``missing``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import pandas as pd

from experiments import store
from experiments.data.first_run import ensure_model_files
from experiments.paths import base_dir, default_data_root
from experiments.provenance import code_version, machine, package_versions
from experiments.tools.floor import compute_floor, hydra_compose_seconds, steps_floor_ms
from ttc.features.descriptors import RUBRIC_DESCRIPTORS
from ttc.features.keypoints import RUBRIC_DETECTORS

FULL = {"detectors": list(RUBRIC_DETECTORS), "descriptors": list(RUBRIC_DESCRIPTORS), "last": 18}
REDUCED = {"detectors": ["fast", "orb"], "descriptors": ["brief", "orb"], "last": 5}
TARGETS = {
    "cold_over_floor_unique_max": 1.15,
    "cold_over_floor_engine_max": 1.10,
    "warm_filter_fixed_s_max": 1.5,
    "warm_filter_s_max": 6.0,
    "rerun_s_max": 3.0,
    "small_rerun_s_max": 2.0,
    "grand_cold_s_max": 600.0,
    "grand_peak_pss_mb_max": 2048.0,
    "grand_report_s_max": 120.0,
}
#: 8 settings on frames 0-3 (2 of them an invalid pair).
SMALL = ["-m", "detector=fast,akaze", "descriptor=brief,akaze", "matcher=bf,flann",
         "dataset.last=3"]  # fmt: skip
GRAND = ["+experiment=grand", "dataset.last=18"]
GRAND_WARM = [*GRAND, "keypoint_filter=zscore", "keypoint_filter.z=2.5"]
PARTS = ("fp6", "small", "grand", "long")
#: Every figure of a full run (``missing`` lists those a report lacks).
FIGURES = ("cold_s", "floor_unique_s", "cold_over_floor_unique", "floor_engine_s",
           "cold_over_floor_engine", "cold_fixed_s", "warm_filter_fixed_s", "warm_filter_s", "rerun_s",
           "nocache_s", "small_cold_s", "small_rerun_s", "grand_cold_s", "grand_warm_s",
           "grand_peak_rss_mb", "grand_peak_pss_mb", "grand_report_s",
           "long_cold_s")  # fmt: skip


def sweep_args(grid: dict[str, Any], name: str) -> list[str]:
    """Command-line overrides of the fp6_grid experiment restricted to ``grid``."""
    return [
        "+experiment=fp6_grid",
        f"detector={','.join(grid['detectors'])}",
        f"descriptor={','.join(grid['descriptors'])}",
        f"dataset.last={grid['last']}",
        f"sweep_name={name}",
    ]


def timed_sweep(
    args: list[str], results: Path, cache: Path, memory: dict | None = None
) -> tuple[float, pd.DataFrame]:
    """Run one sweep through the real command line; (wall seconds, its runs table).
    ``memory``, when given, receives the peaks of :func:`_sample_memory` (MB), sampled every
    0.5 s."""
    env = {**os.environ, "TTC_RESULTS_DIR": str(results), "TTC_CACHE_DIR": str(cache)}
    started = time.time()
    start = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "experiments.run", *args],
        cwd=base_dir(),
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    peaks: dict[str, float] = {}
    if memory is not None:
        done = threading.Event()
        sampler = threading.Thread(target=_sample_memory, args=(proc.pid, peaks, done), daemon=True)
        sampler.start()
    _, err = proc.communicate()
    wall = time.perf_counter() - start
    if memory is not None:
        done.set()
        sampler.join()
        memory.update(peaks)
    if proc.returncode != 0:
        raise RuntimeError(f"sweep {args} failed:\n{err[-4000:]}")
    name = next(a.split("=", 1)[1] for a in args if a.startswith("sweep_name="))
    runs = store.load_runs(results / name)
    runs.attrs.update(started=started, ended=started + wall)  # epoch seconds
    return wall, runs


def timed_report(sweep_dir: Path, out: Path, cache: Path) -> float:
    """Wall seconds of ``python -m experiments.report`` on a sweep (pictures and HTML)."""
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "experiments.report", str(sweep_dir), "--out", str(out),
         "--cache-dir", str(cache)],
        cwd=base_dir(), capture_output=True, text=True,
    )  # fmt: skip
    if proc.returncode != 0:
        raise RuntimeError(f"report of {sweep_dir} failed:\n{proc.stderr[-4000:]}")
    return time.perf_counter() - start


def _sample_memory(pid: int, peaks: dict[str, float], done: threading.Event) -> None:
    """Keep in ``peaks`` the largest ``rss`` (summed resident memory of process ``pid`` and
    its children), ``pss`` (the same, shared pages split between their processes) and
    ``main_rss`` (process ``pid`` alone), in MB."""
    import psutil  # noqa: PLC0415

    while not done.wait(0.5):
        try:
            root = psutil.Process(pid)
            procs = [root, *root.children(recursive=True)]
        except psutil.Error:
            return
        now = {"rss": 0.0, "pss": 0.0, "main_rss": 0.0}
        for p in procs:
            with contextlib.suppress(psutil.Error):
                info = p.memory_full_info()
                now["rss"] += info.rss / 2**20
                now["pss"] += getattr(info, "pss", info.rss) / 2**20
                if p.pid == pid:
                    now["main_rss"] = info.rss / 2**20
        for key, value in now.items():
            peaks[key] = max(peaks.get(key, 0.0), value)


def sweep_breakdown(runs: pd.DataFrame, cores: int) -> dict[str, float]:
    """Where a sweep's wall time went (s): ``jobs_s`` the settings' own work (the run
    records' ``wall_s``, summed, divided by the cores), ``span_s`` first job start to last job
    end (the rest of the span is per-job launcher work: Hydra's ``run_job``, the job's config,
    and workers waiting for the last jobs); from :func:`timed_sweep`'s runs, ``lead_in_s`` the
    command's start to the first job's (start-up, validation and planning) and ``tail_s`` the
    last job's end to the command's (merge and summary). Jobs: the computed ones, this command's."""
    computed = runs[runs["status"] != "skipped"] if "status" in runs else runs
    computed = computed if len(computed) else runs
    if "started" in runs.attrs:
        began = pd.to_datetime(computed["start"]).map(pd.Timestamp.timestamp)
        computed = computed[began >= runs.attrs["started"]]
    start, end = pd.to_datetime(computed["start"]), pd.to_datetime(computed["end"])
    out = {
        "jobs_s": float(computed["wall_s"].sum()) / cores,
        "span_s": (end.max() - start.min()).total_seconds(),
        "jobs": len(computed),
    }
    if {"started", "ended"} <= runs.attrs.keys():
        out["lead_in_s"] = start.min().timestamp() - runs.attrs["started"]
        out["tail_s"] = runs.attrs["ended"] - end.max().timestamp()
    return out


def fp6_figures(
    grid: dict[str, Any], workdir: Path, cores: int, skip_nocache: bool
) -> dict[str, Any]:
    """Cold, warm-filter, re-run, cache-off figures of the fp6 grid and its compute floor."""
    sequence_dir = default_data_root() / "kitti" / "2011_09_26"
    cache, results = workdir / "cache", workdir / "sweeps"
    report: dict[str, Any] = {"grid": grid}
    cold_s, runs = timed_sweep(sweep_args(grid, "cold"), results, cache)
    report.update(cold_s=cold_s, settings=len(runs), status=runs["status"].value_counts().to_dict())
    report["peak_rss_mb"] = float(runs["peak_rss_mb"].max())
    report["rerun_s"], _ = timed_sweep(sweep_args(grid, "cold"), results, cache)

    warm_args = [*sweep_args(grid, "cold"), "keypoint_filter=zscore"]
    report["warm_filter_s"], warm_runs = timed_sweep(warm_args, results, cache)
    report["warm_filter_breakdown"] = sweep_breakdown(warm_runs, cores)
    report["cold_breakdown"] = sweep_breakdown(runs, cores)
    report["hydra_compose_s_per_job"] = hydra_compose_seconds()

    floor = compute_floor(sequence_dir, grid)
    floor["steps"] = steps_floor_ms(sequence_dir, grid, cache)
    strict_ms = floor["objects"] + floor["keypoints"] + floor["descriptors"]
    report["floor_ms_by_stage"] = floor
    report["floor_s"] = (strict_ms + floor["matching_per_setting"]) / 1e3 / cores
    report["floor_unique_s"] = (strict_ms + floor["matching_unique"]) / 1e3 / cores
    report["floor_engine_s"] = report["floor_unique_s"] + floor["steps"] / 1e3 / cores
    report["cold_over_floor"] = cold_s / report["floor_s"]
    report["cold_over_floor_unique"] = cold_s / report["floor_unique_s"]
    report["cold_over_floor_engine"] = cold_s / report["floor_engine_s"]
    for name in ("cold", "warm_filter"):
        b = report[f"{name}_breakdown"]
        if {"lead_in_s", "tail_s"} <= b.keys():
            report[f"{name}_fixed_s"] = b["lead_in_s"] + b["tail_s"]

    if not skip_nocache:
        nocache_args = [*sweep_args(grid, "nocache"), "cache.enabled=false"]
        report["nocache_s"], _ = timed_sweep(nocache_args, results, workdir / "unused-cache")
        report["nocache_over_cold"] = report["nocache_s"] / cold_s
    return report


def small_figures(workdir: Path) -> dict[str, Any]:
    """8 settings on frames 0-3: cold (own empty cache), then the same command again."""
    args, cache, results = [*SMALL, "sweep_name=small"], workdir / "small-cache", workdir / "sweeps"
    cold, _ = timed_sweep(args, results, cache)
    rerun, runs = timed_sweep(args, results, cache)
    return {"small_cold_s": cold, "small_rerun_s": rerun, "small_settings": len(runs)}


def grand_figures(workdir: Path, cores: int) -> dict[str, Any]:
    """``grand`` on frames 0-18 cold (own empty cache), then one downstream axis changed."""
    cache, results = workdir / "grand-cache", workdir / "sweeps"
    memory: dict[str, float] = {}
    cold, runs = timed_sweep([*GRAND, "sweep_name=grand"], results, cache, memory)
    report: dict[str, Any] = {"grand_cold_s": cold, "grand_peak_rss_mb": memory["rss"],
                              "grand_peak_pss_mb": memory["pss"],
                              "grand_main_peak_rss_mb": memory["main_rss"]}  # fmt: skip
    report["grand_settings"] = len(runs)
    report["grand_status"] = runs["status"].value_counts().to_dict()
    report["grand_worker_peak_rss_mb"] = float(runs["peak_rss_mb"].max())
    report["grand_cold_breakdown"] = sweep_breakdown(runs, cores)
    warm, warm_runs = timed_sweep([*GRAND_WARM, "sweep_name=grand_warm"], results, cache, memory)
    report.update(grand_warm_s=warm, grand_warm_settings=len(warm_runs))
    report["grand_report_s"] = timed_report(results / "grand", workdir / "grand-report", cache)
    report["grand_frames_rows"] = store.row_count(store.list_records(results / "grand"))
    return report


def long_figures(workdir: Path) -> dict[str, Any]:
    """``fp6_grid`` on frames 0-77 cold (own empty cache)."""
    args = [*sweep_args(FULL, "long"), "dataset.last=77"]
    wall, runs = timed_sweep(args, workdir / "sweeps", workdir / "long-cache")
    return {"long_cold_s": wall, "long_settings": len(runs)}


def run_benchmark(
    grid: dict[str, Any],
    workdir: Path,
    skip_nocache: bool = False,
    parts: tuple[str, ...] = ("fp6", "small"),
    save: Any = None,
) -> dict[str, Any]:
    """The figures of ``parts`` (see the module docstring) and their targets; ``save(report)``
    is called after each part (a long benchmark stopped midway keeps what it measured)."""
    cores = os.cpu_count() or 1
    report: dict[str, Any] = {"cores": cores, "parts": list(parts)}
    figures = {
        "fp6": lambda: fp6_figures(grid, workdir, cores, skip_nocache),
        "small": lambda: small_figures(workdir),
        "grand": lambda: grand_figures(workdir, cores),
        "long": lambda: long_figures(workdir),
    }
    for part in PARTS:
        if part in parts:
            start = time.perf_counter()
            report.update(figures[part]())
            print(f"{part}: {time.perf_counter() - start:.0f} s", flush=True)
            if save is not None:
                save(_judged(report))
    return _judged(report)


def _judged(report: dict[str, Any]) -> dict[str, Any]:
    """``report`` with its targets, which it meets and which figures it lacks."""
    report["targets"] = TARGETS
    checks = {
        "cold_over_floor_unique": ("cold_over_floor_unique", "cold_over_floor_unique_max"),
        "cold_over_floor_engine": ("cold_over_floor_engine", "cold_over_floor_engine_max"),
        "warm_filter_fixed_s": ("warm_filter_fixed_s", "warm_filter_fixed_s_max"),
        "warm_filter_s": ("warm_filter_s", "warm_filter_s_max"),
        "rerun_s": ("rerun_s", "rerun_s_max"),
        "small_rerun_s": ("small_rerun_s", "small_rerun_s_max"),
        "grand_cold_s": ("grand_cold_s", "grand_cold_s_max"),
        "grand_peak_pss_mb": ("grand_peak_pss_mb", "grand_peak_pss_mb_max"),
        "grand_report_s": ("grand_report_s", "grand_report_s_max"),
    }
    report["meets"] = {k: report[v] <= TARGETS[t] for k, (v, t) in checks.items() if v in report}
    report["missing"] = [k for k in FIGURES if k not in report]
    return report


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reduced", action="store_true", help="small grid for CI")
    parser.add_argument("--skip-nocache", action="store_true", help="skip the cache-off sweep")
    parser.add_argument("--parts", help=f"comma-separated groups of {PARTS} (default: all; "
                        "--reduced: fp6,small)")  # fmt: skip
    parser.add_argument("--out", type=Path, help="JSON report path")
    parser.add_argument("--workdir", type=Path, help="cache + sweeps folder (default: temp)")
    args = parser.parse_args(argv)
    grid = REDUCED if args.reduced else FULL
    default_parts = ("fp6", "small") if args.reduced else PARTS
    parts = tuple(args.parts.split(",")) if args.parts else default_parts
    if unknown := set(parts) - set(PARTS):
        parser.error(f"unknown parts {sorted(unknown)}; known: {PARTS}")
    out = args.out or base_dir() / "results" / "benchmark" / (
        "sweep_reduced.json" if args.reduced else "sweep_fp6_grid.json"
    )

    def save(report: dict[str, Any]) -> None:
        report.update(
            date=time.strftime("%Y-%m-%d %H:%M:%S %Z"),
            **code_version(),
            versions=package_versions(),
            machine=machine(),
            load_average=os.getloadavg(),
        )
        store.write_json_atomic(report, out)

    ensure_model_files()  # the floor runs the detector in this process (and the sweeps inherit it)
    with tempfile.TemporaryDirectory(prefix="ttc-bench-") as tmp:
        workdir = args.workdir or Path(tmp)
        report = run_benchmark(grid, workdir, args.skip_nocache, parts, save)
    save(report)
    keys = ("settings", "cold_s", "floor_s", "floor_unique_s", "floor_engine_s", "cold_over_floor",
            "cold_over_floor_unique", "cold_over_floor_engine", "cold_fixed_s",
            "warm_filter_fixed_s", "nocache_s", "nocache_over_cold", "warm_filter_s",
            "rerun_s", "small_cold_s", "small_rerun_s", "grand_cold_s", "grand_warm_s",
            "grand_peak_rss_mb", "grand_peak_pss_mb", "grand_main_peak_rss_mb",
            "grand_report_s", "long_cold_s", "peak_rss_mb")  # fmt: skip
    for key in keys:
        if key in report:
            value = report[key]
            print(f"{key:>24}: {value:.2f}" if isinstance(value, float) else f"{key:>24}: {value}")
    for name in ("cold", "warm_filter"):
        if f"{name}_breakdown" in report:
            b = report[f"{name}_breakdown"]
            print(f"{name + ' breakdown':>24}: jobs' own work {b['jobs_s']:.1f} s per core, "
                  f"first job start to last end {b['span_s']:.1f} s ({b['jobs']} jobs), "
                  f"before {b.get('lead_in_s', float('nan')):.1f} s, "
                  f"after {b.get('tail_s', float('nan')):.1f} s")  # fmt: skip
    print(f"{'meets targets':>24}: {report['meets']}")
    print(f"{'missing figures':>24}: {report['missing']}")
    print(f"report: {out}")


if __name__ == "__main__":
    main()
