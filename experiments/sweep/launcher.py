"""The launcher of ttc-bench: Hydra's joblib launcher with cheaper per-job set-up.

It runs a sweep's jobs with the same joblib/loky pool and the same Hydra ``run_job`` (job
folders, logs, callbacks) as Hydra's joblib launcher, but:

* the sweep's shared state is pickled once and restored once per worker
  (:mod:`experiments.sweep.workers`);
* each job's config comes from :class:`experiments.sweep.compose.Composer`, seeded with the
  compositions the sweeper made to validate and plan (:meth:`SweepLauncher.share_compositions`),
  so a worker composes nothing itself;
* the sweeper starts the workers while it plans (:meth:`SweepLauncher.warm_up`): their
  imports overlap the planning, and each calls the task module's ``warm_up(master config)``
  (ttc-bench's: :mod:`experiments.sweep.warm_up`).

A worker that dies (a signal: out of memory, a crash in native code) breaks a joblib pool and
would end the sweep with ``TerminatedWorkerError``. Instead each job that was running then is
run again alone in a one-worker pool of its own; one that dies there too is reported as failed
with the signal (``JobStatus.FAILED``; the callbacks' ``on_job_end`` records it), and a batch
that dies is run again a setting at a time. The jobs not started yet then go on in joblib's
pool. The one-worker pool is never joblib's reusable one: loky would hand a pool made outside
joblib to the next ``Parallel``, which fails on it (``'_ReusablePoolExecutor' object has no
attribute '_temp_folder_manager'``, issue 32).

``hydra_plugins/ttc_launcher`` registers it with Hydra (``hydra/launcher=ttc_joblib``).
"""

from __future__ import annotations

import contextlib
import logging
import shutil
import signal
import sys
import threading
from collections.abc import Sequence
from multiprocessing import resource_tracker
from pathlib import Path
from typing import Any

from hydra.core.utils import JobReturn, JobStatus, configure_log, filter_overrides, setup_globals
from hydra_plugins.hydra_joblib_launcher.joblib_launcher import JoblibLauncher
from joblib import Parallel, delayed, effective_n_jobs
from joblib.externals.loky import ProcessPoolExecutor
from joblib.externals.loky.backend import resource_tracker as loky_resource_tracker
from joblib.externals.loky.backend.context import get_start_method as loky_start_method
from joblib.externals.loky.process_executor import TerminatedWorkerError
from omegaconf import DictConfig, open_dict

from experiments.sweep.compose import BATCH_PREFIX, Composer
from experiments.sweep.workers import (
    STARTED_DIR,
    SweepState,
    WorkerDiedError,
    execute_job,
    indexed,
    pickled,
    shut_down_workers,
    sweep_payload,
    warm,
    worker_death,
    worker_environ,
)

log = logging.getLogger(__name__)
#: Joblib options given as strings that are numbers.
INT_OPTIONS = ("pre_dispatch", "batch_size", "max_nbytes")


def joblib_options(options: Any) -> dict[str, Any]:
    """The joblib options of a sweep's pool from the launcher's config: loky, one job per
    dispatch (a dead worker loses one job, not a batch of them), numbers as numbers."""
    out = dict(options)
    for key in INT_OPTIONS:
        if out.get(key):
            with contextlib.suppress(ValueError):  # Hydra's rule: kept as it is
                out[key] = int(out[key])
    out.update(backend="loky", batch_size=1)
    return out


