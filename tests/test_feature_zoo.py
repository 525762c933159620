"""Every detector × descriptor pair beyond the rubric's 42, on the real KITTI frames 0 and 1:
a valid pair gives descriptors and matches, an invalid one raises the typed error before any
work, and a feature the installed OpenCV lacks is reported as unavailable.

To keep the 145 pairs cheap, keypoints are described in the frames' central band (x in
[400, 840) px, the lead car and the road ahead: a third of each frame's keypoints). VGG still
costs ~1 s per frame there: its pairs are marked slow except on the Star detector, so
``-m "not slow"`` still describes with it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from ttc.features import detectors_extra
from ttc.features.descriptors import (
    DESCRIPTORS,
    EXTRA_DESCRIPTOR_NAMES,
    INVALID_PAIRS,
    RUBRIC_DESCRIPTORS,
    FeatureUnavailableError,
    InvalidCombinationError,
    check_pair,
    describe_keypoints,
    descriptor_is_binary,
    valid_pairs,
)
from ttc.features.keypoints import (
    DETECTORS,
    EXTRA_DETECTOR_NAMES,
    RUBRIC_DETECTORS,
    array_to_keypoints,
    detect_keypoints,
)
from ttc.features.matching import MatcherParams, SelectorParams, match_descriptors
from ttc.io.frames import read_image

ALL_DETECTORS = (*RUBRIC_DETECTORS, *EXTRA_DETECTOR_NAMES)
ALL_DESCRIPTORS = (*RUBRIC_DESCRIPTORS, *EXTRA_DESCRIPTOR_NAMES)
#: Pairs the rubric's tests do not cover: a new detector or a new descriptor.
NEW_PAIRS = [
    (det, desc)
    for det in ALL_DETECTORS
    for desc in ALL_DESCRIPTORS
    if det in EXTRA_DETECTOR_NAMES or desc in EXTRA_DESCRIPTOR_NAMES
]
#: LUCID wants colour; on grey frames its matches are mostly wrong (see ttc.features.descriptors).
WEAK_DESCRIPTORS = {"lucid"}
BAND = (400.0, 840.0)  # px: the central band whose keypoints are described


def _param(det: str, desc: str):
    marks = [pytest.mark.slow] if desc == "vgg" and det != "star" else []
    return pytest.param(det, desc, id=f"{det}-{desc}", marks=marks)


@pytest.fixture(scope="module")
def grays(kitti_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    paths = [kitti_dir / "image_02" / "data" / f"{i:010d}.png" for i in (0, 1)]
    return tuple(cv2.cvtColor(read_image(p), cv2.COLOR_BGR2GRAY) for p in paths)


@pytest.fixture(scope="module")
def keypoints(grays) -> Callable[[str], tuple[np.ndarray, np.ndarray]]:
    @functools.cache
    def get(detector: str) -> tuple[np.ndarray, np.ndarray]:
        found = (detect_keypoints(g, DETECTORS[detector]()) for g in grays)
        return tuple(k[(k[:, 0] >= BAND[0]) & (k[:, 0] < BAND[1])] for k in found)

    return get


def test_zoo_registries_and_pair_table() -> None:
    assert set(EXTRA_DETECTOR_NAMES) == {
        "kaze", "agast", "mser", "star", "msd", "harris_laplace", "grid"
    }  # fmt: skip
    assert set(EXTRA_DESCRIPTOR_NAMES) == {
        "kaze", "beblid", "teblid", "daisy", "latch", "lucid", "boostdesc", "vgg"
    }  # fmt: skip
    every = {(d, e) for d in ALL_DETECTORS for e in ALL_DESCRIPTORS}
    assert set(valid_pairs(rubric_only=False)) == every - set(INVALID_PAIRS)
    assert (
        len(every - set(INVALID_PAIRS)) == 182 - 12 - 12 - 1 - 1
    )  # akaze, kaze, sift/orb, msd/sift; the grid (for trackers) pairs with no descriptor


@pytest.mark.parametrize(("detector", "descriptor"), [_param(*p) for p in NEW_PAIRS])
def test_new_pair_matches_frames_0_1_or_raises_the_typed_error(
    grays, keypoints, detector: str, descriptor: str
) -> None:
    params = DESCRIPTORS[descriptor]()
    if (detector, descriptor) in INVALID_PAIRS:
        untouchable = np.zeros((3, 5))  # any work on it would raise ValueError, not ours
        with pytest.raises(InvalidCombinationError) as err:
            describe_keypoints(grays[0], untouchable, detector, params)
        assert err.value.reason == INVALID_PAIRS[(detector, descriptor)]
        return
    described = [
        describe_keypoints(g, kps, detector, params)
        for g, kps in zip(grays, keypoints(detector), strict=True)
    ]
    (kp0, d0), (kp1, d1) = described
    assert len(kp0) == len(d0) > 20 and len(kp1) == len(d1) > 20
    binary = descriptor_is_binary(params)
    assert d0.dtype == (np.uint8 if binary else np.float32) and np.isfinite(d0).all()
    m = match_descriptors(d0, d1, binary, MatcherParams(), SelectorParams())
    assert len(m) > 10
    moved = np.hypot(*(kp1[m.curr_idx, :2] - kp0[m.prev_idx, :2]).T)
    # The car moves ~1 m between frames: good matches move little, random ones do not.
    assert np.mean(moved < 30.0) > (0.05 if descriptor in WEAK_DESCRIPTORS else 0.85)


@pytest.mark.parametrize(("detector", "descriptor"), [("fast", "kaze"), ("msd", "sift")])
def test_the_invalid_reasons_still_hold_in_this_opencv(grays, keypoints, detector, descriptor):
    """The table's reasons are OpenCV's behaviour: revisit the table if this fails."""
    from ttc.features.descriptors import make_extractor

    extractor = make_extractor(DESCRIPTORS[descriptor](), detector)
    with pytest.raises(cv2.error):
        extractor.compute(grays[0], array_to_keypoints(keypoints(detector)[0]))


def test_documented_scale_is_used_when_scale_factor_is_zero(grays, keypoints) -> None:
    """BEBLID with scale 0 on ORB keypoints equals BEBLID with ORB's documented 1.0."""
    kps = keypoints("orb")[0][:200]
    auto = describe_keypoints(grays[0], kps, "orb", DESCRIPTORS["beblid"]())[1]
    fixed = describe_keypoints(grays[0], kps, "orb", DESCRIPTORS["beblid"](scale_factor=1.0))[1]
    other = describe_keypoints(grays[0], kps, "orb", DESCRIPTORS["beblid"](scale_factor=5.0))[1]
    np.testing.assert_array_equal(auto, fixed)
    assert not np.array_equal(auto, other)


def test_a_feature_opencv_lacks_is_reported_unavailable(monkeypatch, grays) -> None:
    monkeypatch.setitem(detectors_extra.OPENCV_ALGORITHMS, "star", "NoSuchStarDetector")
    with pytest.raises(FeatureUnavailableError, match="unavailable") as err:
        check_pair("star", "brief")
    assert isinstance(err.value, InvalidCombinationError)  # a sweep records a skip
    with pytest.raises(FeatureUnavailableError):
        describe_keypoints(grays[0], np.zeros((3, 5)), "star", DESCRIPTORS["brief"]())
    check_pair("fast", "brief")  # the others are untouched
