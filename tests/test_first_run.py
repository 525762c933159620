"""Data on first run: a machine without the frames gets them from a (local) server, then runs."""

# ruff: noqa: F811  (the tests take the imported `server` fixture as an argument)

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from experiments.data import first_run
from experiments.host import paths
from tests.conftest import PROJECT_ROOT
from tests.test_download import server  # noqa: F401  (the local HTTP server fixture)


@pytest.fixture
def fresh_machine(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """No ``../shared/data`` and no ``$TTC_DATA_DIR``: the project's ``data/`` is the default."""
    monkeypatch.delenv("TTC_DATA_DIR", raising=False)
    monkeypatch.delenv(first_run.NO_DOWNLOAD_ENV, raising=False)
    monkeypatch.setattr(paths, "SHARED_DATA", tmp_path / "no_shared")
    monkeypatch.setattr(paths, "PROJECT_DATA", tmp_path / "project_data")
    return tmp_path / "project_data"


def test_first_run_downloads_the_frames_then_runs(server, fresh_machine, tmp_path, monkeypatch):
    url, state = server
    monkeypatch.setenv(first_run.URL_ENV, url)
    argv = first_run.ensure_data(["dataset.last=1", first_run.NO_DOWNLOAD_FLAG + "x"])
    sequence = fresh_machine / "kitti" / "2011_09_26"
    assert len(list((sequence / "image_02" / "data").glob("*.png"))) == 78
    assert len(list((sequence / "velodyne_points" / "data").glob("*.bin"))) == 78
    assert (sequence / "calib_velo_to_cam.txt").is_file() and len(state.requests) == 156
    assert argv == ["dataset.last=1", "--no-downloadx"]
    # a second start finds them: nothing fetched again
    first_run.ensure_data(["dataset.last=1"])
    assert len(state.requests) == 156
    # and the pipeline runs on what was downloaded
    env = {**os.environ, "TTC_DATA_DIR": str(fresh_machine), "TTC_RESULTS_DIR": str(tmp_path / "s"),
           "TTC_CACHE_DIR": str(tmp_path / "c")}  # fmt: skip
    done = subprocess.run([sys.executable, "-m", "experiments.run", "dataset.last=1", "print_rows=0"],
                          cwd=PROJECT_ROOT, env=env, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert "] ok in" in done.stdout


def test_no_download_flag_and_variable_turn_it_off(server, fresh_machine, monkeypatch):
    url, state = server
    monkeypatch.setenv(first_run.URL_ENV, url)
    assert first_run.ensure_data(["detector=orb", "--no-download"]) == ["detector=orb"]
    monkeypatch.setenv(first_run.NO_DOWNLOAD_ENV, "1")
    first_run.ensure_data(["detector=orb"])
    assert not fresh_machine.exists() and state.requests == []


def test_an_explicit_data_root_is_never_downloaded_into(
    server, fresh_machine, tmp_path, monkeypatch
):
    url, state = server
    monkeypatch.setenv(first_run.URL_ENV, url)
    first_run.ensure_data([f"dataset.root={tmp_path / 'mine'}"])
    monkeypatch.setenv("TTC_DATA_DIR", str(tmp_path / "mine"))
    first_run.ensure_data([])
    assert state.requests == [] and not (tmp_path / "mine").exists()
