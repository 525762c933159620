"""Difficulty levels of every box, as KITTI's object benchmark defines them.

KITTI (Geiger et al., CVPR 2012, the object benchmark's evaluation) puts an object in

============  ==============  ================================  =================
level         min box height  max occlusion                     max truncation
============  ==============  ================================  =================
``easy``      40 px           fully visible                     15 %
``moderate``  25 px           partly occluded                   30 %
``hard``      25 px           largely occluded ("difficult")    50 %
============  ==============  ================================  =================

and counts the levels cumulatively (``moderate`` holds the ``easy`` objects, ``hard`` both).
Here, from a detector's boxes and their lidar distances:

* **height**: the box height (px) in the image the detector saw;
* **truncation**: KITTI's is the fraction of the object outside the image, which a box cannot
  tell: a box within :data:`BORDER_PX` of any image border is *truncated* and maps to
  ``hard`` at best (KITTI's hard allows up to 50 %; whether more is cut is unknowable);
* **occlusion**: the share of the box's area covered by the union of the boxes of nearer
  objects in the same frame (the lidar distance decides which is nearer), mapped to KITTI's
  states by :data:`OCCLUSION_EDGES`: ≤ 0.1 fully visible, ≤ 0.5 partly, > 0.5 largely
  occluded. A box without a distance occludes nothing and is occluded by every box with one
  (a box whose frustum's points all went to a nearer box, :mod:`ttc.steps.object_lidar`, is
  behind it; an unmeasured far box is behind the measured near ones).

A box lower than 25 px is in no level (``none``: counted in ``all`` only). The per-box
``difficulty`` is the strictest level met; a box pair takes the worse level of its two boxes
(:func:`worse_level`), and a pair belongs to every level at least as lenient as its own
(:func:`in_level`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

#: The levels from the strictest; ``none``: below every level's height.
LEVELS: tuple[str, ...] = ("easy", "moderate", "hard")
NO_LEVEL = "none"
#: Every level name a box can get, strictest first.
BOX_LEVELS: tuple[str, ...] = (*LEVELS, NO_LEVEL)
#: The ranking levels (cumulative) and ``all`` (every box, a level or not).
RANKING_LEVELS: tuple[str, ...] = (*LEVELS, "all")
#: Least box height (px) per level.
MIN_HEIGHT_PX: dict[str, float] = {"easy": 40.0, "moderate": 25.0, "hard": 25.0}
#: Most occlusion state (0 fully visible, 1 partly, 2 largely occluded) per level.
MAX_OCCLUSION: dict[str, int] = {"easy": 0, "moderate": 1, "hard": 2}
#: Whether a truncated box (touching the border) may be in the level.
TRUNCATED_OK: dict[str, bool] = {"easy": False, "moderate": False, "hard": True}
#: Upper edges of the occluded share (0–1) of the occlusion states 0 and 1; above: state 2.
OCCLUSION_EDGES: tuple[float, float] = (0.1, 0.5)
#: Pixels from an image border within which a box counts as truncated (YOLO's clipped boxes
#: end 1–3 px inside the image; :data:`ttc.evaluation.object_reference.EDGE_PX`).
BORDER_PX = 4


def union_cover(box: np.ndarray, others: np.ndarray) -> float:
    """Share (0–1) of the area of ``box`` (x, y, w, h px) covered by the union of ``others``
    (K × 4), exactly: on the grid of every box edge, cells inside ``box`` and some other."""
    x0, y0, w, h = (float(v) for v in box)
    if w <= 0 or h <= 0 or not len(others):
        return 0.0
    o = np.asarray(others, dtype=float).reshape(-1, 4)
    lx, ly = np.clip(o[:, 0], x0, x0 + w), np.clip(o[:, 1], y0, y0 + h)
    hx, hy = np.clip(o[:, 0] + o[:, 2], x0, x0 + w), np.clip(o[:, 1] + o[:, 3], y0, y0 + h)
    keep = (hx > lx) & (hy > ly)
    if not keep.any():
        return 0.0
    lx, ly, hx, hy = lx[keep], ly[keep], hx[keep], hy[keep]
    xs, ys = np.unique(np.r_[lx, hx]), np.unique(np.r_[ly, hy])
    cx, cy = (xs[:-1] + xs[1:]) / 2, (ys[:-1] + ys[1:]) / 2  # cell centres
    inside_x = (cx[None, :] > lx[:, None]) & (cx[None, :] < hx[:, None])  # (K, X)
    inside_y = (cy[None, :] > ly[:, None]) & (cy[None, :] < hy[:, None])  # (K, Y)
    covered = np.einsum("kx,ky->xy", inside_x.astype(np.int64), inside_y.astype(np.int64)) > 0
    area = np.outer(np.diff(xs), np.diff(ys))
    return float(area[covered].sum() / (w * h))


def occluded_share(boxes: np.ndarray, distance_m: np.ndarray) -> np.ndarray:
    """(N,) share (0–1) of each box's area covered by the boxes of nearer objects of one frame.

    ``boxes`` (N × 4: x, y, w, h px), ``distance_m`` (N,, m; NaN: unknown, behind every box
    with a distance and in front of none). Boxes at the same distance do not occlude each
    other."""
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    d = np.asarray(distance_m, dtype=float)
    key = np.where(np.isfinite(d), d, np.inf)
    out = np.zeros(len(boxes))
    for i in range(len(boxes)):
        nearer = np.isfinite(d) & (key < key[i])
        out[i] = union_cover(boxes[i], boxes[nearer])
    return out


def occlusion_state(share: np.ndarray) -> np.ndarray:
    """KITTI's occlusion state of occluded shares (0–1): 0 fully visible (≤ 0.1), 1 partly
    (≤ 0.5), 2 largely occluded (:data:`OCCLUSION_EDGES`)."""
    return np.searchsorted(np.asarray(OCCLUSION_EDGES), np.asarray(share, dtype=float), "left")


def truncated(boxes: np.ndarray, image_size: tuple[int, int | None]) -> np.ndarray:
    """(N,) bool: box (N × 4, px) within :data:`BORDER_PX` of a border of an image of
    ``image_size`` (width, height px; height None: the left and right borders only)."""
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)
    width, height = image_size
    cut = (b[:, 0] <= BORDER_PX) | (b[:, 0] + b[:, 2] >= width - BORDER_PX)
    if height is not None:
        cut |= (b[:, 1] <= BORDER_PX) | (b[:, 1] + b[:, 3] >= height - BORDER_PX)
    return cut


def box_level(height_px: np.ndarray, is_truncated: np.ndarray, state: np.ndarray) -> np.ndarray:
    """(N,) the strictest level of :data:`LEVELS` each box meets (box height px, truncated,
    occlusion state), :data:`NO_LEVEL` when none."""
    h = np.asarray(height_px, dtype=float)
    out = np.full(len(h), NO_LEVEL, dtype=object)
    for level in reversed(LEVELS):  # the strictest met written last
        ok = (h >= MIN_HEIGHT_PX[level]) & (np.asarray(state) <= MAX_OCCLUSION[level])
        if not TRUNCATED_OK[level]:
            ok &= ~np.asarray(is_truncated, dtype=bool)
        out[ok] = level
    return out


def box_difficulty(
    boxes: pd.DataFrame, image_size: tuple[int, int | None], distance: str = "distance_m"
) -> pd.DataFrame:
    """Per box (rows of ``boxes``: ``frame``, ``box_x``, ``box_y``, ``box_w``, ``box_h`` px and
    ``distance``, m): ``truncated``, ``occluded_share`` (0–1), ``occlusion`` (0–2) and
    ``difficulty`` (:data:`BOX_LEVELS`), aligned with ``boxes``' index."""
    cols = ["box_x", "box_y", "box_w", "box_h"]
    share = pd.Series(0.0, index=boxes.index)
    for _, frame in boxes.groupby("frame", sort=False):
        share[frame.index] = occluded_share(frame[cols].to_numpy(), frame[distance].to_numpy())
    cut = truncated(boxes[cols].to_numpy(), image_size)
    state = occlusion_state(share.to_numpy())
    level = box_level(boxes["box_h"].to_numpy(), cut, state)
    return pd.DataFrame({"truncated": cut, "occluded_share": share.to_numpy(),
                         "occlusion": state, "difficulty": level}, index=boxes.index)  # fmt: skip


