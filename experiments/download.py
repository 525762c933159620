"""Download the KITTI 2011_09_26 frames on a machine that does not have the data.

The 78 frames are the files the public Udacity ``SFND_3D_Object_Tracking`` repository ships
under ``images/KITTI/2011_09_26/``. A manifest (``conf/download/kitti_2011_09_26.yaml``) lists
every file with its size and sha256, and holds the two calibration files' text. Downloads are
resumable (``<file>.part`` + HTTP ``Range``), verified against the manifest, then renamed into
place atomically, so a final file is always whole::

    python -m experiments.download                          # all 78 frames into the data root
    python -m experiments.download --first 0 --last 18      # frames 0-18 only
    python -m experiments.download --base-url http://mirror/kitti/2011_09_26/
    python -m experiments.download --write-manifest ../shared/data   # regenerate the manifest
"""

from __future__ import annotations

import argparse
import hashlib
import http.client
import os
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import BinaryIO

from omegaconf import DictConfig, ListConfig, OmegaConf
from tqdm import tqdm

from experiments.paths import PROJECT_ROOT, default_data_root
from ttc.atomic import write_bytes_atomic

DEFAULT_BASE_URL = (
    "https://raw.githubusercontent.com/udacity/SFND_3D_Object_Tracking/master/"
    "images/KITTI/2011_09_26/"
)
DEFAULT_MANIFEST = PROJECT_ROOT / "conf" / "download" / "kitti_2011_09_26.yaml"
DEFAULT_TARGET = "kitti/2011_09_26"
FRAME_DIRS = ("image_02/data", "velodyne_points/data")
CALIB_FILES = ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt")
CHUNK = 1 << 16
USER_AGENT = "ttc-bench-download/0.1"


class DownloadError(RuntimeError):
    """A file could not be downloaded or did not match the manifest."""


class TransferError(DownloadError):
    """The network failed or the connection dropped: worth a retry (the ``.part`` is kept)."""


class MismatchError(DownloadError):
    """The server's file differs from the manifest (size or sha256): not retried."""


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


@dataclass(frozen=True)
class Manifest:
    """Where to download from, where to put it, what to expect, and the calibration text."""

    base_url: str
    target: str
    files: tuple[FileEntry, ...]
    calib: dict[str, str]


@dataclass
class DownloadReport:
    """What a call did: files fetched, files already complete, bytes over the network."""

    target: Path
    downloaded: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    resumed: list[str] = field(default_factory=list)
    calib_written: list[str] = field(default_factory=list)
    bytes_downloaded: int = 0

    def summary(self) -> str:
        """One line for the terminal."""
        return (
            f"downloaded {len(self.downloaded)} files ({self.bytes_downloaded / 1e6:.1f} MB"
            f", {len(self.resumed)} resumed), skipped {len(self.skipped)} already complete"
            f", wrote {len(self.calib_written)} calib files → {self.target}"
        )


# ---------------------------------------------------------------------------------------------
# Manifest


def load_manifest(path: Path = DEFAULT_MANIFEST) -> Manifest:
    """Read a download manifest YAML."""
    return _parse_manifest(OmegaConf.load(path))


def _parse_manifest(cfg: DictConfig | ListConfig) -> Manifest:
    raw = OmegaConf.to_container(cfg, resolve=True)
    if not isinstance(raw, dict):
        raise ValueError("a download manifest is a mapping (base_url, target, files, calib)")
    files = tuple(FileEntry(str(f["path"]), int(f["size"]), str(f["sha256"])) for f in raw["files"])
    calib = {str(name): str(text) for name, text in (raw.get("calib") or {}).items()}
    return Manifest(str(raw["base_url"]), str(raw["target"]), files, calib)


def sha256_of(path: Path) -> str:
    """Hex sha256 of a file's content."""
    digest = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def scan_source(src: Path) -> list[FileEntry]:
    """Manifest entries of every frame file under a sequence folder, sorted by path."""
    paths = sorted(p for d in FRAME_DIRS for p in (src / d).iterdir() if p.is_file())
    if not paths:
        raise FileNotFoundError(f"no frame files under {src} ({', '.join(FRAME_DIRS)})")
    return [FileEntry(p.relative_to(src).as_posix(), p.stat().st_size, sha256_of(p)) for p in paths]


