"""One file over HTTP, resumable and verified: ``<file>.part`` grows with HTTP ``Range``
requests, survives a dropped connection (retried) and a killed process (resumed), and becomes
the file only once its size and SHA-256 match what was expected (renamed into place), so a
final file is always whole. A network failure is a :class:`TransferError` that names the URL
and what to check; a file that differs from what was expected is a :class:`MismatchError`."""

from __future__ import annotations

import errno
import hashlib
import http.client
import os
import time
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import BinaryIO

import yaml
from tqdm import tqdm

CHUNK = 1 << 16
USER_AGENT = "ttc-bench-download/0.1"


class DownloadError(RuntimeError):
    """A file could not be downloaded or did not match the manifest."""


class TransferError(DownloadError):
    """The network failed or the connection dropped: worth a retry (the ``.part`` is kept)."""


class MismatchError(DownloadError):
    """The server's file differs from the manifest (size or sha256): not retried."""


class DiskFullError(DownloadError):
    """The disk (or quota) filled up while writing: not retried (the ``.part`` is kept)."""


#: ``OSError.errno`` values of a full disk or quota.
DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


@dataclass(frozen=True)
class FileEntry:
    """One file of the manifest, path relative to the sequence folder (POSIX separators)."""

    path: str
    size: int
    sha256: str

    @property
    def frame(self) -> int:
        """Frame index from the file name (``0000000042.png`` → 42)."""
        return int(PurePosixPath(self.path).stem)


def sha256_of(path: Path) -> str:
    """Hex sha256 of a file's content."""
    digest = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


@dataclass(frozen=True)
class FetchOptions:
    """Network settings: seconds per socket operation, retries of a dropped transfer."""

    timeout: float = 30.0
    retries: int = 2
    retry_delay: float = 1.0


@dataclass
class Meter:
    """The progress bar plus a count of the bytes that came over the network."""

    bar: tqdm
    received: int = 0

    def add(self, n: int) -> None:
        self.received += n
        self.bar.update(n)


def file_size(path: Path) -> int:
    """Size of a file, 0 when it does not exist."""
    return path.stat().st_size if path.exists() else 0


def is_complete(path: Path, entry: FileEntry) -> bool:
    """Whether ``path`` exists with the manifest's size and sha256."""
    return path.is_file() and file_size(path) == entry.size and sha256_of(path) == entry.sha256


def _network_hint(url: str, exc: BaseException | str) -> str:
    return (
        f"could not download {url}: {exc}. Check the network connection, or pass --base-url URL "
        "(a mirror of the sequence folder), or set TTC_DATA_DIR to a folder that already holds "
        "the data. Rerun to resume: partial files are kept."
    )


def _resume_start(resp: http.client.HTTPResponse, offset: int) -> int:
    """Byte offset the response body starts at: ``offset`` for a matching 206, else 0."""
    if offset and resp.status == 206:
        unit_range = (resp.headers.get("Content-Range") or "").split()
        if len(unit_range) == 2 and unit_range[1].split("-")[0] == str(offset):
            return offset
    return 0


def _declared_length(resp: http.client.HTTPResponse) -> int | None:
    value = resp.headers.get("Content-Length")
    return int(value) if value is not None and value.isdigit() else None


def _copy_body(resp: http.client.HTTPResponse, out: BinaryIO, limit: int, meter: Meter) -> int:
    """Copy the response into ``out``, at most ``limit + 1`` bytes (enough to detect excess)."""
    copied = 0
    while copied <= limit and (chunk := resp.read(min(CHUNK, limit + 1 - copied))):
        out.write(chunk)
        copied += len(chunk)
        meter.add(len(chunk))
    return copied


def _http_error(url: str, part: Path, offset: int, exc: urllib.error.HTTPError) -> DownloadError:
    """The error for an HTTP error status (retryable ones are TransferErrors)."""
    if exc.code == 416 and offset:  # the part is longer than the server's file: start again
        part.unlink(missing_ok=True)
        return TransferError(_network_hint(url, exc))
    if exc.code in (408, 429) or exc.code >= 500:
        return TransferError(_network_hint(url, exc))
    return DownloadError(_network_hint(url, exc))


