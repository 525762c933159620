"""Run one setting (or, with ``-m`` / an experiment, a sweep of settings) through the pipeline.

Examples::

    python -m experiments.run detector=fast descriptor=brief dataset.last=10
    python -m experiments.run +experiment=fp6_grid            # the main sweep (multirun)
    python -m experiments.run -m detector=fast,orb matcher=glob(*) sweep_name=mine

One job = one setting: its rows go to ``<sweep>/runs/<run_id>.parquet`` and its record
(resolved config, code and package versions, timings, status, rows checksum, identities of
the input files read) to ``<run_id>.json``. A complete run (:func:`store.incomplete_reason`)
is not computed again (resume); any other is recomputed with a line saying why. Invalid
detector × descriptor pairs are recorded as ``skipped``, any other exception as ``failed``:
neither stops a sweep. A single run whose setting failed exits 1; a sweep exits 1 at its end
when a setting failed (:mod:`experiments.callbacks`).
"""

from __future__ import annotations

import datetime as dt
import json
import resource
import sys
import time
import traceback
from pathlib import Path
from typing import Any

import cv2
import hydra
import pandas as pd
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from experiments import store
from experiments.config import (
    config_problems,
    data_root,
    frame_range_from_config,
    missing_data_message,
    register_configs,
    setting_config,
    setting_hash,
    settings_from_config,
)
from experiments.provenance import code_version, machine, package_versions
from ttc.cache import StageCache
from ttc.descriptors import InvalidCombinationError
from ttc.pipeline import AXES, input_files, run_setting

register_configs()


def output_dir() -> Path:
    """The sweep folder in a multirun, the run folder otherwise."""
    hc = HydraConfig.get()
    return Path(hc.sweep.dir if hc.mode == RunMode.MULTIRUN else hc.run.dir)


def _now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")


def _axis_values(cfg: DictConfig) -> dict[str, str]:
    return {axis: str(cfg[axis].name) for axis in AXES}


def check_data(cfg: DictConfig) -> None:
    """Exit with a plain message when the data root is missing."""
    sequence_dir = data_root(cfg) / cfg.dataset.sequence
    if not sequence_dir.is_dir():
        sys.exit(missing_data_message(cfg))


def base_record(cfg: DictConfig, sweep_dir: Path) -> dict[str, Any]:
    """The parts of a run record known before the run: ids, setting, versions, machine."""
    setting = setting_config(cfg)
    return {
        "run_id": setting_hash(setting),
        "sweep_id": sweep_dir.name,
        **_axis_values(cfg),
        "first_frame": int(cfg.dataset.first),
        "last_frame": int(cfg.dataset.last),
        "step": int(cfg.dataset.step),
        "config": json.dumps(setting, sort_keys=True),
        **code_version(),
        **{f"version_{k}": v for k, v in package_versions().items()},
        **machine(),
        "cache_enabled": bool(cfg.cache.enabled),
        "start": _now(),
    }


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
        frames = frame_range_from_config(cfg)
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
        end=_now(),
        wall_s=time.perf_counter() - start,
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        n_rows=0 if rows is None else len(rows),
    )
    if rows is not None:
        rows = _with_run_columns(rows, record)
        cached = rows[[c for c in rows if c.startswith("cached_")]].to_numpy()
        record["stages_computed"] = int((~cached).sum())
        errors = rows.loc[rows["error"] != "", ["frame", "error"]].drop_duplicates("frame")
        record["n_frame_errors"] = len(errors)
        if len(errors):
            record["message"] = f"{len(errors)} frame pair(s) with frame_error: " + "; ".join(
                f"frame {f}: {e}" for f, e in errors.head(3).itertuples(index=False)
            )
    record["rows"] = rows
    return record


def record_crash(cfg: DictConfig, sweep_dir: Path, message: str) -> dict[str, Any]:
    """Record a run whose process died (signal, out of memory) as ``failed`` with
    ``message``; a re-run retries it. Returns the record."""
    record = base_record(cfg, sweep_dir)
    if store.is_complete(sweep_dir, record["run_id"]):  # died after finishing its run
        return store.read_record(sweep_dir, record["run_id"]) or record
    record.update(status="failed", message=message, end=_now(), n_rows=0, crashed=True)
    store.save_run(sweep_dir, record, None)
    mark_progress(sweep_dir, record)
    return record


def mark_progress(sweep_dir: Path, record: dict[str, Any]) -> None:
    """Tell the sweep's progress bar and summary that this job is finished."""
    marker = store.progress_dir(sweep_dir) / record["run_id"]
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.write_text("resumed" if record.get("resumed") else str(record.get("status")))


def _with_run_columns(rows: pd.DataFrame, record: dict[str, Any]) -> pd.DataFrame:
    """Prefix the rows with the run id, sweep id, axis values and code version."""
    front = {k: record[k] for k in ("run_id", "sweep_id", *AXES)}
    front["git_commit"] = record["git_commit"]
    return pd.concat([pd.DataFrame(front, index=rows.index), rows], axis=1)


SUMMARY_COLUMNS = ["frame", "curr_box", "ttc_lidar", "ttc_camera", "lidar_reason",
                   "camera_reason", "matches_in_box", "matches_kept"]  # fmt: skip


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    multirun = HydraConfig.get().mode == RunMode.MULTIRUN
    if not multirun:  # a sweep's configs are checked by the sweeper before any job runs
        problems = config_problems(cfg)
        if problems:
            sys.exit("invalid configuration:\n  " + "\n  ".join(problems))
    sweep_dir = output_dir()
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
        with pd.option_context("display.width", 140, "display.max_columns", 20):
            print(lead[SUMMARY_COLUMNS].head(cfg.print_rows).to_string(index=False))
        print(f"rows: {store.run_paths(sweep_dir, result['run_id'])[0]}")
    if result["status"] == "failed":
        sys.exit(1)


if __name__ == "__main__":
    main()
