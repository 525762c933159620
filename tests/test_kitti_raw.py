"""``dataset=kitti_raw``: the shared frames arranged into the official KITTI-raw layout
(symlinks, made-up timestamps) give the TTCs of ``kitti_0_77`` at 0.1 s, TTCs scaled by the
real dt otherwise, and bad timestamps a clear error naming the file and line."""

from __future__ import annotations

import datetime as dt
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
    setting_config,
    settings_from_config,
)
from tests.conftest import PROJECT_ROOT
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting
from ttc.io.calibration import CAM_TO_CAM, VELO_TO_CAM
from ttc.io.frames import IMAGE_DIR, LIDAR_DIR, FrameDataError, frame_files

DATE = "2011_09_26"
START = dt.datetime(2011, 9, 26, 13, 2, 44)
#: A made-up drive's lidar frame intervals (ns): around 0.1 s, none exactly.
UNEVEN_NS = [103_600_000, 98_700_000, 101_200_000]


def kitti_lines(intervals_ns: list[int], offset_ns: int = 339_690_445) -> str:
    """KITTI ``timestamps.txt`` text: one line per frame, ``intervals_ns`` apart."""
    ns = offset_ns + np.concatenate([[0], np.cumsum(intervals_ns)]).astype(np.int64)
    lines = [
        f"{START + dt.timedelta(seconds=int(t // 1_000_000_000)):%Y-%m-%d %H:%M:%S}"
        f".{int(t % 1_000_000_000):09d}"
        for t in ns
    ]
    return "\n".join(lines) + "\n"


def make_drive(
    kitti_dir: Path,
    root: Path,
    drive: str,
    frames: list[int],
    intervals_ns: list[int] | None = None,
    scans: dict[int, Path] | None = None,
) -> Path:
    """The official layout of a made-up drive under ``root/kitti_raw``: the shared
    ``frames`` symlinked and renumbered from 0 (``scans``: new index → another .bin), the
    calibration in the date folder, lidar and camera timestamps (the camera's 3 ms later)."""
    day = root / "kitti_raw" / DATE
    seq = day / f"{DATE}_drive_{drive}_sync"
    for folder in (IMAGE_DIR, LIDAR_DIR):
        (seq / folder).mkdir(parents=True, exist_ok=True)
    for name in (CAM_TO_CAM, VELO_TO_CAM):
        if not (day / name).exists():
            (day / name).symlink_to(kitti_dir / name)
    for new, old in enumerate(frames):
        src, dst = frame_files(kitti_dir, old), frame_files(seq, new)
        dst.image.symlink_to(src.image)
        dst.scan.symlink_to((scans or {}).get(new, src.scan))
    intervals = intervals_ns or [100_000_000] * (len(frames) - 1)
    (seq / LIDAR_DIR.parent / "timestamps.txt").write_text(kitti_lines(intervals))
    (seq / IMAGE_DIR.parent / "timestamps.txt").write_text(kitti_lines(intervals, 342_690_445))
    return seq


