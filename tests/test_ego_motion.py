"""``ego_speed_mps``: raw drive 0009's real oxts (forward speed ``vf`` at the frames' real
times), sequence 04's poses, NaN for drive 0052's Udacity copy and a raw drive without
``oxts/``; an exact synthetic check of the mean over a pair; per-packet gaps cost only the
pairs that need the packet; a changed oxts file changes the run's recorded inputs."""

from __future__ import annotations

import datetime as dt
import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir

from experiments import store
from experiments.configs.structured import (
    config_problems,
    frame_range_from_config,
    register_configs,
)
from tests.conftest import PROJECT_ROOT
from ttc.engine.stages import input_files
from ttc.features.descriptors import DESCRIPTORS
from ttc.features.keypoints import DETECTORS
from ttc.io import oxts
from ttc.io.calibration import CAM_TO_CAM, VELO_TO_CAM
from ttc.io.ego_motion import EGO_SPEED, pair_ego_speeds
from ttc.io.frames import (
    IMAGE_DIR,
    LIDAR_DIR,
    FrameDataError,
    frame_clock_ns,
    frame_pairs,
    with_truth,
)
from ttc.settings import FrameRange, Settings

DATE = "2011_09_26"
DRIVE = f"kitti_raw/{DATE}/{DATE}_drive_0009_sync"
ODOMETRY = "kitti_odometry/sequences/04"


