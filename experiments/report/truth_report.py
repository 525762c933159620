"""The report of a sweep on a generated recording with an exact truth (``dataset=scale_truth``):
``truth.md``, ``truth_ranking.csv`` (camera settings ranked against the truth, 90 % rank
intervals, median MiD per target TTC), ``truth_metrics.csv`` (every run × target: camera and
lidar metrics) and, for each real-sequence ranking given (``fp6_ranking.csv`` of
``results/kitti_0_18`` …), ``truth_vs_<name>.csv`` with Kendall's τ in ``truth.md``. The
FP.6 writer adds ``fp6_camera.md`` and its files against the truth (way-off pairs explained,
match pictures of the worst).
``metrics.parquet`` (against the truth) and ``metrics_by_target.parquet`` go beside each sweep.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from experiments import store
from experiments.report.encode import markdown_table, write_csv, write_text
from experiments.report.header import provenance_markdown
from experiments.report.load import SweepData
from ttc import evaluation as ev
from ttc.settings import AXES

#: Settings listed per table of ``truth.md``; movers listed per comparison.
SHOWN = 15


def write_sweep_tables(data: SweepData, reference: pd.DataFrame) -> list[Path]:
    """``metrics.parquet`` (:func:`ttc.evaluation.sweep_metrics` against the truth) and
    ``metrics_by_target.parquet`` (:func:`ttc.evaluation.truth_metrics`) beside each sweep."""
    written = []
    for d in data.dirs:
        runs = data.runs[data.runs["sweep_dir"] == str(d.resolve())]
        frames = ev.rows_of_runs(data.frames, runs["run_id"])
        if runs.empty or frames.empty:
            continue
        metrics = ev.sweep_metrics(frames, runs, reference)
        store.write_parquet_atomic(metrics, d / "metrics.parquet")
        store.write_parquet_atomic(ev.truth_metrics(frames), d / "metrics_by_target.parquet")
        written += [d / "metrics.parquet", d / "metrics_by_target.parquet"]
    return written


def per_target_columns(by_target: pd.DataFrame, metric: str) -> pd.DataFrame:
    """``run_id`` and one column ``{metric}_<T>s`` per target TTC (wide)."""
    part = by_target[by_target["target"] != ev.ALL_TARGETS]
    wide = part.pivot(index="run_id", columns="ttc_target", values=metric)
    wide.columns = [f"{metric}_{t:g}s" for t in wide.columns]
    return wide.reset_index()


def truth_tables(data: SweepData) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """(camera ranking against the truth, metrics by run × target, the truth reference)."""
    reference = ev.truth_reference(data.frames)
    t = ev.camera_frame_table(data.frames, data.runs, reference)
    ranking = ev.camera_ranking(data.frames, t, reference, ev.N_BOOT)
    by_target = ev.truth_metrics(data.frames)
    for metric in ("camera_mid_median", "camera_medae_rel"):
        ranking = ranking.merge(per_target_columns(by_target, metric), on="run_id", how="left")
    return ranking, by_target, reference


def compare_with_real(
    ranking: pd.DataFrame, real_path: Path
) -> tuple[str, dict[str, float], pd.DataFrame]:
    """(name, :func:`ttc.evaluation.ranking_agreement` summary, moves) of the ranking against
    a real sequence's ``fp6_ranking.csv`` (joined on the camera axes both have)."""
    real = pd.read_csv(real_path)
    key = [a for a in ev.CAMERA_AXES if a != "dataset" and a in real and a in ranking]
    summary, moves = ev.ranking_agreement(ranking, real, key)
    return str(real["dataset"].iloc[0]), summary, moves


def _comparison_markdown(name: str, summary: dict[str, float], moves: pd.DataFrame) -> list[str]:
    n = int(summary["n_settings"])
    return [
        f"### Against {name}",
        "",
        f"{n} settings in both rankings. **Kendall's tau = {summary['kendall_tau']:.3f}** "
        f"(p = {summary['kendall_p']:.2g}, scipy tau-b of the two ranks). Mean width of the "
        f"10 best settings' 90 % rank intervals, as a share of each ranking's settings: "
        f"{summary['top_width_synthetic']:.1%} on scale_truth, {summary['top_width_real']:.1%} "
        f"on {name}. Settings that move most (`move` = rank here − rank on {name}, both among "
        f"the {n} shared settings; all in `truth_vs_{name}.csv`):",
        "",
        markdown_table(moves.head(SHOWN)),
        "",
    ]


