"""KLT tracking as a matcher: the previous frame's keypoints followed into the current frame.

Instead of describing keypoints in both frames and matching the descriptors, ``matcher=klt``
tracks every previous-frame keypoint with pyramidal Lucas–Kanade optical flow
(``cv2.calcOpticalFlowPyrLK``) and keeps the tracks that pass a forward–backward check: the
tracked point, tracked back into the previous frame, must land within ``fb_threshold`` pixels
of where it started (Kalal et al., "Forward-Backward Error", ICPR 2010). A track onto the wrong
structure (occlusion, repeated texture, a point that left the image) rarely comes back to its
start, so the check removes it without any threshold on appearance.

The result has the shape of descriptor matching: ``prev_idx`` indexes the previous frame's
detected keypoints, and the current frame's keypoints are the tracked positions (row i of
:attr:`Tracks.keypoints_curr` is the track of ``prev_idx[i]``, so ``curr_idx`` is
``0..K-1``). No descriptor is involved, and tracked positions are sub-pixel by construction.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ttc.features.base import X, Y, check_gray, empty_keypoints, require_name, require_positive


@dataclass(frozen=True)
class KltParams:
    """Pyramidal Lucas–Kanade tracking with a forward–backward check.

    ``win_size``: search window side (pixels) at each pyramid level; ``max_level``: pyramid
    levels above the image (0: none; each halves the resolution, so level L follows motions up
    to ~win_size · 2^L / 2 px); ``max_iterations`` / ``epsilon`` (px): stop criteria of the
    iterative search; ``min_eig_threshold``: tracks whose 2 × 2 gradient matrix has a smaller
    minimum eigenvalue (per pixel of the window) are dropped as untrackable;
    ``fb_threshold``: largest forward–backward error (pixels) of a kept track.
    """

    name: str = "klt"
    win_size: int = 21
    max_level: int = 3
    max_iterations: int = 30
    epsilon: float = 0.01
    min_eig_threshold: float = 1e-4
    fb_threshold: float = 1.0

    def __post_init__(self) -> None:
        require_name(self, "klt")
        require_positive(win_size=self.win_size, max_iterations=self.max_iterations,
                         epsilon=self.epsilon, fb_threshold=self.fb_threshold)  # fmt: skip
        if self.win_size < 3:
            raise ValueError(f"win_size must be >= 3 pixels, got {self.win_size}")
        if self.max_level < 0:
            raise ValueError(f"max_level must be >= 0, got {self.max_level}")
        if self.min_eig_threshold < 0:
            raise ValueError(f"min_eig_threshold must be >= 0, got {self.min_eig_threshold}")


@dataclass(frozen=True)
class Tracks:
    """K kept tracks: ``prev_idx`` (int32) indexes the previous frame's keypoints,
    ``keypoints_curr`` (K, 7) are the tracked keypoints (the previous keypoint's fields with
    the tracked x, y in pixels) and ``fb_error`` (float32, pixels) each track's
    forward–backward error."""

    prev_idx: np.ndarray
    keypoints_curr: np.ndarray
    fb_error: np.ndarray

    def __len__(self) -> int:
        return len(self.prev_idx)

    @classmethod
    def empty(cls) -> Tracks:
        """No tracks."""
        return cls(np.empty(0, np.int32), empty_keypoints(), np.empty(0, np.float32))


def _flow(
    src: np.ndarray, dst: np.ndarray, points: np.ndarray, p: KltParams
) -> tuple[np.ndarray, np.ndarray]:
    """(positions (N, 2) float64, found (N,) bool) of ``points`` (N, 2) of ``src`` in ``dst``."""
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, p.max_iterations, p.epsilon)
    start = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 1, 2)
    moved, status, _ = cv2.calcOpticalFlowPyrLK(
        src, dst, start, None, winSize=(p.win_size, p.win_size), maxLevel=p.max_level,
        criteria=criteria, minEigThreshold=p.min_eig_threshold,
    )  # fmt: skip
    return moved.reshape(-1, 2).astype(np.float64), status.reshape(-1).astype(bool)


def forward_backward_error(
    gray_prev: np.ndarray, gray_curr: np.ndarray, xy_prev: np.ndarray, params: KltParams
) -> tuple[np.ndarray, np.ndarray]:
    """(tracked positions (N, 2) px, forward–backward error (N,) px; +inf where either
    direction lost the point) of the points ``xy_prev`` (N, 2) of ``gray_prev``."""
    forward, ok_f = _flow(gray_prev, gray_curr, xy_prev, params)
    backward, ok_b = _flow(gray_curr, gray_prev, forward, params)
    error = np.hypot(*(backward - xy_prev).T)
    error[~(ok_f & ok_b) | ~np.isfinite(error)] = np.inf
    return forward, error


def track_keypoints(
    gray_prev: np.ndarray, gray_curr: np.ndarray, keypoints_prev: np.ndarray, params: KltParams
) -> Tracks:
    """Track ``keypoints_prev`` (N, 7) of the uint8 image ``gray_prev`` into ``gray_curr``.

    Keeps the tracks found in both directions whose forward–backward error is at most
    ``params.fb_threshold`` pixels and whose tracked position lies inside the current image,
    in the order of ``keypoints_prev``.
    """
    check_gray(gray_prev)
    check_gray(gray_curr)
    if gray_prev.shape != gray_curr.shape:
        raise ValueError(f"image sizes differ: {gray_prev.shape} vs {gray_curr.shape}")
    if len(keypoints_prev) == 0:
        return Tracks.empty()
    forward, error = forward_backward_error(gray_prev, gray_curr, keypoints_prev[:, [X, Y]], params)
    h, w = gray_curr.shape
    inside = (forward[:, 0] >= 0) & (forward[:, 0] <= w - 1)
    inside &= (forward[:, 1] >= 0) & (forward[:, 1] <= h - 1)
    keep = np.flatnonzero((error <= params.fb_threshold) & inside)
    tracked = keypoints_prev[keep].copy()
    tracked[:, X], tracked[:, Y] = forward[keep, 0], forward[keep, 1]
    return Tracks(keep.astype(np.int32), tracked, error[keep].astype(np.float32))
