"""Keypoints, descriptors and matching on the real KITTI frames 0 and 1, with real OpenCV.

Keypoints are detected once per detector, descriptors once per valid pair and k=2 candidates
once per (pair, matcher) — cached in module-scoped fixtures — so every one of the 140
detector × descriptor × matcher × selector combinations is its own cheap test.
"""

from __future__ import annotations

import functools
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from ttc.features.descriptors import (
    DESCRIPTORS,
    INVALID_PAIRS,
    RUBRIC_DESCRIPTORS,
    InvalidCombinationError,
    check_pair,
    describe_keypoints,
    is_binary,
    valid_pairs,
)
from ttc.features.keypoints import (
    CLASS_ID,
    DETECTORS,
    KEYPOINT_COLUMNS,
    OCTAVE,
    RESPONSE,
    RUBRIC_DETECTORS,
    SIZE,
    FastParams,
    HarrisParams,
    OpenCVFeatureMissing,
    ShiTomasiParams,
    array_to_keypoints,
    detect_keypoints,
    keypoints_to_array,
    nms_local_maxima,
    opencv_factory,
)
from ttc.features.matching import (
    MATCHERS,
    SELECTORS,
    MatcherParams,
    Matches,
    SelectorParams,
    knn_candidates,
    match_descriptors,
    select_matches,
)
from ttc.io.frames import read_image

FRAMES = (0, 1)
COMBINATIONS = [
    (det, desc, matcher, selector)
    for det, desc in valid_pairs()
    for matcher in MATCHERS
    for selector in SELECTORS
]

