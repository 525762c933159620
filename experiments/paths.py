"""Where things are: the project root and the default data, cache and results folders.

The one place that resolves them. Each default can be moved by an environment variable; the
Hydra configs read them through the ``ttc_path`` resolver (:func:`experiments.config.register_configs`),
so the command line, the reports and the download command agree.
"""

from __future__ import annotations

import os
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[1]

#: The shared data folder beside the project (the developers' and CI's copy of the frames).
SHARED_DATA = PROJECT_ROOT.parent / "shared" / "data"
#: Where the main command downloads the frames on a machine without them.
PROJECT_DATA = PROJECT_ROOT / "data"
#: Environment variable and default of each folder (relative defaults are under the project).
LOCATIONS: dict[str, tuple[str, Path]] = {
    "data": ("TTC_DATA_DIR", SHARED_DATA),
    "cache": ("TTC_CACHE_DIR", PROJECT_ROOT / "cache"),
    "results": ("TTC_RESULTS_DIR", PROJECT_ROOT / "sweeps"),
}


def resolve(path: str | Path) -> Path:
    """``path`` with ``~`` expanded, made absolute against the project root when relative."""
    p = Path(os.path.expanduser(str(path)))
    return p if p.is_absolute() else (PROJECT_ROOT / p).resolve()


def default(kind: str) -> Path:
    """The folder of ``kind`` (``data``, ``cache`` or ``results``): its environment variable
    when set, else the project's default."""
    variable, fallback = LOCATIONS[kind]
    value = os.environ.get(variable)
    if value:
        return resolve(value)
    if kind == "data":  # ../shared/data, else (a fresh machine) where the frames get downloaded
        return SHARED_DATA if SHARED_DATA.is_dir() else PROJECT_DATA
    return fallback


def default_data_root() -> Path:
    """``$TTC_DATA_DIR``, else ``../shared/data`` beside the project root when it exists,
    else ``./data`` in the project (where the main command downloads the frames)."""
    return default("data")


def default_cache_dir() -> Path:
    """``$TTC_CACHE_DIR``, else ``./cache`` in the project."""
    return default("cache")


def default_results_dir() -> Path:
    """``$TTC_RESULTS_DIR``, else ``./sweeps`` in the project."""
    return default("results")
