"""Lidar crop, projection and box assignment: exact synthetic checks and the real frame 0."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ttc.io.calibration import load_calibration
from ttc.io.frames import load_frame
from ttc.steps.lidar import (
    LaneCropParams,
    assign_points_to_boxes,
    associate_lead,
    crop_to_lane,
    project_to_image,
)


def test_crop_keeps_only_the_lane() -> None:
    points = np.array(
        [
            [8.0, 0.0, -1.0, 0.5],  # in
            [1.0, 0.0, -1.0, 0.5],  # too close
            [8.0, 2.5, -1.0, 0.5],  # other lane
            [8.0, 0.0, -0.5, 0.5],  # too high
            [8.0, 0.0, -1.0, 0.05],  # dark
            [20.0, -2.0, -1.5, 0.1],  # on every boundary: in
        ],
        dtype=np.float32,
    )
    kept = crop_to_lane(points, LaneCropParams())
    np.testing.assert_array_equal(kept, points[[0, 5]])


def test_projection_matches_calibration(kitti_dir: Path) -> None:
    """A point straight ahead on the camera axis lands on the pixel the matrices predict."""
    calib = load_calibration(kitti_dir)
    # Build a Velodyne point whose camera-0 coordinates are (0, 0, z): invert [R|T] by hand.
    for z in (5.0, 8.0, 20.0):
        cam = np.array([0.0, 0.0, z])
        rot, trans = (
            calib.velo_to_cam[:3, :3],
            calib.velo_to_cam[:3, 3],
        )  # R is orthonormal to ~1e-6
        rect = calib.r_rect_00
        velo = rot.T @ (rect.T @ cam - trans)
        uv = project_to_image(velo[None, :], calib.velo_to_image)[0]
        p = calib.p_rect
        expected_u = (p[0, 2] * z + p[0, 3]) / (z + p[2, 3])
        expected_v = (p[1, 2] * z + p[1, 3]) / (z + p[2, 3])
        assert uv[0] == pytest.approx(expected_u, abs=1e-4)
        assert uv[1] == pytest.approx(expected_v, abs=1e-4)


def test_p_rect_00_vs_02_shift_is_45_px_over_z(kitti_dir: Path) -> None:
    c02 = load_calibration(kitti_dir, "P_rect_02")
    c00 = load_calibration(kitti_dir, "P_rect_00")
    xs = np.array([4.0, 8.0, 16.0])
    pts = np.column_stack([xs, np.zeros(3), np.full(3, -1.0)])
    du = (
        project_to_image(pts, c02.velo_to_image)[:, 0]
        - project_to_image(pts, c00.velo_to_image)[:, 0]
    )
    depth = (c00.velo_to_image @ np.column_stack([pts, np.ones(3)]).T)[2]
    # u shifts by (44.857 − 0.00275·u) / z: ≈ 43 px·m near the image centre
    np.testing.assert_allclose(du * depth, 44.857 - 0.002746 * 609.6, rtol=0.01)
    assert du[1] == pytest.approx(5.6, abs=0.3)  # ≈ 5.6 px at 8 m


def test_points_behind_camera_are_nan(kitti_dir: Path) -> None:
    calib = load_calibration(kitti_dir)
    uv = project_to_image(np.array([[-5.0, 0.0, 0.0]]), calib.velo_to_image)
    assert np.isnan(uv).all()


def test_assignment_shrinks_boxes_and_drops_ambiguous_points() -> None:
    rois = np.array([[0, 0, 100, 100], [80, 0, 100, 100]])  # overlap in x 80..100
    uv = np.array(
        [
            [50.0, 50.0],  # box 0 only
            [150.0, 50.0],  # box 1 only
            [92.0, 50.0],  # both shrunk boxes (0: 5..95, 1: 85..175) -> dropped
            [2.0, 50.0],  # in box 0 but in its shrunk border band -> none
            [500.0, 500.0],  # nowhere
        ]
    )
    np.testing.assert_array_equal(assign_points_to_boxes(uv, rois, 0.10), [0, 1, -1, -1, -1])
    np.testing.assert_array_equal(assign_points_to_boxes(uv, rois, 0.0)[:4], [0, 1, -1, 0])
    assert assign_points_to_boxes(uv, np.zeros((0, 4)), 0.1).tolist() == [-1] * 5


def test_lead_car_closest_point_frame_0(kitti_dir: Path) -> None:
    """The lane points in the lead car's box on frame 0 start at x ≈ 7.97 m."""
    from ttc.features.objects import ObjectDetectorParams, detect_objects

    frame = load_frame(kitti_dir, 0)
    calib = load_calibration(kitti_dir)
    detections = detect_objects(frame.image, ObjectDetectorParams())
    lane = crop_to_lane(frame.scan.points, LaneCropParams())
    assoc = associate_lead(lane, calib.velo_to_image, detections.roi)
    counts = np.bincount(assoc.owner[assoc.owner >= 0], minlength=len(detections.roi))
    assert assoc.lead == int(np.argmax(counts)) and counts[assoc.lead] > 100
    assert assoc.of_box(lane, assoc.lead)[:, 0].min() == pytest.approx(7.97, abs=0.03)
