"""One setting's job in ``experiments.run``: compute it, store its rows and record, and tell the
user; the batch of settings a sweep's job computes (:func:`experiments.sweep.batch.run_batch`).

These are the imports of the computation (OpenCV, pandas, the engine): ``experiments.run``
(the Hydra entry, imported by every command and by the sweep's main process, which plans and
computes nothing) imports this module when a job runs, and a sweep's workers while the main
process plans (:func:`experiments.run.warm_up`).
"""

from __future__ import annotations

import sys
import time
import traceback
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd
from omegaconf import DictConfig

from experiments import store
from experiments.configs.structured import (
    prepared_frame_range,
    setting_config,
    setting_hash,
    settings_from_config,
)
from experiments.data.first_run import setting_models
from experiments.store import progress
from experiments.store.records import (
    now,
    peak_rss_mb,
    record_head,
    row_statistics,
    with_run_columns,
)
from experiments.sweep.batch import run_batch
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting
from ttc.engine.stages import input_files
from ttc.features.descriptors import InvalidCombinationError
from ttc.reasons import FRAME_ERROR, NO_LEAD_BOX
from ttc.settings import AXES


def base_record(cfg: DictConfig, sweep_dir: Path) -> dict[str, Any]:
    """The parts of a run record known before the run: ids, setting, versions, machine."""
    return record_head(setting_config(cfg), sweep_dir.name, bool(cfg.cache.enabled))


def setting_label(cfg: DictConfig) -> str:
    """``detector=fast descriptor=brief ...``: the setting in words."""
    return " ".join(f"{a}={cfg[a].name}" for a in AXES)


def run_job(cfg: DictConfig, sweep_dir: Path) -> dict[str, Any]:
    """Compute one setting and store its rows and record; return the record.

    A complete run (:func:`store.incomplete_reason`) is resumed; any other run that has a
    record is recomputed with a line saying why. One process computes a run id at a time
    (:func:`store.run_lock`), so two sweeps into one folder do not compute it twice.
    """
    rid = setting_hash(setting_config(cfg))
    with store.run_lock(sweep_dir, rid, setting_label(cfg)):
        reason = store.incomplete_reason(sweep_dir, rid)
        if not cfg.force and reason is None:
            record = store.read_record(sweep_dir, rid) or {}
            return {**record, "resumed": True}
        if reason not in (None, store.NO_RECORD) and not cfg.force:
            print(f"[{rid}] recomputing: {reason}", flush=True)
        record = _compute(cfg, sweep_dir)
        if reason not in (None, store.NO_RECORD):
            record["recomputed_because"] = reason
        rows = record.pop("rows")
        store.save_run(sweep_dir, record, rows)
    return {**record, "resumed": False, "rows": rows}


def _compute(cfg: DictConfig, sweep_dir: Path) -> dict[str, Any]:
    """Run the setting: its record (status ok/skipped/failed) with the rows under ``rows``."""
    cv2.setNumThreads(int(cfg.cv_threads))
    record = base_record(cfg, sweep_dir)
    start = time.perf_counter()
    rows = None
    try:
        settings = settings_from_config(cfg)
        setting_models(settings.objects)  # the detector's files (downloaded on first use)
        frames = prepared_frame_range(cfg)
        record["inputs"] = store.input_identities(input_files(settings, frames))
        cache = StageCache(cfg.cache.dir, enabled=cfg.cache.enabled)
        rows = run_setting(settings, frames, cache)
        status, message = "ok", ""
    except InvalidCombinationError as exc:
        status, message = "skipped", str(exc)
    except Exception as exc:  # a failing setting is recorded; the sweep goes on
        status, message = "failed", "".join(traceback.format_exception_only(exc)).strip()
        record["traceback"] = traceback.format_exc(limit=8)
    record.update(
        status=status,
        message=message,
        end=now(),
        wall_s=time.perf_counter() - start,
        peak_rss_mb=peak_rss_mb(),
        n_rows=0 if rows is None else len(rows),
    )
    if rows is not None:
        rows = with_run_columns(rows, record)
        row_statistics(record, rows)
    record["rows"] = rows
    return record


