"""Learned features, dense flow, tracking and the scale fit against the best classic setting
(``ttc.evaluation.families``): exact checks on a constructed ranking."""

from __future__ import annotations

import pandas as pd

from ttc import evaluation as ev


def _row(setting: str, rank: int, mid: float, lo: float, hi: float) -> dict:
    detector, descriptor, matcher, selector, camera_ttc = setting.split("/")
    return {"dataset": "d", "setting": setting, "detector": detector, "descriptor": descriptor,
            "matcher": matcher, "selector": selector, "camera_ttc": camera_ttc, "rank": rank,
            "rank_lo": rank, "rank_hi": rank + 2, "camera_mid_median": mid,
            "camera_mid_median_lo": lo, "camera_mid_median_hi": hi, "camera_invalid_rate": 0.0,
            "ms_per_frame": 10.0 * rank}  # fmt: skip


RANKING = pd.DataFrame(
    [
        _row("xfeat/none/klt/none/median_ratio", 1, 2.0, 1.0, 2.9),
        _row("sift/sift/bf/nn/median_ratio", 2, 4.0, 3.0, 5.0),
        _row("orb/orb/bf/nn/median_ratio", 3, 6.0, 5.5, 7.0),
        _row("sift/none/dis/none/median_ratio", 4, 4.5, 3.5, 6.0),
        _row("fast/none/klt/none/median_ratio", 5, 9.0, 5.1, 12.0),
        _row("sift/sift/bf/nn/similarity_fit", 6, 5.0, 4.0, 6.0),
        _row("disk/disk/lightglue/none/median_ratio", 7, 20.0, 15.0, 30.0),
    ]
)


def test_each_setting_has_one_family() -> None:
    assert ev.family_of(RANKING).tolist() == [
        "learned", "classic", "classic", "dense flow", "tracking", "scale fit", "learned",
    ]  # fmt: skip


def test_the_best_classic_setting_heads_and_intervals_decide() -> None:
    table = ev.against_best_classic(RANKING)
    assert table["setting"].tolist()[0] == "sift/sift/bf/nn/median_ratio"
    assert dict(zip(table["setting"], table["verdict"], strict=True)) == {
        "sift/sift/bf/nn/median_ratio": "best classic",
        "xfeat/none/klt/none/median_ratio": "better",  # 2.9 < 3.0
        "sift/none/dis/none/median_ratio": "within interval",
        "fast/none/klt/none/median_ratio": "worse",  # 5.1 > 5.0
        "sift/sift/bf/nn/similarity_fit": "within interval",  # 4.0-6.0 touches 3.0-5.0
        "disk/disk/lightglue/none/median_ratio": "worse",
    }
    (sentence,) = ev.verdict_sentence(table)
    assert "1 setting(s) beat it beyond the intervals: xfeat/none/klt/none/median_ratio" in sentence


def test_nothing_to_compare_gives_an_empty_table() -> None:
    classic_only = RANKING[ev.family_of(RANKING) == "classic"]
    assert ev.against_best_classic(classic_only).empty
    learned_only = RANKING[ev.family_of(RANKING) == "learned"]
    assert ev.against_best_classic(learned_only).empty