def truth_markdown(
    data: SweepData,
    ranking: pd.DataFrame,
    by_target: pd.DataFrame,
    comparisons: list[tuple[str, dict[str, float], pd.DataFrame]],
) -> str:
    """The ``truth.md`` text."""
    n_pairs = int(ranking["n_frames"].max()) if len(ranking) else 0
    targets = sorted(by_target["ttc_target"].dropna().unique())
    show = ["rank", "rank_lo", "rank_hi", "setting", "camera_invalid_rate", "camera_mid_median",
            *(f"camera_mid_median_{t:g}s" for t in targets), "camera_medae_rel",
            "ms_compute_per_frame"]  # fmt: skip
    lidar = by_target.merge(data.runs[["run_id", "lidar_ttc"]], on="run_id")
    lidar = lidar.drop_duplicates(["lidar_ttc", "target"]).sort_values(["lidar_ttc", "ttc_target"])
    lidar_cols = ["lidar_ttc", "target", "n_frames", "lidar_invalid_rate", "lidar_mid_median",
                  "lidar_medae_rel", "lidar_outlier_rate"]  # fmt: skip
    parts = [
        provenance_markdown(data, "Exact truth: settings judged on generated pairs"),
        f"Every setting is judged on the same **{n_pairs} generated pairs** with an exact "
        "truth (dataset `scale_truth`: each pair made from a real frame by a known scale "
        f"change about the lead car; target TTCs {', '.join(f'{t:g}' for t in targets)} s), "
        "instead of the lidar reference. MiD = 10^4 x |ln r - ln ratio_true|; the relative "
        "error is against `ttc_true`.",
        "",
        f"**Ranking rule** (`ttc.evaluation.RANKING_RULE`): {ev.RANKING_RULE}",
        "",
        "Why a setting misses the truth, frame by frame (way-off pairs, their reasons and the "
        "matches of the worst): [fp6_camera.md](fp6_camera.md).",
        "",
        f"## Camera ranking against the truth ({len(ranking)} settings)",
        "",
        markdown_table(ranking[[c for c in show if c in ranking]].head(SHOWN)),
        "",
        "## Lidar estimators per target TTC",
        "",
        markdown_table(lidar[[c for c in lidar_cols if c in lidar]]),
        "",
    ]
    if comparisons:
        parts += ["## Does the synthetic ranking predict the real one?", ""]
        for name, summary, moves in comparisons:
            parts += _comparison_markdown(name, summary, moves)
    return "\n".join(parts) + "\n"


def truth_report(data: SweepData, out: Path, real: list[Path]) -> dict:
    """Write the tables beside the sweeps and the report under ``out``; returns what was
    written, the ranking and the comparison summaries."""
    ranking, by_target, reference = truth_tables(data)
    written = write_sweep_tables(data, reference)
    out.mkdir(parents=True, exist_ok=True)
    keep = [c for c in ranking.columns if not c.startswith("ms_") or c.startswith("ms_compute")]
    write_csv(ranking[keep + ["ms_per_frame"]], out / "truth_ranking.csv")
    axes = [a for a in AXES if a != "dataset" and a in data.runs]
    labels = pd.Series(ev.setting_labels(data.runs, axes).to_numpy(), index=data.runs["run_id"])
    metrics = by_target.assign(setting=by_target["run_id"].map(labels))
    write_csv(metrics, out / "truth_metrics.csv")
    comparisons = [compare_with_real(ranking, path) for path in real]
    for name, _, moves in comparisons:
        write_csv(moves, out / f"truth_vs_{name}.csv")
    write_text(truth_markdown(data, ranking, by_target, comparisons), out / "truth.md")
    return {"metrics": written, "ranking": ranking, "by_target": by_target,
            "reference": reference,
            "comparisons": {name: summary for name, summary, _ in comparisons}}  # fmt: skip
