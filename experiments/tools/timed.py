"""Whole commands timed for the sweep benchmark (:mod:`experiments.tools.benchmark`): a sweep
or a report run through the real command line, its wall time, the peak memory of its processes
(resident ``rss`` and proportional ``pss``, summed over the process tree) and where a sweep's
time went (before its first job, its jobs, after its last). A report can be run by the code of
another checkout (:func:`timed_report`'s ``code``: the benchmark's before / after comparison)."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd

from experiments import store
from experiments.host.paths import base_dir, default_data_root


def _timed_command(
    args: list[str], env: dict[str, str], memory: dict | None, cwd: Path | None = None
) -> tuple[float, subprocess.CompletedProcess]:
    """Run ``python <args>`` from ``cwd`` (default: the project folder); (wall seconds, its
    completed process). ``memory``, when given, receives the peaks of :func:`_sample_memory`
    (MB: ``rss``, ``pss``, ``main_rss``), sampled every 0.5 s."""
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, *args], cwd=cwd or base_dir(), env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    peaks: dict[str, float] = {}
    if memory is not None:
        done = threading.Event()
        sampler = threading.Thread(target=_sample_memory, args=(proc.pid, peaks, done), daemon=True)
        sampler.start()
    out, err = proc.communicate()
    wall = time.perf_counter() - start
    if memory is not None:
        done.set()
        sampler.join()
        memory.update(peaks)
    return wall, subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


#: Idle timeout (s) of the benchmark's warm server: it ends soon after the benchmark.
SERVER_IDLE_S = "30"
#: Seconds to wait for a started warm server to answer.
SERVER_START_S = 120.0


def sweep_env(results: Path, cache: Path, served: bool) -> dict[str, str]:
    """The environment of a timed sweep: its results and cache folders, and the warm server
    (:mod:`experiments.warm`) on with a short idle timeout when ``served``, else off."""
    server = {"TTC_BENCH_SERVER": "1", "TTC_BENCH_SERVER_IDLE_S": SERVER_IDLE_S} if served else {
        "TTC_BENCH_SERVER": "0"}  # fmt: skip
    return {**os.environ, "TTC_RESULTS_DIR": str(results), "TTC_CACHE_DIR": str(cache), **server}


def start_warm_server(env: dict[str, str]) -> None:
    """Start the warm server of ``env`` (``python -m experiments.warm.client``, from the
    project folder as the timed commands) and wait until it answers: its start-up (the
    stack's imports) is not part of the command timed after it."""
    out = subprocess.run([sys.executable, "-m", "experiments.warm.client"], cwd=base_dir(),
                         env=env, capture_output=True, text=True, check=True)  # fmt: skip
    path = out.stdout.strip()
    if path in ("", "None"):
        raise RuntimeError(f"the warm server is off or cannot start: {out.stderr[-2000:]}")
    deadline = time.monotonic() + SERVER_START_S
    while time.monotonic() < deadline:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
            try:
                probe.connect(path)
                return
            except OSError:
                time.sleep(0.2)
    raise RuntimeError(f"the warm server at {path} did not answer in {SERVER_START_S:.0f} s")


def timed_sweep(
    args: list[str], results: Path, cache: Path, memory: dict | None = None, served: bool = False
) -> tuple[float, pd.DataFrame]:
    """Run one sweep through the real command line; (wall seconds, its runs table).
    ``served``: as a user's ``ttc-bench run`` with its warm server up (started before, not
    timed); else ``python -m experiments.run`` alone. ``memory``: as
    :func:`_timed_command`'s (the processes under the command: not the server's when served)."""
    env = sweep_env(results, cache, served)
    command = ["-m", "experiments.run", *args]
    if served:
        start_warm_server(env)
        command = ["-m", "experiments.cli", "run", *args]
    started = time.time()
    wall, proc = _timed_command(command, env, memory)
    if proc.returncode != 0:
        raise RuntimeError(f"sweep {args} failed:\n{proc.stderr[-4000:]}")
    name = next(a.split("=", 1)[1] for a in args if a.startswith("sweep_name="))
    runs = store.load_runs(results / name)
    runs.attrs.update(started=started, ended=started + wall)  # epoch seconds
    return wall, runs


def timed_report(
    sweep_dir: Path, out: Path, cache: Path, memory: dict | None = None, code: Path | None = None
) -> float:
    """Wall seconds of ``python -m experiments.report`` on a sweep (pictures and HTML) into
    ``out``; ``memory``: as :func:`_timed_command`'s. ``code``: a checkout of this repository
    (another commit's) whose report runs instead, from that folder with ``PYTHONPATH`` on it
    (as ``tests/test_same_outputs.py`` runs the code before a change); both read the data of
    :func:`~experiments.host.paths.default_data_root`."""
    args = ["-m", "experiments.report", str(sweep_dir), "--out", str(out),
            "--cache-dir", str(cache)]  # fmt: skip
    env = {**os.environ, "TTC_DATA_DIR": str(default_data_root()), "TTC_CACHE_DIR": str(cache)}
    if code is not None:
        env["PYTHONPATH"] = str(code)
    wall, proc = _timed_command(args, env, memory, cwd=code)
    if proc.returncode != 0:
        raise RuntimeError(f"report of {sweep_dir} ({code or 'this code'}) failed:\n"
                           f"{proc.stderr[-4000:]}")  # fmt: skip
    return wall


def _sample_memory(pid: int, peaks: dict[str, float], done: threading.Event) -> None:
    """Keep in ``peaks`` the largest ``rss`` (summed resident memory of process ``pid`` and
    its children), ``pss`` (the same, shared pages split between their processes) and
    ``main_rss`` (process ``pid`` alone), in MB."""
    import psutil  # noqa: PLC0415

    while not done.wait(0.5):
        try:
            root = psutil.Process(pid)
            procs = [root, *root.children(recursive=True)]
        except psutil.Error:
            return
        now = {"rss": 0.0, "pss": 0.0, "main_rss": 0.0}
        for p in procs:
            with contextlib.suppress(psutil.Error):
                info = p.memory_full_info()
                now["rss"] += info.rss / 2**20
                now["pss"] += getattr(info, "pss", info.rss) / 2**20
                if p.pid == pid:
                    now["main_rss"] = info.rss / 2**20
        for key, value in now.items():
            peaks[key] = max(peaks.get(key, 0.0), value)


def sweep_breakdown(runs: pd.DataFrame, cores: int) -> dict[str, float]:
    """Where a sweep's wall time went (s): ``jobs_s`` the settings' own work (the run
    records' ``wall_s``, summed, divided by the cores), ``span_s`` first job start to last job
    end (the rest of the span is per-job launcher work: Hydra's ``run_job``, the job's config,
    and workers waiting for the last jobs); from :func:`timed_sweep`'s runs, ``lead_in_s`` the
    command's start to the first job's (start-up, validation and planning) and ``tail_s`` the
    last job's end to the command's (merge and summary). Jobs: the computed ones, this command's."""
    computed = runs[runs["status"] != "skipped"] if "status" in runs else runs
    computed = computed if len(computed) else runs
    if "started" in runs.attrs:
        began = pd.to_datetime(computed["start"]).map(pd.Timestamp.timestamp)
        computed = computed[began >= runs.attrs["started"]]
    start, end = pd.to_datetime(computed["start"]), pd.to_datetime(computed["end"])
    out = {
        "jobs_s": float(computed["wall_s"].sum()) / cores,
        "span_s": (end.max() - start.min()).total_seconds(),
        "jobs": len(computed),
    }
    if {"started", "ended"} <= runs.attrs.keys():
        out["lead_in_s"] = start.min().timestamp() - runs.attrs["started"]
        out["tail_s"] = runs.attrs["ended"] - end.max().timestamp()
    return out
