"""The HTML report: one self-contained folder (``<out>/html/``) with ``index.html`` that opens
from disk with no server and no network.

* ``index.html``: the camera ranking, sortable and filterable (DataTables, shipped by the
  :mod:`itables` package and copied into ``assets/``), each setting linked to its page;
* ``settings/<dataset>__<setting>.html``: the setting's TTC series against the reference (an
  inline SVG), its metrics, its way-off frames with their reasons, numbers and pictures; on a
  sweep of thousands of settings (``grand``), pages of the :data:`BEST_PAGES` best and
  :data:`WORST_PAGES` worst of each dataset only (the others are rows of the tables);
* ``fp6.html``, ``fp5.html``, ``fp7.html``, ``reference.html``: the FP.6 / FP.5 / FP.7
  (fused TTC) diagnoses and the reference;
* ``pictures/fp6``, ``pictures/fp5``, ``img/``: the report's pictures and figures (the same
  bytes as beside the markdown, so git stores each once).

Pages are built by :mod:`.pages` from the tables the markdown writers made; :mod:`.page`
holds the page skeleton and tables, :mod:`.svg` the series chart.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd

from experiments.report.encode import write_text
from experiments.report.html import pages
from experiments.report.html.objects_page import OBJECT_FIGURES, objects_page, verdict_paragraphs
from experiments.report.html.page import write_assets
from experiments.report.load import SweepData
from ttc.atomic import write_bytes_atomic

#: The FP.6 figures of the markdown report (copied into ``img/`` with the camera pages).
FP6_FIGURES = ("fp6_heatmap.png", "fp6_ttc_series.png", "fp6_pareto.png",
               "fp6_rank_intervals.png")  # fmt: skip
#: Figures of the markdown report shown on the HTML pages (copied into ``img/``).
FIGURES = ("reference.png", "fp5_lidar_ttc.png", *FP6_FIGURES, "fp7_fusion_ttc.png",
           *OBJECT_FIGURES)  # fmt: skip


#: ``fp5.html`` without an FP.5 report: no lidar estimate ran, or the sweep is judged against
#: an exact truth (its lidar estimators are on the truth page).
NO_FP5 = "No lidar estimate ran."
NO_FP5_TRUTH = ("Judged against an exact truth: the lidar estimators per target TTC are on the "
                '<a href="reference.html">truth page</a>.')  # fmt: skip

#: ``objects.html`` of a report without an every-object ranking.
NO_OBJECTS = "No object was judged: a generated recording, or no camera setting ran."

#: Settings of a dataset given a page: the best and the worst of its ranking.
BEST_PAGES, WORST_PAGES = 250, 50


def paged_settings(
    ranking: pd.DataFrame, best: int = BEST_PAGES, worst: int = WORST_PAGES
) -> set[tuple[str, str]]:
    """The (dataset, setting) pairs of ``ranking`` (fp6_ranking rows) that get a page: every
    one when a dataset has at most ``best + worst`` settings, else its ``best`` best ranked
    and ``worst`` worst ranked."""
    chosen: set[tuple[str, str]] = set()
    for dataset, rows in ranking.sort_values("rank", kind="stable").groupby("dataset"):
        keep = rows if len(rows) <= best + worst else pd.concat([rows.head(best), rows.tail(worst)])
        chosen |= {(str(dataset), str(s)) for s in keep["setting"]}
    return chosen


def _copy_files(sources: list[Path], folder: Path) -> dict[str, str]:
    """Copy files into ``folder`` (atomically); their names by stem."""
    for src in sources:
        write_bytes_atomic(src.read_bytes(), folder / src.name)
    return {src.stem: src.name for src in sources}


def html_report(
    data: SweepData,
    reference: pd.DataFrame,
    fp5_table: pd.DataFrame | None,
    fp6_tables: tuple[pd.DataFrame, pd.DataFrame] | None,
    out: Path,
    fp7_tables: tuple[pd.DataFrame, pd.DataFrame] | None = None,
    truth_text: str | None = None,
    objects_ranking: pd.DataFrame | None = None,
) -> Path:
    """Write the HTML report of the tables the markdown writers returned into ``out/html``
    (replacing an earlier one) and return its ``index.html``: :func:`camera_pages` then
    :func:`other_pages`, whose parameters these are."""
    camera_pages(data, fp6_tables, out)
    return other_pages(data, reference, fp5_table, fp6_tables, out, fp7_tables, truth_text,
                       objects_ranking)  # fmt: skip


def camera_pages(
    data: SweepData, fp6_tables: tuple[pd.DataFrame, pd.DataFrame] | None, out: Path
) -> None:
    """Start the HTML report in ``out/html`` (an earlier one removed, the assets written) with
    its camera pages: ``fp6.html`` and a page per setting of :func:`paged_settings`, with the
    FP.6 figures and pictures the markdown writer put in ``out``. The report's own process
    writes them as soon as FP.6 is done, while its second process still works
    (:mod:`experiments.report.forked`); :func:`other_pages` writes the rest."""
    folder = out / "html"
    shutil.rmtree(folder, ignore_errors=True)
    write_assets(folder, write_text)
    figures = {name: name for name in FP6_FIGURES if (out / name).is_file()}
    _copy_files([out / name for name in figures], folder / "img")
    fp6_pictures = _copy_files(sorted((out / "fp6_pictures").glob("*.*")), folder / "pictures/fp6")
    t, ranking = fp6_tables if fp6_tables is not None else (None, None)
    if t is None or ranking is None or ranking.empty:
        write_text(pages.page("FP.6 camera", "<p>No camera setting ran.</p>", here="fp6.html"),
                   folder / "fp6.html")  # fmt: skip
        return
    paged = paged_settings(ranking)
    write_text(pages.fp6_page(pages.provenance_block(data), t, fp6_pictures, figures, paged),
               folder / "fp6.html")  # fmt: skip
    needed = ["dataset", "setting", "reason_text", *pages.FRAME_COLUMNS]
    # only the rows of the settings that get a page (grand: 300 of 5,600 settings)
    pairs = pd.MultiIndex.from_arrays([t["dataset"].astype(str), t["setting"].astype(str)])
    shown = t.loc[pairs.isin(list(paged)), needed]
    by_setting = dict(list(shown.groupby(["dataset", "setting"], sort=False)))
    for _, row in ranking.iterrows():
        rows = by_setting.get((row["dataset"], row["setting"]))
        if rows is None or (row["dataset"], row["setting"]) not in paged:
            continue
        path = folder / pages.setting_href(row["dataset"], row["setting"])
        write_text(pages.setting_page(row, rows, fp6_pictures), path)


def other_pages(
    data: SweepData,
    reference: pd.DataFrame,
    fp5_table: pd.DataFrame | None,
    fp6_tables: tuple[pd.DataFrame, pd.DataFrame] | None,
    out: Path,
    fp7_tables: tuple[pd.DataFrame, pd.DataFrame] | None = None,
    truth_text: str | None = None,
    objects_ranking: pd.DataFrame | None = None,
) -> Path:
    """The pages of the HTML report in ``out/html`` besides :func:`camera_pages` (written
    first), and its ``index.html`` (returned). The pictures and figures are those the markdown
    writers put in ``out``. ``truth_text``: the ``truth.md`` of a sweep judged against an
    exact truth, shown as its reference page. ``objects_ranking``: the every-object ranking
    (``objects_ranking.csv`` rows) of a real recording, shown on ``objects.html`` beside
    ``objects.md``; on a recording without a judged lead it is the verdict ``index.html``
    leads with."""
    folder = out / "html"
    figures = {name: name for name in FIGURES if (out / name).is_file()}
    _copy_files([out / name for name in figures if name not in FP6_FIGURES], folder / "img")
    fp5_pictures = _copy_files(sorted((out / "fp5_pictures").glob("*.*")), folder / "pictures/fp5")
    ranking = fp6_tables[1] if fp6_tables is not None else None
    provenance = pages.provenance_block(data)
    paged = paged_settings(ranking) if ranking is not None and not ranking.empty else set()
    verdict = verdict_paragraphs(ranking, objects_ranking)
    write_text(pages.index_page(provenance, ranking, figures, paged, verdict),
               folder / "index.html")  # fmt: skip
    objects_md = out / "objects.md"
    if objects_ranking is not None and objects_md.is_file():
        text = objects_md.read_text(encoding="utf-8")
        write_text(objects_page(provenance, text, objects_ranking, figures),
                   folder / "objects.html")  # fmt: skip
    else:
        write_text(pages.page("every object", f"<p>{NO_OBJECTS}</p>", here="objects.html"),
                   folder / "objects.html")  # fmt: skip
    if truth_text is None:
        write_text(pages.reference_page(provenance, reference, figures), folder / "reference.html")
    else:
        write_text(pages.truth_page(truth_text), folder / "reference.html")
    if fp5_table is not None:
        write_text(pages.fp5_page(provenance, data, fp5_table, reference, fp5_pictures, figures),
                   folder / "fp5.html")  # fmt: skip
    else:
        text = NO_FP5 if truth_text is None else NO_FP5_TRUTH
        write_text(pages.page("FP.5 lidar", f"<p>{text}</p>", here="fp5.html"),
                   folder / "fp5.html")  # fmt: skip
    if fp7_tables is not None:
        write_text(pages.fp7_page(provenance, *fp7_tables, figures), folder / "fp7.html")
    else:
        write_text(pages.page("FP.7 fused", "<p>No run with a fusion (fusion=none).</p>",
                              here="fp7.html"), folder / "fp7.html")  # fmt: skip
    return folder / "index.html"
