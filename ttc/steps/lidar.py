"""Lidar points: crop to the ego lane, project into the image, assign to object boxes.

Coordinates are the Velodyne frame: x forward, y left, z up, metres. All functions are
vectorised over points; a scan of ~114k points is cropped before anything else, so projection
and box assignment only see the few hundred points in the lane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ttc.steps.box_matching import points_in_rois, shrink_rois


@dataclass(frozen=True)
class LaneCropParams:
    """Ego-lane box in the Velodyne frame (metres) and the minimum reflectance (0–1).

    Defaults are the Udacity starter's: 2 ≤ x ≤ 20, |y| ≤ 2, −1.5 ≤ z ≤ −0.9, r ≥ 0.1.
    """

    min_x: float = 2.0
    max_x: float = 20.0
    max_abs_y: float = 2.0
    min_z: float = -1.5
    max_z: float = -0.9
    min_reflectance: float = 0.1

    def __post_init__(self) -> None:
        if self.min_x >= self.max_x or self.min_z >= self.max_z or self.max_abs_y <= 0:
            raise ValueError(f"empty lane crop: {self}")


def crop_to_lane(points: np.ndarray, crop: LaneCropParams) -> np.ndarray:
    """The rows of ``points`` (N × 4: x, y, z, reflectance) inside the lane crop."""
    return points[lane_mask(points, crop)]


def lane_mask(points: np.ndarray, crop: LaneCropParams) -> np.ndarray:
    """(N,) bool: the rows of ``points`` (N × 4: x, y, z, reflectance) inside the lane crop."""
    x, y, z, r = points[:, 0], points[:, 1], points[:, 2], points[:, 3]
    keep = (
        (x >= crop.min_x)
        & (x <= crop.max_x)
        & (np.abs(y) <= crop.max_abs_y)
        & (z >= crop.min_z)
        & (z <= crop.max_z)
        & (r >= crop.min_reflectance)
    )
    return keep


def project_to_image(xyz: np.ndarray, velo_to_image: np.ndarray) -> np.ndarray:
    """Pixel coordinates (N × 2: u, v) of Velodyne points (N × 3, metres).

    ``velo_to_image`` is the 3 × 4 matrix of :attr:`ttc.io.calibration.Calibration.velo_to_image`.
    Points behind the camera get NaN.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    hom = xyz @ velo_to_image[:, :3].T + velo_to_image[:, 3]
    depth = hom[:, 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = hom[:, :2] / depth
    uv[depth[:, 0] <= 0] = np.nan
    return uv


def assign_points_to_boxes(uv: np.ndarray, rois: np.ndarray, shrink: float = 0.10) -> np.ndarray:
    """Index of the box each pixel falls in after shrinking every box by ``shrink``, else −1.

    A point inside more than one shrunk box is ambiguous and gets −1 (dropped), as in the
    Udacity starter. ``rois`` is (M × 4: x, y, w, h pixels).
    """
    if len(rois) == 0 or len(uv) == 0:
        return np.full(len(uv), -1, dtype=np.int64)
    inside = points_in_rois(uv, shrink_rois(rois, shrink))
    owner = np.argmax(inside, axis=1)
    return np.where(inside.sum(axis=1) == 1, owner, -1)


@dataclass(frozen=True)
class LeadAssociation:
    """Lane lidar points of one frame associated with its boxes: pixel position ``uv``
    (N × 2, px), ``owner`` box index per point (N,; −1: in no box or in two), and the
    ``lead`` box (most points; −1: no box holds any)."""

    uv: np.ndarray
    owner: np.ndarray
    lead: int

    def of_box(self, points: np.ndarray, box_index: int) -> np.ndarray:
        """The rows of ``points`` (the N associated points) assigned to box ``box_index``."""
        return points[self.owner == box_index]


def associate_lead(
    lane_points: np.ndarray, velo_to_image: np.ndarray, rois: np.ndarray, shrink: float = 0.10
) -> LeadAssociation:
    """Project lane points (N × ≥3, m, Velodyne frame) into the image (``velo_to_image``,
    3 × 4), assign each to the box (``rois``: M × 4 x, y, w, h px, shrunk by ``shrink``, a
    fraction) that alone holds it, and pick the lead box (:func:`lead_box_of`): the one
    association step of runs, generated recordings and pictures."""
    uv = project_to_image(lane_points[:, :3], velo_to_image)
    owner = assign_points_to_boxes(uv, rois, shrink)
    return LeadAssociation(uv=uv, owner=owner, lead=lead_box_of(owner, len(rois)))


def lead_box_of(owner: np.ndarray, n_boxes: int) -> int:
    """The lead vehicle's box: the one holding most ego-lane points, or −1 when no box holds
    any. The one rule of the pipeline's ``is_lead`` and of every picture.

    Parameters
    ----------
    owner
        (N,) int: box index per lane lidar point, −1 for a point in no box (or in two).
    n_boxes
        Number of boxes of the frame.
    """
    owner = np.asarray(owner)
    counts = np.bincount(owner[owner >= 0], minlength=n_boxes)
    return int(np.argmax(counts)) if n_boxes and counts.max(initial=0) > 0 else -1
