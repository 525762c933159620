"""Sweeps over several drives: which run is on which drive, the setting shared by a setting's
runs on every drive, and the drives report (``drives.md``, ``drives_ranking.csv``): metrics
and rankings per drive and pooled (:mod:`ttc.evaluation.drives`). The FP.5 / FP.6 reports of
each drive are written by :func:`experiments.report.report_command.build_report` into ``<out>/<id>/``
(the recording id, :func:`experiments.data.datasets.recording_id`; pages show its name)."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from experiments.data.datasets import recording_id, recording_names
from experiments.report.encode import markdown_table, write_csv, write_text
from experiments.report.header import provenance_markdown
from experiments.report.load import Context, SweepData
from experiments.summary.recordings import run_ids_by_recording, runs_drive_rankings
from experiments.summary.references import recording_references
from ttc import evaluation as ev
from ttc.settings import AXES

#: Columns of ``drives_ranking.csv`` (per sensor: its ranking keys and outlier rate).
RANKING_COLUMNS = ["drive", "rank", "rank_lo", "rank_hi", "setting", "run_id", *AXES,
                   "n_frames", "n_judged"]  # fmt: skip


def runs_of(data: SweepData, ids: set[str]) -> SweepData:
    """The part of ``data`` that holds the runs ``ids``: their records, rows and box pairs."""

    def pick(table: pd.DataFrame) -> pd.DataFrame:
        return table if table.empty else table[table["run_id"].isin(ids)].reset_index(drop=True)

    return SweepData(data.dirs, pick(data.frames), pick(data.runs), data.overrides,
                     data.repeated, pick(data.boxes))  # fmt: skip


def split_by_recording(data: SweepData) -> dict[str, SweepData]:
    """One :class:`SweepData` per recording of ``data`` (by recording id; sorted by folder)."""
    return {recording_id(sequence): runs_of(data, set(ids))
            for sequence, ids in run_ids_by_recording(data.runs).items()}  # fmt: skip


def by_detector(data: SweepData) -> dict[str, SweepData]:
    """The runs of ``data`` (one recording) per object-detector setting (the whole ``objects``
    entry: model, tiles, thresholds), the detector most runs use first (ties: sorted), each
    named by its recorded axis value (``yolov3_tiny``, ``ssd_mobilenet_v2+tiles4``; the
    entry's JSON where two entries share a name). The every-object report judges each part
    against its own detector's boxes: a pair is judged by its box numbers, so the runs of two
    detectors cannot share one reference."""
    entries = data.runs["config"].map(
        lambda c: json.dumps(json.loads(c).get("objects"), sort_keys=True)
    )
    counts = entries.value_counts()
    order = sorted(counts.index, key=lambda e: (-counts[e], e))
    names = {e: data.runs.loc[entries == e, "objects"].iloc[0] if "objects" in data.runs
             else json.loads(e)["name"] for e in order}  # fmt: skip
    if len(set(names.values())) < len(names):
        names = {e: e for e in order}
    if len(order) <= 1:
        return {str(names[order[0]]) if order else "": data}
    return {str(names[e]): runs_of(data, set(data.runs.loc[entries == e, "run_id"]))
            for e in order}  # fmt: skip


def drive_references(data: SweepData, ctx: Context) -> dict[str, pd.DataFrame]:
    """What the runs of every recording of ``data`` are judged against
    (:func:`experiments.summary.references.recording_references`), by recording id
    (:func:`experiments.data.datasets.recording_id`; sorted by folder)."""
    references = recording_references(data.frames, data.runs, ctx.root, ctx.cache)
    return {recording_id(sequence): ref for sequence, ref in references.items()}


def sweep_metrics_by_drive(
    frames: pd.DataFrame, runs: pd.DataFrame, references: dict[str, pd.DataFrame]
) -> pd.DataFrame:
    """:func:`ttc.evaluation.sweep_metrics` of the runs of each drive against its own
    reference, with a ``drive`` column, concatenated (sorted by run id)."""
    by_drive = {recording_id(seq): ids for seq, ids in run_ids_by_recording(runs).items()}
    parts = []
    for name, reference in references.items():
        ids = by_drive.get(name, [])
        mine = runs[runs["run_id"].isin(ids)]
        if mine.empty:
            continue
        table = ev.sweep_metrics(frames[frames["run_id"].isin(ids)], mine, reference)
        parts.append(table.assign(drive=name))
    return pd.concat(parts, ignore_index=True).sort_values("run_id", ignore_index=True)


def drives_table(
    data: SweepData, references: dict[str, pd.DataFrame], sensor: str, n_boot: int = ev.N_BOOT
) -> pd.DataFrame:
    """:func:`ttc.evaluation.drive_rankings` of the ok runs of ``data`` on ``sensor``."""
    return runs_drive_rankings(data.frames, data.runs, references, sensor, n_boot)


def drives_report(
    data: SweepData, references: dict[str, pd.DataFrame], out: Path, n_boot: int = ev.N_BOOT
) -> pd.DataFrame:
    """Write ``drives_ranking.csv`` and ``drives.md``: per drive and pooled, every setting's
    metrics and rank on the camera and the lidar; return the table."""
    tables = []
    for sensor in ("camera", "lidar"):
        t = drives_table(data, references, sensor, n_boot)
        keys = [f"{sensor}_{k}" for k in (*ev.RANKING_KEYS, "outlier_rate", "medae_rel")]
        cols = [c for c in [*RANKING_COLUMNS, *keys] if c in t]
        tables.append(t[cols].assign(sensor=sensor))
    table = pd.concat(tables, ignore_index=True)
    write_csv(table, out / "drives_ranking.csv")
    names = {ev.POOLED: ev.POOLED, **recording_names(references)}
    folders = ", ".join(f"{names[r]} (`{r}/`)" for r in references)
    lines = [
        provenance_markdown(data, "Several drives: rankings per drive and pooled"),
        f"Drives: {folders}, each judged against its own reference; FP.5, FP.6 "
        "and the reference of each drive in its folder. **Pooled**: every setting's frame "
        "pairs of all drives together (medians and rates over all of them); its rank interval "
        f"({ev.CI:.0%}) is a moving-block bootstrap resampling blocks of frames within each "
        "drive.",
        "",
        ev.RANKING_RULE,
        "",
    ]
    for name, reference in references.items():
        lines += [f"- {names[name]}: {ev.not_judged_text(reference)}"]
    for sensor, t in zip(("camera", "lidar"), tables, strict=True):
        for drive in [ev.POOLED, *references]:
            part = t[t["drive"] == drive].drop(columns=["sensor", "drive"])
            part = part.dropna(axis=1, how="all")
            lines += ["", f"## {sensor}: {names[drive]}", "", markdown_table(part)]
    write_text("\n".join(lines) + "\n", out / "drives.md")
    return table
