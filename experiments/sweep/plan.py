"""The sweep plan, made by the sweeper before any worker starts.

For every job of a sweep it finds the setting and its run id without composing the job's
config with Hydra (:class:`experiments.sweep.compose.Composer`), then:

1. drops settings whose run is complete (resume before launch; ``force=true`` keeps them);
2. finds the settings of an invalid detector × descriptor pair, checking each pair once; their
   ``skipped`` records are written while the jobs run (:attr:`Plan.deferred`: 1,120 of a
   ``grand`` re-run's 6,720 settings, 0.23 s the workers waited for);
3. groups the rest into batches of settings that share their expensive stages (same
   detector, descriptor, objects, lane crop and frames; :data:`BATCH_FREE_AXES` vary within
   a batch), at most :data:`MAX_BATCH` settings each, and writes each batch's settings to
   ``<sweep>/.plan/<batch id>.json``.

A batch of one setting is launched as that setting's own job (exactly as without batches);
a larger one as one job with ``batch=<batch id>`` (:mod:`experiments.sweep.batch` runs it).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from experiments import store
from experiments.configs.identity import setting_hash, value_text
from experiments.store import progress
from experiments.store.records import now, peak_rss_mb, record_head
from experiments.sweep.compose import Composer
from experiments.sweep.finished import plan_line
from ttc.features.matching import check_features
from ttc.settings import axes_with_role

PLAN_DIR = ".plan"
#: Axes whose values share the cached stages: settings differing only in these form a batch.
BATCH_FREE_AXES = axes_with_role("pair_stage", "step", "fusion")
#: Most settings in one batch (bounds a worker's memory: a batch's rows are held until saved).
MAX_BATCH = 200


@dataclass
class Plan:
    """What the sweeper launches and what it did not have to."""

    jobs: list[list[str]] = field(default_factory=list)
    settings: int = 0  # distinct settings of the sweep
    complete: int = 0  # complete before launch (not launched)
    invalid: int = 0  # invalid detector x descriptor pair: recorded as skipped here
    to_compute: int = 0  # settings in the launched jobs
    batches: int = 0  # launched jobs of more than one setting
    run_ids: list[str] = field(default_factory=list)  # of every setting of the sweep
    #: Work left for while the jobs run (:func:`experiments.sweep.sweeper.SweepSweeper`
    #: calls it, before the sweep ends): writing the invalid settings' skipped records.
    deferred: Callable[[], None] | None = None

    def summary(self) -> str:
        """The plan in one line."""
        return plan_line(
            self.settings, self.complete, self.invalid, self.to_compute, len(self.jobs),
            self.batches,
        )  # fmt: skip


#: Rough ms per frame of a detector's / descriptor's stage on KITTI (docs/benchmarks.md, per-stage
#: benchmarks): jobs are launched most expensive first, so no long job starts last.
STAGE_MS = {"detector": {"sift": 102, "akaze": 73, "brisk": 64, "harris": 18, "orb": 11,
                         "shitomasi": 10, "fast": 1.4},
            "descriptor": {"sift": 106, "akaze": 91, "brisk": 52, "freak": 36, "orb": 10,
                           "brief": 8}}  # fmt: skip


def expected_cost(setting: dict[str, Any]) -> float:
    """A setting's expected stage time per frame (ms; 50 for a feature not in
    :data:`STAGE_MS`): the launch order of the batches."""
    return sum(
        STAGE_MS[axis].get(str(setting.get(axis, {}).get("name")), 50.0) for axis in STAGE_MS
    )


def batch_key(
    setting: dict[str, Any], memo: dict[int, tuple[Any, str]]
) -> tuple[tuple[str, str], ...]:
    """What the settings of one batch have in common (all but :data:`BATCH_FREE_AXES`): each
    entry's JSON, kept in ``memo`` by object (:func:`experiments.configs.identity.value_text`: a
    sweep's settings share their entries; 6,720 settings dumped whole took 0.13 s)."""
    return tuple(
        (k, value_text(setting[k], memo)) for k in sorted(setting) if k not in BATCH_FREE_AXES
    )


def plan_path(sweep_dir: Path, batch_id: str) -> Path:
    """The plan file of a batch."""
    return Path(sweep_dir) / PLAN_DIR / f"{batch_id}.json"


def read_plan(sweep_dir: Path, batch_id: str) -> dict[str, Any]:
    """A batch's plan: ``{"batch_id", "members": [{"run_id", "overrides", "setting"}]}``
    (stored as :func:`_plan_file` writes it)."""
    plan = json.loads(plan_path(sweep_dir, batch_id).read_text())
    shared = plan.pop("shared")
    for member in plan["members"]:
        member["setting"] = {**shared, **member.pop("own")}
    return plan


