"""MLflow round trip: a real 2-setting sweep logged into a temporary SQLite store and read
back with MLflow's own client (no mock)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from experiments import store
from tests.conftest import PROJECT_ROOT

mlflow = pytest.importorskip("mlflow")
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def tracked(tmp_path_factory) -> tuple[Path, str, subprocess.CompletedProcess]:
    tmp = tmp_path_factory.mktemp("tracking")
    uri = f"sqlite:///{tmp / 'mlflow.db'}"
    env = {**os.environ, "TTC_RESULTS_DIR": str(tmp / "sweeps"), "TTC_CACHE_DIR": str(tmp / "c"),
           "MLFLOW_TRACKING_URI": uri}  # fmt: skip
    args = ["-m", "detector=fast,orb", "descriptor=brief", "dataset.last=2", "sweep_name=tr",
            "+tracking=mlflow"]  # fmt: skip
    done = subprocess.run([sys.executable, "-m", "experiments.run", *args], cwd=PROJECT_ROOT,
                          env=env, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    return tmp / "sweeps" / "tr", uri, done


def test_one_parent_run_per_sweep_and_one_child_per_setting(tracked) -> None:
    sweep_dir, uri, done = tracked
    client = mlflow.MlflowClient(tracking_uri=uri)
    experiment = client.get_experiment_by_name("ttc-bench")
    found = client.search_runs([experiment.experiment_id])
    parents = [r for r in found if "mlflow.parentRunId" not in r.data.tags]
    children = [r for r in found if "mlflow.parentRunId" in r.data.tags]
    assert len(parents) == 1 and parents[0].info.run_name == "tr"
    assert parents[0].data.metrics["settings_ok"] == 2.0
    assert {c.data.tags["mlflow.parentRunId"] for c in children} == {parents[0].info.run_id}
    runs = store.load_runs(sweep_dir).set_index("run_id")
    assert {c.data.tags["ttc.run_id"] for c in children} == set(runs.index)
    assert parents[0].info.run_id in done.stdout


def test_child_runs_carry_axes_metrics_record_and_rows(tracked) -> None:
    sweep_dir, uri, _ = tracked
    client = mlflow.MlflowClient(tracking_uri=uri)
    experiment = client.get_experiment_by_name("ttc-bench")
    children = client.search_runs([experiment.experiment_id], "tags.`ttc.status` = 'ok'")
    assert sorted(c.data.params["detector"] for c in children) == ["fast", "orb"]
    for child in children:
        assert child.data.params["descriptor"] == "brief"
        assert child.data.metrics["n_frames"] == 2.0
        assert (
            "camera_mid_median" in child.data.metrics or "camera_invalid_rate" in child.data.metrics
        )
        assert Path(child.data.tags["ttc.rows"]).is_file()
        local = client.download_artifacts(child.info.run_id, "record.json", str(sweep_dir))
        record = json.loads(Path(local).read_text())
        assert record["run_id"] == child.data.tags["ttc.run_id"] and record["status"] == "ok"
        assert child.info.status == "FINISHED"


def test_artifacts_stay_beside_the_sweeps_not_in_the_working_directory(tracked) -> None:
    sweep_dir, _, _ = tracked
    assert list((sweep_dir.parent / "mlartifacts").rglob("record.json"))
    assert not (PROJECT_ROOT / "mlruns").exists()
