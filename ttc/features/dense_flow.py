"""Dense optical flow as a matcher: ``matcher=dis`` and ``matcher=farneback``.

Like ``matcher=klt`` (:mod:`ttc.features.klt`), no descriptor is involved: a dense flow field
from the previous to the current frame is computed once per pair (OpenCV's DIS optical flow,
Kroeger et al. ECCV 2016, or Farnebäck's polynomial expansion), sampled bilinearly at the
previous frame's detected keypoints, and checked forward–backward with the flow field of the
current to the previous frame: a correspondence is kept when following the backward field
from its tracked position lands within ``fb_threshold`` pixels of where it started. The
result is a :class:`ttc.features.klt.Tracks`, so the rest of the pipeline treats it exactly as
KLT tracks (descriptor and selector recorded as ``none``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ttc.features.base import X, Y, check_gray, require_positive
from ttc.features.klt import Tracks

#: DIS presets by name (OpenCV constants).
DIS_PRESETS = {"ultrafast": 0, "fast": 1, "medium": 2}
#: The dense-flow matchers.
DENSE_FLOW_MATCHERS = ("dis", "farneback")


@dataclass(frozen=True)
class DenseFlowParams:
    """A dense flow field sampled at the keypoints, with a forward–backward check.

    ``dis``: ``preset`` (ultrafast, fast, medium) and, when > 0, ``patch_size`` /
    ``patch_stride`` (pixels) and ``finest_scale`` override it. ``farneback``: ``pyr_scale``,
    ``levels``, ``win_size`` (pixels), ``iterations``, ``poly_n`` (pixels), ``poly_sigma``.
    ``fb_threshold``: largest forward–backward error (pixels) of a kept correspondence.
    """

    name: str = "dis"
    preset: str = "medium"
    patch_size: int = 0
    patch_stride: int = 0
    finest_scale: int = -1
    pyr_scale: float = 0.5
    levels: int = 5
    win_size: int = 15
    iterations: int = 3
    poly_n: int = 5
    poly_sigma: float = 1.2
    fb_threshold: float = 1.0

    def __post_init__(self) -> None:
        if self.name not in DENSE_FLOW_MATCHERS:
            raise ValueError(f"name must be one of {DENSE_FLOW_MATCHERS}, got {self.name!r}")
        if self.preset not in DIS_PRESETS:
            raise ValueError(f"preset must be one of {sorted(DIS_PRESETS)}, got {self.preset!r}")
        require_positive(levels=self.levels, win_size=self.win_size, iterations=self.iterations,
                         poly_n=self.poly_n, poly_sigma=self.poly_sigma,
                         fb_threshold=self.fb_threshold)  # fmt: skip
        if not 0 < self.pyr_scale < 1:
            raise ValueError(f"pyr_scale must be within (0, 1), got {self.pyr_scale}")
        if self.patch_size < 0 or self.patch_stride < 0:
            raise ValueError("patch_size and patch_stride must be >= 0 pixels (0: the preset's)")


def flow_field(src: np.ndarray, dst: np.ndarray, params: DenseFlowParams) -> np.ndarray:
    """The dense flow (H, W, 2) float32, pixels, of the uint8 image ``src`` into ``dst``."""
    if params.name == "farneback":
        return cv2.calcOpticalFlowFarneback(
            src, dst, None, params.pyr_scale, params.levels, params.win_size,
            params.iterations, params.poly_n, params.poly_sigma, 0,
        )  # fmt: skip
    dis = cv2.DISOpticalFlow_create(DIS_PRESETS[params.preset])
    if params.patch_size > 0:
        dis.setPatchSize(params.patch_size)
    if params.patch_stride > 0:
        dis.setPatchStride(params.patch_stride)
    if params.finest_scale >= 0:
        dis.setFinestScale(params.finest_scale)
    return dis.calc(src, dst, None)


def sample_flow(flow: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The flow (N, 2) pixels of ``flow`` (H, W, 2) at ``xy`` (N, 2) pixels, bilinear; NaN
    outside the image."""
    h, w = flow.shape[:2]
    maps = np.ascontiguousarray(xy, dtype=np.float32).reshape(-1, 1, 2)
    out = cv2.remap(flow, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan, np.nan))  # fmt: skip
    out = out.reshape(-1, 2).astype(np.float64)
    outside = (xy[:, 0] < 0) | (xy[:, 0] > w - 1) | (xy[:, 1] < 0) | (xy[:, 1] > h - 1)
    out[outside] = np.nan
    return out


def flow_keypoints(
    gray_prev: np.ndarray,
    gray_curr: np.ndarray,
    keypoints_prev: np.ndarray,
    params: DenseFlowParams,
) -> Tracks:
    """Correspondences of ``keypoints_prev`` (N, 7) of ``gray_prev`` in ``gray_curr`` by
    dense flow: the kept ones (forward–backward error ≤ ``params.fb_threshold`` px, inside
    the current image), in the order of ``keypoints_prev``, as :class:`Tracks`."""
    check_gray(gray_prev)
    check_gray(gray_curr)
    if gray_prev.shape != gray_curr.shape:
        raise ValueError(f"image sizes differ: {gray_prev.shape} vs {gray_curr.shape}")
    if len(keypoints_prev) == 0:
        return Tracks.empty()
    xy = keypoints_prev[:, [X, Y]]
    forward = xy + sample_flow(flow_field(gray_prev, gray_curr, params), xy)
    back = forward + sample_flow(flow_field(gray_curr, gray_prev, params), forward)
    error = np.hypot(*(back - xy).T)
    error[~np.isfinite(error)] = np.inf
    keep = np.flatnonzero(error <= params.fb_threshold)
    tracked = keypoints_prev[keep].copy()
    tracked[:, X], tracked[:, Y] = forward[keep, 0], forward[keep, 1]
    return Tracks(keep.astype(np.int32), tracked, error[keep].astype(np.float32))
