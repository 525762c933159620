"""The front page's answer (``README.md`` and ``docs/index.md``, section "What it found")
says what the committed results say (issue 29, item 6).

Each figure there is followed by an HTML comment naming where it comes from, under
``results/``::

    4<!--@kitti_0_18/fp6_ranking.csv:count rank_lo==1-->
    3.82<!--@kitti_0_18/fp6_ranking.csv:camera_mid_median@rank==1%.2f-->
    `sift/sift/flann/nn`<!--@kitti_0_18/fp6_ranking.csv:setting@rank==1-->
    −0.03<!--@recordings/recordings.md#camera:kendall_tau%.2f-->

``count [QUERY]``: the number of rows (matching the pandas query); ``COLUMN[@QUERY][%FMT]``:
the value in the one row (matching the query), formatted. A markdown file's table is the
first one with that column under the heading ``## <section>``. When the results are
regenerated, this test names every figure that changed.
"""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd

from tests.conftest import PROJECT_ROOT

RESULTS = PROJECT_ROOT / "results"
PAGES = ("README.md", "docs/index.md")
SECTION = "## What it found"
#: A figure (a number, or a value in backticks) and the pointer to its source after it.
POINTER = re.compile(
    r"(?P<figure>`[^`]+`|[−-]?\d+(?:\.\d+)?)<!--@(?P<path>[^:#]+)(?:#(?P<section>[^:]+))?"
    r":(?P<expr>.*?)-->"
)


def found_section(page: str) -> str:
    """The "What it found" section of a front page (up to the next ``## `` heading)."""
    text = (PROJECT_ROOT / page).read_text()
    assert SECTION in text, f"{page} has no '{SECTION}' section"
    return text.split(SECTION, 1)[1].split("\n## ", 1)[0]


def markdown_table(path: Path, section: str, column: str) -> pd.DataFrame:
    """The first table with ``column`` under the heading ``## <section>`` of ``path``."""
    text = path.read_text().split(f"\n## {section}\n", 1)[1].split("\n## ", 1)[0]
    for block in re.findall(r"(?:^\|.*\|\n)+", text, flags=re.M):
        rows = [[c.strip() for c in line.strip("|").split("|")] for line in block.splitlines()]
        if column in rows[0]:
            return pd.DataFrame(rows[2:], columns=rows[0]).apply(_numbers)
    raise AssertionError(f"{path}: no table with column {column} under '## {section}'")


def _numbers(column: pd.Series) -> pd.Series:
    """A markdown table's column as numbers when every cell is one."""
    try:
        return pd.to_numeric(column)
    except ValueError:
        return column


def source_value(path: str, section: str | None, expr: str) -> str:
    """What a pointer's source says, as the page should print it."""
    file = RESULTS / path.strip()
    count = expr.strip().startswith("count")
    column, query, fmt = None, expr.strip().removeprefix("count").strip(), ""
    if not count:
        column, _, fmt = expr.partition("%")
        column, _, query = column.partition("@")
        column = column.strip()
    table = markdown_table(file, section.strip(), column or "") if section else pd.read_csv(file)
    rows = table.query(query) if query.strip() else table
    if count:
        return str(len(rows))
    assert len(rows) == 1, f"{path} {expr}: {len(rows)} rows, expected one"
    value = rows[column].iloc[0]
    return format(value, fmt) if fmt else str(value)


def mismatches(text: str) -> list[str]:
    """Every figure of ``text`` that differs from its source, in words."""
    out = []
    for m in POINTER.finditer(text):
        figure = m["figure"].strip("`").replace("−", "-")
        expected = source_value(m["path"], m["section"], m["expr"])
        if figure != expected:
            out.append(f"{figure} ≠ {expected} ({m['path']} {m['section'] or ''}: {m['expr']})")
    return out


def test_every_figure_on_the_front_page_is_its_source_file() -> None:
    for page in PAGES:
        section = found_section(page)
        assert len(POINTER.findall(section)) >= 10, f"{page}: figures without their sources"
        assert not mismatches(section), (page, mismatches(section))


def test_the_readme_and_the_docs_index_give_the_same_answer() -> None:
    readme, index = (POINTER.findall(found_section(p)) for p in PAGES)
    assert readme == index
    assert len(found_section(PAGES[0]).strip().splitlines()) <= 12


def test_a_changed_figure_is_named() -> None:
    """The check fails, naming the figure and its source, when a figure differs."""
    section = found_section(PAGES[0])
    first = POINTER.search(section)
    assert first is not None
    changed = section.replace(first.group(0), "987654" + first.group(0)[len(first["figure"]) :])
    assert mismatches(changed) == [
        f"987654 ≠ {first['figure'].strip('`').replace('−', '-')} "
        f"({first['path']} {first['section'] or ''}: {first['expr']})"
    ]
