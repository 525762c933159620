"""Report pages name folders relative to the working directory (exact checks)."""

from __future__ import annotations

from pathlib import Path

import pytest

from experiments.host.paths import shown


def test_a_folder_under_the_working_directory_is_named_relative(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert shown(tmp_path / "sweeps" / "fp6_grid_kitti_0_18") == "sweeps/fp6_grid_kitti_0_18"
    assert shown("sweeps/mine") == "sweeps/mine"


def test_a_folder_elsewhere_stays_absolute(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "here").mkdir()
    monkeypatch.chdir(tmp_path / "here")
    assert shown(tmp_path / "there" / "s") == (tmp_path / "there" / "s").as_posix()
