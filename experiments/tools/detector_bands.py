"""Boxes per frame by lidar distance band and milliseconds per frame of object detectors.

For each recording and each detector setting (``objects=...``, ``objects.tiles=N``): every
frame's boxes (:func:`ttc.features.objects.detect_objects`, timed on one OpenCV thread: the
mean over the frames) and each box's lidar distance (its own points' best-supported depth
group, :func:`experiments.summary.references.recording_boxes`, the every-object code's
association).
Prints a markdown table (docs/features.md "Object detectors")::

    python -m experiments.tools.detector_bands --out detector_bands.csv
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import pandas as pd
from hydra import compose, initialize_config_dir

from experiments.configs.structured import (
    prepared_frame_range,
    register_configs,
    settings_from_config,
)
from experiments.data.first_run import ensure_setting_models
from experiments.host import paths
from experiments.summary.references import recording_boxes
from ttc.engine.cache import StageCache
from ttc.evaluation.ttc_bins import band_counts
from ttc.features.objects import detect_objects
from ttc.io.frames import frame_files, read_image

#: (label, dataset overrides) of the recordings measured.
RECORDINGS = {
    "drive 0009 (0-15)": ["dataset=kitti_raw_0009"],
    "drive 0052 (0-18)": ["dataset=kitti_0_18"],
    "odometry 04 (0-40)": ["dataset=kitti_odometry"],
}
#: (label, objects overrides) of the detector settings measured.
DETECTORS = {
    "yolov3_tiny": ["objects=yolov3_tiny"],
    "yolov3_tiny, 4 tiles": ["objects=yolov3_tiny", "objects.tiles=4"],
    "ssd_mobilenet_v2, 1 tile": ["objects=ssd_mobilenet_v2", "objects.tiles=1"],
    "ssd_mobilenet_v2, 3 tiles": ["objects=ssd_mobilenet_v2", "objects.tiles=3"],
    "ssd_mobilenet_v2, 4 tiles": ["objects=ssd_mobilenet_v2", "objects.tiles=4"],
}


#: Upper edges of the distance bands (metres).
def measure(recording: list[str], detector: list[str]) -> dict[str, float]:
    """Boxes per frame by band and ms per frame of one detector setting on one recording."""
    with initialize_config_dir(config_dir=str(paths.CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[*recording, *detector])
    settings, frames = settings_from_config(cfg), prepared_frame_range(cfg)
    ensure_setting_models(settings.objects)
    images = [read_image(frame_files(frames.sequence_dir, i).image) for i in frames.indices]
    detect_objects(images[0], settings.objects)  # the network loaded
    start = time.perf_counter()
    for image in images:
        detect_objects(image, settings.objects)
    ms = 1000.0 * (time.perf_counter() - start) / len(images)
    with tempfile.TemporaryDirectory() as folder:
        span = (frames.indices[0], frames.indices[-1])
        boxes, _, _ = recording_boxes(frames.sequence_dir, settings, StageCache(folder),
                                      frames.projection, span)  # fmt: skip
    counts = band_counts(boxes["distance_m"].to_numpy(dtype=float))
    return {k: v / len(images) for k, v in counts.items()} | {"ms_per_frame": ms}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=None, help="CSV of the table")
    parser.add_argument("--recordings", nargs="*", default=list(RECORDINGS))
    args = parser.parse_args()
    cv2.setNumThreads(1)  # one core
    register_configs()
    rows = []
    for rec in args.recordings:
        for name, overrides in DETECTORS.items():
            row = {"recording": rec, "detector": name} | measure(RECORDINGS[rec], overrides)
            print(row, flush=True)
            rows.append(row)
    table = pd.DataFrame(rows)
    if args.out is not None:
        table.to_csv(args.out, index=False)
    print(markdown(table))


def markdown(table: pd.DataFrame) -> str:
    """The table as markdown, numbers with one decimal (ms per frame whole)."""
    lines = ["| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns)]
    for row in table.itertuples(index=False):
        cells = [f"{v:.0f}" if c == "ms_per_frame" else f"{v:.1f}" if isinstance(v, float)
                 else str(v) for c, v in zip(table.columns, row, strict=True)]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
