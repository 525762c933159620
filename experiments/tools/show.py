"""Pictures of one frame and of the frame pair ending there, under any setting.

Examples::

    python -m experiments.tools.show show.frame=7
    python -m experiments.tools.show detector=orb descriptor=brisk lidar_ttc=cluster show.frame=18
    python -m experiments.tools.show show.frame=7 show.out_dir=/tmp/pictures

Writes PNGs into ``<show.out_dir>/frame_NNNN/``:

* ``objects.png``: the frame's YOLO boxes with class and confidence (lead box yellow);
* ``lidar.png``: top, the whole scan in front of the car up to 30 m, coloured by distance;
  bottom, the ego-lane points the pipeline uses (Udacity colour scale, 0–20 m) and the boxes;
* ``top_view.png``: the lane points per box from above (whole lane left, the lead car's rear
  zoomed right) with the distance every lidar estimator picks on the lead box;

and, for the pair (frame − dataset.step, frame) under the configured setting:

* ``lead_ttc.png``: lead box, its lidar points (colour: its own 1.5 m range), both TTCs;
* ``keypoint_matches.png``: previous above current, the lead box's matches kept / removed by FP.3;
* ``box_matches.png``: the FP.1 box pairs, one colour each, with their shared-match counts.

For a ROS 2 bag (``dataset=ros2_bag``) it first lists the bag's topics, types and message
counts and which ones the run reads.

Frame 0 (or any frame < step) has no previous frame: only the three frame pictures are written.
No Hydra output folder is created; Hydra's log goes to stdout.
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
import numpy as np
from omegaconf import DictConfig

from experiments.configs.structured import (
    prepared_frame_range,
    recording_source,
    register_configs,
    settings_from_config,
)
from experiments.data.first_run import ensure_data, ensure_setting_models, fail
from experiments.host import paths
from experiments.report.encode import save_png
from experiments.run import check_data
from ttc import draw
from ttc import evaluation as ev
from ttc.engine.cache import StageCache
from ttc.engine.runner import pair_detail
from ttc.features.objects import ModelFileError, coco_names
from ttc.io.bag_recording import topics
from ttc.io.calibration import load_calibration
from ttc.io.frames import FrameDataError, frame_files, read_lidar_scan
from ttc.io.ros2_bag import BagSource
from ttc.rows import PairDetail
from ttc.settings import AXES, FrameRange, Settings
from ttc.steps.lidar import project_to_image

register_configs()

#: Farthest point (metres) of the whole-scan panel of ``lidar.png``.
SCAN_MAX_X = 30.0
FRAME_PICTURES = ("objects.png", "lidar.png", "top_view.png")
PAIR_PICTURES = ("lead_ttc.png", "keypoint_matches.png", "box_matches.png")
#: Overrides added unless given: no ``.hydra`` folder, no log file, run dir = picture dir.
DEFAULT_OVERRIDES = {
    "hydra.output_subdir": "null",
    "hydra.run.dir": "${show.out_dir}",
    "hydra/job_logging": "stdout",
}


def setting_title(cfg: DictConfig) -> str:
    """One line naming the setting, e.g. ``fast + brief, bf/knn, mutual_best, ...``."""
    v = {axis: str(cfg[axis].name) for axis in AXES}
    return (
        f"{v['detector']} + {v['descriptor']}, {v['matcher']}/{v['selector']}, "
        f"FP.1 {v['box_matching']}, FP.2 {v['lidar_ttc']}, FP.3 {v['keypoint_filter']}, "
        f"FP.4 {v['camera_ttc']}"
    )


def lidar_picture(
    detail: PairDetail, frame: int, frames: FrameRange, settings: Settings, names: list[str]
) -> np.ndarray:
    """Whole scan in front of the car (0–30 m) above the ego-lane points with the boxes."""
    image = detail.images[frame]
    scan = read_lidar_scan(frame_files(frames.sequence_dir, frame).scan).points
    ahead = scan[(scan[:, 0] > 0.0) & (scan[:, 0] <= SCAN_MAX_X)]
    calib = load_calibration(frames.sequence_dir, frames.projection)
    uv = project_to_image(ahead[:, :3], calib.velo_to_image)
    top = draw.draw_lidar_on_image(image, uv, ahead[:, 0], SCAN_MAX_X, radius=1)
    top = draw.draw_distance_legend(top, 0.0, SCAN_MAX_X)
    draw.put_lines(top, [f"frame {frame}: scan points 0 < x <= {SCAN_MAX_X:.0f} m "
                        f"({len(ahead)} of {len(scan)})"])  # fmt: skip
    lane = settings.lane
    owner = detail.lane_owner[frame]
    lead = ev.lead_box_of(owner, len(detail.objects[frame]["roi"]))
    bottom = draw.draw_frame_boxes(detail, frame, names, lead)
    pts = detail.lane_points[frame]
    bottom = draw.draw_lidar_on_image(
        bottom, detail.lane_uv[frame], pts[:, 0], lane.max_x, radius=3
    )
    bottom = draw.draw_distance_legend(bottom, 0.0, lane.max_x)
    draw.put_lines(bottom, [
        f"ego lane: {lane.min_x:g} <= x <= {lane.max_x:g} m, |y| <= {lane.max_abs_y:g} m, "
        f"{lane.min_z:g} <= z <= {lane.max_z:g} m, r >= {lane.min_reflectance:g}: {len(pts)} pts, "
        f"{int(np.sum(owner >= 0))} in one box",
    ])  # fmt: skip
    return draw.stack(top, bottom)


def top_view_picture(
    detail: PairDetail, frame: int, settings: Settings, names: list[str]
) -> np.ndarray:
    """Lane points per box from above: the whole lane (left), the lead's rear zoomed (right)."""
    pts, owner = detail.lane_points[frame], detail.lane_owner[frame]
    objects = detail.objects[frame]
    labels = draw.box_labels(objects, names)
    boxes = [int(b) for b in np.unique(owner[owner >= 0])]
    boxes.sort(key=lambda b: -int(np.sum(owner == b)))
    clouds = [(labels[b], pts[owner == b]) for b in boxes]
    if np.any(owner < 0):
        clouds.append(("in no box / two boxes", pts[owner < 0]))
    lead = ev.lead_box_of(owner, len(objects["roi"]))
    marks = ev.estimator_marks(pts[owner == lead], settings.lidar_ttc) if lead >= 0 else None
    lane = settings.lane
    half = lane.max_abs_y + 0.5
    overview = draw.top_view(
        clouds, marks, world=((0.0, lane.max_x), (-half, half)), size=(420, 1000), grid=2.0,
        title=f"frame {frame}: lane points per box",
    )  # fmt: skip
    if lead < 0:
        return overview
    near = float(pts[owner == lead, 0].min())
    x0 = np.floor(near * 4.0) / 4.0 - 0.5
    zoom = draw.top_view(
        clouds, marks, world=((x0, x0 + 2.0), (-half, half)), size=(580, 1000), grid=0.25, lateral_grid=1.0,
        title=f"lead box #{lead}, zoomed: rear distance by estimator",
    )  # fmt: skip
    seam = np.full((1000, 4, 3), 90, dtype=np.uint8)
    return np.hstack([overview, seam, zoom])


