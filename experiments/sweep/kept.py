"""Hydra's compositions of a planned sweep, kept for its next plan.

The sweeper composes a sweep's template job, its variants and its validation jobs with Hydra
(~0.1 s each: 1.5 s of ``fp6_grid``'s planning). A sweep planned again with everything those
compositions depend on unchanged (a sweep resumed after Ctrl-C, a failed setting or a killed
process: its plan is not remembered as finished) reads them from
``<sweep>/.plan/compositions-<key>.pkl`` instead (~0.01 s). The key covers the plan's key
(:func:`experiments.plan.plan_key`: the jobs' overrides, the task config, every config and
code file, the Hydra and OmegaConf versions) and the master config's Hydra part (launcher,
sweeper, runtime); anything else composes again. The file is the sweep's own output, read
with ``pickle`` like the workers read the compositions the sweeper hands them.
"""

from __future__ import annotations

import hashlib
import json
import pickle
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from ttc.atomic import atomic_write

#: Folder of the kept compositions, in the sweep folder (the plan's folder).
KEPT_DIR = ".plan"


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
    data = pickle.dumps(dict(known))
    atomic_write(path, lambda tmp: tmp.write_bytes(data))