def _plan_file(batch_id: str, batch: list[dict[str, Any]]) -> dict[str, Any]:
    """What a batch's plan file holds: the entries every member's setting has (all but
    :data:`BATCH_FREE_AXES`: equal in a batch, :func:`batch_key`) once, as ``shared``, and
    each member's others as its ``own``: a ``grand`` batch's file 449 → 157 kB, written in
    1.3 instead of 5.9 ms and read back by the worker in 1.4 instead of 3.0 ms."""
    first = batch[0]["setting"]
    shared = {k: v for k, v in first.items() if k not in BATCH_FREE_AXES}
    members = [
        {"run_id": m["run_id"], "overrides": m["overrides"],
         "own": {k: v for k, v in m["setting"].items() if k not in shared}}
        for m in batch
    ]  # fmt: skip
    return {"batch_id": batch_id, "shared": shared, "members": members}


def make_plan(
    jobs: Sequence[Sequence[str]],
    composer: Composer,
    config: DictConfig,
    sweep_dir: Path,
    max_batch: int = MAX_BATCH,
) -> Plan:
    """Plan the jobs of a sweep (see the module docstring; ``max_batch=1``: one setting per
    job); writes the batches' plan files and leaves the skipped records of invalid pairs and
    their progress markers to :attr:`Plan.deferred`."""
    plan = Plan()
    members: dict[str, dict[str, Any]] = {}
    texts: dict[int, tuple[Any, str]] = {}  # the JSON of the settings' shared values
    for overrides in jobs:
        setting = composer.setting(overrides)
        rid = setting_hash(setting, texts)
        members.setdefault(rid, {"run_id": rid, "overrides": list(overrides), "setting": setting})
    plan.settings = len(members)
    checks, force = store.Checks(), bool(config.force)
    runs_dir = Path(sweep_dir) / store.RUNS_DIR
    recorded = set(os.listdir(runs_dir)) if runs_dir.is_dir() else set()
    todo = []
    for member in members.values():
        rid = member["run_id"]
        if (
            not force
            and f"{rid}.json" in recorded
            and store.incomplete_reason(sweep_dir, rid, checks) is None
        ):
            plan.complete += 1
        else:
            todo.append(member)
    if plan.complete:
        progress.mark_progress(sweep_dir, "complete-before-launch", ["resumed"] * plan.complete)
    todo = _drop_invalid(todo, sweep_dir, config, plan)
    groups: dict[tuple[tuple[str, str], ...], list[dict[str, Any]]] = {}
    for member in todo:
        groups.setdefault(batch_key(member["setting"], texts), []).append(member)
    for group in sorted(groups.values(), key=lambda g: -expected_cost(g[0]["setting"])):
        for start in range(0, len(group), max_batch):
            plan.jobs.append(_job(group[start : start + max_batch], sweep_dir, plan))
    plan.to_compute = len(todo)
    plan.run_ids = list(members)
    return plan


def records_missing(sweep_dir: Path, jobs: Sequence[Sequence[str]]) -> bool:
    """True when the sweep folder holds fewer run records than there are ``jobs``: some
    setting certainly has none, so the sweep will compute (the sweeper then starts the
    workers while it plans; a sweep that may be complete starts none)."""
    runs_dir = Path(sweep_dir) / store.RUNS_DIR
    if not runs_dir.is_dir():
        return True
    with os.scandir(runs_dir) as entries:
        return sum(e.name.endswith(".json") for e in entries) < len(jobs)


def first_record_missing(
    sweep_dir: Path, composer: Composer, jobs: Sequence[Sequence[str]]
) -> bool:
    """True when the first job's setting has no run record in the sweep folder: the sweep
    will compute. A folder holding as many records as the sweep has jobs (a sweep re-run with
    one axis changed) says nothing by their count; its first setting's run id does (its
    composition is the composer's template, which validation composes anyway). False when
    it cannot be told (the composition fails: validation says why)."""
    if not jobs:
        return False
    try:
        run_id = setting_hash(composer.setting(jobs[0]))
    except Exception:  # noqa: BLE001 (validation reports the same problem)
        return False
    return not store.run_paths(sweep_dir, run_id)[1].exists()


def _job(batch: list[dict[str, Any]], sweep_dir: Path, plan: Plan) -> list[str]:
    """The overrides of the job computing ``batch`` (writes its plan file when > 1)."""
    if len(batch) == 1:
        return list(batch[0]["overrides"])
    ids = sorted(m["run_id"] for m in batch)
    batch_id = "batch-" + hashlib.sha256(" ".join(ids).encode()).hexdigest()[:16]
    path = plan_path(sweep_dir, batch_id)
    path.parent.mkdir(parents=True, exist_ok=True)
    store.write_json_atomic(_plan_file(batch_id, batch), path, indent=None)
    plan.batches += 1
    return [*batch[0]["overrides"], f"batch={batch_id}"]


