"""Merge a sweep's runs into one dataset and print its summary (also for interrupted sweeps).

Usage::

    python -m experiments.collect sweeps/fp6_grid_kitti_0_18
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from experiments import store
from experiments.callbacks import PROGRESS_DIR

SETTING_COLUMNS = ["detector", "descriptor", "matcher", "selector", "box_matching",
                   "lidar_ttc", "keypoint_filter", "camera_ttc"]  # fmt: skip


def interim_scores(frames: pd.DataFrame) -> pd.DataFrame:
    """Median |TTC camera − TTC lidar| (s) of the lead vehicle per run, finite pairs only.

    A stop-gap score until a reference TTC is available: low means camera and lidar agree.
    """
    lead = frames[frames["is_lead"]]
    both = lead[np.isfinite(lead["ttc_camera"]) & np.isfinite(lead["ttc_lidar"])]
    diff = (both["ttc_camera"] - both["ttc_lidar"]).abs().rename("median_abs_diff_s")
    scores = diff.groupby([both["run_id"], *[both[c] for c in SETTING_COLUMNS]]).median()
    valid = both.groupby("run_id").size().rename("finite_pairs")
    total = lead.groupby("run_id").size().rename("pairs")
    out = scores.reset_index().merge(valid, on="run_id").merge(total, on="run_id")
    return out.sort_values(["median_abs_diff_s", "run_id"], ignore_index=True)


def summarise_sweep(sweep_dir: Path, top: int = 5) -> pd.DataFrame:
    """Collect the sweep, print where the dataset is, the run counts and the best settings."""
    frames, runs = store.collect(sweep_dir)
    counts = runs["status"].value_counts() if not runs.empty else pd.Series(dtype=int)
    print(f"\nsweep dataset: {sweep_dir / store.FRAMES_FILE} ({len(frames)} rows)")
    print(f"run records:   {sweep_dir / store.RUNS_FILE}")
    print(
        f"settings: {len(runs)} total, {counts.get('ok', 0)} ok, "
        f"{counts.get('skipped', 0)} skipped, {counts.get('failed', 0)} failed"
    )
    progress = sweep_dir / PROGRESS_DIR
    if progress.is_dir():
        outcomes = pd.Series([p.read_text() for p in progress.iterdir()], dtype=str)
        print(
            f"this invocation: {int((outcomes != 'resumed').sum())} computed, "
            f"{int((outcomes == 'resumed').sum())} already complete (resumed)"
        )
    for _, run in runs[runs["status"] == "failed"].iterrows() if not runs.empty else []:
        print(f"  failed {run['run_id']}: {run['message']}")
    if frames.empty:
        return pd.DataFrame()
    scores = interim_scores(frames)
    with pd.option_context("display.width", 160, "display.max_columns", 20):
        print(f"\nbest {top} settings by median |TTC camera - TTC lidar| (interim score):")
        print(scores.head(top).to_string(index=False, float_format="%.2f"))
    return scores


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep_dir", type=Path, help="the sweep folder (hydra.sweep.dir)")
    parser.add_argument("--top", type=int, default=5, help="how many settings to list")
    args = parser.parse_args(argv)
    if not (args.sweep_dir / store.RUNS_DIR).is_dir():
        parser.error(f"{args.sweep_dir} has no {store.RUNS_DIR}/ folder: not a sweep folder")
    summarise_sweep(args.sweep_dir, args.top)


if __name__ == "__main__":
    main()
