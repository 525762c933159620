"""Hydra's compositions of a planned sweep, kept for its next plans.

The sweeper composes a sweep's template job, its variants and its validation jobs with Hydra
(~0.1 s each: 1.5 s of ``fp6_grid``'s planning). A sweep planned again with everything those
compositions depend on unchanged (a sweep resumed after Ctrl-C, a failed setting or a killed
process: its plan is not remembered as finished) reads them from
``<sweep>/.plan/compositions-<key>.pkl`` instead (~0.01 s). The key covers the plan's key
(:func:`experiments.sweep.plan.plan_key`: the jobs' overrides, the task config, every config and
code file, the Hydra and OmegaConf versions) and the master config's Hydra part (launcher,
sweeper, runtime); anything else composes again. The file is the sweep's own output, read
with ``cloudpickle`` like the compositions the sweeper hands its workers.

A sweep planned after changing an axis (another command line) finds no exact match, but the
last plan of the sweep folder whose variants were composed (its template and compositions:
``<sweep>/.plan/earlier-<key>.pkl``) serves as an :class:`experiments.sweep.earlier.EarlierPlan`
when everything a composition depends on besides the jobs' overrides is unchanged
(:func:`earlier_key`: config and code files, package versions, the config name, the Hydra
overrides of the command line, the config sources and the working folder).
"""

from __future__ import annotations

import hashlib
import json
import pickle
from pathlib import Path
from typing import Any

import cloudpickle
from omegaconf import DictConfig, OmegaConf

from experiments.sweep.earlier import EarlierPlan
from ttc.atomic import atomic_write

#: Packages whose versions the compositions depend on (the launchers' config classes too).
PACKAGES = ("hydra-core", "omegaconf", "hydra-joblib-launcher", "hydra-submitit-launcher")

#: Folder of the kept compositions, in the sweep folder (the plan's folder).
KEPT_DIR = ".plan"


def _dumps(value: Any) -> bytes:
    """``pickle``, or ``cloudpickle`` when a config class does not pickle by reference (Hydra
    loads plugin modules twice: their config classes are then pickled by value)."""
    try:
        return pickle.dumps(value)
    except (pickle.PicklingError, TypeError, AttributeError):
        return cloudpickle.dumps(value)


def compositions_key(plan_key: str, config: DictConfig) -> str:
    """The key of a sweep's compositions: its ``plan_key`` and its master ``config``'s Hydra
    part (unresolved)."""
    hydra = OmegaConf.to_container(config.hydra, resolve=False)
    text = json.dumps([plan_key, hydra], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def kept_path(sweep_dir: Path, key: str) -> Path:
    """Where the compositions of key ``key`` are kept."""
    return Path(sweep_dir) / KEPT_DIR / f"compositions-{key}.pkl"


def load_compositions(sweep_dir: Path, key: str) -> dict[tuple[str, ...], DictConfig]:
    """The compositions kept under ``key`` ({} when there are none or they do not load)."""
    try:
        known: Any = pickle.loads(kept_path(sweep_dir, key).read_bytes())
    except Exception:  # missing, partial or from another version: compose again
        return {}
    return known if isinstance(known, dict) else {}


def keep_compositions(sweep_dir: Path, key: str, known: dict[tuple[str, ...], DictConfig]) -> None:
    """Keep ``known`` under ``key`` (written atomically)."""
    path = kept_path(sweep_dir, key)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = _dumps(dict(known))
    atomic_write(path, lambda tmp: tmp.write_bytes(data))


def earlier_key(config: DictConfig) -> str:
    """What a sweep's compositions depend on besides its jobs' overrides (module docstring),
    as a key."""
    import os  # noqa: PLC0415
    from importlib import metadata  # noqa: PLC0415

    from experiments.host.provenance import source_identities  # noqa: PLC0415

    sources = OmegaConf.to_container(config.hydra.runtime.config_sources, resolve=False)
    extra = tuple(
        Path(str(source["path"])[len("file://") :])
        for source in sources
        if source["provider"] != "hydra" and str(source["path"]).startswith("file://")
    )
    versions = []
    for package in PACKAGES:
        try:
            versions.append(metadata.version(package))
        except metadata.PackageNotFoundError:
            versions.append(None)
    parts = [source_identities(extra), versions, str(config.hydra.job.config_name),
             list(config.hydra.overrides.hydra), sources, os.getcwd()]  # fmt: skip
    return hashlib.sha256(json.dumps(parts, default=str).encode()).hexdigest()[:24]


def earlier_path(sweep_dir: Path, key: str) -> Path:
    """Where the earlier plan of key ``key`` is kept."""
    return Path(sweep_dir) / KEPT_DIR / f"earlier-{key}.pkl"


def load_earlier(sweep_dir: Path, key: str) -> EarlierPlan | None:
    """The earlier plan kept under ``key``, if any."""
    try:
        earlier: Any = pickle.loads(earlier_path(sweep_dir, key).read_bytes())
    except Exception:  # missing, partial or from another version
        return None
    return earlier if isinstance(earlier, EarlierPlan) else None


def keep_earlier(sweep_dir: Path, key: str, earlier: EarlierPlan) -> None:
    """Keep ``earlier`` under ``key`` for the next plans (written atomically)."""
    path = earlier_path(sweep_dir, key)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = _dumps(earlier)
    atomic_write(path, lambda tmp: tmp.write_bytes(data))
