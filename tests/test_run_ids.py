"""Run ids are the identity of a stored result: the default setting and one other value of
every axis keep the ids they had when this test was written (computed on the code of stop 19,
4fb15ca, and unchanged since). A change here is a change of every stored result's identity:
make it on purpose, never by accident."""

from __future__ import annotations

import pytest

from experiments.config import run_id
from tests.test_beyond_rubric import composed
from ttc.settings import AXES

PINNED: dict[tuple[str, ...], str] = {
    (): "5292f35d7defd78f",
    ("detector=agast",): "a54abde9757782a5",
    ("descriptor=orb",): "764c79cd378135b6",
    ("matcher=flann",): "62db5fc1af4f2805",
    ("selector=nn",): "c6bd1818efab5011",
    ("box_matching=greedy_matrix",): "bf59aa7ab462a314",
    ("lidar_ttc=closest",): "3d07ba8f79136542",
    ("keypoint_filter=displacement_mad",): "0d3c1c7aaef21531",
    ("camera_ttc=mean_ratio",): "006b1b5481646240",
    ("fusion=kalman_ca",): "f9ba926ec879d100",
    # the full YOLOv3 files are found under the data root: its id depends on where that is
    ("objects=yolov3", "dataset.root=/pinned/data"): "faf657b74da28283",
    ("dataset=kitti_0_77",): "a6868168a6c537e0",
}


def test_every_axis_has_a_pinned_value() -> None:
    pinned = {o.split("=")[0] for overrides in PINNED for o in overrides}
    assert pinned >= set(AXES)


@pytest.mark.parametrize("overrides", list(PINNED), ids=lambda o: " ".join(o) or "default")
def test_run_id_is_pinned(overrides: tuple[str, ...]) -> None:
    assert run_id(composed(list(overrides))) == PINNED[overrides]
