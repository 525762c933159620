"""Full-height tiles (ttc/features/tiles.py, ``objects.tiles``): the strips' geometry, and the
merge on a synthetic image through the harness's detection path (NMS, containment rule) with a
stand-in network whose boxes are exactly the white rectangles it is shown."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from experiments.configs.identity import axis_values, setting_config, setting_hash
from tests.test_beyond_rubric import composed
from ttc.engine.stages import stage_params
from ttc.features.objects import ObjectDetectorParams, detect_objects
from ttc.features.ssd import SSD_LABELS
from ttc.features.tiles import merge_split_boxes, tile_spans

WIDTH, HEIGHT = 1242, 375  # a KITTI frame
CAR = SSD_LABELS.index("car")


class WhiteBoxes:
    """A stand-in for SSD's ``cv2.dnn.Net``: each white rectangle of the input blob is one
    ``car`` (score 0.9), its corners relative to the blob, as SSD's ``[1, 1, N, 7]`` rows."""

    def __init__(self) -> None:
        self.inputs: list[tuple[int, int]] = []

    def setInput(self, blob: np.ndarray) -> None:  # noqa: N802 (cv2.dnn.Net's name)
        self.blob = blob
        self.inputs.append(blob.shape[2:])

    def forward(self) -> np.ndarray:
        white = (self.blob[0].min(axis=0) > 127).astype(np.uint8)
        n, _, stats, _ = cv2.connectedComponentsWithStats(white)
        height, width = white.shape
        rows = [[0, CAR, 0.9, x / width, y / height, (x + w) / width, (y + h) / height]
                for x, y, w, h, _ in stats[1:n]]  # fmt: skip
        return np.asarray(rows, dtype=np.float32).reshape(1, 1, -1, 7)


def _image(*rects: tuple[int, int, int, int]) -> np.ndarray:
    """A black KITTI-sized BGR image with white rectangles (x, y, w, h pixels)."""
    image = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    for x, y, w, h in rects:
        image[y : y + h, x : x + w] = 255
    return image


def _params(tiles: int) -> ObjectDetectorParams:
    return ObjectDetectorParams(name="ssd_mobilenet_v2", input_width=300, input_height=300,
                                scale=1.0, tiles=tiles, tile_overlap=0.2)  # fmt: skip


def test_strips_cover_the_image_with_equal_widths_and_the_overlap() -> None:
    spans = tile_spans(WIDTH, 3, 0.2)
    widths = spans[:, 1] - spans[:, 0]
    assert spans[0, 0] == 0 and spans[-1, 1] == WIDTH
    assert widths.max() - widths.min() <= 1
    shared = spans[:-1, 1] - spans[1:, 0]  # columns two neighbours share
    assert np.all(np.abs(shared - 0.2 * widths[0]) <= 1)
    assert tile_spans(WIDTH, 1, 0.2).tolist() == [[0, WIDTH]]
    assert tile_spans(WIDTH, 4, 0.0)[:, 0].tolist() == [0, 310, 621, 932]  # no overlap: abutting
    for bad in ((0, 0.2), (3, 1.0), (3, -0.1)):
        with pytest.raises(ValueError):
            tile_spans(WIDTH, *bad)
    with pytest.raises(ValueError, match="tiles must be >= 1"):
        _params(0)


def test_an_object_split_by_a_strip_border_is_one_box_at_its_place() -> None:
    spans = tile_spans(WIDTH, 3, 0.2)  # strips 0-478, 382-860, 764-1242
    car = (330, 150, 200, 100)  # wider than the shared 96 columns: no strip sees it whole
    assert car[0] < spans[1, 0] and car[0] + car[2] > spans[0, 1]
    net = WhiteBoxes()
    found = detect_objects(_image(car), _params(3), net)
    assert net.inputs == [(300, 300)] * 3  # each strip resized to the network input
    assert len(found) == 1 and found.names() == ["car"]
    assert np.abs(found.roi[0] - car).max() <= 2  # the whole car (strip resizing: ±2 px)
    alone = detect_objects(_image(car), _params(1), WhiteBoxes())
    assert np.abs(found.roi[0] - alone.roi[0]).max() <= 2  # as the whole image boxes it


def test_an_object_inside_the_overlap_is_not_doubled() -> None:
    car = (400, 180, 60, 40)  # inside 382-478: whole in strips 0 and 1
    far = (800, 190, 30, 20)  # inside 764-860: whole in strips 1 and 2
    found = detect_objects(_image(car, far), _params(3), WhiteBoxes())
    assert len(found) == 2
    rois = found.roi[np.argsort(found.roi[:, 0])]
    assert np.abs(rois - np.array([car, far])).max() <= 2


def test_an_object_cut_twice_is_joined_twice_and_a_part_inside_a_box_goes() -> None:
    bus = (300, 100, 700, 200)  # crosses both borders of 3 strips
    found = detect_objects(_image(bus), _params(3), WhiteBoxes())
    assert len(found) == 1 and np.abs(found.roi[0] - bus).max() <= 3
    # a part that touches a cut edge but has no partner of its height stays its own box
    spans = tile_spans(WIDTH, 2, 0.2)
    boxes = np.array([[500.0, 100, spans[0, 1] - 500.0, 50], [spans[1, 0], 200, 80, 50]])
    merged = merge_split_boxes(boxes, np.array([CAR, CAR]), np.array([0.5, 0.6], np.float32),
                               np.array([0, 1]), spans)  # fmt: skip
    assert len(merged[0]) == 2  # vertical extents disjoint: two objects


def test_tiles_1_is_todays_setting_and_run_id() -> None:
    default = composed(["dataset.last=3"])
    explicit = composed(["dataset.last=3", "objects.tiles=1", "objects.tile_overlap=0.2"])
    tiled = composed(["dataset.last=3", "objects.tiles=3"])
    assert setting_hash(setting_config(default)) == setting_hash(setting_config(explicit))
    assert setting_hash(setting_config(tiled)) != setting_hash(setting_config(default))
    assert axis_values(setting_config(default))["objects"] == "yolov3_tiny"  # as recorded before
    assert axis_values(setting_config(tiled))["objects"] == "yolov3_tiny+tiles3"  # told apart
    key = stage_params(ObjectDetectorParams(), "objects")  # the objects stage's cache key
    assert "tiles" not in key and "tile_overlap" not in key
    assert stage_params(ObjectDetectorParams(tiles=3), "objects")["tiles"] == 3
