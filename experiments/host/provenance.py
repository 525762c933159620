"""Where a result came from: code version, package versions, machine."""

from __future__ import annotations

import functools
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path

from experiments.host.paths import PROJECT_ROOT

PACKAGES = ("opencv-contrib-python-headless", "numpy", "scipy", "pandas", "pyarrow", "hydra-core")


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(
            ["git", *args], cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=10, check=True
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip()


@functools.cache
def code_version() -> dict[str, str | bool | None]:
    """Git commit of the project and whether the work tree has uncommitted changes to anything
    but the committed reports (``results/``, written by the reports themselves: regenerating
    one report must not make the next one's code version dirty)."""
    commit = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain", "--untracked-files=no", "--", ".", ":!results")
    return {"git_commit": commit, "git_dirty": bool(status) if status is not None else None}


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


@functools.cache
def package_versions() -> dict[str, str | None]:
    """Versions of Python and the packages that determine the numbers."""
    import cv2

    versions = {"python": platform.python_version(), "opencv": cv2.__version__}
    versions.update({name: _version(name) for name in PACKAGES[1:]})
    return versions


#: The project's folders whose Python and YAML files decide what a command computes.
SOURCE_ROOTS = ("conf", "experiments", "ttc", "hydra_plugins")


def source_identities(extra_roots: tuple[Path, ...] = ()) -> list[tuple[str, int, int]]:
    """(path, size in bytes, mtime in ns) of every ``.py`` / ``.yaml`` file under the project's
    :data:`SOURCE_ROOTS` and ``extra_roots``, sorted: a change to the code or configs shows."""
    files = []
    for root in (*(PROJECT_ROOT / r for r in SOURCE_ROOTS), *extra_roots):
        for path in sorted(Path(root).rglob("*")):
            if path.suffix in (".py", ".yaml", ".yml") and path.is_file():
                stat = path.stat()
                files.append((str(path), stat.st_size, stat.st_mtime_ns))
    return files


@functools.cache
def machine() -> dict[str, str | int | None]:
    """Host name, platform and core count."""
    import os

    return {
        "host": platform.node(),
        "platform": platform.platform(terse=True),
        "cpu_count": os.cpu_count(),
        "executable": sys.executable,
    }
