"""Every object judged per object detector (:mod:`experiments.report.detectors_report`): a real
sweep of drive 0009 frames 0-8 with YOLOv3-tiny and SSD-MobileNetV2 on 4 tiles gives one
every-object report per detector, each against its own boxes, and Kendall's τ between the two
detectors' rankings per difficulty level."""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd
import pytest

from experiments.data import weights
from experiments.report.detectors_report import detector_folder
from tests.test_report import make_report, make_sweep, shared_root
from ttc.features.model_files import SSD_MODEL_DIR_ENV

SSD = "ssd_mobilenet_v2"


@pytest.fixture(scope="module")
def two_detectors(tmp_path_factory) -> Path:
    """The report of fast, orb x brief with both detectors on drive 0009 frames 0-8."""
    folder = weights.resolve_model_dir(model=SSD)  # the project's verified copy (download once)
    assert folder is not None
    os.environ[SSD_MODEL_DIR_ENV] = str(folder)  # the sweep's and report's subprocesses
    root = shared_root(tmp_path_factory)
    args = ["-m", "dataset=kitti_raw_0009", "dataset.last=8", "detector=fast,orb",
            "descriptor=brief", f"objects=yolov3_tiny,{SSD}", "sweep_name=two_detectors"]  # fmt: skip
    sweep = make_sweep(root, args, "two_detectors")
    return make_report(root, [sweep], root / "reports" / "two_detectors", "--no-pictures")


@pytest.mark.slow
def test_each_detector_is_judged_against_its_own_boxes(two_detectors: Path) -> None:
    ssd = detector_folder(two_detectors, f"{SSD}+tiles4", first=False)
    assert ssd.name == f"objects_{SSD}+tiles4"
    yolo_ref = pd.read_csv(two_detectors / "reference_objects.csv")
    ssd_ref = pd.read_csv(ssd / "reference_objects.csv")
    # two references, each of its own detector's boxes: SSD on tiles boxes more far objects
    assert not yolo_ref[["frame", "box_x", "box_w"]].equals(ssd_ref[["frame", "box_x", "box_w"]])
    far = lambda ref: int((ref["distance_m"] > 20).sum())  # noqa: E731
    assert far(ssd_ref) > far(yolo_ref)
    for folder in (two_detectors, ssd):
        ranking = pd.read_csv(folder / "objects_ranking.csv")
        assert set(ranking["setting"]) == {"fast", "orb"}  # the camera setting, no detector
        assert "all" in set(ranking["difficulty"])
    tau = pd.read_csv(two_detectors / "objects_detectors.csv")
    assert set(tau["detector_a"]) == {"yolov3_tiny"} and set(tau["detector_b"]) == {f"{SSD}+tiles4"}
    assert set(tau["difficulty"]) == {"easy", "moderate", "hard", "all"}
    assert (tau.loc[tau["difficulty"] == "all", "n_settings"] == 2).all()
    text = (two_detectors / "objects_detectors.md").read_text(encoding="utf-8")
    assert f"objects_{SSD}+tiles4/objects.md" in text and "Level the report stands behind" in text
