"""Exact-truth frame pairs made from one real frame: a known scale change of the image and of
the lead vehicle's lidar points (the ``scale_truth`` dataset).

For a source frame and a target TTC ``T`` (seconds) at the frame interval ``dt`` the distance
ratio of the pair is ``s = 1 + dt / T`` (constant velocity: ``TTC = dt / (s − 1)``).

- **Images**: both made from the source image by the same resampling (:func:`scale_image`,
  ``cv2.warpAffine`` with one interpolation), so neither is favoured: the previous image scaled
  by ``s^(−1/2)`` and the current by ``s^(+1/2)`` about the lead vehicle's rear centre
  (the centre of its box, pixels), each then given its own random sub-pixel shift,
  contrast/brightness change and Gaussian noise.
- **Lidar**: the lead vehicle's points; forward coordinates (``x``, metres) multiplied by
  ``s^(+1/2)`` for the previous scan and ``s^(−1/2)`` for the current (``y``, ``z`` kept:
  the geometry of an approach), so the distance ratio of every point is exactly ``s``; then
  range noise (Gaussian, along each point's ray) and, in a share of the pairs, a few outlier
  points ahead of the bumper in both scans (spurious returns at random distances: the
  closest point of a scan is then no longer the vehicle's, while the ranks of the vehicle's
  points move alike in both scans, so a median or quantile stays exact).

Everything random comes from one :class:`numpy.random.Generator` per pair, seeded by
``(seed, source frame, target index)``: a pair does not depend on which other pairs are made.
Arrays in, arrays out; no files.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from ttc.io.frames import frame_interval

#: OpenCV interpolation flags by name (:attr:`ScaleTruthParams.interpolation`).
INTERPOLATIONS = {
    "nearest": cv2.INTER_NEAREST,
    "linear": cv2.INTER_LINEAR,
    "cubic": cv2.INTER_CUBIC,
    "lanczos4": cv2.INTER_LANCZOS4,
}


@dataclass(frozen=True)
class ScaleTruthParams:
    """How the pairs are made (every value enters the generated recording's identity).

    ``source_step``: every how-many-th real frame is a source (from ``first`` to ``last``);
    ``targets_s``: target TTCs (s) at the recording's nominal frame interval
    (:func:`ttc.io.frames.frame_interval`, 0.1 s: a generated recording has no timestamps).
    Photometric:
    ``noise_sigma`` (grey levels, Gaussian per pixel), ``contrast`` / ``brightness`` (each image
    gets a gain in ``1 ± contrast`` and an offset in ``± brightness`` grey levels),
    ``max_shift_px`` (uniform sub-pixel shift per image and axis, pixels). Lidar:
    ``range_sigma_m`` (metres), ``outlier_share`` (share of pairs with injected outliers),
    ``outlier_points`` (how many), ``outlier_ahead_m`` (range of their distance ahead of the
    closest point of the current scan, metres). ``point_shrink``: the lead vehicle's points are
    those in its box shrunk by this fraction (a margin over the pipeline's 0.10, so the same
    points fall in the boxes detected on both synthetic images).
    """

    first: int = 0
    last: int = 76
    source_step: int = 4
    targets_s: tuple[float, ...] = (3.0, 6.0, 12.0, 24.0)
    interpolation: str = "lanczos4"
    noise_sigma: float = 2.0
    contrast: float = 0.05
    brightness: float = 5.0
    max_shift_px: float = 0.5
    range_sigma_m: float = 0.02
    outlier_share: float = 0.25
    outlier_points: int = 3
    outlier_ahead_m: tuple[float, float] = (0.3, 1.0)
    point_shrink: float = 0.25
    seed: int = 0

    def __post_init__(self) -> None:
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(
                f"interpolation must be one of {sorted(INTERPOLATIONS)}, got {self.interpolation!r}"
            )
        if self.source_step < 1 or self.first < 0 or self.last < self.first:
            raise ValueError(
                f"invalid source frames {self.first}..{self.last} / {self.source_step}"
            )
        if not self.targets_s or min(self.targets_s) <= 0:
            raise ValueError(f"targets_s must be positive seconds, got {self.targets_s}")
        if not 0.0 <= self.outlier_share <= 1.0:
            raise ValueError(f"outlier_share must be in [0, 1], got {self.outlier_share}")
        lo, hi = self.outlier_ahead_m
        if not 0.0 < lo <= hi:
            raise ValueError(f"outlier_ahead_m must be 0 < low <= high, got {lo}, {hi}")
        for name in ("noise_sigma", "contrast", "brightness", "max_shift_px", "range_sigma_m"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")

    @property
    def sources(self) -> list[int]:
        """The source frame indices."""
        return list(range(self.first, self.last + 1, self.source_step))

    def noiseless(self) -> ScaleTruthParams:
        """The same pairs without photometric noise, shift, range noise or outliers."""
        return replace(self, noise_sigma=0.0, contrast=0.0, brightness=0.0, max_shift_px=0.0,
                       range_sigma_m=0.0, outlier_share=0.0)  # fmt: skip


def scale_ratio(ttc_s: float, dt_s: float) -> float:
    """The distance ratio ``d_prev / d_curr = 1 + dt / TTC`` of a constant-velocity approach."""
    return 1.0 + dt_s / ttc_s


def scale_matrix(centre: tuple[float, float], scale: float, shift=(0.0, 0.0)) -> np.ndarray:
    """The 2 × 3 affine matrix scaling by ``scale`` about ``centre`` (u, v pixels), then
    shifting by ``shift`` (pixels)."""
    cu, cv = centre
    return np.array(
        [[scale, 0.0, (1.0 - scale) * cu + shift[0]], [0.0, scale, (1.0 - scale) * cv + shift[1]]]
    )


def scale_image(image: np.ndarray, matrix: np.ndarray, interpolation: str = "linear") -> np.ndarray:
    """``image`` (H × W × C uint8) resampled by the affine ``matrix`` (2 × 3) with the named
    interpolation; the border reflected, so no black edge appears."""
    h, w = image.shape[:2]
    return cv2.warpAffine(image, matrix, (w, h), flags=INTERPOLATIONS[interpolation],
                          borderMode=cv2.BORDER_REFLECT_101)  # fmt: skip


def photometric(image: np.ndarray, rng: np.random.Generator, p: ScaleTruthParams) -> np.ndarray:
    """Gain ``1 ± contrast``, offset ``± brightness`` and Gaussian noise ``noise_sigma`` (grey
    levels) on an uint8 image, rounded and clipped back to uint8. Identity when all are 0."""
    gain = 1.0 + rng.uniform(-p.contrast, p.contrast)
    offset = rng.uniform(-p.brightness, p.brightness)
    if gain == 1.0 and offset == 0.0 and p.noise_sigma == 0.0:
        return image
    out = image.astype(np.float32) * gain + offset
    if p.noise_sigma > 0:
        out += rng.normal(0.0, p.noise_sigma, image.shape).astype(np.float32)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def move_points(points: np.ndarray, factor: float) -> np.ndarray:
    """Points (N × 4: x, y, z, reflectance) with ``x`` (forward, metres) times ``factor``."""
    out = np.array(points, dtype=np.float32, copy=True)
    out[:, 0] = (points[:, 0].astype(np.float64) * factor).astype(np.float32)
    return out


def range_noise(points: np.ndarray, sigma_m: float, rng: np.random.Generator) -> np.ndarray:
    """Points moved along their ray from the sensor by Gaussian noise ``sigma_m`` (metres)."""
    if sigma_m == 0:
        return points
    xyz = points[:, :3].astype(np.float64)
    rng_m = np.linalg.norm(xyz, axis=1, keepdims=True)
    noisy = xyz * (1.0 + rng.normal(0.0, sigma_m, (len(xyz), 1)) / rng_m)
    out = np.array(points, dtype=np.float32, copy=True)
    out[:, :3] = noisy.astype(np.float32)
    return out


def outlier_points(
    prev: np.ndarray,
    curr: np.ndarray,
    n: int,
    ahead_m: tuple[float, float],
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points (n × 4) ahead of the bumper in each scan: copies of the same points near
    the middle of the vehicle (the central third by ``|y|``, so they still project into its
    box) with ``x`` set ``ahead_m`` (uniform, metres, drawn per scan) before that scan's
    closest point. ``prev`` and ``curr`` hold the same points (row for row)."""
    if n == 0 or len(prev) == 0:
        empty = np.empty((0, prev.shape[1]), dtype=np.float32)
        return empty, empty.copy()
    central = np.argsort(np.abs(prev[:, 1]), kind="stable")[: max(1, len(prev) // 3)]
    picked = central[rng.integers(0, len(central), n)]
    out = []
    for points in (prev, curr):
        copies = points[picked].astype(np.float32)
        copies[:, 0] = points[:, 0].min() - rng.uniform(*ahead_m, n)
        out.append(copies)
    return out[0], out[1]


@dataclass(frozen=True)
class SyntheticPair:
    """One generated pair: images (H × W × 3 uint8), lidar points (N × 4 float32, Velodyne
    frame, metres) and the truth (``ttc_true`` seconds, ``ratio_true`` = d_prev / d_curr)."""

    image_prev: np.ndarray
    image_curr: np.ndarray
    points_prev: np.ndarray
    points_curr: np.ndarray
    outliers_prev: np.ndarray
    outliers_curr: np.ndarray
    source_frame: int
    ttc_target: float
    ttc_true: float
    ratio_true: float
    outliers: int

    def scans(self) -> tuple[np.ndarray, np.ndarray]:
        """The previous and current scans ((N + n) × 4 float32): the vehicle's points, then
        the outliers; row i of both is the same point."""
        return (np.vstack([self.points_prev, self.outliers_prev]),
                np.vstack([self.points_curr, self.outliers_curr]))  # fmt: skip


def pair_rng(seed: int, source_frame: int, target_index: int) -> np.random.Generator:
    """The random generator of one pair (independent of the other pairs)."""
    return np.random.default_rng([seed, source_frame, target_index])


def make_pair(
    image: np.ndarray,
    lead_points: np.ndarray,
    centre: tuple[float, float],
    source_frame: int,
    target_index: int,
    p: ScaleTruthParams,
) -> SyntheticPair:
    """The pair of target ``p.targets_s[target_index]`` from a source frame.

    Parameters
    ----------
    image
        (H, W, 3) uint8 source image.
    lead_points
        (N, 4) float32 lidar points of the lead vehicle in the source frame (x, y, z, r).
    centre
        The lead vehicle's rear centre (u, v pixels) the images are scaled about.
    """
    rng = pair_rng(p.seed, source_frame, target_index)
    ttc = float(p.targets_s[target_index])
    s = scale_ratio(ttc, frame_interval())
    images = []
    for factor in (s**-0.5, s**0.5):
        shift = rng.uniform(-p.max_shift_px, p.max_shift_px, 2)
        warped = scale_image(image, scale_matrix(centre, factor, shift), p.interpolation)
        images.append(photometric(warped, rng, p))
    prev = range_noise(move_points(lead_points, s**0.5), p.range_sigma_m, rng)
    curr = range_noise(move_points(lead_points, s**-0.5), p.range_sigma_m, rng)
    n_out = p.outlier_points if len(curr) and rng.uniform() < p.outlier_share else 0
    outliers = outlier_points(prev, curr, n_out, p.outlier_ahead_m, rng)
    ttc_true = frame_interval() / (s - 1.0)
    return SyntheticPair(*images, prev, curr, *outliers, source_frame, ttc, ttc_true, s, n_out)
