"""``ttc-bench export``: one setting of a real sweep written as an MCAP file for Foxglove and
read back with the ``mcap`` reader: every frame's image, scan and boxes at the recording's own
times, every box of the rows with its TTC, Foxglove's schema names; a bag's export keeps the
bag's own topics (``--keep-topics``)."""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from scipy.spatial.transform import Rotation

from experiments import store
from experiments.report.load import make_context
from experiments.summary.references import object_references
from experiments.tools.export import TOPICS, select_run
from tests.conftest import data_root
from tests.test_report import make_sweep, run_module, shared_root
from ttc.io.calibration import load_calibration
from ttc.io.frames import frame_files, read_image
from ttc.io.timestamps import read_times_ns
from ttc.steps.lidar import project_to_image

DRIVE_0009 = Path("kitti_raw") / "2011_09_26" / "2011_09_26_drive_0009_sync"
#: Foxglove's schema of each exported topic (the JSON series is the harness's own).
SCHEMAS = {"image": "foxglove.CompressedImage", "points": "foxglove.PointCloud",
           "boxes": "foxglove.ImageAnnotations", "objects": "foxglove.SceneUpdate",
           "ttc": "ttc_bench.TrackTtc", "calibration": "foxglove.CameraCalibration",
           "transform": "foxglove.FrameTransform"}  # fmt: skip


def export(root: Path, sweep: Path, out: Path, *extra: str):
    """``ttc-bench export SWEEP --out OUT`` through the real command line."""
    args = ["export", str(sweep), "--out", str(out), "--cache-dir", str(root / "cache"), *extra]
    return run_module("experiments.cli", args, root)


def read_back(path: Path) -> tuple[dict[str, str], dict[str, list]]:
    """(schema name by topic, [(log time, decoded message)] by topic) of an MCAP file; the
    JSON topic's messages as dicts."""
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        messages, decoders = defaultdict(list), {}
        for schema, channel, message in reader.iter_messages(topics=list(TOPICS.values())):
            if schema.encoding == "jsonschema":
                decoded = json.loads(message.data)
            else:
                if schema.id not in decoders:
                    decoders[schema.id] = DecoderFactory().decoder_for("protobuf", schema)
                decoded = decoders[schema.id](message.data)
            messages[channel.topic].append((message.log_time, decoded))
    return schemas, messages


def stamp_ns(message) -> int:
    """A message's stamp (ns); an ``ImageAnnotations``' is also each of its elements'."""
    if hasattr(message, "texts"):
        stamps = {stamp_ns(e) for e in [*message.points, *message.texts]}
        assert (
            len(stamps) == 1
            and message.timestamp.seconds * 10**9 + message.timestamp.nanos in stamps
        )
    return message.timestamp.seconds * 1_000_000_000 + message.timestamp.nanos


def same_ttc(exported: float | None, row: float) -> bool:
    """A finite TTC exported exactly; a NaN or infinite one as null (NaN in a table)."""
    if math.isfinite(row):
        return exported == row
    return exported is None or math.isnan(exported)


@pytest.fixture(scope="module")
def export_0009(tmp_path_factory) -> tuple[Path, Path, Path]:
    """(root, sweep, mcap) of drive 0009 frames 0-15 under the default setting."""
    root = shared_root(tmp_path_factory)
    sweep = make_sweep(root, ["-m", "dataset=kitti_raw_0009", "sweep_name=export_0009"],
                       "export_0009")  # fmt: skip
    out = root / "export_0009.mcap"
    done = export(root, sweep, out)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "frames 0-15" in done.stdout and "MB in" in done.stdout
    return root, sweep, out


def test_an_export_of_drive_0009_holds_every_frame_at_the_recording_s_times(export_0009) -> None:
    _, _, out = export_0009
    schemas, messages = read_back(out)
    assert {schemas[TOPICS[k]] for k in SCHEMAS} == set(SCHEMAS.values())
    assert all(schemas[TOPICS[k]] == name for k, name in SCHEMAS.items())
    for key in ("image", "points", "boxes", "objects", "calibration", "transform"):
        assert len(messages[TOPICS[key]]) == 16, key
    drive = data_root() / DRIVE_0009
    camera = read_times_ns(drive / "image_02" / "timestamps.txt")[0][:16]
    lidar = read_times_ns(drive / "velodyne_points" / "timestamps.txt")[0][:16]
    for key, clock in (("image", camera), ("boxes", camera), ("points", lidar)):
        logged = np.array([t for t, _ in messages[TOPICS[key]]])
        stamped = np.array([stamp_ns(m) for _, m in messages[TOPICS[key]]])
        assert np.array_equal(logged, clock) and np.array_equal(stamped, clock), key
    for frame in (0, 15):  # the frame's own pixels (JPEG) and its whole scan, bit for bit
        _, image = messages[TOPICS["image"]][frame]
        decoded = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_COLOR)
        original = read_image(frame_files(drive, frame).image)
        assert image.format == "jpeg" and decoded.shape == original.shape
        assert cv2.PSNR(decoded, original) > 27.0  # dB: JPEG at quality 90 (29.2 on frame 0)
        other = read_image(frame_files(drive, 15 - frame).image)
        assert cv2.PSNR(decoded, other) < 20.0  # the frame's own image, not another's
        _, cloud = messages[TOPICS["points"]][frame]
        scan = np.fromfile(frame_files(drive, frame).scan, dtype="<f4")
        assert cloud.point_stride == 16 and [f.name for f in cloud.fields] == [
            "x",
            "y",
            "z",
            "intensity",
        ]
        assert np.array_equal(np.frombuffer(cloud.data, "<f4"), scan)


