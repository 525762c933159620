"""Which verdict a recording supports (:mod:`ttc.evaluation.verdict`): exact checks on small
tables, and a real report of drive 0009 (frames 0-8, parked cars, no vehicle ahead) whose
markdown and HTML lead with "no lead" and the every-object verdict, with ``objects.html`` in the
navigation of every page."""

from __future__ import annotations

from html.parser import HTMLParser
from pathlib import Path

import pandas as pd
import pytest

from tests.test_report import make_report, make_sweep, shared_root
from ttc.evaluation.verdict import has_lead, level_rows, objects_verdict, supported_level


def _objects(levels: dict[str, list[int]]) -> pd.DataFrame:
    """An every-object ranking: per level, settings s0, s1 … with these ``n_pairs``."""
    rows = []
    for level, pairs in levels.items():
        for i, n in enumerate(pairs):
            rows.append({"difficulty": level, "setting": f"s{i}", "score": 0.1 * (i + 1),
                         "n_pairs": n, "rank": i + 1, "rank_lo": 1 if i < 2 else i,
                         "rank_hi": i + 2})  # fmt: skip
    return pd.DataFrame(rows)


def test_has_lead_is_any_judged_lead_frame() -> None:
    assert not has_lead(pd.DataFrame({"n_judged": [0, 0, float("nan")]}))
    assert has_lead(pd.DataFrame({"n_judged": [0, 3]}))
    assert not has_lead(pd.DataFrame({"n_judged": []}))


def test_the_strictest_level_with_enough_pairs_leads() -> None:
    table = _objects({"easy": [5, 6, 7], "moderate": [30, 25, 10], "hard": [40, 40, 40],
                      "all": [90, 90, 90]})  # fmt: skip
    assert supported_level(table, min_pairs=20) == "moderate"  # easy's median 6 < 20
    assert supported_level(table, min_pairs=5) == "easy"
    assert supported_level(table, min_pairs=1000) == "all"  # none has enough: every box
    assert supported_level(table.assign(n_pairs=0)) is None
    # a ranking without levels (before difficulty levels existed) is "all"
    assert supported_level(table[table["difficulty"] == "all"].drop(columns="difficulty")) == "all"
    sentence = objects_verdict(table, min_pairs=20)
    assert "level `moderate`: 2 of 3 settings are tied for first" in sentence
    assert "`s0`, has a score of 0.10" in sentence and "over 30 judged pairs" in sentence
    assert "the strictest KITTI level" in sentence
    assert "read this ranking with care" in objects_verdict(table, min_pairs=1000)


class _Text(HTMLParser):
    """The text of a page's paragraphs, in order, and its links."""

    def __init__(self) -> None:
        super().__init__()
        self.paragraphs: list[str] = []
        self.links: list[str] = []
        self._in_p = False

    def handle_starttag(self, tag: str, attrs) -> None:
        if tag == "p":
            self._in_p = True
            self.paragraphs.append("")
        if tag == "a":
            self.links += [v for k, v in attrs if k == "href" and v]

    def handle_endtag(self, tag: str) -> None:
        if tag == "p":
            self._in_p = False

    def handle_data(self, data: str) -> None:
        if self._in_p:
            self.paragraphs[-1] += data


def _parse(path: Path) -> _Text:
    parser = _Text()
    parser.feed(path.read_text(encoding="utf-8"))
    return parser


@pytest.fixture(scope="module")
def report_0009(tmp_path_factory) -> Path:
    """A report of a 2 x 2 camera grid on drive 0009, frames 0-8 (no lead vehicle)."""
    root = shared_root(tmp_path_factory)
    args = ["-m", "dataset=kitti_raw_0009", "dataset.last=8", "detector=fast,orb",
            "descriptor=brief,orb", "sweep_name=no_lead"]  # fmt: skip
    sweep = make_sweep(root, args, "no_lead")
    return make_report(root, [sweep], root / "reports" / "no_lead")


@pytest.mark.slow
def test_a_recording_without_a_lead_leads_with_every_object(report_0009: Path) -> None:
    lead = pd.read_csv(report_0009 / "fp6_ranking.csv")
    assert (lead["n_judged"] == 0).all()  # drive 0009: no vehicle ahead in the ego lane
    objects = pd.read_csv(report_0009 / "objects_ranking.csv")
    assert (objects["n_pairs"] > 0).any()
    # the markdown: the no-lead sentence comes before the ranking rule
    md = (report_0009 / "fp6_camera.md").read_text(encoding="utf-8")
    assert md.index("no lead vehicle was judged") < md.index("**Ranking rule**")
    assert "[objects.md](objects.md)" in md
    # the HTML: the first paragraphs say so and give the every-object verdict
    index = _parse(report_0009 / "html" / "index.html")
    opening = " ".join(index.paragraphs[:3])
    assert "no lead vehicle was judged" in opening
    assert "Every object, level" in opening and "tied for first" in opening
    level = supported_level(objects)
    assert level in ("easy", "moderate", "hard", "all")
    best = level_rows(objects, level).sort_values("rank").iloc[0]["setting"]
    assert f"level {level}:" in opening and best in opening
    assert "objects.html" in index.links
    # the every-object page: the verdict, objects.md's tables, the ranking table, the figure
    page = report_0009 / "html" / "objects.html"
    text = page.read_text(encoding="utf-8")
    assert text.count("Every object, level") == 1 and "Tracks by role" in text
    assert 'id="objects_ranking"' in text and "img/objects.png" in text
    assert (report_0009 / "html" / "img" / "objects.png").is_file()
    for other in ("fp6.html", "fp5.html", "reference.html"):
        assert "objects.html" in _parse(report_0009 / "html" / other).links


@pytest.mark.slow
def test_a_recording_with_a_lead_keeps_the_lead_verdict(tmp_path_factory) -> None:
    root = shared_root(tmp_path_factory)
    args = ["-m", "detector=fast,orb", "descriptor=brief,brisk", "dataset.last=5",
            "sweep_name=grid"]  # fmt: skip
    report = make_report(root, [make_sweep(root, args, "grid")], root / "reports" / "grid")
    index = _parse(report / "html" / "index.html")
    assert not any("no lead vehicle" in p for p in index.paragraphs)
    assert any("statistically tied for first" in p for p in index.paragraphs)
    assert "no lead vehicle" not in (report / "fp6_camera.md").read_text(encoding="utf-8")
