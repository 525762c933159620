"""The HTML report's pages: the ranking (``index.html``), FP.6 (``fp6.html``), FP.5
(``fp5.html``), the reference (``reference.html``) and one page per camera setting
(``settings/<slug>.html``). Each function takes the report's tables and returns the page's
HTML; :mod:`experiments.report.html` writes them."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from experiments.report import fp5, fp6, fp7, reference_report
from experiments.report.header import provenance_markdown
from experiments.report.html.page import (
    esc,
    fmt,
    html_table,
    inline,
    interactive_table,
    markdown_html,
    page,
    static_table,
)
from experiments.report.html.svg import ttc_series_svg
from experiments.report.load import SweepData
from ttc import evaluation as ev

#: Columns of the ranking table on ``index.html`` (those present), in this order.
INDEX_COLUMNS = [
    "dataset", "rank", "rank_lo", "rank_hi", "setting", *ev.CAMERA_AXES[:-1],
    "camera_invalid_rate", "camera_mid_median", "camera_outlier_rate", "camera_medae_rel",
    "camera_jitter_s", "way_off_frames", "ms_compute_per_frame",
]  # fmt: skip
#: Metrics listed on a setting's page.
SETTING_METRICS = [
    "rank", "rank_lo", "rank_hi", "camera_invalid_rate", "camera_mid_median",
    "camera_mid_median_lo", "camera_mid_median_hi", "camera_outlier_rate", "camera_medae_rel",
    "camera_meanae_rel", "camera_false_alarm_rate", "camera_jitter_s", "way_off_frames",
    "n_frames", "n_judged", "ms_per_frame", "ms_compute_per_frame", "run_id",
]  # fmt: skip
#: Per-frame columns of a setting's page.
FRAME_COLUMNS = [
    "frame", "prev_frame", "ttc_camera", "camera_reason", "ttc_ref_s", "camera_rel_err",
    "camera_ratio", "matches_in_box", "matches_kept", "matches_removed", "way_off", "reasons",
]  # fmt: skip


def slug(dataset: str, setting: str) -> str:
    """The file name stem of a setting's page: dataset and setting, safe characters only."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", f"{dataset}__{setting}")


def setting_href(dataset: str, setting: str, depth: int = 0) -> str:
    """The link to a setting's page from a page ``depth`` folders below the report folder."""
    return f"{'../' * depth}settings/{slug(dataset, setting)}.html"


def _link(href: str, text: object) -> str:
    return f'<a href="{esc(href)}">{esc(text)}</a>'


def _setting_link(
    dataset: str, setting: str, text: object, anchor: str, paged: set[tuple[str, str]]
) -> str:
    """``text`` linked to ``anchor`` on the setting's page, or plain when it has no page."""
    if (dataset, setting) not in paged:
        return esc(text)
    return _link(setting_href(dataset, setting) + anchor, text)


def provenance_block(data: SweepData) -> str:
    """The provenance header of the sweeps (:mod:`.header`) as HTML, folded."""
    body = markdown_html(provenance_markdown(data, "").partition("\n")[2])
    return (
        f"<details><summary>provenance: sweeps, code versions, machine, config</summary>"
        f"{body}</details>"
    )


def titled(title: str, provenance: str) -> str:
    """A page's heading followed by the folded provenance block."""
    return f"<h1>{esc(title)}</h1>\n{provenance}"


def _figure(name: str | None, alt: str) -> str:
    """An image of ``img/`` (or nothing when the report has no such figure)."""
    return f'<p><img class="figure" src="img/{esc(name)}" alt="{esc(alt)}"></p>' if name else ""


# --------------------------------------------------------------------------- index


