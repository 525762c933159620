"""How far a ranking carries between recordings (ttc.evaluation.transfer), on constructed
rankings with known answers."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from experiments.store.flat_configs import leaf_text
from experiments.summary.recordings import recording_entries, setting_of
from ttc.evaluation.transfer import (
    best_elsewhere,
    recording_agreement,
    top_everywhere,
    transfer_sentence,
)

KEY = "camera_mid_median"


def _table() -> pd.DataFrame:
    """Settings s0..s5 on three drives: B ranks them as A does, C in reverse; D judged
    nothing (a drive without a lead); pooled rows are ignored."""
    rows = []
    settings = [f"s{i}" for i in range(6)]
    for drive, order in (("A", settings), ("B", settings), ("C", settings[::-1])):
        for rank, s in enumerate(order, start=1):
            rows.append({"drive": drive, "setting": s, "rank": rank, KEY: float(rank)})
    rows += [{"drive": "D", "setting": s, "rank": 1, KEY: np.nan} for s in settings]
    rows += [{"drive": "pooled", "setting": s, "rank": 1, KEY: 1.0} for s in settings]
    return pd.DataFrame(rows)


def test_kendall_tau_between_each_pair_of_ranked_drives() -> None:
    out = recording_agreement(_table(), KEY).set_index(["drive_a", "drive_b"])
    assert list(out.index) == [("A", "B"), ("A", "C"), ("B", "C")]
    assert out.loc[("A", "B"), "kendall_tau"] == pytest.approx(1.0)
    assert out.loc[("A", "C"), "kendall_tau"] == pytest.approx(-1.0)
    assert (out["n_settings"] == 6).all()


def test_best_on_one_drive_and_their_ranks_elsewhere() -> None:
    out = best_elsewhere(_table(), KEY, k=2)
    a = out[out["best_on"] == "A"]
    assert a["setting"].tolist() == ["s0", "s1"]
    assert a["C"].tolist() == [6, 5] and a["B"].tolist() == [1, 2]
    assert (out["n_C"] == 6).all() and "D" not in out


def test_top_everywhere_and_the_sentence() -> None:
    table = _table()
    assert top_everywhere(table, KEY, k=3) == []
    assert top_everywhere(table, KEY, k=6) == [f"s{i}" for i in range(6)]
    sentence = transfer_sentence(table, KEY, k=3)
    assert sentence.startswith("Kendall's τ between the recordings' rankings is -1.00–1.00;")
    assert "A's best (s0) ranks 1 of 6 on B, 6 of 6 on C" in sentence
    assert sentence.endswith("0 setting(s) are in the top 3 on every recording.")


def _runs(rows: list[tuple[str, str, float, str, str]]) -> pd.DataFrame:
    """Run records: (run id, recording, lidar crop max_x, detector, lidar_ttc) → config."""
    configs = [
        json.dumps({"dataset": {"name": seq.split("/")[0], "sequence": seq},
                    "lidar": {"crop": {"max_x": max_x}},
                    "detector": {"name": det}, "lidar_ttc": {"name": lid}})
        for _, seq, max_x, det, lid in rows
    ]  # fmt: skip
    return pd.DataFrame({"run_id": [r[0] for r in rows], "config": configs})


def test_a_setting_across_recordings_leaves_out_what_each_recording_fixes() -> None:
    """Sequence 04 sets its own lidar crop (40 m, drive 0052 20 m) and its own dataset name:
    one setting's runs on both share an id; a crop swept on one recording stays a setting's."""
    runs = _runs([("a", "kitti/0052", 20.0, "orb", "median"), ("b", "kitti/0052", 20.0, "sift", "median"),
                  ("c", "odo/04", 40.0, "orb", "median"), ("d", "odo/04", 40.0, "sift", "median"),
                  ("e", "kitti/0052", 20.0, "orb", "closest"), ("f", "odo/04", 40.0, "orb", "closest")])  # fmt: skip
    assert recording_entries(runs) == {"dataset.name", "dataset.sequence", "lidar.crop.max_x"}
    ids = setting_of(runs)
    assert ids["a"] == ids["c"] and ids["b"] == ids["d"] and ids["e"] == ids["f"]
    assert len({ids["a"], ids["b"], ids["e"]}) == 3
    camera = setting_of(runs, "camera")  # lidar_ttc changes only the lidar TTC
    assert camera["a"] == camera["e"] == camera["f"] and camera["a"] != camera["b"]
    swept = _runs([("a", "kitti/0052", 20.0, "orb", "median"), ("b", "kitti/0052", 30.0, "orb", "median"),
                   ("c", "odo/04", 40.0, "orb", "median")])  # fmt: skip
    assert "lidar.crop.max_x" not in recording_entries(swept)
    assert setting_of(swept)["a"] != setting_of(swept)["b"]


@pytest.mark.parametrize(
    "value", ["fast", "é\n\"x", 3, -1, 0.1 + 0.2, 1e-7, 1e300, float("nan"), float("-inf"),
              True, False, None, [1, "a", [2.5]], {"b": 1, "a": None}, ""],
)  # fmt: skip
def test_a_config_leaf_is_its_json_text(value) -> None:
    """Setting ids hash the leaves' text: the fast path writes exactly what json.dumps does."""
    assert leaf_text(value) == json.dumps(value, sort_keys=True)
