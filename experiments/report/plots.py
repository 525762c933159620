"""The report's matplotlib figures: reference, FP.5 lidar TTC series, FP.6 heatmap, best and
worst series, accuracy against time. Each function takes tables and returns a figure;
:func:`save_figure` writes it."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import seaborn as sns

from ttc import evaluation as ev
from ttc.atomic import write_bytes_atomic

FIGURE_DPI = 90


def save_figure(fig: plt.Figure, path: Path) -> Path:
    """Save a matplotlib figure as a compact PNG (atomically) and close it."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=FIGURE_DPI, bbox_inches="tight",
                metadata={"Software": None})  # fmt: skip
    plt.close(fig)
    return write_bytes_atomic(buffer.getvalue(), path)


def _ttc_ceiling(reference: pd.DataFrame, frames: pd.Series, factor: float) -> tuple:
    """The reference rows of ``frames`` and the top of a TTC axis: ``factor`` times the
    largest finite reference TTC (s), 60 s without one."""
    ref = reference[reference["frame"].isin(frames.unique())]
    finite_ref = ref["ttc_ref_s"].where(np.isfinite(ref["ttc_ref_s"]))
    top = factor * float(finite_ref.max()) if finite_ref.notna().any() else 60.0
    return ref, top


def _finish_series(
    fig: plt.Figure, ax: plt.Axes, ref: pd.DataFrame, top: float, ylabel: str, title: str
) -> plt.Figure:
    """A TTC-per-frame figure's common end: the reference TTC line (s), the y axis 0..``top``,
    labels, the legend beside the axes."""
    ax.plot(ref["frame"], ref["ttc_ref_s"], color="black", lw=2.5, label="reference")
    ax.set(ylim=(0, top), xlabel="frame", ylabel=ylabel, title=title)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    return fig


def plot_reference(reference: pd.DataFrame) -> plt.Figure:
    """Distance (m), closing speed (m/s) and reference TTC (s) per frame."""
    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    interp = reference["distance_interpolated"].astype(bool)
    axes[0].plot(reference["frame"], reference["distance_m"], "o", ms=3, label="lidar rear")
    axes[0].plot(reference["frame"], reference["distance_smooth_m"], "-", label="smoothed")
    axes[0].plot(reference.loc[interp, "frame"], reference.loc[interp, "distance_smooth_m"],
                 "x", color="crimson", ms=8, label="interpolated")  # fmt: skip
    axes[0].set_ylabel("distance (m)")
    axes[1].plot(reference["frame"], reference["closing_speed_mps"], "-o", ms=3)
    axes[1].axhline(ev.MIN_CLOSING_SPEED_MPS, color="grey", ls="--",
                    label="min closing speed")  # fmt: skip
    axes[1].set_ylabel("closing speed (m/s)")
    ttc = reference["ttc_ref_s"].where(np.isfinite(reference["ttc_ref_s"]))
    sd = reference["ttc_ref_sd_s"]
    axes[2].fill_between(reference["frame"], ttc - 2 * sd, ttc + 2 * sd, color="black",
                         alpha=0.15, label="±2 sd")  # fmt: skip
    axes[2].plot(reference["frame"], ttc, "-o", ms=3, color="black")
    shaky = ~reference["judgeable"].astype(bool) & ttc.notna()
    axes[2].plot(reference.loc[shaky, "frame"], ttc[shaky], "o", ms=6, mfc="none",
                 color="crimson", label="too uncertain to judge")  # fmt: skip
    for regime, colour in zip(ev.REGIMES[1:], ("gold", "grey"), strict=True):
        axes[0].fill_between(reference["frame"], 0, 1, where=reference["regime"] == regime,
                             color=colour, alpha=0.2, label=regime,
                             transform=axes[0].get_xaxis_transform())  # fmt: skip
    no_course = ~reference["collision_course"].astype(bool)
    axes[2].fill_between(reference["frame"], 0, 1, where=no_course, color="grey", alpha=0.2,
                         transform=axes[2].get_xaxis_transform(),
                         label="no collision course")  # fmt: skip
    axes[2].set(ylabel="reference TTC (s)", xlabel="frame", ylim=(0, min(60, ttc.max() * 1.1)))
    for ax in axes:
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.suptitle("reference: lead vehicle distance, closing speed and TTC")
    fig.tight_layout()
    return fig


