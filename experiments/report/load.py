"""Reading sweeps for a report or a notebook: rows and run records of one or more sweep
folders, the data root and stage cache, the reference of their recording, and the
intermediate arrays of a run's frame pair (recomputed through the stage cache)."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml
from omegaconf import DictConfig, OmegaConf

from experiments import store
from experiments.configs.structured import (
    frame_range_from_config,
    settings_from_config,
    with_neutral_axes,
    with_neutral_options,
)
from experiments.data.first_run import ensure_setting_models
from experiments.host.heap import release_freed_memory
from experiments.host.paths import default_cache_dir, default_data_root, resolve
from experiments.report import judged_rows, kept_judged
from experiments.store.flat_configs import flatten_kept
from experiments.summary.references import recording_references, sequence_of
from ttc import evaluation as ev
from ttc.engine.cache import StageCache
from ttc.engine.runner import pair_detail
from ttc.features.model_files import uses_bundled_files
from ttc.features.objects import clear_detector_cache
from ttc.io.frames import read_image
from ttc.rows import PairDetail
from ttc.settings import FrameRange, Settings


@dataclass
class SweepData:
    """Rows and run records of one or more sweeps (run ids unique across them). ``frames``:
    the rows a report judges, each frame pair's lead row (else its first row) of every run,
    on the columns a report reads (:func:`~experiments.report.judged_rows.read_columns`, no
    ``cached_*``), with ``ms_compute_per_frame`` (:mod:`experiments.report.judged_rows`); ``boxes``:
    the matched box pairs of one run per camera setting and recording (the "every object"
    report), on :data:`~experiments.report.judged_rows.BOX_COLUMNS`; ``runs``: the run
    records but :data:`experiments.store.UNREAD_RECORD_FIELDS`."""

    dirs: list[Path]
    frames: pd.DataFrame
    runs: pd.DataFrame
    overrides: dict[str, list[str]] = field(default_factory=dict)
    repeated: int = 0  # runs of a later sweep already present in an earlier one (dropped)
    boxes: pd.DataFrame = field(default_factory=pd.DataFrame)


def read_sweep(sweep_dir: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``frames`` (every row, every column) and ``runs`` of a sweep, checked against its
    ``runs/`` folder and merged again when missing or stale (:func:`experiments.store.load_sweep`;
    its :class:`~experiments.store.StoreError` names a corrupt file). A report reads less
    (:func:`load_sweeps`)."""
    return store.load_sweep(Path(sweep_dir))


def sweep_overrides(sweep_dir: Path) -> list[str]:
    """The command-line overrides of a sweep (Hydra's ``multirun.yaml``), or []."""
    path = Path(sweep_dir) / "multirun.yaml"
    if not path.is_file():
        return []
    doc = yaml.safe_load(path.read_text()) or {}
    hydra = doc.get("hydra", {})
    task = list(hydra.get("overrides", {}).get("task", []) or [])
    params = hydra.get("sweeper", {}).get("params", {}) or {}
    return task + [f"{k}={v} (sweep)" for k, v in params.items()]


