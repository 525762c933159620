"""Typed Hydra configuration: schemas for every config group, and config → core objects.

Every option YAML in ``conf/<group>/`` starts with ``defaults: [/schema/<group>/<x>@_here_]``,
so Hydra validates its keys and value types against the core's parameter dataclass: a typo
in a key (``detector.treshold=5``) or a wrong type fails when the config is composed, before
any job runs. The core's dataclasses are frozen; the schema nodes stored here are the same
classes made writable, so YAML files and overrides can set their fields.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import MISSING as MISSING_FIELD
from dataclasses import Field, dataclass, field, fields, make_dataclass
from pathlib import Path
from typing import Any, get_type_hints

from hydra.core.config_store import ConfigStore
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import MISSING, DictConfig, OmegaConf

from experiments.configs.identity import (  # noqa: F401 (also imported from here)
    NEUTRAL_OPTIONS,
    SETTING_KEYS,
    SUBPIXEL_SUFFIX,
    axis_values,
    finish_setting,
    run_id,
    run_identity,
    setting_config,
    setting_entry,
    setting_hash,
    with_neutral_axes,
    with_neutral_options,
)
from experiments.data import datasets
from experiments.host import paths
from ttc.features.descriptors import DESCRIPTORS, NO_DESCRIPTOR
from ttc.features.keypoints import DETECTORS
from ttc.features.learned_params import LEARNED_MATCHERS
from ttc.features.matching import MATCHER_PARAMS, NO_SELECTOR, TRACKERS, SelectorParams
from ttc.io.calibration import PROJECTIONS
from ttc.io.frames import recording_frames
from ttc.io.ros2_bag import BagSource
from ttc.settings import AXIS_TABLE, FrameRange, Settings
from ttc.steps.lidar import LaneCropParams
from ttc.steps.object_lidar import ObjectLidarParams

#: Config groups whose options each pick one parameter class by name (ttc.settings.AXIS_TABLE).
NAMED_GROUPS: dict[str, Mapping[str, type]] = {
    a.name: a.registry for a in AXIS_TABLE if a.registry is not None
}
#: Config groups with one parameter class for all their options.
SINGLE_CLASS_GROUPS: dict[str, type] = {
    a.name: a.params for a in AXIS_TABLE if a.params is not None and a.registry is None
}


@dataclass
class DatasetConfig:
    """A frame range of one recording under the data root (KITTI folders or a ROS 2 bag)."""

    name: str = MISSING
    root: str = MISSING  # data root (``$TTC_DATA_DIR`` or ../shared/data)
    sequence: str = "kitti/2011_09_26"
    first: int = 0
    last: int | None = 18  # None: the recording's last frame (experiments/data/datasets.py)
    step: int = 1
    projection: str = "P_rect_02"
    min_scan_points: int = 100_000
    date: str = ""  # kitti_raw: the KITTI date folder, e.g. 2011_09_26
    drive: str = ""  # kitti_raw: the drive number, e.g. 0052
    sequence_id: str = ""  # kitti_odometry: the sequence number, e.g. 04
    path: str = ""  # ros2_bag: the bag (.mcap or rosbag2 folder), absolute or under root
    image_topic: str = ""  # ros2_bag: "" = the bag's only Image / CompressedImage topic
    camera_info_topic: str = ""  # ros2_bag: "" = the bag's only CameraInfo topic
    lidar_topic: str = ""  # ros2_bag: "" = the bag's only PointCloud2 topic
    scan_tolerance_s: float | None = None  # ros2_bag: None = half the lidar's period
    camera_frame: str = "optical"  # ros2_bag: optical (ROS) or rectified (ttc.io.bag_recording)
    generator: Any = None  # a generated dataset's parameters (dataset=scale_truth), else None


@dataclass
class LidarConfig:
    """Lidar association: ego-lane crop (the lead), the shrink factor applied to boxes, and
    every object box's own points (``objects``)."""

    crop: LaneCropParams = field(default_factory=LaneCropParams)
    shrink: float = 0.10
    objects: ObjectLidarParams = field(default_factory=ObjectLidarParams)


@dataclass
class CacheConfig:
    """Stage cache location; ``enabled=false`` recomputes every stage (benchmarks)."""

    dir: str = MISSING
    enabled: bool = True


@dataclass
class ShowConfig:
    """Pictures of one frame / frame pair (``python -m experiments.tools.show``)."""

    frame: int = 1  # current frame; the previous is frame - dataset.step
    out_dir: str = "${results_root}/pictures"


