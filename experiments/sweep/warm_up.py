"""Work every setting of a sweep needs, done while the sweep is being planned.

The ttc launcher starts its workers while the sweeper validates and plans
(``hydra_plugins/ttc_launcher``); each worker then calls the task module's ``warm_up`` with
the sweep's master config. In a cold sweep the workers would otherwise wait idle for the plan:
here they fill the stage cache with what any setting of the sweep reads, whatever its
features: each frame's objects (YOLO) and lane points, and the recording's reference TTC
that the end-of-sweep summary ranks against. Two workers split the entries (the cache's
cooperative locking). Entries already stored are left for the jobs to read: loading them
here (0.2-0.3 s a worker on ``fp6_grid``'s 19 frames) took the cores from the main process
while it validates and plans, and delayed the first job of a re-run.

Nothing is done when the sweep varies the recording, the frames, the objects or the lane
crop (the master config holds none of the sweep's values then) or the cache is off. Errors
are left for the jobs, which record them per frame.
"""

from __future__ import annotations

import logging

from omegaconf import DictConfig

from experiments.configs.structured import (
    prepared_frame_range,
    sequence_dir,
    settings_from_config,
    swept_overrides,
)
from experiments.data.first_run import setting_models
from ttc.engine.cache import StageCache
from ttc.engine.stages import shared_frame_tasks

log = logging.getLogger(__name__)
#: Config groups whose values the shared stages depend on: swept, nothing is warmed up.
SHARED_GROUPS = ("dataset", "objects", "lidar")


def swept_keys(master: DictConfig) -> set[str]:
    """The keys a multirun sweeps (:func:`experiments.configs.structured.swept_overrides`)."""
    return set(swept_overrides(master))


def warm_up(master: DictConfig) -> None:
    """Fill the stage cache with the shared entries of ``master``'s sweep (module docstring);
    never raises."""
    try:
        swept = {k.lstrip("+~").split(".")[0].split("/")[0] for k in swept_keys(master)}
        if swept & set(SHARED_GROUPS) or not master.cache.enabled:
            return
        frames = prepared_frame_range(master)
        cache = StageCache(master.cache.dir)
        settings = settings_from_config(master)
        setting_models(settings.objects, allowed=False)  # a copy the sweep downloaded
        tasks = shared_frame_tasks(settings, frames, cache)
        if master.dataset.get("generator") is None:  # the exact truth needs no reference
            from experiments.summary.references import reference_task  # noqa: PLC0415 (SciPy)

            tasks.insert(0, reference_task(sequence_dir(master)))
        missing = [t for t in tasks if not cache.path(t.stage, t.key).is_file()]
        cache.resolve(missing, errors=(Exception,))
    except Exception as exc:  # the jobs meet the same problem and record it
        log.debug(f"warm-up skipped: {exc!r}")
