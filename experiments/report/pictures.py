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
#: FP.6 match pictures per report (full size, ~70-100 kB each as WebP: 12 take about the
#: bytes the 10 shrunk PNGs of earlier reports took).
MAX_CAMERA_PICTURES = 12
#: Camera frames per second (KITTI raw: 10 Hz), for the ratio the reference implies.
FRAME_RATE_HZ = 10.0
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


def camera_lines(t_row: pd.Series) -> list[str]:
    """The numbers that explain a way-off row of the FP.6 table, as text lines: setting and
    frames, camera against reference TTC, the distance ratio against the one the reference
    implies, the match counts, the reasons and their text."""
    prev, frame = int(t_row["prev_frame"]), int(t_row["frame"])
    ref = float(t_row["ttc_ref_s"])
    implied = 1.0 + (frame - prev) / FRAME_RATE_HZ / ref if np.isfinite(ref) and ref else 1.0
    in_box = int(t_row["matches_in_box"])
    removed = int(t_row["matches_removed"])
    share = f" ({removed / in_box:.0%})" if in_box else ""
    ttc = draw.format_ttc(float(t_row["ttc_camera"]), str(t_row["camera_reason"]))
    return [
        f"{t_row['setting']}    frame {prev} -> {frame}    ({t_row['dataset']})",
        f"camera TTC {ttc}, reference {ref:.2f} s, relative error "
        + (f"{rel:.2f}" if np.isfinite(rel := float(t_row["camera_rel_err"])) else "n/a"),
        f"median distance ratio r = {t_row['camera_ratio']:.4f}; the reference implies "
        f"{implied:.4f} ({t_row['camera_pairs']} keypoint pairs)",
        f"{in_box} matches in the lead box: {int(t_row['matches_kept'])} kept, {removed} removed"
        f"{share}; {int(t_row['keypoints_curr'])} keypoints, {int(t_row['matches_total'])} "
        "matches in the frame",
        f"way off: {t_row['reasons']}",
        str(t_row["reason_text"]),
    ]


def camera_picture(t_row: pd.Series, runs: pd.DataFrame, ctx: Context) -> np.ndarray:
    """The lead box region of both frames of a way-off row of the FP.6 table, side by side
    and enlarged to at least :data:`ttc.draw.lead_pair.MIN_WIDTH` pixels, with its kept and
    removed matches and the numbers of :func:`camera_lines` (BGR)."""
    detail = ctx.detail(runs, t_row["run_id"], int(t_row["prev_frame"]), int(t_row["frame"]))
    return draw.lead_match_picture(detail, camera_lines(t_row))
