"""The analysis notebooks (jupytext percent-format ``.py``) run headless without an error cell."""

from __future__ import annotations

import jupytext
import pytest
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError

from tests.conftest import PROJECT_ROOT
from tests.test_report import camera_grid  # noqa: F401  (session fixture: the 2 × 2 sweep)

NOTEBOOKS = ("ranking", "fp5_lidar", "fp6_camera")

pytestmark = pytest.mark.slow


def error_outputs(notebook) -> list[str]:
    """``ename: evalue`` of every error output of the executed notebook's code cells."""
    return [
        f"{out.get('ename')}: {out.get('evalue')}"
        for cell in notebook.cells
        if cell.cell_type == "code"
        for out in cell.get("outputs", [])
        if out.get("output_type") == "error"
    ]


@pytest.mark.parametrize("name", NOTEBOOKS)
def test_notebook_runs_without_errors(name: str, camera_grid, monkeypatch) -> None:  # noqa: F811
    root, sweep = camera_grid
    monkeypatch.setenv("TTC_SWEEP_DIR", str(sweep))
    monkeypatch.setenv("TTC_CACHE_DIR", str(root / "cache"))
    notebook = jupytext.read(PROJECT_ROOT / "notebooks" / f"{name}.py")
    assert any("parameters" in c.metadata.get("tags", []) for c in notebook.cells)
    client = NotebookClient(notebook, kernel_name="python3", timeout=600,
                            resources={"metadata": {"path": str(PROJECT_ROOT / "notebooks")}})  # fmt: skip
    try:
        client.execute()
    except CellExecutionError as exc:
        pytest.fail(f"{name}: {str(exc)[-3000:]}")
    assert error_outputs(notebook) == []
    images = [o for c in notebook.cells for o in c.get("outputs", [])
              if "image/png" in o.get("data", {})]  # fmt: skip
    assert images, f"{name} drew no figure"
