"""The per-frame pictures of a report: FP.5 top views of a flagged frame, FP.6 keypoint
matches of a way-off frame. Each recomputes the frame pair through the stage cache
(:meth:`~experiments.report.load.Context.detail`), measures with :mod:`ttc.evaluation` and
draws with :mod:`ttc.draw`; the writers encode and save."""

from __future__ import annotations

import numpy as np
import pandas as pd

from experiments.report.load import Context
from ttc import draw
from ttc import evaluation as ev

#: One top view per flagged frame, up to this many (the most flagged estimators first).
MAX_LIDAR_PICTURES = 50
MAX_CAMERA_PICTURES = 10
#: Depth (m) shown by an FP.5 top view, from just in front of the nearest point.
TOP_VIEW_SPAN_M = 1.5
#: Width and height (pixels) of one panel of an FP.5 top view.
TOP_VIEW_SIZE = (400, 520)


def _panel_titles(rows: pd.DataFrame, f: int, curr: int) -> list[str]:
    """Text lines above one top view: frame, and for the current frame the flagged TTCs."""
    if f != curr:
        n = int(rows["flagged"].sum())
        return [f"frame {f} (previous)", *[""] * (1 + (n + 1) // 2)]
    row = rows.iloc[0]
    flagged = rows[rows["flagged"]]
    ttcs = [f"{r.lidar_ttc} {r.ttc_lidar:.1f} s" for r in flagged.itertuples()]
    lines = [", ".join(ttcs[i : i + 2]) for i in range(0, len(ttcs), 2)]
    return [f"frame {f} (current), reference TTC {row['ttc_ref_s']:.1f} s", "flagged:", *lines]


def _top_view_world(clouds: dict[int, np.ndarray], ref_x: float) -> draw.World:
    """The world window (metres) of both panels: :data:`TOP_VIEW_SPAN_M` of depth from just in
    front of the nearest point (or the reference rear ``ref_x``), the clouds' width plus as
    much again on the right for the labels."""
    both = np.vstack([c[:, :2] for c in clouds.values()])
    xs = np.append(both[:, 0], ref_x)
    lo = np.floor((np.nanmin(xs) - 0.25) * 10) / 10
    y_hi = float(both[:, 1].max(initial=1.0)) + 0.1
    y_lo = float(both[:, 1].min(initial=-1.0)) - 0.1
    return (lo, lo + TOP_VIEW_SPAN_M), (y_lo - (y_hi - y_lo), y_hi)


def lidar_picture(
    t: pd.DataFrame,
    runs: pd.DataFrame,
    ctx: Context,
    dataset: str,
    frame: int,
    reference: pd.DataFrame,
) -> np.ndarray:
    """Top views (BGR) of the lead box's points in the previous and current frame of a
    flagged frame of the FP.5 table ``t``, each with the distance every estimator picks
    (:func:`ttc.evaluation.estimator_marks`) and the reference rear."""
    rows = t[(t["dataset"] == dataset) & (t["frame"] == frame)]
    row = rows.iloc[0]
    detail = ctx.detail(runs, row["run_id"], int(row["prev_frame"]), frame)
    params = ctx.settings(runs, row["run_id"]).lidar_ttc
    ref = reference.set_index("frame")["distance_m"]
    clouds = ev.lead_clouds(detail)
    world = _top_view_world(clouds, float(ref.reindex([frame]).iloc[0]))
    panels = []
    for f, points in clouds.items():
        marks = ev.estimator_marks(points, params) if len(points) else {}
        marks["reference rear"] = float(ref.get(f, np.nan))
        view = draw.top_view([(f"frame {f} box", points)], marks, world, TOP_VIEW_SIZE,
                             grid=0.5, lateral_grid=1.0)  # fmt: skip
        titles = _panel_titles(rows, f, detail.curr)
        panels.append(np.vstack([draw.text_band(titles, TOP_VIEW_SIZE[0]), view]))
    seam = np.full((panels[0].shape[0], 4, 3), 255, np.uint8)
    return np.hstack([panels[0], seam, panels[1]])


def _crop_around_boxes(image: np.ndarray, rois: list[np.ndarray], h: int) -> np.ndarray:
    """The stacked (previous above current, each ``h`` rows) matches picture cropped around
    the boxes ``rois`` (x, y, w, h pixels): at least 560 px wide, 40 px above, 20 below."""
    x0, x1 = (min(r[0] for r in rois), max(r[0] + r[2] for r in rois)) if rois else (0, 1)
    y0, y1 = (min(r[1] for r in rois), max(r[1] + r[3] for r in rois)) if rois else (0, h)
    width = image.shape[1]
    cx, half = (x0 + x1) // 2, max(280, (x1 - x0) // 2 + 80)
    left, right = max(0, cx - half), min(width, cx + half)
    top, bottom = max(0, y0 - 40), min(h, y1 + 20)
    return np.vstack([image[top:bottom, left:right], image[h + top : h + bottom, left:right]])


def camera_picture(t_row: pd.Series, runs: pd.DataFrame, ctx: Context) -> np.ndarray:
    """The lead box's matches (previous above current) of a row of the FP.6 table, cropped
    around the box, with the setting, TTCs and reasons in a text band on top (BGR)."""
    detail = ctx.detail(runs, t_row["run_id"], int(t_row["prev_frame"]), int(t_row["frame"]))
    image = draw.draw_keypoint_matches(detail, max_draw=150)
    prev_box, curr_box = ev.lead_boxes(detail)
    rois = [detail.objects[detail.curr]["roi"][curr_box]] if curr_box >= 0 else []
    if prev_box >= 0:
        rois.append(detail.objects[detail.prev]["roi"][prev_box])
    crop = _crop_around_boxes(image, rois, detail.images[detail.prev].shape[0])
    ttc = draw.format_ttc(float(t_row["ttc_camera"]), str(t_row["camera_reason"]))
    lines = [
        f"{t_row['setting']}  frame {int(t_row['prev_frame'])} -> {int(t_row['frame'])}",
        f"TTC camera {ttc}, reference {t_row['ttc_ref_s']:.2f} s, ratio "
        f"{t_row['camera_ratio']:.4f}",
        f"{int(t_row['matches_kept'])} kept (green) / {int(t_row['matches_removed'])} removed"
        f" (red) of {int(t_row['matches_in_box'])} in the box; reasons: {t_row['reasons']}",
    ]
    return np.vstack([draw.text_band(lines, crop.shape[1]), crop])
