"""Committed reports come from a clean commit (issue 29, item 5): every provenance line of
every page under ``results/`` says ``dirty=False``, and regenerating one report does not make
the next one dirty (the code version ignores ``results/``)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import PROJECT_ROOT

RESULTS = PROJECT_ROOT / "results"
#: A code version as the provenance header prints it (markdown and HTML).
VERSION = re.compile(
    r"([0-9a-f]{40})</code> dirty=(True|False)|`([0-9a-f]{40})` dirty=(True|False)"
)


def committed_pages() -> list[Path]:
    """The report pages git tracks under ``results/``."""
    out = subprocess.run(["git", "ls-files", "results"], cwd=PROJECT_ROOT, capture_output=True,
                         text=True, check=True).stdout.split()  # fmt: skip
    return [PROJECT_ROOT / p for p in out if p.endswith((".md", ".html"))]


def test_every_committed_report_comes_from_a_clean_commit() -> None:
    dirty, seen = [], 0
    for page in committed_pages():
        for found in VERSION.finditer(page.read_text(encoding="utf-8")):
            seen += 1
            if "True" in found.groups():
                dirty.append(str(page.relative_to(PROJECT_ROOT)))
    assert seen > 0, "no provenance found under results/"
    assert not dirty, f"generated from a dirty work tree: {sorted(set(dirty))}"


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_a_changed_report_does_not_make_the_code_version_dirty(tmp_path: Path) -> None:
    """In a clean clone, a changed file under results/ leaves ``git_dirty`` False; a changed
    source file makes it True."""
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(PROJECT_ROOT), str(clone)], check=True)
    probe = "from experiments.provenance import code_version; print(code_version()['git_dirty'])"
    env = {**os.environ, "PYTHONPATH": str(clone)}

    def dirty() -> str:
        return subprocess.run([sys.executable, "-c", probe], cwd=clone, env=env, check=True,
                              capture_output=True, text=True).stdout.strip()  # fmt: skip

    assert dirty() == "False"
    page = next((clone / "results").rglob("*.md"))
    page.write_text(page.read_text() + "\nregenerated\n")
    assert dirty() == "False"
    (clone / "ttc" / "__init__.py").write_text("# changed\n")
    assert dirty() == "True"
