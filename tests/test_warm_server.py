"""The warm server (``experiments.warm``): a command on it runs as without it (same output,
exit status), and what #10 and #21 guarantee holds with its worker model (workers forked from
the command's fork server): Ctrl-C ends a sweep with one line and exit 130 and no worker
left, a SIGKILLed worker costs no setting, a crashing job is recorded with its reason while
the sweep goes on. Stale code is never served: any code file's change gives another key."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from experiments.store import load_runs
from experiments.sweep.workers import STARTED_DIR
from experiments.warm import server_key
from tests.conftest import PROJECT_ROOT
from tests.test_launcher import _kill_first_job

psutil = pytest.importorskip("psutil")
LINE = re.compile(r"^interrupted: (\d+) of (\d+) settings done .*resumes the other (\d+)$", re.M)


def crash_if(gray, crash: bool = False):
    """A detector that crashes its process as native code does (SIGSEGV) when told to; else
    a few corners."""
    if crash:
        os.kill(os.getpid(), signal.SIGSEGV)
    import cv2  # noqa: PLC0415

    return cv2.goodFeaturesToTrack(gray, 200, 0.01, 8).reshape(-1, 2).astype(float)


def test_any_code_change_or_environment_change_gives_another_key(tmp_path: Path) -> None:
    env = {"HOME": "/home/u", "PWD": "/a"}
    key = server_key.server_key(env)
    assert server_key.server_key({**env, "PWD": "/b", "SHLVL": "3"}) == key  # the shell's own
    assert server_key.server_key({**env, "TTC_DATA_DIR": "/x"}) != key
    code = Path(server_key.__file__)
    before = code.stat()
    try:
        os.utime(code, ns=(before.st_atime_ns, before.st_mtime_ns + 1_000_000))
        assert server_key.server_key(env) != key  # edited: another server, never this one
    finally:
        os.utime(code, ns=(before.st_atime_ns, before.st_mtime_ns))
    assert server_key.server_key(env) == key


def test_files_beside_the_code_keep_the_key_a_package_install_does_not(
    tmp_path: Path, monkeypatch
) -> None:
    """A file created in the project's folder (a sweep's ``sweeps/``, a test's output) leaves
    the key as it is (else a server importing meanwhile never starts: seen in CI); a change
    of another folder of ``sys.path`` (a package installed) gives another key."""
    project, site = tmp_path / "project", tmp_path / "site"
    project.mkdir()
    site.mkdir()
    monkeypatch.setattr(server_key, "project_top", lambda: project)
    search = ["", str(project), str(site)]
    key = server_key.server_key({}, search)
    (project / "sweeps").mkdir()
    assert server_key.server_key({}, search) == key
    time.sleep(0.01)
    (site / "newpackage").mkdir()
    assert server_key.server_key({}, search) != key


def test_the_socket_folder_must_be_private(tmp_path: Path) -> None:
    folder = tmp_path / "ttc-bench"
    assert server_key.runtime_dir({"XDG_RUNTIME_DIR": str(tmp_path)}) == folder
    folder.chmod(0o755)
    with pytest.raises(OSError, match="not a private folder"):
        server_key.runtime_dir({"XDG_RUNTIME_DIR": str(tmp_path)})
    assert not server_key.enabled({server_key.SWITCH: "0"})


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[dict, psutil.Process]]:
    """The environment of commands served by one warm server, and that server (stopped
    after the module's tests)."""
    root = tmp_path_factory.mktemp("warm")
    (root / "run").mkdir(mode=0o700)
    env = {**os.environ, server_key.SWITCH: "1", server_key.IDLE_VARIABLE: "300",
           "XDG_RUNTIME_DIR": str(root / "run"), "TTC_RESULTS_DIR": str(root / "sweeps"),
           "TTC_CACHE_DIR": str(root / "cache")}  # fmt: skip
    started = subprocess.run([sys.executable, "-m", "experiments.warm.client"], env=env,
                             cwd=PROJECT_ROOT, capture_output=True, text=True, check=True)  # fmt: skip
    socket = Path(started.stdout.strip())
    deadline = time.time() + 180
    while not socket.exists() and time.time() < deadline:
        time.sleep(0.2)
    assert socket.exists(), Path(f"{socket}.log").read_text()
    server = next(
        p for p in psutil.process_iter(["cmdline"]) if str(socket) in (p.info["cmdline"] or [])
    )
    yield env, server
    server.terminate()
    server.wait(30)


def sweep(env: dict, args: list[str]) -> subprocess.Popen:
    """``ttc-bench sweep ...`` (the client) in a subprocess."""
    return subprocess.Popen([sys.executable, "-m", "experiments.cli", "sweep", *args],
                            cwd=PROJECT_ROOT, env=env, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)  # fmt: skip


def workers_of(server: psutil.Process) -> list:
    """The server's command processes and their workers (the resource trackers aside)."""
    return [p for p in server.children(recursive=True)
            if "resource_tracker" not in " ".join(p.cmdline())]  # fmt: skip


def served_log(env: dict) -> str:
    """Every warm server's log in this environment's folder."""
    folder = Path(env["XDG_RUNTIME_DIR"]) / "ttc-bench"
    return "".join(p.read_text() for p in folder.glob("*.log"))


@pytest.mark.slow
def test_ctrl_c_on_a_served_sweep(served) -> None:
    env, server = served
    args = ["detector=fast,orb,brisk", "descriptor=brief,orb", "keypoint_filter=none,zscore",
            "dataset.last=3", "sweep_name=interrupted"]  # fmt: skip
    proc = sweep(env, args)
    runs = Path(env["TTC_RESULTS_DIR"]) / "interrupted" / "runs"
    deadline = time.time() + 300
    while time.time() < deadline and not list(runs.glob("*.json")) and proc.poll() is None:
        time.sleep(0.05)
    running = workers_of(server)
    assert len(running) >= 3, "the command, its fork server and workers"
    assert all(p.cmdline() == server.cmdline() for p in running), "forked, not started afresh"
    proc.send_signal(signal.SIGINT)  # the client passes it on
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    found = LINE.findall(err)
    assert len(found) == 1 and 1 <= int(found[0][0]) < 12, err[-3000:]
    _, alive = psutil.wait_procs(workers_of(server), timeout=15)
    assert not alive, f"left behind: {alive}"
    assert "sweep +" not in served_log(env) and "sweep detector=fast" in served_log(env)


@pytest.mark.slow
def test_a_killed_worker_and_a_crashing_job_on_a_served_sweep(served) -> None:
    env, server = served
    args = ["detector=fast,orb", "descriptor=brief,orb", "dataset.last=3", "cache.enabled=false",
            "hydra.launcher.n_jobs=2", "sweep_name=killed"]  # fmt: skip
    proc = sweep(env, args)
    killed = _kill_first_job(Path(env["TTC_RESULTS_DIR"]) / "killed" / STARTED_DIR, proc)
    out, err = proc.communicate(timeout=300)
    assert killed and proc.returncode == 0, err[-3000:]
    assert "Traceback" not in err, err[-3000:]
    assert "worker process died (SIGKILL(-9)): killed by a signal" in out
    runs = load_runs(Path(env["TTC_RESULTS_DIR"]) / "killed")
    assert len(runs) == 4 and (runs["status"] == "ok").all(), runs[["status", "message"]]

    crashing = ["detector=custom", f"detector.target={__name__}:crash_if",
                "+detector.params.crash=false,true", "descriptor=brief", "dataset.last=2",
                "cache.enabled=false", "sweep_name=crashing"]  # fmt: skip
    proc = sweep(env, crashing)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 1 and "sweep incomplete: 1 setting(s) failed" in err, err[-3000:]
    runs = load_runs(Path(env["TTC_RESULTS_DIR"]) / "crashing")
    assert sorted(runs["status"]) == ["failed", "ok"], runs[["status", "message"]]
    failed = runs.loc[runs["status"] == "failed", "message"].iloc[0]
    assert "worker process died (SIGSEGV(-11))" in failed
    _, alive = psutil.wait_procs(workers_of(server), timeout=15)
    assert not alive, f"left behind: {alive}"
    assert "exit 1" in served_log(env)  # both ran on the server
