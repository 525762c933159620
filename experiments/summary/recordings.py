"""Runs grouped by recording: which recording a run is on (named by
:func:`experiments.data.datasets.recording_id`), the setting a
setting's runs share on every recording, and their rankings per drive and pooled. Light on
imports (the end-of-sweep summary, the references, MLflow and the report use it)."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np
import pandas as pd

from experiments.configs.structured import setting_hash
from experiments.data.datasets import bag_source, recording_id
from experiments.store.flat_configs import (
    NO_LEAF,
    config_table,
    entry_leaves,
    flattened_leaves,
    leaf_value,
)
from ttc.io.ros2_bag import BagSource
from ttc.settings import SETTING_AXES, only_sensor_axes


def recording_of(runs: pd.DataFrame) -> pd.Series:
    """The recording (``dataset.sequence``, a folder under the data root) of each run, by
    run id. Only that entry is read (:func:`config_table` flattens every entry: 0.48 s a
    call for 980 configs, which the end-of-sweep summary made three times), or taken from
    the configs flattened already when each of them is."""
    leaves = flattened_leaves(runs["config"], "dataset.sequence")
    if leaves is not None:
        sequences = [leaf_value(v) for v in leaves]
    else:
        sequences = [_sequence(c) for c in runs["config"]]
    return pd.Series(sequences, index=runs["run_id"].to_numpy(), dtype=str)


@functools.lru_cache(maxsize=1 << 17)
def _sequence(config: str) -> str:
    """``dataset.sequence`` of a run's stored config (each config text read once per
    process, only up to its ``dataset`` entry: :func:`experiments.store.flat_configs.entry_leaves`)."""
    return leaf_value(entry_leaves(config, "dataset")["dataset.sequence"])


def recording_source_of(runs: pd.DataFrame, run_id: str, root: Path) -> Path | BagSource:
    """What run ``run_id`` of ``runs`` read: ``dataset.sequence`` under the data ``root``, or
    for a ``ros2_bag`` run the bag with the run's own topics, scan tolerance and camera frame
    (its stored ``config``; :func:`experiments.data.datasets.bag_source`)."""
    dataset = json.loads(runs.loc[runs["run_id"] == run_id, "config"].iloc[0])["dataset"]
    recording = Path(root) / dataset["sequence"]
    return bag_source(dataset, recording) or recording


def run_ids_by_recording(runs: pd.DataFrame) -> dict[str, list[str]]:
    """The run ids of each recording (``dataset.sequence``) of ``runs``, recordings sorted."""
    recording = recording_of(runs)
    return {seq: list(recording.index[recording == seq]) for seq in sorted(set(recording))}


def recording_entries(runs: pd.DataFrame, flat: pd.DataFrame | None = None) -> set[str]:
    """The setting entries (dotted keys) that belong to the recording, not to the setting:
    those with one value among each recording's runs of one choice on every axis
    (``detector.name``, ...), except the choices themselves. The dataset (name, frames, drive)
    is one; so is what a recording sets for itself (``conf/dataset/kitti_odometry.yaml``: its
    lidar crop, its camera pair distance), also where an option's own value differs from
    another's (``camera_ttc=vertical_ratio``'s 20 px beside ``median_ratio``'s 100 px on drive
    0052, 0 px for both on sequence 04); an entry a sweep varies within one choice is a
    setting's. ``flat``: :func:`~experiments.store.flat_configs.config_table` of the runs' configs,
    when made already. A missing entry is a value of its own. Each entry is checked on its
    codes against those of its group's first run (a group-by's ``nunique`` of the 130 entries
    of ``grand``'s 28,000 runs took 0.25 s)."""
    flat = config_table(runs["config"]) if flat is None else flat
    choices = [f"{axis}.name" for axis in SETTING_AXES if axis != "dataset"]
    keys = [recording_of(runs).to_numpy(), *(flat[c].to_numpy() for c in choices if c in flat)]
    coded = np.column_stack([pd.factorize(k, use_na_sentinel=False)[0] for k in keys])
    _, firsts, group = np.unique(coded, axis=0, return_index=True, return_inverse=True)
    first = firsts[group.ravel()]  # (n,) the first run of each run's group
    constant = set()
    for key in (k for k in flat.columns if k not in choices):
        codes = pd.factorize(flat[key], use_na_sentinel=False)[0]
        if (codes == codes[first]).all():
            constant.add(key)
    return constant


def setting_of(runs: pd.DataFrame, sensor: str | None = None) -> pd.Series:
    """The id of each run's setting without its recording (:func:`recording_entries` left out
    of the stored setting's hash): equal for one setting's runs on every recording, and never
    equal for two runs of one recording. ``sensor="camera"``: the axes that change only the
    lidar or the fused TTC are left out too, so runs that differ only there (same camera TTC)
    share an id. By run id."""
    flat = config_table(runs["config"])
    left_out = recording_entries(runs, flat)
    other = () if sensor != "camera" else (*only_sensor_axes("lidar"), *only_sensor_axes("fused"))
    prefixes = tuple(f"{axis}." for axis in other)
    kept = [k for k in sorted(flat.columns) if k not in left_out and not k.startswith(prefixes)]
    texts = flat[kept].fillna(NO_LEAF)
    codes = np.column_stack([pd.factorize(texts[k])[0] for k in kept] or [np.zeros(len(flat))])
    _, first, inverse = np.unique(codes, axis=0, return_index=True, return_inverse=True)
    leaves = texts.to_numpy()
    ids = [
        setting_hash({k: v for k, v in zip(kept, leaves[i], strict=True) if v != NO_LEAF})
        for i in first
    ]
    return pd.Series([ids[i] for i in inverse.ravel()], index=runs["run_id"].to_numpy())


def runs_drive_rankings(
    frames: pd.DataFrame,
    runs: pd.DataFrame,
    references: dict[str, pd.DataFrame],
    sensor: str,
    n_boot: int | None = None,
) -> pd.DataFrame:
    """:func:`ttc.evaluation.drive_rankings` of the ok runs of ``runs`` (run records) and
    their ``frames`` on ``sensor``; ``references`` by recording id (:func:`recording_id`);
    ``n_boot`` bootstrap draws (None: :data:`ttc.evaluation.N_BOOT`, 0: no intervals)."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    ok = runs[runs["status"] == "ok"]
    setting = setting_of(ok, sensor)
    drive = recording_of(ok).map(recording_id)
    first = ~pd.DataFrame({"drive": drive, "setting": setting}).duplicated().to_numpy()
    ok, setting, drive = ok[first], setting[first], drive[first]  # one run per camera TTC
    frames = frames[frames["run_id"].isin(ok["run_id"])]
    return ev.drive_rankings(
        frames,
        drive.to_dict(),
        setting.to_dict(),
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
