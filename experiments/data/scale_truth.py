"""The ``scale_truth`` dataset on disk: the pairs of :mod:`ttc.io.scaled_pairs` written as a KITTI
recording folder inside the stage cache, so the unchanged pipeline (and its real YOLO
detector) runs on the synthetic images.

The folder ``<cache>/scale_truth/<key>/`` holds ``image_02/data/NNNNNNNNNN.png``,
``velodyne_points/data/NNNNNNNNNN.bin`` (pair i = frames 2i → 2i+1), copies of both
calibration files and ``truth.csv`` (:data:`ttc.io.frames.TRUTH_FILE`). ``key`` is the hash of the
generator parameters (seed included), the identities of the source files
(:func:`ttc.io.frames.file_identity`), the YOLO model files, and the source code of
:mod:`ttc.io.scaled_pairs` and of this module: a change of any gives a new folder, nothing stale is
reused. The folder is written under a temporary name and renamed into place (atomic), by one
process at a time (a lock file beside it).

The lead vehicle of a source frame (its rear centre for the warp and its lidar points) comes
from the real frame through the pipeline's own cached stages and rule: YOLO boxes (default
``objects``), the lane crop, :func:`ttc.steps.lidar.associate_lead`.
"""

from __future__ import annotations

import dataclasses
import fcntl
import hashlib
import inspect
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd
from omegaconf import DictConfig, OmegaConf

from experiments.host import paths
from ttc.engine.cache import StageCache, cache_key
from ttc.engine.stages import FrameStages
from ttc.features.descriptors import DESCRIPTORS
from ttc.features.keypoints import DETECTORS
from ttc.features.objects import detect_objects, model_identity
from ttc.io import scaled_pairs as generator
from ttc.io.calibration import (
    CAM_TO_CAM,
    VELO_TO_CAM,
    Calibration,
    calibration_dir,
    load_calibration,
)
from ttc.io.frames import (
    IMAGE_DIR,
    LIDAR_DIR,
    TRUTH_COLUMNS,
    TRUTH_FILE,
    file_identity,
    frame_files,
    read_image,
)
from ttc.io.scaled_pairs import ScaleTruthParams, SyntheticPair, make_pair
from ttc.settings import FrameRange, Settings
from ttc.steps.lidar import assign_points_to_boxes, associate_lead, lane_mask

#: Bump when the written folder's layout changes (the code hashes cover the rest).
LAYOUT_VERSION = 1
#: The generator's dataset config key (``dataset.generator``) and its folder in the cache.
GENERATOR = "scale_truth"


@dataclasses.dataclass(frozen=True)
class SourceLead:
    """The lead vehicle of a real frame: its box (x, y, w, h pixels), the rear centre (u, v
    pixels) and its lane lidar points (N × 4 float32, Velodyne frame)."""

    frame: int
    box: np.ndarray
    centre: tuple[float, float]
    points: np.ndarray


def _source_settings() -> Settings:
    """Settings whose default objects detector and lane crop pick the source frames' lead
    vehicles (fixed: the dataset must not change with a sweep's axes)."""
    return Settings(detector=DETECTORS["fast"](), descriptor=DESCRIPTORS["brief"]())


def source_leads(
    sequence_dir: Path, params: ScaleTruthParams, cache: StageCache, calib: Calibration
) -> list[SourceLead]:
    """The lead vehicle of every source frame; a frame without a lead box gets the image
    centre and no points (its pairs then have no lidar estimate: judged invalid)."""
    settings = _source_settings()
    stages = FrameStages(settings, FrameRange(sequence_dir), cache)
    out = []
    for k in params.sources:
        objects, lane = (
            lookup.arrays for lookup in cache.resolve([stages.objects(k), stages.lidar(k)])
        )
        rois, points = objects["roi"], lane["points"]
        found = associate_lead(points, calib.velo_to_image, rois, settings.lidar_shrink)
        lead = found.lead
        if lead < 0:
            width, height = calib.image_size
            out.append(SourceLead(k, np.zeros(4, np.int64), (width / 2, height / 2), points[:0]))
            continue
        inner = assign_points_to_boxes(found.uv, rois, params.point_shrink) == lead
        x, y, w, h = (float(v) for v in rois[lead])
        out.append(SourceLead(k, rois[lead], (x + w / 2, y + h / 2), points[inner]))
    return out