def plot_lidar_series(t: pd.DataFrame, reference: pd.DataFrame) -> plt.Figure:
    """Lidar TTC per frame and estimator (FP.5 table ``t``) against the reference; flagged
    frames crossed, invalid TTCs (NaN / inf) as triangles on the top edge, values above it
    clipped."""
    fig, ax = plt.subplots(figsize=(10, 4.2))
    ref, top = _ttc_ceiling(reference, t["frame"], 2.5)
    valid = np.isfinite(t["ttc_lidar"])
    shown = t.assign(ttc=t["ttc_lidar"].where(valid).clip(upper=top))
    order = sorted(t["lidar_ttc"].unique())
    sns.lineplot(data=shown[valid], x="frame", y="ttc", hue="lidar_ttc", hue_order=order,
                 style="dataset", marker="o", markersize=4, ax=ax)  # fmt: skip
    bad = shown[~valid]
    sns.scatterplot(x=bad["frame"], y=np.full(len(bad), 0.98 * top), hue=bad["lidar_ttc"],
                    hue_order=order, marker="v", s=50, legend=False, ax=ax)  # fmt: skip
    flagged = shown[shown["flagged"]]
    ax.scatter(flagged["frame"], flagged["ttc"].fillna(0.98 * top), marker="x", s=60,
               color="crimson", label="flagged", zorder=5)  # fmt: skip
    return _finish_series(
        fig, ax, ref, top, "TTC (s, clipped)", "FP.5 lidar TTC (triangles on top: invalid TTC)"
    )


def plot_fused_series(t: pd.DataFrame, reference: pd.DataFrame) -> plt.Figure:
    """One fused setting's TTC per frame (rows of the FP.7 table ``t``) with its ±2 sd band,
    beside the lidar and camera TTCs it fuses and the reference; flagged frames crossed,
    values clipped at the top."""
    fig, ax = plt.subplots(figsize=(10, 4.2))
    ref, top = _ttc_ceiling(reference, t["frame"], 2.5)
    for column, label, style in (("ttc_lidar", "lidar", "s--"), ("ttc_camera", "camera", "^--")):
        shown = t[column].where(np.isfinite(t[column])).clip(upper=top)
        ax.plot(t["frame"], shown, style, ms=4, lw=1, alpha=0.7, label=label)
    fused = t["ttc_fused"].where(np.isfinite(t["ttc_fused"]))
    sd = t["ttc_fused_sd"].where(np.isfinite(t["ttc_fused_sd"]))
    ax.fill_between(t["frame"], (fused - 2 * sd).clip(lower=0, upper=top),
                    (fused + 2 * sd).clip(upper=top), alpha=0.2, label="fused ±2 sd")  # fmt: skip
    ax.plot(t["frame"], fused.clip(upper=top), "o-", ms=4, lw=2, label="fused")
    flagged = t[t["flagged"]]
    ax.scatter(flagged["frame"], fused[t["flagged"]].fillna(0.98 * top).clip(upper=top),
               marker="x", s=70, color="crimson", label="flagged", zorder=5)  # fmt: skip
    return _finish_series(
        fig, ax, ref, top, "TTC (s, clipped)", f"FP.7 fused TTC: {t['setting'].iloc[0]}"
    )


#: What a heatmap panel with no value says instead.
NOTHING_JUDGED = "nothing to draw: no frame has a valid camera TTC of a lead vehicle to judge"


def plot_heatmap(ranking: pd.DataFrame) -> plt.Figure:
    """Detector × descriptor heatmaps of the best setting's invalid rate and median MiD (the
    ranking rule's two keys). A key with no value (no setting has a valid camera TTC of a
    lead vehicle: drive 0009 has none) gets one line saying so instead of an empty heatmap."""
    best = ranking.sort_values("rank").drop_duplicates(["detector", "descriptor"])
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, (col, label, fmt) in zip(
        axes,
        (("camera_invalid_rate", "invalid rate", ".2f"),
         ("camera_mid_median", "median MiD (1e-4 log ratio)", ".0f")),
        strict=True,
    ):  # fmt: skip
        ax.set_title(f"{label} (best over the other axes)", fontsize=10)
        grid = best.pivot(index="detector", columns="descriptor", values=col)
        if not np.isfinite(grid.to_numpy(float)).any():
            ax.set_axis_off()
            ax.text(0.5, 0.5, NOTHING_JUDGED, ha="center", va="center", wrap=True,
                    fontsize=9, transform=ax.transAxes)  # fmt: skip
            continue
        sns.heatmap(grid, annot=True, fmt=fmt, cmap="rocket_r", vmin=0, ax=ax,
                    cbar_kws={"shrink": 0.8}, annot_kws={"size": 8})  # fmt: skip
    fig.suptitle("FP.6 camera TTC error by detector x descriptor (blank: invalid pair)")
    fig.tight_layout()
    return fig


