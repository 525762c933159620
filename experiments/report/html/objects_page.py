"""The HTML report's every-object page (``objects.html``) and the verdict ``index.html`` leads
with: the lead ranking where a lead was judged, else the every-object ranking of the level the
report stands behind (:mod:`ttc.evaluation.verdict`).

``objects.html`` shows what ``objects.md`` holds (tracks by role, pairs judged per level and
TTC range, the best settings per level, τ between levels, per track, where camera TTC breaks
down), the per-track picture and the breakdown figure, and the whole every-object ranking as a
sortable, filterable table (a ``difficulty`` filter when the ranking has levels)."""

from __future__ import annotations

import pandas as pd

from experiments.report.html.page import esc, inline, interactive_table, markdown_html, page
from ttc.evaluation.verdict import has_lead, no_lead_sentence, objects_verdict

#: How :func:`ttc.evaluation.verdict.objects_verdict`'s sentence starts (``objects.md``'s first
#: paragraph, which ``objects.html`` shows above its provenance instead).
VERDICT_START = "**Every object"
#: The every-object figures of the markdown report shown on ``objects.html``.
OBJECT_FIGURES = ("objects.png", "objects_breakdown.png")


def verdict_paragraphs(
    lead_ranking: pd.DataFrame | None, objects_ranking: pd.DataFrame | None
) -> list[str]:
    """The paragraphs (HTML) ``index.html`` opens with, per dataset without a judged lead:
    that no lead was judged and the every-object verdict it supports (empty where every
    dataset of ``lead_ranking`` has a judged lead: the lead ranking is the verdict)."""
    if lead_ranking is None or lead_ranking.empty:
        return []
    out = []
    for dataset, group in lead_ranking.groupby("dataset", sort=True):
        if has_lead(group):
            continue
        out.append(f"<p>{inline(no_lead_sentence(str(dataset), group))}</p>")
        if objects_ranking is not None and not objects_ranking.empty:
            out.append(
                f'<p class="verdict">{inline(objects_verdict(objects_ranking))} '
                '<a href="objects.html">every object</a></p>'
            )
        else:
            out.append("<p>No object was judged either.</p>")
    return out


def objects_page(
    provenance: str, markdown: str, ranking: pd.DataFrame, figures: dict[str, str]
) -> str:
    """``objects.html``: the every-object verdict, ``objects.md``'s tables (``markdown``, its
    title line dropped), its figures (``figures``: names under ``img/``) and the whole
    every-object ranking (``objects_ranking.csv`` rows), sortable and filterable."""
    body = markdown.partition("\n")[2] if markdown.startswith("# ") else markdown
    images = [
        f'<p><img class="figure" src="img/{esc(figures[name])}" alt="{esc(name)}"></p>'
        for name in OBJECT_FIGURES
        if name in figures
    ]
    parts = [
        "<h1>Every object: TTC judged per tracked vehicle</h1>",
        f'<p class="verdict">{inline(objects_verdict(ranking))}</p>' if len(ranking) else "",
        provenance,
        markdown_html(_without_provenance(body)),
        "<h2>Figures</h2>",
        *images,
        f'<h2 id="objects-ranking">Every-object ranking ({len(ranking)} rows)</h2>',
        "<p>One row per setting and difficulty level (<code>all</code>: every box); click a "
        "column header to sort, type in a column's filter below the table.</p>",
        interactive_table(ranking, "objects_ranking") if len(ranking) else "<p>Nothing judged.</p>",
    ]
    return page("every object", "\n".join(parts), here="objects.html", tables=True)


def _without_provenance(text: str) -> str:
    """``objects.md`` without its provenance table and folded config (the page has its own
    provenance block) and its verdict line (the page leads with it): everything before the
    first paragraph that is not part of them."""
    lines = [line for line in text.splitlines() if not line.startswith(VERDICT_START)]
    i = 0
    while i < len(lines) and (
        not lines[i].strip() or lines[i].startswith("|") or lines[i].startswith("<details>")
    ):
        if lines[i].startswith("<details>"):
            i = next((j for j in range(i, len(lines)) if lines[j].startswith("</details>")), i)
        i += 1
    return "\n".join(lines[i:])
