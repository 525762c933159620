"""Per-stage times of the learned features and dense flow on one KITTI frame pair (issue 23).

XFeat, ALIKED-n16 and DISK keypoints + descriptors per frame, LighterGlue / LightGlue per pair
(on those features) and DIS / Farnebäck per pair, on ``--device`` (cpu: one torch and OpenCV
thread, as a sweep job; cuda: the GPU, synchronised), each the median of ``--repeat`` calls
after one warm-up call. Writes a JSON list of ``{stage, device, ms_median, ms_min, n, ...}``.
Needs the learned extra.

    python -m experiments.tools.learned_timing --device cpu cuda --repeat 5 --out timing.json
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from experiments.host import paths
from ttc.features import learned
from ttc.features.dense_flow import DenseFlowParams, flow_keypoints
from ttc.features.keypoints import FastParams, detect_keypoints
from ttc.features.learned_params import LEARNED_DETECTORS, GlueParams
from ttc.io.frames import read_image

#: (learned detector, its matcher) timed.
CASES = (("xfeat", "lighterglue"), ("aliked", "lightglue"), ("disk", "lightglue"))


def timed(fn: Callable[[], Any], repeat: int, sync: Callable[[], None]) -> tuple[list[float], Any]:
    """(ms of each of ``repeat`` calls after one warm-up, the last result)."""
    out = fn()
    sync()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        sync()
        times.append(1e3 * (time.perf_counter() - start))
    return times, out


def _row(stage: str, device: str, times: list[float], **extra: Any) -> dict[str, Any]:
    return {"stage": stage, "device": device, "ms_median": float(np.median(times)),
            "ms_min": float(min(times)), "repeat": len(times), **extra}  # fmt: skip


def time_device(
    grays: list[np.ndarray], device: str, repeat: int, cases: tuple[str, ...], match: bool = True
) -> list[dict[str, Any]]:
    """The rows of the learned stages of ``cases`` (detector names) on ``device`` (cpu or
    cuda) for frames ``grays``; without ``match``, extraction only (for a copy of the weights
    packages that leaves the matchers' files out)."""
    import torch

    def sync() -> None:
        if device == "cuda":
            torch.cuda.synchronize()

    rows = []
    size = grays[0].shape[::-1]
    for name, glue in CASES:
        if name not in cases:
            continue
        params = LEARNED_DETECTORS[name](device=device)

        def cold(g: np.ndarray = grays[0], p: Any = params) -> Any:
            learned.forget_recent()
            return learned.extract(g, p)

        times, (kps, _) = timed(cold, repeat, sync)
        rows.append(_row(f"{name} keypoints+descriptors per frame", device, times, n=len(kps)))
        if not match:
            continue
        feats = [learned.extract(g, params) for g in grays]
        matcher = GlueParams(glue, device=device)

        def match(f: list = feats, m: GlueParams = matcher, d: str = name) -> Any:
            return learned.glue_candidates(*f[0], *f[1], size, d, m)

        times, (idx, _) = timed(match, repeat, sync)
        rows.append(_row(f"{glue} ({name}) per pair", device, times, n=int((idx[:, 0] >= 0).sum())))
    return rows


def time_dense_flow(grays: list[np.ndarray], repeat: int) -> list[dict[str, Any]]:
    """DIS and Farnebäck per pair on FAST keypoints (CPU, OpenCV)."""
    kps = detect_keypoints(grays[0], FastParams())
    rows = []
    for name in ("dis", "farneback"):
        p = DenseFlowParams(name)
        times, tracks = timed(lambda p=p: flow_keypoints(*grays, kps, p), repeat, lambda: None)
        rows.append(_row(f"{name} per pair (both directions)", "cpu", times, n=len(tracks)))
    return rows


def _devices() -> dict[str, Any]:
    """The processor and, when there is one, the GPU and the torch build the times come from."""
    import torch

    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    cpuinfo = Path("/proc/cpuinfo")
    names = [line.split(":", 1)[1].strip() for line in
             (cpuinfo.read_text().splitlines() if cpuinfo.exists() else [])
             if line.startswith("model name")]  # fmt: skip
    cpu = names[0] if names else platform.processor() or platform.machine()
    return {"cpu": cpu, "torch": torch.__version__,
            "gpu": gpu}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", nargs="+", default=["cpu"], choices=["cpu", "cuda"])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--data-root", type=Path, default=None,
                        help="data root (default: TTC_DATA_DIR or ../shared/data)")  # fmt: skip
    parser.add_argument("--frames", type=int, nargs=2, default=(10, 11))
    parser.add_argument("--cases", nargs="+", default=[c[0] for c in CASES],
                        choices=[c[0] for c in CASES], help="learned detectors timed")  # fmt: skip
    parser.add_argument("--no-match", action="store_true", help="time extraction only")
    parser.add_argument("--no-flow", action="store_true", help="leave out DIS and Farneback")
    parser.add_argument("--out", type=Path, default=Path("learned_timing.json"))
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    root = args.data_root or paths.default_data_root()
    images = root / "kitti" / "2011_09_26" / "image_02" / "data"
    grays = [cv2.cvtColor(read_image(images / f"{i:010d}.png"), cv2.COLOR_BGR2GRAY)
             for i in args.frames]  # fmt: skip
    rows = [] if args.no_flow else time_dense_flow(grays, args.repeat)
    for device in args.device:
        rows += time_device(grays, device, args.repeat, tuple(args.cases), not args.no_match)
    meta = {"machine": platform.node(), "python": platform.python_version(),
            "frames": list(args.frames), **_devices()}  # fmt: skip
    args.out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    for row in rows:
        print(f"{row['stage']:<45} {row['device']:<5} {row['ms_median']:9.1f} ms  n={row['n']}")


if __name__ == "__main__":
    main()
