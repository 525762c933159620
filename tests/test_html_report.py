"""The HTML report (``<out>/html``) of a real camera-grid sweep: self-contained (every link
and source resolves inside the folder, nothing from the network), and in a real headless
Chromium the ranking table renders, sorts and filters, settings and flagged frames link to
their reasons and pictures, and no page logs an error."""

from __future__ import annotations

import time
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pandas as pd
import pytest

from experiments.report.html import pages
from tests.browser_cdp import Browser, chromium_path
from tests.test_report import camera_grid, grid_report, shared_root  # noqa: F401

#: Attributes whose URLs a page loads or links to.
URL_ATTRS = {("a", "href"), ("img", "src"), ("script", "src"), ("link", "href")}


class _Links(HTMLParser):
    """The URLs (tag, attribute, value) and element ids of a page."""

    def __init__(self) -> None:
        super().__init__()
        self.urls: list[tuple[str, str, str]] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for name, value in attrs:
            if name == "id" and value:
                self.ids.add(value)
            if (tag, name) in URL_ATTRS and value:
                self.urls.append((tag, name, value))


def parse(path: Path) -> _Links:
    parser = _Links()
    parser.feed(path.read_text(encoding="utf-8"))
    return parser


@pytest.fixture(scope="module")
def html_dir(grid_report: Path) -> Path:  # noqa: F811
    return grid_report / "html"


@pytest.mark.slow
def test_html_report_is_self_contained(html_dir: Path, grid_report: Path) -> None:  # noqa: F811
    ranking = pd.read_csv(grid_report / "fp6_ranking.csv")
    for name in ("index.html", "fp6.html", "fp5.html", "fp7.html", "reference.html"):
        assert (html_dir / name).is_file(), name
    settings = sorted((html_dir / "settings").glob("*.html"))
    assert len(settings) == len(ranking) == 4
    ids = {p: parse(p) for p in html_dir.rglob("*.html")}
    checked = 0
    for page, links in ids.items():
        for tag, attr, url in links.urls:
            parts = urlsplit(url)
            if tag == "a" and parts.scheme in ("http", "https"):
                continue  # a link a reader may follow, never loaded by the page
            assert not parts.scheme and not parts.netloc, f"{page.name}: {tag} {attr}={url}"
            target = (page.parent / unquote(parts.path)).resolve() if parts.path else page
            assert target.is_file(), f"{page.name}: {url} does not exist"
            assert html_dir.resolve() in target.parents, f"{page.name}: {url} leaves the folder"
            if parts.fragment and target.suffix == ".html":
                assert parts.fragment in ids[target].ids, f"{page.name}: no #{parts.fragment}"
            checked += 1
    assert checked > 50
    # every way-off row of the CSV has its section on its setting's page
    frames = pd.read_csv(grid_report / "fp6_camera_ttc.csv")
    way = frames[frames["way_off"]]
    assert len(way) >= 1
    for row in way.itertuples():
        page = html_dir / pages.setting_href(row.dataset, row.setting)
        assert f"f{row.frame}" in ids[page].ids
        assert str(row.reasons) in page.read_text()


@pytest.mark.slow
@pytest.mark.skipif(chromium_path() is None, reason="chromium is not installed: `.ci/run` "
                    "installs it (apt-get install -y chromium)")  # fmt: skip
