"""Typed Hydra configuration: schemas for every config group, and config → core objects.

Every option YAML in ``conf/<group>/`` starts with ``defaults: [/schema/<group>/<x>@_here_]``,
so Hydra validates its keys and value types against the core's parameter dataclass: a typo
in a key (``detector.treshold=5``) or a wrong type fails when the config is composed, before
any job runs. The core's dataclasses are frozen; the schema nodes stored here are the same
classes made writable, so YAML files and overrides can set their fields.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
from hydra.core.config_store import ConfigStore
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import MISSING, DictConfig, OmegaConf

from experiments import datasets, paths
from ttc.box_matching import BoxMatchingParams
from ttc.camera_ttc import CameraTTCParams
from ttc.descriptors import DESCRIPTORS, NO_DESCRIPTOR
from ttc.frames import PROJECTIONS, recording_frames
from ttc.fusion import FusionParams
from ttc.keypoint_filter import KeypointFilterParams
from ttc.keypoints import DETECTORS
from ttc.lidar import LaneCropParams
from ttc.lidar_ttc import LidarTTCParams
from ttc.matching import MATCHER_PARAMS, NO_SELECTOR, TRACKERS, SelectorParams
from ttc.objects import ObjectDetectorParams
from ttc.pipeline import AXES, FrameRange, Settings

#: Config groups whose options each pick one parameter class by name.
NAMED_GROUPS: dict[str, dict[str, type]] = {
    "detector": DETECTORS,
    "descriptor": DESCRIPTORS,
    "matcher": MATCHER_PARAMS,
}
#: Config groups with one parameter class for all their options.
SINGLE_CLASS_GROUPS: dict[str, type] = {
    "selector": SelectorParams,
    "box_matching": BoxMatchingParams,
    "lidar_ttc": LidarTTCParams,
    "keypoint_filter": KeypointFilterParams,
    "camera_ttc": CameraTTCParams,
    "fusion": FusionParams,
    "objects": ObjectDetectorParams,
}


@dataclass
class DatasetConfig:
    """A frame range of one KITTI-raw recording under the data root."""

    name: str = MISSING
    root: str = MISSING  # data root (``$TTC_DATA_DIR`` or ../shared/data)
    sequence: str = "kitti/2011_09_26"
    first: int = 0
    last: int | None = 18  # None: the recording's last frame (experiments/datasets.py)
    step: int = 1
    projection: str = "P_rect_02"
    min_scan_points: int = 100_000
    date: str = ""  # kitti_raw: the KITTI date folder, e.g. 2011_09_26
    drive: str = ""  # kitti_raw: the drive number, e.g. 0052
    sequence_id: str = ""  # kitti_odometry: the sequence number, e.g. 04
    generator: Any = None  # a generated dataset's parameters (dataset=scale_truth), else None


@dataclass
class LidarConfig:
    """Lidar association: ego-lane crop and the shrink factor applied to boxes."""

    crop: LaneCropParams = field(default_factory=LaneCropParams)
    shrink: float = 0.10


@dataclass
class CacheConfig:
    """Stage cache location; ``enabled=false`` recomputes every stage (benchmarks)."""

    dir: str = MISSING
    enabled: bool = True


@dataclass
class ShowConfig:
    """Pictures of one frame / frame pair (``python -m experiments.show``)."""

    frame: int = 1  # current frame; the previous is frame - dataset.step
    out_dir: str = "${results_root}/pictures"


@dataclass
class RunConfig:
    """The root of the configuration (``conf/config.yaml`` fills it)."""

    detector: Any = MISSING
    descriptor: Any = MISSING
    matcher: Any = MISSING
    selector: Any = MISSING
    box_matching: Any = MISSING
    lidar_ttc: Any = MISSING
    keypoint_filter: Any = MISSING
    camera_ttc: Any = MISSING
    fusion: Any = MISSING
    objects: Any = MISSING
    dataset: DatasetConfig = field(default_factory=DatasetConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    cache: CacheConfig = field(default_factory=CacheConfig)
    show: ShowConfig = field(default_factory=ShowConfig)
    results_root: str = MISSING
    sweep_name: str = "adhoc"
    cv_threads: int = 1  # OpenCV threads per job; jobs already use every core
    force: bool = False  # recompute a run even when its record says complete
    print_rows: int = 20
    batch: str = ""  # set by the sweeper: this job runs the settings of <sweep>/.plan/<batch>.json


def _writable(schema: type) -> DictConfig:
    """A structured-config node of ``schema`` whose fields may be set (frozen or not)."""
    node = OmegaConf.structured(schema)

    def unfreeze(cfg: DictConfig) -> None:
        OmegaConf.set_readonly(cfg, False)
        for key in cfg:
            child = cfg._get_node(key)
            if isinstance(child, DictConfig):
                unfreeze(child)

    unfreeze(node)
    return node


def register_configs() -> None:
    """Store the schemas in Hydra's ConfigStore and the ``ttc_path`` resolver (default folders)."""
    if not OmegaConf.has_resolver("ttc_path"):
        OmegaConf.register_new_resolver("ttc_path", lambda kind: str(paths.default(kind)))
    datasets.register_resolvers()
    cs = ConfigStore.instance()
    cs.store(name="ttc_schema", node=_writable(RunConfig))
    for group, registry in NAMED_GROUPS.items():
        for name, schema in registry.items():
            cs.store(group=f"schema/{group}", name=name, node=_writable(schema))
    for group, schema in SINGLE_CLASS_GROUPS.items():
        cs.store(group="schema", name=group, node=_writable(schema))
    cs.store(group="schema", name="dataset", node=_writable(DatasetConfig))


