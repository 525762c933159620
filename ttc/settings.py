"""The vocabulary of a sweep: its axes, one setting, a frame range, the cached stages.

Every other list of axes in the project derives from :data:`AXIS_TABLE`: the fields of
:class:`Settings`, the results' axis columns (:data:`AXES`), the axes a batch of settings may
vary in (:func:`axes_with_role`), the run-identity options left out at their off value
(:data:`NEUTRAL_OPTIONS`), the config groups and their parameter classes, the axes that change
only one sensor's TTC (:func:`only_sensor_axes`), and the inputs of each cached stage
(:data:`CACHED_STAGES`). This module imports only the parameter dataclasses of the steps; it
is imported by everything above them (engine, evaluation, drawing, experiments).

================  ===============================================================
role              meaning
================  ===============================================================
``frame_stage``   a cached stage computed per frame (objects, keypoints, descriptors)
``pair_stage``    a cached stage computed per frame pair (the matcher's candidates)
``step``          an FP.1–FP.4 step, computed per pair from the cached stages
``fusion``        computed over a whole run's lead rows (FP.7)
``dataset``       the recording and frame range
================  ===============================================================
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ttc.features.descriptors import DESCRIPTORS
from ttc.features.keypoints import DETECTORS
from ttc.features.matching import MATCHER_PARAMS, MatcherParams, SelectorParams
from ttc.features.objects import ObjectDetectorParams
from ttc.io.frames import frame_indices, frame_interval, frame_pairs
from ttc.steps.box_matching import BoxMatchingParams
from ttc.steps.camera_ttc import CameraTTCParams
from ttc.steps.fusion import FusionParams
from ttc.steps.keypoint_filter import KeypointFilterParams
from ttc.steps.lidar import LaneCropParams
from ttc.steps.lidar_ttc import LidarTTCParams
from ttc.steps.object_lidar import ObjectLidarParams

ROLES = ("frame_stage", "pair_stage", "step", "fusion", "dataset")


@dataclass(frozen=True)
class Axis:
    """One axis of a sweep: a config group (``conf/<name>/``) and a field of :class:`Settings`.

    ``params`` is the parameter class of every option, or a registry (option name → class)
    when each option has its own. ``neutral`` lists ``(key, off value)`` options that leave
    a setting's numbers as they were before the option existed: at their off value they are
    left out of run ids and cache keys (a ``name`` key: the whole axis). ``only_sensor`` names
    the one TTC an axis changes (``lidar``, ``fused``), ``None`` when it changes several;
    ``doc``: what its results column holds.
    """

    name: str
    role: str
    params: type | Mapping[str, type] | None
    doc: str
    neutral: tuple[tuple[str, Any], ...] = ()
    only_sensor: str | None = None

    @property
    def registry(self) -> Mapping[str, type] | None:
        """Option name → parameter class, for an axis whose options have their own class."""
        return self.params if isinstance(self.params, Mapping) else None


#: The axes, in the order of the results' columns. The one table: settings, configs,
#: batches, run ids, metrics and reports derive their lists from it.
AXIS_TABLE: tuple[Axis, ...] = (
    Axis(
        "detector",
        "frame_stage",
        DETECTORS,
        "keypoint detector (+subpixel: refined keypoints)",
        neutral=(("subpixel", False),),
    ),
    Axis("descriptor", "frame_stage", DESCRIPTORS, "keypoint descriptor (none with matcher=klt)"),
    Axis("matcher", "pair_stage", MATCHER_PARAMS, "bf, flann, klt (tracking) or custom"),
    Axis("selector", "step", SelectorParams, "nn or knn (none with matcher=klt)"),
    Axis("box_matching", "step", BoxMatchingParams, "FP.1 strategy"),
    Axis("lidar_ttc", "step", LidarTTCParams, "FP.2 estimator", only_sensor="lidar"),
    Axis("keypoint_filter", "step", KeypointFilterParams, "FP.3 outlier filter"),
    Axis(
        "camera_ttc",
        "step",
        CameraTTCParams,
        "FP.4 estimator",
        neutral=(("min_box_fraction", 0.0), ("fit_method", "ransac"), ("fit_threshold", 1.0)),
    ),
    Axis(
        "fusion",
        "fusion",
        FusionParams,
        "FP.7 fusion: none, kalman_cv or kalman_ca",
        neutral=(("name", "none"),),
        only_sensor="fused",
    ),
    Axis(
        "objects",
        "frame_stage",
        ObjectDetectorParams,
        "object detector config",
        neutral=(("tiles", 1), ("tile_overlap", 0.2)),
    ),
    Axis(
        "dataset",
        "dataset",
        None,
        "dataset config (frame range)",
        neutral=(("date", ""), ("drive", ""), ("sequence_id", ""), ("generator", None)),
    ),
)
AXIS_BY_NAME: dict[str, Axis] = {a.name: a for a in AXIS_TABLE}

#: Every axis of a sweep, in the order of the results' columns: the stage axes, then the
#: dataset (the recording and frame range).
AXES: tuple[str, ...] = tuple(a.name for a in AXIS_TABLE)
#: The axes a :class:`Settings` picks a variant on (all but the dataset).
SETTING_AXES: tuple[str, ...] = tuple(a.name for a in AXIS_TABLE if a.role != "dataset")
#: ``(axis, key, off value)`` of every neutral option (see :class:`Axis`).
NEUTRAL_OPTIONS: tuple[tuple[str, str, Any], ...] = tuple(
    (a.name, key, off) for a in AXIS_TABLE for key, off in a.neutral
)


def axes_with_role(*roles: str) -> tuple[str, ...]:
    """The axes whose role is one of ``roles``, in table order."""
    unknown = set(roles) - set(ROLES)
    if unknown:
        raise ValueError(f"unknown axis role(s) {sorted(unknown)}; roles are {ROLES}")
    return tuple(a.name for a in AXIS_TABLE if a.role in roles)


def only_sensor_axes(sensor: str) -> tuple[str, ...]:
    """The axes that change only the ``sensor`` TTC (``lidar`` or ``fused``)."""
    return tuple(a.name for a in AXIS_TABLE if a.only_sensor == sensor)


def neutral_off(axis: str, key: str) -> Any:
    """The off value of neutral option ``key`` of ``axis`` (KeyError when it is none)."""
    return dict(AXIS_BY_NAME[axis].neutral)[key]


#: A cached stage: its time and cache-flag columns and the axes its key depends on besides
#: the frame (each stage's key chains the keys of the stages it is computed from).
@dataclass(frozen=True)
class CachedStage:
    name: str
    time_column: str
    axes: tuple[str, ...]

    @property
    def cached_column(self) -> str:
        return f"cached_{self.name}"


#: The cached stages in the order they are produced. The lidar stage (scan load + lane crop)
#: depends on no axis: it costs the same for every setting of a recording.
CACHED_STAGES: tuple[CachedStage, ...] = (
    CachedStage("objects", "ms_objects", ("objects",)),
    CachedStage("lidar", "ms_lidar", ()),
    CachedStage("keypoints", "ms_keypoints", ("detector",)),
    CachedStage("descriptors", "ms_descriptors", ("detector", "descriptor")),
    CachedStage("matches", "ms_matching", ("detector", "descriptor", "matcher")),
)
CACHED_STAGE_NAMES: tuple[str, ...] = tuple(s.name for s in CACHED_STAGES)

#: Field metadata of a :class:`Settings` field that is a sweep axis.
_AXIS = {"axis": True}


@dataclass(frozen=True)
class Settings:
    """One value of every axis of a sweep (each a params dataclass of its stage), plus the
    lidar association's lane crop and box shrink factor (fractions of the box), and which
    scan points can be an object box's own (:class:`ttc.steps.object_lidar.ObjectLidarParams`)."""

    detector: Any = field(metadata=_AXIS)
    descriptor: Any = field(metadata=_AXIS)
    matcher: MatcherParams = field(default_factory=MatcherParams, metadata=_AXIS)
    selector: SelectorParams = field(default_factory=SelectorParams, metadata=_AXIS)
    box_matching: BoxMatchingParams = field(default_factory=BoxMatchingParams, metadata=_AXIS)
    lidar_ttc: LidarTTCParams = field(default_factory=LidarTTCParams, metadata=_AXIS)
    keypoint_filter: KeypointFilterParams = field(
        default_factory=KeypointFilterParams, metadata=_AXIS
    )
    camera_ttc: CameraTTCParams = field(default_factory=CameraTTCParams, metadata=_AXIS)
    fusion: FusionParams = field(default_factory=FusionParams, metadata=_AXIS)
    objects: ObjectDetectorParams = field(default_factory=ObjectDetectorParams, metadata=_AXIS)
    lane: LaneCropParams = field(default_factory=LaneCropParams)
    lidar_shrink: float = 0.10
    object_lidar: ObjectLidarParams = field(default_factory=ObjectLidarParams)

    def axes(self) -> dict[str, str]:
        """The name chosen on every axis, e.g. ``{"detector": "fast", ...}``."""
        return {axis: getattr(self, axis).name for axis in SETTING_AXES}


def _check_table() -> None:
    """The table and :class:`Settings` name the same axes in the same order."""
    fields = tuple(f.name for f in dataclasses.fields(Settings) if f.metadata.get("axis"))
    if fields != SETTING_AXES:
        raise AssertionError(f"Settings axes {fields} differ from AXIS_TABLE {SETTING_AXES}")


_check_table()


@dataclass(frozen=True)
class FrameRange:
    """Frames ``first..last`` (every ``step``-th) of one recording folder."""

    sequence_dir: Path
    first: int = 0
    last: int = 18
    step: int = 1
    projection: str = "P_rect_02"
    min_scan_points: int = 100_000
    pairing: str = "consecutive"  # or "disjoint": pairs 0→1, 2→3, … (ttc.io.frames.frame_pairs)

    @property
    def pairs(self) -> list[tuple[int, int]]:
        """The (previous, current) frame pairs of the range."""
        return frame_pairs(self.indices, self.pairing)

    @property
    def indices(self) -> list[int]:
        return frame_indices(self.first, self.last, self.step)

    @property
    def dt(self) -> float:
        """Nominal seconds between two processed frames."""
        return frame_interval(self.step)
