"""Small inline SVG charts of the HTML report: one setting's TTC per frame against the
reference (a few KB each, no image files, hover titles, way-off frames linked to their
section of the page)."""

from __future__ import annotations

import math

import numpy as np

from experiments.report.html.page import esc

WIDTH, HEIGHT = 720, 240
LEFT, RIGHT, TOP, BOTTOM = 44, 12, 30, 30
SERIES_COLOUR = "#1f77b4"
REFERENCE_COLOUR = "#222"
WAY_OFF_COLOUR = "#d62728"


def _nice_step(span: float, ticks: int = 5) -> float:
    """A round tick step (1, 2 or 5 times a power of ten) giving about ``ticks`` ticks."""
    raw = max(span, 1e-9) / ticks
    power = 10 ** math.floor(math.log10(raw))
    return next(m * power for m in (1, 2, 5, 10) if m * power >= raw)


def _axes(x0: float, x1: float, top: float) -> list[str]:
    """Grid lines, tick labels and axis titles of a frame × seconds chart."""
    out = []
    for v in np.arange(0, top + 1e-9, _nice_step(top)):
        y = _y(v, top)
        out.append(f'<line x1="{LEFT}" y1="{y:.1f}" x2="{WIDTH - RIGHT}" y2="{y:.1f}" '
                   f'stroke="#e3e3e3"/><text x="{LEFT - 4}" y="{y + 4:.1f}" '
                   f'text-anchor="end">{v:g}</text>')  # fmt: skip
    for f in np.arange(math.ceil(x0), x1 + 1e-9, max(1, _nice_step(x1 - x0, 10))):
        x = _x(f, x0, x1)
        out.append(f'<text x="{x:.1f}" y="{HEIGHT - BOTTOM + 14}" text-anchor="middle">'
                   f"{f:g}</text>")  # fmt: skip
    out.append(f'<text x="{(LEFT + WIDTH - RIGHT) / 2}" y="{HEIGHT - 3}" '
               'text-anchor="middle">frame</text>')  # fmt: skip
    middle = (TOP + HEIGHT - BOTTOM) / 2
    out.append(f'<text transform="rotate(-90)" x="{-middle}" y="11" text-anchor="middle">'
               "TTC (s)</text>")  # fmt: skip
    return out


def _x(frame: float, x0: float, x1: float) -> float:
    return LEFT + (frame - x0) / max(x1 - x0, 1) * (WIDTH - LEFT - RIGHT)


def _y(value: float, top: float) -> float:
    return TOP + (1 - min(max(value, 0.0), top) / top) * (HEIGHT - TOP - BOTTOM)


def _polylines(points: list[tuple[float, float] | None], colour: str, dash: str = "") -> str:
    """Polylines through consecutive points, broken where a point is None (invalid TTC)."""
    runs, current = [], []
    for p in [*points, None]:
        if p is None:
            if len(current) > 1:
                runs.append(current)
            current = []
        else:
            current.append(p)
    style = f' stroke-dasharray="{dash}"' if dash else ""
    return "".join(
        f'<polyline fill="none" stroke="{colour}" stroke-width="1.6"{style} points="'
        + " ".join(f"{x:.1f},{y:.1f}" for x, y in run) + '"/>'
        for run in runs
    )  # fmt: skip


def ttc_series_svg(rows: dict[str, list]) -> str:
    """One setting's camera TTC per frame against the reference TTC as an inline SVG;
    ``rows``: lists ``frame``, ``ttc_camera``, ``ttc_ref_s``, ``way_off``, ``reasons`` in frame
    order. Values above the top are drawn on the top edge; invalid TTCs (NaN, inf) as open
    triangles on the top edge; way-off frames red and linked to ``#f<frame>``."""
    frames = [int(f) for f in rows["frame"]]
    ttc, ref = rows["ttc_camera"], rows["ttc_ref_s"]
    finite_ref = [v for v in ref if np.isfinite(v) and v > 0]
    top = 1.5 * max(finite_ref) if finite_ref else 60.0
    top = float(_nice_step(top) * math.ceil(top / _nice_step(top)))
    x0, x1 = float(min(frames)), float(max(frames))

    def point(frame: float, value: float) -> tuple[float, float] | None:
        return (_x(frame, x0, x1), _y(value, top)) if np.isfinite(value) and value > 0 else None

    parts = _axes(x0, x1, top)
    parts.append(_polylines([point(f, v) for f, v in zip(frames, ref, strict=True)],
                            REFERENCE_COLOUR, "5 3"))  # fmt: skip
    parts.append(_polylines([point(f, v) for f, v in zip(frames, ttc, strict=True)],
                            SERIES_COLOUR))  # fmt: skip
    for frame, value, r, way_off, reasons in zip(frames, ttc, ref, rows["way_off"],
                                                 rows["reasons"], strict=True):  # fmt: skip
        valid = np.isfinite(value) and value > 0
        x, y = _x(frame, x0, x1), _y(value if valid else top, top)
        colour = WAY_OFF_COLOUR if way_off else SERIES_COLOUR
        title = (f"frame {frame}: {value:.1f} s, reference {r:.1f} s"
                 + (f"; way off: {reasons}" if way_off else ""))  # fmt: skip
        mark = (f'<circle cx="{x:.1f}" cy="{y:.1f}" r="{4 if way_off else 2.5}" fill="{colour}">'
                if valid else
                f'<path d="M{x - 5:.1f},{y + 8:.1f}h10l-5,-9z" fill="none" stroke="{colour}">')  # fmt: skip
        end = "</circle>" if valid else "</path>"
        mark += f"<title>{esc(title)}</title>{end}"
        parts.append(f'<a href="#f{frame}">{mark}</a>' if way_off else mark)
    legend = (f'<text x="{WIDTH - RIGHT}" y="12" text-anchor="end">'
              f'<tspan fill="{SERIES_COLOUR}">— camera TTC</tspan>  '
              f'<tspan fill="{REFERENCE_COLOUR}">- - reference</tspan>  '
              f'<tspan fill="{WAY_OFF_COLOUR}">● way off (click)</tspan>  △ invalid</text>')  # fmt: skip
    return (f'<svg class="series" xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" '
            f'height="{HEIGHT}" viewBox="0 0 {WIDTH} {HEIGHT}" font-size="11" '
            f'font-family="sans-serif">{"".join(parts)}{legend}</svg>')  # fmt: skip