def _fetch(url: str, part: Path, entry: FileEntry, timeout: float, meter: Meter) -> bool:
    """Append the rest of ``url`` to ``part`` (Range when it is partial); True if resumed."""
    offset = file_size(part)
    headers = {"User-Agent": USER_AGENT} | ({"Range": f"bytes={offset}-"} if offset else {})
    try:
        with urllib.request.urlopen(
            urllib.request.Request(url, headers=headers), timeout=timeout
        ) as resp:
            start = _resume_start(resp, offset)
            if start != offset:  # the server ignored the Range: the part restarts from 0
                meter.bar.update(start - offset)
            declared = _declared_length(resp)
            if declared is not None and start + declared != entry.size:
                part.unlink(missing_ok=True)
                raise MismatchError(
                    f"{entry.path}: size mismatch, expected {entry.size} bytes, "
                    f"got {start + declared} (from {url})"
                )
            with part.open("ab" if start else "wb") as out:
                copied = _copy_body(resp, out, entry.size - start, meter)
    except urllib.error.HTTPError as exc:
        raise _http_error(url, part, offset, exc) from exc
    except (urllib.error.URLError, http.client.HTTPException, OSError) as exc:
        if isinstance(exc, OSError) and exc.errno in DISK_FULL:
            raise DiskFullError(f"no space left writing {part}: {exc.strerror}") from exc
        raise TransferError(_network_hint(url, exc)) from exc
    if declared is not None and copied < declared:
        raise TransferError(
            _network_hint(url, f"connection closed after {copied} of {declared} bytes")
        )
    return bool(start)


def _fetch_with_retries(
    url: str, part: Path, entry: FileEntry, opts: FetchOptions, meter: Meter
) -> bool:
    """``_fetch``, again (resuming) after a dropped transfer; True if the last one resumed."""
    for attempt in range(opts.retries + 1):
        try:
            return _fetch(url, part, entry, opts.timeout, meter)
        except TransferError:
            if attempt == opts.retries:
                raise
            time.sleep(opts.retry_delay * (attempt + 1))
    raise AssertionError("unreachable")


def _verify_part(part: Path, entry: FileEntry) -> None:
    """Raise (and delete the part) unless it has the manifest's size and sha256."""
    size = file_size(part)
    got = sha256_of(part) if size == entry.size else ""
    if got == entry.sha256:
        return
    part.unlink(missing_ok=True)
    if size != entry.size:
        raise MismatchError(f"{entry.path}: size mismatch, expected {entry.size} bytes, got {size}")
    raise MismatchError(f"{entry.path}: sha256 mismatch, expected {entry.sha256}, got {got}")


def download_one(
    entry: FileEntry, base_url: str, dest: Path, opts: FetchOptions, meter: Meter
) -> bool:
    """Fetch one file into ``dest`` via ``dest.part``, verify, rename; True if it resumed a part."""
    url = base_url.rstrip("/") + "/" + urllib.parse.quote(entry.path)
    part = dest.with_name(dest.name + ".part")
    dest.parent.mkdir(parents=True, exist_ok=True)
    if file_size(part) > entry.size or (
        file_size(part) == entry.size and not is_complete(part, entry)
    ):
        part.unlink()  # a stale or foreign part: start again
    meter.bar.update(file_size(part))
    resumed = file_size(part) == entry.size or _fetch_with_retries(url, part, entry, opts, meter)
    _verify_part(part, entry)
    os.replace(part, dest)
    return resumed


def manifest_mapping(text: str, source: object) -> dict:
    """A download manifest's YAML mapping, parsed with PyYAML's C loader where built (a
    command reads one at every start: OmegaConf's loader took 0.16 s for the frames' 160
    entries, this 0.013 s). Text that is not a mapping is a ``ValueError`` naming ``source``."""
    raw = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))  # noqa: S506
    if not isinstance(raw, dict):
        raise ValueError(f"{source}: a download manifest is a mapping, not {type(raw).__name__}")
    return raw


def read_manifest(path: Path) -> dict:
    """:func:`manifest_mapping` of the file at ``path``."""
    return manifest_mapping(Path(path).read_text(encoding="utf-8"), path)
