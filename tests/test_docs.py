"""The documentation says what the code does: the README carries the two newcomer commands
(the test command is the CI command); the docs pages (``docs/``, a MkDocs site) hold the
schema table and every config option, and the site builds without a warning."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from experiments.store.schema import markdown_table
from tests.conftest import PROJECT_ROOT
from ttc.settings import AXES

README = (PROJECT_ROOT / "README.md").read_text()
DOCS = {p.name: p.read_text() for p in sorted((PROJECT_ROOT / "docs").glob("*.md"))}


def test_schema_table_is_current() -> None:
    assert markdown_table() in DOCS["results.md"], (
        "regenerate with: python -m experiments.store.schema"
    )


def test_readme_test_command_is_the_ci_command() -> None:
    ci = (PROJECT_ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert ci in README


def test_every_config_group_value_is_documented() -> None:
    text = "\n".join(DOCS.values())
    for group in AXES:
        for option in sorted((PROJECT_ROOT / "conf" / group).glob("*.yaml")):
            assert option.stem in text, f"{group}/{option.stem} missing from docs/"


def test_the_readme_is_short_and_links_every_page() -> None:
    assert len(README.encode()) < 8_000, "the README holds the commands; the guide is docs/"
    for name in DOCS:
        assert f"(docs/{name})" in README, f"docs/{name} is not linked from the README"


def test_the_site_builds_strictly(tmp_path: Path) -> None:
    """``mkdocs build --strict``: every page in the nav, no broken link or anchor."""
    pytest.importorskip("mkdocs")
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
        cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    for name in DOCS:
        page = "index.html" if name == "index.md" else f"{Path(name).stem}/index.html"
        assert (tmp_path / page).is_file(), page


def _main_command() -> list[list[str]]:
    """The README's main command as its ``ttc-bench`` steps (argument lists)."""
    line = next(x for x in README.splitlines() if "ttc-bench run +experiment=fp6_grid" in x)
    steps = [s.split() for s in line.split("&&")]
    return [s[1:] for s in steps if s[0].endswith("/ttc-bench")]


def test_the_main_command_writes_only_where_nothing_is_tracked() -> None:
    """Everything the main command writes (its sweeps, its report folder, the stage cache and
    the downloaded frames) is ignored by git, so running it leaves ``git status`` clean; the
    committed reports are under ``results/``, which it does not touch."""
    steps = _main_command()
    assert [s[0] for s in steps] == ["run", "run", "report"]
    report = steps[-1]
    out = report[report.index("--out") + 1]
    written = [out, *[a for a in report[1:] if a.startswith("sweeps/")], "sweeps/x", "cache/x"]
    written.append("data/kitti/x.png")
    assert not out.startswith("results/")
    for path in written:
        ignored = subprocess.run(["git", "check-ignore", "-q", "--no-index", path],
                                 cwd=PROJECT_ROOT).returncode == 0  # fmt: skip
        assert ignored, f"the main command writes {path}, which git does not ignore"
