"""Results store: one folder per sweep, one record + parquet file per run, merged datasets.

Layout of a sweep folder::

    <sweep>/runs/<run_id>.parquet     frame-pair rows of one run (written first)
    <sweep>/runs/<run_id>.json        the run record (written last: marks the run complete)
    <sweep>/frames.parquet            every run's rows, merged (collect)
    <sweep>/runs.parquet              every run record, merged (collect)

Every file is written to a temporary name in the same folder and renamed into place, so a
killed sweep leaves whole files or none. Only these names are read; Hydra's job folders and
logs beside them are ignored.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Any

import pandas as pd

from ttc.atomic import atomic_write

RUNS_DIR = "runs"
FRAMES_FILE = "frames.parquet"
RUNS_FILE = "runs.parquet"
COMPLETE_STATUSES = ("ok", "skipped")


def write_parquet_atomic(df: pd.DataFrame, path: Path) -> None:
    """Write ``df`` to ``path`` as parquet, atomically."""
    atomic_write(path, lambda tmp: df.to_parquet(tmp, index=False))


def write_json_atomic(obj: Any, path: Path) -> None:
    """Write ``obj`` to ``path`` as JSON, atomically."""
    atomic_write(path, lambda tmp: tmp.write_text(json.dumps(obj, indent=1, default=str)))


def run_paths(sweep_dir: Path, run_id: str) -> tuple[Path, Path]:
    """(rows parquet, record json) of one run."""
    base = Path(sweep_dir) / RUNS_DIR
    return base / f"{run_id}.parquet", base / f"{run_id}.json"


def read_record(sweep_dir: Path, run_id: str) -> dict[str, Any] | None:
    """The record of a run, or None when absent or unreadable."""
    _, record_path = run_paths(sweep_dir, run_id)
    try:
        return json.loads(record_path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def is_complete(sweep_dir: Path, run_id: str) -> bool:
    """True when the run finished as ok (rows present) or skipped."""
    record = read_record(sweep_dir, run_id)
    if record is None or record.get("status") not in COMPLETE_STATUSES:
        return False
    rows_path, _ = run_paths(sweep_dir, run_id)
    return record["status"] == "skipped" or rows_path.is_file()


def save_run(sweep_dir: Path, record: dict[str, Any], rows: pd.DataFrame | None) -> None:
    """Store a run: rows first, then the record that marks it complete."""
    rows_path, record_path = run_paths(sweep_dir, record["run_id"])
    if rows is not None:
        write_parquet_atomic(rows, rows_path)
    write_json_atomic(record, record_path)


def list_records(sweep_dir: Path) -> list[dict[str, Any]]:
    """Every readable run record of a sweep, sorted by run id."""
    records = []
    for path in sorted((Path(sweep_dir) / RUNS_DIR).glob("*.json")):
        with contextlib.suppress(json.JSONDecodeError, OSError):
            records.append(json.loads(path.read_text()))
    return records


def collect(sweep_dir: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Merge every run's rows and records into ``frames.parquet`` and ``runs.parquet``.

    Call it when no job of the sweep is running (end of a multirun, or after a kill): it also
    deletes temporary files that killed jobs left behind.
    """
    sweep_dir = Path(sweep_dir)
    for stale in (sweep_dir / RUNS_DIR).glob(".*.tmp"):  # left by a killed job
        stale.unlink(missing_ok=True)
    records = list_records(sweep_dir)
    runs = pd.DataFrame.from_records(records)
    frames_parts = []
    for record in records:
        rows_path, _ = run_paths(sweep_dir, record["run_id"])
        if record.get("status") == "ok" and rows_path.is_file():
            frames_parts.append(pd.read_parquet(rows_path))
    frames = pd.concat(frames_parts, ignore_index=True) if frames_parts else pd.DataFrame()
    if not runs.empty:
        runs = runs.sort_values("run_id", ignore_index=True)
    write_parquet_atomic(runs, sweep_dir / RUNS_FILE)
    write_parquet_atomic(frames, sweep_dir / FRAMES_FILE)
    return frames, runs
