"""What a run is: its setting (the part of a composed config that determines the numbers) and
its run id, the one hash of a setting (:func:`setting_hash`): a single run, the sweep's planner
and the reports all name runs with it, so equal settings get equal ids, across machines.
Options added after runs were stored are left out of the id at their "off" value
(:data:`NEUTRAL_OPTIONS`), so the ids of those runs stay the same."""

from __future__ import annotations

import hashlib
import json
from typing import Any

import pandas as pd
from omegaconf import DictConfig, OmegaConf

from experiments.data import datasets
from experiments.host import paths
from ttc import settings
from ttc.features.descriptors import NO_DESCRIPTOR
from ttc.features.learned_params import LEARNED_MATCHERS
from ttc.features.matching import NO_SELECTOR, TRACKERS
from ttc.settings import AXES

#: The top-level config entries a setting is made of (:func:`setting_config`).
SETTING_KEYS: tuple[str, ...] = (*AXES, "lidar")


def setting_entry(cfg: DictConfig, key: str) -> Any:
    """One entry of :func:`setting_config`, resolved from ``cfg[key]`` alone (the dataset
    without its data root, named by :func:`experiments.data.datasets.dataset_identity`)."""
    value = OmegaConf.to_container(cfg[key], resolve=True)
    if key == "dataset":
        recording = paths.resolve(value["root"]) / value["sequence"]
        value = datasets.dataset_identity({k: v for k, v in value.items() if k != "root"},
                                          recording)  # fmt: skip
    return value


def finish_setting(entries: dict[str, Any]) -> dict[str, Any]:
    """The setting of the resolved :data:`SETTING_KEYS` entries: a tracking matcher (KLT)
    uses no descriptor and selects nothing, so those two are recorded as ``none`` (one run
    id). ``entries`` is not changed; untouched values are the same objects."""
    setting = dict(entries)
    if setting["matcher"]["name"] in TRACKERS:
        setting["descriptor"] = {"name": NO_DESCRIPTOR.name}
        setting["selector"] = {"name": NO_SELECTOR.name}
    if setting["matcher"]["name"] in LEARNED_MATCHERS:  # LightGlue selects its own matches
        setting["selector"] = {"name": NO_SELECTOR.name}
    return setting


def setting_config(cfg: DictConfig) -> dict[str, Any]:
    """The part of the config that determines the numbers (no paths, no launcher)."""
    return finish_setting({key: setting_entry(cfg, key) for key in SETTING_KEYS})


def axis_values(setting: dict[str, Any]) -> dict[str, str]:
    """The value recorded on every axis of a :func:`setting_config`: the option's name
    (``none`` for the descriptor and selector of ``matcher=klt``), the detector's with
    ``+subpixel`` when its keypoints are refined, the object detector's with ``+tiles<N>`` when
    it runs on N > 1 tiles, so reports tell them apart."""
    values = {axis: str(setting[axis]["name"]) for axis in AXES}
    if setting["detector"].get("subpixel"):
        values["detector"] += SUBPIXEL_SUFFIX
    if (tiles := setting["objects"].get("tiles", 1)) != 1:
        values["objects"] += f"{TILES_SUFFIX}{tiles}"
    return values


#: Appended to the recorded detector name of a setting with ``detector.subpixel=true``.
SUBPIXEL_SUFFIX = "+subpixel"
#: Appended (with the count) to the recorded object detector of a setting with tiles.
TILES_SUFFIX = "+tiles"

#: Options that leave a setting's numbers as they were before the option existed, at their
#: "off" value: left out of the run id, so the ids of settings stored before stay the same.
#: From :data:`ttc.settings.NEUTRAL_OPTIONS` (the axis table's ``neutral`` values).
NEUTRAL_OPTIONS: tuple[tuple[str, str, Any], ...] = settings.NEUTRAL_OPTIONS


def with_neutral_options(setting: dict[str, Any]) -> dict[str, Any]:
    """A stored :func:`setting_config` with every :data:`NEUTRAL_OPTIONS` axis it lacks (a run
    recorded before that axis existed) at its off value, so it composes into
    :func:`settings_from_config` like a new one."""
    out = dict(setting)
    for axis, key, off in NEUTRAL_OPTIONS:
        if key == "name" and axis not in out:
            out[axis] = {"name": off}
    return out


def with_neutral_axes(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` (frames or run records) with the column of every :data:`NEUTRAL_OPTIONS` axis,
    its off value where a row was recorded before the axis existed. ``table`` is left as it
    is (a shallow copy: pandas copies on write; no second copy of a report's rows)."""
    out = table.copy(deep=False)
    for axis, key, off in NEUTRAL_OPTIONS:
        if key == "name" and not out.empty:
            out[axis] = _filled(out[axis], off) if axis in out else off
    return out


def _filled(values: pd.Series, off: str) -> pd.Series:
    """``values`` with ``off`` where missing; a category (a report's axes) gets ``off`` among
    its categories, kept sorted, when it has a missing value."""
    if isinstance(values.dtype, pd.CategoricalDtype) and values.isna().any():
        categories = sorted({*values.cat.categories, off})
        values = values.cat.set_categories(categories)
    return values.fillna(off)


def run_identity(setting: dict[str, Any]) -> dict[str, Any]:
    """:func:`setting_config` without the :data:`NEUTRAL_OPTIONS` at their off value (a whole
    axis goes when its ``name`` is off). Untouched values are the same objects."""
    out = dict(setting)
    for axis, key, off in NEUTRAL_OPTIONS:
        value = out.get(axis)
        if isinstance(value, dict) and key in value and value[key] == off:
            if key == "name":
                del out[axis]
            else:
                out[axis] = {k: v for k, v in value.items() if k != key}
    return out


def setting_hash(setting: dict[str, Any], memo: dict[int, tuple[Any, str]] | None = None) -> str:
    """The run id of a :func:`setting_config`: 16 hex digits of the SHA-256 of its
    :func:`run_identity`'s canonical JSON (sorted keys, no spaces).

    ``memo`` (a dict the caller keeps for a sweep): the JSON of each top-level value is kept
    there by object, so settings that share their values (a sweep's, from
    :class:`experiments.sweep.compose.Composer`) write each value once; the text hashed is
    the same."""
    identity = run_identity(setting)
    if memo is None:
        text = json.dumps(identity, sort_keys=True, separators=(",", ":"))
    else:
        parts = [
            json.dumps(key) + ":" + value_text(identity[key], memo) for key in sorted(identity)
        ]
        text = "{" + ",".join(parts) + "}"
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def value_text(value: Any, memo: dict[int, tuple[Any, str]]) -> str:
    """The canonical JSON (sorted keys, no spaces) of a setting's top-level value, kept in
    ``memo`` by object (:func:`setting_hash`)."""
    known = memo.get(id(value))
    if known is None or known[0] is not value:
        known = memo[id(value)] = (value, json.dumps(value, sort_keys=True, separators=(",", ":")))
    return known[1]


def run_id(cfg: DictConfig) -> str:
    """Hash of :func:`setting_config`: equal configs give equal ids, across machines."""
    return setting_hash(setting_config(cfg))