def _yaml_block(text: str, indent: str) -> str:
    """``text`` as a YAML literal block scalar that loads back unchanged."""
    if not text or text.endswith("\n\n") or any(line[:1].isspace() for line in text.splitlines()):
        raise ValueError("calibration text cannot be kept exactly as a YAML block string")
    style = "|" if text.endswith("\n") else "|-"
    body = "".join(f"{indent}{line}\n" for line in text.splitlines())
    return f"{style}\n{body}"


def manifest_yaml(
    entries: Iterable[FileEntry], calib: dict[str, str], base_url: str, target: str
) -> str:
    """The manifest file's text (written by hand to keep one compact line per file)."""
    lines = [
        "# Files of KITTI raw 2011_09_26 (78 frames) for `python -m experiments.download`.",
        "# Generated by `python -m experiments.download --write-manifest <sequence folder>`;",
        "# calib texts are copied exactly from the sequence's calib_*.txt files.",
        f"base_url: {base_url}",
        f"target: {target}            # sub-folder of the data root",
        "files:",
    ]
    lines += [f'  - {{path: {e.path}, size: {e.size}, sha256: "{e.sha256}"}}' for e in entries]
    lines.append("calib:")
    lines += [f"  {name}: {_yaml_block(text, '    ')}" for name, text in sorted(calib.items())]
    return "\n".join(lines).rstrip("\n") + "\n"


def write_manifest(
    src: Path,
    out: Path = DEFAULT_MANIFEST,
    base_url: str = DEFAULT_BASE_URL,
    target: str = DEFAULT_TARGET,
) -> Manifest:
    """Scan a sequence folder (e.g. ``<data>/kitti/2011_09_26``), write the manifest, check it."""
    src = Path(src)
    if not (src / FRAME_DIRS[0]).is_dir() and (src / target / FRAME_DIRS[0]).is_dir():
        src = src / target  # a data root was given
    entries = scan_source(src)
    calib = {name: (src / name).read_text(encoding="utf-8") for name in CALIB_FILES}
    text = manifest_yaml(entries, calib, base_url, target)
    manifest = _parse_manifest(OmegaConf.create(text))
    if manifest.files != tuple(entries) or manifest.calib != calib:
        raise ValueError(f"the manifest text does not load back to what was scanned from {src}")
    write_bytes_atomic(text.encode("utf-8"), Path(out))
    return manifest


# ---------------------------------------------------------------------------------------------
# Download


@dataclass(frozen=True)
class FetchOptions:
    """Network settings: seconds per socket operation, retries of a dropped transfer."""

    timeout: float = 30.0
    retries: int = 2
    retry_delay: float = 1.0


@dataclass
class _Meter:
    """The progress bar plus a count of the bytes that came over the network."""

    bar: tqdm
    received: int = 0

    def add(self, n: int) -> None:
        self.received += n
        self.bar.update(n)


def _size(path: Path) -> int:
    """Size of a file, 0 when it does not exist."""
    return path.stat().st_size if path.exists() else 0


def _is_complete(path: Path, entry: FileEntry) -> bool:
    """Whether ``path`` exists with the manifest's size and sha256."""
    return path.is_file() and _size(path) == entry.size and sha256_of(path) == entry.sha256


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


def _copy_body(resp: http.client.HTTPResponse, out: BinaryIO, limit: int, meter: _Meter) -> int:
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


def _fetch(url: str, part: Path, entry: FileEntry, timeout: float, meter: _Meter) -> bool:
    """Append the rest of ``url`` to ``part`` (Range when it is partial); True if resumed."""
    offset = _size(part)
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
        raise TransferError(_network_hint(url, exc)) from exc
    if declared is not None and copied < declared:
        raise TransferError(
            _network_hint(url, f"connection closed after {copied} of {declared} bytes")
        )
    return bool(start)