def load_sweeps(dirs: Iterable[Path | str]) -> SweepData:
    """Concatenate sweeps; a run id present in several sweeps is taken from the first. The
    judged rows get ``ms_compute_per_frame`` looked up over every row of all of them
    (:func:`ttc.evaluation.compute_times`, from the stage times counted). Bounded memory: the
    rows are read a fragment at a time and cut at once, to the judged rows, the box pairs of a
    few runs and the counts (:func:`experiments.report.judged_rows.cut_fragment`), each
    fragment's cut kept for the next report (:mod:`experiments.report.kept_judged`)."""
    dirs = [Path(d) for d in dirs]
    lead_parts, box_parts, counts, run_parts, overrides = [], [], [], [], {}
    seen: set[str] = set()
    repeated = 0
    for d in dirs:
        records = store.sweep_records(d)
        runs = store.runs_table(records, exclude=store.UNREAD_RECORD_FIELDS)
        release_freed_memory()  # the records listed: their pages back before the rows come
        if runs.empty:
            continue
        known = runs["run_id"].isin(seen)
        repeated += int(known.sum())
        # the configs as Python strings: each one's hash then computed once (the configs are
        # looked up by text many times: 0.08 s a lookup of 40,320 Arrow strings)
        runs = runs[~known].assign(sweep_dir=str(d.resolve()), config=runs["config"].astype(object))
        # every config flattened once (those an earlier report flattened read back): the
        # recordings, setting ids and headers below read them
        flatten_kept(d, runs["config"])
        lead, boxes, sweep_counts = kept_judged.read_judged(d, runs, records)
        if not lead.empty:
            lead_parts.append(lead)
            box_parts.append(boxes)
            counts.append(sweep_counts)
        run_parts.append(runs)
        seen |= set(runs["run_id"])
        overrides[d.name] = sweep_overrides(d)
    stacked = judged_rows.stacked
    frames, boxes, runs = stacked(lead_parts), stacked(box_parts), stacked(run_parts)
    frames, runs = with_neutral_axes(frames), with_neutral_axes(runs)  # axes added since
    if not frames.empty:  # a stage one sweep computed gives its time to runs of the others
        times = judged_rows.compute_times(frames, ev.join_counts(counts))
        frames["ms_compute_per_frame"] = times.to_numpy()
        frames = frames.drop(columns=[c for c in judged_rows.COUNTED_ONLY if c in frames])
    release_freed_memory()  # the fragments read and cut: their pages back to the system
    return SweepData(dirs, frames, runs, overrides, repeated, boxes)


def run_config(config_json: str, root: Path) -> DictConfig:
    """A run's stored setting config (runs.parquet ``config``) with the data root put back."""
    cfg = OmegaConf.create(with_neutral_options(json.loads(config_json)))
    cfg.dataset.root = str(root)
    return cfg


def setting_of_run(runs: pd.DataFrame, run_id: str, root: Path) -> tuple[Settings, FrameRange]:
    """The core :class:`Settings` and :class:`FrameRange` of a run of ``runs``."""
    config = runs.loc[runs["run_id"] == run_id, "config"].iloc[0]
    cfg = run_config(config, root)
    return settings_from_config(cfg), frame_range_from_config(cfg)


#: Pair details a :class:`Context` keeps (``grand`` 0–18's report asks for 71, each with its two images).
DETAILS_KEPT = 16
#: Images a :class:`Context` keeps (those of the details kept, at most: shared among them).
IMAGES_KEPT = 2 * DETAILS_KEPT


def _most_recent(kept: dict, key: Any, limit: int, make: Callable[[], Any]) -> Any:
    """``kept[key]``, made by ``make()`` when absent; ``kept`` holds the ``limit`` most
    recently used (its order: least recently used first)."""
    if key in kept:
        kept[key] = kept.pop(key)  # the most recently used last
        return kept[key]
    kept[key] = value = make()
    while len(kept) > limit:
        del kept[next(iter(kept))]
    return value


