"""Building blocks of the HTML report's pages: escaping, the little markdown the report's
paragraphs use, the page skeleton, static tables, and interactive tables (DataTables through
:mod:`itables`, loaded from the report folder: no server, no network)."""

from __future__ import annotations

import html
import json
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

import itables
import numpy as np
import pandas as pd

#: Files under ``assets/`` of the report folder.
DT_CSS = "assets/dt_bundle.css"
DT_LOADER = "assets/itables_dt.js"
STYLE = "assets/report.css"

NAV = (("index.html", "ranking"), ("fp6.html", "FP.6 camera"), ("fp5.html", "FP.5 lidar"),
       ("fp7.html", "FP.7 fused"), ("objects.html", "every object"),
       ("reference.html", "reference"))  # fmt: skip

CSS = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 0 auto; max-width: 1400px; padding: 0 16px;
       color: #1b1b1b; }
nav { position: sticky; top: 0; background: #f4f6f8; padding: 6px 10px; border-bottom: 1px solid #ccd;
      z-index: 10; }
nav a { margin-right: 18px; font-weight: 600; text-decoration: none; }
nav a.here { color: #1b1b1b; }
h1 { font-size: 1.5em; } h2 { font-size: 1.25em; margin-top: 1.6em; } h3 { font-size: 1.1em; }
table.plain { border-collapse: collapse; margin: 8px 0; }
table.plain th, table.plain td { border: 1px solid #d5d9de; padding: 3px 7px; text-align: left;
                                 vertical-align: top; }
table.plain th { background: #f4f6f8; }
table.plain td { font-variant-numeric: tabular-nums; }
tr.way-off td, tr.flagged td { background: #fff0f0; }
[id] { scroll-margin-top: 48px; }
tr:target td, section:target { background: #fff3bf; }
code { background: #f2f2f2; padding: 0 3px; border-radius: 3px; }
details { margin: 8px 0; } pre { font-size: 12px; max-height: 300px; overflow: auto; }
img.figure { max-width: 100%; border: 1px solid #ddd; }
img.picture { max-width: 100%; border: 1px solid #999; display: block; margin: 6px 0; }
section.frame { border-top: 1px solid #ccd; padding-top: 4px; }
svg.series { max-width: 100%; height: auto; background: #fff; }
.dt-container { font-size: 13px; }
.muted { color: #666; }
"""


def esc(value: object) -> str:
    """``value`` as text with HTML special characters escaped."""
    return html.escape(str(value), quote=True)


def inline(text: str) -> str:
    """One line of the report's markdown (``**bold**``, `` `code` ``, ``[text](page.md)``) as
    HTML; ``.md`` links point to the HTML page of the same name."""
    out = esc(text)
    out = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", out)
    out = re.sub(r"`([^`]+)`", r"<code>\1</code>", out)
    return re.sub(
        r"\[([^\]]+)\]\(([^)\s]+?)(\.md)?\)",
        lambda m: f'<a href="{m.group(2)}{".html" if m.group(3) else ""}">{m.group(1)}</a>',
        out,
    )


def _table_lines(lines: list[str]) -> str:
    """A markdown pipe table (header, rule, rows) as a static HTML table."""

    def cells(line: str) -> list[str]:
        return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]

    head = "".join(f"<th>{inline(c)}</th>" for c in cells(lines[0]))
    body = "".join(
        "<tr>" + "".join(f"<td>{inline(c)}</td>" for c in cells(line)) + "</tr>"
        for line in lines[2:]
    )
    return f'<table class="plain"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def markdown_html(text: str) -> str:
    """The subset of markdown the report writes (headings, pipe tables, lists, ``<details>``,
    code fences, paragraphs) as HTML; images are left out (pages place their own)."""
    out: list[str] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("```"):
            end = next((j for j in range(i + 1, len(lines)) if lines[j].startswith("```")),
                       len(lines))  # fmt: skip
            out.append(f"<pre>{esc(chr(10).join(lines[i + 1 : end]))}</pre>")
            i = end + 1
            continue
        if line.startswith("|"):
            end = i
            while end < len(lines) and lines[end].startswith("|"):
                end += 1
            out.append(_table_lines(lines[i:end]))
            i = end
            continue
        heading = re.match(r"(#{1,4}) (.*)", line)
        if heading:
            level = len(heading.group(1))
            out.append(f"<h{level}>{inline(heading.group(2))}</h{level}>")
        elif line.startswith(("<details>", "</details>")):
            out.append(line)
        elif line.startswith("- "):
            out.append(f"<ul><li>{inline(line[2:])}</li></ul>")
        elif line.strip() and not line.startswith("!["):
            out.append(f"<p>{inline(line)}</p>")
        i += 1
    return "\n".join(out).replace("</ul>\n<ul>", "\n")


def page(title: str, body: str, depth: int = 0, here: str = "", tables: bool = False) -> str:
    """A whole HTML page: head (styles, and the DataTables bundle when ``tables``), the
    navigation bar and ``body``. ``depth``: folders below the report folder (links go up)."""
    up = "../" * depth
    mark = ' class="here"'
    links = " ".join(
        f'<a href="{up}{href}"{mark if href == here else ""}>{esc(name)}</a>' for href, name in NAV
    )
    head = [
        '<meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{esc(title)}</title>",
        f'<link rel="stylesheet" href="{up}{STYLE}">',
    ]
    if tables:
        head += [f'<link rel="stylesheet" href="{up}{DT_CSS}">',
                 f'<script src="{up}{DT_LOADER}"></script>']  # fmt: skip
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n' + "\n".join(head) + "\n</head>\n<body>\n"
        f"<nav>{links}</nav>\n{body}\n</body>\n</html>\n"
    )


def fmt(value: object, digits: int = 3) -> str:
    """A table cell: floats with ``digits`` significant digits, NaN empty, inf as 'inf'."""
    if isinstance(value, bool | np.bool_):
        return "yes" if value else ""
    if isinstance(value, float | np.floating):
        if np.isnan(value):
            return ""
        if np.isinf(value):
            return "inf" if value > 0 else "-inf"
        return f"{value:.{digits}g}" if abs(value) < 1000 else f"{value:.0f}"
    return str(value)


def html_table(
    columns: dict[str, Sequence[str]],
    row_class: Sequence[str] | None = None,
    row_id: Sequence[str] | None = None,
) -> str:
    """A plain HTML table of cells that are HTML already (header: the keys, escaped);
    optional class and id per row."""
    head = "".join(f"<th>{esc(c)}</th>" for c in columns)
    n = len(next(iter(columns.values()), []))
    classes = row_class if row_class is not None else [""] * n
    ids = row_id if row_id is not None else [""] * n
    rows = [
        "<tr" + (f' class="{k}"' if k else "") + (f' id="{i}"' if i else "") + "><td>"
        + "</td><td>".join(cells) + "</td></tr>"
        for k, i, *cells in zip(classes, ids, *columns.values(), strict=True)
    ]  # fmt: skip
    return (f'<table class="plain"><thead><tr>{head}</tr></thead>'
            f"<tbody>{''.join(rows)}</tbody></table>")  # fmt: skip


def static_table(
    df: pd.DataFrame,
    html_columns: Iterable[str] = (),
    row_class: Sequence[str] | None = None,
    row_id: Sequence[str] | None = None,
) -> str:
    """``df`` as a plain HTML table; cells of ``html_columns`` are HTML already, the others are
    formatted (:func:`fmt`) and escaped; optional class and id per row."""
    raw = set(html_columns)
    columns = {
        str(c): df[c].tolist() if c in raw else [esc(fmt(v)) for v in df[c].tolist()]
        for c in df.columns
    }
    return html_table(columns, row_class, row_id)


def interactive_table(
    df: pd.DataFrame, table_id: str, html_columns: Iterable[str] = (), page_length: int = 25
) -> str:
    """``df`` as a sortable, searchable DataTable (itables, offline): a search box, one filter
    per column, pages of ``page_length`` rows. Cells of ``html_columns`` are HTML already;
    text elsewhere is escaped. The page must be made with ``tables=True``."""
    raw = set(html_columns)
    shown = df.copy()
    for c in shown.columns:
        if c not in raw and not pd.api.types.is_numeric_dtype(shown[c]):
            # each value as text (a category's map would stay a category, which itables
            # writes as codes)
            shown[c] = shown[c].astype(object).map(lambda v: esc(fmt(v)))
        elif pd.api.types.is_float_dtype(shown[c]):
            shown[c] = shown[c].replace([np.inf, -np.inf], np.nan).round(4)
    return itables.to_html_datatable(
        shown.reset_index(drop=True),
        table_id=table_id,
        connected=False,
        allow_html=True,
        maxBytes=0,
        display_logo_when_loading=False,
        column_filters="footer",
        pageLength=page_length,
        lengthMenu=[10, 25, 100, 500],
        text_in_header_can_be_selected=False,
        classes="display compact",
        showIndex=False,
        # not itables' default layout, which drops the search box from tables of one page
        layout={
            "topStart": "info",
            "topEnd": "search",
            "bottomStart": "pageLength",
            "bottomEnd": "paging",
        },
    )


def itables_global() -> str:
    """The name of the promise itables' offline tables wait for (``window._itables_<v>``)."""
    return "_itables_" + itables.__version__.replace(".", "_")


def write_assets(folder: Path, write_text) -> None:
    """Write ``assets/`` under ``folder``: the page style, itables' DataTables stylesheet and
    a classic script that holds itables' DataTables bundle (an ES module) as a string and
    imports it from a blob URL (pages opened from disk cannot import module files)."""
    bundle = Path(itables.__file__).parent / "html" / "dt_bundle.js"
    source = bundle.read_text(encoding="utf-8")
    loader = (
        f"// DataTables bundle of itables {itables.__version__} (itables/html/dt_bundle.js,\n"
        "// MIT licences of its parts inside), written by the report. Pages opened from disk\n"
        "// cannot import module files, so the module is imported from a blob URL.\n"
        f"window.{itables_global()} = import(URL.createObjectURL(new Blob([\n"
        f"{json.dumps(source)}\n], {{ type: 'text/javascript' }})));\n"
    )
    write_text(CSS.lstrip(), folder / STYLE)
    write_text(bundle.with_suffix(".css").read_text(encoding="utf-8"), folder / DT_CSS)
    write_text(loader, folder / DT_LOADER)