def dataset_key(sequence_dir: Path, params: ScaleTruthParams) -> str:
    """The identity of a generated recording (module docstring), 64 hex digits."""
    files = [frame_files(sequence_dir, k) for k in params.sources]
    sources = [(file_identity(f.image), file_identity(f.scan)) for f in files]
    calib_dir = calibration_dir(sequence_dir)
    calib = [file_identity(calib_dir / name) for name in (CAM_TO_CAM, VELO_TO_CAM)]
    code = [
        hashlib.sha256(inspect.getsource(module).encode()).hexdigest()
        for module in (generator, sys.modules[__name__])
    ]
    model = model_identity(_source_settings().objects)
    return cache_key(
        GENERATOR, LAYOUT_VERSION, dataclasses.asdict(params), sources, calib, model, code
    )


def consistent_points(pair: SyntheticPair, calib: Calibration, settings: Settings) -> np.ndarray:
    """(N + n,) bool over the rows of :meth:`SyntheticPair.scans`: the points the pipeline's
    rules keep in both frames of the pair: inside the lane crop (:func:`ttc.steps.lidar.lane_mask`)
    and assigned to the lead box (YOLO with ``settings.objects`` on each synthetic image,
    :func:`ttc.steps.lidar.associate_lead` with ``settings.lidar_shrink``). The scans keep only these, so both hold the same points
    and the distance ratio of any order statistic is exactly the truth's."""
    scans = pair.scans()
    keep = np.ones(len(scans[0]), dtype=bool)
    for image, points in zip((pair.image_prev, pair.image_curr), scans, strict=True):
        rois = detect_objects(image, settings.objects).roi
        found = associate_lead(points, calib.velo_to_image, rois, settings.lidar_shrink)
        keep &= (found.owner == found.lead) & (found.lead >= 0) & lane_mask(points, settings.lane)
    return keep


def write_recording(
    folder: Path,
    sequence_dir: Path,
    params: ScaleTruthParams,
    leads: list[SourceLead],
    calib: Calibration,
) -> pd.DataFrame:
    """Write every pair of ``leads`` × ``params.targets_s`` into ``folder``; return the truth
    table (one row per pair: ``prev_frame``, ``frame`` and :data:`TRUTH_COLUMNS`). Every pair
    is written (:func:`n_pairs`); its scans keep the :func:`consistent_points`."""
    settings = _source_settings()
    (folder / IMAGE_DIR).mkdir(parents=True)
    (folder / LIDAR_DIR).mkdir(parents=True)
    for name in (CAM_TO_CAM, VELO_TO_CAM):  # beside the pairs: the Udacity layout
        shutil.copyfile(calibration_dir(sequence_dir) / name, folder / name)
    rows = []
    for lead in leads:
        image = read_image(frame_files(sequence_dir, lead.frame).image)
        for t in range(len(params.targets_s)):
            pair = make_pair(image, lead.points, lead.centre, lead.frame, t, params)
            keep = consistent_points(pair, calib, settings)
            scans = [scan[keep] for scan in pair.scans()]
            outliers = int(keep[len(pair.points_prev) :].sum())
            prev = 2 * len(rows)
            for index, img, pts in ((prev, pair.image_prev, scans[0]),
                                    (prev + 1, pair.image_curr, scans[1])):  # fmt: skip
                files = frame_files(folder, index)
                if not cv2.imwrite(str(files.image), img):
                    raise OSError(f"{files.image}: could not write the image")
                pts.astype("<f4").tofile(files.scan)
            rows.append({"prev_frame": prev, "frame": prev + 1, "source_frame": pair.source_frame,
                         "ttc_target": pair.ttc_target, "ttc_true": pair.ttc_true,
                         "ratio_true": pair.ratio_true, "outliers_injected": outliers})  # fmt: skip
    truth = pd.DataFrame(rows, columns=["prev_frame", "frame", *TRUTH_COLUMNS])
    truth.to_csv(folder / TRUTH_FILE, index=False, float_format="%.17g")
    return truth


