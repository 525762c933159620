"""Reference writer: ``reference.csv``, ``reference.png`` and ``reference.md`` (what the
reference is and its caveats, :mod:`ttc.evaluation`)."""

from __future__ import annotations

import inspect
from pathlib import Path

import pandas as pd

from experiments.report.encode import write_csv, write_text
from experiments.report.header import provenance_markdown
from experiments.report.load import SweepData
from experiments.report.plots import plot_reference, save_figure
from ttc import evaluation as ev


def reference_summary() -> str:
    """The first paragraph of the docstring of the module that computes the reference TTC."""
    return inspect.getmodule(ev.reference_ttc).__doc__.strip().split("\n\n")[0]


def reference_report(data: SweepData, reference: pd.DataFrame, out: Path) -> None:
    """Write ``reference.csv``, ``reference.png`` and ``reference.md`` (with the caveats)."""
    write_csv(reference, out / "reference.csv")
    save_figure(plot_reference(reference), out / "reference.png")
    text = [
        provenance_markdown(data, "Reference TTC"),
        reference_summary(),
        "",
        f"**Caveats.** {ev.REFERENCE_CAVEATS}",
        "",
        "![reference](reference.png)",
        "",
        "Per frame: `reference.csv` (distance in m, closing speed in m/s, TTC in s).",
    ]
    write_text("\n".join(text) + "\n", out / "reference.md")
