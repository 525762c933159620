"""One batch of settings in one job (``batch=<id>``, planned by :mod:`experiments.sweep.plan`).

The batch's settings run together through :func:`ttc.engine.runner.run_settings` (expensive stages
streamed once per upstream group, FP.1–FP.4 pieces computed once per pair for the settings
that share them). What users rely on stays per setting: each setting keeps its run id and
gets its own record with its resolved config; a complete setting is resumed, a setting
that raises is recorded as ``failed`` (``skipped`` for an invalid pair) without touching the
others. The rows of the batch's ok settings go to one file, ``runs/<batch>-<sha>.parquet``,
that each of their records names (``rows_file``); the merged dataset is the same.
"""

from __future__ import annotations

import time
import traceback
from pathlib import Path
from typing import Any

import cv2
import pandas as pd
from omegaconf import DictConfig

from experiments import store
from experiments.configs.structured import prepared_frame_range
from experiments.data.first_run import setting_models
from experiments.store import progress
from experiments.store.records import now, peak_rss_mb, record_head, row_statistics
from experiments.sweep.compose import core_settings
from experiments.sweep.plan import read_plan
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_settings
from ttc.engine.stages import input_files
from ttc.features.descriptors import InvalidCombinationError
from ttc.rows import MEMBER
from ttc.settings import AXES


def run_batch(cfg: DictConfig, sweep_dir: Path) -> list[dict[str, Any]]:
    """Compute the incomplete settings of batch ``cfg.batch`` and store their rows and
    records; return every member's record (``resumed`` set for those already complete).

    One process computes a batch at a time (:func:`store.run_lock` on the batch id); each
    member's completeness is checked under the lock.
    """
    plan = read_plan(sweep_dir, cfg.batch)
    members = plan["members"]
    label = f"{cfg.batch}: {batch_label(members)}"
    with store.run_lock(sweep_dir, cfg.batch, label):
        todo, done, checks = [], [], store.Checks()
        for member in members:
            reason = store.incomplete_reason(sweep_dir, member["run_id"], checks)
            if not cfg.force and reason is None:
                record = store.read_record(sweep_dir, member["run_id"]) or {}
                done.append({**record, "resumed": True})
                continue
            if reason not in (None, store.NO_RECORD) and not cfg.force:
                print(f"[{member['run_id']}] recomputing: {reason}", flush=True)
            todo.append({**member, "reason": reason})
        records = _compute(cfg, sweep_dir, todo) if todo else []
    outcomes = ["resumed"] * len(done) + [str(r["status"]) for r in records]
    progress.mark_progress(sweep_dir, cfg.batch, outcomes)
    return done + records


def batch_label(members: list[dict[str, Any]]) -> str:
    """``detector=fast descriptor=orb ... (4 settings)``: the axes all members share, named
    like a setting (the holder of the batch's lock)."""
    shared = [
        f"{axis}={values.pop()}"
        for axis in AXES
        if len(values := {str(m["setting"][axis]["name"]) for m in members}) == 1
    ]
    return " ".join(shared) + f" ({len(members)} settings)"