def index_page(
    provenance: str,
    ranking: pd.DataFrame | None,
    figures: dict[str, str],
    paged: set[tuple[str, str]],
    verdict: Sequence[str] = (),
) -> str:
    """``index.html``: provenance, the ``verdict`` paragraphs (HTML; on a recording without a
    judged lead, the every-object verdict it supports), ranking rule, who is tied for first,
    the ranking table (sortable, filterable; each setting in ``paged`` links to its page) and
    the rank-interval figure."""
    parts = ["<h1>TTC benchmark: ranking of the camera settings</h1>", *verdict, provenance]
    if ranking is None or ranking.empty:
        parts.append('<p>No camera setting ran: see <a href="fp5.html">FP.5 lidar</a>.</p>')
        return page("ranking", "\n".join(parts), here="index.html")
    columns = [c for c in INDEX_COLUMNS if c in ranking and (c != "dataset"
               or ranking["dataset"].nunique() > 1)]  # fmt: skip
    shown = ranking[columns].copy()
    shown["setting"] = [_setting_link(d, s, s, "", paged)
                        for d, s in zip(ranking["dataset"], ranking["setting"], strict=True)]  # fmt: skip
    shown["way_off_frames"] = [
        _setting_link(d, s, int(n), "#way-off", paged)
        for d, s, n in zip(ranking["dataset"], ranking["setting"], ranking["way_off_frames"],
                           strict=True)
    ]  # fmt: skip
    unpaged = len(ranking) - len(paged)
    pages_note = (f" Pages of the {len(paged)} best and worst settings only; the other "
                  f"{unpaged} are rows of this table." if unpaged > 0 else "")  # fmt: skip
    parts += [
        f"<p><strong>Ranking rule</strong> (<code>ttc.evaluation.RANKING_RULE</code>): "
        f"{inline(ev.RANKING_RULE)}</p>",
        *[f"<p>{inline(s)}</p>" for s in fp6._tied_sentences(ranking)],
        f"<p>{inline(fp6._intervals_paragraph(ranking))}</p>",
        f'<h2 id="ranking-table">Ranking ({len(ranking)} settings)</h2>',
        "<p>Click a column header to sort, type in the search box or a column's filter below "
        "the table; click a setting for its TTC series, its way-off frames, their reasons and "
        f"pictures.{pages_note}</p>",
        interactive_table(shown, "ranking", ["setting", "way_off_frames"]),
        _figure(figures.get("fp6_rank_intervals.png"), "rank intervals"),
    ]
    return page("ranking", "\n".join(parts), here="index.html", tables=True)


# --------------------------------------------------------------------------- FP.6


def fp6_page(
    provenance: str,
    t: pd.DataFrame,
    pictures: dict[str, str],
    figures: dict[str, str],
    paged: set[tuple[str, str]],
) -> str:
    """``fp6.html``: what way off means and its rules, reason counts, the figures, and every
    way-off setting × frame (filterable), each linked to its section of the setting's page
    (settings in ``paged``)."""
    way = t[t["way_off"]].copy()
    codes = way["reasons"].str.split(";").explode().value_counts().rename_axis("reason")
    stems = [fp6.picture_stem(s, f) for s, f in zip(way["setting"], way["frame"], strict=True)]
    table = pd.DataFrame({
        "setting": way["setting"].to_numpy(),
        "frame": [_setting_link(d, s, int(f), f"#f{int(f)}", paged)
                  for d, s, f in zip(way["dataset"], way["setting"], way["frame"], strict=True)],
        "ttc_camera": way["ttc_camera"].to_numpy(), "ttc_ref_s": way["ttc_ref_s"].to_numpy(),
        "camera_rel_err": way["camera_rel_err"].to_numpy(),
        "reasons": way["reasons"].fillna("").to_numpy(),
        "picture": [_link(f"pictures/fp6/{pictures[s]}", "picture") if s in pictures else ""
                    for s in stems],
    })  # fmt: skip
    parts = [
        titled("FP.6: camera TTC across detector / descriptor settings", provenance),
        f"<p>{inline(fp6._way_off_paragraph(t))}</p>",
        f"<h2>Reasons of the {len(way)} way-off rows (of {len(t)} setting × frame rows)</h2>",
        static_table(codes.reset_index()),
        '<h2 id="way-off">Way-off frames</h2>',
        "<p>Every way-off setting × frame; click a frame for its reasons and numbers on the "
        f"setting's page ({len(pictures)} pictured).</p>",
        interactive_table(table, "way_off", ["frame", "picture"]),
        "<h2>Figures</h2>",
        *[
            _figure(figures.get(n), n)
            for n in ("fp6_heatmap.png", "fp6_ttc_series.png", "fp6_pareto.png")
        ],  # fmt: skip
    ]
    return page("FP.6 camera", "\n".join(parts), here="fp6.html", tables=True)


