"""Every object judged per KITTI difficulty level (issue 50, item 2): a pair takes the worse
level of its boxes, levels are cumulative, ``all`` is the ranking without levels, τ between
levels. Synthetic judged pairs (exact checks)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ttc.evaluation.difficulty import RANKING_LEVELS
from ttc.evaluation.object_errors import judge_objects, object_metrics, track_bootstrap_ranks
from ttc.evaluation.object_levels import (
    judged_in_level,
    level_agreement,
    level_counts,
    level_metrics,
    level_pairs,
    level_rankings,
)


def _reference() -> pd.DataFrame:
    """Three tracks over frames 0–2, one box each a frame: track 0 easy, track 1 easy on
    frames 0–1 and hard on frame 2 (cut by the border), track 2 below 25 px (none)."""
    rows = []
    for frame in range(3):
        for box, level in enumerate(["easy", "hard" if frame == 2 else "easy", "none"]):
            rows.append({"frame": frame, "box": box, "track_id": box, "role": "static",
                         "distance_m": 10.0 + box, "closing_speed_mps": 10.0,
                         "ratio_ref": 1.1, "ttc_ref_s": 1.0 + box, "ttc_ref_sd_s": 0.01,
                         "judgeable": True, "bearing_deg": 0.0, "difficulty": level})  # fmt: skip
    return pd.DataFrame(rows)


def _rows(run_id: str, errors: tuple[float, float, float]) -> pd.DataFrame:
    """A run's pairs (frames 1 and 2, every box matched to itself): camera TTC off by
    ``errors`` (relative) on the boxes 0, 1, 2."""
    rows = []
    for frame in (1, 2):
        for box, err in enumerate(errors):
            ttc = (1.0 + box) * (1.0 + err)
            rows.append({"run_id": run_id, "prev_frame": frame - 1, "frame": frame,
                         "prev_box": box, "curr_box": box, "box_w": 50.0, "ttc_camera": ttc,
                         "ttc_lidar": 1.0 + box, "camera_ratio": np.nan,
                         "d_prev": np.nan, "d_curr": np.nan})  # fmt: skip
    return pd.DataFrame(rows)


@pytest.fixture()
def judged() -> pd.DataFrame:
    rows = pd.concat([_rows("a", (0.1, 0.5, 0.9)), _rows("b", (0.2, 0.2, 0.2)),
                      _rows("c", (0.3, 0.1, 0.0))], ignore_index=True)  # fmt: skip
    out = judge_objects(rows, _reference())
    return out.assign(setting=out["run_id"])


def test_a_pair_takes_the_worse_level_of_its_two_boxes(judged) -> None:
    level = judged.set_index(["run_id", "frame", "curr_box"])["difficulty"]
    assert level[("a", 1, 1)] == "easy"
    assert level[("a", 2, 1)] == "hard"  # easy → hard
    assert level[("a", 1, 2)] == "none"


def test_levels_are_cumulative_and_all_is_the_ranking_without_levels(judged) -> None:
    rankings = level_rankings(judged)
    assert rankings["difficulty"].unique().tolist() == ["easy", "moderate", "hard", "all"]
    pairs = rankings.groupby("difficulty", sort=False)["n_pairs"].first()
    assert pairs.tolist() == [3, 3, 4, 6]  # easy: 2 + 1 pairs; hard adds the cut one
    easy = rankings[rankings["difficulty"] == "easy"].set_index("setting")["score"]
    assert easy.to_dict() == pytest.approx({"a": 0.7 / 3, "b": 0.2, "c": 0.7 / 3})
    every = rankings[rankings["difficulty"] == "all"].drop(columns="difficulty")
    pd.testing.assert_frame_equal(every.reset_index(drop=True), track_bootstrap_ranks(judged))
    metrics = level_metrics(judged, ["setting"])
    easy_a = metrics[(metrics["difficulty"] == "easy") & (metrics["setting"] == "a")].iloc[0]
    assert easy_a["camera_medae_rel"] == pytest.approx(0.1)
    assert easy_a["n_tracks"] == 2 and easy_a["camera_invalid_rate"] == 0


def test_tau_between_levels_and_pairs_per_level(judged) -> None:
    tau = level_agreement(level_rankings(judged)).set_index(["level_a", "level_b"])
    # moderate holds exactly the easy pairs here: the same order
    assert tau.loc[("easy", "moderate"), "kendall_tau"] == pytest.approx(1.0)
    assert tau.loc[("easy", "all"), "n_settings"] == 3
    assert -1.0 <= tau.loc[("easy", "all"), "kendall_tau"] <= 1.0
    counts = level_counts(judged).set_index("difficulty")
    assert counts.loc["easy", "<3s"] == 3 and counts.loc["hard", "total"] == 4
    assert counts.loc["all", "total"] == 6


def test_tau_between_recordings_per_level(tmp_path) -> None:
    """``objects_recordings.csv`` keeps τ of the ``all`` rankings (one row per pair of
    recordings, as before levels); ``objects_recordings_levels.csv`` has τ per level."""
    from experiments.report.objects_report import cross_recording_objects

    def ranking(order: dict[str, list[float]]) -> pd.DataFrame:
        return pd.concat([pd.DataFrame({"difficulty": level, "setting": ["a", "b", "c", "d"],
                                        "score": scores, "n_pairs": 5})
                          for level, scores in order.items()], ignore_index=True)  # fmt: skip

    one = ranking({"easy": [1, 2, 3, 4], "moderate": [1, 2, 3, 4], "hard": [1, 2, 3, 4],
                   "all": [1, 2, 3, 4]})  # fmt: skip
    two = ranking({"easy": [1, 2, 3, 4], "moderate": [4, 3, 2, 1], "hard": [1, 2, 4, 3],
                   "all": [2, 1, 3, 4]})  # fmt: skip
    cross_recording_objects({"x": one, "y": two}, tmp_path)
    every = pd.read_csv(tmp_path / "objects_recordings.csv")
    assert every.columns.tolist() == ["recording_a", "recording_b", "kendall_tau"]
    assert every["kendall_tau"].tolist() == pytest.approx([4 / 6])
    levels = pd.read_csv(tmp_path / "objects_recordings_levels.csv").set_index("difficulty")
    assert levels["kendall_tau"].to_dict() == pytest.approx(
        {"easy": 1.0, "moderate": -1.0, "hard": 4 / 6, "all": 4 / 6}
    )
    assert "per difficulty level" in (tmp_path / "objects_recordings.md").read_text()


@pytest.mark.parametrize("level", RANKING_LEVELS)
def test_a_level_flagged_in_place_gives_the_tables_of_its_pairs(judged, level) -> None:
    """The level's pairs flagged (no copy) give the metrics and ranking its pairs cut out
    give, exactly; the flag holds only judged pairs of the level."""
    flagged = judged_in_level(judged, level)
    cut = level_pairs(judged, level)
    assert len(flagged) == len(judged) and flagged["judged"].sum() == cut["judged"].sum()
    assert flagged["judged"].sum() < judged["judged"].sum() or level in ("hard", "all")
    pd.testing.assert_frame_equal(object_metrics(flagged, ["setting"]),
                                  object_metrics(cut, ["setting"]), check_exact=True)  # fmt: skip
    pd.testing.assert_frame_equal(track_bootstrap_ranks(flagged, n_boot=50),
                                  track_bootstrap_ranks(cut, n_boot=50), check_exact=True)  # fmt: skip
