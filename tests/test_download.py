"""The download command against a local HTTP server that serves the shared KITTI folder."""

from __future__ import annotations

import contextlib
import functools
import re
import socket
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from experiments.data import download as dl

FRAMES = range(0, 4)
IMAGE_1 = "image_02/data/0000000001.png"
SCAN_2 = "velodyne_points/data/0000000002.bin"


@dataclass
class ServerState:
    """What the handler saw, and how it should misbehave."""

    ranges: list[tuple[str, str]] = field(default_factory=list)  # (path, Range header)
    requests: list[str] = field(default_factory=list)
    serve_instead: dict[str, bytes] = field(default_factory=dict)  # path → body to send
    drop_once: set[str] = field(default_factory=set)  # paths whose first GET stops halfway
    ignore_range: bool = False  # behave like SimpleHTTPRequestHandler (always 200)


class RangeHandler(SimpleHTTPRequestHandler):
    """SimpleHTTPRequestHandler plus single ``bytes=N-`` ranges and injected faults."""

    state: ServerState
    timeout = 5  # a stuck client cannot hold a server thread

    def log_message(self, format: str, *args: object) -> None:
        """Quiet."""

    def do_GET(self) -> None:
        rel = self.path.lstrip("/")
        self.state.requests.append(rel)
        if rel in self.state.serve_instead:
            return self._send(200, self.state.serve_instead[rel])
        header = self.headers.get("Range")
        if self.state.ignore_range or (header is None and rel not in self.state.drop_once):
            return super().do_GET()
        file = Path(self.translate_path(self.path))
        if not file.is_file():
            return self.send_error(404)
        data = file.read_bytes()
        if header is None:  # announce the whole file, send half, close
            self.state.drop_once.discard(rel)
            self._send(200, data[: len(data) // 2], length=len(data))
            self.close_connection = True
            return None
        self.state.ranges.append((rel, header))
        start = int(re.fullmatch(r"bytes=(\d+)-", header).group(1))
        self._send(206, data[start:], content_range=f"bytes {start}-{len(data) - 1}/{len(data)}")
        return None

    def _send(
        self, status: int, body: bytes, length: int | None = None, content_range: str = ""
    ) -> None:
        self.send_response(status)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Content-Length", str(len(body) if length is None else length))
        if content_range:
            self.send_header("Content-Range", content_range)
        self.end_headers()
        self.wfile.write(body)


@contextlib.contextmanager
def serving(folder: Path) -> Iterator[tuple[str, ServerState]]:
    """A local HTTP server (127.0.0.1 only, ranges, injected faults) over ``folder``: (base
    URL, state)."""
    state = ServerState()
    handler = type("Handler", (RangeHandler,), {"state": state})
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(handler, directory=str(folder)))
    thread = threading.Thread(
        target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True
    )
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}/", state
    finally:
        httpd.shutdown()
        httpd.server_close()
        thread.join(timeout=5)


@pytest.fixture
def server(kitti_dir: Path) -> Iterator[tuple[str, ServerState]]:
    """A local server over the shared sequence folder: (base URL, state)."""
    with serving(kitti_dir) as served:
        yield served


@pytest.fixture(scope="module")
def manifest() -> dl.Manifest:
    return dl.load_manifest()


def _get(
    data_root: Path, url: str, manifest: dl.Manifest, frames: range = FRAMES
) -> dl.DownloadReport:
    options = dl.FetchOptions(timeout=5, retries=2, retry_delay=0)
    return dl.download_dataset(data_root, url, manifest, frames, progress=False, options=options)


def _subset(manifest: dl.Manifest, frames: range) -> list[dl.FileEntry]:
    return [e for e in manifest.files if e.frame in frames]


def test_manifest_matches_shared_data(manifest: dl.Manifest, kitti_dir: Path) -> None:
    on_disk = sorted(
        p.relative_to(kitti_dir).as_posix()
        for d in dl.FRAME_DIRS
        for p in (kitti_dir / d).iterdir()
    )
    assert [e.path for e in manifest.files] == on_disk
    assert len(manifest.files) == 156
    assert {e.frame for e in manifest.files} == set(range(78))
    for entry in manifest.files:
        assert (kitti_dir / entry.path).stat().st_size == entry.size, entry.path
    assert dl.sha256_of(kitti_dir / IMAGE_1) == next(
        e.sha256 for e in manifest.files if e.path == IMAGE_1
    )
    for name in dl.CALIB_FILES:
        assert manifest.calib[name] == (kitti_dir / name).read_text(encoding="utf-8")
    assert manifest.target == "kitti/2011_09_26"
    assert manifest.base_url == dl.DEFAULT_BASE_URL


def test_download_then_skip(server, manifest: dl.Manifest, kitti_dir: Path, tmp_path: Path) -> None:
    url, _ = server
    report = _get(tmp_path, url, manifest)
    target = tmp_path / "kitti" / "2011_09_26"
    entries = _subset(manifest, FRAMES)
    assert sorted(report.downloaded) == sorted(e.path for e in entries)
    assert report.bytes_downloaded == sum(e.size for e in entries)
    for entry in entries:
        assert (target / entry.path).read_bytes() == (kitti_dir / entry.path).read_bytes()
    for name in dl.CALIB_FILES:
        assert (target / name).read_bytes() == (kitti_dir / name).read_bytes()
    assert not list(tmp_path.rglob("*.part")) and not list(tmp_path.rglob("*.tmp"))
    again = _get(tmp_path, url, manifest)
    assert again.downloaded == [] and again.bytes_downloaded == 0 and again.calib_written == []
    assert len(again.skipped) == len(entries)


