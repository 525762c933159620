"""The camera pair rule (issue 50, item 4): which keypoint pairs give FP.4 a distance ratio.

The default is read from the config (``conf/camera_ttc/*.yaml``, with whatever a recording's
own config adds), never written here: every recording must get a finite camera TTC on at
least the measured number of boxes under it, ``dataset=kitti2mcap`` (a ROS 2 bag of drive
0009) on the same boxes as the drive's folder. The rubric's 100 px stays one named option,
``+camera_pairs=rubric``, that keeps the run ids of the settings stored with it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from experiments.configs.structured import (
    frame_range_from_config,
    register_configs,
    run_id,
    settings_from_config,
)
from tests.conftest import PROJECT_ROOT
from tests.test_run_ids import RUBRIC_PINNED
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_settings
from ttc.rows import MEMBER

CONF = PROJECT_ROOT / "conf"
#: The camera estimators a pair rule applies to (similarity_fit fits the points: no pairs).
PAIR_ESTIMATORS = ("median_ratio", "mean_ratio", "vertical_ratio")
#: The real recordings, each on its first frames 0-5 (5 frame pairs, default fast/BRIEF).
RECORDINGS = ("kitti_0_18", "kitti_odometry", "kitti_raw_0009")
FRAMES = ["dataset.first=0", "dataset.last=5"]
#: Least number of box pairs with a finite camera TTC on frames 0-5, per recording, estimator
#: and rule (min_dist px, min_box_fraction): the count this test's own run gave on 2026-11-28
#: (OpenCV 4.12, the default fast/BRIEF/bf/knn setting) less about 10 %. Of the matched box
#: pairs (drive 0052: 27, sequence 04: 11, drive 0009: 21) the box-relative rule (0 px, 0.15
#: of the box width) gives narrow boxes a camera TTC that the rubric's 100 px does not
#: (drive 0052: median_ratio 17 against 14, drive 0009: 15 against 7). The rules before the
#: box-relative default (drive 0052: 100 px, vertical_ratio 20 px; sequence 04 and drive 0009:
#: 0 px and 0.25 of the box width, their own configs) are measured too.
LEAST_FINITE: dict[tuple[str, str, tuple[float, float]], int] = {
    # the box-relative default: measured 17, 22, 13 / 7, 9, 6 / 15, 16, 10
    ("kitti_0_18", "median_ratio", (0.0, 0.15)): 15,
    ("kitti_0_18", "mean_ratio", (0.0, 0.15)): 19,
    ("kitti_0_18", "vertical_ratio", (0.0, 0.15)): 11,
    ("kitti_odometry", "median_ratio", (0.0, 0.15)): 6,
    ("kitti_odometry", "mean_ratio", (0.0, 0.15)): 8,
    ("kitti_odometry", "vertical_ratio", (0.0, 0.15)): 5,
    ("kitti_raw_0009", "median_ratio", (0.0, 0.15)): 13,
    ("kitti_raw_0009", "mean_ratio", (0.0, 0.15)): 14,
    ("kitti_raw_0009", "vertical_ratio", (0.0, 0.15)): 9,
    # before it: measured 14, 15, 10 / 7, 8, 6 / 14, 14, 11
    ("kitti_0_18", "median_ratio", (100.0, 0.0)): 12,
    ("kitti_0_18", "mean_ratio", (100.0, 0.0)): 13,
    ("kitti_0_18", "vertical_ratio", (20.0, 0.0)): 9,
    ("kitti_odometry", "median_ratio", (0.0, 0.25)): 6,
    ("kitti_odometry", "mean_ratio", (0.0, 0.25)): 7,
    ("kitti_odometry", "vertical_ratio", (0.0, 0.25)): 5,
    ("kitti_raw_0009", "median_ratio", (0.0, 0.25)): 12,
    ("kitti_raw_0009", "mean_ratio", (0.0, 0.25)): 12,
    ("kitti_raw_0009", "vertical_ratio", (0.0, 0.25)): 10,
}


def composed(overrides: list[str]) -> DictConfig:
    register_configs()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def rule_of(cfg: DictConfig) -> tuple[float, float]:
    """The composed config's pair rule: (min_dist px, min_box_fraction)."""
    return float(cfg.camera_ttc.min_dist), float(cfg.camera_ttc.min_box_fraction)


def box_rows(overrides: list[str], cache: StageCache) -> pd.DataFrame:
    """The matched box pairs of each pair estimator (column ``camera_ttc``) on ``overrides``'
    recording: one run of the estimators together (their stages shared)."""
    cfgs = [composed([*overrides, f"camera_ttc={e}"]) for e in PAIR_ESTIMATORS]
    rows, failed = run_settings([settings_from_config(c) for c in cfgs],
                                frame_range_from_config(cfgs[0]), cache)  # fmt: skip
    assert not failed, failed
    rows = rows[(rows["prev_box"] >= 0) & (rows["curr_box"] >= 0)]
    return rows.assign(camera_ttc=np.asarray(PAIR_ESTIMATORS)[rows[MEMBER].to_numpy()])


