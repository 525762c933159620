"""One setting end to end on the real frames 0–18 (FAST + BRIEF + BF + kNN)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments.store.schema import FRAME_COLUMNS, schema_problems
from tests.conftest import copy_frames
from ttc import reasons
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting
from ttc.features.descriptors import DESCRIPTORS, InvalidCombinationError
from ttc.features.keypoints import DETECTORS
from ttc.io.frames import frame_files
from ttc.settings import AXES, FrameRange, Settings
from ttc.steps.lidar_ttc import LidarTTCParams

RUN_COLUMNS = {"run_id", "sweep_id", "git_commit", *AXES}


def check_frame_columns(frames: pd.DataFrame, core_only: bool = False) -> None:
    """Every documented column is present with its documented type."""
    problems = schema_problems(frames)
    if core_only:
        problems = [p for p in problems if p.split()[-1] not in RUN_COLUMNS]
    assert not problems, problems
    documented = {name for name, *_ in FRAME_COLUMNS}
    assert set(frames.columns) <= documented, set(frames.columns) - documented


def settings(detector: str = "fast", descriptor: str = "brief", **kwargs) -> Settings:
    return Settings(detector=DETECTORS[detector](), descriptor=DESCRIPTORS[descriptor](), **kwargs)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("stage-cache")


@pytest.fixture(scope="module")
def rows_0_18(kitti_dir: Path, cache_dir: Path) -> pd.DataFrame:
    s = settings(lidar_ttc=LidarTTCParams(name="median"))
    return run_setting(s, FrameRange(kitti_dir, 0, 18), StageCache(cache_dir))


def test_every_pair_has_a_matched_lead_box(rows_0_18: pd.DataFrame) -> None:
    lead = rows_0_18[rows_0_18["is_lead"]]
    assert lead["frame"].tolist() == list(range(1, 19))
    assert (lead["prev_box"] >= 0).all()
    assert (lead["box_shared_matches"] > 0).all()


def test_median_lidar_ttc_between_7_and_20_s(rows_0_18: pd.DataFrame) -> None:
    lead = rows_0_18[rows_0_18["is_lead"]]
    assert (lead["lidar_reason"] == reasons.OK).all()
    assert lead["ttc_lidar"].between(7.0, 20.0).all(), lead[["frame", "ttc_lidar"]]
    assert (lead["lidar_points_curr"] > 100).all()
    assert lead["d_curr"].between(6.5, 8.1).all()


def test_camera_ttc_mostly_finite_and_plausible(rows_0_18: pd.DataFrame) -> None:
    lead = rows_0_18[rows_0_18["is_lead"]]
    finite = lead[np.isfinite(lead["ttc_camera"])]
    assert len(finite) >= 15
    assert finite["ttc_camera"].median() == pytest.approx(12.5, abs=4.0)
    assert (lead["matches_kept"] <= lead["matches_in_box"]).all()
    assert (lead["matches_kept"] + lead["matches_removed"] == lead["matches_in_box"]).all()


def test_columns_and_types(rows_0_18: pd.DataFrame) -> None:
    check_frame_columns(rows_0_18, core_only=True)
    other = rows_0_18[~rows_0_18["is_lead"]]
    assert len(other) > 0  # the other matched boxes are kept too
    assert not other.duplicated(["frame", "curr_box"]).any()
    assert rows_0_18.groupby("frame")["is_lead"].sum().eq(1).all()  # exactly one lead per pair
    assert (rows_0_18["error"] == "").all()


def test_second_run_reads_every_stage_from_cache(
    kitti_dir: Path, cache_dir: Path, rows_0_18
) -> None:
    again = run_setting(settings(lidar_ttc=LidarTTCParams(name="median")), FrameRange(kitti_dir, 0, 18),
                        StageCache(cache_dir))  # fmt: skip
    assert again.filter(like="cached_").to_numpy().all()
    pd.testing.assert_series_equal(again["ttc_camera"], rows_0_18["ttc_camera"])
    pd.testing.assert_series_equal(again["ttc_lidar"], rows_0_18["ttc_lidar"])


def test_invalid_pair_raises_before_work(kitti_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(InvalidCombinationError):
        run_setting(settings("fast", "akaze"), FrameRange(kitti_dir, 0, 2), StageCache(tmp_path))
    assert not any(tmp_path.iterdir())


def test_broken_frame_is_a_row_not_a_crash(kitti_dir: Path, tmp_path: Path) -> None:
    """A damaged scan in the middle of the range gives error rows; other pairs still compute."""
    copy_frames(kitti_dir, tmp_path, range(4))
    scan = frame_files(tmp_path, 2).scan
    scan.write_bytes(scan.read_bytes()[:-3])
    rows = run_setting(settings(), FrameRange(tmp_path, 0, 3), StageCache(None))
    lead = rows[rows["is_lead"]].set_index("frame")
    assert lead.loc[1, "lidar_reason"] == reasons.OK
    for frame in (2, 3):
        assert lead.loc[frame, "lidar_reason"] == reasons.FRAME_ERROR
        assert "0000000002.bin" in lead.loc[frame, "error"]
    check_frame_columns(rows, core_only=True)


@pytest.mark.parametrize("step_ns", [100_000_000, 200_000_000])
def test_real_frame_times_set_dt(kitti_dir: Path, tmp_path: Path, cache_dir: Path, step_ns) -> None:
    """With a timestamps file 0.1 s apart the TTCs are today's; 0.2 s apart doubles them."""
    from tests.test_frames import kitti_times
    from ttc.io.calibration import CAM_TO_CAM, VELO_TO_CAM

    for index in range(4):
        for src in (frame_files(kitti_dir, index).image, frame_files(kitti_dir, index).scan):
            dst = tmp_path / src.relative_to(kitti_dir)
            dst.parent.mkdir(parents=True, exist_ok=True)
            dst.symlink_to(src)
    for name in (CAM_TO_CAM, VELO_TO_CAM):
        (tmp_path / name).symlink_to(kitti_dir / name)
    (tmp_path / "velodyne_points" / "timestamps.txt").write_text(kitti_times(4, step_ns))
    nominal = run_setting(settings(), FrameRange(kitti_dir, 0, 3), StageCache(cache_dir))
    timed = run_setting(settings(), FrameRange(tmp_path, 0, 3), StageCache(cache_dir))
    factor = step_ns / 100_000_000
    assert (timed["dt"] == 0.1 * factor).all() and (nominal["dt"] == 0.1).all()
    for column in ("ttc_lidar", "ttc_camera"):
        expected = nominal[column] * factor
        if factor == 1:
            pd.testing.assert_series_equal(timed[column], nominal[column])  # bit for bit
        np.testing.assert_allclose(timed[column], expected, rtol=1e-12)
        assert np.isfinite(timed[column]).sum() >= 3
    pd.testing.assert_series_equal(timed["lidar_reason"], nominal["lidar_reason"])


def test_a_frames_grey_image_is_decoded_once_per_file_content(kitti_dir, tmp_path) -> None:
    """:func:`ttc.engine.stages.gray_image`: decoded once per process and file content; the file
    changed (new bytes, new mtime) is decoded again; the shared image is read-only."""
    import os
    import shutil

    import cv2

    from ttc.engine.stages import gray_image
    from ttc.io.frames import read_image

    path = tmp_path / "frame.png"
    shutil.copy(kitti_dir / "image_02" / "data" / "0000000000.png", path)
    decoded = []

    def decode():
        decoded.append(path)
        return read_image(path)

    first = gray_image(path, decode)
    assert gray_image(path, decode) is first and len(decoded) == 1
    assert not first.flags.writeable
    np.testing.assert_array_equal(first, cv2.cvtColor(read_image(path), cv2.COLOR_BGR2GRAY))
    shutil.copy(kitti_dir / "image_02" / "data" / "0000000001.png", path)
    os.utime(path, ns=(1, 1))
    second = gray_image(path, decode)
    assert len(decoded) == 2 and not np.array_equal(second, first)