def _drop_invalid(
    todo: list[dict[str, Any]], sweep_dir: Path, config: DictConfig, plan: Plan
) -> list[dict[str, Any]]:
    """``todo`` without the settings of invalid detector × descriptor × matcher combinations
    (:func:`ttc.features.matching.check_features`, each combination checked once); writing
    their ``skipped`` records is left to ``plan.deferred``."""
    verdicts: dict[tuple[str, ...], str | None] = {}
    keep, skipped = [], []
    for member in todo:
        s = member["setting"]
        pair = (s["detector"]["name"], s["descriptor"]["name"], s["matcher"]["name"],
                s["detector"].get("variant", "n16"))  # fmt: skip
        if pair not in verdicts:
            try:
                check_features(*pair)
                verdicts[pair] = None
            except ValueError as exc:  # InvalidCombinationError
                verdicts[pair] = str(exc)
        if verdicts[pair] is None:
            keep.append(member)
        else:
            skipped.append((s, verdicts[pair]))
    plan.invalid = len(skipped)
    if skipped:
        cache_enabled, peak = bool(config.cache.enabled), peak_rss_mb()
        plan.deferred = lambda: write_skipped(sweep_dir, skipped, cache_enabled, peak)
    return keep


def write_skipped(
    sweep_dir: Path, skipped: list[tuple[dict[str, Any], str]], cache_enabled: bool, peak: float
) -> None:
    """Write the ``skipped`` record of each (setting, reason) of ``skipped``, an index file
    of them (the summary parses none of them) and their progress marker; ``peak``: the
    planning process's peak RSS (MB) when they were found."""
    name = Path(sweep_dir).name
    records = []
    for setting, reason in skipped:
        record = record_head(setting, name, cache_enabled)
        record.update(status="skipped", message=reason, end=now(), wall_s=0.0,
                      peak_rss_mb=peak, n_rows=0, skipped_at="plan")  # fmt: skip
        records.append(record)
    entries: dict[str, Any] = {}
    with ThreadPoolExecutor(max_workers=8) as pool:  # file system calls, in parallel
        for entry in pool.map(lambda r: store.write_record(sweep_dir, r), records):
            entries.update(entry)
    store.keep_index(sweep_dir, entries)
    progress.mark_progress(sweep_dir, "invalid-pairs", ["skipped"] * len(records))


# -- the plan of a finished sweep, remembered -----------------------------------------------
def plan_key(jobs: Sequence[Sequence[str]], config: DictConfig) -> str:
    """A digest of everything a sweep's run ids depend on: the jobs' overrides, the sweep's
    config (task part, as composed), every config file of its config sources (path, size,
    mtime), the source files of the project's Python packages (the schemas and parameter
    classes fill in defaults) and the Hydra and OmegaConf versions."""
    from importlib import metadata  # noqa: PLC0415

    from experiments.host.provenance import source_identities  # noqa: PLC0415

    task = {k: v for k, v in OmegaConf.to_container(config, resolve=False).items()
            if k != "hydra"}  # fmt: skip
    extra = tuple(
        Path(str(source.path)[len("file://") :])
        for source in config.hydra.runtime.config_sources
        if source.provider != "hydra" and str(source.path).startswith("file://")
    )
    files = source_identities(extra)
    versions = [metadata.version(p) for p in ("hydra-core", "omegaconf")]
    digest = hashlib.sha256()
    for part in (task, [list(j) for j in jobs], files, versions):
        digest.update(json.dumps(part, sort_keys=True, default=str).encode())
    return digest.hexdigest()[:24]


def _index_path(sweep_dir: Path, key: str) -> Path:
    return Path(sweep_dir) / PLAN_DIR / f"index-{key}.json"


def remember_run_ids(sweep_dir: Path, key: str, run_ids: list[str]) -> None:
    """Store the run ids of a planned sweep (validated: only a sweep that passed validation
    is planned) under its :func:`plan_key`."""
    store.write_json_atomic(run_ids, _index_path(sweep_dir, key), indent=None)


def finished_from_memory(sweep_dir: Path, key: str, config: DictConfig) -> Plan | None:
    """The plan of a sweep whose every setting is complete, from the run ids remembered
    under its :func:`plan_key` (no composition, no validation: an identical sweep was
    validated before); None when not remembered, ``force=true`` or a run is incomplete."""
    if config.force:
        return None
    try:
        run_ids = json.loads(_index_path(sweep_dir, key).read_text())
    except (OSError, ValueError):
        return None
    runs_dir = Path(sweep_dir) / store.RUNS_DIR
    recorded = set(os.listdir(runs_dir)) if runs_dir.is_dir() else set()
    checks = store.Checks()
    for rid in run_ids:
        if f"{rid}.json" not in recorded or store.incomplete_reason(sweep_dir, rid, checks):
            return None
    progress.mark_progress(sweep_dir, "complete-before-launch", ["resumed"] * len(run_ids))
    return Plan(settings=len(run_ids), complete=len(run_ids), run_ids=list(run_ids))