def record_crash(cfg: DictConfig, sweep_dir: Path, message: str) -> dict[str, Any]:
    """Record a run whose process died (signal, out of memory) as ``failed`` with
    ``message``; a re-run retries it. Returns the record."""
    record = base_record(cfg, sweep_dir)
    if store.is_complete(sweep_dir, record["run_id"]):  # died after finishing its run
        return store.read_record(sweep_dir, record["run_id"]) or record
    record.update(status="failed", message=message, end=now(), n_rows=0, crashed=True)
    store.save_run(sweep_dir, record, None)
    mark_progress(sweep_dir, record)
    return record


def mark_progress(sweep_dir: Path, record: dict[str, Any]) -> None:
    """Tell the sweep's progress bar and summary that this job is finished."""
    outcome = "resumed" if record.get("resumed") else str(record.get("status"))
    progress.mark_progress(sweep_dir, record["run_id"], [outcome])


SUMMARY_COLUMNS = ["frame", "curr_box", "ttc_lidar", "ttc_camera", "lidar_reason",
                   "camera_reason", "matches_in_box", "matches_kept"]  # fmt: skip


def no_lead_line(rows: pd.DataFrame) -> str | None:
    """One line for a run none of whose frame pairs has a lead vehicle (no lead row but the
    ``frame_error`` rows of unreadable pairs), e.g. ``no lead vehicle in frames 0–10: 10 of
    10 pairs `no_lead_box```; None when some pair has one (or there are no rows)."""
    if rows.empty:
        return None
    errors = rows["lidar_reason"] == FRAME_ERROR
    if (rows["is_lead"] & ~errors).any():
        return None
    pair = rows.assign(no_lead=rows["lidar_reason"] == NO_LEAD_BOX, error=errors)
    pair = pair.groupby(["prev_frame", "frame"])[["no_lead", "error"]].any()
    reason = np.where(pair["error"], FRAME_ERROR, np.where(pair["no_lead"], NO_LEAD_BOX, "other"))
    counts = pd.Series(reason).value_counts()
    told = ", ".join(f"{n} of {len(reason)} pairs `{r}`" for r, n in counts.items())
    first, last = int(rows["prev_frame"].min()), int(rows["frame"].max())
    return f"no lead vehicle in frames {first}–{last}: {told}"


def run_main(cfg: DictConfig, sweep_dir: Path, multirun: bool) -> None:
    """``experiments.run``'s job: a sweep's batch of settings, a sweep's one setting, or a
    single run with its lines and rows printed (exit 1 when it failed)."""
    if cfg.batch:  # a batch of settings planned by the sweeper (experiments.sweep.plan)
        for record in run_batch(cfg, sweep_dir):
            if record.get("status") == "failed" and not record.get("resumed"):
                label = " ".join(f"{a}={record.get(a)}" for a in AXES[:8])
                print(f"\n[{record['run_id']}] failed: {label}\n  {record['message']}")
        return
    result = run_job(cfg, sweep_dir)
    label = " ".join(f"{a}={result.get(a)}" for a in AXES[:8])
    if multirun:
        mark_progress(sweep_dir, result)
        if result["status"] == "failed" and not result.get("resumed"):
            print(f"\n[{result['run_id']}] failed: {label}\n  {result['message']}")
        return
    if result.get("resumed"):
        print(f"[{result['run_id']}] already complete ({result.get('status')}): {label}")
        print("  (force=true recomputes it)")
        return
    print(f"[{result['run_id']}] {result['status']} in {result['wall_s']:.2f} s: {label}")
    if result["status"] != "ok" or result.get("n_frame_errors"):
        print(f"  {result['message']}")
    if result["status"] == "ok" and cfg.print_rows:
        rows = result["rows"]
        lead = rows[rows["is_lead"]]
        if (line := no_lead_line(rows)) is not None:
            print(line)
        else:
            with pd.option_context("display.width", 140, "display.max_columns", 20):
                print(lead[SUMMARY_COLUMNS].head(cfg.print_rows).to_string(index=False))
        print(f"rows: {store.run_paths(sweep_dir, result['run_id'])[0]}")
    if result["status"] == "failed":
        sys.exit(1)
