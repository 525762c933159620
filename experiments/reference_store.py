"""The reference TTC of a sweep's recording, kept in the stage cache. Light on imports (no plotting): the end-of-sweep summary
ranks against the reference without loading the report's libraries."""

from __future__ import annotations

import hashlib
import inspect
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd

from experiments.paths import default_cache_dir, default_data_root
from experiments.recordings import recording_of, run_ids_by_recording
from ttc import evaluation as ev
from ttc.engine.cache import StageCache, Task, cache_key
from ttc.evaluation import lead_distance, lead_status
from ttc.evaluation import reference as reference_module
from ttc.io.frames import (
    file_identity,
    frame_files,
    read_frame_times,
    read_lidar_scan,
    recording_frames,
)

#: Bump to invalidate every cached reference (the key also holds the source of ttc/evaluation/lead_distance.py, lead_status.py and reference.py).
REFERENCE_CACHE_VERSION = 1


def sequence_of(runs: pd.DataFrame) -> str:
    """The one KITTI recording (``dataset.sequence``) of the runs."""
    sequences = sorted(set(recording_of(runs)))
    if len(sequences) != 1:
        raise ValueError(
            f"the sweeps cover {len(sequences)} recordings {sequences}: `python -m "
            "experiments.report` ranks them per drive and pooled (drives.md)"
        )
    return sequences[0]


def _reference_key(sequence_dir: Path, last: int, times: np.ndarray | None) -> str:
    scans = [file_identity(frame_files(sequence_dir, i).scan) for i in range(last + 1)]
    code = "".join(inspect.getsource(m) for m in (lead_distance, lead_status, reference_module))
    source = hashlib.sha256(code.encode()).hexdigest()
    clock = None if times is None else hashlib.sha256(times.tobytes()).hexdigest()
    return cache_key("reference", REFERENCE_CACHE_VERSION, source, scans, clock)


def recording_scans(sequence_dir: Path, last: int) -> Iterator[tuple[int, np.ndarray]]:
    """``(frame, points)`` of frames 0..``last`` of a recording, one scan read at a time."""
    for index in range(last + 1):
        yield index, read_lidar_scan(frame_files(sequence_dir, index).scan).points


def reference_task(sequence_dir: Path) -> Task:
    """The stage-cache task of the reference TTC over every frame of the recording
    (:func:`reference_for_sequence`), at the recording's real frame times when it ships a
    ``timestamps.txt`` (:func:`ttc.io.frames.read_frame_times`); key: the scans' identities, the
    frame times and the source of ``ttc/evaluation/lead_distance.py`` and ``reference.py``."""
    frames = recording_frames(sequence_dir)  # any layout (KITTI raw, Udacity, odometry)
    last = frames[-1] if frames else -1
    if last < 1:
        raise FileNotFoundError(f"fewer than two frames under {Path(sequence_dir)}")
    times = read_frame_times(sequence_dir)

    def compute() -> dict[str, np.ndarray]:
        ref = reference_module.reference_for_sequence(
            recording_scans(sequence_dir, last), times=times
        )
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


def recording_references(
    frames: pd.DataFrame,
    runs: pd.DataFrame,
    data_dir: Path | None = None,
    cache: StageCache | None = None,
) -> dict[str, pd.DataFrame]:
    """What the runs of each recording are judged against, by recording (``dataset.sequence``,
    sorted): a generated recording's exact truth (:func:`ttc.evaluation.truth_reference` of
    its runs' ``frames``), else the recording's reference TTC (:func:`sequence_reference`).
    ``data_dir`` / ``cache``: None for the configured data root and stage cache."""
    root = Path(data_dir) if data_dir else default_data_root()
    out = {}
    for sequence, ids in run_ids_by_recording(runs).items():
        mine = frames[frames["run_id"].isin(ids)]
        if ev.has_truth(mine):
            out[sequence] = ev.truth_reference(mine)
            continue
        cache = cache if cache is not None else StageCache(default_cache_dir())
        out[sequence] = sequence_reference(root / sequence, cache)
    return out
