"""Committed reports come from a clean commit (issue 29, item 5): regenerating one report does
not make the next one's code version dirty (it ignores ``results/``, which the reports write)."""

from __future__ import annotations

import os
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
