"""Sweep benchmark: wall times of ``fp6_grid``, ``grand`` and a small sweep, cold and warm,
against the compute floor.

Usage::

    python -m experiments.tools.benchmark                 # every figure (long: see --parts)
    python -m experiments.tools.benchmark --parts fp6,small --skip-nocache
    python -m experiments.tools.benchmark --reduced       # CI: 2 detectors x 2 descriptors, 0-5
    # the report of the grand sweep made before in W, today's code against commit X's:
    python -m experiments.tools.benchmark --workdir W --parts grand_report --before X --rounds 3

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
  folder as a user's changed command goes (new settings, expensive stages from the cache),
  as a user runs it: ``ttc-bench run`` with its warm server up (:mod:`experiments.warm`;
  started before, not timed); ``warm_filter_lead_in_s`` its start to its first job's;
  ``warm_filter_local_s`` / ``warm_filter_local_breakdown``: such a re-run without the server
  (``python -m experiments.run``: a session's first command);
* ``rerun_s``: the finished ``fp6_grid`` command again (nothing to compute), served;
* ``small_cold_s`` / ``small_rerun_s``: 8 settings on frames 0-3, cold, then again;
* ``grand_cold_s``, ``grand_warm_s``: ``+experiment=grand`` on frames 0-18 (28,000 valid
  settings) with an empty cache, then after changing one downstream axis
  (``keypoint_filter=zscore keypoint_filter.z=2.5``: 5,600 new settings, warm cache);
  ``grand_peak_rss_mb``: the largest summed resident memory of the sweep's processes (pages
  shared between processes, e.g. the libraries, counted once per process);
  ``grand_peak_pss_mb``: the same with shared pages split between the processes sharing them
  (proportional set size: the memory the sweep holds; the figure judged against 2 GB);
  ``grand_main_peak_rss_mb``: the main process alone;
  ``grand_warm_breakdown`` / ``grand_warm_fixed_s``: that re-run goes into the cold sweep's
  folder, as a user's changed command does; its split before the first job and after the last;
  ``grand_report_s`` / ``grand_report_peak_rss_mb`` / ``grand_report_peak_pss_mb``:
  ``python -m experiments.report`` of that folder (both sweeps' settings), wall and peak
  resident / proportional memory (the process and its children;
  :mod:`experiments.tools.report_timing`);
* ``grand_long_cold_s``, ``grand_long_peak_pss_mb``, ``grand_long_report_s``,
  ``grand_long_report_peak_rss_mb``, ``grand_long_report_peak_pss_mb``: ``grand`` on frames
  0-77 (≈ 4× the rows of 0-18) with an empty cache, then its report (part ``grand_long``);
* ``long_cold_s``: ``fp6_grid`` on frames 0-77 with an empty cache;
* ``peak_rss_mb``: the largest peak resident memory of one job's worker process.

``--parts`` picks the groups (``fp6``, ``small``, ``grand``, ``grand_long``, ``long``, and the
report-only ``grand_report``, ``grand_long_report``); a figure of a group not run is absent from
the report and listed under ``missing``. ``grand_report`` / ``grand_long_report`` make no sweep:
they time the report figures of ``<workdir>/sweeps/grand`` / ``grand_long`` made before by
``grand`` / ``grand_long`` with the same ``--workdir`` (the grand cold sweep takes minutes; a
report-only re-measure takes the reports' time). Give either a part or its report-only part.

``--before <commit>``: the report figures (parts ``grand``, ``grand_long`` and their report-only
parts) are also measured for the code at that commit, on the same sweep folder, in the same run
(:func:`~experiments.tools.report_timing.report_figures`: a ``git clone --shared --no-checkout``
of this repository in the workdir checked out at the commit, its report run from there with
``PYTHONPATH`` on it; one untimed report by each code, then ``--rounds`` times before, today's,
alternating, the figures the medians): ``grand_report_before_s``,
``grand_report_before_peak_rss_mb``, ``grand_report_before_peak_pss_mb`` (and the
``grand_long_report_before_*`` ones), the ratios today / before ``grand_report_over_before``
(wall) and ``grand_report_peak_pss_over_before``, every round under ``grand_report_rounds``.

The targets (:data:`TARGETS`, each ``<figure>_max``; ``meets`` says which a report meets) include
issue 51's: the report of ``grand`` within 10 s and 1 GB proportional memory, that of
``grand_long`` within 1.5 GB, the served ``grand`` re-run within 6 s and the cold ``fp6_grid``
within 1.15× its unique compute floor.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from experiments import store
from experiments.data.first_run import ensure_model_files
from experiments.host.paths import base_dir, default_data_root
from experiments.host.provenance import code_version, machine, package_versions
from experiments.tools.floor import compute_floor, hydra_compose_seconds, steps_floor_ms
from experiments.tools.report_timing import clone_at, existing_sweep, report_figures
from experiments.tools.timed import sweep_breakdown, timed_sweep
from ttc.features.descriptors import RUBRIC_DESCRIPTORS
from ttc.features.keypoints import RUBRIC_DETECTORS

FULL = {"detectors": list(RUBRIC_DETECTORS), "descriptors": list(RUBRIC_DESCRIPTORS), "last": 18}
REDUCED = {"detectors": ["fast", "orb"], "descriptors": ["brief", "orb"], "last": 5}
TARGETS = {
    "cold_over_floor_unique_max": 1.15,
    "cold_over_floor_engine_max": 1.15,
    "warm_filter_fixed_s_max": 1.5,
    "warm_filter_lead_in_s_max": 1.0,
    "warm_filter_s_max": 6.0,
    "rerun_s_max": 3.0,
    "small_rerun_s_max": 2.0,
    "grand_cold_s_max": 600.0,
    "grand_warm_s_max": 6.0,
    "grand_peak_pss_mb_max": 2048.0,
    "grand_report_s_max": 10.0,
    "grand_report_peak_pss_mb_max": 1024.0,
    "grand_long_report_peak_pss_mb_max": 1536.0,
    "grand_report_peak_rss_mb_max": 1536.0,
    "grand_long_report_peak_rss_mb_max": 1536.0,
}
#: 8 settings on frames 0-3 (2 of them an invalid pair).
SMALL = ["-m", "detector=fast,akaze", "descriptor=brief,akaze", "matcher=bf,flann",
         "dataset.last=3"]  # fmt: skip
GRAND = ["+experiment=grand", "dataset.last=18"]
GRAND_WARM = [*GRAND, "keypoint_filter=zscore", "keypoint_filter.z=2.5"]
GRAND_LONG = ["+experiment=grand", "dataset.last=77"]
PARTS = ("fp6", "small", "grand", "grand_long", "long", "grand_report", "grand_long_report")
#: The parts of a run without ``--parts`` (the report-only ones re-measure what these make).
SWEEP_PARTS = PARTS[:5]
#: Every figure of a full run (``missing`` lists those a report lacks).
FIGURES = ("cold_s", "floor_unique_s", "cold_over_floor_unique", "floor_engine_s",
           "cold_over_floor_engine", "cold_fixed_s", "warm_filter_fixed_s", "warm_filter_s",
           "warm_filter_lead_in_s", "warm_filter_local_s", "rerun_s",
           "nocache_s", "small_cold_s", "small_rerun_s", "grand_cold_s", "grand_warm_s",
           "grand_warm_fixed_s", "grand_peak_rss_mb", "grand_peak_pss_mb", "grand_report_s",
           "grand_report_peak_rss_mb", "grand_report_peak_pss_mb", "grand_long_cold_s",
           "grand_long_report_s", "grand_long_report_peak_rss_mb",
           "grand_long_report_peak_pss_mb", "long_cold_s")  # fmt: skip
#: A comparison run (``--before``): the code at the earlier commit, how many rounds.
Before = tuple[Path | None, int]


def sweep_args(grid: dict[str, Any], name: str) -> list[str]:
    """Command-line overrides of the fp6_grid experiment restricted to ``grid``."""
    return [
        "+experiment=fp6_grid",
        f"detector={','.join(grid['detectors'])}",
        f"descriptor={','.join(grid['descriptors'])}",
        f"dataset.last={grid['last']}",
        f"sweep_name={name}",
    ]


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
    report["rerun_s"], _ = timed_sweep(sweep_args(grid, "cold"), results, cache, served=True)

    local_args = [*sweep_args(grid, "cold"), "keypoint_filter=zscore"]
    report["warm_filter_local_s"], local_runs = timed_sweep(local_args, results, cache)
    report["warm_filter_local_breakdown"] = sweep_breakdown(local_runs, cores)
    warm_args = [*sweep_args(grid, "cold"), "keypoint_filter=iqr"]
    report["warm_filter_s"], warm_runs = timed_sweep(warm_args, results, cache, served=True)
    report["warm_filter_breakdown"] = sweep_breakdown(warm_runs, cores)
    report["warm_filter_lead_in_s"] = report["warm_filter_breakdown"].get("lead_in_s")
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
    for name in ("cold", "warm_filter", "warm_filter_local"):
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


def grand_figures(workdir: Path, cores: int, before: Before = (None, 1)) -> dict[str, Any]:
    """``grand`` on frames 0-18 cold (own empty cache), then one downstream axis changed into
    the same folder (served), then :func:`grand_report_figures`."""
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
    warm, warm_runs = timed_sweep([*GRAND_WARM, "sweep_name=grand"], results, cache, served=True)
    split = sweep_breakdown(warm_runs, cores)
    report.update(grand_warm_s=warm, grand_warm_settings=len(warm_runs) - len(runs),
                  grand_warm_breakdown=split)  # fmt: skip
    if {"lead_in_s", "tail_s"} <= split.keys():
        report["grand_warm_fixed_s"] = split["lead_in_s"] + split["tail_s"]
    return {**report, **grand_report_figures(workdir, before)}


def grand_report_figures(workdir: Path, before: Before = (None, 1)) -> dict[str, Any]:
    """The report figures of ``<workdir>/sweeps/grand`` (:func:`report_figures`) and its rows."""
    sweep = existing_sweep(workdir / "sweeps" / "grand")
    report = report_figures("grand", sweep, workdir / "grand-report", workdir / "grand-cache",
                            *before)  # fmt: skip
    report["grand_frames_rows"] = store.row_count(store.list_records(sweep))
    return report


def grand_long_figures(workdir: Path, before: Before = (None, 1)) -> dict[str, Any]:
    """``grand`` on frames 0-77 cold (own empty cache), then :func:`grand_long_report_figures`."""
    cache, results = workdir / "grand-long-cache", workdir / "sweeps"
    memory: dict[str, float] = {}
    cold, runs = timed_sweep([*GRAND_LONG, "sweep_name=grand_long"], results, cache, memory)
    report: dict[str, Any] = {"grand_long_cold_s": cold, "grand_long_peak_pss_mb": memory["pss"],
                              "grand_long_settings": len(runs),
                              "grand_long_status": runs["status"].value_counts().to_dict()}  # fmt: skip
    return {**report, **grand_long_report_figures(workdir, before)}


def grand_long_report_figures(workdir: Path, before: Before = (None, 1)) -> dict[str, Any]:
    """The report figures of ``<workdir>/sweeps/grand_long`` and its rows."""
    sweep = existing_sweep(workdir / "sweeps" / "grand_long")
    report = report_figures("grand_long", sweep, workdir / "grand-long-report",
                            workdir / "grand-long-cache", *before)  # fmt: skip
    report["grand_long_rows"] = store.row_count(store.list_records(sweep))
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
    before: str | None = None,
    rounds: int = 1,
) -> dict[str, Any]:
    """The figures of ``parts`` (see the module docstring) and their targets; ``save(report)``
    is called after each part (a long benchmark stopped midway keeps what it measured).
    ``before``: a commit whose report is timed beside today's, ``rounds`` times each."""
    cores = os.cpu_count() or 1
    report: dict[str, Any] = {"cores": cores, "parts": list(parts), "report_rounds": rounds}
    code = None
    if before is not None and {"grand", "grand_long", *PARTS[5:]} & set(parts):
        code, report["before_commit"] = clone_at(before, workdir)
    compare: Before = (code, rounds)
    figures = {
        "fp6": lambda: fp6_figures(grid, workdir, cores, skip_nocache),
        "small": lambda: small_figures(workdir),
        "grand": lambda: grand_figures(workdir, cores, compare),
        "grand_long": lambda: grand_long_figures(workdir, compare),
        "long": lambda: long_figures(workdir),
        "grand_report": lambda: grand_report_figures(workdir, compare),
        "grand_long_report": lambda: grand_long_report_figures(workdir, compare),
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
    figures = {target.removesuffix("_max"): target for target in TARGETS}
    report["meets"] = {
        figure: report[figure] <= TARGETS[target]
        for figure, target in figures.items()
        if figure in report
    }
    report["missing"] = [k for k in FIGURES if k not in report]
    return report


def parse_parts(
    parser: argparse.ArgumentParser, text: str | None, reduced: bool, workdir: Path | None
) -> tuple[str, ...]:
    """The parts of ``--parts`` (comma-separated; default: all sweep parts, ``--reduced``:
    ``fp6,small``); unknown ones, a part with its report-only part, or a report-only part
    without ``--workdir`` are the ``parser``'s errors."""
    default = ("fp6", "small") if reduced else SWEEP_PARTS
    parts = tuple(text.split(",")) if text else default
    if unknown := set(parts) - set(PARTS):
        parser.error(f"unknown parts {sorted(unknown)}; known: {PARTS}")
    for part in ("grand", "grand_long"):
        if {part, f"{part}_report"} <= set(parts):
            parser.error(f"{part} times its reports already: give {part} or {part}_report")
    if workdir is None and {"grand_report", "grand_long_report"} & set(parts):
        parser.error("the report-only parts need --workdir (where their sweeps were made)")
    return parts


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reduced", action="store_true", help="small grid for CI")
    parser.add_argument("--skip-nocache", action="store_true", help="skip the cache-off sweep")
    parser.add_argument("--parts", help=f"comma-separated groups of {PARTS} (default: "
                        f"{','.join(SWEEP_PARTS)}; --reduced: fp6,small)")  # fmt: skip
    parser.add_argument("--out", type=Path, help="JSON report path")
    parser.add_argument("--workdir", type=Path, help="cache + sweeps folder (default: temp)")
    parser.add_argument("--before", metavar="COMMIT", help="also time the reports by the code "
                        "at COMMIT, alternating with today's")  # fmt: skip
    parser.add_argument("--rounds", type=int, default=1, help="reports timed per code and folder "
                        "(default 1; the figures are the medians)")  # fmt: skip
    args = parser.parse_args(argv)
    grid = REDUCED if args.reduced else FULL
    parts = parse_parts(parser, args.parts, args.reduced, args.workdir)
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
        report = run_benchmark(grid, workdir, args.skip_nocache, parts, save, args.before,
                               args.rounds)  # fmt: skip
    save(report)
    keys = ("settings", "cold_s", "floor_s", "floor_unique_s", "floor_engine_s", "cold_over_floor",
            "cold_over_floor_unique", "cold_over_floor_engine", "cold_fixed_s",
            "warm_filter_fixed_s", "nocache_s", "nocache_over_cold", "warm_filter_s",
            "rerun_s", "small_cold_s", "small_rerun_s", "grand_cold_s", "grand_warm_s",
            "grand_warm_fixed_s", "grand_peak_rss_mb", "grand_peak_pss_mb",
            "grand_main_peak_rss_mb", "grand_report_s", "grand_report_peak_rss_mb",
            "grand_report_peak_pss_mb", "grand_report_before_s",
            "grand_report_before_peak_pss_mb", "grand_report_over_before",
            "grand_report_peak_pss_over_before", "grand_long_cold_s", "grand_long_report_s",
            "grand_long_report_peak_rss_mb", "grand_long_report_peak_pss_mb",
            "grand_long_report_before_s", "grand_long_report_before_peak_pss_mb",
            "grand_long_report_over_before", "grand_long_report_peak_pss_over_before",
            "long_cold_s", "peak_rss_mb")  # fmt: skip
    for key in keys:
        if key in report:
            value = report[key]
            print(f"{key:>24}: {value:.2f}" if isinstance(value, float) else f"{key:>24}: {value}")
    for name in ("cold", "warm_filter_local", "warm_filter", "grand_warm"):
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
