"""KITTI's real gaps are per-frame facts: raw drive 0009 ships its full ``timestamps.txt``
(447 lines, blank at frames 177–180, where its scans are missing). Frames outside the range
do not matter; a blank line inside it gives that frame's pairs ``frame_error`` rows."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir

from experiments.configs.structured import (
    config_problems,
    frame_range_from_config,
    register_configs,
    run_id,
    settings_from_config,
)
from experiments.sweep.job import no_lead_line
from tests.conftest import PROJECT_ROOT
from ttc import reasons
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting
from ttc.io.calibration import CAM_TO_CAM, VELO_TO_CAM
from ttc.io.ego_motion import EGO_SPEED
from ttc.io.frames import IMAGE_DIR, LIDAR_DIR, read_frame_times

DATE = "2011_09_26"
DRIVE = f"kitti_raw/{DATE}/{DATE}_drive_0009_sync"


@pytest.fixture(scope="module")
def drive_0009(data_dir: Path) -> Path:
    seq = data_dir / DRIVE
    if not seq.is_dir():
        pytest.fail(f"{seq} not found (README of the data: kitti_raw/)")
    return seq


def composed(overrides: list[str]):
    register_configs()
    with initialize_config_dir(config_dir=str(PROJECT_ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def test_the_real_timestamps_have_blank_lines_past_the_frames(drive_0009: Path) -> None:
    lines = (drive_0009 / LIDAR_DIR.parent / "timestamps.txt").read_text().splitlines()
    assert len(lines) == 447
    assert [i for i, t in enumerate(lines) if not t.strip()] == [177, 178, 179, 180]
    times = read_frame_times(drive_0009)
    assert np.flatnonzero(np.isnan(times)).tolist() == [177, 178, 179, 180]
    assert np.all(np.diff(times[:11]) > 0.09) and np.all(np.diff(times[:11]) < 0.11)


def test_real_drive_0009_runs_frames_0_to_10(drive_0009: Path, data_dir: Path, tmp_path) -> None:
    """``python -m experiments.run dataset=kitti_raw dataset.drive=0009 dataset.last=10``: no
    refusal, ten pairs judged at the real frame times, no lead vehicle, and one line saying
    so. The range is named: ``../shared`` may hold more frames of the drive than it did."""
    drive = ["dataset=kitti_raw", "dataset.drive=0009", "dataset.last=10"]
    assert config_problems(composed(drive)) == []
    env = {
        **os.environ,
        "TTC_DATA_DIR": str(data_dir),
        "TTC_RESULTS_DIR": str(tmp_path / "sweeps"),
        "TTC_CACHE_DIR": str(tmp_path / "cache"),
    }
    args = [*drive, f"hydra.run.dir={tmp_path / 'run'}"]
    done = subprocess.run(
        [sys.executable, "-m", "experiments.run", *args], cwd=PROJECT_ROOT, env=env,
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert "no lead vehicle in frames 0–10: 10 of 10 pairs `no_lead_box`" in done.stdout
    assert "Empty DataFrame" not in done.stdout
    record_path = next((tmp_path / "run" / "runs").glob("*.json"))
    record = json.loads(record_path.read_text())
    assert record["status"] == "ok" and record["n_frame_errors"] == 0
    rows = pd.read_parquet(record_path.with_suffix(".parquet"))
    assert sorted(rows["frame"].unique()) == list(range(1, 11))
    assert not rows["is_lead"].any()
    times = read_frame_times(drive_0009)
    expected = rows["frame"].map(lambda k: round(times[k] - times[k - 1], 9))
    np.testing.assert_array_equal(rows["dt"], expected)
    speeds = rows.groupby("frame")[EGO_SPEED].agg(["min", "max"])  # the oxts vf: ≈ 10.7 m/s
    assert (speeds["min"] == speeds["max"]).all() and speeds["min"].between(9.0, 12.0).all()


def gapped_copy(drive_0009: Path, root: Path, blank: int) -> Path:
    """Drive 0009 under ``root/kitti_raw`` (frames and calibration symlinked, timestamps
    copied) with the lidar's line of frame ``blank`` emptied."""
    day = root / "kitti_raw" / DATE
    seq = day / drive_0009.name
    for name in (CAM_TO_CAM, VELO_TO_CAM):
        day.mkdir(parents=True, exist_ok=True)
        (day / name).symlink_to(drive_0009.parent / name)
    for folder in (IMAGE_DIR, LIDAR_DIR):
        (seq / folder).parent.mkdir(parents=True)
        (seq / folder).symlink_to(drive_0009 / folder)
        shutil.copy(drive_0009 / folder.parent / "timestamps.txt", seq / folder.parent)
    path = seq / LIDAR_DIR.parent / "timestamps.txt"
    lines = path.read_text().splitlines()
    lines[blank] = ""
    path.write_text("\n".join(lines) + "\n")
    return seq


def test_a_blank_line_inside_the_range_costs_its_pairs_only(drive_0009, tmp_path) -> None:
    seq = gapped_copy(drive_0009, tmp_path, blank=5)
    cfg = composed(
        ["dataset=kitti_raw", f"dataset.root={tmp_path}", "dataset.drive=0009", "dataset.last=10"]
    )
    assert config_problems(cfg) == []
    rows = run_setting(settings_from_config(cfg), frame_range_from_config(cfg), StageCache(None))
    errors = rows[rows["lidar_reason"] == reasons.FRAME_ERROR]
    assert errors[["prev_frame", "frame"]].values.tolist() == [[4, 5], [5, 6]]
    path = seq / LIDAR_DIR.parent / "timestamps.txt"
    assert (errors["error"] == f"{path}: line 6: blank timestamp: frame 5 was not recorded").all()
    assert errors["dt"].isna().all()
    others = rows[~rows["frame"].isin([5, 6])]
    assert sorted(others["frame"].unique()) == [1, 2, 3, 4, 7, 8, 9, 10]
    assert (others["error"] == "").all() and np.isfinite(others["dt"]).all()
    assert no_lead_line(rows) == (
        "no lead vehicle in frames 0–10: 8 of 10 pairs `no_lead_box`, 2 of 10 pairs `frame_error`"
    )


def test_the_no_lead_drive_has_its_own_option_with_the_same_run_ids() -> None:
    """``dataset=kitti_raw_0009`` (what ``+experiment=recordings`` sweeps) is the same
    recording, settings and run id as ``dataset=kitti_raw dataset.drive=0009
    dataset.last=15`` (the camera pair rule is one for every recording since issue 50: the
    option sets none of its own)."""
    option = composed(["dataset=kitti_raw_0009", "detector=orb"])
    spelled = composed(
        ["dataset=kitti_raw", "dataset.drive=0009", "dataset.last=15", "detector=orb"]
    )  # fmt: skip
    assert option.dataset.sequence.endswith("2011_09_26_drive_0009_sync")
    assert run_id(option) == run_id(spelled)
    assert run_id(option) != run_id(composed(["dataset=kitti_raw", "detector=orb"]))
