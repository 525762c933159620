"""Loading KITTI frames and calibration: real files, and malformed copies in a temp folder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import copy_frames
from ttc.io.calibration import load_calibration
from ttc.io.frames import (
    FrameDataError,
    frame_files,
    frame_indices,
    frame_interval,
    load_frame,
    missing_time_errors,
    pair_interval,
    read_frame_times,
    read_image,
    read_lidar_scan,
)

MIN_SCAN_POINTS = 100_000


def test_real_frame_loads(kitti_dir: Path) -> None:
    frame = load_frame(kitti_dir, 0)
    assert frame.image.shape == (375, 1242, 3)
    assert frame.image.dtype == np.uint8
    assert frame.scan.points.shape[1] == 4
    assert frame.scan.points.dtype == np.float32
    assert 110_000 < len(frame.scan) < 116_000
    assert frame.scan.n_dropped == 0
    assert not frame.scan_is_short(MIN_SCAN_POINTS)


def test_frame_77_truncated_scan_loads_and_is_flagged(kitti_dir: Path) -> None:
    frame = load_frame(kitti_dir, 77)
    assert len(frame.scan) == 1_115_504 // 16 == 69_719
    assert frame.scan_is_short(MIN_SCAN_POINTS)


def test_calibration_parsed(kitti_dir: Path) -> None:
    calib = load_calibration(kitti_dir)
    assert calib.p_rect.shape == (3, 4)
    assert calib.p_rect[0, 0] == pytest.approx(721.5377)
    assert calib.p_rect[0, 3] == pytest.approx(44.85728)
    assert calib.image_size == (1242, 375)
    assert calib.velo_to_image.shape == (3, 4)
    assert load_calibration(kitti_dir, "P_rect_00").p_rect[0, 3] == 0.0
    with pytest.raises(ValueError, match="projection"):
        load_calibration(kitti_dir, "P_rect_03")


def test_frame_range_and_interval() -> None:
    assert frame_indices(0, 18) == list(range(19))
    assert frame_indices(0, 18, 3) == [0, 3, 6, 9, 12, 15, 18]
    assert frame_interval(1) == pytest.approx(0.1)
    assert frame_interval(3) == pytest.approx(0.3)
    with pytest.raises(ValueError):
        frame_indices(5, 2)


@pytest.fixture
def broken_dir(kitti_dir: Path, tmp_path: Path) -> Path:
    """A copy of frames 0–1 and the calibration, to be damaged by each test."""
    return copy_frames(kitti_dir, tmp_path, (0, 1))


def test_missing_image_names_file(broken_dir: Path) -> None:
    files = frame_files(broken_dir, 0)
    files.image.unlink()
    with pytest.raises(FrameDataError, match=r"0000000000\.png: image not found"):
        load_frame(broken_dir, 0)


def test_missing_scan_names_file(broken_dir: Path) -> None:
    files = frame_files(broken_dir, 1)
    files.scan.unlink()
    with pytest.raises(FrameDataError, match=r"0000000001\.bin: lidar scan not found"):
        load_frame(broken_dir, 1)


def test_unreadable_png_names_file(broken_dir: Path) -> None:
    path = frame_files(broken_dir, 0).image
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10)
    with pytest.raises(FrameDataError, match=r"0000000000\.png: unreadable image"):
        read_image(path)


def test_scan_size_not_multiple_of_16(broken_dir: Path) -> None:
    path = frame_files(broken_dir, 0).scan
    data = path.read_bytes()
    path.write_bytes(data[:-5])
    with pytest.raises(
        FrameDataError, match=r"0000000000\.bin: size \d+ bytes is not a multiple of 16"
    ):
        read_lidar_scan(path)


def test_non_finite_points_dropped_and_counted(broken_dir: Path) -> None:
    path = frame_files(broken_dir, 0).scan
    points = np.fromfile(path, dtype="<f4").reshape(-1, 4)
    points[[3, 10, 11], 0] = np.nan
    points[20, 2] = np.inf
    points.tofile(path)
    scan = read_lidar_scan(path)
    assert scan.n_dropped == 4
    assert len(scan) == len(points) - 4
    assert np.isfinite(scan.points).all()


def test_missing_calibration_entry(broken_dir: Path) -> None:
    path = broken_dir / "calib_cam_to_cam.txt"
    lines = [line for line in path.read_text().splitlines() if not line.startswith("P_rect_02")]
    path.write_text("\n".join(lines))
    with pytest.raises(FrameDataError, match=r"calib_cam_to_cam\.txt: missing entry 'P_rect_02'"):
        load_calibration(broken_dir)
    (broken_dir / "calib_velo_to_cam.txt").unlink()
    with pytest.raises(FrameDataError, match="calib_velo_to_cam.txt: calibration file not found"):
        load_calibration(broken_dir, "P_rect_00")


# -- frame times from KITTI timestamps.txt -------------------------------------------------
def kitti_times(n: int, step_ns: int, start: str = "2011-09-26 13:02:44.339690445") -> str:
    """``n`` KITTI timestamp lines ``step_ns`` nanoseconds apart."""
    import datetime as dt

    date, frac = start.split(".")
    base = dt.datetime.fromisoformat(date)
    lines = []
    for i in range(n):
        ns = int(frac) + i * step_ns
        when = base + dt.timedelta(seconds=ns // 1_000_000_000)
        lines.append(f"{when:%Y-%m-%d %H:%M:%S}.{ns % 1_000_000_000:09d}")
    return "\n".join(lines) + "\n"


def test_no_timestamps_file_means_none(kitti_dir: Path) -> None:
    assert read_frame_times(kitti_dir) is None  # our copy of the recording has none


def test_frame_times_relative_to_frame_0_lidar_preferred(tmp_path: Path) -> None:
    (tmp_path / "image_02").mkdir()
    (tmp_path / "velodyne_points").mkdir()
    (tmp_path / "image_02" / "timestamps.txt").write_text(kitti_times(4, 50_000_000))
    assert read_frame_times(tmp_path).tolist() == [0.0, 0.05, 0.1, 0.15]  # camera alone
    (tmp_path / "velodyne_points" / "timestamps.txt").write_text(kitti_times(4, 103_456_789))
    (tmp_path / "image_02" / "timestamps.txt").write_text(kitti_times(4, 99_000_000))
    times = read_frame_times(tmp_path)  # both: the lidar's, the camera's within 10 ms
    np.testing.assert_allclose(
        times, [0.0, 0.103456789, 0.206913578, 0.310370367], rtol=0, atol=1e-12
    )
    assert pair_interval(times, 1, 2) == 0.103456789
    assert pair_interval(None, 1, 3, step=2) == pytest.approx(0.2)


@pytest.mark.parametrize(
    ("line", "problem"),
    [
        ("2011-09-26 13:02:44,539690445", "line 3: malformed timestamp '2011-09-26 13:02:44,539690445'"),
        ("2011-09-26 13:02:61.000000000", "line 3: malformed timestamp"),
        (" x", "line 3: malformed timestamp ' x'"),
        ("2011-09-26 13:02:44.439690445", "line 3: time '2011-09-26 13:02:44.439690445' is not after line 2's"),
    ],
)  # fmt: skip
def test_malformed_or_non_increasing_timestamps_name_file_and_line(tmp_path, line, problem):
    path = tmp_path / "velodyne_points" / "timestamps.txt"
    path.parent.mkdir()
    lines = kitti_times(4, 100_000_000).splitlines()
    lines[2] = line
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(FrameDataError) as info:
        read_frame_times(tmp_path)
    assert str(info.value).startswith(f"{path}: {problem}")


def test_a_blank_timestamp_line_is_a_missing_frame(tmp_path: Path) -> None:
    """KITTI publishes drives with blank lines where a sensor's data is missing (drive 0009,
    frames 177–180): those frames have no time (NaN), the others keep theirs, and the times
    still count from frame 0, or from the first frame that has a time."""
    path = tmp_path / "velodyne_points" / "timestamps.txt"
    path.parent.mkdir()
    lines = kitti_times(5, 100_000_000).splitlines()
    lines[2] = ""
    path.write_text("\n".join(lines) + "\n")
    times = read_frame_times(tmp_path)
    np.testing.assert_allclose(times, [0.0, 0.1, np.nan, 0.3, 0.4], rtol=0, atol=1e-12)
    assert np.isnan(pair_interval(times, 1, 2))
    assert pair_interval(times, 3, 4) == 0.1
    errors = missing_time_errors(tmp_path, [0, 1, 2, 3])
    assert list(errors) == [2]
    assert str(errors[2]) == f"{path}: line 3: blank timestamp: frame 2 was not recorded"
    assert missing_time_errors(tmp_path, [3, 4]) == {}  # outside the range: no matter
    lines[0] = ""
    path.write_text("\n".join(lines) + "\n")
    np.testing.assert_allclose(
        read_frame_times(tmp_path), [np.nan, 0.0, np.nan, 0.2, 0.3], rtol=0, atol=1e-12
    )


def test_blank_lines_of_both_clocks_are_compared_only_where_both_have_a_time(tmp_path):
    """The lidar's file blank at a frame the camera has (drive 0009): the clocks agree."""
    for folder, step in (("velodyne_points", 100_000_000), ("image_02", 100_500_000)):
        (tmp_path / folder).mkdir()
        lines = kitti_times(5, step).splitlines()
        if folder == "velodyne_points":
            lines[2] = ""
        (tmp_path / folder / "timestamps.txt").write_text("\n".join(lines) + "\n")
    assert np.isnan(read_frame_times(tmp_path)[2])