@dataclass
class RunSettingsConfig:
    """The root of the configuration after its axes (``conf/config.yaml`` fills it)."""

    lidar: LidarConfig = field(default_factory=LidarConfig)
    cache: CacheConfig = field(default_factory=CacheConfig)
    show: ShowConfig = field(default_factory=ShowConfig)
    results_root: str = MISSING
    sweep_name: str = "adhoc"
    cv_threads: int = 1  # OpenCV threads per job; jobs already use every core
    force: bool = False  # recompute a run even when its record says complete
    print_rows: int = 20
    batch: str = ""  # set by the sweeper: this job runs the settings of <sweep>/.plan/<batch>.json


def _copy(f: Field) -> Field:
    """A new field with ``f``'s default (a field object belongs to one dataclass)."""
    if f.default_factory is not MISSING_FIELD:
        return field(default_factory=f.default_factory)
    return field(default=f.default)


#: The root of the configuration: one field per axis of ttc.settings.AXIS_TABLE (each a config
#: group: ``dataset`` typed, the others validated by their options' schemas), then the rest.
RunConfig = make_dataclass(
    "RunConfig",
    [
        (a.name, DatasetConfig, field(default_factory=DatasetConfig))
        if a.name == "dataset"
        else (a.name, Any, field(default=MISSING))
        for a in AXIS_TABLE
    ]
    + [
        (f.name, get_type_hints(RunSettingsConfig)[f.name], _copy(f))
        for f in fields(RunSettingsConfig)
    ],
)
RunConfig.__module__ = __name__  # pickled by reference, like a class written out


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


#: The ConfigStore instances holding the schemas: a command the warm server forks runs its
#: module again as ``__main__`` in a process that has them (storing them again: 0.08 s).
_STORED_IN: list[ConfigStore] = []


def register_configs() -> None:
    """Store the schemas in Hydra's ConfigStore (once per instance) and the ``ttc_path``
    resolver (default folders)."""
    if not OmegaConf.has_resolver("ttc_path"):
        OmegaConf.register_new_resolver("ttc_path", lambda kind: str(paths.default(kind)))
    datasets.register_resolvers()
    cs = ConfigStore.instance()
    if any(stored is cs for stored in _STORED_IN):
        return
    _STORED_IN.append(cs)
    cs.store(name="ttc_schema", node=_writable(RunConfig))
    for group, registry in NAMED_GROUPS.items():
        for name, schema in registry.items():
            cs.store(group=f"schema/{group}", name=name, node=_writable(schema))
    for group, schema in SINGLE_CLASS_GROUPS.items():
        cs.store(group="schema", name=group, node=_writable(schema))
    cs.store(group="schema", name="dataset", node=_writable(DatasetConfig))


def _to_object(node: DictConfig, schema: type) -> Any:
    return schema(**OmegaConf.to_container(node, resolve=True))


def _params(entry: dict[str, Any], schema: type) -> Any:
    """The core parameter object of one resolved config entry."""
    return schema(**entry)


def _tracking(matcher: dict[str, Any]) -> bool:
    """True for a tracking matcher (KLT): no descriptor, no selection."""
    return matcher["name"] in TRACKERS


def _descriptor(descriptor: dict[str, Any], matcher: dict[str, Any]) -> Any:
    """The descriptor's parameters (none for a tracking matcher)."""
    if _tracking(matcher):
        return NO_DESCRIPTOR
    return _params(descriptor, DESCRIPTORS[descriptor["name"]])


def _selector(selector: dict[str, Any], matcher: dict[str, Any]) -> Any:
    """The selector's parameters (none for a tracking matcher)."""
    if _tracking(matcher) or matcher["name"] in LEARNED_MATCHERS:  # LightGlue selects itself
        return NO_SELECTOR
    return _params(selector, SelectorParams)


def _single(group: str) -> tuple[tuple[str, ...], Any]:
    """The :data:`SETTINGS_FIELDS` entry of a group with one parameter class."""
    schema = SINGLE_CLASS_GROUPS[group]
    return (group,), lambda entry: _params(entry, schema)


#: Every field of the core's :class:`Settings`: the config entries it is made from (its
#: converter gets exactly those, resolved, and nothing else) and the converter, in the order
#: they are converted (the first bad value is the one reported).
SETTINGS_FIELDS: dict[str, tuple[tuple[str, ...], Any]] = {
    "matcher": (("matcher",), lambda m: _params(m, MATCHER_PARAMS[m["name"]])),
    "selector": (("selector", "matcher"), _selector),
    **{g: _single(g) for g in SINGLE_CLASS_GROUPS if g != "selector"},
    "descriptor": (("descriptor", "matcher"), _descriptor),
    "detector": (("detector",), lambda d: _params(d, DETECTORS[d["name"]])),
    "lane": (("lidar",), lambda lidar: _params(lidar["crop"], LaneCropParams)),
    "lidar_shrink": (("lidar",), lambda lidar: float(lidar["shrink"])),
    "object_lidar": (("lidar",), lambda lidar: _params(lidar["objects"], ObjectLidarParams)),
}