def frame_pictures(
    detail: PairDetail, frame: int, frames: FrameRange, settings: Settings, names: list[str]
) -> dict[str, np.ndarray]:
    """``objects.png``, ``lidar.png``, ``top_view.png`` of ``frame`` (one of the pair's)."""
    objects = detail.objects[frame]
    lead = ev.lead_box_of(detail.lane_owner[frame], len(objects["roi"]))
    boxes = draw.draw_frame_boxes(detail, frame, names, lead)
    draw.put_lines(boxes, [f"frame {frame}: {len(objects['roi'])} boxes ({settings.objects.name}), "
                          f"lead (most lane lidar points) yellow"])  # fmt: skip
    return {
        "objects.png": boxes,
        "lidar.png": lidar_picture(detail, frame, frames, settings, names),
        "top_view.png": top_view_picture(detail, frame, settings, names),
    }


def pair_pictures(detail: PairDetail, names: list[str], title: str) -> dict[str, np.ndarray]:
    """``lead_ttc.png``, ``keypoint_matches.png``, ``box_matches.png`` of a frame pair."""
    return {
        "lead_ttc.png": draw.draw_lead_ttc(detail, names, title),
        "keypoint_matches.png": draw.draw_keypoint_matches(detail, names=names, title=title),
        "box_matches.png": draw.draw_box_matches(detail, names, title),
    }


