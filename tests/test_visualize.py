"""Pictures (:mod:`ttc.draw`) on the real frames 6 → 7: sizes, what gets drawn where, the lead
box they are told, atomic PNGs, the command."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from experiments.report.encode import save_png
from experiments.tools.show import FRAME_PICTURES, PAIR_PICTURES, with_default_overrides
from ttc import draw
from ttc import evaluation as ev
from ttc.engine.cache import StageCache
from ttc.engine.runner import pair_detail
from ttc.features.descriptors import DESCRIPTORS
from ttc.features.keypoints import DETECTORS
from ttc.rows import PairDetail
from ttc.settings import FrameRange, Settings
from ttc.steps.lidar_ttc import LIDAR_ESTIMATORS, LidarTTCParams

PROJECT_ROOT = Path(__file__).resolve().parents[1]
RED, GREEN = (0, 0, 255), (0, 255, 0)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("stage-cache")


@pytest.fixture(scope="module")
def detail(kitti_dir: Path, cache_dir: Path) -> PairDetail:
    settings = Settings(detector=DETECTORS["fast"](), descriptor=DESCRIPTORS["brief"]())
    return pair_detail(settings, FrameRange(kitti_dir, 0, 18), 6, 7, StageCache(cache_dir))


def lead_points(d: PairDetail) -> tuple[np.ndarray, np.ndarray]:
    """The lead box's lane points (metres) and their pixels in the current frame."""
    mine = d.lane_owner[d.curr] == d.lead_box
    return d.lane_points[d.curr][mine], d.lane_uv[d.curr][mine]