def n_pairs(params: ScaleTruthParams) -> int:
    """The number of pairs of a generated recording: sources × targets."""
    return len(params.sources) * len(params.targets_s)


def recording_folder(sequence_dir: Path, params: ScaleTruthParams, cache_dir: Path) -> Path:
    """Where the recording of ``params`` is (or will be) written (nothing is computed)."""
    return Path(cache_dir) / GENERATOR / dataset_key(Path(sequence_dir), params)[:24]


def materialise(sequence_dir: Path, params: ScaleTruthParams, cache_dir: Path) -> Path:
    """The generated recording folder of ``params`` from the recording ``sequence_dir``,
    written (atomically) when missing; returns its path."""
    sequence_dir = Path(sequence_dir)
    folder = recording_folder(sequence_dir, params, cache_dir)
    if (folder / TRUTH_FILE).is_file():
        return folder
    folder.parent.mkdir(parents=True, exist_ok=True)
    with open(folder.parent / f".{folder.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one writer; the others wait and find it written
        if not (folder / TRUTH_FILE).is_file():
            _write_atomically(folder, sequence_dir, params, cache_dir)
    return folder


def _write_atomically(
    folder: Path, sequence_dir: Path, params: ScaleTruthParams, cache_dir: Path
) -> None:
    calib = load_calibration(sequence_dir)
    leads = source_leads(sequence_dir, params, StageCache(cache_dir), calib)
    tmp = Path(tempfile.mkdtemp(dir=folder.parent, prefix=f".{folder.name}."))
    try:
        write_recording(tmp / "rec", sequence_dir, params, leads, calib)
        os.chmod(tmp / "rec", 0o755)
        os.rename(tmp / "rec", folder)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def params_from_config(dataset: DictConfig) -> ScaleTruthParams:
    """The generator parameters of a ``dataset`` config with a ``generator`` node (its
    ``first`` / ``last`` are the source frames)."""
    node: dict[str, Any] = OmegaConf.to_container(dataset.generator, resolve=True)  # type: ignore
    node = {k: tuple(v) if isinstance(v, list) else v for k, v in node.items() if k != "name"}
    return ScaleTruthParams(first=int(dataset.first), last=int(dataset.last), **node)


def _cache_dir(cfg: DictConfig) -> Path:
    return paths.resolve(cfg.cache.dir) if "cache" in cfg else paths.default("cache")


def generated_frame_range(cfg: DictConfig, sequence_dir: Path) -> FrameRange:
    """The :class:`FrameRange` of a generated dataset: every frame of its recording folder in
    ``cfg.cache.dir`` (or the default cache), in disjoint pairs. Nothing is generated here
    (:func:`materialise_config` does it before a run)."""
    if cfg.dataset.generator.get("name", GENERATOR) != GENERATOR:
        raise ValueError(f"unknown dataset.generator.name {cfg.dataset.generator.name!r}")
    params = params_from_config(cfg.dataset)
    return FrameRange(
        sequence_dir=recording_folder(sequence_dir, params, _cache_dir(cfg)),
        first=0,
        last=2 * n_pairs(params) - 1,
        step=1,
        projection=cfg.dataset.projection,
        min_scan_points=int(cfg.dataset.min_scan_points),
        pairing="disjoint",
    )


def materialise_config(cfg: DictConfig, sequence_dir: Path) -> Path:
    """Write the recording of a generated dataset's config when missing; its folder."""
    return materialise(sequence_dir, params_from_config(cfg.dataset), _cache_dir(cfg))