@dataclass
class Context:
    """What a report needs besides the sweep tables: data root, stage cache, pair details
    (``models_found``: the detectors whose files were looked for, and downloaded if missing)."""

    root: Path
    cache: StageCache
    details: dict[tuple[str, int, int], PairDetail] = field(default_factory=dict)
    calls: int = 0
    models_found: set[str] = field(default_factory=set)
    setups: dict[str, tuple[Settings, FrameRange]] = field(default_factory=dict)
    images: dict[Any, np.ndarray] = field(default_factory=dict)

    def detail(self, runs: pd.DataFrame, run_id: str, prev: int, curr: int) -> PairDetail:
        """:func:`~ttc.engine.runner.pair_detail` of a run's frame pair (memoised); the first
        one that needs a detector's files finds them as the sweep did
        (:meth:`detector_setup`). The :data:`DETAILS_KEPT` most
        recently used are kept (a report asks for a pair again soon after, if at all)."""
        return _most_recent(self.details, (run_id, prev, curr), DETAILS_KEPT,
                            lambda: self._new_detail(runs, run_id, prev, curr))  # fmt: skip

    def _new_detail(self, runs: pd.DataFrame, run_id: str, prev: int, curr: int) -> PairDetail:
        """:meth:`detail` when it is not kept: the detector's files found first if needed."""
        settings, frames = self.detector_setup(runs, run_id)
        detail = pair_detail(settings, frames, prev, curr, self.cache, self.image)
        self.calls += 1
        return detail

    def image(self, ref: Any) -> np.ndarray:
        """A frame's image (:func:`ttc.io.frames.read_image` of its file or bag message),
        read once for every pair detail that shows it (``grand`` 0–18's report: 162 images of
        19 frames, 0.9 s) and read-only; the :data:`IMAGES_KEPT` most recently used kept."""

        def read() -> np.ndarray:
            image = read_image(ref)
            image.flags.writeable = False  # shared by the details: drawn on copies only
            return image

        return _most_recent(self.images, ref, IMAGES_KEPT, read)

    def drop_details(self) -> None:
        """Forget the pair details and images kept (FP.5 and FP.6 ask for them; a report's
        later sections do not: ``grand`` 0–18's 16 kept held 43 MB through the "every object"
        report) and the object detectors' networks a detail may have loaded (an empty stage
        cache: YOLOv3-tiny, ≈ 0.2 GB, read again if a later step detects)."""
        self.details.clear()
        self.images.clear()
        clear_detector_cache()

    def setup(self, runs: pd.DataFrame, run_id: str) -> tuple[Settings, FrameRange]:
        """:func:`setting_of_run` of a run of ``runs`` (memoised by run id: unique across a
        report's sweeps; its config is parsed once, not for each pair detail and lookup)."""
        if run_id not in self.setups:
            self.setups[run_id] = setting_of_run(runs, run_id, self.root)
        return self.setups[run_id]

    def detector_setup(self, runs: pd.DataFrame, run_id: str) -> tuple[Settings, FrameRange]:
        """:meth:`setup` of a run whose boxes may be detected here: its detector's files
        found first, once per detector (:func:`experiments.data.first_run.ensure_setting_models`:
        downloaded when missing; YOLOv3-tiny, SSD-MobileNetV2)."""
        settings, frames = self.setup(runs, run_id)
        if settings.objects.name not in self.models_found and uses_bundled_files(settings.objects):
            ensure_setting_models(settings.objects)
            self.models_found.add(settings.objects.name)
        return settings, frames

    def settings(self, runs: pd.DataFrame, run_id: str) -> Settings:
        """The core settings of a run of ``runs``."""
        return self.setup(runs, run_id)[0]


def make_context(data_dir: Path | None = None, cache_dir: Path | None = None) -> Context:
    """A :class:`Context` with the given or default data root and cache folder."""
    root = Path(data_dir) if data_dir else default_data_root()
    cache = StageCache(cache_dir if cache_dir else default_cache_dir())
    return Context(root, cache)


def reference_for(data: SweepData, ctx: Context) -> pd.DataFrame:
    """The reference of the sweeps' recording (kept in the stage cache); a generated
    recording's exact truth (:func:`ttc.evaluation.truth_reference`) when the rows carry one."""
    sequence_of(data.runs)  # one recording, else a ValueError naming them
    references = recording_references(data.frames, data.runs, ctx.root, ctx.cache)
    return next(iter(references.values()))


def open_sweep(sweep_dir: Path | str) -> tuple[SweepData, Context, pd.DataFrame]:
    """A sweep folder (relative paths from the checkout root, else the working directory) as the notebooks use it: its
    data, the default context and its reference."""
    sweep_dir = resolve(sweep_dir)
    data = load_sweeps([sweep_dir])
    ctx = make_context()
    return data, ctx, reference_for(data, ctx)