def test_the_exported_calibration_puts_the_scan_where_the_harness_projects_it(export_0009) -> None:
    """Foxglove draws the scan on the image through the exported ``CameraCalibration`` (P) and
    ``FrameTransform`` (lidar in the camera frame): the pixels of the KITTI projection
    ``P_rect_02 · R_rect_00 · [R | T]`` (the rotation made orthonormal: 10⁻⁵ px)."""
    _, _, out = export_0009
    _, messages = read_back(out)
    drive = data_root() / DRIVE_0009
    for frame in (0, 15):
        (_, camera), (_, move) = (
            messages[TOPICS["calibration"]][frame],
            messages[TOPICS["transform"]][frame],
        )
        assert (camera.frame_id, move.parent_frame_id, move.child_frame_id) == (
            "camera",
            "camera",
            "lidar",
        )
        assert (camera.width, camera.height) == (1242, 375)
        pose = np.eye(4)
        q = move.rotation
        pose[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
        pose[:3, 3] = [move.translation.x, move.translation.y, move.translation.z]
        points = np.fromfile(frame_files(drive, frame).scan, "<f4").reshape(-1, 4)[:, :3]
        points = points[points[:, 0] > 3.0].astype(float)
        seen = (np.array(camera.P).reshape(3, 4) @ pose @ np.c_[points, np.ones(len(points))].T).T
        harness = project_to_image(points, load_calibration(drive, "P_rect_02").velo_to_image)
        inside = (harness >= 0).all(axis=1) & (harness[:, 0] < 1242) & (harness[:, 1] < 375)
        gap = np.linalg.norm(seen[:, :2] / seen[:, 2:] - harness, axis=1)[inside]
        assert inside.sum() > 10_000 and gap.max() < 1e-3


def test_every_box_of_the_rows_is_exported_with_its_ttc(export_0009) -> None:
    root, sweep, out = export_0009
    rows, runs = store.load_sweep(sweep)
    boxes = rows[rows["curr_box"] >= 0]
    _, messages = read_back(out)
    series = pd.DataFrame([m for _, m in messages[TOPICS["ttc"]]])
    assert len(series) == len(boxes) > 50
    both = boxes.merge(series, left_on=["frame", "curr_box"], right_on=["frame", "box"],
                       suffixes=("", "_x"), validate="one_to_one")  # fmt: skip
    assert len(both) == len(boxes) and (both["track_id"] == both["track_id_x"]).all()
    for sensor in ("camera", "lidar"):
        assert all(map(same_ttc, both[f"ttc_{sensor}_x"], both[f"ttc_{sensor}"])), sensor
    # the reference TTC is every object's reference of the recording, joined on frame and box
    ctx = make_context(data_root(), root / "cache")
    ref = object_references(rows, runs, lambda r: ctx.detector_setup(runs, r), ctx.root, ctx.cache)
    ref = next(iter(ref.values()))[["frame", "box", "ttc_ref_s"]]
    judged = both.merge(ref.rename(columns={"box": "curr_box"}), on=["frame", "curr_box"])
    assert judged["ttc_ref_s"].notna().sum() >= 20
    assert all(map(same_ttc, judged["ttc_ref"], judged["ttc_ref_s"]))
    # the image annotations: one outline per box, its numbers in its metadata, its label
    camera = {stamp_ns(m): f for f, (_, m) in enumerate(messages[TOPICS["image"]])}
    for log_time, note in messages[TOPICS["boxes"]]:
        frame = camera[log_time]
        mine = boxes[boxes["frame"] == frame]
        tracks = sorted(int(dict((kv.key, kv.value) for kv in p.metadata)["track_id"])
                        for p in note.points)  # fmt: skip
        assert tracks == sorted(mine["track_id"]), frame
        labels = [t.text for t in note.texts]
        assert f"frame {frame}" in labels
        assert all(any(t.startswith(f"#{k} cam ") for t in labels) for k in mine["track_id"])
    for log_time, message in messages[TOPICS["ttc"]]:
        assert camera[log_time] == message["frame"]


@pytest.mark.slow  # a bag, a sweep and three exports in subprocesses (~35 s)
def test_a_bag_export_keeps_the_bag_s_own_topics(tmp_path_factory) -> None:
    pytest.importorskip("kitti2mcap", reason="installed by .ci/run (--no-deps)")
    from tests.ros2_bags import make_bag  # noqa: PLC0415 (kitti2mcap checked first)

    root = tmp_path_factory.mktemp("export_bag")
    bag = make_bag(root / "0009.mcap")
    args = ["-m", "dataset=kitti2mcap", f"dataset.path={bag}", "dataset.last=3", "sweep_name=bag"]
    sweep = make_sweep(root, args, "bag")
    out = root / "bag_export.mcap"
    done = export(root, sweep, out, "--keep-topics")
    assert done.returncode == 0, done.stderr[-3000:]
    with bag.open("rb") as f:
        original = make_reader(f)
        summary = original.get_summary()
        kept = {(c.topic, m.log_time, bytes(m.data)) for _, c, m in original.iter_messages()}
    with out.open("rb") as f:
        exported = make_reader(f)
        names = {c.topic: exported.get_summary().schemas[c.schema_id].name
                 for c in exported.get_summary().channels.values()}  # fmt: skip
        copied = {(c.topic, m.log_time, bytes(m.data)) for _, c, m in exported.iter_messages()
                  if not c.topic.startswith("/ttc_bench/")}  # fmt: skip
    assert copied == kept and len(kept) >= 16 * 3
    for channel in summary.channels.values():
        assert names[channel.topic] == summary.schemas[channel.schema_id].name
    _, messages = read_back(out)
    drive = data_root() / DRIVE_0009  # kitti2mcap stamps each message with KITTI's own times
    camera = read_times_ns(drive / "image_02" / "timestamps.txt")[0][:4]
    lidar = read_times_ns(drive / "velodyne_points" / "timestamps.txt")[0][:4]
    assert [t for t, _ in messages[TOPICS["image"]]] == list(camera)
    assert [t for t, _ in messages[TOPICS["points"]]] == list(lidar)
    assert len(messages[TOPICS["boxes"]]) == 4 and len(messages[TOPICS["ttc"]]) > 4

    # the bag damaged since (4 KiB flipped inside the chunk of frame 2's scan): that frame is
    # left out and named with its chunk, the others exported; its topics cannot be copied
    flip_inside_the_chunk_of(bag, lidar[2])
    damaged = export(root, sweep, root / "damaged.mcap")
    assert damaged.returncode == 0, damaged.stderr[-3000:]
    assert "frame 2 not exported" in damaged.stderr and "chunk" in damaged.stderr
    _, messages = read_back(root / "damaged.mcap")
    assert [t for t, _ in messages[TOPICS["image"]]] == [camera[0], camera[1], camera[3]]
    refused = export(root, sweep, root / "refused.mcap", "--keep-topics")
    assert refused.returncode == 1 and "Traceback" not in refused.stderr
    assert "cannot be copied whole" in refused.stderr and str(bag) in refused.stderr


def flip_inside_the_chunk_of(bag: Path, log_ns: int) -> None:
    """4 KiB flipped in the middle of the (zstd) chunk of ``bag`` that begins with the
    message logged at ``log_ns`` (a scan: compressed blocks, which zstd checks; an image's
    are stored raw and would only change pixels)."""
    with bag.open("rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    chunk = next(c for c in chunks if c.message_start_time == log_ns)
    data = bytearray(bag.read_bytes())
    middle = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[middle : middle + 4096] = bytes(b ^ 0xFF for b in data[middle : middle + 4096])
    bag.write_bytes(bytes(data))


def test_the_run_is_picked_by_id_or_setting_and_a_wrong_pick_says_which_exist() -> None:
    runs = pd.DataFrame({"run_id": ["aa11", "bb22", "cc33"], "status": ["ok", "ok", "failed"],
                         "detector": ["fast", "orb", "orb"], "descriptor": ["brief", "brief", "orb"]})  # fmt: skip
    assert select_run(runs, "bb", None, Path("s")) == "bb22"
    assert select_run(runs, None, "fast/brief", Path("s")) == "aa11"
    with pytest.raises(ValueError, match="matches 2 runs"):
        select_run(runs, None, None, Path("s"))
    with pytest.raises(ValueError, match=r"'orb/orb'.*matches no ok run(.|\n)*aa11"):
        select_run(runs, None, "orb/orb", Path("s"))


def test_keep_topics_on_a_folder_recording_is_one_clear_error(export_0009, tmp_path) -> None:
    root, sweep, _ = export_0009
    done = export(root, sweep, tmp_path / "x.mcap", "--keep-topics")
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert "--keep-topics" in done.stderr and "not a bag" in done.stderr