# --------------------------------------------------------------------------- settings


def _frame_section(row: dict, picture: str) -> str:
    """A pictured way-off frame of a setting's page: its reasons, the numbers, its picture."""
    numbers = (f"camera TTC {fmt(row['ttc_camera'])} s ({esc(row['camera_reason'])}), reference "
               f"{fmt(row['ttc_ref_s'])} s, relative error {fmt(row['camera_rel_err']) or 'n/a'}; "
               f"median distance ratio {fmt(row['camera_ratio'], 5)}; "
               f"{fmt(row['matches_in_box'])} matches in the box, {fmt(row['matches_kept'])} "
               f"kept, {fmt(row['matches_removed'])} removed")  # fmt: skip
    src = f"../pictures/fp6/{esc(picture)}"
    return (f'<section class="frame" id="f{int(row["frame"])}"><h3>frame '
            f'{int(row["prev_frame"])} → {int(row["frame"])}: {esc(row["reasons"])}</h3>'
            f"<p>{esc(row['reason_text'])}</p><p>{numbers}</p>"
            f'<a href="{src}"><img class="picture" loading="lazy" src="{src}" '
            f'alt="matches of frame {int(row["frame"])}"></a></section>')  # fmt: skip


def _cells(values: Sequence, digits: int = 3) -> list[str]:
    """Formatted, escaped table cells (:func:`fmt`)."""
    return [esc(fmt(v, digits)) for v in values]


def _frames_table(rows: dict[str, list], pictured: set[int]) -> str:
    """Every frame of a setting (``rows``: its columns as lists): its numbers, way-off rows
    highlighted with their reasons and explanation; a way-off row is the target
    ``#f<frame>`` unless the frame is pictured (then its frame links to the picture's
    section)."""
    way, frames = rows["way_off"], [int(f) for f in rows["frame"]]
    columns = {
        "frame": [f'<a href="#f{f}">{f}</a>' if f in pictured else str(f) for f in frames],
        "TTC camera (s)": _cells(rows["ttc_camera"]), "reason": _cells(rows["camera_reason"]),
        "TTC ref (s)": _cells(rows["ttc_ref_s"]), "rel. error": _cells(rows["camera_rel_err"]),
        "ratio": _cells(rows["camera_ratio"], 5), "in box": _cells(rows["matches_in_box"]),
        "kept": _cells(rows["matches_kept"]), "removed": _cells(rows["matches_removed"]),
        "way off because": [esc(r) if w else "" for r, w in zip(rows["reasons"], way, strict=True)],
        "explanation": [esc(r) if w else "" for r, w in zip(rows["reason_text"], way, strict=True)],
    }  # fmt: skip
    ids = [f"f{f}" if w and f not in pictured else "" for f, w in zip(frames, way, strict=True)]
    return html_table(columns, ["way-off" if w else "" for w in way], ids)


