"""Several drives in one sweep: metrics and rankings per drive and pooled over the drives.

A sweep over several recordings holds one run per setting per drive, each judged against its
own drive's reference. To use the one-recording functions (:func:`ttc.evaluation.run_metrics`,
:func:`ttc.evaluation.bootstrap_rank_intervals`) unchanged, the drives are *stacked*: the
frames of drive number ``i`` (in the order given) become ``i · DRIVE_FRAME_STRIDE + frame``
in the frame tables and in one stacked reference, and each row keeps its ``drive``. Pooling a
setting over the drives then only renames its runs to one ``setting`` id: every metric of the
pooled run is over the frames of all drives (a median over all pooled frame pairs, not a
median of the drives' medians). The pooled bootstrap resamples blocks of frames *within*
each drive (:func:`ttc.evaluation.bootstrap.block_draws` with ``strata``), so a replicate has
as many frames of every drive as the sweep and no block spans two drives.

One approximation: a run's jitter (median change between consecutive finite TTCs) pooled
over drives counts one change across each drive boundary.
"""

from __future__ import annotations

from collections.abc import Mapping

import pandas as pd

from ttc.evaluation.bootstrap import bootstrap_rank_intervals
from ttc.evaluation.metrics import run_metrics
from ttc.evaluation.ranking import rank_runs

#: Offset between the stacked frame numbers of consecutive drives (more than any drive's
#: frame count: KITTI-raw drives hold at most a few thousand frames).
DRIVE_FRAME_STRIDE = 1_000_000
#: The ``drive`` value of the pooled rows of :func:`drive_rankings`.
POOLED = "pooled"


def stack_drives(
    frames: pd.DataFrame, drive_of_run: Mapping[str, str], references: Mapping[str, pd.DataFrame]
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(frames, reference) of several drives stacked into one frame numbering (module
    docstring). ``drive_of_run``: run id → drive name, ``references``: drive name → its
    reference table (``frame``, ...), in the order that numbers them. Both outputs get a
    ``drive`` column; a run whose drive has no reference raises ``KeyError`` naming it."""
    offsets = {drive: i * DRIVE_FRAME_STRIDE for i, drive in enumerate(references)}
    drive = frames["run_id"].map(drive_of_run)
    if drive.isna().any() or not drive.isin(list(offsets)).all():
        bad = sorted(set(frames.loc[~drive.isin(list(offsets)), "run_id"]))
        raise KeyError(f"runs without a drive or a reference: {bad[:5]}")
    offset = drive.map(offsets).astype("int64")
    stacked = frames.assign(drive=drive, frame=frames["frame"] + offset)
    if "prev_frame" in frames:
        stacked["prev_frame"] = frames["prev_frame"] + offset
    parts = []
    for name, ref in references.items():
        part = ref.assign(drive=name, frame=ref["frame"] + offsets[name])
        if "lead_segment" in part:  # segments never join across drives
            segment = part["lead_segment"]
            part["lead_segment"] = segment.where(segment < 0, segment + offsets[name])
        parts.append(part)
    return stacked, pd.concat(parts, ignore_index=True)


def pooled_frames(stacked: pd.DataFrame, setting_of_run: Mapping[str, str]) -> pd.DataFrame:
    """Stacked frames (:func:`stack_drives`) with every run renamed to its setting id
    (``setting_of_run``: run id → the id shared by one setting's runs on all drives)."""
    return stacked.assign(run_id=stacked["run_id"].map(setting_of_run))


def drive_rankings(
    frames: pd.DataFrame,
    drive_of_run: Mapping[str, str],
    setting_of_run: Mapping[str, str],
    references: Mapping[str, pd.DataFrame],
    sensor: str = "camera",
    n_boot: int = 500,
) -> pd.DataFrame:
    """Metrics and rank on ``sensor`` of every run on its own drive (``drive`` = its name,
    ranked among the runs of that drive) and of every setting pooled over the drives
    (``drive`` = :data:`POOLED`, ``run_id`` = the setting id, with the moving-block bootstrap's
    rank interval resampling within drives: ``rank_lo``, ``rank_hi``, ``block_length``; none
    with ``n_boot=0``).
    Every row carries its ``setting`` id; drives in the order of ``references``."""
    stacked, reference = stack_drives(frames, drive_of_run, references)
    parts = []
    for drive in references:
        mine = stacked[stacked["drive"] == drive]
        ranked = rank_runs(run_metrics(mine, reference), sensor)
        parts.append(ranked.assign(drive=drive, setting=ranked["run_id"].map(setting_of_run)))
    pooled = pooled_frames(stacked, setting_of_run)
    ranked = rank_runs(run_metrics(pooled, reference), sensor)
    if n_boot > 0:
        intervals = bootstrap_rank_intervals(pooled, reference, n_boot=n_boot, sensor=sensor)
        ranked = ranked.merge(
            intervals[["run_id", "rank_lo", "rank_hi", "block_length"]], on="run_id", how="left"
        )
    parts.append(ranked.assign(drive=POOLED, setting=ranked["run_id"]))
    return pd.concat(parts, ignore_index=True)
