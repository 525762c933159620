"""Shared fixtures: every test reads the real KITTI frames from the configurable data root."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[1]
#: The suite's commands run without the warm server (experiments.warm), which would outlive
#: them; tests/test_warm_server.py turns it on for its own commands.
os.environ.setdefault("TTC_BENCH_SERVER", "0")
DEFAULT_DATA_ROOT = PROJECT_ROOT.parent / "shared" / "data"


def data_root() -> Path:
    """The data root: ``$TTC_DATA_DIR`` when set, else ``../shared/data`` beside the project."""
    return Path(os.environ.get("TTC_DATA_DIR", DEFAULT_DATA_ROOT)).resolve()


@pytest.fixture(scope="session")
def data_dir() -> Path:
    root = data_root()
    if not (root / "kitti").is_dir():
        pytest.fail(f"KITTI data not found under {root}; set TTC_DATA_DIR")
    return root


@pytest.fixture(scope="session")
def kitti_dir(data_dir: Path) -> Path:
    """Folder of the 2011_09_26 sequence (image_02/, velodyne_points/, calib_*.txt)."""
    return data_dir / "kitti" / "2011_09_26"


def copy_frames(kitti_dir: Path, target: Path, indices: range | list[int]) -> Path:
    """Copy frames (image + scan) and both calibration files to ``target`` (to be damaged)."""
    from ttc.io.calibration import CAM_TO_CAM, VELO_TO_CAM
    from ttc.io.frames import frame_files

    for index in indices:
        files = frame_files(kitti_dir, index)
        for src in (files.image, files.scan):
            dst = target / src.relative_to(kitti_dir)
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(src, dst)
    for name in (CAM_TO_CAM, VELO_TO_CAM):
        shutil.copy(kitti_dir / name, target / name)
    return target