def test_html_report_in_headless_chromium(
    html_dir: Path,
    grid_report: Path,  # noqa: F811
    tmp_path: Path,
) -> None:
    ranking = pd.read_csv(grid_report / "fp6_ranking.csv")
    frames = pd.read_csv(grid_report / "fp6_camera_ttc.csv")
    pictured = sorted(p.stem for p in (grid_report / "fp6_pictures").iterdir())
    start = time.monotonic()
    with Browser(tmp_path / "profile") as browser:
        browser.open(html_dir / "index.html")
        rows = "document.querySelectorAll('#ranking tbody tr').length"
        assert browser.wait_for(f"document.querySelector('#ranking.dataTable') && {rows}") == 4
        links = browser.evaluate("[...document.querySelectorAll('#ranking tbody a')]"
                                 ".map(a => a.textContent)")  # fmt: skip
        assert set(ranking["setting"]) <= set(links)
        # sort: a click on the "setting" header orders the rows by setting
        browser.evaluate("[...document.querySelectorAll('#ranking thead th')]"
                         ".find(th => th.textContent.trim() === 'setting').click()")  # fmt: skip
        shown = browser.evaluate("[...document.querySelectorAll('#ranking tbody td a')]"
                                 ".filter(a => a.href.includes('/settings/') && !a.hash)"
                                 ".map(a => a.textContent)")  # fmt: skip
        assert shown == sorted(ranking["setting"])
        # filter: typing in the search box keeps the matching rows
        browser.evaluate("(() => { const i = document.querySelector('#ranking_wrapper "
                         "input[type=search]'); i.value = 'orb/'; "
                         "i.dispatchEvent(new Event('input', {bubbles: true})); })()")  # fmt: skip
        assert browser.wait_for(f"{rows} === 2 && {rows}") == 2
        browser.evaluate("window.scrollTo(0, 0)")
        shot = browser.screenshot(tmp_path / "index.png")
        assert shot.stat().st_size > 20_000

        # a setting with a pictured way-off frame: from the ranking to its reasons and picture
        way = frames[frames["way_off"]]
        stems = way["setting"].str.replace("/", "_") + "_frame_" + way["frame"].map("{:04d}".format)
        row = way[stems.isin(pictured)].iloc[0]
        page = html_dir / pages.setting_href(row["dataset"], row["setting"])
        browser.open(page)
        n_frames = int((frames["setting"] == row["setting"]).sum())
        assert browser.evaluate("document.querySelectorAll('svg.series circle, svg.series "
                                "path').length") == n_frames  # fmt: skip
        link = f"document.querySelector('svg.series a[href=\"#f{row['frame']}\"]')"
        assert browser.evaluate(f"!!{link}")
        section = f"document.getElementById('f{row['frame']}')"
        assert row["reasons"] in browser.evaluate(f"{section}.textContent")
        image = f"{section}.querySelector('img')"
        assert browser.wait_for(f"{image}.complete && {image}.naturalWidth") >= 800
        browser.screenshot(tmp_path / "setting.png")

        # FP.6: a way-off frame's link leads to that frame's section
        browser.open(html_dir / "fp6.html")
        assert browser.wait_for("document.querySelector('#way_off.dataTable') && "
                                "document.querySelectorAll('#way_off tbody tr').length") == min(
            len(way), 25)  # fmt: skip
        href = browser.evaluate("document.querySelector('#way_off tbody a[href*=\"#f\"]').href")
        browser.open(href)
        fragment = urlsplit(href).fragment
        assert browser.evaluate(f"!!document.getElementById('{fragment}')")
        for name in ("fp5.html", "reference.html"):
            browser.open(html_dir / name)
            browser.wait_for("document.querySelectorAll('img').length > 0 && [...document."
                             "querySelectorAll('img')].every(i => i.complete && i.naturalWidth)")  # fmt: skip
        assert browser.errors == []
    assert time.monotonic() - start < 60


def test_a_sweep_of_thousands_gives_pages_to_its_best_and_worst_only() -> None:
    from experiments.report.html import paged_settings  # noqa: PLC0415
    from experiments.report.html.pages import index_page  # noqa: PLC0415

    rank = [10, 1, 2, 3, 4, 5, 6, 7, 8, 9]
    ranking = pd.DataFrame({"dataset": "kitti_0_18", "setting": [f"s{i}" for i in range(10)],
                            "rank": rank, "rank_lo": rank, "rank_hi": [r + 1 for r in rank],
                            "way_off_frames": 1, "block_length": 2, "n_uncertain": 0,
                            "n_judged": 18})  # fmt: skip
    assert paged_settings(ranking, best=20, worst=5) == {("kitti_0_18", f"s{i}") for i in range(10)}
    paged = paged_settings(ranking, best=3, worst=2)
    assert paged == {("kitti_0_18", s) for s in ("s1", "s2", "s3", "s9", "s0")}
    html = index_page("", ranking, {}, paged)
    assert 'href="settings/kitti_0_18__s1.html"' in html and "s5.html" not in html
    assert "Pages of the 5 best and worst settings only; the other 5 are rows" in html
