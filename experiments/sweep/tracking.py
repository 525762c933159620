"""Experiment tracking: a finished sweep logged to MLflow, one parent run per sweep and one
child run per setting.

Switched on with ``+tracking=mlflow`` (``conf/tracking/mlflow.yaml``; install the extra with
``pip install -e ".[mlflow]"``). The store defaults to a SQLite file beside the sweeps
(``${results_root}/mlflow.db``); ``tracking.uri`` or ``$MLFLOW_TRACKING_URI`` point elsewhere
(``file:``, ``sqlite:`` or a tracking server). Browse with ``mlflow ui --backend-store-uri
sqlite:///sweeps/mlflow.db``.

What is logged. Parent: the sweep folder, its overrides, the code version, the counts of ok /
skipped / failed settings. Child, per setting: its axes as params; its status, run id, sweep
and the path of its rows file (``runs/<run_id>.parquet``) as tags; its metrics against the
reference (:func:`ttc.evaluation.run_metrics`, every numeric column; each run against its own
recording's reference, a generated recording's exact truth); its run record as the
artifact ``record.json``. Logging happens once, after every setting of the sweep has ended,
from the merged dataset (:func:`experiments.store.load_sweep`), so workers never write to the
store concurrently and a tracking failure never costs a setting.
"""

from __future__ import annotations

import json
import math
import numbers
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from experiments import store
from experiments.configs.structured import data_root
from experiments.summary.recordings import run_ids_by_recording
from experiments.summary.references import recording_references
from ttc import evaluation as ev
from ttc.engine.cache import StageCache
from ttc.settings import AXES

#: Tag names of the child runs (``ttc.`` prefix: the project's own).
TAG_RUN_ID, TAG_SWEEP, TAG_ROWS, TAG_STATUS = "ttc.run_id", "ttc.sweep", "ttc.rows", "ttc.status"


def _mlflow() -> Any:
    try:
        import mlflow  # noqa: PLC0415 (optional extra)
    except ImportError as exc:
        raise RuntimeError('tracking=mlflow needs MLflow: pip install -e ".[mlflow]"') from exc
    return mlflow


def _metrics_of(
    frames: pd.DataFrame, runs: pd.DataFrame, data_dir: Path | None, cache_dir: Path | None
) -> pd.DataFrame:
    """Metrics of the ok runs, each against its own recording's reference
    (:func:`experiments.summary.references.recording_references`: a generated recording's exact
    truth); empty when none is ok."""
    ok = runs[runs["status"] == "ok"]
    if ok.empty or frames.empty:
        return pd.DataFrame(columns=["run_id"])
    frames = ev.with_compute_times(frames)
    cache = StageCache(cache_dir) if cache_dir else None
    ids = run_ids_by_recording(ok)
    parts = [
        ev.run_metrics(frames[frames["run_id"].isin(ids[seq])], ref)
        for seq, ref in recording_references(frames, ok, data_dir, cache).items()
    ]
    return pd.concat(parts, ignore_index=True)


def _numbers(row: pd.Series) -> dict[str, float]:
    """The finite numeric values of a metrics row (MLflow takes floats, not NaN labels)."""
    out = {}
    for key, value in row.items():
        if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
            continue
        if math.isfinite(value):
            out[str(key)] = float(value)
    return out


def log_sweep(
    sweep_dir: Path,
    tracking_uri: str,
    experiment: str = "ttc-bench",
    artifact_location: str | None = None,
    data_dir: Path | None = None,
    cache_dir: Path | None = None,
) -> str:
    """Log the sweep in ``sweep_dir`` to MLflow at ``tracking_uri``; return the parent run id.

    ``artifact_location``: where a new ``experiment`` keeps its artifacts (MLflow's default
    for a database store is ``./mlruns`` in the working directory); ``data_dir`` /
    ``cache_dir``: where the reference's scans and cache are (default: the configured ones).
    """
    mlflow = _mlflow()
    from mlflow.entities import Metric, Param, RunTag  # noqa: PLC0415

    sweep_dir = Path(sweep_dir)
    frames, runs = store.load_sweep(sweep_dir)
    metrics = _metrics_of(frames, runs, data_dir, cache_dir)
    metrics = metrics.set_index("run_id") if "run_id" in metrics else metrics
    client = mlflow.MlflowClient(tracking_uri=tracking_uri)
    found = client.get_experiment_by_name(experiment)
    experiment_id = (
        found.experiment_id
        if found
        else client.create_experiment(experiment, artifact_location=artifact_location)
    )
    now = int(time.time() * 1000)

    counts = runs["status"].value_counts().to_dict() if "status" in runs else {}
    parent = client.create_run(
        experiment_id, run_name=sweep_dir.name, tags={TAG_SWEEP: str(sweep_dir.resolve())}
    )
    commits = sorted({str(c) for c in runs.get("git_commit", pd.Series(dtype=str)).dropna()})
    client.log_batch(
        parent.info.run_id,
        params=[Param("sweep", sweep_dir.name), Param("git_commit", ",".join(commits)[:500])],
        metrics=[Metric(f"settings_{k}", float(v), now, 0) for k, v in counts.items()],
    )
    for record in runs.to_dict("records"):
        run_id = record["run_id"]
        axes = {a: str(record[a]) for a in AXES if a in record}
        rows_file = record.get("rows_file")  # a batch's rows file, NaN in older records
        rows_path = store.rows_path(
            sweep_dir,
            {"run_id": run_id, "rows_file": rows_file if isinstance(rows_file, str) else None},
        )
        child = client.create_run(
            experiment_id,
            run_name=" ".join(axes.get(a, "") for a in AXES[:4]).strip() or run_id,
            tags={
                "mlflow.parentRunId": parent.info.run_id,
                TAG_RUN_ID: run_id,
                TAG_SWEEP: sweep_dir.name,
                TAG_STATUS: str(record.get("status")),
                TAG_ROWS: str(rows_path.resolve()),
            },
        )
        values = _numbers(metrics.loc[run_id]) if run_id in metrics.index else {}
        client.log_batch(
            child.info.run_id,
            params=[Param(k, v) for k, v in axes.items()],
            metrics=[Metric(k, v, now, 0) for k, v in values.items()],
            tags=[RunTag("ttc.message", str(record.get("message") or "")[:5000])],
        )
        record_text = json.dumps(record, default=str, indent=1)
        client.log_text(child.info.run_id, record_text, "record.json")
        status = "FINISHED" if record.get("status") in ("ok", "skipped") else "FAILED"
        client.set_terminated(child.info.run_id, status)
    client.set_terminated(parent.info.run_id, "FINISHED")
    return parent.info.run_id


class MLflowCallback(Callback):
    """Hydra callback: log the sweep to MLflow when it ends (:func:`log_sweep`). A tracking
    failure is reported and does not change the sweep's own outcome."""

    def __init__(
        self, tracking_uri: str, experiment: str = "ttc-bench", artifacts: str | None = None
    ) -> None:
        self.tracking_uri = tracking_uri
        self.experiment = experiment
        self.artifacts = artifacts

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        try:
            parent = log_sweep(
                sweep_dir,
                self.tracking_uri,
                self.experiment,
                self.artifacts,
                data_dir=data_root(config),
                cache_dir=Path(str(config.cache.dir)),
            )
        except Exception as exc:  # tracking is a view of the results: never fail the sweep
            print(f"MLflow tracking failed for {sweep_dir}: {type(exc).__name__}: {exc}")
            return
        print(f"MLflow: sweep logged as run {parent} at {self.tracking_uri}")