def border_pixel(image: np.ndarray, roi: np.ndarray, dv: int = 0) -> np.ndarray:
    """The pixel in the middle of a box's left edge (``dv``: row offset of a stacked half)."""
    x, y, _, h = (int(v) for v in roi)
    return image[y + h // 2 + dv, x]


def new_pixels(out: np.ndarray, before: np.ndarray, colour_test) -> int:
    """Pixels that pass ``colour_test`` (B, G, R arrays → bool) in ``out`` but not ``before``."""
    now = colour_test(*np.moveaxis(out.astype(int), -1, 0))
    was = colour_test(*np.moveaxis(before.astype(int), -1, 0))
    return int(np.count_nonzero(now & ~was))


def greenish(b, g, r):
    return (g > 180) & (r < 120) & (b < 120)


def reddish(b, g, r):
    return (r > 180) & (g < 100) & (b < 100)


# --------------------------------------------------------------------------- primitives


def test_distance_colours_run_from_red_to_green() -> None:
    colours = draw.distance_colours(np.array([0.0, 10.0, 20.0, 35.0, -3.0]), max_x=20.0)
    assert colours.dtype == np.uint8
    assert tuple(colours[0]) == RED and tuple(colours[2]) == GREEN
    assert colours[1, 0] == 0 and abs(int(colours[1, 1]) - 128) <= 1
    assert abs(int(colours[1, 2]) - 128) <= 1
    assert tuple(colours[3]) == GREEN and tuple(colours[4]) == RED  # clipped


def test_lidar_point_colours_its_pixel_nearest_on_top(detail: PairDetail) -> None:
    image = detail.images[detail.curr]
    one = draw.draw_lidar_on_image(image, np.array([[100.4, 50.6]]), np.array([0.0]), radius=0)
    assert tuple(one[51, 100]) == RED
    assert np.count_nonzero((one != image).any(axis=2)) == 1
    uv = np.array([[300.0, 200.0], [300.0, 200.0], [np.nan, 5.0], [-50.0, 10.0]])
    for order in ([0, 1, 2, 3], [1, 0, 3, 2]):
        out = draw.draw_lidar_on_image(image, uv[order], np.array([5.0, 15.0, 1.0, 1.0])[order])
        near = tuple(draw.distance_colours(np.array([5.0]))[0])
        assert tuple(out[200, 300]) == near  # the nearer of two points wins, in either order
    assert np.array_equal(image, detail.images[detail.curr])  # input untouched


def test_lane_points_drawn_where_they_project(detail: PairDetail) -> None:
    image = detail.images[detail.curr]
    points, uv = lead_points(detail)
    out = draw.draw_lidar_on_image(image, uv, points[:, 0], radius=1)
    assert out.shape == image.shape and out.dtype == np.uint8
    nearest = int(np.argmin(points[:, 0]))
    u, v = np.rint(uv[nearest]).astype(int)
    assert tuple(out[v, u]) == tuple(draw.distance_colours(points[nearest : nearest + 1, 0])[0])
    rows, cols = np.nonzero((out != image).any(axis=2))
    assert rows.min() >= np.floor(uv[:, 1].min()) - 1 and rows.max() <= np.ceil(uv[:, 1].max()) + 1
    assert cols.min() >= np.floor(uv[:, 0].min()) - 1 and cols.max() <= np.ceil(uv[:, 0].max()) + 1


def test_draw_boxes_highlights_one(detail: PairDetail) -> None:
    image = detail.images[detail.curr]
    rois = detail.objects[detail.curr]["roi"]
    labels = draw.box_labels(detail.objects[detail.curr], ["person", "bicycle", "car"])
    assert labels[detail.lead_box].startswith(f"#{detail.lead_box} car ")
    out = draw.draw_boxes(image, rois, labels, highlight=detail.lead_box)
    assert out.shape == image.shape and out.dtype == np.uint8
    assert tuple(border_pixel(out, rois[detail.lead_box])) == draw.HIGHLIGHT_COLOUR
    x, y, w, h = rois[detail.lead_box]
    assert np.array_equal(out[y + h // 2, x + w // 2], image[y + h // 2, x + w // 2])
    other = (detail.lead_box + 1) % len(rois)
    plain = draw.draw_boxes(image, rois, labels)
    assert tuple(border_pixel(plain, rois[detail.lead_box])) == draw.BOX_COLOUR
    assert tuple(border_pixel(plain, rois[other])) in {draw.BOX_COLOUR, draw.HIGHLIGHT_COLOUR}
    with pytest.raises(ValueError, match="labels"):
        draw.draw_boxes(image, rois, labels[:-1])


# --------------------------------------------------------------------------- top view, marks


def test_top_view_puts_8_m_at_its_row() -> None:
    cloud = np.array([[8.0, 0.0, -1.0]])
    img = draw.top_view([("lead", cloud)], {"m": 10.0, "gone": float("nan")},
                       world=((0.0, 20.0), (-3.0, 3.0)), size=(500, 1000))  # fmt: skip
    assert img.shape == (1000, 500, 3) and img.dtype == np.uint8
    rows, cols = np.nonzero((img == draw.palette_colour(0)).all(axis=2))
    rows, cols = rows[cols < 300], cols[cols < 300]  # the point, not the legend text
    assert len(rows) > 0
    assert rows.mean() == pytest.approx(600.0, abs=0.5)  # (20 - 8) / 20 * 1000
    assert cols.mean() == pytest.approx(250.0, abs=0.5)  # y = 0 in the middle
    mark_colour = draw.palette_colour(2)  # after the cloud's colour and one spare
    assert tuple(img[500, 120]) == mark_colour  # the 10 m line
    assert not (img[:, 120] == mark_colour).all(axis=1)[700:].any()


def test_top_view_zoomed_world_and_empty_cloud() -> None:
    cloud = np.array([[7.55, 0.5, -1.0], [7.9, -0.5, -1.0]])
    world = ((7.0, 9.0), (-2.0, 2.0))
    img = draw.top_view([("a", cloud), ("none", np.empty((0, 4)))], None, world, (400, 800),
                       grid=0.25, lateral_grid=1.0)  # fmt: skip
    expected = draw.world_to_pixel(cloud[:, 0], cloud[:, 1], world, (400, 800))
    np.testing.assert_allclose(expected, [[150.0, 580.0], [250.0, 440.0]])
    for col, row in np.rint(expected).astype(int):
        assert tuple(img[row, col]) == draw.palette_colour(0)
    with pytest.raises(ValueError, match="empty top view"):
        draw.top_view([], world=((5.0, 5.0), (-1.0, 1.0)))


def test_estimator_marks_equal_the_estimators(detail: PairDetail) -> None:
    points, _ = lead_points(detail)
    params = LidarTTCParams(quantile=0.2)
    marks = ev.estimator_marks(points, params)
    assert list(marks) == list(LIDAR_ESTIMATORS)
    for name, estimator in LIDAR_ESTIMATORS.items():
        xyz = points[:, :3].astype(np.float64)  # as the pipeline hands them over
        own = estimator(xyz, dataclasses.replace(params, name=name)).distance
        assert marks[name] == own
    assert marks["closest"] < marks["quantile"] < marks["median"]
    row = ev.lead_row(detail)  # the pipeline ran with the median estimator
    assert ev.estimator_marks(points)["median"] == pytest.approx(row["d_curr"])
    assert all(np.isnan(d) for d in ev.estimator_marks(np.empty((0, 4))).values())


def test_lead_boxes_are_the_lead_row_and_its_fp1_partner(detail: PairDetail) -> None:
    prev_box, curr_box = ev.lead_boxes(detail)
    assert curr_box == detail.lead_box >= 0
    bm = detail.box_matches
    pairs = dict(zip(np.asarray(bm.curr_box).tolist(), np.asarray(bm.prev_box).tolist(),
                     strict=True))  # fmt: skip
    assert prev_box == pairs.get(curr_box, -1)
    clouds = ev.lead_clouds(detail)
    assert list(clouds) == [detail.prev, detail.curr]
    assert len(clouds[detail.curr]) == ev.lead_row(detail)["lidar_points_curr"]


# --------------------------------------------------------------------------- pair pictures


@pytest.mark.parametrize(
    ("value", "reason", "text"),
    [(11.9843, "ok", "11.98 s"), (float("nan"), "no_lidar_points_prev",
      "n/a (no_lidar_points_prev)"), (float("inf"), "receding", "+inf (receding)"),
     (float("-inf"), "ratio_one", "-inf (ratio_one)")],
)  # fmt: skip
def test_format_ttc(value: float, reason: str, text: str) -> None:
    assert draw.format_ttc(value, reason) == text


def test_lead_ttc_draws_box_points_and_text(detail: PairDetail) -> None:
    image = detail.images[detail.curr]
    out = draw.draw_lead_ttc(detail, title="setting")
    assert out.shape == image.shape and out.dtype == np.uint8
    roi = detail.objects[detail.curr]["roi"][detail.lead_box]
    assert tuple(border_pixel(out, roi)) == draw.HIGHLIGHT_COLOUR
    points, uv = lead_points(detail)
    u, v = np.rint(uv[np.argmin(points[:, 0])]).astype(int)
    b, g, r = (int(c) for c in out[v, u])
    assert b == 0 and r > g  # the nearest point: the red end of the box's own colour range
    assert (out[5:90, 5:300] != image[5:90, 5:300]).any()  # the text block


def test_keypoint_matches_green_kept_red_removed(detail: PairDetail) -> None:
    h, w = detail.images[detail.prev].shape[:2]
    assert len(detail.kept) > 20 and len(detail.removed) > 0
    before = np.vstack([detail.images[detail.prev], detail.images[detail.curr]])
    flat = draw.draw_keypoint_matches(detail, zoom=False)
    assert flat.shape == (2 * h, w, 3) and flat.dtype == np.uint8
    assert new_pixels(flat, before, greenish) > 200
    assert new_pixels(flat, before, reddish) > 20
    none = draw.draw_keypoint_matches(detail, max_draw=0, zoom=False)
    assert new_pixels(none, before, greenish) == 0 and new_pixels(none, before, reddish) == 0
    zoomed = draw.draw_keypoint_matches(detail)
    assert zoomed.shape[0] == 2 * h and zoomed.shape[1] > w + 100
    assert np.array_equal(zoomed[:, :w], flat)


def test_box_matches_colour_pairs_and_grey_unmatched(detail: PairDetail) -> None:
    h, w = detail.images[detail.prev].shape[:2]
    out = draw.draw_box_matches(detail)
    assert out.shape == (2 * h, w, 3) and out.dtype == np.uint8
    bm = detail.box_matches
    k = int(np.flatnonzero(bm.curr_box == detail.lead_box)[0])
    lead_prev = int(bm.prev_box[k])
    assert tuple(border_pixel(out, detail.objects[detail.prev]["roi"][lead_prev])) == (
        draw.palette_colour(k)
    )
    roi = detail.objects[detail.curr]["roi"][detail.lead_box]
    assert tuple(border_pixel(out, roi, dv=h)) == draw.palette_colour(k)
    n_curr = len(detail.objects[detail.curr]["roi"])
    grey = {c: grey_share(out, detail.objects[detail.curr]["roi"][c], h) for c in range(n_curr)}
    unmatched = set(range(n_curr)) - set(bm.curr_box.tolist())
    assert unmatched
    assert max(grey[c] for c in unmatched) > 0.9  # (others are overdrawn by overlapping boxes)
    assert all(grey[c] < 0.2 for c in bm.curr_box.tolist())


def grey_share(image: np.ndarray, roi: np.ndarray, dv: int) -> float:
    """Share of a box's outline pixels that are exactly the unmatched grey."""
    x, y, w, h = (int(v) for v in roi)
    y += dv
    outline = np.concatenate([image[y, x : x + w], image[y + h - 1, x : x + w],
                              image[y : y + h, x], image[y : y + h, x + w - 1]])  # fmt: skip
    return float((outline == draw.UNMATCHED_COLOUR).all(axis=1).mean())


# --------------------------------------------------------------------------- files


def test_save_png_writes_readable_file_atomically(tmp_path: Path) -> None:
    image = np.random.default_rng(0).integers(0, 256, (40, 60, 3), dtype=np.uint8)
    path = save_png(image, tmp_path / "a" / "b" / "pic.png")
    assert np.array_equal(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), image)
    assert os.listdir(path.parent) == ["pic.png"]  # no temporary file left
    with pytest.raises(ValueError, match=r"\.png"):
        save_png(image, tmp_path / "pic.jpg")
    assert not (tmp_path / "pic.jpg").exists()
    with pytest.raises(OSError, match="could not encode"):
        save_png(np.zeros((4, 4, 5), np.uint8), path)  # 5 channels: no PNG
    with pytest.raises(ValueError, match="uint8"):
        save_png(image.astype(np.float32), path)
    assert np.array_equal(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), image)  # intact
    assert os.listdir(path.parent) == ["pic.png"]


# --------------------------------------------------------------------------- the command


def test_default_overrides_yield_to_the_user() -> None:
    argv = with_default_overrides(["show", "hydra.run.dir=/x", "show.frame=3"])
    assert argv[0] == "show" and argv[-2:] == ["hydra.run.dir=/x", "show.frame=3"]
    assert "hydra.output_subdir=null" in argv
    assert sum(a.startswith("hydra.run.dir=") for a in argv) == 1


def run_show(tmp_path: Path, cache_dir: Path, frame: int) -> subprocess.CompletedProcess:
    env = {**os.environ, "TTC_CACHE_DIR": str(cache_dir),
           "TTC_RESULTS_DIR": str(tmp_path / "sweeps")}  # fmt: skip
    cmd = [sys.executable, "-m", "experiments.tools.show", f"show.frame={frame}",
           f"show.out_dir={tmp_path / 'pictures'}", f"dataset.last={max(frame, 1)}"]  # fmt: skip
    return subprocess.run(cmd, cwd=PROJECT_ROOT, env=env, capture_output=True, text=True,
                          timeout=120)  # fmt: skip


def test_show_command_writes_six_pictures(tmp_path: Path, cache_dir: Path) -> None:
    proc = run_show(tmp_path, cache_dir, 3)
    assert proc.returncode == 0, proc.stderr
    folder = tmp_path / "pictures" / "frame_0003"
    assert sorted(os.listdir(folder)) == sorted(FRAME_PICTURES + PAIR_PICTURES)
    for name in FRAME_PICTURES + PAIR_PICTURES:
        image = cv2.imread(str(folder / name))
        assert image is not None and image.shape[0] >= 375, name
        assert str(folder / name) in proc.stdout
    assert not (tmp_path / "sweeps").exists()  # no Hydra run folder, no .hydra


def test_show_frame_0_has_no_pair_pictures(tmp_path: Path, cache_dir: Path) -> None:
    proc = run_show(tmp_path, cache_dir, 0)
    assert proc.returncode == 0, proc.stderr
    assert sorted(os.listdir(tmp_path / "pictures" / "frame_0000")) == sorted(FRAME_PICTURES)
    assert "no previous frame" in proc.stdout