def composed(overrides: list[str]):
    register_configs()
    with initialize_config_dir(config_dir=str(PROJECT_ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def pairs_of(indices: list[int]) -> pd.DataFrame:
    return pd.DataFrame(frame_pairs(indices), columns=["prev_frame", "frame"])


@pytest.fixture(scope="module")
def drive_0009(data_dir: Path) -> Path:
    seq = data_dir / DRIVE
    if not (seq / "oxts").is_dir():
        pytest.fail(f"{seq / 'oxts'} not found (README of the data: kitti_raw/)")
    return seq


@pytest.fixture(scope="module")
def speeds_0_15(drive_0009: Path) -> np.ndarray:
    """Ego speeds of drive 0009's pairs 0->1 ... 14->15 (the range named: dataset.last=15)."""
    cfg = composed(["dataset=kitti_raw", "dataset.drive=0009", "dataset.last=15"])
    assert config_problems(cfg) == []
    frames = frame_range_from_config(cfg)
    assert Path(frames.sequence_dir).resolve() == drive_0009.resolve()
    assert frames.indices == list(range(16))
    return pair_ego_speeds(drive_0009, frame_clock_ns(drive_0009), pairs_of(frames.indices))


def test_drive_0009_speed_is_the_oxts_forward_speed(drive_0009, speeds_0_15) -> None:
    names = [line.split(":")[0] for line in (drive_0009 / oxts.DATAFORMAT).read_text().split("\n")]
    assert names.index("vf") == 8 and len([n for n in names if n]) == 30  # column 9 of 30
    vf_0 = float((drive_0009 / oxts.DATA_DIR / "0000000000.txt").read_text().split()[8])
    assert vf_0 == pytest.approx(10.70, abs=0.005)  # the data README
    assert abs(speeds_0_15[0] - vf_0) < 0.05
    assert len(speeds_0_15) == 15 and ((speeds_0_15 > 9) & (speeds_0_15 < 12)).all()


def test_sequence_04_speed_from_its_poses(data_dir: Path) -> None:
    seq = data_dir / ODOMETRY
    speeds = pair_ego_speeds(seq, None, pairs_of(list(range(41))))
    assert ((speeds > 12.55) & (speeds < 13.75)).all(), speeds  # the data README: 12.6–13.7


def raw_copy(drive_0009: Path, root: Path, with_oxts: bool = True) -> Path:
    """Drive 0009 under ``root/kitti_raw`` (frames, calibration and lidar/camera timestamps
    symlinked), with a copy of its ``oxts/`` (to be damaged) or without one."""
    day = root / "kitti_raw" / DATE
    seq = day / drive_0009.name
    day.mkdir(parents=True)
    for name in (CAM_TO_CAM, VELO_TO_CAM):
        (day / name).symlink_to(drive_0009.parent / name)
    for folder in (IMAGE_DIR.parent, LIDAR_DIR.parent):
        (seq / folder).parent.mkdir(parents=True, exist_ok=True)
        (seq / folder).symlink_to(drive_0009 / folder)
    if with_oxts:
        shutil.copytree(drive_0009 / oxts.OXTS_DIR, seq / oxts.OXTS_DIR)
    return seq


def test_no_oxts_or_no_timestamps_gives_nan(drive_0009, kitti_dir, tmp_path) -> None:
    rows = pairs_of([0, 1, 2, 3]).assign(is_lead=False)
    udacity = with_truth(rows, kitti_dir)  # drive 0052's Udacity copy: no oxts, no timestamps
    assert udacity[EGO_SPEED].isna().all() and len(udacity) == 3
    bare = raw_copy(drive_0009, tmp_path, with_oxts=False)
    assert with_truth(rows, bare)[EGO_SPEED].isna().all()


def write_lines(path: Path, lines: list[str]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def kitti_times(seconds: list[float]) -> list[str]:
    start = dt.datetime(2011, 9, 26, 13, 0, 0)
    return [f"{start + dt.timedelta(seconds=s):%Y-%m-%d %H:%M:%S.%f}000" for s in seconds]


def test_mean_over_a_pair_is_the_integral_of_vf(tmp_path) -> None:
    """Packets at 0.0, 0.1, 0.2, 0.3 s with vf 10, 12, 12, 8 m/s (vf the 2nd of 3 columns);
    frames at -0.03 (before the first packet, within the 0.05 s edge), 0.05, 0.15, 0.25 and
    0.40 s (past the last packet by more than the edge)."""
    write_lines(tmp_path / oxts.DATAFORMAT, ["lat: x", "vf: forward (m/s)", "vl: left (m/s)"])
    write_lines(tmp_path / oxts.TIMESTAMPS, kitti_times([0.0, 0.1, 0.2, 0.3]))
    for k, vf in enumerate([10.0, 12.0, 12.0, 8.0]):
        write_lines(oxts.packet_path(tmp_path, k), [f"49.0 {vf} -0.5"])
    write_lines(tmp_path / LIDAR_DIR.parent / "timestamps.txt", kitti_times([-0.03, 0.05, 0.15, 0.25, 0.4]))  # fmt: skip
    speeds = pair_ego_speeds(tmp_path, frame_clock_ns(tmp_path), pairs_of([0, 1, 2, 3, 4]))
    # [-0.03, 0.05]: 10 held for 0.03 s, then 10 -> 11 over 0.05 s: (0.3 + 0.525) / 0.08
    # [0.05, 0.15]: 11 -> 12 over 0.05 s, 12 for 0.05 s: (0.575 + 0.6) / 0.1
    # [0.15, 0.25]: 12 for 0.05 s, 12 -> 10 over 0.05 s: (0.6 + 0.55) / 0.1
    np.testing.assert_allclose(speeds[:3], [10.3125, 11.75, 11.5], rtol=0, atol=1e-9)
    assert np.isnan(speeds[3])  # frame 4 is 0.1 s after the last packet
    assert pair_ego_speeds(tmp_path, frame_clock_ns(tmp_path), pairs_of([1, 3]))[0] == pytest.approx(11.625, abs=1e-9)  # fmt: skip


@pytest.mark.parametrize("blank", ["packet", "time"])
def test_a_blank_oxts_line_costs_the_pairs_that_need_it(drive_0009, speeds_0_15, tmp_path, blank):
    """Packet 5 (a blank data file, or a blank line 6 of oxts/timestamps.txt): frame 5 lies
    12 ms before packet 5, frames 5 and 6 between it and its neighbours, so pairs 4->5,
    5->6 and 6->7 need it; the other 12 pairs keep their speed exactly."""
    seq = raw_copy(drive_0009, tmp_path)
    if blank == "packet":
        oxts.packet_path(seq, 5).write_text("\n")
    else:
        lines = (seq / oxts.TIMESTAMPS).read_text().splitlines()
        write_lines(seq / oxts.TIMESTAMPS, [*lines[:5], "", *lines[6:]])
    speeds = pair_ego_speeds(seq, frame_clock_ns(seq), pairs_of(list(range(16))))
    assert np.flatnonzero(np.isnan(speeds)).tolist() == [4, 5, 6]
    keep = ~np.isnan(speeds)
    np.testing.assert_array_equal(speeds[keep], speeds_0_15[keep])


def test_a_malformed_packet_costs_its_pairs_and_a_bad_file_names_itself(drive_0009, tmp_path):
    seq = raw_copy(drive_0009, tmp_path)
    words = oxts.packet_path(seq, 10).read_text().split()
    oxts.packet_path(seq, 10).write_text(" ".join(words[:20]) + "\n")  # 20 of 30 numbers
    speeds = pair_ego_speeds(seq, frame_clock_ns(seq), pairs_of(list(range(16))))
    assert np.flatnonzero(np.isnan(speeds)).tolist() == [9, 10, 11]
    lines = (seq / oxts.TIMESTAMPS).read_text().splitlines()
    write_lines(seq / oxts.TIMESTAMPS, [*lines[:2], "2011-09-26 13:08:2x.1", *lines[3:]])
    with pytest.raises(FrameDataError, match=r"oxts/timestamps.txt: line 3: malformed timestamp"):
        pair_ego_speeds(seq, frame_clock_ns(seq), pairs_of([0, 1]))
    assert "line 3: malformed timestamp" in oxts.layout_problems(seq)[0]
    write_lines(seq / oxts.TIMESTAMPS, lines)
    fmt = seq / oxts.DATAFORMAT
    fmt.write_text(fmt.read_text().replace("vf:", "vx:"))
    with pytest.raises(FrameDataError) as info:
        pair_ego_speeds(seq, frame_clock_ns(seq), pairs_of([0, 1]))
    assert str(info.value) == f"{fmt}: no column 'vf' (forward speed) among 30 names"


def test_the_run_inputs_hold_the_oxts_packets_of_its_frames(drive_0009, tmp_path) -> None:
    """A run over frames 0–15 records oxts/timestamps.txt, dataformat.txt and packets 0–15
    (frame 15 is before packet 15): changing one of them marks the run's inputs changed."""
    seq = raw_copy(drive_0009, tmp_path)
    setting = Settings(detector=DETECTORS["fast"](), descriptor=DESCRIPTORS["brief"]())
    files = input_files(setting, FrameRange(seq, 0, 15))
    used = [f for f in files if oxts.OXTS_DIR.name in f.parts]
    assert used == [seq / oxts.TIMESTAMPS, seq / oxts.DATAFORMAT] + [
        oxts.packet_path(seq, k) for k in range(16)
    ]
    recorded = store.input_identities(files)
    assert store.changed_inputs(recorded) == []
    packet = oxts.packet_path(seq, 7)
    os.utime(packet, ns=(packet.stat().st_atime_ns, packet.stat().st_mtime_ns + 1_000_000))
    assert store.changed_inputs(recorded) == [str(packet)]
