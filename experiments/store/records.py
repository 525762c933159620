"""Run records: what a record holds before a run (ids, setting, versions, machine) and what
its outcome adds (status, message, times, memory, row statistics). Used for a setting run
alone (:mod:`experiments.run`), for the settings of a batch (:mod:`experiments.sweep.batch`) and
for invalid pairs recorded at planning time (:mod:`experiments.sweep.plan`)."""

from __future__ import annotations

import datetime as dt
import json
import resource
from typing import Any

import pandas as pd

from experiments.configs.structured import axis_values, setting_hash
from experiments.host.provenance import code_version, machine, package_versions
from ttc.settings import AXES


def now() -> str:
    """UTC now, ISO 8601 with milliseconds."""
    return dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")


def record_head(setting: dict[str, Any], sweep_id: str, cache_enabled: bool) -> dict[str, Any]:
    """The parts of a run record known before the run, from its :func:`setting_config`."""
    dataset = setting["dataset"]
    return {
        "run_id": setting_hash(setting),
        "sweep_id": sweep_id,
        **axis_values(setting),
        "first_frame": int(dataset["first"]),
        "last_frame": int(dataset["last"]),
        "step": int(dataset["step"]),
        "config": json.dumps(setting, sort_keys=True),
        **code_version(),
        **{f"version_{k}": v for k, v in package_versions().items()},
        **machine(),
        "cache_enabled": bool(cache_enabled),
        "start": now(),
    }


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def with_run_columns(rows: pd.DataFrame, record: dict[str, Any]) -> pd.DataFrame:
    """Prefix the rows with the run id, sweep id, axis values and code version."""
    front = {k: record[k] for k in ("run_id", "sweep_id", *AXES)}
    front["git_commit"] = record["git_commit"]
    return pd.concat([pd.DataFrame(front, index=rows.index), rows], axis=1)


def row_statistics(record: dict[str, Any], rows: pd.DataFrame) -> None:
    """Add what the rows of an ok run say to its record: stages computed (not from the
    cache), frame pairs with ``frame_error`` (count, and the first three in the message) and
    the frames lost (:func:`lost_frames`: count, and which in the message)."""
    cached = rows[[c for c in rows if c.startswith("cached_")]].to_numpy()
    record["stages_computed"] = int((~cached).sum())
    errors = rows.loc[rows["error"] != "", ["frame", "error"]].drop_duplicates("frame")
    record["n_frame_errors"] = len(errors)
    lost = lost_frames(rows)
    record["n_frames_lost"] = len(lost)
    if len(errors):
        record["message"] = (
            f"{len(errors)} frame pair(s) with frame_error, {len(lost)} frame(s) lost "
            f"({', '.join(map(str, lost))}): "
            + "; ".join(f"frame {f}: {e}" for f, e in errors.head(3).itertuples(index=False))
        )


def lost_frames(rows: pd.DataFrame) -> list[int]:
    """The frames every pair of which has a ``frame_error`` (a frame whose image or scan could
    not be read costs both pairs it is in), ascending."""
    pairs = rows[["prev_frame", "frame"]].drop_duplicates()
    failed = rows.loc[rows["error"] != "", ["prev_frame", "frame"]].drop_duplicates()
    if failed.empty:
        return []
    frames = pd.concat([pairs["prev_frame"], pairs["frame"]])
    bad = pd.concat([failed["prev_frame"], failed["frame"]])
    every = frames.value_counts()
    broken = bad.value_counts().reindex(every.index, fill_value=0)
    return sorted(int(f) for f in every.index[broken.to_numpy() == every.to_numpy()])