def _compute(cfg: DictConfig, sweep_dir: Path, todo: list[dict[str, Any]]) -> list[dict]:
    """Run the members of ``todo`` together; save and return their records."""
    cv2.setNumThreads(int(cfg.cv_threads))
    start = time.perf_counter()
    records = [record_head(m["setting"], sweep_dir.name, bool(cfg.cache.enabled)) for m in todo]
    made = core_settings([m["setting"] for m in todo])  # a bad value costs only its setting
    errors: dict[int, BaseException] = {
        i: s for i, s in enumerate(made) if isinstance(s, Exception)
    }
    settings = [None if isinstance(s, Exception) else s for s in made]
    valid = [i for i, s in enumerate(settings) if s is not None]
    rows = pd.DataFrame()
    try:
        frames = prepared_frame_range(cfg)
        # each detector's files found (a copy the sweep downloaded), once per distinct entry:
        # settings made together share one objects entry per distinct value (core_settings)
        for objects in {id(settings[i].objects): settings[i].objects for i in valid}.values():
            setting_models(objects)
        inputs = store.input_identities(input_files(settings[valid[0]], frames)) if valid else ""
        cache = StageCache(cfg.cache.dir, enabled=cfg.cache.enabled)
        rows, failed = run_settings([settings[i] for i in valid], frames, cache)
        errors.update({valid[k]: exc for k, exc in failed.items()})
        if len(rows):
            rows[MEMBER] = rows[MEMBER].map(dict(enumerate(valid)))
    except Exception as exc:  # the batch's shared part raised: every member fails with it
        errors.update(dict.fromkeys(valid, exc))
    wall = time.perf_counter() - start
    rows = _with_run_columns(rows, records)
    counts = rows[MEMBER].value_counts() if len(rows) else pd.Series(dtype=int)
    stats, peak = _statistics(rows), peak_rss_mb()
    for i, (member, record) in enumerate(zip(todo, records, strict=True)):
        _outcome(record, errors.get(i), int(counts.get(i, 0)), wall / len(todo))
        record["peak_rss_mb"] = peak
        record.update(batch_id=cfg.batch, batch_size=len(todo), batch_wall_s=wall)
        if member["reason"] not in (None, store.NO_RECORD):
            record["recomputed_because"] = member["reason"]
        if record["status"] == "ok":
            record["inputs"] = inputs
            record["stages_computed"] = int(stats["computed"].get(i, 0))
            record["n_frame_errors"] = record["n_frames_lost"] = 0
            if i in stats["errors"]:  # rare: the rows of that run say which frames
                row_statistics(record, rows[rows[MEMBER] == i])
    ok = {i for i, r in enumerate(records) if r["status"] == "ok"}
    rows = rows[rows[MEMBER].isin(ok)] if len(rows) else rows
    store.save_batch(sweep_dir, cfg.batch, records, rows.drop(columns=MEMBER, errors="ignore"))
    return records


def _statistics(rows: pd.DataFrame) -> dict[str, Any]:
    """Per member: stages computed (not from the cache), and the members with frame errors
    (what :func:`experiments.store.records.row_statistics` finds, for all members at once)."""
    if not len(rows):
        return {"computed": pd.Series(dtype=int), "errors": set()}
    cached = rows[[c for c in rows if c.startswith("cached_")]].to_numpy(dtype=bool)
    computed = pd.Series((~cached).sum(axis=1), index=rows.index).groupby(rows[MEMBER]).sum()
    errors = set(rows.loc[rows["error"] != "", MEMBER].tolist())
    return {"computed": computed, "errors": errors}


def _outcome(record: dict, error: BaseException | None, n_rows: int, wall_s: float) -> None:
    """Status, message and end of a member's record."""
    if error is None:
        status, message = "ok", ""
    elif isinstance(error, InvalidCombinationError):
        status, message = "skipped", str(error)
    else:
        status = "failed"
        message = "".join(traceback.format_exception_only(error)).strip()
        record["traceback"] = "".join(traceback.format_exception(error, limit=8))
    record.update(status=status, message=message, end=now(), wall_s=wall_s,
                  n_rows=n_rows if status == "ok" else 0)  # fmt: skip


def _with_run_columns(rows: pd.DataFrame, records: list[dict[str, Any]]) -> pd.DataFrame:
    """Prefix the rows with their run's id, sweep id, axis values and code version (the
    columns :func:`experiments.store.records.with_run_columns` gives a run's own rows)."""
    if not len(rows):
        return rows
    keys = ("run_id", "sweep_id", *AXES, "git_commit")
    front = {k: rows[MEMBER].map({i: r[k] for i, r in enumerate(records)}) for k in keys}
    return pd.concat([pd.DataFrame(front, index=rows.index), rows], axis=1)