def _to_object(node: DictConfig, schema: type) -> Any:
    return schema(**OmegaConf.to_container(node, resolve=True))


def settings_from_config(cfg: DictConfig) -> Settings:
    """The core's :class:`Settings` for a composed config (raises ValueError on bad values)."""
    matcher = _to_object(cfg.matcher, MATCHER_PARAMS[cfg.matcher.name])
    tracking = matcher.name in TRACKERS  # KLT uses no descriptor and selects nothing
    objects = {
        g: NO_SELECTOR if tracking and g == "selector" else _to_object(cfg[g], schema)
        for g, schema in SINGLE_CLASS_GROUPS.items()
    }
    if tracking:
        descriptor = NO_DESCRIPTOR
    else:
        descriptor = _to_object(cfg.descriptor, DESCRIPTORS[cfg.descriptor.name])
    return Settings(
        detector=_to_object(cfg.detector, DETECTORS[cfg.detector.name]),
        descriptor=descriptor,
        matcher=matcher,
        **objects,
        lane=_to_object(cfg.lidar.crop, LaneCropParams),
        lidar_shrink=float(cfg.lidar.shrink),
    )


def data_root(cfg: DictConfig) -> Path:
    """The dataset's data root, resolved against the project root when relative."""
    return paths.resolve(cfg.dataset.root)


def swept_overrides(config: DictConfig) -> dict[str, Any]:
    """The sweep overrides of a multirun's master ``config``, by key element: the sweeper's
    ``params``, then the command line's; the last override of a key wins (a plain value ends
    its sweep). Values are Hydra ``Override`` objects."""
    params = config.hydra.sweeper.get("params") or {}
    args = [f"{k}={v}" for k, v in params.items()] + list(config.hydra.overrides.task)
    swept: dict[str, Any] = {}
    for override in OverridesParser.create().parse_overrides(args):
        swept.pop(override.get_key_element(), None)
        if override.is_sweep_override():
            swept[override.get_key_element()] = override
    return swept


def sequence_dir(cfg: DictConfig) -> Path:
    """The recording's folder: ``dataset.sequence`` under the data root."""
    return data_root(cfg) / cfg.dataset.sequence


def frame_range_from_config(cfg: DictConfig) -> FrameRange:
    """The core's :class:`FrameRange` for a composed config."""
    ds = cfg.dataset
    if ds.get("generator") is not None:  # generated pairs (experiments/scale_truth.py)
        from experiments.scale_truth import generated_frame_range

        return generated_frame_range(cfg, sequence_dir(cfg))
    recording = sequence_dir(cfg)
    return FrameRange(
        sequence_dir=recording,
        first=ds.first,
        last=datasets.frame_range_last(ds.last, recording),
        step=ds.step,
        projection=ds.projection,
        min_scan_points=ds.min_scan_points,
    )


def prepared_frame_range(cfg: DictConfig) -> FrameRange:
    """:func:`frame_range_from_config`, a generated dataset's recording written first when
    missing (``dataset=scale_truth``): what a run reads."""
    if cfg.dataset.get("generator") is not None:
        from experiments.scale_truth import materialise_config

        materialise_config(cfg, sequence_dir(cfg))
    return frame_range_from_config(cfg)


def setting_config(cfg: DictConfig) -> dict[str, Any]:
    """The part of the config that determines the numbers (no paths, no launcher)."""
    setting = {key: OmegaConf.to_container(cfg[key], resolve=True) for key in (*AXES, "lidar")}
    setting["dataset"] = {k: v for k, v in setting["dataset"].items() if k != "root"}
    setting["dataset"] = datasets.dataset_identity(setting["dataset"], sequence_dir(cfg))
    if setting["matcher"]["name"] in TRACKERS:  # no descriptor, no selection: one run id
        setting["descriptor"] = {"name": NO_DESCRIPTOR.name}
        setting["selector"] = {"name": NO_SELECTOR.name}
    return setting