def finite(rows: pd.DataFrame) -> pd.Series:
    """Whether each row's camera TTC is a finite positive number of seconds."""
    ttc = rows["ttc_camera"].to_numpy(dtype=float)
    return pd.Series(np.isfinite(ttc) & (ttc > 0), index=rows.index)


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> StageCache:
    """One stage cache for the module: the estimators and rules of a recording share stages."""
    return StageCache(tmp_path_factory.mktemp("pair_rule_cache"))


@pytest.mark.parametrize("dataset", ["kitti_0_18", "kitti_0_77", "kitti_odometry",
                                     "kitti_raw_0009", "ros2_bag", "kitti2mcap", "scale_truth"])  # fmt: skip
def test_the_rubric_is_one_named_option_on_every_recording(dataset: str) -> None:
    """``+camera_pairs=rubric`` sets 100 px and no box fraction for every estimator, over
    whatever the estimator's config and the recording's config say."""
    for estimator in (*PAIR_ESTIMATORS, "similarity_fit"):
        cfg = composed([f"dataset={dataset}", f"camera_ttc={estimator}", "+camera_pairs=rubric"])
        assert rule_of(cfg) == (100.0, 0.0), (dataset, estimator)
    cfg = composed([f"dataset={dataset}", "+camera_pairs=rubric", "camera_ttc.min_dist=80"])
    assert rule_of(cfg) == (80.0, 0.0)  # the command line still wins


@pytest.mark.parametrize("overrides", list(RUBRIC_PINNED), ids=lambda o: " ".join(o) or "default")
def test_the_rubric_option_keeps_the_stored_run_ids(overrides: tuple[str, ...]) -> None:
    """The settings stored with 100 px keep their ids under the option."""
    assert run_id(composed(["+camera_pairs=rubric", *overrides])) == RUBRIC_PINNED[overrides]


@pytest.mark.parametrize("dataset", RECORDINGS)
def test_the_default_rule_gives_a_camera_ttc_on_every_recording(dataset: str, cache) -> None:
    """Under the configured default each estimator has a finite camera TTC on at least the
    measured number of box pairs (:data:`LEAST_FINITE`), and on no fewer than under the
    rubric's 100 px."""
    rows = box_rows([f"dataset={dataset}", *FRAMES], cache)
    counts = finite(rows).groupby(rows["camera_ttc"]).sum()
    rubric = box_rows([f"dataset={dataset}", *FRAMES, "+camera_pairs=rubric"], cache)
    rubric_counts = finite(rubric).groupby(rubric["camera_ttc"]).sum()
    for estimator in PAIR_ESTIMATORS:
        key = (
            dataset,
            estimator,
            rule_of(composed([f"dataset={dataset}", f"camera_ttc={estimator}"])),
        )
        if key not in LEAST_FINITE:
            pytest.fail(f"{key}: no count measured under this rule: measure it, add it")
        assert counts[estimator] >= LEAST_FINITE[key], (key, counts[estimator])
        assert counts[estimator] >= rubric_counts[estimator], key


def _bag_and_folder_rules_differ() -> bool:
    """Whether ``dataset=kitti2mcap`` composes another pair rule than drive 0009's folder
    (``dataset=kitti_raw_0009``): true while a recording's config sets its own."""
    bag = composed(["dataset=kitti2mcap", "dataset.path=/unused/0009.mcap"])
    return rule_of(bag) != rule_of(composed(["dataset=kitti_raw_0009"]))


@pytest.mark.xfail(
    _bag_and_folder_rules_differ(),
    strict=True,
    reason="conf/dataset/kitti_raw_0009.yaml sets its own pair rule, a bag gets the 100 px "
    "default: NaN where the folder has values (issue 50's fourth finding)",
)
def test_a_bag_of_drive_0009_gets_a_camera_ttc_where_the_folder_does(tmp_path_factory) -> None:
    """A kitti2mcap bag of drive 0009 (``dataset=kitti2mcap``, a ``ros2_bag``) and the drive's
    folder, each with its configured default: a finite camera TTC on the same box pairs,
    within 2 % of each other (the bag's camera frame moves points, not pixels: same matches)."""
    pytest.importorskip("kitti2mcap", reason="installed by .ci/run (--no-deps)")
    from tests.ros2_bags import make_bag

    bag = make_bag(tmp_path_factory.mktemp("pair_rule_bag") / "0009.mcap")
    cache = StageCache(tmp_path_factory.mktemp("pair_rule_bag_cache"))
    keys = [MEMBER, "prev_frame", "frame", "prev_box", "curr_box"]
    folder = box_rows(["dataset=kitti_raw_0009", *FRAMES], cache).set_index(keys)
    from_bag = box_rows(["dataset=kitti2mcap", f"dataset.path={bag}", *FRAMES], cache)
    from_bag = from_bag.set_index(keys).reindex(folder.index)
    both = finite(folder)
    assert (both == finite(from_bag)).all()
    rules = {
        e: rule_of(composed(["dataset=kitti_raw_0009", f"camera_ttc={e}"])) for e in PAIR_ESTIMATORS
    }
    assert both.sum() >= sum(LEAST_FINITE[("kitti_raw_0009", e, r)] for e, r in rules.items())
    ratio = from_bag["ttc_camera"][both] / folder["ttc_camera"][both]
    assert ratio.between(0.98, 1.02).all()