class SweepLauncher(JoblibLauncher):
    """:class:`JoblibLauncher` that pickles the sweep state once and composes jobs cheaply."""

    def __init__(self, **kwargs: Any) -> None:
        """``kwargs``: the joblib launcher's options."""
        super().__init__(**kwargs)
        self._payload: tuple[str, bytes] | None = None
        self._shared: tuple[str, bytes] = ("", b"")
        self._composer: Composer | None = None
        self._warming: threading.Thread | None = None
        self._lone: ProcessPoolExecutor | None = None

    def _state(self, started: Path) -> SweepState:
        """The sweep state the jobs get (the payload pickled once per sweep)."""
        if self._payload is None:
            assert self.hydra_context is not None and self.config is not None
            self._payload = sweep_payload(self.hydra_context, self.config, self.task_function)
        key, payload = self._payload
        forked = loky_start_method() == "forkserver"  # experiments.warm.forks
        environ = worker_environ(joblib_options(self.joblib).get("n_jobs")) if forked else ()
        return SweepState(key, payload, str(started), *self._shared, environ=environ)

    def share_compositions(self, composer: Composer) -> None:
        """Hand over the sweeper's composer state (made from this launcher's master config):
        the workers' :class:`Composer` starts from it instead of composing again."""
        self._shared = pickled(composer.shared())
        self._composer = composer

    def warm_up(self) -> None:
        """Start the pool's workers now, in the background: each imports the task's module and
        restores the sweep state while the main process validates and plans. :meth:`launch`
        waits for it; :meth:`release` stops the workers when nothing is launched."""
        if self._warming is not None:
            return
        assert self.config is not None
        main_spec = getattr(sys.modules.get("__main__"), "__spec__", None)
        modules = [main_spec.name] if main_spec is not None else []
        state = self._state(Path(str(self.config.hydra.sweep.dir)) / STARTED_DIR)
        options = joblib_options(self.joblib)
        workers = effective_n_jobs(options.get("n_jobs"))

        def start() -> None:
            """Run :func:`warm` once in each worker. SIGINT is blocked in this thread, so in
            the workers it starts (the mask is inherited through fork and exec) and in loky's
            manager thread: Ctrl-C reaches the main process only, which stops the workers
            (:meth:`stop`), instead of a worker printing a ``KeyboardInterrupt`` traceback
            from the middle of its imports. The resource trackers start first: starting one
            unblocks SIGINT in the calling thread."""
            loky_resource_tracker.ensure_running()
            resource_tracker.ensure_running()
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            try:
                Parallel(**options)(delayed(warm)(state, modules) for _ in range(workers))
            except BaseException as exc:  # Ctrl-C too: the main thread says what it kept
                log.debug(f"warming the workers up failed: {exc!r}")  # the launch reports errors

        log.info(f"Starting {workers} workers while the sweep is planned")
        self._warming = threading.Thread(target=start, name="ttc-warm-up", daemon=True)
        self._warming.start()

    def _wait_for_warm_up(self) -> bool:
        """Wait for a running :meth:`warm_up`; True when there was one."""
        if self._warming is None:
            return False
        self._warming.join()
        self._warming = None
        return True

    def release(self) -> None:
        """Wait for a :meth:`warm_up` and stop the workers it started (a sweep that launched
        nothing)."""
        if self._wait_for_warm_up():
            shut_down_workers(joblib_options(self.joblib).get("n_jobs"))

    def stop(self) -> None:
        """End the pool's workers at once, in the middle of their jobs (Ctrl-C)."""
        self._end_lone(kill=True)
        shut_down_workers(joblib_options(self.joblib).get("n_jobs"), wait=True, kill=True)

    def launch(
        self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int
    ) -> Sequence[JobReturn]:
        """Run the jobs (module docstring); their returns in order."""
        setup_globals()
        assert self.config is not None and self.hydra_context is not None
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        options = joblib_options(self.joblib)
        log.info(f"Launching {len(job_overrides)} jobs, sweep output dir: {sweep_dir}")
        for idx, overrides in enumerate(job_overrides):  # hydra.verbose=true shows them
            log.debug(f"\t#{initial_job_idx + idx} : {' '.join(filter_overrides(overrides))}")
        self._wait_for_warm_up()
        started = sweep_dir / STARTED_DIR
        shutil.rmtree(started, ignore_errors=True)
        started.mkdir(parents=True)
        state = self._state(started)
        jobs = {initial_job_idx + i: list(o) for i, o in enumerate(job_overrides)}
        results: dict[int, JobReturn] = {}
        while pending := [i for i in jobs if i not in results]:
            try:
                runs = Parallel(**options, return_as="generator_unordered")(
                    delayed(indexed)(i, jobs[i], state) for i in pending
                )
                for i, ret in runs:  # kept one by one: a later crash loses none of them
                    results[i] = ret
            except TerminatedWorkerError as exc:
                left = [i for i in pending if i not in results]
                running = [i for i in left if (started / str(i)).exists()] or left[:1]
                log.warning(f"{worker_death(exc)}; re-running its jobs {running} one by one")
                try:
                    for i in running:
                        results[i] = self._alone(i, jobs[i], state)
                except BaseException:  # Ctrl-C: its worker ends at once
                    self._end_lone(kill=True)
                    raise
                self._end_lone()
        shutil.rmtree(started, ignore_errors=True)
        shut_down_workers(options.get("n_jobs"), wait=False)
        return [results[i] for i in sorted(jobs)]

    def _alone(self, idx: int, overrides: list[str], state: SweepState) -> JobReturn:
        """Run one job alone in a fresh worker; a job that kills it is reported FAILED. A
        batch that kills it is run again a setting at a time (each alone), so the setting that
        dies costs only itself."""
        if self._lone is None:
            self._lone = ProcessPoolExecutor(max_workers=1)
        try:
            return self._lone.submit(execute_job, idx, overrides, state).result()
        except TerminatedWorkerError as exc:
            message = worker_death(exc)
            self._end_lone()  # broken: the next job alone gets a fresh pool
        members = self._batch_members(overrides)
        if members:
            log.warning(f"job #{idx} (a batch of {len(members)}): {message}; one by one now")
            returns = [self._alone(idx, m, state) for m in members]
            failed = [r for r in returns if r.status == JobStatus.FAILED]
            return failed[0] if failed else returns[0]
        log.error(f"job #{idx} ({' '.join(overrides)}): {message}")
        return self._died(idx, overrides, message)

    def _end_lone(self, kill: bool = False) -> None:
        """Stop the one-worker pool of the jobs run alone, if there is one (waiting for its
        worker to exit; ``kill``: in the middle of its job)."""
        lone, self._lone = self._lone, None
        if lone is not None:
            lone.shutdown(wait=True, kill_workers=kill)

    def _died(self, idx: int, overrides: list[str], message: str) -> JobReturn:
        """The FAILED return of a job whose worker died, told to the callbacks."""
        assert self.hydra_context is not None and self.config is not None
        if self._composer is None:
            self._composer = Composer(self.hydra_context.config_loader, self.config)
        cfg: DictConfig = self._composer.config(overrides)
        with open_dict(cfg):
            cfg.hydra.job.id, cfg.hydra.job.num = f"{cfg.hydra.job.name}_{idx}", idx
        ret = JobReturn(
            overrides=overrides,
            cfg=cfg,
            hydra_cfg=cfg,
            status=JobStatus.FAILED,
            _return_value=WorkerDiedError(message),
        )
        self.hydra_context.callbacks.on_job_end(config=cfg, job_return=ret)
        return ret

    def _batch_members(self, overrides: list[str]) -> list[list[str]]:
        """The overrides of each setting of a batch job (none for a one-setting job)."""
        batch = [o[len(BATCH_PREFIX) :] for o in overrides if o.startswith(BATCH_PREFIX)]
        if not batch:
            return []
        from experiments.sweep.plan import read_plan  # noqa: PLC0415 (pandas, OpenCV)

        assert self.config is not None
        plan = read_plan(Path(str(self.config.hydra.sweep.dir)), batch[-1])
        return [list(m["overrides"]) for m in plan["members"]]
