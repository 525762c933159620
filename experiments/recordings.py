"""Runs grouped by recording: which recording a run is on (named by
:func:`experiments.data.datasets.recording_id`), the setting a
setting's runs share on every recording, and their rankings per drive and pooled. Light on
imports (the end-of-sweep summary, the references, MLflow and the report use it)."""

from __future__ import annotations

import functools
import json
import math
import sys
from json.encoder import encode_basestring_ascii
from pathlib import Path

import numpy as np
import pandas as pd

from experiments.config import setting_hash
from experiments.data.datasets import bag_source, recording_id
from ttc.io.ros2_bag import BagSource
from ttc.settings import SETTING_AXES, only_sensor_axes


def recording_of(runs: pd.DataFrame) -> pd.Series:
    """The recording (``dataset.sequence``, a folder under the data root) of each run, by
    run id. Only that entry is read (:func:`config_table` flattens every entry: 0.48 s a
    call for 980 configs, which the end-of-sweep summary made three times), or taken from
    the configs flattened already when each of them is."""
    leaves = _flattened_leaves(runs["config"], "dataset.sequence")
    if leaves is not None:
        sequences = [_leaf_value(v) for v in leaves]
    else:
        sequences = [_sequence(c) for c in runs["config"]]
    return pd.Series(sequences, index=runs["run_id"].to_numpy(), dtype=str)


@functools.lru_cache(maxsize=1 << 17)
def _sequence(config: str) -> str:
    """``dataset.sequence`` of a run's stored config (each config text parsed once per
    process)."""
    return json.loads(config)["dataset"]["sequence"]


@functools.lru_cache(maxsize=1 << 12)
def _leaf_value(leaf: str) -> str:
    """A string leaf's value from its JSON text (:func:`_leaf_text`)."""
    return json.loads(leaf)


def _flattened_leaves(configs: pd.Series, key: str) -> list[str] | None:
    """Each config's leaf text at ``key`` from the configs :func:`config_table` flattened,
    None unless every config is there with a string leaf at ``key`` (no config parsed)."""
    if not _FLAT_CONFIGS or key not in _FLAT_CONFIGS[0][1]:
        return None
    rows, table = _FLAT_CONFIGS[0]
    at = [rows.get(hash(t), -1) if isinstance(t, str) else -1 for t in configs]
    if -1 in at:
        return None
    leaves = table[key].to_numpy()[at].tolist() if at else []
    return leaves if all(isinstance(v, str) for v in leaves) else None


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


def _leaf_text(value: object) -> str:
    """``json.dumps(value, sort_keys=True)``, without building an encoder for a scalar (a
    ``grand`` sweep's setting ids flatten 28,000 configs of 90 leaves each)."""
    if isinstance(value, str):
        return encode_basestring_ascii(value)
    if value is None or isinstance(value, bool):
        return {None: "null", True: "true", False: "false"}[value]
    if type(value) is int or (type(value) is float and math.isfinite(value)):
        return repr(value)
    return json.dumps(value, sort_keys=True)


def _flat(tree: dict, prefix: str = "") -> dict[str, str]:
    """``{"a": {"b": 1}}`` → ``{"a.b": "1"}``: each leaf as its JSON text (lists, scalars
    and empty dicts are leaves; keys and texts interned: a sweep's runs share them)."""
    out: dict[str, str] = {}
    for key, value in tree.items():
        if isinstance(value, dict) and value:
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[sys.intern(f"{prefix}{key}")] = sys.intern(_leaf_text(value))
    return out


#: The configs :func:`config_table` flattened in this process: (the hash of each config text
#: → its row of the table, the table), rows added as new configs come. The report asks for
#: them in the load step (each recording's runs apart), the references, the "every object"
#: report and each page's header (``grand`` 0–18: 33,600 configs, 2.5 s a pass).
_FLAT_CONFIGS: list[tuple[dict[int, int], pd.DataFrame]] = []
#: Configs kept flattened at most; past it the table starts again from the configs asked for.
FLAT_CONFIGS_KEPT = 200_000
#: A config key's cell where the config lacks it, or has an empty dict there (no leaf).
NO_LEAF = "{}"


def config_table(configs: pd.Series) -> pd.DataFrame:
    """Each stored run config (JSON text; runs.parquet ``config``) flattened (:func:`_flat`):
    one column per dotted key that one of them has, each cell the leaf's JSON text (an empty
    dict's ``{}``), NaN where a config lacks the key or is itself missing; ``configs``' index.
    Each distinct text is parsed once per process (looked up by its hash; up to
    :data:`FLAT_CONFIGS_KEPT` of them kept)."""
    texts = [t if isinstance(t, str) else None for t in configs]
    rows, table = _FLAT_CONFIGS[0] if _FLAT_CONFIGS else ({}, pd.DataFrame())
    new = list(dict.fromkeys(t for t in texts if t is not None and hash(t) not in rows))
    if new:
        if len(rows) + len(new) > FLAT_CONFIGS_KEPT:
            rows, table = {}, pd.DataFrame()
            new = list(dict.fromkeys(t for t in texts if t is not None))
        added = pd.DataFrame([_flat(json.loads(t)) for t in new], dtype=object)
        rows = rows | {hash(t): len(rows) + i for i, t in enumerate(new)}
        table = pd.concat([table, added], ignore_index=True) if len(table) else added
        _FLAT_CONFIGS[:] = [(rows, table)]
    at = [rows[hash(t)] if t is not None else -1 for t in texts]
    found = table.reindex(at).set_axis(configs.index)  # a missing config (-1): NaN
    return found.dropna(axis=1, how="all")


def recording_entries(runs: pd.DataFrame) -> set[str]:
    """The setting entries (dotted keys) that belong to the recording, not to the setting:
    those with one value among each recording's runs of one choice on every axis
    (``detector.name``, ...), except the choices themselves. The dataset (name, frames, drive)
    is one; so is what a recording sets for itself (``conf/dataset/kitti_odometry.yaml``: its
    lidar crop, its camera pair distance), also where an option's own value differs from
    another's (``camera_ttc=vertical_ratio``'s 20 px beside ``median_ratio``'s 100 px on drive
    0052, 0 px for both on sequence 04); an entry a sweep varies within one choice is a
    setting's."""
    flat = config_table(runs["config"])
    choices = [f"{axis}.name" for axis in SETTING_AXES if axis != "dataset"]
    present = [c for c in choices if c in flat]
    keys = [recording_of(runs).to_numpy(), *(flat[c].to_numpy() for c in present)]
    constant = flat.groupby(keys, dropna=False).nunique(dropna=False).le(1).all()
    return {key for key, fixed in constant.items() if fixed and key not in choices}


def setting_of(runs: pd.DataFrame, sensor: str | None = None) -> pd.Series:
    """The id of each run's setting without its recording (:func:`recording_entries` left out
    of the stored setting's hash): equal for one setting's runs on every recording, and never
    equal for two runs of one recording. ``sensor="camera"``: the axes that change only the
    lidar or the fused TTC are left out too, so runs that differ only there (same camera TTC)
    share an id. By run id."""
    flat = config_table(runs["config"])
    left_out = recording_entries(runs)
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