def _fetch_with_retries(
    url: str, part: Path, entry: FileEntry, opts: FetchOptions, meter: _Meter
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
    size = _size(part)
    got = sha256_of(part) if size == entry.size else ""
    if got == entry.sha256:
        return
    part.unlink(missing_ok=True)
    if size != entry.size:
        raise MismatchError(f"{entry.path}: size mismatch, expected {entry.size} bytes, got {size}")
    raise MismatchError(f"{entry.path}: sha256 mismatch, expected {entry.sha256}, got {got}")


def _download_one(
    entry: FileEntry, base_url: str, dest: Path, opts: FetchOptions, meter: _Meter
) -> bool:
    """Fetch one file into ``dest`` via ``dest.part``, verify, rename; True if it resumed a part."""
    url = base_url.rstrip("/") + "/" + urllib.parse.quote(entry.path)
    part = dest.with_name(dest.name + ".part")
    dest.parent.mkdir(parents=True, exist_ok=True)
    if _size(part) > entry.size or (_size(part) == entry.size and not _is_complete(part, entry)):
        part.unlink()  # a stale or foreign part: start again
    meter.bar.update(_size(part))
    resumed = _size(part) == entry.size or _fetch_with_retries(url, part, entry, opts, meter)
    _verify_part(part, entry)
    os.replace(part, dest)
    return resumed


def _select(files: Sequence[FileEntry], frames: range | None) -> list[FileEntry]:
    """The manifest entries of ``frames`` (all when None); unknown frames are an error."""
    if frames is None:
        return list(files)
    missing = sorted(set(frames) - {e.frame for e in files})
    if missing:
        raise ValueError(f"frames {missing} are not in the manifest (it has {len(files)} files)")
    return [e for e in files if e.frame in frames]


def _write_calib(target: Path, calib: dict[str, str], report: DownloadReport) -> None:
    """Write the calibration files beside the frames (atomically; unchanged ones are left)."""
    for name, text in calib.items():
        path, data = target / name, text.encode("utf-8")
        if not (path.is_file() and path.read_bytes() == data):
            write_bytes_atomic(data, path)
            report.calib_written.append(name)


def download_dataset(
    data_root: Path,
    base_url: str | None = None,
    manifest: Manifest | Path = DEFAULT_MANIFEST,
    frames: range | None = None,
    progress: bool = True,
    options: FetchOptions | None = None,
) -> DownloadReport:
    """Download (or complete) the manifest's files of ``frames`` into ``data_root/<target>``."""
    if not isinstance(manifest, Manifest):
        manifest = load_manifest(Path(manifest))
    target = Path(data_root) / manifest.target
    report = DownloadReport(target=target)
    todo = []
    for entry in _select(manifest.files, frames):
        if _is_complete(target / entry.path, entry):
            report.skipped.append(entry.path)
        else:
            todo.append(entry)
    total = sum(e.size for e in todo)
    with tqdm(total=total, unit="B", unit_scale=True, disable=not progress or not todo) as bar:
        meter = _Meter(bar)
        for entry in todo:
            bar.set_postfix_str(entry.path, refresh=False)
            url = base_url or manifest.base_url
            if _download_one(entry, url, target / entry.path, options or FetchOptions(), meter):
                report.resumed.append(entry.path)
            report.downloaded.append(entry.path)
    report.bytes_downloaded = meter.received
    _write_calib(target, manifest.calib, report)
    return report


# ---------------------------------------------------------------------------------------------
# CLI


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m experiments.download", description=__doc__.split("\n")[0]
    )
    p.add_argument(
        "--data-root", type=Path, default=None, help="default: $TTC_DATA_DIR else ../shared/data"
    )
    p.add_argument(
        "--base-url", default=None, help="folder URL holding image_02/ and velodyne_points/"
    )
    p.add_argument("--first", type=int, default=None, help="first frame (default 0)")
    p.add_argument(
        "--last", type=int, default=None, help="last frame, inclusive (default: the last one)"
    )
    p.add_argument("--manifest", type=Path, default=DEFAULT_MANIFEST)
    p.add_argument("--timeout", type=float, default=30.0, help="seconds per network operation")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument(
        "--write-manifest",
        type=Path,
        metavar="SRC",
        default=None,
        help="regenerate --manifest from a local copy of the sequence (or data root) and exit",
    )
    return p


def _frames(args: argparse.Namespace, manifest: Manifest) -> range | None:
    if args.first is None and args.last is None:
        return None
    last = args.last if args.last is not None else max(e.frame for e in manifest.files)
    return range(args.first or 0, last + 1)


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    args = _parser().parse_args(argv)
    if args.write_manifest is not None:
        m = write_manifest(args.write_manifest, args.manifest)
        print(f"wrote {args.manifest}: {len(m.files)} files, {sum(e.size for e in m.files)} bytes")
        return 0
    manifest = load_manifest(args.manifest)
    data_root = args.data_root or default_data_root()
    try:
        report = download_dataset(
            data_root,
            args.base_url,
            manifest,
            _frames(args, manifest),
            not args.no_progress,
            FetchOptions(timeout=args.timeout),
        )
    except (DownloadError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted: rerun the same command to resume", file=sys.stderr)
        return 130
    print(report.summary())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