def write_pictures(cfg: DictConfig) -> list[Path]:
    """Compute the frame and its pair under the configured setting and write the PNGs."""
    settings = settings_from_config(cfg)
    ensure_setting_models(settings.objects)  # e.g. objects=ssd_mobilenet_v2's files
    frames = prepared_frame_range(cfg)  # dataset=scale_truth: its recording written first
    cache = StageCache(cfg.cache.dir, enabled=cfg.cache.enabled)
    frame, step = int(cfg.show.frame), int(cfg.dataset.step)
    if frame < 0:
        raise ValueError(f"show.frame must be >= 0, got {frame}")
    names = list(coco_names(settings.objects))
    has_prev = frame - step >= 0
    prev, curr = (frame - step, frame) if has_prev else (frame, frame + step)
    detail = pair_detail(settings, frames, prev, curr, cache)
    pictures = frame_pictures(detail, frame, frames, settings, names)
    if has_prev:
        pictures |= pair_pictures(detail, names, setting_title(cfg))
    out_dir = Path(str(cfg.show.out_dir)) / f"frame_{frame:04d}"
    return [save_png(image, out_dir / name) for name, image in pictures.items()]


def print_bag_topics(cfg: DictConfig) -> None:
    """For a ``ros2_bag`` dataset: the bag's topics with their types and message counts, and
    the topics the run reads (``lidar.png`` then shows whether the projection is right)."""
    source = recording_source(cfg)
    if not isinstance(source, BagSource):
        return
    index, image, info, lidar = topics(source)
    print(f"{source.path}:")
    for topic in index.topics.values():
        used = " <- frames" if topic.name == image else ""
        used = used or (" <- calibration" if topic.name == info else "")
        used = used or (" <- scans" if topic.name == lidar else "")
        print(f"  {topic.name}  {topic.type}  {len(topic)} messages{used}")


@hydra.main(version_base="1.3", config_path=str(paths.CONF_DIR), config_name="config")
def main(cfg: DictConfig) -> None:
    check_data(cfg)
    try:
        print_bag_topics(cfg)
        paths = write_pictures(cfg)
    except (FrameDataError, ModelFileError) as exc:
        fail(f"cannot show frame {cfg.show.frame}: {exc}", exc)
    for path in paths:
        print(path)
    if int(cfg.show.frame) - int(cfg.dataset.step) < 0:
        print(f"frame {cfg.show.frame} has no previous frame: no pair pictures")


def with_default_overrides(argv: list[str]) -> list[str]:
    """``argv`` plus :data:`DEFAULT_OVERRIDES` whose keys it does not set itself."""
    given = {a.split("=", 1)[0].lstrip("+~") for a in argv[1:] if "=" in a}
    extra = [f"{k}={v}" for k, v in DEFAULT_OVERRIDES.items() if k not in given]
    return [argv[0], *extra, *argv[1:]]


if __name__ == "__main__":
    sys.argv[1:] = ensure_data(sys.argv[1:])  # frames and weights on first run
    sys.argv = with_default_overrides(sys.argv)
    main()
