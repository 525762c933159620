"""Proof for the move to one engine (issue #21): ttc.engine gives the rows, timings aside, that
the old single-setting pipeline gives, for single runs, batches and pair details. Removed
with the old path."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ttc import engine, pipeline
from ttc.box_matching import BoxMatchingParams
from ttc.cache import StageCache
from ttc.camera_ttc import CameraTTCParams
from ttc.descriptors import DESCRIPTORS, NO_DESCRIPTOR
from ttc.fusion import FusionParams
from ttc.keypoint_filter import KeypointFilterParams
from ttc.keypoints import DETECTORS
from ttc.klt import KltParams
from ttc.lidar_ttc import LidarTTCParams
from ttc.matching import NO_SELECTOR, SelectorParams
from ttc.settings import FrameRange, Settings


def _settings() -> list[Settings]:
    fast = Settings(detector=DETECTORS["fast"](), descriptor=DESCRIPTORS["brief"]())
    return [
        fast,
        dataclasses.replace(fast, selector=SelectorParams(name="knn")),
        dataclasses.replace(fast, keypoint_filter=KeypointFilterParams(name="zscore")),
        dataclasses.replace(fast, lidar_ttc=LidarTTCParams(name="cluster")),
        dataclasses.replace(fast, camera_ttc=CameraTTCParams(name="mean_ratio")),
        dataclasses.replace(fast, fusion=FusionParams(name="kalman_ca")),
        dataclasses.replace(fast, box_matching=BoxMatchingParams(name="hungarian")),
        Settings(detector=DETECTORS["akaze"](), descriptor=DESCRIPTORS["akaze"]()),
        Settings(detector=DETECTORS["shitomasi"](), descriptor=DESCRIPTORS["sift"]()),
        Settings(detector=DETECTORS["fast"](), descriptor=NO_DESCRIPTOR, matcher=KltParams(),
                 selector=NO_SELECTOR),  # fmt: skip
    ]


def _untimed(rows: pd.DataFrame) -> pd.DataFrame:
    return rows.drop(columns=[c for c in rows if c.startswith(("ms_", "cached_"))]).reset_index(drop=True)


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> StageCache:
    return StageCache(tmp_path_factory.mktemp("cache"))


@pytest.mark.parametrize("index", range(len(_settings())))
def test_one_setting_same_rows(kitti_dir: Path, cache: StageCache, index: int) -> None:
    s = _settings()[index]
    frames = FrameRange(kitti_dir, 0, 10)
    old = pipeline.run_setting(s, frames, cache)
    new = engine.run_setting(s, frames, cache)
    pd.testing.assert_frame_equal(_untimed(new), _untimed(old))


def test_batch_same_rows(kitti_dir: Path, cache: StageCache) -> None:
    settings = _settings()
    frames = FrameRange(kitti_dir, 0, 10)
    rows, failed = engine.run_settings(settings, frames, cache)
    assert not failed
    for member, s in enumerate(settings):
        got = rows[rows[engine.MEMBER] == member].drop(columns=engine.MEMBER)
        pd.testing.assert_frame_equal(_untimed(got), _untimed(pipeline.run_setting(s, frames, cache)))


@pytest.mark.parametrize("index", [0, 2, 9])
def test_pair_detail_same(kitti_dir: Path, cache: StageCache, index: int) -> None:
    s = _settings()[index]
    frames = FrameRange(kitti_dir, 0, 18)
    old = pipeline.pair_detail(s, frames, 4, 5, cache)
    new = engine.pair_detail(s, frames, 4, 5, cache)
    pd.testing.assert_frame_equal(_untimed(new.rows), _untimed(old.rows))
    for name in ("images", "objects", "keypoints", "lane_points", "lane_uv", "lane_owner"):
        a, b = getattr(old, name), getattr(new, name)
        assert a.keys() == b.keys()
        for k in a:
            if isinstance(a[k], dict):
                for key in a[k]:
                    np.testing.assert_array_equal(a[k][key], b[k][key])
            else:
                np.testing.assert_array_equal(a[k], b[k])
    assert old.lead_box == new.lead_box
    np.testing.assert_array_equal(old.kept, new.kept)
    np.testing.assert_array_equal(old.removed, new.removed)
    np.testing.assert_array_equal(old.matches.prev_idx, new.matches.prev_idx)
    np.testing.assert_array_equal(old.box_matches.curr_box, new.box_matches.curr_box)
