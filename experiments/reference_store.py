"""The reference TTC of a sweep's recording, kept in the stage cache. Light on imports (no plotting): the end-of-sweep summary
ranks against the reference without loading the report's libraries."""

from __future__ import annotations

import hashlib
import inspect
import json
from pathlib import Path

import numpy as np
import pandas as pd

from experiments.paths import default_cache_dir, default_data_root
from ttc.cache import StageCache, Task, cache_key
from ttc.evaluation import reference as reference_module
from ttc.frames import LIDAR_DIR, file_identity, frame_files

#: Bump to invalidate every cached reference (the key also holds ttc/evaluation/reference.py's source).
REFERENCE_CACHE_VERSION = 1


def sequence_of(runs: pd.DataFrame) -> str:
    """The one KITTI recording (``dataset.sequence``) of the runs."""
    sequences = sorted({json.loads(c)["dataset"]["sequence"] for c in runs["config"]})
    if len(sequences) != 1:
        raise ValueError(f"the sweeps cover {len(sequences)} recordings {sequences}; report one")
    return sequences[0]


def _reference_key(sequence_dir: Path, last: int) -> str:
    scans = [file_identity(frame_files(sequence_dir, i).scan) for i in range(last + 1)]
    source = hashlib.sha256(inspect.getsource(reference_module).encode()).hexdigest()
    return cache_key("reference", REFERENCE_CACHE_VERSION, source, scans)


def sequence_reference(sequence_dir: Path, cache: StageCache) -> pd.DataFrame:
    """Reference TTC over every frame of the recording (:func:`reference_for_sequence`),
    kept in the stage cache (key: the scans' identities and ``ttc/evaluation/reference.py``'s source)."""
    last = len(list((Path(sequence_dir) / LIDAR_DIR).glob("*.bin"))) - 1
    if last < 1:
        raise FileNotFoundError(f"no lidar scans under {Path(sequence_dir) / LIDAR_DIR}")

    def compute() -> dict[str, np.ndarray]:
        ref = reference_module.reference_for_sequence(sequence_dir, 0, last)
        return {c: ref[c].to_numpy() for c in ref.columns}

    arrays = cache.get(Task("reference", _reference_key(Path(sequence_dir), last), compute))
    return pd.DataFrame(arrays.arrays)


def runs_reference(
    runs: pd.DataFrame, data_dir: Path | None = None, cache_dir: Path | None = None
) -> pd.DataFrame:
    """The reference of the recording of ``runs`` (runs.parquet rows); ``data_dir`` and
    ``cache_dir`` default to the configured ones."""
    root = Path(data_dir) if data_dir else default_data_root()
    cache = StageCache(cache_dir if cache_dir else default_cache_dir())
    return sequence_reference(root / sequence_of(runs), cache)