def test_partial_file_is_resumed_with_range(
    server, manifest: dl.Manifest, kitti_dir: Path, tmp_path: Path
) -> None:
    url, state = server
    source = (kitti_dir / SCAN_2).read_bytes()
    part = tmp_path / "kitti" / "2011_09_26" / (SCAN_2 + ".part")
    part.parent.mkdir(parents=True)
    part.write_bytes(source[:700_001])
    report = _get(tmp_path, url, manifest, range(2, 3))
    assert state.ranges == [(SCAN_2, "bytes=700001-")]
    assert report.resumed == [SCAN_2]
    assert report.bytes_downloaded == len(source) - 700_001 + next(
        e.size for e in _subset(manifest, range(2, 3)) if e.path != SCAN_2
    )
    assert (tmp_path / "kitti" / "2011_09_26" / SCAN_2).read_bytes() == source
    assert not part.exists()


def test_server_ignoring_range_restarts_the_part(
    server, manifest: dl.Manifest, kitti_dir: Path, tmp_path: Path
) -> None:
    url, state = server
    state.ignore_range = True
    source = (kitti_dir / SCAN_2).read_bytes()
    part = tmp_path / "kitti" / "2011_09_26" / (SCAN_2 + ".part")
    part.parent.mkdir(parents=True)
    part.write_bytes(source[:1000])
    report = _get(tmp_path, url, manifest, range(2, 3))
    assert report.resumed == []
    assert report.bytes_downloaded == sum(e.size for e in _subset(manifest, range(2, 3)))
    assert (tmp_path / "kitti" / "2011_09_26" / SCAN_2).read_bytes() == source


def test_dropped_connection_is_retried_and_resumed(
    server, manifest: dl.Manifest, kitti_dir: Path, tmp_path: Path
) -> None:
    url, state = server
    state.drop_once.add(SCAN_2)
    report = _get(tmp_path, url, manifest, range(2, 3))
    source = (kitti_dir / SCAN_2).read_bytes()
    assert state.ranges == [(SCAN_2, f"bytes={len(source) // 2}-")]
    assert report.resumed == [SCAN_2]
    assert (tmp_path / "kitti" / "2011_09_26" / SCAN_2).read_bytes() == source


def test_wrong_size_is_a_clear_error(
    server, manifest: dl.Manifest, kitti_dir: Path, tmp_path: Path
) -> None:
    url, state = server
    expected = (kitti_dir / IMAGE_1).stat().st_size
    state.serve_instead[IMAGE_1] = (kitti_dir / IMAGE_1).read_bytes()[:-10]
    with pytest.raises(
        dl.MismatchError, match=rf"{IMAGE_1}.*expected {expected} bytes, got {expected - 10}"
    ):
        _get(tmp_path, url, manifest, range(1, 2))
    final = tmp_path / "kitti" / "2011_09_26" / IMAGE_1
    assert not final.exists() and not final.with_name(final.name + ".part").exists()
    assert state.requests.count(IMAGE_1) == 1  # a mismatch is not retried


def test_wrong_content_same_size_fails_the_hash(
    server, manifest: dl.Manifest, kitti_dir: Path, tmp_path: Path
) -> None:
    url, state = server
    data = bytearray((kitti_dir / IMAGE_1).read_bytes())
    data[100] ^= 0xFF
    state.serve_instead[IMAGE_1] = bytes(data)
    with pytest.raises(dl.MismatchError, match=rf"{IMAGE_1}: sha256 mismatch"):
        _get(tmp_path, url, manifest, range(1, 2))
    assert not list((tmp_path / "kitti").rglob("0000000001.png*"))


def test_network_error_names_url_and_remedies(manifest: dl.Manifest, tmp_path: Path) -> None:
    with socket.socket() as sock:  # a port that nothing listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    with pytest.raises(dl.DownloadError) as err:
        _get(tmp_path, f"http://127.0.0.1:{port}/", manifest, range(0, 1))
    message = str(err.value)
    assert f"http://127.0.0.1:{port}/image_02/data/0000000000.png" in message
    assert "--base-url" in message and "TTC_DATA_DIR" in message


def test_unknown_frames_are_rejected(manifest: dl.Manifest, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="78"):
        _get(tmp_path, "http://127.0.0.1:9/", manifest, range(76, 79))


def test_cli(server, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    url, _ = server
    args = [
        "--data-root",
        str(tmp_path),
        "--base-url",
        url,
        "--first",
        "5",
        "--last",
        "5",
        "--no-progress",
    ]
    assert dl.main(args) == 0
    assert "downloaded 2 files" in capsys.readouterr().out
    assert (
        tmp_path / "kitti" / "2011_09_26" / "velodyne_points" / "data" / "0000000005.bin"
    ).is_file()


def test_write_manifest_round_trip(kitti_dir: Path, manifest: dl.Manifest, tmp_path: Path) -> None:
    out = tmp_path / "m.yaml"
    written = dl.write_manifest(kitti_dir, out)
    assert written == manifest
    assert out.read_text() == dl.DEFAULT_MANIFEST.read_text()


def test_a_manifest_that_is_not_a_mapping_names_its_file(tmp_path: Path) -> None:
    bad = tmp_path / "list.yaml"
    bad.write_text("- {path: a.png, size: 1, sha256: x}\n")
    with pytest.raises(ValueError, match=r"list\.yaml: a download manifest is a mapping"):
        dl.load_manifest(bad)