def setting_page(rank_row: pd.Series, rows: pd.DataFrame, pictures: dict[str, str]) -> str:
    """A setting's page: its TTC series against the reference (inline SVG), its metrics,
    every frame (way-off ones with their reasons) and the pictured way-off frames."""
    dataset, setting = rank_row["dataset"], rank_row["setting"]
    rows = rows.sort_values("frame")
    names = [m for m in SETTING_METRICS if m in rank_row]
    metrics = "".join(
        html_table({m: [esc(fmt(rank_row[m]))] for m in chunk})
        for chunk in (names[i : i + 6] for i in range(0, len(names), 6))
    )
    axes = ", ".join(f"{a}: <code>{esc(rank_row[a])}</code>" for a in ev.CAMERA_AXES[:-1]
                     if a in rank_row)  # fmt: skip
    lists = {c: rows[c].tolist() for c in (*FRAME_COLUMNS, "reason_text")}
    records = (
        dict(zip(lists, values, strict=True)) for values in zip(*lists.values(), strict=True)
    )
    way = [r for r in records if r["way_off"]]
    stems = {int(r["frame"]): pictures.get(fp6.picture_stem(setting, r["frame"])) for r in way}
    pictured = {f for f, name in stems.items() if name}
    sections = [_frame_section(r, stems[int(r["frame"])]) for r in way
                if int(r["frame"]) in pictured]  # fmt: skip
    parts = [
        f'<h1>{esc(setting)} <span class="muted">({esc(dataset)})</span></h1>',
        f'<p>{axes}. <a href="../index.html#ranking-table">back to the ranking</a></p>',
        "<h2>TTC per frame against the reference</h2>",
        ttc_series_svg(lists),
        "<h2>Metrics</h2>",
        metrics,
        f'<h2 id="way-off">Frames ({len(way)} of {len(rows)} way off, highlighted)</h2>',
        _frames_table(lists, pictured),
        *(["<h2>Pictured way-off frames</h2>", *sections] if sections else []),
    ]
    return page(f"{setting} ({dataset})", "\n".join(parts), depth=1)


# --------------------------------------------------------------------------- FP.5


def fp5_page(
    provenance: str,
    data: SweepData,
    t: pd.DataFrame,
    reference: pd.DataFrame,
    pictures: dict[str, str],
    figures: dict[str, str],
) -> str:
    """``fp5.html``: the rules, the estimators' metrics, the series figure, the flagged rows
    (filterable, each linked to its frame) and per flagged frame its reasons and top view."""
    flagged = t[t["flagged"]].sort_values(["dataset", "frame", "lidar_ttc"])
    table = pd.DataFrame({
        "frame": [_link(f"#frame-{d}-{int(f)}", int(f))
                  for d, f in zip(flagged["dataset"], flagged["frame"], strict=True)],
        "lidar_ttc": flagged["lidar_ttc"].to_numpy(), "ttc_lidar": flagged["ttc_lidar"].to_numpy(),
        "ttc_ref_s": flagged["ttc_ref_s"].to_numpy(), "reasons": flagged["reasons"].to_numpy(),
        "reason_text": flagged["reason_text"].to_numpy(),
    })  # fmt: skip
    sections = []
    for (dataset, frame), group in flagged.groupby(["dataset", "frame"], sort=True):
        stem = fp5.picture_stem(dataset, frame)
        image = (f'<img class="picture" loading="lazy" src="pictures/fp5/{esc(pictures[stem])}" '
                 f'alt="top view of frame {frame}">' if stem in pictures else "")  # fmt: skip
        items = "".join(f"<li><strong>{esc(r.lidar_ttc)}</strong> {fmt(r.ttc_lidar)} s "
                        f"(reference {fmt(r.ttc_ref_s)} s): {esc(r.reason_text)}</li>"
                        for r in group.itertuples())  # fmt: skip
        sections.append(f'<section class="frame" id="frame-{esc(dataset)}-{int(frame)}"><h3>'
                        f"{esc(dataset)} frame {int(frame)}</h3><ul>{items}</ul>{image}"
                        "</section>")  # fmt: skip
    parts = [
        titled("FP.5: implausible lidar TTC estimates", provenance),
        f"<p>{inline(fp5._rules_paragraph())}</p>",
        "<h2>Estimators</h2>",
        static_table(ev.lidar_metrics(data.frames, t, reference)),
        _figure(figures.get("fp5_lidar_ttc.png"), "lidar TTC per frame"),
        f"<h2>Flagged rows ({len(flagged)} estimator × frame)</h2>",
        interactive_table(table, "flagged", ["frame"], page_length=10),
        "<h2>Flagged frames: reasons and top views</h2>",
        "<p>Lead box points from above (x forward), previous frame left, current right; lines: "
        "the distance each estimator picks and the reference rear.</p>",
        *sections,
    ]
    return page("FP.5 lidar", "\n".join(parts), here="fp5.html", tables=True)


