"""One setting of a sweep as an MCAP file that Foxglove opens: scrub through the drive with
the camera image, the lidar scan, every box with its track id and its camera, lidar and
reference TTC, and each track's TTC as a time series.

Usage::

    ttc-bench export sweeps/x --out drive.mcap                       # the sweep's only setting
    ttc-bench export sweeps/fp6_grid_kitti_0_18 --run 3f2a... --out x.mcap
    ttc-bench export sweeps/fp6_grid_kitti_0_18 --setting sift/sift/flann/nn --out x.mcap
    ttc-bench export sweeps/bag --out bag_results.mcap --keep-topics    # the bag's topics too

``--setting``: the run's axis values '/'-joined in the order of ``ttc.settings.AXES``
(detector/descriptor/matcher/selector/box_matching/...), as many as pick one run. Topics
(:data:`TOPICS`): ``/ttc_bench/image`` (``foxglove.CompressedImage``), ``/ttc_bench/points``
(``foxglove.PointCloud``, frame ``lidar``), ``/ttc_bench/boxes`` (``foxglove.ImageAnnotations``),
``/ttc_bench/objects`` (``foxglove.SceneUpdate``) one message a frame, and ``/ttc_bench/ttc``
(JSON, ``ttc_bench.TrackTtc``) one message per tracked box and frame. Times are the
recording's (:func:`sensor_clocks`). The reference TTC is every object's
(:func:`experiments.summary.references.object_references`).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.dataset as ds

from experiments import store
from experiments.data.first_run import fail
from experiments.host.paths import resolve
from experiments.report.load import Context, make_context
from experiments.summary.recordings import recording_source_of
from experiments.summary.references import object_references
from experiments.tools import foxglove_messages as fm
from experiments.tools.mcap_out import McapOut
from ttc.features.objects import ModelFileError
from ttc.io import kitti_odometry
from ttc.io.bag_recording import topics, unpaired_errors
from ttc.io.calibration import Calibration, load_calibration
from ttc.io.frame_errors import FrameDataError
from ttc.io.frames import (
    IMAGE_DIR,
    LIDAR_DIR,
    frame_clock_ns,
    frame_files,
    frame_interval,
    read_image,
    read_lidar_scan,
)
from ttc.io.ros2_bag import BagSource, bag_files, header_stamp_ns
from ttc.io.timestamps import MISSING_NS, read_times_ns
from ttc.settings import AXES

TOPICS = {"image": "/ttc_bench/image", "points": "/ttc_bench/points",
          "boxes": "/ttc_bench/boxes", "objects": "/ttc_bench/objects", "ttc": "/ttc_bench/ttc",
          "calibration": "/ttc_bench/calibration", "transform": "/ttc_bench/transform"}  # fmt: skip
CAMERA_FRAME, LIDAR_FRAME = "camera", "lidar"
#: Columns of the rows the export reads.
ROW_COLUMNS = ["run_id", "prev_frame", "frame", "track_id", "curr_box", "prev_box", "is_lead",
               "box_x", "box_y", "box_w", "box_h", "ttc_camera", "ttc_lidar", "camera_reason",
               "lidar_reason", "ego_speed_mps", "error"]  # fmt: skip


@dataclass
class Exported:
    """What an export wrote: the file, its run, frames, messages per topic, bytes, seconds."""

    path: Path
    run_id: str
    frames: list[int]
    counts: dict[str, int]
    size_bytes: int
    seconds: float
    skipped: dict[int, str]
    copied: int = 0
    notes: list[str] = field(default_factory=list)


def select_run(runs: pd.DataFrame, run: str | None, setting: str | None, sweep: Path) -> str:
    """The run id of the ok run of ``runs`` that ``run`` (an id or its prefix) or ``setting``
    (axis values '/'-joined in :data:`AXES` order) names; with neither, the sweep's only ok
    run. A ValueError lists the candidates when none or several match."""
    ok = runs[runs["status"] == "ok"] if "status" in runs else runs
    if run:
        found = ok[ok["run_id"].str.startswith(run)]
        what = f"run id {run!r}"
    elif setting:
        values = setting.strip("/").split("/")
        if len(values) > len(AXES):
            axes = "/".join(AXES)
            raise ValueError(f"--setting {setting!r} has {len(values)} values; the axes: {axes}")
        keep = np.ones(len(ok), dtype=bool)
        for axis, value in zip(AXES, values, strict=False):
            keep &= ok[axis].astype(str).to_numpy() == value if axis in ok else False
        found, what = ok[keep], f"setting {setting!r} ({'/'.join(AXES[: len(values)])})"
    else:
        found, what = ok, "no --run or --setting"
    if len(found) == 1:
        return str(found["run_id"].iloc[0])
    shown = ok if found.empty else found  # the runs to pick from (20 at most)
    listing = "\n".join(f"  {r.run_id}  {'/'.join(str(getattr(r, a, '')) for a in AXES)}"
                        for r in shown.head(20).itertuples())  # fmt: skip
    problem = "matches no ok run" if found.empty else f"matches {len(found)} runs"
    raise ValueError(f"{sweep}: {what} {problem}; pick one with --run or --setting:\n{listing}")


def run_rows(sweep: Path, run_id: str) -> pd.DataFrame:
    """The rows of one run of a sweep, on :data:`ROW_COLUMNS` (those the sweep has)."""
    dataset = store.rows_dataset(sweep)
    columns = [c for c in ROW_COLUMNS if c in dataset.schema.names]
    return dataset.to_table(filter=ds.field("run_id") == run_id, columns=columns).to_pandas()


def box_table(rows: pd.DataFrame, reference: pd.DataFrame | None) -> pd.DataFrame:
    """One row per current box of the run (``curr_box`` >= 0) as
    :mod:`experiments.tools.foxglove_messages` reads it: ``box``, ``ttc_ref`` (the object
    reference's ``ttc_ref_s`` joined on frame and box; NaN without one), ``role``,
    ``distance_m`` and ``bearing_deg``."""
    boxes = rows[rows["curr_box"].to_numpy() >= 0].rename(columns={"curr_box": "box"})
    ref_columns = {"ttc_ref_s": "ttc_ref", "role": "role", "distance_m": "distance_m",
                   "bearing_deg": "bearing_deg"}  # fmt: skip
    if reference is not None and not reference.empty:
        ref = reference[["frame", "box", *[c for c in ref_columns if c in reference]]]
        boxes = boxes.merge(ref.rename(columns=ref_columns), on=["frame", "box"], how="left",
                            validate="many_to_one")  # fmt: skip
    defaults = {"ttc_ref": np.nan, "role": "", "distance_m": np.nan, "bearing_deg": np.nan,
                "camera_reason": "", "lidar_reason": ""}  # fmt: skip
    for column, value in defaults.items():
        boxes[column] = boxes[column].fillna(value) if column in boxes else value
    boxes["role"] = boxes["role"].astype(str)
    return boxes.sort_values(["frame", "box"], ignore_index=True)


def _kitti_clock(source: Path, folder: Path) -> np.ndarray | None:
    """One sensor's ``timestamps.txt`` of a KITTI raw recording in ns, or None."""
    path = source / folder.parent / "timestamps.txt"
    return read_times_ns(path)[0] if path.is_file() else None


def _bag_stamp(source: BagSource, frame: int) -> int:
    """A bag frame's camera header stamp (ns), :data:`MISSING_NS` where a damaged chunk holds
    it (the frame is then left out, its image read naming the chunk)."""
    try:
        return int(frame_clock_ns(source)[frame])
    except FrameDataError:
        return MISSING_NS


def sensor_clocks(source: Path | BagSource, frames: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """(camera, lidar) time in ns since 1970 of each of ``frames``: a KITTI raw recording's
    ``image_02/`` and ``velodyne_points/`` ``timestamps.txt`` (one stands for the other where
    it is missing or blank); a bag's camera header stamps and its paired scans'; a KITTI
    odometry sequence's ``times.txt`` (from 0); else 10 Hz from 0 (the Udacity copy of drive 0052)."""
    if isinstance(source, BagSource):
        camera = np.array([_bag_stamp(source, i) for i in frames], dtype=np.int64)
        index, _, _, lidar_topic = topics(source)
        scans = [frame_files(source, i).scan.position if c != MISSING_NS else -1
                 for i, c in zip(frames, camera, strict=True)]  # fmt: skip
        lidar = [header_stamp_ns(index, lidar_topic, s) if s >= 0 else c
                 for s, c in zip(scans, camera, strict=True)]  # fmt: skip
        return camera, np.array(lidar, dtype=np.int64)
    if kitti_odometry.is_odometry_sequence(source):
        seconds = kitti_odometry.read_times(source)
        if seconds is not None:
            ns = np.round(np.asarray(seconds)[frames] * 1e9).astype(np.int64)
            return ns, ns
    camera, lidar = _kitti_clock(source, IMAGE_DIR), _kitti_clock(source, LIDAR_DIR)
    nominal = (np.arange(max(frames) + 1) * frame_interval() * 1e9).astype(np.int64)
    camera = lidar if camera is None else camera
    lidar = camera if lidar is None else lidar
    if camera is None:
        return nominal[frames], nominal[frames]
    camera, lidar = camera[frames], lidar[frames]
    camera = np.where(camera == MISSING_NS, lidar, camera)
    return camera, np.where(lidar == MISSING_NS, camera, lidar)


def frame_header(label: str, frame: int, rows: pd.DataFrame) -> list[str]:
    """The top-left lines of a frame's annotations: the setting, the frame, a frame error."""
    lines = [label, f"frame {frame}"]
    errors = [e for e in rows.get("error", pd.Series(dtype=str)).astype(str) if e]
    return lines + [f"error: {errors[0][:160]}"] if errors else lines


def camera_from_lidar(calib: Calibration) -> np.ndarray:
    """4 × 4 pose of the lidar in the rectified camera frame (``R_rect_00 · [R | T]``, m):
    ``calib.p_rect`` then projects it to pixels, as :attr:`Calibration.velo_to_image` does."""
    r_rect = np.eye(4)
    r_rect[:3, :3] = calib.r_rect_00
    return r_rect @ calib.velo_to_cam


def write_frame(out: McapOut, source, frame: int, clocks: tuple[int, int], boxes: pd.DataFrame,
                header: list[str], image_format: str, calib: Calibration) -> None:  # fmt: skip
    """Every exported topic's messages of one frame (its image and scan read here)."""
    camera_ns, lidar_ns = clocks
    files = frame_files(source, frame)
    image = read_image(files.image)
    scan = read_lidar_scan(files.scan).points
    size = (image.shape[1], image.shape[0])
    out.proto(
        TOPICS["calibration"],
        fm.camera_calibration(calib.p_rect, size, camera_ns, CAMERA_FRAME),
        camera_ns,
    )
    out.proto(
        TOPICS["transform"],
        fm.frame_transform(camera_from_lidar(calib), camera_ns, CAMERA_FRAME, LIDAR_FRAME),
        camera_ns,
    )
    out.proto(
        TOPICS["image"],
        fm.compressed_image(image, camera_ns, CAMERA_FRAME, image_format),
        camera_ns,
    )
    out.proto(TOPICS["points"], fm.point_cloud(scan, lidar_ns, LIDAR_FRAME), lidar_ns)
    out.proto(TOPICS["boxes"], fm.box_annotations(boxes, camera_ns, header), camera_ns)
    out.proto(TOPICS["objects"], fm.scene_update(boxes, lidar_ns, LIDAR_FRAME), lidar_ns)
    for message in fm.track_messages(boxes, camera_ns, frame):
        out.json(TOPICS["ttc"], fm.TRACK_SCHEMA, message, camera_ns)


def export(
    sweep: Path, out_path: Path, run: str | None = None, setting: str | None = None,
    keep_topics: bool = False, ctx: Context | None = None, image_format: str = "jpeg",
) -> Exported:  # fmt: skip
    """Write one run of ``sweep`` as an MCAP file at ``out_path`` (:mod:`experiments.tools.export`)."""
    start = time.perf_counter()
    ctx = ctx or make_context()
    runs = store.load_runs(sweep)
    if runs.empty:
        raise ValueError(f"{sweep}: no run records (runs/*.json)")
    run_id = select_run(runs, run, setting, sweep)
    runs = runs[runs["run_id"] == run_id]
    rows = run_rows(sweep, run_id)
    _, rng = ctx.detector_setup(runs, run_id)
    source = recording_source_of(runs, run_id, ctx.root)
    if keep_topics and not isinstance(source, BagSource):
        raise ValueError(f"--keep-topics: run {run_id} read {source}, not a bag (dataset=ros2_bag)")
    notes = []
    try:
        refs = object_references(rows, runs, lambda r: ctx.detector_setup(runs, r), ctx.root,
                                 ctx.cache)  # fmt: skip
    except FrameDataError as exc:  # e.g. a damaged bag: the estimates are exported all the same
        refs = {}
        notes.append(f"no reference TTC (ref n/a): {exc}")
    boxes = box_table(rows, next(iter(refs.values()), None))
    frames = rng.indices
    calib = load_calibration(source, rng.projection)
    camera_ns, lidar_ns = sensor_clocks(source, frames)
    label = "/".join(str(runs[a].iloc[0]) for a in AXES if a in runs)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    skipped: dict[int, str] = {}
    with out_path.open("wb") as stream:
        out = McapOut(stream)
        out.writer.add_metadata("ttc_bench", {"sweep": str(sweep), "run_id": run_id,
                                              "setting": label, "recording": str(source)})  # fmt: skip
        for k, frame in enumerate(frames):
            header = frame_header(label, frame, rows[rows["frame"] == frame])
            try:
                write_frame(out, source, frame, (camera_ns[k], lidar_ns[k]),
                            boxes[boxes["frame"] == frame], header, image_format, calib)  # fmt: skip
            except FrameDataError as exc:  # a damaged frame costs that frame only
                why = unpaired_errors(source, [frame]) if isinstance(source, BagSource) else {}
                skipped[frame] = str(why.get(frame, exc))  # a bag's: the chunk that lost it
        copied = out.copy_messages(bag_files(source.path)) if keep_topics else 0
        out.finish()
    size = out_path.stat().st_size
    return Exported(out_path, run_id, frames, dict(out.counts), size, time.perf_counter() - start,
                    skipped, copied, notes)  # fmt: skip


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="ttc-bench export", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("sweep", type=Path, help="the sweep folder (sweeps/<name>)")
    pick = parser.add_mutually_exclusive_group()
    pick.add_argument("--run", help="the run id (or a prefix of it)")
    pick.add_argument("--setting", help="axis values '/'-joined: detector/descriptor/matcher/...")
    parser.add_argument("--out", type=Path, required=True, help="the MCAP file to write")
    parser.add_argument("--keep-topics", action="store_true",
                        help="a bag recording's own topics copied beside the results")  # fmt: skip
    parser.add_argument("--image-format", choices=("jpeg", "png"), default="jpeg")
    parser.add_argument("--data-dir", type=Path, help="data root (default: the configured one)")
    parser.add_argument("--cache-dir", type=Path, help="stage cache (default: the configured one)")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    sweep = resolve(args.sweep)
    try:
        done = export(sweep, args.out, args.run, args.setting, args.keep_topics,
                      make_context(args.data_dir, args.cache_dir), args.image_format)  # fmt: skip
    except (ValueError, FrameDataError, store.StoreError, ModelFileError) as exc:
        fail(f"ttc-bench export: {exc}", exc)
    counts = ", ".join(f"{topic} {n}" for topic, n in done.counts.items())
    print(f"{done.path}: run {done.run_id}, frames {done.frames[0]}-{done.frames[-1]}, "
          f"{done.size_bytes / 1e6:.1f} MB in {done.seconds:.1f} s ({counts}"
          f"{f', {done.copied} bag messages copied' if done.copied else ''})")  # fmt: skip
    for note in done.notes:
        print(note, file=sys.stderr)
    for frame, why in done.skipped.items():
        print(f"frame {frame} not exported: {why}", file=sys.stderr)


if __name__ == "__main__":
    main()
