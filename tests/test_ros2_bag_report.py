"""The report of a ros2_bag sweep reads the bag as the runs did: with the run's own topics,
scan tolerance and camera frame (runs.parquet ``config``), not the defaults of its path."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from experiments import store
from experiments.configs.structured import config_problems, frame_range_from_config
from experiments.summary.recordings import recording_source_of
from tests.conftest import PROJECT_ROOT, data_root
from tests.ros2_bags import LIDAR, bag_config, make_bag, rewrite
from tests.test_sweep import hydra_run

pytest.importorskip("kitti2mcap", reason="installed by .ci/run (--no-deps)")
NEAR = "/kitti/velodyne_near"  # a second PointCloud2 topic: the scans' first 1000 points


def with_a_second_cloud(topic, name, msg):
    """Each scan written twice: as it is, and its first 1000 points on :data:`NEAR`."""
    if topic != LIDAR:
        return name, msg
    cut = {field: getattr(msg, field) for field in msg.__slots__}
    size = msg.point_step * 1000
    cut.update(data=bytes(msg.data)[:size], width=1000, row_step=size)
    return [(topic, name, msg), (NEAR, name, cut)]


@pytest.mark.slow  # a sweep and a report in subprocesses (~45 s)
def test_the_objects_report_of_a_bag_with_two_clouds_uses_the_run_s_lidar_topic(
    tmp_path_factory,
) -> None:
    tmp = tmp_path_factory.mktemp("bag_report")
    plain = make_bag(tmp / "0009.mcap")
    two = rewrite(plain, tmp / "two_clouds.mcap", with_a_second_cloud)
    plain.unlink()
    problems = config_problems(bag_config(two))  # its path alone does not say which cloud
    assert len(problems) == 1 and "dataset.lidar_topic" in problems[0] and NEAR in problems[0]

    options = [f"dataset.lidar_topic={LIDAR}", "dataset.last=3"]
    result = hydra_run(["-m", "dataset=kitti2mcap", f"dataset.path={two}", *options,
                        "sweep_name=bag"], tmp)  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    sweep = tmp / "sweeps" / "bag"
    rows, runs = store.load_sweep(sweep)
    source = recording_source_of(runs, runs["run_id"].iloc[0], data_root())
    assert source == frame_range_from_config(bag_config(two, *options)).sequence_dir
    assert source.lidar_topic == LIDAR and source.camera_frame == "rectified"

    out = tmp / "report"
    env = {**os.environ, "TTC_CACHE_DIR": str(tmp / "cache")}
    cmd = [sys.executable, "-m", "experiments.report", str(sweep), "--out", str(out),
           "--no-pictures", "--no-html"]  # fmt: skip
    report = subprocess.run(cmd, cwd=PROJECT_ROOT, env=env, capture_output=True, text=True)
    assert report.returncode == 0, report.stderr[-3000:]
    assert "## Per track" in (out / "objects.md").read_text()
    assert len(pd.read_csv(out / "objects.csv")) > 0
    # the reference's nearest faces are the run's (same scans, same projection): with the
    # 1000-point cloud or the ROS camera convention they would not be
    ref = pd.read_csv(out / "reference_objects.csv")
    keys = ["frame", "box_x", "box_y", "box_w", "box_h"]
    both = ref.merge(rows[[*keys, "object_distance_m"]].drop_duplicates(keys), on=keys)
    both = both[both["distance_m"].notna() & both["object_distance_m"].notna()]
    gap = (both["distance_m"] - both["object_distance_m"]).abs()
    assert len(both) >= 8 and np.median(gap) < 0.01 and set(ref["frame"]) >= {0, 1, 2, 3}