Described = tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@pytest.fixture(scope="module")
def grays(kitti_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """Frames 0 and 1 as uint8 grayscale (375 × 1242)."""
    paths = [kitti_dir / "image_02" / "data" / f"{i:010d}.png" for i in FRAMES]
    return tuple(cv2.cvtColor(read_image(p), cv2.COLOR_BGR2GRAY) for p in paths)


@pytest.fixture(scope="module")
def keypoints(grays) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Keypoints of frames 0 and 1 for every rubric detector with default parameters (the
    other detectors: ``tests/test_feature_zoo.py``)."""
    return {
        name: tuple(detect_keypoints(g, DETECTORS[name]()) for g in grays)
        for name in RUBRIC_DETECTORS
    }


@pytest.fixture(scope="module")
def described(grays, keypoints) -> Callable[[str, str], Described]:
    """(kept keypoints, descriptors) of frames 0 and 1 for a pair, computed once per pair."""

    @functools.cache
    def get(detector: str, descriptor: str) -> Described:
        params = DESCRIPTORS[descriptor]()
        return tuple(
            describe_keypoints(g, kps, detector, params)
            for g, kps in zip(grays, keypoints[detector], strict=True)
        )

    return get


@pytest.fixture(scope="module")
def candidates(described) -> Callable[[str, str, str], tuple[np.ndarray, np.ndarray]]:
    """k=2 candidates 0 → 1 for a pair and matcher, computed once."""

    @functools.cache
    def get(detector: str, descriptor: str, matcher: str) -> tuple[np.ndarray, np.ndarray]:
        (_, d0), (_, d1) = described(detector, descriptor)
        return knn_candidates(d0, d1, is_binary(descriptor), MatcherParams(name=matcher))

    return get


# --- every valid combination ---------------------------------------------------------------


def test_pair_table_has_35_valid_and_7_invalid() -> None:
    assert len(valid_pairs()) == 35 and len(set(valid_pairs())) == 35
    rubric = {(d, e) for d in RUBRIC_DETECTORS for e in RUBRIC_DESCRIPTORS}
    assert set(INVALID_PAIRS) & rubric == {
        (d, "akaze") for d in RUBRIC_DETECTORS if d != "akaze"
    } | {("sift", "orb")}
    assert not set(valid_pairs()) & set(INVALID_PAIRS)


@pytest.mark.parametrize(("detector", "descriptor", "matcher", "selector"), COMBINATIONS,
                         ids=["-".join(c) for c in COMBINATIONS])  # fmt: skip
def test_valid_combination_matches_frames_0_1(
    described, candidates, detector: str, descriptor: str, matcher: str, selector: str
) -> None:
    (kp0, d0), (kp1, d1) = described(detector, descriptor)
    assert len(kp0) == len(d0) > 0 and len(kp1) == len(d1) > 0
    assert d0.dtype == (np.uint8 if is_binary(descriptor) else np.float32)
    m = select_matches(*candidates(detector, descriptor, matcher), SelectorParams(name=selector))
    assert len(m) > 0
    assert m.prev_idx.dtype == m.curr_idx.dtype == np.int32 and m.distance.dtype == np.float32
    assert m.prev_idx.min() >= 0 and m.prev_idx.max() < len(kp0)
    assert m.curr_idx.min() >= 0 and m.curr_idx.max() < len(kp1)
    assert len(np.unique(m.prev_idx)) == len(m)  # one match per previous keypoint
    assert np.all(np.isfinite(m.distance)) and m.distance.min() >= 0
    # The car moves ~1 m between frames: good matches move little. Random ones would not.
    moved = np.hypot(*(kp1[m.curr_idx, :2] - kp0[m.prev_idx, :2]).T)
    assert np.mean(moved < 30.0) > (0.85 if selector == "knn" else 0.4)


@pytest.mark.parametrize(("detector", "descriptor"), sorted(INVALID_PAIRS))
def test_invalid_pair_raises_before_any_work(grays, detector: str, descriptor: str) -> None:
    untouchable = np.zeros((3, 5))  # not a keypoint array: any work on it raises ValueError
    with pytest.raises(InvalidCombinationError) as err:
        describe_keypoints(grays[0], untouchable, detector, DESCRIPTORS[descriptor]())
    exc = err.value
    assert (exc.detector, exc.descriptor) == (detector, descriptor)
    assert exc.reason == INVALID_PAIRS[(detector, descriptor)]
    assert detector in str(exc) and descriptor in str(exc) and exc.reason in str(exc)
    with pytest.raises(InvalidCombinationError):
        check_pair(detector, descriptor)


def test_akaze_descriptor_really_fails_on_foreign_keypoints(grays, keypoints) -> None:
    """The reason in the table still holds in this OpenCV: revisit the table if this fails."""
    extractor = cv2.AKAZE_create()
    with pytest.raises(cv2.error, match="class_id"):
        extractor.compute(grays[0], array_to_keypoints(keypoints["fast"][0]))


def test_unknown_names_are_plain_value_errors() -> None:
    for det, desc in (("surf", "brief"), ("fast", "surf")):
        with pytest.raises(ValueError) as err:
            check_pair(det, desc)
        assert not isinstance(err.value, InvalidCombinationError)


# --- keypoints -----------------------------------------------------------------------------


def test_array_keypoint_round_trip_keeps_all_fields(keypoints) -> None:
    hand = [
        cv2.KeyPoint(1.5, 2.25, 7.0, 123.5, 0.75, 3, 9),
        cv2.KeyPoint(1241.0, 374.0, 128.5, -1.0, -2.5, -16711425, -1),  # negative packed octave
    ]
    arr = keypoints_to_array(hand)
    assert arr.shape == (2, len(KEYPOINT_COLUMNS)) and arr.dtype == np.float64
    for kp, row in zip(array_to_keypoints(arr), arr, strict=True):
        fields = (*kp.pt, kp.size, kp.angle, kp.response, kp.octave, kp.class_id)
        assert fields == tuple(row)
    np.testing.assert_array_equal(arr[1], [1241.0, 374.0, 128.5, -1.0, -2.5, -16711425, -1])
    # Real keypoints exercise every field: SIFT packs octave/layer, AKAZE sets class_id.
    for name in ("sift", "akaze", "orb"):
        real = keypoints[name][0]
        np.testing.assert_array_equal(keypoints_to_array(array_to_keypoints(real)), real)
    assert keypoints["akaze"][0][:, CLASS_ID].max() > 0
    assert np.abs(keypoints["sift"][0][:, OCTAVE]).max() > 2**16
    assert keypoints_to_array([]).shape == (0, 7) and array_to_keypoints(np.empty((0, 7))) == []


def test_detection_is_deterministic_and_sane(grays, keypoints) -> None:
    h, w = grays[0].shape
    for name in RUBRIC_DETECTORS:
        kps = keypoints[name][0]
        assert len(kps) > 50, name
        np.testing.assert_array_equal(
            detect_keypoints(grays[0], DETECTORS[name]()), kps, err_msg=name
        )
        assert kps[:, 0].min() >= 0 and kps[:, 0].max() < w and kps[:, 1].max() < h, name
        assert np.all(kps[:, SIZE] > 0), name


def test_harris_nms_keeps_keypoints_apart(keypoints) -> None:
    params = HarrisParams()
    kps = keypoints["harris"][0]
    assert params.nms_distance == 6.0 and np.all(kps[:, SIZE] == 6.0)
    assert np.all(kps[:, RESPONSE] > params.min_response)
    diff = kps[:, None, :2] - kps[None, :, :2]
    dist = np.hypot(diff[..., 0], diff[..., 1]) + np.diag(np.full(len(kps), np.inf))
    assert dist.min() >= params.nms_distance


def test_nms_on_hand_built_responses() -> None:
    resp = np.zeros((40, 40), np.float32)
    resp[5:8, 5:8] = 200.0  # a 3 × 3 plateau: exactly one survivor, the first in raster order
    resp[20, 10], resp[20, 15] = 150.0, 160.0  # 5 px apart: only the stronger
    resp[30, 10], resp[30, 16] = 150.0, 160.0  # 6 px apart: both
    resp[35, 35] = 90.0  # below min_response
    rows, cols = nms_local_maxima(resp, 100.0, 6.0)
    assert list(zip(rows.tolist(), cols.tolist(), strict=True)) == [
        (5, 5), (20, 15), (30, 10), (30, 16)
    ]  # fmt: skip
    rows, _ = nms_local_maxima(resp, 100.0, 1.0)  # no suppression: every candidate
    assert len(rows) == 9 + 4


def test_shitomasi_min_distance_follows_max_overlap(grays) -> None:
    assert ShiTomasiParams().min_distance == 4.0
    assert ShiTomasiParams(max_overlap=0.5).min_distance == 2.0
    kps = detect_keypoints(grays[0], ShiTomasiParams(block_size=6))
    xy = kps[:, :2]
    d2 = ((xy[:, None] - xy[None]) ** 2).sum(-1) + np.diag(np.full(len(xy), np.inf))
    assert d2.min() >= 6.0**2


def test_params_validate_choices_and_names() -> None:
    with pytest.raises(ValueError, match="TYPE_9_16"):
        FastParams(type="TYPE_9_15")
    with pytest.raises(ValueError, match="'fast'"):
        FastParams(name="orb")
    for registry in (DETECTORS, DESCRIPTORS):
        for name, cls in registry.items():
            assert cls().name == name
    with pytest.raises(ValueError, match="grayscale"):
        detect_keypoints(np.zeros((4, 4, 3), np.uint8), FastParams())


def test_missing_opencv_factory_names_the_package() -> None:
    with pytest.raises(OpenCVFeatureMissing, match="opencv-contrib-python-headless") as err:
        opencv_factory("NoSuchExtractor", contrib=True)
    assert "cv2.xfeatures2d.NoSuchExtractor_create" in str(err.value)
    assert callable(opencv_factory("FREAK", contrib=True))


# --- descriptors ---------------------------------------------------------------------------


WIDTHS = {"brisk": 64, "brief": 32, "orb": 32, "freak": 64, "akaze": 61, "sift": 128,
          "beblid": 64, "teblid": 32, "daisy": 200, "latch": 32, "lucid": 27, "boostdesc": 32,
          "vgg": 120}  # fmt: skip


@pytest.mark.parametrize("descriptor", list(WIDTHS))
def test_empty_keypoints_give_empty_arrays(grays, descriptor: str) -> None:
    kps, desc = describe_keypoints(grays[0], np.empty((0, 7)), "akaze", DESCRIPTORS[descriptor]())
    width = WIDTHS
    assert kps.shape == (0, 7) and desc.shape == (0, width[descriptor])
    assert desc.dtype == (np.uint8 if is_binary(descriptor) else np.float32)


def test_descriptor_keypoints_are_the_ones_opencv_kept(grays, keypoints, described) -> None:
    """FREAK drops many ORB keypoints; the kept rows must be a subset of the detected ones."""
    detected = keypoints["orb"][0]
    (kept, desc), _ = described("orb", "freak")
    assert len(kept) == len(desc) < len(detected)
    rows = {tuple(r) for r in detected[:, :2].tolist()}
    assert all(tuple(r) in rows for r in kept[:, :2].tolist())


# --- matching ------------------------------------------------------------------------------


def test_select_matches_on_hand_built_table() -> None:
    inf = np.inf
    idx = np.array([[4, 1], [2, 3], [7, 0], [5, -1], [-1, -1], [6, 2]], np.int32)
    dist = np.array([[10, 20], [8, 10], [7, 10], [3, inf], [inf, inf], [0, 0]], np.float32)
    nn = select_matches(idx, dist, SelectorParams(name="nn"))
    np.testing.assert_array_equal(nn.prev_idx, [0, 1, 2, 3, 5])
    np.testing.assert_array_equal(nn.curr_idx, [4, 2, 7, 5, 6])
    np.testing.assert_array_equal(nn.distance, [10, 8, 7, 3, 0])
    knn = select_matches(idx, dist, SelectorParams(name="knn", ratio=0.8))
    np.testing.assert_array_equal(knn.prev_idx, [0, 2, 3])  # 8 < 0.8·10 is false: boundary out
    np.testing.assert_array_equal(knn.curr_idx, [4, 7, 5])
    half = select_matches(idx, dist, SelectorParams(name="knn", ratio=0.5))
    np.testing.assert_array_equal(half.prev_idx, [3])  # 10 < 0.5·20 is false too
    assert len(select_matches(idx[:0], dist[:0], SelectorParams())) == 0


@pytest.mark.parametrize("matcher", MATCHERS)
def test_knn_matches_are_a_subset_of_nn_matches(candidates, matcher: str) -> None:
    for det, desc in valid_pairs():
        idx, dist = candidates(det, desc, matcher)
        nn = select_matches(idx, dist, SelectorParams(name="nn"))
        knn = select_matches(idx, dist, SelectorParams(name="knn"))
        pairs = set(zip(nn.prev_idx.tolist(), nn.curr_idx.tolist(), strict=True))
        assert set(zip(knn.prev_idx.tolist(), knn.curr_idx.tolist(), strict=True)) <= pairs
        assert 0 < len(knn) < len(nn), (det, desc)


def test_candidates_are_sorted_and_agree_with_brute_force(candidates, described) -> None:
    (_, d0), (_, d1) = described("fast", "brief")
    idx, dist = candidates("fast", "brief", "bf")
    assert np.all(dist[:, 0] <= dist[:, 1])
    bits = np.unpackbits(d0[:, None, :] ^ d1[None, :, :], axis=-1).sum(-1)
    np.testing.assert_array_equal(dist[:, 0], bits.min(axis=1))
    np.testing.assert_array_equal(np.sort(bits, axis=1)[:, 1], dist[:, 1])


@pytest.mark.parametrize(("detector", "descriptor"), [("orb", "orb"), ("sift", "sift")])
def test_flann_is_deterministic(described, tmp_path: Path, detector: str, descriptor: str):
    (_, d0), (_, d1) = described(detector, descriptor)
    flann = MatcherParams(name="flann")
    first = knn_candidates(d0, d1, is_binary(descriptor), flann)
    cv2.randu(np.empty(1000, np.float32), 0.0, 1.0)  # move OpenCV's RNG on
    second = knn_candidates(d0, d1, is_binary(descriptor), flann)
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a, b)
    # ... and in a fresh process, as a sweep worker would run it.
    np.save(tmp_path / "d0.npy", d0)
    np.save(tmp_path / "d1.npy", d1)
    script = (
        "import sys, numpy as np\n"
        "from ttc.features.matching import MatcherParams, knn_candidates\n"
        "d0, d1 = (np.load(f'{sys.argv[1]}/{n}.npy') for n in ('d0', 'd1'))\n"
        f"idx, _ = knn_candidates(d0, d1, {is_binary(descriptor)}, MatcherParams(name='flann'))\n"
        "np.save(f'{sys.argv[1]}/idx.npy', idx)\n"
    )
    subprocess.run([sys.executable, "-c", script, str(tmp_path)], check=True, timeout=120)
    np.testing.assert_array_equal(np.load(tmp_path / "idx.npy"), first[0])


@pytest.mark.parametrize("matcher", MATCHERS)
@pytest.mark.parametrize("binary", [True, False])
def test_empty_and_tiny_inputs(matcher: str, binary: bool) -> None:
    rng = np.random.default_rng(0)
    desc = (
        rng.integers(0, 256, (5, 32), dtype=np.uint8)
        if binary
        else rng.random((5, 128), dtype=np.float32)
    )
    params, sel = MatcherParams(name=matcher), SelectorParams()
    for prev, curr in ((None, desc), (desc, None), (desc[:0], desc), (desc, desc[:0])):
        m = match_descriptors(prev, curr, binary, params, sel)
        assert isinstance(m, Matches) and len(m) == 0 and m.prev_idx.dtype == np.int32
    idx, dist = knn_candidates(desc, desc[:1], binary, params)  # one train row: k = 1
    assert idx.shape == (5, 2) and np.all(idx[:, 1] == -1) and np.all(np.isinf(dist[:, 1]))
    assert set(idx[:, 0].tolist()) <= {-1, 0}
    idx, dist = knn_candidates(desc, desc, binary, MatcherParams(name="bf"))
    np.testing.assert_array_equal(idx[:, 0], np.arange(5))  # every descriptor finds itself
    assert np.all(dist[:, 0] == 0)


@pytest.mark.parametrize("descriptor", RUBRIC_DESCRIPTORS)
def test_a_shared_extractor_describes_as_a_new_one(grays, descriptor: str) -> None:
    """One extractor object per (params, detector) and process describes every frame as a
    freshly made one (no state carried over from the previous image)."""
    from ttc.features.descriptors import make_extractor, shared_extractor

    detector = descriptor if descriptor in ("akaze", "sift") else "orb"
    params = DESCRIPTORS[descriptor]()
    assert shared_extractor(params, detector) is shared_extractor(
        DESCRIPTORS[descriptor](), detector
    )
    for gray in (*grays, grays[0]):
        kps = detect_keypoints(gray, DETECTORS[detector]())
        kept, desc = describe_keypoints(gray, kps, detector, params)  # the shared object
        fresh_kept, fresh = make_extractor(params, detector).compute(gray, array_to_keypoints(kps))
        np.testing.assert_array_equal(kept, keypoints_to_array(fresh_kept))
        np.testing.assert_array_equal(desc, fresh)