def settings_field(name: str, entries: dict[str, Any]) -> Any:
    """One field of the core's :class:`Settings` from the resolved config ``entries`` (a
    :func:`setting_config` or any dict holding the field's entries; raises ValueError on a
    bad value)."""
    sources, convert = SETTINGS_FIELDS[name]
    return convert(*(entries[key] for key in sources))


def settings_from_config(cfg: DictConfig) -> Settings:
    """The core's :class:`Settings` for a composed config (raises ValueError on bad values)."""
    keys = {key for sources, _ in SETTINGS_FIELDS.values() for key in sources}
    entries = {key: OmegaConf.to_container(cfg[key], resolve=True) for key in keys}
    return Settings(**{name: settings_field(name, entries) for name in SETTINGS_FIELDS})


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
    """The recording's folder: ``dataset.sequence`` under the data root (a bag: its path)."""
    return data_root(cfg) / cfg.dataset.sequence


def recording_source(cfg: DictConfig) -> Path | BagSource:
    """What the core reads the recording from: :func:`sequence_dir`, or for a ``ros2_bag``
    dataset its :class:`~ttc.io.ros2_bag.BagSource` (topics, tolerance, camera frame)."""
    ds = OmegaConf.to_container(cfg.dataset, resolve=True)
    return datasets.bag_source(ds, sequence_dir(cfg)) or sequence_dir(cfg)


def frame_range_from_config(cfg: DictConfig) -> FrameRange:
    """The core's :class:`FrameRange` for a composed config."""
    ds = cfg.dataset
    if ds.get("generator") is not None:  # generated pairs (experiments/data/scale_truth.py)
        from experiments.data.scale_truth import generated_frame_range

        return generated_frame_range(cfg, sequence_dir(cfg))
    recording = recording_source(cfg)
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
        from experiments.data.scale_truth import materialise_config

        materialise_config(cfg, sequence_dir(cfg))
    return frame_range_from_config(cfg)


def missing_data_message(cfg: DictConfig) -> str:
    """What to say when the configured recording folder does not exist."""
    recording = sequence_dir(cfg)
    if cfg.dataset.get("path"):
        return f"ROS 2 bag not found: {recording} (dataset.path={cfg.dataset.path})"
    if cfg.dataset.get("date"):
        return datasets.missing_drive_message(recording)
    if cfg.dataset.get("sequence_id"):
        return datasets.missing_odometry_message(recording)
    return (
        f"KITTI frames not found: {recording} does not exist.\n"
        "Point TTC_DATA_DIR (or dataset.root=...) at a folder holding "
        f"{cfg.dataset.sequence}/, or fetch the 78 frames with:\n"
        f"  python -m experiments.data.download --data-root {data_root(cfg)}"
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
    for key, schema in (("crop", LaneCropParams), ("objects", ObjectLidarParams)):
        try:
            _to_object(cfg.lidar[key], schema)
        except (ValueError, TypeError) as exc:
            problems.append(f"lidar.{key}: {exc}")
    ds = cfg.dataset
    bag = datasets.bag_problems(OmegaConf.to_container(ds, resolve=True), sequence_dir(cfg))
    if bag:  # a ros2_bag dataset that cannot be read: nothing below can be checked
        return problems + bag
    recording = recording_source(cfg)
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
    if bag is None and not recording.is_dir():
        return [missing_data_message(cfg)]
    present = recording_frames(recording)
    if not present:
        problems.append(f"{recording}: no frames found (image_02/data/NNNNNNNNNN.png)")
    elif last > present[-1]:
        problems.append(
            f"dataset.last={last} is past the recording's last frame: frames "
            f"{present[0]}–{present[-1]} exist in {recording}"
        )
    return problems + ([] if bag is not None else datasets.layout_problems(ds.date, recording))


def validate_config(cfg: DictConfig) -> None:
    """Raise ``ValueError`` listing :func:`config_problems` (the sweeper calls it)."""
    problems = config_problems(cfg)
    if problems:
        raise ValueError("invalid configuration:\n  " + "\n  ".join(problems))
