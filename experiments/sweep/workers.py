"""What runs in a sweep's worker processes: the sweep state restored once per worker, a job's
config from :class:`experiments.sweep.compose.Composer`, its run
(:mod:`experiments.sweep.job_run`), the warm-up while the sweep is planned, and the markers
that tell which jobs a dead worker was running.

A worker restores the sweep's shared state (Hydra context, master config, task function,
Hydra's singletons) once per sweep, not once per job: the stock joblib launcher pickles it
again for every job and the worker re-discovers every Hydra plugin when it restores it.

A worker's memory grows by design after its first call: the stage cache keeps up to 96 MB
of entries and 64 MB of derived work (:data:`ttc.engine.cache.MEMORY_MB`,
:data:`~ttc.engine.cache.DERIVED_MB`), the grey images up to 64 MB, and models
load on first use. loky takes a worker whose memory grew by more than 300 MB since its first
call for a leaking one and replaces it mid-sweep, with a ``UserWarning: A worker stopped
while some jobs were given to the executor`` (a cold ``fp6_grid``: both workers grew from
≈ 350 to 630-710 MB and were replaced after 110-120 s). :func:`allow_worker_growth` raises
that limit in each worker to :data:`WORKER_GROWTH_BYTES`.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import os
import pickle
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cloudpickle
from hydra.core.hydra_config import HydraConfig
from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, setup_globals
from joblib import effective_n_jobs
from joblib.externals.loky import get_reusable_executor, process_executor
from omegaconf import DictConfig, open_dict

from experiments.host.heap import freeze_alive
from experiments.sweep.compose import Composer
from experiments.sweep.job_run import run_sweep_job

#: Folder (in the sweep folder) of the markers of the jobs running right now: ``<job idx>``.
STARTED_DIR = ".launcher"
#: How much a worker's memory may grow after its first call before loky retires it as leaking
#: (bytes): its bounded caches (320 MB) and the models it loads on first use (PyTorch and the
#: learned features: several hundred MB) stay below it; a real leak still reaches it.
WORKER_GROWTH_BYTES = 2 * 2**30
#: The module global of loky's memory-leak check (read by each worker after each call).
LOKY_LEAK_LIMIT = "_MAX_MEMORY_LEAK_SIZE"


@dataclass(frozen=True)
class SweepState:
    """What every job of a sweep needs besides its overrides, pickled once in the main
    process and restored once per worker process (each part keyed by its SHA-256).

    ``payload``: (Hydra context, master config, task function, singletons); ``shared``:
    the sweeper's :meth:`Composer.shared` (compositions, template, earlier plan), or empty;
    ``started``: the folder of the running jobs' markers; ``environ``: for workers forked
    from a process made before the sweep set its environment (:mod:`experiments.warm.forks`),
    the environment a freshly started worker would have (:func:`worker_environ`), else empty.
    """

    key: str
    payload: bytes
    started: str
    shared_key: str = ""
    shared: bytes = b""
    environ: tuple[tuple[str, str], ...] = ()


def pickled(value: Any) -> tuple[str, bytes]:
    """(SHA-256, cloudpickle) of ``value``: a part of :class:`SweepState`."""
    data = cloudpickle.dumps(value)
    return hashlib.sha256(data).hexdigest(), data


def sweep_payload(hydra_context: Any, config: DictConfig, task_function: Any) -> tuple[str, bytes]:
    """The :class:`SweepState` payload of a sweep (Hydra's singletons included)."""
    return pickled((hydra_context, config, task_function, Singleton.get_state()))


#: The sweep state of this worker process: restored once per sweep, not once per job.
_WORKER: dict[str, Any] = {}


def worker_environ(n_jobs: int | None) -> tuple[tuple[str, str], ...]:
    """The environment loky gives a worker it starts: this process's, with joblib's limits
    of the native thread pools (OpenMP, BLAS: cores / workers) unless already set."""
    from joblib._parallel_backends import LokyBackend  # noqa: PLC0415

    limits = LokyBackend()._prepare_worker_env(n_jobs=effective_n_jobs(n_jobs))
    return tuple({**os.environ, **limits}.items())


def take_environ(environ: tuple[tuple[str, str], ...]) -> None:
    """In a forked worker: take the sweep's environment and apply its thread limits to the
    native thread pools already loaded (a fresh worker reads them when it loads them)."""
    os.environ.clear()
    os.environ.update(dict(environ))
    from threadpoolctl import threadpool_limits  # noqa: PLC0415

    with contextlib.suppress(KeyError, ValueError):
        threadpool_limits(limits=int(os.environ["OMP_NUM_THREADS"]))


def worker_state(state: SweepState) -> dict[str, Any]:
    """This worker's restored sweep state (Hydra context, master, task function, composer),
    restored when ``state`` is another sweep's; a forked worker takes its environment."""
    if _WORKER.get("key") != state.key:
        hydra_context, master, task_function, singletons = pickle.loads(state.payload)
        setup_globals()
        Singleton.set_state(singletons)
        _WORKER.clear()
        _WORKER.update(key=state.key, hydra_context=hydra_context, master=master,
                       task_function=task_function)  # fmt: skip
    if state.environ and _WORKER.get("environ") != state.environ:
        take_environ(state.environ)
        _WORKER["environ"] = state.environ
    if _WORKER.get("shared_key") != state.shared_key or "composer" not in _WORKER:
        shared = pickle.loads(state.shared) if state.shared else ()
        loader = _WORKER["hydra_context"].config_loader
        _WORKER["composer"] = Composer(loader, _WORKER["master"], *shared)
        _WORKER["shared_key"] = state.shared_key
    return _WORKER


def allow_worker_growth(limit: int = WORKER_GROWTH_BYTES) -> None:
    """In a worker process: let its memory grow by up to ``limit`` bytes after its first call
    before loky's memory-leak check replaces it (module docstring). Never lowers loky's own
    limit. A loky without it is left as it is (tests/test_launcher.py fails on such a loky)."""
    if not hasattr(process_executor, LOKY_LEAK_LIMIT):
        return
    current = getattr(process_executor, LOKY_LEAK_LIMIT)
    setattr(process_executor, LOKY_LEAK_LIMIT, max(int(current), limit))


def warm(state: SweepState, modules: Sequence[str]) -> int:
    """Import ``modules``, restore the sweep state in this worker and call each module's
    ``warm_up(master config)`` if it has one (work any job of the sweep needs, done while the
    main process plans); this worker's process id."""
    allow_worker_growth()
    imported = [importlib.import_module(name) for name in modules]
    worker = worker_state(state)
    HydraConfig.instance().set_config(worker["master"])
    # the stack and the sweep state live as long as the worker: out of the garbage
    # collector's passes (a full collection walked them, 70 ms, every ~2 s of jobs), after
    # one collection (in a worker forked from the warm server it walks only what the worker
    # made since: the server froze the stack, whose shared pages stay untouched)
    freeze_alive()
    for module in imported:
        if callable(hook := getattr(module, "warm_up", None)):
            hook(worker["master"])
    return os.getpid()


class WorkerDiedError(RuntimeError):
    """The process running a job died (a signal: out of memory, a crash in native code)."""


def worker_death(exc: BaseException) -> str:
    """What killed a loky worker, from its ``TerminatedWorkerError``, in words."""
    found = re.search(r"exit codes of the workers are \{([^}]*)\}", str(exc))
    codes = found.group(1) if found else "unknown"
    return (
        f"worker process died ({codes}): killed by a signal, e.g. out of memory or a crash "
        "in native code (OpenCV)"
    )


def execute_job(idx: int, overrides: Sequence[str], state: SweepState) -> JobReturn:
    """One job in a worker: its config (:meth:`Composer.config`), then Hydra's ``run_job``
    without its copies (:func:`experiments.sweep.job_run.run_sweep_job`).
    ``<state.started>/<idx>`` exists while it runs (it stays when the worker dies)."""
    allow_worker_growth()  # a worker that did not warm up (a job re-run alone)
    marker = Path(state.started) / str(idx)
    marker.write_text(str(os.getpid()))
    worker = worker_state(state)
    sweep_config = worker["composer"].config(overrides)
    with open_dict(sweep_config):
        sweep_config.hydra.job.id = f"{sweep_config.hydra.job.name}_{idx}"
        sweep_config.hydra.job.num = idx
    ret = run_sweep_job(worker["task_function"], sweep_config, worker["hydra_context"])
    marker.unlink(missing_ok=True)
    return ret


def indexed(idx: int, overrides: Sequence[str], state: SweepState) -> tuple[int, JobReturn]:
    """:func:`execute_job` with its index (results arrive unordered)."""
    return idx, execute_job(idx, overrides, state)


def shut_down_workers(n_jobs: int | None, wait: bool = True, kill: bool = False) -> None:
    """Stop the pool's worker processes once a sweep's jobs are done: loky keeps idle workers
    for reuse, each holding its imports and in-memory stage cache (~0.7 GB on ``grand``)
    while the main process merges and ranks. ``wait=False``: tell them to exit and go on
    (they are gone within a fraction of a second; waiting for it cost a sweep ~0.3 s);
    ``kill=True``: end them in the middle of their jobs (an interrupted sweep).

    ``reuse=True`` fetches the pool the jobs ran on whatever its settings: asked with other
    arguments than joblib's (its ``env`` of thread limits), loky would first shut that pool
    down *waiting* for its workers (0.4 s at the end of every sweep) and start another."""
    executor = get_reusable_executor(max_workers=effective_n_jobs(n_jobs), reuse=True)
    executor.shutdown(wait=wait, kill_workers=kill)