def fp7_page(
    provenance: str, t: pd.DataFrame, compared: pd.DataFrame, figures: dict[str, str]
) -> str:
    """``fp7.html``: what is judged, each fused setting against its inputs (sortable), the
    best setting's series and the flagged fused frames with their reasons (filterable)."""
    flagged = t[t["flagged"]].sort_values(["setting", "frame"])
    columns = ["setting", "frame", "ttc_fused", "ttc_lidar", "ttc_camera", "ttc_ref_s",
               "fused_reason", "reasons", "reason_text"]  # fmt: skip
    parts = [
        titled("FP.7: fused TTC against its lidar and camera inputs", provenance),
        f"<p>{inline(fp7._intro())}</p>",
        f"<h2>Fused against its inputs ({int(compared['beats_inputs'].sum())} of "
        f"{len(compared)} fused settings beat both inputs' median MiD)</h2>",
        interactive_table(compared.drop(columns=["run_id"]), "fused", page_length=25),
        _figure(figures.get("fp7_fusion_ttc.png"), "fused TTC per frame, best setting"),
        f"<h2>Flagged fused frames ({len(flagged)} setting × frame rows of {len(t)})</h2>",
        interactive_table(flagged[columns], "flagged_fused", page_length=10),
    ]
    return page("FP.7 fused", "\n".join(parts), here="fp7.html", tables=True)


# --------------------------------------------------------------------------- reference


def reference_page(provenance: str, reference: pd.DataFrame, figures: dict[str, str]) -> str:
    """``reference.html``: what the reference is, its facts and caveats, the figure and the
    per-frame values."""
    columns = [c for c in ("frame", "distance_m", "distance_smooth_m", "closing_speed_mps",
                           "ratio_ref", "ttc_ref_s", "ttc_ref_sd_s", "judgeable", "regime")
               if c in reference]  # fmt: skip
    shown = reference[columns].copy()
    parts = [
        titled("Reference TTC", provenance),
        f"<p>{inline(ev.REFERENCE_SUMMARY)}</p>",
        "<ul>"
        + "".join(f"<li>{inline(f)}</li>" for f in reference_report.reference_facts(reference))
        + "</ul>",
        f"<p><strong>Caveats.</strong> {inline(ev.REFERENCE_CAVEATS)}</p>",
        _figure(figures.get("reference.png"), "reference"),
        "<h2>Per frame</h2>",
        static_table(shown),
    ]
    return page("reference", "\n".join(parts), here="reference.html")


def truth_page(truth_text: str) -> str:
    """``reference.html`` of a sweep judged against an exact truth: its ``truth.md`` (whose
    link to ``fp6_camera.md`` leads to ``fp6.html`` here)."""
    text = truth_text.replace(
        "[fp6_camera.md](fp6_camera.md)", "[FP.6 against the truth](fp6.html)"
    )
    return page("exact truth", markdown_html(text), here="reference.html")


def picture_files(folder: Path) -> dict[str, str]:
    """File names of the pictures in ``folder`` by stem (empty when it does not exist)."""
    if not folder.is_dir():
        return {}
    return {p.stem: p.name for p in sorted(folder.iterdir()) if p.is_file()}
