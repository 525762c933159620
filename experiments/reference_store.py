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
from ttc.frames import LIDAR_DIR, file_identity, frame_files, read_frame_times

#: Bump to invalidate every cached reference (the key also holds ttc/evaluation/reference.py's source).
REFERENCE_CACHE_VERSION = 1


def sequence_of(runs: pd.DataFrame) -> str:
    """The one KITTI recording (``dataset.sequence``) of the runs."""
    sequences = sorted({json.loads(c)["dataset"]["sequence"] for c in runs["config"]})
    if len(sequences) != 1:
        raise ValueError(
            f"the sweeps cover {len(sequences)} recordings {sequences}: `python -m "
            "experiments.report` ranks them per drive and pooled (drives.md)"
        )
    return sequences[0]


def _reference_key(sequence_dir: Path, last: int, times: np.ndarray | None) -> str:
    scans = [file_identity(frame_files(sequence_dir, i).scan) for i in range(last + 1)]
    source = hashlib.sha256(inspect.getsource(reference_module).encode()).hexdigest()
    clock = None if times is None else hashlib.sha256(times.tobytes()).hexdigest()
    return cache_key("reference", REFERENCE_CACHE_VERSION, source, scans, clock)


def reference_task(sequence_dir: Path) -> Task:
    """The stage-cache task of the reference TTC over every frame of the recording
    (:func:`reference_for_sequence`), at the recording's real frame times when it ships a
    ``timestamps.txt`` (:func:`ttc.frames.read_frame_times`); key: the scans' identities, the
    frame times and ``ttc/evaluation/reference.py``'s source."""
    last = len(list((Path(sequence_dir) / LIDAR_DIR).glob("*.bin"))) - 1
    if last < 1:
        raise FileNotFoundError(f"no lidar scans under {Path(sequence_dir) / LIDAR_DIR}")
    times = read_frame_times(sequence_dir)

    def compute() -> dict[str, np.ndarray]:
        ref = reference_module.reference_for_sequence(sequence_dir, 0, last, times=times)
        # text columns (object, or pandas' str dtype) as fixed-width strings: cache entries
        # hold no pickled objects, and an object array would make every load discard it
        return {
            c: ref[c].to_numpy().astype(str)
            if pd.api.types.is_string_dtype(ref[c]) or pd.api.types.is_object_dtype(ref[c])
            else ref[c].to_numpy()
            for c in ref.columns
        }

    return Task("reference", _reference_key(Path(sequence_dir), last, times), compute)


def sequence_reference(sequence_dir: Path, cache: StageCache) -> pd.DataFrame:
    """Reference TTC over every frame of the recording (:func:`reference_task`), from the
    stage cache when it holds it."""
    return pd.DataFrame(cache.get(reference_task(sequence_dir)).arrays)


def runs_reference(
    runs: pd.DataFrame, data_dir: Path | None = None, cache_dir: Path | None = None
) -> pd.DataFrame:
    """The reference of the recording of ``runs`` (runs.parquet rows); ``data_dir`` and
    ``cache_dir`` default to the configured ones."""
    root = Path(data_dir) if data_dir else default_data_root()
    cache = StageCache(cache_dir if cache_dir else default_cache_dir())
    return sequence_reference(root / sequence_of(runs), cache)
