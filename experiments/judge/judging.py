"""Reading the user's files and ranking their settings beside the harness's: one long table
per file (:mod:`experiments.judge.layouts`), checked against the recording
(:func:`ttc.evaluation.external.checked_long_table`), turned into lead rows and judged with
the harness's own metrics, ranking rule and bootstrap rank intervals."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from experiments.judge.harness import HarnessSide
from experiments.judge.layouts import read_long
from experiments.judge.readers import InputError
from ttc import evaluation as ev
from ttc.evaluation.external import (
    ExternalTableError,
    checked_long_table,
    is_external,
    judged_external_rows,
    missing_pairs,
    with_frame_convention,
)


@dataclass
class ExternalInput:
    """What was read: the judged rows of every file, and per file its name, settings,
    frames and the rows dropped (``first_frame``, ``repeated``)."""

    rows: pd.DataFrame
    files: list[dict] = field(default_factory=list)


def read_inputs(
    paths: list[Path], names: list[str], first: int, last: int, reference: pd.DataFrame,
    convention: str = "current", minus_inf_is_ratio_one: bool = False,
) -> ExternalInput:  # fmt: skip
    """Every file as judged lead rows (:func:`~ttc.evaluation.external.judged_external_rows`)
    under its name (``names``, one per file); an :class:`InputError` names the file, line and
    column of the first problem, or a setting another file already gave under that name."""
    parts, files, seen = [], [], {}
    for path, name in zip(paths, names, strict=True):
        if not path.is_file():
            raise InputError(path, 0, "", "no such file")
        long = with_frame_convention(read_long(path), convention)
        try:
            long, dropped = checked_long_table(long, first, last)
        except ExternalTableError as exc:
            raise InputError(path, exc.line, exc.column, exc.message) from None
        rows = judged_external_rows(long, reference, name, minus_inf_is_ratio_one)
        for run_id in rows["run_id"].unique():
            if run_id in seen:
                raise InputError(path, 0, "setting", f"{run_id} was already read from "
                                 f"{seen[run_id]}: give each file its own --name")  # fmt: skip
            seen[run_id] = path
        parts.append(rows)
        files.append({"file": str(path), "name": name, "settings": int(long["setting"].nunique()),
                      "rows": len(long), **{f"dropped_{k}": v for k, v in dropped.items()}})  # fmt: skip
    return ExternalInput(pd.concat(parts, ignore_index=True), files)


def rank_together(
    harness: pd.DataFrame, external: pd.DataFrame, reference: pd.DataFrame, sensor: str,
    labels: dict[str, str], n_boot: int = ev.N_BOOT,
) -> pd.DataFrame:  # fmt: skip
    """The harness's and the external settings' lead rows of ``sensor`` ranked together:
    :func:`~ttc.evaluation.run_metrics`, :func:`~ttc.evaluation.rank_runs` and
    :func:`~ttc.evaluation.bootstrap_rank_intervals` (``n_boot`` replicates, seed 0) on the
    harness's frames (an external setting's missing frame is an invalid estimate, frames the
    harness has not judged are left out). Columns: ``setting``, ``external`` (bool), the
    metrics and rank interval; an external setting's times NaN (unknown)."""
    frames = np.sort(harness["frame"].unique())
    own = external[external[f"ttc_{sensor}"].notna().groupby(external["run_id"]).transform("any")]
    own = missing_pairs(own, frames) if not own.empty else own
    rows = pd.concat([harness, own], ignore_index=True)
    metrics = ev.run_metrics(rows, reference)
    with np.errstate(invalid="ignore"):  # an unknown time (+inf) weighted 0: NaN, sorted last
        intervals = ev.bootstrap_rank_intervals(rows, reference, n_boot=n_boot, seed=0,
                                                sensor=sensor, metrics=metrics)  # fmt: skip
    ranked = ev.rank_runs(metrics, sensor).merge(intervals.drop(columns="rank"), on="run_id")
    ranked["external"] = is_external(ranked["run_id"])
    names = {**labels, **dict(zip(own["run_id"], own["run_id"], strict=False))}
    ranked.insert(0, "setting", ranked["run_id"].map(names))
    for col in ("ms_per_frame", "ms_compute_per_frame"):
        ranked.loc[ranked["external"], col] = np.nan
    return ranked


def judge(
    side: HarnessSide, external: ExternalInput, n_boot: int = ev.N_BOOT
) -> dict[str, pd.DataFrame]:
    """Per sensor the harness has rows of and some external setting estimates: the joint
    ranking (:func:`rank_together`)."""
    out = {}
    for sensor, rows in side.rows.items():
        col = f"ttc_{sensor}"
        if col in external.rows and external.rows[col].notna().any():
            out[sensor] = rank_together(rows, external.rows, side.reference, sensor, side.labels[sensor],
                                        n_boot)  # fmt: skip
    return out
