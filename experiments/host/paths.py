"""Where things are: the config tree, the source, and the default data, cache and results folders.

The one place that resolves them. Two layouts:

* **a checkout** (``pip install -e .`` or ``python -m`` in the repository): the defaults are
  under the checkout, as they always were — ``./sweeps``, ``./cache``, ``./data`` (or
  ``../shared/data`` beside it) — and relative paths are taken against the checkout root;
* **an installed wheel** (``pip install .``): nothing is written where the code is installed.
  Results go to ``./sweeps`` in the working directory, relative paths are taken against the
  working directory, and the stage cache and downloaded frames and weights go to the platform's
  cache folder (``$XDG_CACHE_HOME/ttc-bench``, default ``~/.cache/ttc-bench``).

Each default can be moved by an environment variable (:data:`LOCATIONS`); the Hydra configs
read them through the ``ttc_path`` resolver (:func:`experiments.configs.structured.register_configs`), so
the command line, the reports and the download command agree.
"""

from __future__ import annotations

import os
from pathlib import Path

#: The folder holding the ``ttc``, ``experiments`` and ``hydra_plugins`` packages: the checkout
#: root, or ``site-packages`` for an installed wheel.
SOURCE_ROOT = Path(__file__).resolve().parents[2]


def _checkout(root: Path) -> Path | None:
    """``root`` when it is a source checkout (its ``pyproject.toml`` and ``conf/`` beside the
    packages), else None."""
    return root if (root / "pyproject.toml").is_file() and (root / "conf").is_dir() else None


#: The checkout root when running from a checkout, None for an installed wheel.
CHECKOUT = _checkout(SOURCE_ROOT)
#: Kept for the code that needs the checkout (git, benchmarks): the source root.
PROJECT_ROOT = SOURCE_ROOT
#: The Hydra config tree: ``conf/`` in a checkout, the copy packaged as ``experiments/conf``
#: (pyproject ``[tool.setuptools.package-dir]``) in a wheel.
CONF_DIR = SOURCE_ROOT / "conf" if CHECKOUT is not None else SOURCE_ROOT / "experiments" / "conf"
#: Manifests of what the first run downloads (frames, YOLO weights).
DOWNLOAD_DIR = CONF_DIR / "download"

#: The shared data folder beside the checkout (the developers' and CI's copy of the frames).
SHARED_DATA = SOURCE_ROOT.parent / "shared" / "data"
#: Where the main command downloads the frames on a fresh clone.
PROJECT_DATA = SOURCE_ROOT / "data"
APP_NAME = "ttc-bench"
#: Environment variable of each folder.
LOCATIONS: dict[str, str] = {
    "data": "TTC_DATA_DIR",
    "cache": "TTC_CACHE_DIR",
    "results": "TTC_RESULTS_DIR",
}


def base_dir() -> Path:
    """What relative paths are taken against: the checkout root, else the working directory."""
    return CHECKOUT if CHECKOUT is not None else Path.cwd()


def user_cache_dir() -> Path:
    """The platform cache folder of this tool: ``$XDG_CACHE_HOME/ttc-bench``, default
    ``~/.cache/ttc-bench`` (``%LOCALAPPDATA%/ttc-bench`` on Windows)."""
    xdg = os.environ.get("XDG_CACHE_HOME") or os.environ.get("LOCALAPPDATA")
    root = Path(xdg) if xdg else Path.home() / ".cache"
    return root / APP_NAME


def resolve(path: str | Path) -> Path:
    """``path`` with ``~`` expanded, made absolute against :func:`base_dir` when relative."""
    p = Path(os.path.expanduser(str(path)))
    return p if p.is_absolute() else (base_dir() / p).resolve()


def _fallback(kind: str) -> Path:
    """The default of ``kind`` when its environment variable is not set."""
    if CHECKOUT is not None:
        if kind == "data":  # ../shared/data, else (a fresh clone) where the frames get downloaded
            return SHARED_DATA if SHARED_DATA.is_dir() else PROJECT_DATA
        return CHECKOUT / {"cache": "cache", "results": "sweeps"}[kind]
    if kind == "results":
        return Path.cwd() / "sweeps"
    return user_cache_dir() / kind


def default(kind: str) -> Path:
    """The folder of ``kind`` (``data``, ``cache`` or ``results``): its environment variable
    when set, else the default of the layout (see the module docstring)."""
    value = os.environ.get(LOCATIONS[kind])
    return resolve(value) if value else _fallback(kind)


def default_data_root() -> Path:
    """``$TTC_DATA_DIR``, else ``../shared/data`` beside a checkout when it exists, else
    ``./data`` in the checkout, else (a wheel) ``~/.cache/ttc-bench/data``."""
    return default("data")


def default_cache_dir() -> Path:
    """``$TTC_CACHE_DIR``, else ``./cache`` in the checkout, else ``~/.cache/ttc-bench/cache``."""
    return default("cache")


def default_results_dir() -> Path:
    """``$TTC_RESULTS_DIR``, else ``./sweeps`` in the checkout, else ``./sweeps`` in the
    working directory."""
    return default("results")


def shown(path: str | Path) -> str:
    """``path`` as a report names it: relative to the working directory when it lies under it
    (so a committed report does not carry the machine's folders), else absolute."""
    p = Path(os.path.expanduser(str(path))).absolute()
    try:
        return p.relative_to(Path.cwd()).as_posix()
    except ValueError:
        return p.as_posix()
