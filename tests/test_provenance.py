"""Committed reports come from a clean commit (issue 29, item 5): regenerating one report does
not make the next one's code version dirty (it ignores ``results/``, which the reports write)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import PROJECT_ROOT


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_a_changed_report_does_not_make_the_code_version_dirty(tmp_path: Path) -> None:
    """In a clean clone, a changed file under results/ leaves ``git_dirty`` False; a changed
    source file makes it True."""
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(PROJECT_ROOT), str(clone)], check=True)
    probe = (
        "from experiments.host.provenance import code_version; print(code_version()['git_dirty'])"
    )
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


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=PROJECT_ROOT, capture_output=True, text=True)


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_every_committed_report_names_clean_commits_of_this_repository() -> None:
    """Every committed page under ``results/`` that prints a code version says
    ``dirty=False`` for its runs and itself, and each commit it names is one of this
    repository's (so the numbers can be regenerated from a checkout of it)."""
    listed = _git("ls-files", "results")
    if listed.returncode != 0:
        pytest.skip("not a git checkout")
    pages = [PROJECT_ROOT / p for p in listed.stdout.split() if p.endswith(".md")]
    shallow = _git("rev-parse", "--is-shallow-repository").stdout.strip() == "true"
    checked = 0
    for page in pages:
        for line in page.read_text().splitlines():
            if not line.startswith("| code version"):
                continue
            checked += 1
            assert "dirty=True" not in line, f"{page.relative_to(PROJECT_ROOT)}: {line}"
            assert "dirty=False" in line, f"{page.relative_to(PROJECT_ROOT)}: {line}"
            for sha in re.findall(r"`([0-9a-f]{40})`", line):
                if not shallow:
                    found = _git("cat-file", "-e", f"{sha}^{{commit}}").returncode == 0
                    assert found, f"{page.relative_to(PROJECT_ROOT)}: {sha} is no commit here"
    assert checked >= 10, "no committed report prints its code version"