def plot_top_bottom(
    t: pd.DataFrame, ranking: pd.DataFrame, reference: pd.DataFrame, n: int = 3
) -> plt.Figure:
    """Camera TTC per frame of the ``n`` best and ``n`` worst settings against the reference;
    invalid TTCs as triangles on the top edge, values above it clipped."""
    ranked = ranking.sort_values("rank")["setting"].drop_duplicates().tolist()
    picked = ranked[:n] + [s for s in ranked[-n:] if s not in ranked[:n]]
    sub = t[t["setting"].isin(picked)].copy()
    sub["group"] = np.where(sub["setting"].isin(ranked[:n]), "best", "worst")
    ref, top = _ttc_ceiling(reference, t["frame"], 3.0)
    valid = np.isfinite(sub["ttc_camera"])
    sub["ttc"] = sub["ttc_camera"].where(valid).clip(upper=top)
    fig, ax = plt.subplots(figsize=(10, 4.5))
    sns.lineplot(data=sub[valid], x="frame", y="ttc", hue="setting", hue_order=picked,
                 style="group", style_order=["best", "worst"], marker="o", markersize=4,
                 ax=ax)  # fmt: skip
    bad = sub[~valid]
    sns.scatterplot(x=bad["frame"], y=np.full(len(bad), 0.98 * top), hue=bad["setting"],
                    hue_order=picked, marker="v", s=50, legend=False, ax=ax)  # fmt: skip
    return _finish_series(
        fig,
        ax,
        ref,
        top,
        "camera TTC (s, clipped)",
        f"best {n} and worst {n} settings (triangles on top: invalid TTC)",
    )


def plot_pareto(ranking: pd.DataFrame) -> plt.Figure:
    """Accuracy against time per frame, with the Pareto front of each accuracy metric
    (:func:`ttc.evaluation.pareto_front`).

    Time: ``ms_compute_per_frame`` (cached stages at their computing time), else the run's
    own ``ms_per_frame``."""
    time_col = "ms_frame"
    ranking = ranking.assign(
        **{time_col: ranking["ms_compute_per_frame"].fillna(ranking["ms_per_frame"])},
        # the legend in the ranking's order (seaborn orders a category's values by its
        # categories: the report's axes are categories, experiments.report.judged_rows)
        **{axis: ranking[axis].astype(object) for axis in ("detector", "descriptor")},
    )
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, col in zip(axes, ("camera_mid_median", "camera_outlier_rate"), strict=True):
        sns.scatterplot(data=ranking, x=time_col, y=col, hue="detector", style="descriptor",
                        s=40, ax=ax)  # fmt: skip
        front = ranking.iloc[ev.pareto_front(ranking[time_col].to_numpy(float),
                                             ranking[col].to_numpy(float))]  # fmt: skip
        ax.step(front[time_col], front[col], where="post", color="black", lw=1.2,
                label="Pareto front")  # fmt: skip
        for r in front.itertuples():
            ax.annotate(r.setting, (getattr(r, time_col), getattr(r, col)), fontsize=6,
                        xytext=(3, 3), textcoords="offset points")  # fmt: skip
        ax.set(xscale="log", xlabel="time per frame (ms, log; computed stages)", ylabel=col)
        ax.legend(fontsize=6, ncol=2)
    fig.suptitle("accuracy against time per frame")
    fig.tight_layout()
    return fig


