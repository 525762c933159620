"""Ctrl-C (SIGINT to the process group) during a real multi-batch sweep: exit 130 with one line
saying what was kept, no traceback, no worker left behind, and the re-run resumes the
finished settings instead of computing them again. Real sweeps in subprocesses, ~8 s and
~4 s on a quiet 2-core machine (not marked slow)."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from experiments.sweep.interrupt import SigintSeen, done_count, interrupted_line, watch_sigint
from tests.conftest import PROJECT_ROOT

#: 3 detectors x 2 descriptors x 2 filters on frames 0-3: 6 batches of 2 settings.
ARGS = ["-m", "detector=fast,orb,brisk", "descriptor=brief,orb", "keypoint_filter=none,zscore",
        "dataset.last=3", "sweep_name=interrupted"]  # fmt: skip
SETTINGS = 12
LINE = re.compile(
    r"^interrupted: (\d+) of 12 settings done \(kept in .*\); re-running the same command "
    r"resumes the other (\d+)$",
    re.M,
)


def test_the_line_counts_the_records(tmp_path: Path) -> None:
    (tmp_path / "runs").mkdir()
    for rid in ("a", "b"):
        (tmp_path / "runs" / f"{rid}.json").write_text("{}")
    (tmp_path / "runs" / "c.parquet").write_text("")
    assert done_count(tmp_path, ["a", "b", "c"]) == 2
    assert "2 of 3 settings done" in interrupted_line(tmp_path, ["a", "b", "c", "c"])
    assert "before the sweep was planned: nothing launched" in interrupted_line(tmp_path, [])


def test_sigint_is_remembered_when_a_library_turns_it_into_another_error() -> None:
    """Ctrl-C inside OmegaConf (Hydra composing a config) came out as an ``AttributeError``
    and the sweep exited 1 with a traceback (CI, stop 25): the sweeper asks whether SIGINT
    arrived instead of matching the exception's type. Python's own handler is put back after."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # SIG_IGN where a shell
    # started the tests in the background
    seen = SigintSeen()
    with pytest.raises(AttributeError), watch_sigint(seen):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)  # the handler runs here
        except KeyboardInterrupt:
            raise AttributeError("'NoneType' object has no attribute '_invalidate'") from None
    assert seen.seen
    quiet = SigintSeen()
    with pytest.raises(ValueError), watch_sigint(quiet):
        raise ValueError("a real error")
    assert not quiet.seen
    assert signal.signal(signal.SIGINT, before) is signal.default_int_handler


def descendants(pid: int) -> list:
    """The live processes below ``pid`` (the sweep's workers)."""
    psutil = pytest.importorskip("psutil")
    with contextlib.suppress(psutil.NoSuchProcess):
        return psutil.Process(pid).children(recursive=True)
    return []


def test_ctrl_c_says_what_it_kept(tmp_path: Path) -> None:
    psutil = pytest.importorskip("psutil")
    env = {**os.environ, "TTC_RESULTS_DIR": str(tmp_path / "sweeps"),
           "TTC_CACHE_DIR": str(tmp_path / "cache")}  # fmt: skip
    command = [sys.executable, "-m", "experiments.run", *ARGS]
    proc = subprocess.Popen(command, cwd=PROJECT_ROOT, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)  # fmt: skip
    runs = tmp_path / "sweeps" / "interrupted" / "runs"
    deadline = time.time() + 300
    while time.time() < deadline and not list(runs.glob("*.json")) and proc.poll() is None:
        time.sleep(0.05)
    workers = descendants(proc.pid)
    assert workers, "the sweep should be running its workers"
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=60)

    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    found = LINE.findall(err)
    assert len(found) == 1, err[-3000:]
    done, left = map(int, found[0])
    assert 1 <= done < SETTINGS and done + left == SETTINGS
    kept = {p.name: p.read_bytes() for p in runs.glob("*.json")}
    assert len(kept) == done
    _, alive = psutil.wait_procs(workers, timeout=10)
    assert not alive, f"workers left behind: {alive}"

    again = subprocess.run(command, cwd=PROJECT_ROOT, env=env, text=True, capture_output=True,
                           timeout=600)  # fmt: skip
    assert again.returncode == 0, again.stderr[-3000:]
    assert f"sweep plan: 12 settings: {done} already complete (not launched)" in again.stdout
    assert f"this invocation: {SETTINGS - done} computed, {done} already complete" in again.stdout
    assert {name: (runs / name).read_bytes() for name in kept} == kept  # not recomputed


def test_ctrl_c_while_the_workers_warm_up(tmp_path: Path) -> None:
    """SIGINT as soon as the workers exist (the sweep is being planned, the workers warm the
    stage cache up): the same one line, exit 130, no traceback from the warm-up thread."""
    psutil = pytest.importorskip("psutil")
    env = {**os.environ, "TTC_RESULTS_DIR": str(tmp_path / "sweeps"),
           "TTC_CACHE_DIR": str(tmp_path / "cache")}  # fmt: skip
    proc = subprocess.Popen([sys.executable, "-m", "experiments.run", *ARGS], cwd=PROJECT_ROOT,
                            env=env, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)  # fmt: skip
    deadline = time.time() + 120
    while time.time() < deadline and len(descendants(proc.pid)) < 2 and proc.poll() is None:
        time.sleep(0.02)
    time.sleep(0.5)  # the workers import and start warming up
    workers = descendants(proc.pid)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    assert err.strip().splitlines()[-1].startswith("interrupted"), err[-3000:]
    _, alive = psutil.wait_procs(workers, timeout=10)
    assert not alive, f"workers left behind: {alive}"
