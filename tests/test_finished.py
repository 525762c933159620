"""The remembered sweep command (experiments/sweep/finished.py): what its key covers and when it
refuses to stand in for Hydra. The end-to-end checks (a re-run recognised, a damaged run
falling through to the sweeper) are in tests/test_batch.py and tests/test_faults.py."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from experiments.host import provenance
from experiments.sweep import finished
from tests.conftest import PROJECT_ROOT

SWEEP = ["-m", "detector=fast,orb", "dataset.last=2"]


def test_key_changes_with_the_command_line_and_environment(monkeypatch) -> None:
    key = finished.command_key(SWEEP)
    assert key is not None and key == finished.command_key(list(SWEEP))
    assert finished.command_key([*SWEEP, "lidar_ttc=cluster"]) != key
    assert finished.command_key(["+experiment=fp6_grid"]) is not None  # a sweep, no -m
    monkeypatch.setenv("TTC_CACHE_DIR", "/elsewhere")
    assert finished.command_key(SWEEP) != key
    monkeypatch.chdir(Path(os.sep))
    assert finished.command_key(SWEEP) not in (key, None)


@pytest.mark.parametrize(
    "argv",
    [
        ["detector=fast"],  # a single run: not a sweep
        [*SWEEP, "force=true"],
        [*SWEEP, "--config-dir", "/tmp/confs"],  # config files the key does not cover
        [*SWEEP, "hydra.searchpath=[file:///tmp]"],
        [*SWEEP, "hydra/launcher=slurm"],
    ],
)
def test_no_key_for_what_must_reach_hydra(argv) -> None:
    assert finished.command_key(argv) is None
    assert finished.report_if_finished(argv) is False


def test_key_changes_when_a_config_or_code_file_changes(tmp_path, monkeypatch) -> None:
    for root in provenance.SOURCE_ROOTS:
        shutil.copytree(PROJECT_ROOT / root, tmp_path / root)
    monkeypatch.setattr(provenance, "PROJECT_ROOT", tmp_path)
    key = finished.command_key(SWEEP)
    config = tmp_path / "conf" / "lidar_ttc" / "median.yaml"
    config.write_text(config.read_text() + "\n")
    assert finished.command_key(SWEEP) != key
    key = finished.command_key(SWEEP)
    code = tmp_path / "ttc" / "steps" / "lidar_ttc.py"
    stat = code.stat()
    os.utime(code, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000))
    assert finished.command_key(SWEEP) != key


def test_unknown_or_damaged_memo_falls_through(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("TTC_RESULTS_DIR", str(tmp_path))
    assert finished.report_if_finished(SWEEP) is False  # never planned
    path = finished.memo_path(finished.command_key(SWEEP))
    path.parent.mkdir(parents=True)
    path.write_text("{not json")
    assert finished.report_if_finished(SWEEP) is False
    path.write_text(json.dumps({"sweep_dir": str(tmp_path), "run_ids": ["0123456789abcdef"]}))
    assert finished.report_if_finished(SWEEP) is False  # its run has no record
