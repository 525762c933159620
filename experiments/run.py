"""Run one setting (or, with ``-m`` / an experiment, a sweep of settings) through the pipeline.

Examples::

    python -m experiments.run detector=fast descriptor=brief dataset.last=10
    python -m experiments.run +experiment=fp6_grid            # the main sweep (multirun)
    python -m experiments.run -m detector=fast,orb matcher=glob(*) sweep_name=mine

One job = one setting: its rows go to ``<sweep>/runs/<run_id>.parquet`` and its record
(resolved config, code and package versions, timings, status) to ``<run_id>.json``. A run
whose record already says ``ok`` or ``skipped`` is not computed again (resume). Invalid
detector × descriptor pairs are recorded as ``skipped``, any other exception as ``failed``:
neither stops a sweep.
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
from experiments.callbacks import PROGRESS_DIR
from experiments.config import (
    data_root,
    frame_range_from_config,
    register_configs,
    setting_config,
    setting_hash,
    settings_from_config,
)
from experiments.provenance import code_version, machine, package_versions
from ttc.cache import StageCache
from ttc.descriptors import InvalidCombinationError
from ttc.pipeline import AXES, run_setting

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
        sys.exit(
            f"KITTI frames not found: {sequence_dir} does not exist.\n"
            "Point TTC_DATA_DIR (or dataset.root=...) at a folder holding "
            f"{cfg.dataset.sequence}/, or fetch the 78 frames with:\n"
            f"  python -m experiments.download --data-root {data_root(cfg)}"
        )


def run_job(cfg: DictConfig, sweep_dir: Path) -> dict[str, Any]:
    """Compute one setting and store its rows and record; return the record."""
    setting = setting_config(cfg)
    rid = setting_hash(setting)
    if not cfg.force and store.is_complete(sweep_dir, rid):
        record = store.read_record(sweep_dir, rid) or {}
        return {**record, "resumed": True}

    cv2.setNumThreads(int(cfg.cv_threads))
    record: dict[str, Any] = {
        "run_id": rid,
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
    start = time.perf_counter()
    rows = None
    try:
        settings = settings_from_config(cfg)
        cache = StageCache(cfg.cache.dir, enabled=cfg.cache.enabled)
        rows = run_setting(settings, frame_range_from_config(cfg), cache)
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
    store.save_run(sweep_dir, record, rows)
    return {**record, "resumed": False, "rows": rows}


def mark_progress(sweep_dir: Path, record: dict[str, Any]) -> None:
    """Tell the sweep's progress bar and summary that this job is finished."""
    marker = sweep_dir / PROGRESS_DIR / record["run_id"]
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
    check_data(cfg)
    sweep_dir = output_dir()
    result = run_job(cfg, sweep_dir)
    label = " ".join(f"{a}={result.get(a)}" for a in AXES[:8])
    if HydraConfig.get().mode == RunMode.MULTIRUN:
        mark_progress(sweep_dir, result)
        if result["status"] == "failed" and not result.get("resumed"):
            print(f"\n[{result['run_id']}] failed: {label}\n  {result['message']}")
        return
    if result.get("resumed"):
        print(f"[{result['run_id']}] already complete ({result.get('status')}): {label}")
        print("  (force=true recomputes it)")
        return
    print(f"[{result['run_id']}] {result['status']} in {result['wall_s']:.2f} s: {label}")
    if result["status"] != "ok":
        print(f"  {result['message']}")
    elif cfg.print_rows:
        rows = result["rows"]
        lead = rows[rows["is_lead"]]
        with pd.option_context("display.width", 140, "display.max_columns", 20):
            print(lead[SUMMARY_COLUMNS].head(cfg.print_rows).to_string(index=False))
        print(f"rows: {store.run_paths(sweep_dir, result['run_id'])[0]}")


if __name__ == "__main__":
    main()
