"""Descriptor matching between two frames: one expensive k=2 query, one cheap selection.

The query set is the previous frame's descriptors and the train set the current frame's (the
Udacity starter's source = previous, reference = current), so ``prev_idx`` indexes the
previous frame's kept keypoints and ``curr_idx`` the current frame's.

Design: :func:`knn_candidates` runs the only expensive call, a k = 2 nearest-neighbour query
(BF or FLANN), and returns the two best candidates of every query as arrays (missing second —
or first — neighbours get index −1 and distance +inf). :func:`select_matches` turns those
candidates into :class:`Matches` for either selector: ``nn`` keeps the first neighbour of
every query, ``knn`` keeps it when ``d0 < ratio · d1`` (a lone neighbour, d1 = inf, passes).
The first neighbour of a k = 2 query is the k = 1 answer, so NN and kNN share one query and the
stage cache keys matching by matcher only; selection costs microseconds.

Distances: BF uses NORM_HAMMING for binary descriptors and NORM_L2 for float ones. FLANN uses
an LSH index for binary (uint8) descriptors and randomised KD-trees for float (float32) ones;
its distances are on the same scale as BF's (Hamming bits, L2 — not squared).

Determinism: building a FLANN index draws random numbers from OpenCV's RNG (KD-tree split
dimensions, LSH hash bits). Unseeded, two identical queries in one process returned different
neighbours for ~25 % (LSH, ORB) and ~38 % (KD-tree, SIFT) of the queries on KITTI frames 0→1.
:func:`knn_candidates` therefore calls ``cv2.setRNGSeed(FLANN_SEED)`` before every FLANN query
(which reseeds the calling thread's OpenCV RNG), so equal inputs give equal matches in every
process and worker. BF is exact and deterministic.

Beyond descriptor matching: ``matcher=klt`` tracks the previous frame's keypoints into the
current frame (:mod:`ttc.features.klt`, no descriptor; :func:`tracks_to_matches` gives the same
index pairs), ``matcher=dis`` / ``farneback`` do the same with a dense flow field
(:mod:`ttc.features.dense_flow`) and ``matcher=custom`` calls your own k = 2 candidate function
(:mod:`ttc.plugins`). :data:`MATCHER_PARAMS` maps every matcher name to its parameter class.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from operator import attrgetter
from typing import Any

import cv2
import numpy as np

from ttc.features.dense_flow import DENSE_FLOW_MATCHERS, DenseFlowParams
from ttc.features.descriptors import check_pair
from ttc.features.klt import KltParams, Tracks
from ttc.features.learned_params import (
    LEARNED_MATCHER_PARAMS,
    LearnedUnavailableError,
    check_learned,
    learned_missing,
)
from ttc.plugins import USER, CustomMatcherParams, match_custom

FLANN_SEED = 0
FLANN_INDEX_KDTREE = 1
FLANN_INDEX_LSH = 6
#: The descriptor matchers (the rubric's).
MATCHERS = ("bf", "flann")
#: Matchers that track keypoints instead of matching descriptors.
TRACKERS = ("klt", *DENSE_FLOW_MATCHERS)
SELECTORS = ("nn", "knn")

_TRAIN_AND_DISTANCE = attrgetter("trainIdx", "distance")


@dataclass(frozen=True)
class MatcherParams:
    """Nearest-neighbour search: ``bf`` (brute force) or ``flann``.

    FLANN: ``flann_trees`` randomised KD-trees searched with ``flann_checks`` leaf checks
    (float descriptors); LSH with ``lsh_table_number`` tables of ``lsh_key_size``-bit keys and
    ``lsh_multi_probe_level`` (binary descriptors).
    """

    name: str = "bf"
    flann_trees: int = 5
    flann_checks: int = 50
    lsh_table_number: int = 12
    lsh_key_size: int = 20
    lsh_multi_probe_level: int = 2

    def __post_init__(self) -> None:
        if self.name not in MATCHERS:
            raise ValueError(f"matcher name must be one of {MATCHERS}, got {self.name!r}")
        for field in ("flann_trees", "flann_checks", "lsh_table_number", "lsh_key_size"):
            if getattr(self, field) <= 0:
                raise ValueError(f"{field} must be > 0, got {getattr(self, field)!r}")
        if self.lsh_multi_probe_level < 0:
            raise ValueError(
                f"lsh_multi_probe_level must be >= 0, got {self.lsh_multi_probe_level}"
            )


@dataclass(frozen=True)
class SelectorParams:
    """Match selection: ``nn`` (best neighbour) or ``knn`` (best if d0 < ``ratio`` · d1)."""

    name: str = "knn"
    k: int = 2
    ratio: float = 0.8

    def __post_init__(self) -> None:
        if self.name not in SELECTORS:
            raise ValueError(f"selector name must be one of {SELECTORS}, got {self.name!r}")
        if self.k != 2:
            raise ValueError(f"only k = 2 is supported (the ratio test), got k={self.k}")
        if not 0.0 < self.ratio <= 1.0:
            raise ValueError(f"ratio must be in (0, 1], got {self.ratio!r}")


@dataclass(frozen=True)
class NoSelectorParams:
    """The selector of a setting whose matcher selects nothing (``matcher=klt``): recorded as
    ``none``."""

    name: str = "none"


NO_SELECTOR = NoSelectorParams()


@dataclass(frozen=True)
class Matches:
    """K matches: ``prev_idx``/``curr_idx`` (int32) index the previous/current frame's kept
    keypoints; ``distance`` (float32) is the descriptor distance (Hamming bits or L2)."""

    prev_idx: np.ndarray
    curr_idx: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        return len(self.prev_idx)

    @classmethod
    def empty(cls) -> Matches:
        """No matches."""
        return cls(np.empty(0, np.int32), np.empty(0, np.int32), np.empty(0, np.float32))


#: Every matcher name → its parameter class.
MATCHER_PARAMS: dict[str, type] = {
    "bf": MatcherParams,
    "flann": MatcherParams,
    "klt": KltParams,
    "dis": DenseFlowParams,
    "farneback": DenseFlowParams,
    **LEARNED_MATCHER_PARAMS,
    USER: CustomMatcherParams,
}


def check_features(detector: str, descriptor: str, matcher: str, variant: str = "n16") -> None:
    """Refuse, before any work, a detector × descriptor × matcher combination that cannot run
    (:class:`~ttc.features.descriptors.InvalidCombinationError` or
    :class:`~ttc.features.learned_params.LearnedUnavailableError`, both ValueErrors): an
    invalid pair, a learned matcher without weights for the descriptor, a missing package or
    weights file (``variant``: ALIKED's). A tracking matcher uses no descriptor."""
    if matcher in TRACKERS:
        missing = learned_missing(detector, variant)
        if missing is not None:
            raise LearnedUnavailableError(missing)
        return
    check_pair(detector, descriptor)
    check_learned(detector, descriptor, matcher, variant)


def uses_descriptors(matcher: Any) -> bool:
    """False for a tracking matcher (``klt``), which needs no descriptor."""
    return matcher.name not in TRACKERS


def tracks_to_matches(tracks: Tracks) -> Matches:
    """KLT tracks as matches: ``curr_idx`` indexes ``tracks.keypoints_curr`` (0..K−1) and
    ``distance`` is the forward–backward error (pixels)."""
    return Matches(
        prev_idx=tracks.prev_idx.astype(np.int32),
        curr_idx=np.arange(len(tracks), dtype=np.int32),
        distance=tracks.fb_error.astype(np.float32),
    )


def empty_candidates(n_queries: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Candidate arrays of ``n_queries`` queries without neighbours (idx −1, dist +inf)."""
    return (
        np.full((n_queries, 2), -1, dtype=np.int32),
        np.full((n_queries, 2), np.inf, dtype=np.float32),
    )


def _rows(descriptors: np.ndarray | None) -> int:
    return 0 if descriptors is None else len(descriptors)


def _prepare(descriptors: np.ndarray, binary: bool) -> np.ndarray:
    """C-contiguous uint8 (binary) or float32 (float) descriptors; ValueError otherwise."""
    descriptors = np.asarray(descriptors)
    if descriptors.ndim != 2:
        raise ValueError(f"descriptors must be 2-D, got shape {descriptors.shape}")
    if binary:
        if descriptors.dtype != np.uint8:
            raise ValueError(f"binary descriptors must be uint8, got {descriptors.dtype}")
        return np.ascontiguousarray(descriptors)
    return np.ascontiguousarray(descriptors, dtype=np.float32)


def _make_matcher(binary: bool, params: MatcherParams) -> Any:
    if params.name == "bf":
        return cv2.BFMatcher(cv2.NORM_HAMMING if binary else cv2.NORM_L2, crossCheck=False)
    if binary:
        index = {
            "algorithm": FLANN_INDEX_LSH,
            "table_number": params.lsh_table_number,
            "key_size": params.lsh_key_size,
            "multi_probe_level": params.lsh_multi_probe_level,
        }
    else:
        index = {"algorithm": FLANN_INDEX_KDTREE, "trees": params.flann_trees}
    return cv2.FlannBasedMatcher(index, {"checks": params.flann_checks})


def knn_results_to_arrays(results: Any, n_queries: int) -> tuple[np.ndarray, np.ndarray]:
    """(idx int32 (Q, 2), dist float32 (Q, 2)) of OpenCV's per-query lists of ≤ 2 DMatch.

    Row q holds query q's neighbours, best first; missing ones are −1 / +inf.
    """
    idx, dist = empty_candidates(n_queries)
    lengths = np.fromiter(map(len, results), dtype=np.int64, count=n_queries)
    flat = [m for ms in results for m in ms]
    if not flat:
        return idx, dist
    pairs = np.array(list(map(_TRAIN_AND_DISTANCE, flat)), dtype=np.float64)
    rows = np.repeat(np.arange(n_queries), lengths)
    cols = np.arange(len(flat)) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    idx[rows, cols] = pairs[:, 0].astype(np.int32)
    dist[rows, cols] = pairs[:, 1]
    return idx, dist


def knn_candidates(
    desc_prev: np.ndarray | None,
    desc_curr: np.ndarray | None,
    binary: bool,
    matcher: MatcherParams | CustomMatcherParams,
) -> tuple[np.ndarray, np.ndarray]:
    """The two nearest current-frame descriptors of every previous-frame descriptor.

    Returns ``idx`` int32 (Q, 2) into ``desc_curr`` and ``dist`` float32 (Q, 2), best first,
    Q = len(desc_prev); missing neighbours are −1 / +inf. Empty or None input on either side
    gives Q rows without neighbours (Q = 0 when ``desc_prev`` is empty or None).
    """
    n_prev, n_curr = _rows(desc_prev), _rows(desc_curr)
    if n_prev == 0 or n_curr == 0:
        return empty_candidates(n_prev)
    if matcher.name == USER:
        return match_custom(desc_prev, desc_curr, binary, matcher)
    query, train = _prepare(desc_prev, binary), _prepare(desc_curr, binary)
    if query.shape[1] != train.shape[1]:
        raise ValueError(f"descriptor widths differ: {query.shape[1]} vs {train.shape[1]}")
    if matcher.name == "flann":
        cv2.setRNGSeed(FLANN_SEED)
    k = min(2, n_curr)  # FLANN asserts k <= index size
    results = _make_matcher(binary, matcher).knnMatch(query, train, k=k)
    return knn_results_to_arrays(results, n_prev)


def select_matches(idx: np.ndarray, dist: np.ndarray, selector: SelectorParams) -> Matches:
    """Matches chosen from k = 2 candidates (see the module docstring).

    ``nn``: the first neighbour of every query that has one. ``knn``: the first neighbour when
    ``dist[:, 0] < selector.ratio · dist[:, 1]`` (strict, as in the course).
    """
    idx, dist = np.asarray(idx), np.asarray(dist)
    if len(idx) == 0:
        return Matches.empty()
    has_first = idx[:, 0] >= 0
    if selector.name in ("nn", NO_SELECTOR.name):  # none: a learned matcher chose already
        keep = has_first
    else:
        d0, d1 = dist[:, 0].astype(np.float64), dist[:, 1].astype(np.float64)
        keep = has_first & (d0 < selector.ratio * d1)
    rows = np.flatnonzero(keep)
    return Matches(
        prev_idx=rows.astype(np.int32),
        curr_idx=idx[rows, 0].astype(np.int32),
        distance=dist[rows, 0].astype(np.float32),
    )


def match_descriptors(
    desc_prev: np.ndarray | None,
    desc_curr: np.ndarray | None,
    binary: bool,
    matcher: MatcherParams,
    selector: SelectorParams,
) -> Matches:
    """:func:`knn_candidates` followed by :func:`select_matches`."""
    idx, dist = knn_candidates(desc_prev, desc_curr, binary, matcher)
    return select_matches(idx, dist, selector)


#: The arrays of a matches-stage entry of a tracking matcher (else ``idx`` and ``dist``).
TRACK_ARRAYS = ("prev_idx", "keypoints", "fb_error")


def tracks_to_arrays(tracks: Tracks) -> dict[str, np.ndarray]:
    """The matches-stage entry of KLT tracks (:data:`TRACK_ARRAYS`)."""
    return dict(zip(TRACK_ARRAYS, (tracks.prev_idx, tracks.keypoints_curr, tracks.fb_error),
                    strict=True))  # fmt: skip


def is_tracks(match_arrays: Mapping[str, np.ndarray]) -> bool:
    """True for a matches-stage entry of a tracking matcher (KLT tracks)."""
    return TRACK_ARRAYS[0] in match_arrays


def pair_matches(match_arrays: Mapping[str, np.ndarray], selector: Any) -> Matches:
    """The matches of a frame pair from its matches-stage entry: ``selector`` applied to k = 2
    candidates (``idx``, ``dist``), or KLT tracks as matches (the selector unused)."""
    if is_tracks(match_arrays):
        return tracks_to_matches(Tracks(*(match_arrays[k] for k in TRACK_ARRAYS)))
    return select_matches(match_arrays["idx"], match_arrays["dist"], selector)


def current_keypoints(
    described_curr: np.ndarray, match_arrays: Mapping[str, np.ndarray]
) -> np.ndarray:
    """The current frame's keypoints (N, 7) that :func:`pair_matches`' ``curr_idx`` index: the
    described keypoints, or the tracked positions of KLT tracks."""
    return match_arrays["keypoints"] if is_tracks(match_arrays) else described_curr