def axis_values(setting: dict[str, Any]) -> dict[str, str]:
    """The value recorded on every axis of a :func:`setting_config`: the option's name
    (``none`` for the descriptor and selector of ``matcher=klt``), the detector's with
    ``+subpixel`` when its keypoints are refined, so reports tell the two apart."""
    values = {axis: str(setting[axis]["name"]) for axis in AXES}
    if setting["detector"].get("subpixel"):
        values["detector"] += SUBPIXEL_SUFFIX
    return values


#: Appended to the recorded detector name of a setting with ``detector.subpixel=true``.
SUBPIXEL_SUFFIX = "+subpixel"

#: Options that leave a setting's numbers as they were before the option existed, at their
#: "off" value: left out of the run id, so the ids of settings stored before stay the same.
NEUTRAL_OPTIONS: tuple[tuple[str, str, Any], ...] = (
    ("detector", "subpixel", False),
    ("fusion", "name", "none"),
    ("dataset", "date", ""),
    ("dataset", "drive", ""),
    ("dataset", "sequence_id", ""),
    ("dataset", "generator", None),
)


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
    its off value where a row was recorded before the axis existed."""
    out = table.copy()
    for axis, key, off in NEUTRAL_OPTIONS:
        if key == "name" and not out.empty:
            out[axis] = out[axis].fillna(off) if axis in out else off
    return out


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


def setting_hash(setting: dict[str, Any]) -> str:
    """The run id of a :func:`setting_config` (16 hex digits of the SHA-256 of its
    :func:`run_identity`'s canonical JSON)."""
    text = json.dumps(run_identity(setting), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def run_id(cfg: DictConfig) -> str:
    """Hash of :func:`setting_config`: equal configs give equal ids, across machines."""
    return setting_hash(setting_config(cfg))


def missing_data_message(cfg: DictConfig) -> str:
    """What to say when the configured recording folder does not exist."""
    recording = sequence_dir(cfg)
    if cfg.dataset.get("date"):
        return datasets.missing_drive_message(recording)
    if cfg.dataset.get("sequence_id"):
        return datasets.missing_odometry_message(recording)
    return (
        f"KITTI frames not found: {recording} does not exist.\n"
        "Point TTC_DATA_DIR (or dataset.root=...) at a folder holding "
        f"{cfg.dataset.sequence}/, or fetch the 78 frames with:\n"
        f"  python -m experiments.download --data-root {data_root(cfg)}"
    )


def config_problems(cfg: DictConfig) -> list[str]:
    """What is wrong with a composed config's values, in words (empty: nothing).

    Checks what key and type validation cannot: every stage's parameter ranges (the core
    dataclasses' own checks), the frame range (``first >= 0``, ``step >= 1``, at least two
    frames), and that the recording exists and holds the range's last frame.
    """
    problems = []
    schemas = {
        "detector": DETECTORS.get(cfg.detector.name),
        "descriptor": DESCRIPTORS.get(cfg.descriptor.name),
        **SINGLE_CLASS_GROUPS,
    }
    for group, schema in schemas.items():
        try:
            _to_object(cfg[group], schema)
        except (ValueError, TypeError) as exc:
            problems.append(f"{group}: {exc}")
    try:
        _to_object(cfg.lidar.crop, LaneCropParams)
    except (ValueError, TypeError) as exc:
        problems.append(f"lidar.crop: {exc}")
    ds = cfg.dataset
    recording = sequence_dir(cfg)
    first, step = int(ds.first), int(ds.step)
    last = datasets.resolved_last(ds.last, recording)
    if last is None:  # a whole drive that has no frames: said below
        last = first + step
    if first < 0:
        problems.append(f"dataset.first={first} must be >= 0")
    if step < 1:
        problems.append(f"dataset.step={step} must be >= 1")
    elif last < first + step:
        problems.append(
            f"dataset.last={last} must be >= dataset.first + dataset.step = {first + step} "
            "(a frame range needs at least two frames)"
        )
    if int(ds.min_scan_points) < 0:
        problems.append(f"dataset.min_scan_points={ds.min_scan_points} must be >= 0")
    if ds.projection not in PROJECTIONS:
        problems.append(f"dataset.projection={ds.projection} must be one of {PROJECTIONS}")
    if problems:
        return problems
    if not recording.is_dir():
        return [missing_data_message(cfg)]
    present = recording_frames(recording)
    if not present:
        problems.append(f"{recording}: no frames found (image_02/data/NNNNNNNNNN.png)")
    elif last > present[-1]:
        problems.append(
            f"dataset.last={last} is past the recording's last frame: frames "
            f"{present[0]}–{present[-1]} exist in {recording}"
        )
    return problems + datasets.layout_problems(ds.date, recording)


def validate_config(cfg: DictConfig) -> None:
    """Raise ``ValueError`` listing :func:`config_problems` (the sweeper calls it)."""
    problems = config_problems(cfg)
    if problems:
        raise ValueError("invalid configuration:\n  " + "\n  ".join(problems))
