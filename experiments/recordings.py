"""Runs grouped by recording: which recording a run is on, its short drive name, the setting a
setting's runs share on every recording, and their rankings per drive and pooled. Light on
imports (the end-of-sweep summary, the references, MLflow and the report use it)."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from experiments.config import setting_hash

#: ``dataset`` keys that name the drive and its frames: left out of the pooled setting id.
DRIVE_KEYS = ("sequence", "date", "drive", "first", "last")


def recording_of(runs: pd.DataFrame) -> pd.Series:
    """The recording (``dataset.sequence``, a folder under the data root) of each run, by
    run id."""
    sequences = [json.loads(c)["dataset"]["sequence"] for c in runs["config"]]
    return pd.Series(sequences, index=runs["run_id"].to_numpy(), dtype=str)


def run_ids_by_recording(runs: pd.DataFrame) -> dict[str, list[str]]:
    """The run ids of each recording (``dataset.sequence``) of ``runs``, recordings sorted."""
    recording = recording_of(runs)
    return {seq: list(recording.index[recording == seq]) for seq in sorted(set(recording))}


def drive_name(sequence: str) -> str:
    """A recording's short name: its folder without ``_sync``
    (``kitti_raw/2011_09_26/2011_09_26_drive_0052_sync`` → ``2011_09_26_drive_0052``)."""
    return Path(sequence).name.removesuffix("_sync")


def setting_of(runs: pd.DataFrame) -> pd.Series:
    """The id of each run's setting without its drive (:data:`DRIVE_KEYS` left out of the
    stored setting's hash): equal for one setting's runs on every drive, by run id."""

    def key(config: str) -> str:
        setting = json.loads(config)
        setting["dataset"] = {
            k: v for k, v in setting["dataset"].items() if k not in DRIVE_KEYS
        }  # fmt: skip
        return setting_hash(setting)

    return pd.Series([key(c) for c in runs["config"]], index=runs["run_id"].to_numpy())


def runs_drive_rankings(
    frames: pd.DataFrame,
    runs: pd.DataFrame,
    references: dict[str, pd.DataFrame],
    sensor: str,
    n_boot: int | None = None,
) -> pd.DataFrame:
    """:func:`ttc.evaluation.drive_rankings` of the ok runs of ``runs`` (run records) and
    their ``frames`` on ``sensor``; ``references`` by drive name (:func:`drive_name`);
    ``n_boot`` bootstrap draws (None: :data:`ttc.evaluation.N_BOOT`, 0: no intervals)."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    ok = runs[runs["status"] == "ok"]
    frames = frames[frames["run_id"].isin(ok["run_id"])]
    drive = recording_of(ok).map(drive_name)
    return ev.drive_rankings(
        frames,
        drive.to_dict(),
        setting_of(ok).to_dict(),
        references,
        sensor,
        ev.N_BOOT if n_boot is None else n_boot,
    )


#: What ``experiments.report`` writes for each kind of sweep (:func:`report_kind`).
REPORT_CONTENTS = {
    "truth": "truth.md, FP.6 against the truth, ranking with bootstrap intervals, HTML",
    "drives": "FP.5 / FP.6 per drive, drives.md ranked per drive and pooled, HTML",
    "recording": "FP.5, FP.6{fused}, ranking with bootstrap intervals, HTML",
}


def report_kind(frames: pd.DataFrame, runs: pd.DataFrame) -> str:
    """Which report a sweep gets, the one rule of the report and the summary: ``truth`` for a
    generated recording (judged against its exact truth), ``drives`` for the ok runs of
    several recordings (per drive and pooled), else ``recording``."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    if ev.has_truth(frames):
        return "truth"
    ok = runs[runs["status"] == "ok"]
    return "drives" if recording_of(ok).nunique() > 1 else "recording"
