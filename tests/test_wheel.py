"""A tool people install: the wheel carries the config tree and every package, and installed
outside the checkout, ``ttc-bench run`` and ``ttc-bench report`` work from a temporary folder
without writing under the venv or the checkout; ``ttc-bench`` lists and dispatches its
subcommands (experiments/cli.py); the README's main command leaves a fresh clone's
``git status`` clean."""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import tomllib
import venv
import zipfile
from pathlib import Path

import pytest
from setuptools import find_namespace_packages

from experiments.cli import SUBCOMMANDS
from tests.conftest import PROJECT_ROOT
from ttc.features.model_files import SOURCES


def test_pyproject_lists_every_package() -> None:
    listed = tomllib.loads((PROJECT_ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    found = find_namespace_packages(
        PROJECT_ROOT, include=["ttc*", "experiments*", "hydra_plugins*"]
    )
    assert set(listed["packages"]) == {*found, "experiments.conf"}


def _cli(*args: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "experiments.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)  # fmt: skip


def test_help_lists_every_subcommand_and_each_has_its_own(tmp_path: Path) -> None:
    top = _cli("--help", cwd=PROJECT_ROOT)
    assert top.returncode == 0 and all(f"  {name} " in top.stdout for name in SUBCOMMANDS)
    for name in SUBCOMMANDS:
        done = _cli(name, "--help", cwd=PROJECT_ROOT)
        assert done.returncode == 0, (name, done.stderr[-500:])
        assert "usage" in done.stdout.lower() or "powered by Hydra" in done.stdout, name
    wrong = _cli("runn", cwd=PROJECT_ROOT)
    assert wrong.returncode != 0 and "unknown subcommand 'runn'" in wrong.stderr


def test_run_passes_overrides_through_and_sweep_is_run_m(tmp_path: Path, data_dir: Path) -> None:
    env = {**os.environ, "TTC_DATA_DIR": str(data_dir), "TTC_RESULTS_DIR": str(tmp_path / "s"),
           "TTC_CACHE_DIR": str(tmp_path / "c")}  # fmt: skip
    one = _cli("run", "dataset.last=1", "detector=orb", "print_rows=0", cwd=tmp_path, env=env)
    assert one.returncode == 0 and "] ok in" in one.stdout and "detector=orb" in one.stdout
    many = _cli("sweep", "dataset.last=1", "detector=orb,fast", "sweep_name=two", cwd=tmp_path,
                env=env)  # fmt: skip
    assert many.returncode == 0, many.stderr[-2000:]
    assert len(list((tmp_path / "s" / "two" / "runs").glob("*.json"))) == 2


def _tree(root: Path) -> set[str]:
    return {str(p) for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts}


@pytest.mark.slow
def test_the_wheel_runs_and_reports_from_any_folder(tmp_path: Path, data_dir: Path) -> None:
    dist = tmp_path / "dist"
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", dist,
                            PROJECT_ROOT], capture_output=True, text=True, timeout=600)  # fmt: skip
    assert build.returncode == 0, build.stderr[-2000:]
    wheel = next(dist.glob("ttc_bench-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    manifests = {f"experiments/conf/download/{m}.yaml" for m in SOURCES}  # every detector's
    assert {"experiments/conf/config.yaml", *manifests} <= {*names}
    assert not any(n.startswith(("conf/", "tests/")) for n in names)
    # a fresh venv outside the checkout; its dependencies come from this one's site-packages
    # through a .pth line (offline; the checkout's editable finder is not processed from there)
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    site = next((env_dir / "lib").glob("python*/site-packages"))
    (site / "zz_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    install = subprocess.run([env_dir / "bin" / "python", "-m", "pip", "install", "-q", "--no-deps",
                              "--no-index", wheel], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert install.returncode == 0, install.stderr[-2000:]
    before_venv, before_git = _tree(env_dir), _git_status()
    work = tmp_path / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("TTC_", "PYTHON"))}
    env |= {"TTC_DATA_DIR": str(data_dir), "XDG_CACHE_HOME": str(tmp_path / "xdg"),
            "HOME": str(tmp_path / "home")}  # fmt: skip
    tool = str(env_dir / "bin" / "ttc-bench")
    run = subprocess.run([tool, "run", "dataset.last=2", "print_rows=0", "sweep_name=x"], cwd=work,
                         env=env, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert run.returncode == 0 and "] ok in" in run.stdout, run.stderr[-2000:]
    assert "site-packages/experiments" in subprocess.run(
        [env_dir / "bin" / "python", "-c", "import experiments; print(experiments.__file__)"],
        cwd=work, capture_output=True, text=True).stdout  # fmt: skip
    single = next((work / "sweeps" / "single").iterdir())  # results under the working directory
    assert (tmp_path / "xdg" / "ttc-bench" / "cache").is_dir()  # the cache in the platform's
    report = subprocess.run([tool, "report", str(single.relative_to(work)), "--out", "rep"],
                            cwd=work, env=env, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert report.returncode == 0, report.stderr[-2000:]
    assert (work / "rep" / "fp6_camera.md").is_file()
    assert _tree(env_dir) == before_venv and _git_status() == before_git


def _git_status(root: Path = PROJECT_ROOT) -> str:
    return subprocess.run(["git", "status", "--porcelain"], cwd=root, capture_output=True,
                          text=True).stdout  # fmt: skip