def level_rank(levels: np.ndarray | pd.Series) -> np.ndarray:
    """(N,) position of each level name in :data:`BOX_LEVELS` (0 easy … 3 none; an unknown
    name, e.g. a box without a reference row, ranks as none)."""
    codes = pd.Categorical(np.asarray(levels, dtype=object), categories=BOX_LEVELS).codes
    return np.where(codes < 0, len(LEVELS), codes).astype(np.int64)


def worse_level(a: np.ndarray | pd.Series, b: np.ndarray | pd.Series) -> np.ndarray:
    """(N,) the worse (less strict) of two level names per pair: a box pair's level."""
    return np.asarray(BOX_LEVELS, dtype=object)[np.maximum(level_rank(a), level_rank(b))]


def in_level(levels: np.ndarray | pd.Series, level: str) -> np.ndarray:
    """(N,) bool: the boxes or pairs of ``levels`` counted in ranking level ``level``
    (:data:`RANKING_LEVELS`, cumulative: ``moderate`` holds ``easy``; ``all`` holds every)."""
    if level == "all":
        return np.ones(len(levels), dtype=bool)
    if level not in LEVELS:
        raise ValueError(f"difficulty level {level!r}: expected one of {RANKING_LEVELS}")
    return level_rank(levels) <= LEVELS.index(level)
