"""The command: parse → load the sweeps → reference → metrics beside each sweep → the
reference, FP.5 and FP.6 reports, with the seconds each step took."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib
import pyarrow as pa

from experiments import store
from experiments.data.first_run import fail
from experiments.host.heap import long_lived, release_freed_memory
from experiments.host.provenance import code_version
from experiments.report import (
    drives_report,
    forked,
    fp5,
    fp6,
    fp7,
    objects_report,
    recordings_report,
    reference_report,
    truth_report,
)
from experiments.report.detectors_report import objects_by_detector
from experiments.report.html import camera_pages, html_report, other_pages
from experiments.report.load import (
    Context,
    SweepData,
    load_sweeps,
    make_context,
    reference_for,
)
from experiments.summary.recordings import report_kind
from ttc import evaluation as ev
from ttc.features.model_files import ModelFileError


def write_sweep_metrics(data: SweepData, reference) -> list[Path]:
    """``metrics.parquet`` beside each sweep (its own runs, :func:`ttc.evaluation.sweep_metrics`;
    ``reference`` a dict drive name → reference for sweeps over several drives, each run
    against its own drive's, :func:`experiments.report.drives_report.sweep_metrics_by_drive`)."""
    written = []
    for d in data.dirs:
        runs = data.runs[data.runs["sweep_dir"] == str(d.resolve())]
        if runs.empty:
            continue
        frames = ev.rows_of_runs(data.frames, runs["run_id"])
        path = d / "metrics.parquet"
        if isinstance(reference, dict):
            table = drives_report.sweep_metrics_by_drive(frames, runs, reference)
        else:
            table = ev.sweep_metrics(frames, runs, reference)
        store.write_parquet_atomic(table, path)
        written.append(path)
    return written


def build_report(
    sweep_dirs: list[Path],
    out: Path,
    data_dir: Path | None = None,
    cache_dir: Path | None = None,
    pictures: bool = True,
    log: Callable[[str], None] = print,
    html: bool = True,
    real: list[Path] | None = None,
    one_process: bool = False,
) -> dict[str, Any]:
    """Metrics beside each sweep and both reports under ``out`` (with ``html``, the HTML
    report in ``out/html`` too); returns what was written and the seconds each step took.
    ``one_process``: FP.5 and every object in the report's own process after FP.6, not in a
    second one beside it (:mod:`.forked`): the same files, a lower peak of memory and a longer
    time (``grand`` 0–18: 1.28 GB and 36 s against 1.74 GB and 27 s)."""
    times: dict[str, float] = {}
    start = last = time.perf_counter()
    code_version()  # the report's code version before it writes anything (a report written
    # into the repository would otherwise find the tree dirty with its own first files)

    def lap(name: str) -> None:
        nonlocal last
        release_freed_memory()  # a step's transient tables: their pages back before the next
        now = time.perf_counter()
        times[name], last = now - last, now

    with long_lived() as kept:
        data = load_sweeps(sweep_dirs)
        kept()  # the sweeps loaded live to the end: out of the collector's passes
        if data.runs.empty:
            raise ValueError(f"no runs in {', '.join(map(str, sweep_dirs))}")
        kind = report_kind(data.frames, data.runs)
        if kind == "truth":  # a generated recording: judged against its exact truth
            summary = truth_report.truth_report(data, out, list(real or []))
            ctx = make_context(data_dir, cache_dir)
            summary["fp6"] = fp6.fp6_report(data, summary["reference"], ctx, out, pictures,
                                            against=fp6.AGAINST_TRUTH)  # fmt: skip
            truth_text = (out / "truth.md").read_text(encoding="utf-8")
            summary["html"] = html_report(data, summary["reference"], None, summary["fp6"], out,
                                          truth_text=truth_text) if html else None  # fmt: skip
            log(f"metrics: {', '.join(map(str, summary['metrics']))}\n"
                f"reports: {out / 'truth.md'}, {out / 'fp6_camera.md'}")  # fmt: skip
            if summary["html"] is not None:
                log(f"HTML report: {summary['html']}")
            return summary
        ctx = make_context(data_dir, cache_dir)
        out.mkdir(parents=True, exist_ok=True)
        lap("load")
        if kind == "drives":
            return build_drives_report(data, ctx, out, pictures, log, html)
        reference = reference_for(data, ctx)
        lap("reference")
        has_rows = not data.frames.empty
        side = forked.start(lambda: _side_sections(data, reference, ctx, out, pictures),
                            "FP.5 and every object", fork=not one_process)  # fmt: skip
        written = write_sweep_metrics(data, reference)
        lap("metrics")
        reference_report.reference_report(data, reference, out)
        lap("reference report")
        fp6_tables = fp6.fp6_report(data, reference, ctx, out, pictures) if has_rows else None
        ctx.drop_details()
        lap("fp6")
        fp7_tables = fp7.fp7_report(data, reference, out) if has_rows else None
        lap("fp7")
        if html:  # while the second process works
            camera_pages(data, fp6_tables, out)
            lap("html camera pages")
        fp5_table, by_detector, side_times = side.result()
        times.update(side_times)
        objects = next(iter(by_detector.values()), None)  # the detector most runs use
        lap("waited for fp5, objects")
        index = (
            other_pages(data, reference, fp5_table, fp6_tables, out, fp7_tables,
                        objects_ranking=objects) if html else None
        )  # fmt: skip
        lap("html")
        times["total"] = time.perf_counter() - start
        summary = {"metrics": written, "out": out, "times": times, "pair_details": ctx.calls,
                   "fp5": fp5_table, "fp6": fp6_tables, "fp7": fp7_tables,
                   "html": index}  # fmt: skip
        log(f"metrics: {', '.join(map(str, written))}")
        log(f"reports: {out} ({', '.join(sorted(p.name for p in out.glob('*.md')))})")
        if index is not None:
            log(f"HTML report: {index}")
        log("seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in times.items())
            + f"; {ctx.calls} pair details")  # fmt: skip
        return summary


def _side_sections(
    data: SweepData, reference, ctx: Context, out: Path, pictures: bool
) -> tuple[Any, dict[str, Any], dict[str, float]]:
    """The FP.5 and every-object sections ("side": in a second process, :mod:`.forked`,
    beside the reference, FP.6 and FP.7 sections, or after them with ``--one-process``):
    (FP.5's table or None, each detector's every-object ranking, the seconds each took)."""
    times: dict[str, float] = {}
    start = time.perf_counter()
    has_rows = not data.frames.empty
    fp5_table = fp5.fp5_report(data, reference, ctx, out, pictures) if has_rows else None
    ctx.drop_details()
    release_freed_memory()
    times["fp5 (side)"] = (middle := time.perf_counter()) - start
    by_detector = objects_by_detector(data, ctx, out) if has_rows else {}
    times["objects (side)"] = time.perf_counter() - middle
    return fp5_table, by_detector, times


def build_drives_report(
    data: SweepData,
    ctx: Context,
    out: Path,
    pictures: bool = True,
    log: Callable[[str], None] = print,
    html: bool = True,
) -> dict[str, Any]:
    """:func:`build_report` of sweeps over several drives: metrics beside each sweep (each
    run against its drive's reference), the reference, FP.5, FP.6 (and HTML) reports of each
    drive in ``out/<drive>/``, and the per-drive and pooled rankings in ``out/drives.md``
    (:mod:`experiments.report.drives_report`)."""
    start = time.perf_counter()
    references = drives_report.drive_references(data, ctx)
    written = write_sweep_metrics(data, references)
    object_rankings: dict[str, Any] = {}
    for name, part in drives_report.split_by_recording(data).items():
        folder, reference = out / name, references[name]
        folder.mkdir(parents=True, exist_ok=True)
        reference_report.reference_report(part, reference, folder)
        if part.frames.empty:
            continue
        fp5_table = fp5.fp5_report(part, reference, ctx, folder, pictures)
        fp6_tables = fp6.fp6_report(part, reference, ctx, folder, pictures)
        ctx.drop_details()
        fp7_tables = fp7.fp7_report(part, reference, folder)
        by_detector = objects_by_detector(part, ctx, folder)  # each against its own boxes
        object_rankings[name] = next(iter(by_detector.values()), None)
        if html:
            html_report(part, reference, fp5_table, fp6_tables, folder, fp7_tables,
                        objects_ranking=object_rankings[name])  # fmt: skip
    objects_report.cross_recording_objects(object_rankings, out)
    table = drives_report.drives_report(data, references, out) if not data.frames.empty else None
    finding = None
    if table is not None:
        finding = recordings_report.recordings_report(data, references, table, out)
    log(f"metrics: {', '.join(map(str, written))}")
    log(f"reports: {out}/drives.md, {out}/recordings.md and one folder per drive "
        f"({', '.join(references)})")  # fmt: skip
    if finding:
        log(finding)
    return {"metrics": written, "out": out, "drives": table, "recordings": finding,
            "pair_details": ctx.calls,
            "times": {"total": time.perf_counter() - start}}  # fmt: skip


def parser() -> argparse.ArgumentParser:
    """The command-line options."""
    p = argparse.ArgumentParser(
        prog="python -m experiments.report",
        description="The FP.5 (lidar) and FP.6 (camera) reports of one or more sweeps: "
        "markdown + CSV + pictures, and an HTML report (out/html/index.html).",
    )
    p.add_argument("sweep_dirs", type=Path, nargs="+", help="sweep folders")
    p.add_argument(
        "--out",
        type=Path,
        required=True,
        help="report folder (reports/<name>; results/ holds the committed ones)",
    )
    p.add_argument("--data-dir", type=Path, default=None,
                   help="data root (default: $TTC_DATA_DIR or the configured one)")  # fmt: skip
    p.add_argument("--cache-dir", type=Path, default=None,
                   help="stage cache (default: $TTC_CACHE_DIR or the configured one)")  # fmt: skip
    p.add_argument("--no-pictures", action="store_true", help="tables and plots only")
    p.add_argument("--no-html", action="store_true", help="no HTML report (out/html)")
    p.add_argument("--one-process", action="store_true",
                   help="FP.5 and every object after FP.6 in the report's own process, not in a "
                   "second one beside it: the same files, less memory at once, slower")  # fmt: skip
    p.add_argument("--real", type=Path, nargs="*", default=[],
                   help="scale_truth sweeps: real-sequence fp6_ranking.csv files to compare "
                   "the ranking with (Kendall's tau, the settings that move most)")  # fmt: skip
    return p


def main(argv: list[str] | None = None) -> None:
    """Run the command (``argv``: the arguments, default ``sys.argv[1:]``)."""
    matplotlib.use("Agg")  # files only
    # Arrow's buffers (the string columns) from glibc's heap, which release_freed_memory
    # trims after each step, not from mimalloc, which keeps what it freed: grand 0-18's
    # report peaks 0.07 GB lower (FP.6 1.49 -> 1.42 GB, objects 1.50 -> 1.42 GB)
    pa.set_memory_pool(pa.system_memory_pool())
    p = parser()
    args = p.parse_args(argv)
    for d in args.sweep_dirs:
        if not d.is_dir():
            p.error(f"{d} is not a folder")
    try:
        build_report(args.sweep_dirs, args.out, args.data_dir, args.cache_dir,
                     not args.no_pictures, html=not args.no_html, real=args.real,
                     one_process=args.one_process)  # fmt: skip
    except (store.StoreError, ModelFileError) as exc:  # a corrupt results file, a missing
        fail(f"report not written: {exc}", exc)  # model file: named, one message