def composed(overrides: list[str]):
    register_configs()
    with initialize_config_dir(config_dir=str(PROJECT_ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> StageCache:
    return StageCache(tmp_path_factory.mktemp("cache"))


@pytest.fixture(scope="module")
def nominal(cache: StageCache) -> pd.DataFrame:
    """Rows of the default setting on ``kitti_0_77``'s frames 0–3 (10 Hz, no timestamps)."""
    cfg = composed(["dataset=kitti_0_77", "dataset.last=3"])
    return run_setting(settings_from_config(cfg), frame_range_from_config(cfg), cache)


def raw_rows(root: Path, drive: str, cache: StageCache) -> pd.DataFrame:
    cfg = composed(["dataset=kitti_raw", f"dataset.root={root}", f"dataset.drive={drive}"])
    assert config_problems(cfg) == []
    frames = frame_range_from_config(cfg)
    assert (frames.first, frames.last) == (0, 3)  # the whole drive: last from the files
    return run_setting(settings_from_config(cfg), frames, cache)


def test_kitti_raw_at_0_1_s_gives_the_ttcs_of_kitti_0_77(kitti_dir, tmp_path, cache, nominal):
    make_drive(kitti_dir, tmp_path, "0052", [0, 1, 2, 3])
    rows = raw_rows(tmp_path, "0052", cache)
    assert (rows["dt"] == 0.1).all()
    for column in ("ttc_lidar", "ttc_camera", "lidar_reason", "camera_reason"):
        pd.testing.assert_series_equal(rows[column], nominal[column])  # bit for bit
    assert np.isfinite(rows.loc[rows["is_lead"], "ttc_lidar"]).sum() == 3


def test_kitti_raw_ttcs_scale_with_the_real_dt(kitti_dir, tmp_path, cache, nominal):
    make_drive(kitti_dir, tmp_path, "0052", [0, 1, 2, 3], UNEVEN_NS)
    rows = raw_rows(tmp_path, "0052", cache)
    dt_s = rows["frame"].map({k: UNEVEN_NS[k - 1] / 1e9 for k in (1, 2, 3)})
    np.testing.assert_array_equal(rows["dt"], dt_s)
    for column in ("ttc_lidar", "ttc_camera"):
        np.testing.assert_allclose(rows[column], nominal[column] * dt_s / 0.1, rtol=1e-9)
    assert not np.allclose(rows["ttc_lidar"], nominal["ttc_lidar"], rtol=1e-3, equal_nan=True)


def test_run_id_names_date_drive_and_the_resolved_last_frame(kitti_dir, tmp_path) -> None:
    make_drive(kitti_dir, tmp_path, "0052", [0, 1, 2, 3])
    make_drive(kitti_dir, tmp_path, "0040", [40, 41, 42])
    base = ["dataset=kitti_raw", f"dataset.root={tmp_path}"]
    cfg = composed([*base, "dataset.date=2011_09_26"])  # read by Hydra as the int 20110926
    dataset = setting_config(cfg)["dataset"]
    assert (dataset["date"], dataset["drive"], dataset["last"]) == (DATE, "0052", 3)
    other = composed([*base, "dataset.drive=40"])
    assert setting_config(other)["dataset"]["last"] == 2
    assert other.dataset.sequence == f"kitti_raw/{DATE}/{DATE}_drive_0040_sync"
    assert run_id(cfg) != run_id(other)


@pytest.mark.parametrize(
    ("line", "problem"),
    [
        (
            "2011-09-26 13:02:4x.439690445",
            "line 2: malformed timestamp '2011-09-26 13:02:4x.439690445' (",
        ),
        ("2011-09-26 13:02:44.3", "line 2: time '2011-09-26 13:02:44.3' is not after line 1's"),
        ("2011-09-26 13:02:44.459690445", "line 2: the camera's interval of frames 0->1 "),
    ],
)
def test_bad_timestamps_name_the_file_and_line(kitti_dir, tmp_path, line, problem) -> None:
    """A malformed line, a time going back, a camera clock 20 ms off the lidar's."""
    seq = make_drive(kitti_dir, tmp_path, "0052", [0, 1, 2])
    camera = seq / IMAGE_DIR.parent / "timestamps.txt"
    if "camera" in problem:
        lines = camera.read_text().splitlines()
        lines[1] = "2011-09-26 13:02:44." + line.split(".")[1]  # 117 ms after line 1
    else:
        camera = seq / LIDAR_DIR.parent / "timestamps.txt"  # the lidar's file, damaged
        lines = camera.read_text().splitlines()
        lines[1] = line
    camera.write_text("\n".join(lines) + "\n")
    cfg = composed(["dataset=kitti_raw", f"dataset.root={tmp_path}"])
    assert [p for p in config_problems(cfg) if p.startswith(f"{camera}: {problem}")]
    with pytest.raises(FrameDataError) as info:
        run_setting(settings_from_config(cfg), frame_range_from_config(cfg), StageCache(None))
    assert str(info.value).startswith(f"{camera}: {problem}")


def test_a_drive_without_timestamps_or_calibration_is_refused(kitti_dir, tmp_path) -> None:
    seq = make_drive(kitti_dir, tmp_path, "0052", [0, 1, 2])
    for name in ("velodyne_points", "image_02"):
        (seq / name / "timestamps.txt").unlink()
    (seq.parent / CAM_TO_CAM).unlink()
    problems = config_problems(composed(["dataset=kitti_raw", f"dataset.root={tmp_path}"]))
    assert problems == [
        f"{seq}: no timestamps (velodyne_points/timestamps.txt or image_02/timestamps.txt); "
        "a KITTI-raw drive is judged at its real frame times",
        f"{seq.parent / CAM_TO_CAM}: calibration file not found",
    ]


def test_calibration_split_between_drive_and_date_folder_is_refused(kitti_dir, tmp_path) -> None:
    """The run reads both files from one folder (:func:`ttc.io.calibration.calibration_dir`): one in
    the drive folder and the other only in the date folder is refused before any job, naming
    the file the run would miss."""
    seq = make_drive(kitti_dir, tmp_path, "0052", [0, 1, 2])
    (seq / CAM_TO_CAM).symlink_to(kitti_dir / CAM_TO_CAM)  # the date folder keeps both
    problems = config_problems(composed(["dataset=kitti_raw", f"dataset.root={tmp_path}"]))
    assert problems == [f"{seq / VELO_TO_CAM}: calibration file not found"]


def test_a_missing_drive_says_how_to_obtain_it_and_downloads_nothing(tmp_path) -> None:
    problems = config_problems(composed(["dataset=kitti_raw", f"dataset.root={tmp_path}"]))
    assert len(problems) == 1 and "registration" in problems[0]
    assert problems[0].startswith(
        f"KITTI raw drive not found: {tmp_path}/kitti_raw/{DATE}/{DATE}_drive_0052_sync"
    )
    assert list(tmp_path.iterdir()) == []
