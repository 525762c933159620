"""The judge report: ``judge.md`` (what was read, the conventions, each sensor's ranking of
the external settings among the harness's), ``judge_<sensor>_ranking.csv`` (every setting,
``external`` marked), ``judge_<sensor>_series.png`` (the external TTC series against
the reference), ``judge_rank_intervals.png`` and ``html/judge.html``, with the report's own
writers."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from experiments.judge.harness import HarnessSide
from experiments.judge.judging import ExternalInput
from experiments.report.encode import markdown_table, write_csv, write_text
from experiments.report.html.page import CSS, STYLE, esc, markdown_html
from experiments.report.plots import plot_rank_intervals, save_figure
from ttc import evaluation as ev

#: Harness settings shown in ``judge.md`` beside the external ones (the best by rank).
SHOWN_BEST = 10
CONVENTIONS = (
    "Conventions: a TTC belongs to the current frame of its pair (frame 1 = pair 0→1); NaN, "
    "±inf and blank cells are invalid estimates, counted in the invalid rate; seconds; the "
    "distance ratio judged is r = 1 + dt / TTC (dt from the recording's clock), so a "
    "negative TTC is a receding lead. External settings are marked `ext:<name>/<setting>`; "
    "their computing time is unknown and loses every tie of the ranking rule."
)


def _columns(sensor: str) -> list[str]:
    """The ranking CSV's columns for ``sensor``."""
    s = sensor
    return ["rank", "rank_lo", "rank_hi", "rank_median", "setting", "external",
            f"{s}_invalid_rate", f"{s}_invalid_rate_lo", f"{s}_invalid_rate_hi",
            f"{s}_mid_median", f"{s}_mid_median_lo", f"{s}_mid_median_hi", f"{s}_mid_mean",
            f"{s}_outlier_rate", f"{s}_medae_rel", f"{s}_medae_rel_lo", f"{s}_medae_rel_hi",
            f"{s}_meanae_rel", f"{s}_false_alarm_rate", f"{s}_jitter_s", f"{s}_invalid",
            "n_frames", "n_judged", "block_length", "ms_compute_per_frame", "run_id"]  # fmt: skip


def shown_rows(ranking: pd.DataFrame, best: int = SHOWN_BEST) -> pd.DataFrame:
    """The ``best`` harness settings and every external one, by rank."""
    return ranking[ranking["external"] | (ranking["rank"] <= best)].sort_values("rank")


def _section(sensor: str, ranking: pd.DataFrame) -> list[str]:
    """``judge.md``'s part for one sensor: the verdict line and the table."""
    s, ext = sensor, ranking[ranking["external"]]
    tied = ev.tied_for_first(ranking)
    best = ext.nsmallest(1, "rank").iloc[0]
    cols = ["rank", "rank_lo", "rank_hi", "setting", f"{s}_invalid_rate", f"{s}_mid_median",
            f"{s}_mid_median_lo", f"{s}_mid_median_hi", f"{s}_medae_rel"]  # fmt: skip
    return [
        f"## {sensor.capitalize()} TTC",
        "",
        f"{len(ext)} external and {len(ranking) - len(ext)} harness settings ranked together; "
        f"{tied} tie for first (90 % rank interval includes 1). The best external setting, "
        f"`{best['setting']}`, ranks {best['rank']:.0f} (interval {best['rank_lo']:.0f}–"
        f"{best['rank_hi']:.0f}) with a median motion-in-depth error of "
        f"{best[f'{s}_mid_median']:.2f} × 10⁻⁴ and an invalid rate of "
        f"{best[f'{s}_invalid_rate']:.2f}.",
        "",
        markdown_table(shown_rows(ranking)[cols]),
        "",
    ]


def plot_external_series(external: pd.DataFrame, reference: pd.DataFrame, sensor: str,
                         first: int, last: int) -> plt.Figure:  # fmt: skip
    """Each external setting's TTC (s) per frame against the reference TTC (black)."""
    fig, ax = plt.subplots(figsize=(9, 4.5))
    col = f"ttc_{sensor}"
    for run_id, own in external[external[col].notna()].groupby("run_id"):
        ax.plot(own["frame"], own[col].where(np.isfinite(own[col])), "-o", ms=3, lw=1,
                alpha=0.8, label=run_id)  # fmt: skip
    ref = reference[(reference["frame"] > first) & (reference["frame"] <= last)]
    finite = ref["ttc_ref_s"][np.isfinite(ref["ttc_ref_s"])]
    top = 2.5 * float(finite.max()) if len(finite) else 60.0
    ax.plot(ref["frame"], ref["ttc_ref_s"], color="black", lw=2.5, label="reference")
    ax.set(ylim=(min(0.0, -0.2 * top), top), xlabel="frame (current frame of the pair)",
           ylabel=f"{sensor} TTC (s)", title=f"External {sensor} TTC against the reference")  # fmt: skip
    ax.axhline(0, color="grey", lw=0.5)
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    return fig


def write_judge_report(
    side: HarnessSide, external: ExternalInput, rankings: dict[str, pd.DataFrame], out: Path
) -> list[Path]:
    """Write the judge report into ``out``; return the files written."""
    out.mkdir(parents=True, exist_ok=True)
    files = pd.DataFrame(external.files)
    lines = [
        "# External TTC judged",
        "",
        f"Harness side: {side.source}; frames {side.first}–{side.last} (pairs ending at "
        f"{side.first + 1}–{side.last}).",
        "",
        markdown_table(files),
        "",
        CONVENTIONS + " `dropped_first_frame`: invalid values on the recording's first frame "
        "(no pair ends there); `dropped_repeated`: exact repeats of an earlier row.",
        "",
    ]
    written = []
    for sensor, ranking in rankings.items():
        lines += _section(sensor, ranking)
        path = write_csv(ranking[_columns(sensor)], out / f"judge_{sensor}_ranking.csv")
        written.append(path)
        lines += [f"All settings: [{path.name}]({path.name}).", ""]
        if sensor == "camera":
            shown = shown_rows(ranking)
            written.append(save_figure(plot_rank_intervals(shown, n=len(shown)),
                                       out / "judge_rank_intervals.png"))  # fmt: skip
            lines += ["![rank intervals](judge_rank_intervals.png)", ""]
    for sensor in rankings:
        name = f"judge_{sensor}_series.png"
        fig = plot_external_series(external.rows, side.reference, sensor, side.first, side.last)
        written.append(save_figure(fig, out / name))
        lines += [f"![{sensor} TTC series]({name})", ""]
    text = "\n".join(lines)
    written.insert(0, write_text(text, out / "judge.md"))
    written.append(judge_html(text, [p.name for p in written if p.suffix == ".png"], out))
    return written


def judge_html(text: str, pictures: list[str], out: Path) -> Path:
    """``out/html/judge.html``: ``judge.md`` as a page in the report's style (its markdown
    subset, :func:`~experiments.report.html.page.markdown_html`), the pictures below."""
    images = "".join(f'<p><img src="../{esc(p)}" alt="{esc(p)}"></p>' for p in pictures)
    write_text(CSS.lstrip(), out / "html" / STYLE)
    body = markdown_html(text) + images
    return write_text(
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f'<title>External TTC judged</title>\n<link rel="stylesheet" href="{STYLE}">\n'
        f"</head>\n<body>\n{body}\n</body>\n</html>\n",
        out / "html" / "judge.html",
    )
