"""Reference writer: ``reference.csv``, ``reference.png`` and ``reference.md`` (what the
reference is and its caveats, :mod:`ttc.evaluation`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from experiments.report.encode import write_csv, write_text
from experiments.report.header import provenance_markdown
from experiments.report.load import SweepData
from experiments.report.plots import plot_reference, save_figure
from ttc import evaluation as ev


def reference_facts(reference: pd.DataFrame) -> list[str]:
    """Sentences a reader can check in ``reference.csv``: the stop, the noise, the regimes and
    the frames too uncertain to judge a TTC on."""
    regimes = reference["regime"].iloc[1:].value_counts()
    stationary = reference.loc[reference["regime"] == "stationary", "frame"]
    stop = (
        f"The lead car stands still from frame {int(stationary.min()) - 1} on (found from the "
        "data), so every later frame pair has ratio 1 and no collision course."
        if len(stationary)
        else "The lead car does not come to a standstill in this recording."
    )
    finite = np.isfinite(reference["ttc_ref_s"]) & (reference["ttc_ref_s"] > 0)
    uncertain = reference.loc[finite & ~reference["judgeable"].astype(bool), "frame"]
    listed = ", ".join(str(int(f)) for f in uncertain) or "none"
    return [
        stop,
        f"Residual noise of the rear distance around the fit: "
        f"{100 * reference['noise_sd_m'].iloc[0]:.1f} cm per frame.",
        "Frame pairs per regime: "
        + ", ".join(f"{r} {int(regimes.get(r, 0))}" for r in ev.REGIMES)
        + ".",
        f"Frame pairs whose finite reference TTC is too uncertain to judge a TTC on (relative "
        f"standard deviation above {ev.MAX_REF_REL_SD:.0%}; left out of the outlier rate and "
        f"the relative error, still judged by the motion-in-depth error): {listed}.",
        ev.not_judged_text(reference),
    ]


def reference_report(data: SweepData, reference: pd.DataFrame, out: Path) -> None:
    """Write ``reference.csv``, ``reference.png`` and ``reference.md`` (with the caveats)."""
    write_csv(reference, out / "reference.csv")
    save_figure(plot_reference(reference), out / "reference.png")
    text = [
        provenance_markdown(data, "Reference TTC"),
        ev.REFERENCE_SUMMARY,
        "",
        *[f"- {fact}" for fact in reference_facts(reference)],
        "",
        f"**Caveats.** {ev.REFERENCE_CAVEATS}",
        "",
        "![reference](reference.png)",
        "",
        "Per frame: `reference.csv`: distance raw / smoothed / its standard deviation (m), "
        "closing speed over the pair's interval (m/s), `ratio_ref` (D(k-1) / D(k)), "
        "`ttc_ref_s` and `ttc_ref_sd_s` (s), `mid_ref_sd` (standard deviation of the "
        "reference's motion in depth, MiD units), `judgeable`, `regime`.",
    ]
    write_text("\n".join(text) + "\n", out / "reference.md")