def plot_rank_intervals(ranking: pd.DataFrame, n: int = 30) -> plt.Figure:
    """The ``n`` best settings' rank (dot) and 90 % block-bootstrap rank interval (bar), best
    at the top; the settings whose interval includes rank 1 (tied for first) in colour."""
    top = ranking.nsmallest(n, "rank").iloc[::-1]
    tied = (top["rank_lo"] <= 1).to_numpy()
    y = np.arange(len(top))
    fig, ax = plt.subplots(figsize=(8, 0.25 * len(top) + 1.2))
    colours = np.where(tied, "tab:orange", "tab:blue")
    ax.hlines(y, top["rank_lo"], top["rank_hi"], colors=colours, lw=3, alpha=0.6)
    ax.scatter(top["rank"], y, c=colours, s=18, zorder=3)
    ax.set_yticks(y, top["setting"], fontsize=7)
    ax.set_xlabel("rank (90 % interval, moving-block bootstrap over frames)")
    ax.set_title(f"{int(tied.sum())} of the top {len(top)} settings are tied for first", fontsize=9)
    ax.grid(axis="x", alpha=0.3)
    return fig


def plot_objects(reference: pd.DataFrame, judged: pd.DataFrame, ranking: pd.DataFrame):
    """Every object of a recording: each track's reference distance against time (top; m),
    its reference TTC with the best all-object setting's camera TTC (dots) and lidar TTC
    (crosses) (bottom; s, clipped at 30 s). ``reference``:
    :func:`ttc.evaluation.object_reference.object_reference`; ``judged``:
    :func:`ttc.evaluation.object_errors.judge_objects` with a ``setting`` column."""
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
    t0 = reference["frame"].min()
    best = ranking["setting"].iloc[0] if len(ranking) else None
    mine = judged[judged["setting"] == best] if best is not None else judged.iloc[:0]
    colours = plt.get_cmap("tab20")
    tracks = reference.groupby("track_id")
    for n, (tid, track) in enumerate(t for t in tracks if len(t[1]) >= 3):
        colour = colours(n % 20)
        top.plot(track["frame"] - t0, track["distance_m"], color=colour, lw=1.2)
        ttc = track["ttc_ref_s"].where(np.isfinite(track["ttc_ref_s"]))
        bottom.plot(track["frame"] - t0, ttc.clip(upper=30), color=colour, lw=1.2)
        est = mine[mine["ref_track_id"] == tid]
        bottom.scatter(est["frame"] - t0, est["ttc_camera"].clip(0, 30), s=10, color=colour)
        bottom.scatter(est["frame"] - t0, est["ttc_lidar"].clip(0, 30), s=14, color=colour,
                       marker="x")  # fmt: skip
    top.set_ylabel("reference distance (m)")
    bottom.set_ylabel("TTC (s, ≤ 30)")
    bottom.set_xlabel("frame")
    title = f"tracks with ≥ 3 boxes; dots: camera, crosses: lidar TTC of {best}" if best else ""
    top.set_title(title, fontsize=9)
    fig.tight_layout()
    return fig


def plot_breakdown(table: pd.DataFrame) -> plt.Figure:
    """Where camera TTC breaks down: one panel per quantity of
    :func:`ttc.evaluation.object_errors.breakdown` (distance, box width, bearing, TTC range),
    its median relative error (bars, left axis, clipped at 2) and invalid rate (dots, right
    axis, 0–1) per range."""
    quantities = list(dict.fromkeys(table["quantity"]))
    fig, axes = plt.subplots(1, len(quantities), figsize=(3.2 * len(quantities), 3.2))
    for ax, quantity in zip(np.atleast_1d(axes), quantities, strict=True):
        part = table[table["quantity"] == quantity]
        x = np.arange(len(part))
        ax.bar(x, part["medae_rel"].clip(upper=2).fillna(0), color="tab:blue", alpha=0.7)
        ax.set_ylim(0, 2)
        ax.set_xticks(x, part["range"], rotation=45, ha="right", fontsize=7)
        ax.set_title(quantity, fontsize=9)
        twin = ax.twinx()
        twin.plot(x, part["invalid_rate"], "o", color="tab:red")
        twin.set_ylim(0, 1.05)
    np.atleast_1d(axes)[0].set_ylabel("median relative error (bars)")
    twin.set_ylabel("invalid rate (dots)")
    fig.tight_layout()
    return fig
