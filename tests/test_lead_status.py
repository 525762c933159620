"""``no_lead`` / ``lead_change``: frames without one lead vehicle are found, split the
reference into segments and are not judged; the FP.5 and reference reports name them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments.configs.structured import frame_range_from_config, settings_from_config
from experiments.summary.references import sequence_reference
from tests.test_kitti_raw import composed, make_drive
from ttc import evaluation as ev
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_setting
from ttc.evaluation.reference import reference_ttc
from ttc.io.frames import frame_files

#: The made-up drive: the shared frames 0–23; scans 10 and 11 without the lead car.
EMPTY = (10, 11)


def test_a_jump_of_the_rear_is_a_lead_change_and_a_missing_rear_in_a_full_scan_no_lead():
    d = np.array([10.0, 9.9, 9.8, 5.0, 4.95, np.nan, np.nan, 4.9, 4.85])
    t = np.arange(len(d)) * 0.1
    scans = np.array([110_000] * 5 + [112_000, 60_000, 110_000, 110_000])  # 6: truncated
    status = ev.lead_status(d, t, scans)
    assert status.tolist() == ["ok"] * 3 + ["lead_change"] + ["ok", "no_lead"] + ["ok"] * 3
    assert ev.lead_segments(status).tolist() == [0, 0, 0, 1, 1, -1, 2, 2, 2]
    assert ev.lead_status(d, t).tolist() == ["ok"] * 3 + ["lead_change"] + ["ok"] * 5
    # 1.5 m in 0.1 s is 15 m/s: still the same car; 1.6 m is not
    assert ev.lead_status(np.array([9.0, 7.5, 5.9]), t[:3]).tolist() == ["ok", "ok", "lead_change"]


def test_pairs_across_a_lead_change_have_no_reference():
    d = pd.Series(np.r_[np.linspace(20.0, 18.0, 12), np.linspace(9.0, 8.0, 12)])
    ref = reference_ttc(d)
    assert ref.loc[12, "lead"] == "lead_change" and np.isnan(ref.loc[12, "ratio_ref"])
    assert (ref["lead_segment"] == (ref["frame"] >= 12)).all()
    assert not ref.loc[12, "judgeable"] and ref.loc[[5, 18], "judgeable"].all()
    np.testing.assert_allclose(ref.loc[13:, "distance_smooth_m"], d[13:], atol=1e-9)  # no bleed


def without_lead(scan: Path, out: Path) -> Path:
    """A copy of ``scan`` without any point of the ego lane ahead (x 0–30 m, |y| < 2.5 m)."""
    points = np.fromfile(scan, dtype="<f4").reshape(-1, 4)
    ahead = (points[:, 0] > 0) & (points[:, 0] < 30) & (np.abs(points[:, 1]) < 2.5)
    points[~ahead].tofile(out)
    return out


@pytest.fixture(scope="module")
def empty_lane_drive(kitti_dir, tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("raw")
    scans = {
        k: without_lead(frame_files(kitti_dir, k).scan, root / f"{k}.bin") for k in EMPTY
    }  # fmt: skip
    return make_drive(kitti_dir, root, "0099", list(range(24)), scans=scans)


def test_frames_whose_lead_disappears_are_no_lead_and_not_judged(empty_lane_drive, tmp_path):
    cache = StageCache(tmp_path / "cache")
    ref = sequence_reference(empty_lane_drive, cache).set_index("frame")
    assert ref.index.tolist() == list(range(24))
    assert ref.loc[list(EMPTY), "lead"].eq("no_lead").all()
    assert ref.drop(index=list(EMPTY))["lead"].eq("ok").all()
    not_judged = [*EMPTY, 12]  # 12: its previous frame has no lead
    assert (
        not ref.loc[not_judged, "judgeable"].any() and ref.loc[not_judged, "ttc_ref_s"].isna().all()
    )
    assert ref.loc[[5, 9, 14, 20], "judgeable"].all()  # both segments judged

    cfg = composed(["dataset=kitti_raw", f"dataset.root={empty_lane_drive.parents[2]}",
                    "dataset.drive=0099", "dataset.first=8", "dataset.last=14"])  # fmt: skip
    rows = run_setting(settings_from_config(cfg), frame_range_from_config(cfg), cache)
    errors = ev.frame_errors(ev.attach_reference(rows.assign(run_id="r"), ref.reset_index()))
    errors = errors.set_index("frame")
    for sensor in ("lidar", "camera"):
        assert errors.loc[not_judged, f"{sensor}_outlier"].isna().all()
        assert errors.loc[not_judged, f"{sensor}_rel_err"].isna().all()
        assert errors.loc[[9, 14], f"{sensor}_outlier"].notna().all()
    assert (errors.loc[list(EMPTY), "lidar_reason"] == "no_lead_box").all()

    text = ev.not_judged_text(ref.reset_index())
    assert (
        "(`no_lead`): 10, 11;" in text and "(`lead_change`: a cut-in or lane change): none" in text
    )


def test_one_empty_scan_between_two_agreeing_measurements_is_a_dropout() -> None:
    """KITTI odometry sequence 04: the van 21 m ahead leaves no point in the lane crop of
    frame 20 alone (a complete scan); it is a missed measurement, not an empty lane, so the
    pairs 20 and 21 are judged and a lead TTC there is no false alarm. Two empty scans in a
    row, or one between distances that disagree, stay ``no_lead``."""
    t = np.arange(6) * 0.1
    scans = np.full(6, 120_000)
    one = np.array([21.8, 21.75, np.nan, 21.7, 21.65, 21.6])
    assert ev.lead_status(one, t, scans).tolist() == ["ok"] * 6
    two = np.array([21.8, np.nan, np.nan, 21.7, 21.65, 21.6])
    assert ev.lead_status(two, t, scans).tolist() == ["ok", "no_lead", "no_lead", "ok", "ok", "ok"]
    jump = np.array([21.8, 21.75, np.nan, 9.0, 8.95, 8.9])  # another car 0.2 s later
    assert ev.lead_status(jump, t, scans)[2] == "no_lead"


def test_sequence_04s_reference_follows_the_van_on_every_frame(data_dir, tmp_path) -> None:
    seq = data_dir / "kitti_odometry" / "sequences" / "04"
    reference = sequence_reference(seq, StageCache(tmp_path))
    assert (reference["lead"] == "ok").all()
    assert np.isnan(reference.loc[reference["frame"] == 20, "distance_m"]).all()
    assert reference["distance_smooth_m"].between(20.4, 22.3).all()
