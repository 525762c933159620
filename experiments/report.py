"""The FP.5 (lidar) and FP.6 (camera) reports of one or more sweeps: markdown + CSV + PNG.

Usage::

    python -m experiments.report sweeps/fp6_grid_kitti_0_18 --out results/kitti_0_18
    python -m experiments.report sweeps/fp5_lidar_kitti_0_18 sweeps/fp6_grid_kitti_0_18 \\
        --out results/kitti_0_18

Writes ``metrics.parquet`` beside each sweep (one row per run) and, under ``--out``:

* ``reference.md/.csv/.png``: the reference TTC (:mod:`ttc.evaluation.reference`) and its caveats;
* ``fp5_lidar.md``, ``fp5_lidar_ttc.csv`` (one row per frame × lidar estimator),
  ``fp5_lidar_ttc.png`` and ``fp5_pictures/`` (top views of flagged frames);
* ``fp6_camera.md``, ``fp6_camera_ttc.csv`` (one row per frame × camera setting),
  ``fp6_ranking.csv`` (metrics + bootstrap rank interval per setting), the heatmap, series and
  Pareto plots and ``fp6_pictures/`` (keypoint matches of the worst frames).

FP.5 covers every lidar estimator present in the sweeps, FP.6 every camera setting (all axes
but ``lidar_ttc``). Flags and reasons are derived from the data by the rules below (each a
vectorised test on the frame table, plus a few measurements on the intermediate arrays of
:func:`ttc.pipeline.pair_detail` for a bounded number of frames). The CSVs hold no timestamps
and fixed float formats: the same sweep data gives byte-identical CSVs.
"""

from __future__ import annotations

import argparse
import datetime as dt
import functools
import io
import json
import shutil
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import seaborn as sns
import yaml
from omegaconf import DictConfig, OmegaConf
from PIL import Image
from scipy.spatial import cKDTree

from experiments import store
from experiments.config import (
    frame_range_from_config,
    settings_from_config,
)
from experiments.paths import PROJECT_ROOT, default_cache_dir, default_data_root
from experiments.provenance import code_version, machine, package_versions
from experiments.reference_store import sequence_of, sequence_reference
from ttc import reasons
from ttc import visualize as vis
from ttc.atomic import write_bytes_atomic
from ttc.cache import StageCache
from ttc.camera_ttc import distance_ratios
from ttc.evaluation import metrics
from ttc.evaluation import reference as reference_module
from ttc.keypoints import X, Y
from ttc.lidar_ttc import LidarTTCParams
from ttc.lidar_ttc import rear_distance as lidar_rear_distance
from ttc.pipeline import FrameRange, PairDetail, Settings, pair_detail

AXES: tuple[str, ...] = metrics.AXES
#: Axes of a camera setting: everything but the lidar estimator.
CAMERA_AXES: tuple[str, ...] = tuple(a for a in AXES if a != "lidar_ttc")

# ---- FP.5 rules (metres) -----------------------------------------------------------------
#: Closest box point this far in front of the reference rear: points ahead of the bumper.
AHEAD_M = 0.10
#: The estimator's distance moved this far from its usual offset to the reference rear.
ANOMALY_M = 0.02
#: |Δd| per frame below this is within the lidar's range noise (HDL-64E: ≈ 2 cm per return).
NOISE_FLOOR_M = 0.03
#: The measured rear's step differs from the smoothed reference's by more than this while the
#: estimate follows the measured step within it: a step shared by every estimator.
SHARED_STEP_M = 0.015
#: A step of the estimate larger than this is not blamed on range noise.
MAX_NOISE_STEP_M = 0.5
#: A Euclidean cluster of at least this many box points, apart from the largest one (the
#: car's rear) by more than ``OTHER_GAP_M`` in x: points of another object in the box.
SECOND_CLUSTER_POINTS = 5
OTHER_GAP_M = 0.5
#: ... and they count when they move the estimator's distance by more than this (metres).
OTHER_EFFECT_M = 0.01
#: Relative change of the lead box's width or height between consecutive frames: box jump.
BOX_JUMP = 0.15

# ---- FP.6 rules ----------------------------------------------------------------------------
#: Camera TTC "way off": relative error above this (or invalid where the reference is finite).
WAY_OFF_REL = 0.5
#: Fewer kept matches than this in the box: few matches.
FEW_MATCHES = 20
#: Share of the box's matches removed by FP.3 above this: many outliers.
REMOVED_SHARE = 0.4
#: |r − 1| below this: a scale change too small to measure (TTC > dt / 0.002 = 50 s at 10 Hz).
RATIO_HAIR = 0.002
#: Share of pair ratios exactly 1 above this: integer keypoint positions freeze the ratio.
EXACT_SHARE = 0.3
#: A kept match moving this many pixels off the box's motion (median displacement): leaving.
#: The lead car moves ≈ 1 px per frame in the image, keypoints are located to ≈ 1 px.
LEAVE_PX = 2.0
LEAVE_SHARE = 0.2
#: Kept current keypoints within this fraction of the box size of its edge: on the border.
BORDER_FRAC = 0.1
BORDER_SHARE = 0.45
#: A keypoint whose nearest projected lidar point (within ``LIDAR_PX`` pixels) is this far
#: behind the lead car's rear sits on the background.
BACKGROUND_M = 1.0
LIDAR_PX = 4.0
BACKGROUND_SHARE = 0.2

# ---- output bounds -------------------------------------------------------------------------
#: One top view per flagged frame, up to this many (the most flagged estimators first).
MAX_LIDAR_PICTURES = 50
MAX_CAMERA_PICTURES = 10
#: Way-off camera cases whose intermediate arrays are examined (≈ 30 ms each).
MAX_EXAMINED = 60
#: Examined cases per detector × descriptor pair at most (pictured: one).
PER_PAIR = 2
MAX_PICTURE_WIDTH = 640
#: Largest PNG (bytes): pictures are downscaled until they fit.
MAX_PICTURE_BYTES = 120_000
#: Largest FP.5 top view (bytes): there is one per flagged frame.
LIDAR_PICTURE_BYTES = 60_000
#: Colours of an FP.5 top view's palette PNG (lines and dots on white: 4x smaller than RGB).
TOP_VIEW_COLOURS = 32
#: Depth (m) shown by an FP.5 top view, from just in front of the nearest point.
TOP_VIEW_SPAN_M = 1.5
FIGURE_DPI = 90
FLOAT_FORMAT = "%.6g"
N_BOOT = 500


# =========================================================================== loading


@dataclass
class SweepData:
    """Rows and run records of one or more sweeps (run ids unique across them)."""

    dirs: list[Path]
    frames: pd.DataFrame
    runs: pd.DataFrame
    overrides: dict[str, list[str]] = field(default_factory=dict)
    repeated: int = 0  # runs of a later sweep already present in an earlier one (dropped)


def read_sweep(sweep_dir: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``frames.parquet`` and ``runs.parquet`` of a sweep (merged first when missing)."""
    sweep_dir = Path(sweep_dir)
    frames_path, runs_path = sweep_dir / store.FRAMES_FILE, sweep_dir / store.RUNS_FILE
    if not (frames_path.is_file() and runs_path.is_file()):
        if not (sweep_dir / store.RUNS_DIR).is_dir():
            raise FileNotFoundError(f"{sweep_dir} is not a sweep folder (no {store.RUNS_DIR}/)")
        return store.collect(sweep_dir)
    return pd.read_parquet(frames_path), pd.read_parquet(runs_path)


def sweep_overrides(sweep_dir: Path) -> list[str]:
    """The command-line overrides of a sweep (Hydra's ``multirun.yaml``), or []."""
    path = Path(sweep_dir) / "multirun.yaml"
    if not path.is_file():
        return []
    doc = yaml.safe_load(path.read_text()) or {}
    hydra = doc.get("hydra", {})
    task = list(hydra.get("overrides", {}).get("task", []) or [])
    params = hydra.get("sweeper", {}).get("params", {}) or {}
    return task + [f"{k}={v} (sweep)" for k, v in params.items()]


def load_sweeps(dirs: Iterable[Path | str]) -> SweepData:
    """Concatenate sweeps; a run id present in several sweeps is taken from the first. The
    frames get ``ms_compute_per_frame`` looked up over all of them
    (:func:`ttc.evaluation.metrics.with_compute_times`)."""
    dirs = [Path(d) for d in dirs]
    frame_parts, run_parts, overrides = [], [], {}
    seen: set[str] = set()
    repeated = 0
    for d in dirs:
        frames, runs = read_sweep(d)
        if runs.empty:
            continue
        known = runs["run_id"].isin(seen)
        repeated += int(known.sum())
        runs = runs[~known].assign(sweep_dir=str(d.resolve()))
        if not frames.empty:
            frame_parts.append(frames[frames["run_id"].isin(runs["run_id"])])
        run_parts.append(runs)
        seen |= set(runs["run_id"])
        overrides[d.name] = sweep_overrides(d)
    frames = pd.concat(frame_parts, ignore_index=True) if frame_parts else pd.DataFrame()
    runs = pd.concat(run_parts, ignore_index=True) if run_parts else pd.DataFrame()
    if not frames.empty:  # a stage one sweep computed gives its time to runs of the others
        frames = metrics.with_compute_times(frames)
    return SweepData(dirs, frames, runs, overrides, repeated)


# =========================================================================== environment


def run_config(config_json: str, root: Path) -> DictConfig:
    """A run's stored setting config (runs.parquet ``config``) with the data root put back."""
    cfg = OmegaConf.create(json.loads(config_json))
    cfg.dataset.root = str(root)
    return cfg


def setting_of_run(runs: pd.DataFrame, run_id: str, root: Path) -> tuple[Settings, FrameRange]:
    """The core :class:`Settings` and :class:`FrameRange` of a run of ``runs``."""
    config = runs.loc[runs["run_id"] == run_id, "config"].iloc[0]
    cfg = run_config(config, root)
    return settings_from_config(cfg), frame_range_from_config(cfg)


@dataclass
class Context:
    """What the report needs besides the sweep tables: data root, stage cache, details."""

    root: Path
    cache: StageCache
    details: dict[tuple[str, int, int], PairDetail] = field(default_factory=dict)
    calls: int = 0

    def detail(self, runs: pd.DataFrame, run_id: str, prev: int, curr: int) -> PairDetail:
        """:func:`pair_detail` of a run's frame pair (memoised)."""
        key = (run_id, prev, curr)
        if key not in self.details:
            settings, frames = setting_of_run(runs, run_id, self.root)
            self.details[key] = pair_detail(settings, frames, prev, curr, self.cache)
            self.calls += 1
        return self.details[key]


def open_sweep(sweep_dir: Path | str) -> tuple[SweepData, Context, pd.DataFrame]:
    """A sweep folder (relative paths from the project root) as the notebooks use it: its
    data, the default context and its reference."""
    sweep_dir = Path(sweep_dir)
    sweep_dir = sweep_dir if sweep_dir.is_absolute() else PROJECT_ROOT / sweep_dir
    data = load_sweeps([sweep_dir])
    ctx = make_context()
    return data, ctx, reference_for(data, ctx)


def make_context(data_dir: Path | None = None, cache_dir: Path | None = None) -> Context:
    """A :class:`Context` with the given or default data root and cache folder."""
    root = Path(data_dir) if data_dir else default_data_root()
    cache = StageCache(cache_dir if cache_dir else default_cache_dir())
    return Context(root, cache)


# =========================================================================== reference


def reference_for(data: SweepData, ctx: Context) -> pd.DataFrame:
    """The reference of the sweeps' recording."""
    return sequence_reference(ctx.root / sequence_of(data.runs), ctx.cache)


# =========================================================================== metrics


def sweep_metrics(frames: pd.DataFrame, runs: pd.DataFrame, reference: pd.DataFrame):
    """One row per run of ``runs``: axes, status and :func:`ttc.evaluation.metrics.run_metrics`."""
    keep = ["run_id", "sweep_id", *[a for a in AXES if a in runs], "status", "message"]
    table = runs[keep].copy()
    if not frames.empty:
        table = table.merge(
            metrics.run_metrics(frames, reference).drop(columns=list(AXES), errors="ignore"),
            on="run_id",
            how="left",
        )
    return table.sort_values("run_id", ignore_index=True)


def write_sweep_metrics(data: SweepData, reference: pd.DataFrame) -> list[Path]:
    """``metrics.parquet`` beside each sweep (its own runs)."""
    written = []
    for d in data.dirs:
        runs = data.runs[data.runs["sweep_dir"] == str(d.resolve())]
        if runs.empty:
            continue
        frames = data.frames[data.frames["run_id"].isin(runs["run_id"])]
        path = d / "metrics.parquet"
        store.write_parquet_atomic(sweep_metrics(frames, runs, reference), path)
        written.append(path)
    return written


# =========================================================================== formatting


def _cell(value: Any) -> str:
    if isinstance(value, float | np.floating):
        if np.isnan(value):
            return ""
        if np.isinf(value):
            return "inf" if value > 0 else "-inf"
        return f"{value:.3g}" if abs(value) < 1000 else f"{value:.0f}"
    return str(value).replace("|", "\\|").replace("\n", " ")


def markdown_table(df: pd.DataFrame) -> str:
    """``df`` as a GitHub markdown table (floats with 3 significant digits)."""
    if df.empty:
        return "_(none)_"
    header = "| " + " | ".join(map(str, df.columns)) + " |"
    rule = "|" + "---|" * len(df.columns)
    cells = df.map(_cell).astype(str)
    body = (("| " + cells.agg(" | ".join, axis=1) + " |").tolist()) if len(df) else []
    return "\n".join([header, rule, *body])


def write_csv(df: pd.DataFrame, path: Path) -> Path:
    """Deterministic CSV: fixed float format, ``\\n`` line ends, no index."""
    path.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(path, index=False, float_format=FLOAT_FORMAT, lineterminator="\n")
    return path


def save_figure(fig: plt.Figure, path: Path) -> Path:
    """Save a matplotlib figure as a compact PNG and close it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=FIGURE_DPI, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)
    return path


def fit_width(image: np.ndarray, width: int = MAX_PICTURE_WIDTH) -> np.ndarray:
    """``image`` downscaled (area interpolation) to at most ``width`` pixels wide."""
    if image.shape[1] <= width:
        return image
    scale = width / image.shape[1]
    return cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)


def rgb_png(image: np.ndarray) -> bytes:
    """A BGR image encoded as an RGB PNG (OpenCV's default compression)."""
    ok, buffer = cv2.imencode(".png", image)
    if not ok:
        raise OSError("OpenCV could not encode the picture as PNG")
    return buffer.tobytes()


def palette_png(image: np.ndarray, colours: int = TOP_VIEW_COLOURS) -> bytes:
    """A BGR drawing encoded as a palette PNG of ``colours`` colours: plots and top views have
    few colours, so it stays sharp at a quarter of the bytes of an RGB PNG."""
    rgb = Image.fromarray(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
    buffer = io.BytesIO()
    rgb.quantize(colours, method=Image.Quantize.MEDIANCUT).save(buffer, "PNG", optimize=True)
    return buffer.getvalue()


def shrink_to_fit(
    image: np.ndarray, encode: Callable[[np.ndarray], bytes], max_bytes: int
) -> tuple[np.ndarray, bytes]:
    """``image`` downscaled in 15 % steps (not below 200 px wide) until ``encode`` of it fits
    ``max_bytes``; the image and its encoding."""
    data = encode(image)
    while len(data) > max_bytes and image.shape[1] > 200:
        image = cv2.resize(image, None, fx=0.85, fy=0.85, interpolation=cv2.INTER_AREA)
        data = encode(image)
    return image, data


def within_budget(image: np.ndarray, max_bytes: int = MAX_PICTURE_BYTES) -> np.ndarray:
    """``image`` downscaled in 15 % steps until its PNG encoding fits ``max_bytes``."""
    return shrink_to_fit(image, rgb_png, max_bytes)[0]


def save_picture(image: np.ndarray, path: Path) -> Path:
    """Write a picture (at most :data:`MAX_PICTURE_WIDTH` wide, within the byte budget)."""
    write_bytes_atomic(shrink_to_fit(fit_width(image), rgb_png, MAX_PICTURE_BYTES)[1], path)
    return path


def save_top_view(image: np.ndarray, path: Path, max_bytes: int = LIDAR_PICTURE_BYTES) -> Path:
    """Write a drawing as a palette PNG (atomically), downscaled until it fits ``max_bytes``."""
    write_bytes_atomic(shrink_to_fit(image, palette_png, max_bytes)[1], path)
    return path


def text_band(lines: list[str], width: int, scale: float = 0.45) -> np.ndarray:
    """A dark band (uint8 BGR) of ``width`` pixels holding ``lines`` of text."""
    band = np.full((10 + 20 * len(lines), width, 3), 20, dtype=np.uint8)
    vis.put_lines(band, lines, (6, 18), scale)
    return band


def _fmt(values: pd.Series, spec: str) -> pd.Series:
    """Element-wise ``format(v, spec)`` (for reason texts of a few flagged rows)."""
    return values.map(lambda v: format(v, spec)).astype(str)


def _cm(values: pd.Series) -> pd.Series:
    """Metres as ``"12.3 cm"`` (``"n/a"`` for NaN)."""
    text = _fmt(100.0 * values.astype(float), ".1f") + " cm"
    return text.where(values.notna(), "n/a")


def combine_reasons(parts: dict[str, pd.Series], index: pd.Index) -> pd.DataFrame:
    """``reasons`` (codes joined by ';') and ``reason_text`` from per-rule texts ('' = no).

    The rule named ``code`` contributes its text's prefix (a :mod:`ttc.reasons` code).
    """
    if not parts:
        return pd.DataFrame({"reasons": "", "reason_text": ""}, index=index)
    texts = pd.DataFrame(parts, index=index).fillna("").astype(str)
    fired = texts.ne("")
    names = {c: texts[c].str.split(":").str[0] if c == "code" else c for c in texts.columns}
    codes = functools.reduce(
        lambda a, b: a + b, [np.where(fired[c], names[c] + ";", "") for c in texts.columns]
    )
    text = functools.reduce(
        lambda a, b: a + b, [np.where(fired[c], texts[c] + ". ", "") for c in texts.columns]
    )
    out = pd.DataFrame({"reasons": codes, "reason_text": text}, index=index)
    out["reasons"] = out["reasons"].str.rstrip(";")
    out["reason_text"] = out["reason_text"].str.strip()
    return out


def with_reasons(
    t: pd.DataFrame,
    selected: str,
    rules: Callable[[pd.DataFrame], dict[str, pd.Series]],
    fallback_code: str,
    fallback: Callable[[pd.DataFrame], pd.Series],
) -> pd.DataFrame:
    """``t`` with ``reasons`` / ``reason_text`` on the rows where ``selected`` is true: the
    rules that fire, else ``fallback_code`` and its text; '' on the other rows."""
    t = t.copy()
    chosen = t[t[selected]]
    found = combine_reasons(rules(chosen), chosen.index)
    none = found["reasons"].eq("")
    found.loc[none, "reasons"] = fallback_code
    found.loc[none, "reason_text"] = fallback(chosen[none])
    t["reasons"], t["reason_text"] = "", ""
    t.loc[chosen.index, ["reasons", "reason_text"]] = found[["reasons", "reason_text"]]
    return t


def _code_texts(codes: pd.Series) -> pd.Series:
    """``"code: description"`` for non-ok reason codes, '' otherwise."""
    described = codes.map(lambda c: f"{c}: {reasons.DESCRIPTIONS.get(c, c)}")
    return described.where(~codes.isin(["", reasons.OK]), "")


# =========================================================================== provenance


def _unique(values: Iterable[Any]) -> str:
    return ", ".join(sorted({str(v) for v in values if v is not None and v == v})) or "n/a"


def _common_config(configs: pd.Series) -> tuple[dict[str, Any], list[str]]:
    """Keys (dotted) equal in every run's config, and the keys that vary."""
    flat = pd.json_normalize([json.loads(c) for c in configs]).astype(str)
    constant = flat.nunique(dropna=False) == 1
    common = {k: json.loads(json.dumps(flat[k].iloc[0])) for k in flat.columns[constant]}
    return common, sorted(flat.columns[~constant])


def provenance_markdown(data: SweepData, title: str) -> str:
    """The provenance header every report starts with."""
    runs = data.runs
    counts = runs.groupby("sweep_id")["status"].value_counts().unstack(fill_value=0)
    sweeps = "; ".join(
        f"`{s}` ({', '.join(f'{n} {k}' for k, n in row.items() if n)})"
        for s, row in counts.iterrows()
    )
    commits = runs.groupby(["git_commit", "git_dirty"], dropna=False).size()
    code = "; ".join(f"`{c}` dirty={d} ({n} runs)" for (c, d), n in commits.items())
    now = code_version()
    versions = [c for c in runs.columns if c.startswith("version_")]
    pkgs = ", ".join(f"{c.removeprefix('version_')} {_unique(runs[c])}" for c in versions)
    here = machine()
    common, varying = _common_config(runs["config"])
    groups = pd.Series(varying, dtype=str).str.split(".").str[0].value_counts().sort_index()
    varying_text = ", ".join(f"{g}.* ({n})" for g, n in groups.items()) or "none"
    if data.repeated:
        sweeps += f" ({data.repeated} runs also in an earlier sweep counted there)"
    axes = "; ".join(f"{a}: {_unique(runs[a])}" for a in AXES if a in runs)
    overrides = "; ".join(
        f"`{s}`: {' '.join(o) or '(defaults)'}" for s, o in data.overrides.items()
    )
    lines = [
        f"# {title}",
        "",
        "| provenance | |",
        "|---|---|",
        f"| sweeps | {sweeps} |",
        f"| sweep folders | {', '.join(f'`{d}`' for d in data.dirs)} |",
        f"| code version (runs) | {code} |",
        f"| code version (report) | `{now['git_commit']}` dirty={now['git_dirty']} |",
        f"| sweep command-line | {overrides} |",
        f"| axes | {axes} |",
        f"| config keys that vary | {varying_text} |",
        f"| runs from / to | {_unique([runs['start'].min()])} / {_unique([runs['end'].max()])} |",
        f"| report date | {dt.datetime.now(dt.UTC).isoformat(timespec='seconds')} |",
        f"| machine (runs) | {_unique(runs['host'])}, {_unique(runs['platform'])}, "
        f"{_unique(runs['cpu_count'])} cores |",
        f"| machine (report) | {here['host']}, {here['platform']}, {here['cpu_count']} cores |",
        f"| package versions (runs) | {pkgs} |",
        f"| package versions (report) | "
        f"{', '.join(f'{k} {v}' for k, v in package_versions().items())} |",
        "",
        "<details><summary>config shared by every run</summary>",
        "",
        "```json",
        json.dumps(common, indent=1, sort_keys=True),
        "```",
        "</details>",
        "",
    ]
    return "\n".join(lines)


# =========================================================================== run selection


def setting_labels(table: pd.DataFrame, axes: Iterable[str]) -> pd.Series:
    """A short label per row: the values of the ``axes`` that vary in ``table``, '/'-joined
    (detector/descriptor/matcher/selector when none varies)."""
    axes = [a for a in axes if a in table]
    varying = [a for a in axes if table[a].nunique() > 1]
    shown = varying or [a for a in ("detector", "descriptor", "matcher", "selector") if a in axes]
    return functools.reduce(lambda a, b: a + "/" + b, [table[a].astype(str) for a in shown])


def _key(table: pd.DataFrame, axes: Iterable[str]) -> pd.Series:
    return functools.reduce(lambda a, b: a + "|" + b, [table[a].astype(str) for a in axes])


def lidar_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """One ok run per (dataset, lidar estimator): all on the camera setting shared by the most
    estimators (ties: the alphabetically first), else the estimator's first run id."""
    ok = runs[runs["status"] == "ok"].sort_values("run_id").copy()
    ok["camera_key"] = _key(ok, CAMERA_AXES)
    spread = ok.groupby(["dataset", "camera_key"])["lidar_ttc"].nunique().reset_index()
    spread = spread.sort_values(["dataset", "lidar_ttc", "camera_key"], ascending=[1, 0, 1])
    best = spread.drop_duplicates("dataset").set_index("dataset")["camera_key"]
    ok["preferred"] = ok["camera_key"].eq(ok["dataset"].map(best))
    ok = ok.sort_values(["dataset", "lidar_ttc", "preferred", "run_id"], ascending=[1, 1, 0, 1])
    return ok.drop_duplicates(["dataset", "lidar_ttc"])[["dataset", "lidar_ttc", "run_id"]]


def camera_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """One ok run per camera setting (its first run id): run_id, the camera axes, setting."""
    ok = runs[runs["status"] == "ok"].sort_values("run_id")
    chosen = ok.drop_duplicates(list(CAMERA_AXES))[["run_id", *CAMERA_AXES]].copy()
    chosen["setting"] = setting_labels(chosen, [a for a in CAMERA_AXES if a != "dataset"])
    return chosen.reset_index(drop=True)


def judged_rows(frames: pd.DataFrame, reference: pd.DataFrame, run_ids) -> pd.DataFrame:
    """Lead rows of the given runs with the reference and per-frame errors."""
    subset = frames[frames["run_id"].isin(set(run_ids))]
    return metrics.frame_errors(metrics.attach_reference(subset, reference))


# =========================================================================== FP.5


def _with_reference_distances(table: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """Reference rear distance (raw, m; NaN where interpolated) and smoothed distance of the
    previous and current frame, the reference's and the estimator's Δd (m)."""
    ref = reference.set_index("frame")
    raw = ref["distance_m"].where(~ref["distance_interpolated"].astype(bool))
    out = table.copy()
    out["ref_d_prev"] = out["prev_frame"].map(raw)
    out["ref_d_curr"] = out["frame"].map(raw)
    out["ref_step"] = out["prev_frame"].map(ref["distance_smooth_m"]) - out["frame"].map(
        ref["distance_smooth_m"]
    )
    out["raw_step"] = out["ref_d_prev"] - out["ref_d_curr"]
    out["est_step"] = out["d_prev"] - out["d_curr"]
    return out


def _with_history(table: pd.DataFrame) -> pd.DataFrame:
    """The lead box of each run's previous frame pair (id, width, height; −1/NaN if none) and
    each estimator's offset to the reference rear, less its usual (median) offset (m)."""
    out = table.sort_values(["run_id", "frame"]).copy()
    before = out.groupby("run_id")[["frame", "curr_box", "box_w", "box_h"]].shift(1)
    follows = before["frame"].eq(out["prev_frame"])
    out["lead_before"] = before["curr_box"].where(follows, -1).astype(int)
    out["w_before"] = before["box_w"].where(follows & before["curr_box"].ge(0))
    out["h_before"] = before["box_h"].where(follows & before["curr_box"].ge(0))
    off_prev = out["d_prev"] - out["ref_d_prev"]
    off_curr = out["d_curr"] - out["ref_d_curr"]
    usual = off_curr.groupby(out["run_id"]).transform("median")
    out["anomaly_prev"] = off_prev - usual
    out["anomaly_curr"] = off_curr - usual
    out["scan_usual"] = out.groupby("run_id")["scan_points_curr"].transform("median")
    return out


def lidar_frame_table(
    frames: pd.DataFrame, runs: pd.DataFrame, reference: pd.DataFrame
) -> pd.DataFrame:
    """One row per (dataset, frame, lidar estimator) of :func:`lidar_runs` with the reference,
    errors, derived quantities and ``flagged`` (outlier, false alarm or truncated scan)."""
    chosen = lidar_runs(runs)
    if chosen.empty:
        return pd.DataFrame()
    table = judged_rows(frames, reference, chosen["run_id"])
    table = _with_history(_with_reference_distances(table, reference))
    table["flagged"] = (
        table["lidar_outlier"].eq(1) | table["lidar_false_alarm"].eq(1) | table["scan_short"]
    )
    n_settings = runs[runs["status"] == "ok"].groupby(["dataset", "lidar_ttc"]).size()
    table["camera_settings"] = pd.MultiIndex.from_frame(table[["dataset", "lidar_ttc"]]).map(
        n_settings
    )
    return table.sort_values(["dataset", "frame", "lidar_ttc"], ignore_index=True)


def _ahead_text(t: pd.DataFrame, which: str, effect: str) -> pd.Series:
    closest, ref = t[f"lidar_closest_{which}"], t[f"ref_d_{which}"]
    fires = (closest < ref - AHEAD_M) & (t[f"anomaly_{which}"] < -ANOMALY_M)
    frame = t["frame"] if which == "curr" else t["prev_frame"]
    text = (
        "points ahead of the bumper in frame " + frame.astype(str) + ": closest point "
        + _fmt(closest, ".2f") + " m, " + _cm(ref - closest) + " in front of the rear at "
        + _fmt(ref, ".2f") + " m, and the chosen distance " + _fmt(t[f"d_{which}"], ".2f")
        + " m followed them (" + effect + ")"
    )  # fmt: skip
    return text.where(fires, "")


def lidar_rules(t: pd.DataFrame) -> dict[str, pd.Series]:
    """Reason texts per rule for FP.5 rows ('' where the rule does not fire)."""
    short = (
        "truncated scan: frame " + t["frame"].astype(str) + " has "
        + t["scan_points_curr"].astype(str) + " points, "
        + _fmt(100 * t["scan_points_curr"] / t["scan_usual"], ".0f")
        + " % of the usual scan; the box holds " + t["lidar_points_curr"].astype(str)
        + " points (median x " + _fmt(t["lidar_median_curr"], ".2f") + " m)"
    ).where(t["scan_short"], "")  # fmt: skip
    ahead_curr = _ahead_text(t, "curr", "distance too short: TTC too small")
    ahead_prev = _ahead_text(t, "prev", "previous distance too short: TTC too large or receding")
    ahead = ahead_curr + np.where(ahead_curr.ne("") & ahead_prev.ne(""), "; ", "") + ahead_prev
    floor = f"{100 * NOISE_FLOOR_M:.0f} cm"
    est_small = t["est_step"].abs() < NOISE_FLOOR_M
    true_small = ~est_small & (t["ref_step"].abs() < NOISE_FLOOR_M)
    true_small &= t["est_step"].abs() < MAX_NOISE_STEP_M
    noise_est = (
        "distance change below the noise floor: the estimate moved only " + _cm(t["est_step"])
        + " (measured rear " + _cm(t["raw_step"]) + ", smoothed reference "
        + _cm(t["ref_step"]) + "), under the lidar's ~" + floor + " range noise, so TTC = "
        + "d dt / delta-d is huge or unstable"
    ).where(est_small, "")  # fmt: skip
    noise_true = (
        "the cars close by only " + _cm(t["ref_step"]) + " per frame (smoothed reference; "
        + "measured rear " + _cm(t["raw_step"]) + "), below the ~" + floor + " noise floor: "
        + "the estimate's " + _cm(t["est_step"]) + " step is noise or a change in the sampled "
        + "points, and any such step gives a finite TTC"
    ).where(true_small & t["est_step"].notna(), "")  # fmt: skip
    noise = noise_est + noise_true
    switch = t["lead_before"].ge(0) & t["prev_box"].ge(0) & t["prev_box"].ne(t["lead_before"])
    switched = (
        "box switch: FP.1 paired lead box #" + t["curr_box"].astype(str) + " with box #"
        + t["prev_box"].astype(str) + " of frame " + t["prev_frame"].astype(str)
        + ", whose lead box was #" + t["lead_before"].astype(str)
    ).where(switch, "")  # fmt: skip
    jump = (t["box_w"] / t["w_before"] - 1).abs().gt(BOX_JUMP) | (
        t["box_h"] / t["h_before"] - 1
    ).abs().gt(BOX_JUMP)
    jumped = (
        "box size jump: " + _fmt(t["w_before"], ".0f") + "x" + _fmt(t["h_before"], ".0f")
        + " -> " + t["box_w"].astype(str) + "x" + t["box_h"].astype(str)
        + " px, the box takes in other points"
    ).where(jump, "")  # fmt: skip
    other = t.get("other_object_text", pd.Series("", index=t.index))
    shared = (t["raw_step"] - t["ref_step"]).abs().gt(SHARED_STEP_M) & (
        t["est_step"] - t["raw_step"]
    ).abs().lt(SHARED_STEP_M)
    measured = (
        "the measured rear itself moved " + _cm(t["raw_step"]) + " where the smoothed "
        + "reference moves " + _cm(t["ref_step"]) + ", and the estimate followed it ("
        + _cm(t["est_step"]) + "): a one-frame step every rear estimate shares (a speed "
        + "change within 0.1 s or noise of the whole rear surface), which the 0.9 s smoothing "
        + "of the reference does not follow"
    ).where(shared, "")  # fmt: skip
    return {
        "scan_short": short,
        "code": _code_texts(t["lidar_reason"].astype(str)),
        "points_ahead": ahead,
        "noise_floor": noise,
        "other_object": other,
        "measured_step": measured,
        "box_switch": switched,
        "box_jump": jumped,
    }


def lidar_fallback(t: pd.DataFrame) -> pd.Series:
    """The reason of a flagged row no rule explains: the distances' deviation (range noise)."""
    return (
        "range noise: the estimate moved " + _cm(t["est_step"]) + ", the measured rear "
        + _cm(t["raw_step"]) + ", the smoothed reference " + _cm(t["ref_step"])
        + "; the estimate's distances are "
        + _cm(t["anomaly_prev"]) + " (frame " + t["prev_frame"].astype(str) + ") and "
        + _cm(t["anomaly_curr"]) + " (frame " + t["frame"].astype(str)
        + ") off their usual offset to the rear"
    )  # fmt: skip


def box_points(detail: PairDetail, frame: int, box: int) -> np.ndarray:
    """Lane lidar points (N × 4, metres) of ``box`` in ``frame`` of a pair detail."""
    if box < 0:
        return detail.lane_points[frame][:0]
    return detail.lane_points[frame][detail.lane_owner[frame] == box]


def other_clusters(points: np.ndarray) -> tuple[np.ndarray, str]:
    """Points (mask over N × ≥3 box points, metres) of clusters of ≥ SECOND_CLUSTER_POINTS
    points more than OTHER_GAP_M in x off the largest cluster (the car's rear), and a
    description of them ('' when none)."""
    none = np.zeros(len(points), dtype=bool)
    if len(points) < 2 * SECOND_CLUSTER_POINTS:
        return none, ""
    labels = reference_module.euclidean_clusters(points[:, :3].astype(np.float64))
    x = pd.Series(points[:, 0]).groupby(labels).agg(["size", "min", "max"])
    main = x.loc[x["size"].idxmax()]
    apart = (x["max"] < main["min"] - OTHER_GAP_M) | (x["min"] > main["max"] + OTHER_GAP_M)
    other = x[apart & (x["size"] >= SECOND_CLUSTER_POINTS)]
    if other.empty:
        return none, ""
    found = ", ".join(f"{r.size} at {r.min:.2f}-{r.max:.2f} m" for r in other.itertuples())
    text = f"{found} beside the rear cluster at {main['min']:.2f}-{main['max']:.2f} m"
    return np.isin(labels, other.index.to_numpy()), text


def other_object_effect(points: np.ndarray, params: LidarTTCParams) -> tuple[float, str]:
    """How far (m) the other clusters of a box move the estimator's distance (with − without
    them), and their description; (0, '') when there are none."""
    other, text = other_clusters(points)
    if not other.any():
        return 0.0, ""
    with_them = lidar_rear_distance(points, params).distance
    without = lidar_rear_distance(points[~other], params).distance
    return float(with_them - without), text


def other_object_texts(t: pd.DataFrame, runs: pd.DataFrame, ctx: Context) -> pd.Series:
    """'points of another object' for flagged rows where another cluster in the previous or
    current box moves the estimator's distance by more than OTHER_EFFECT_M (with − without)."""
    texts = pd.Series("", index=t.index, dtype=object)
    flagged = t[t["flagged"] & t["prev_box"].ge(0)]
    for (_, frame), rows in flagged.groupby(["dataset", "frame"], sort=True):
        first = rows.iloc[0]
        detail = ctx.detail(runs, first["run_id"], int(first["prev_frame"]), int(frame))
        clouds = {detail.prev: box_points(detail, detail.prev, int(first["prev_box"])),
                  detail.curr: box_points(detail, detail.curr, detail.lead_box)}  # fmt: skip
        for idx, row in rows.iterrows():
            params = setting_of_run(runs, row["run_id"], ctx.root)[0].lidar_ttc
            found = []
            for f, points in clouds.items():
                shift, text = other_object_effect(points, params)
                if abs(shift) > OTHER_EFFECT_M:
                    found.append(f"frame {f}: {text} move the distance by {100 * shift:+.1f} cm")
            if found:
                texts[idx] = "points of another object in the box (" + "; ".join(found) + ")"
    return texts


def lidar_reasons(t: pd.DataFrame, runs: pd.DataFrame, ctx: Context | None) -> pd.DataFrame:
    """``t`` with ``reasons`` / ``reason_text`` on its flagged rows ('' elsewhere)."""
    t = t.copy()
    if ctx is not None:
        t["other_object_text"] = other_object_texts(t, runs, ctx)
    t = with_reasons(t, "flagged", lidar_rules, "range_noise", lidar_fallback)
    return t.drop(columns=["other_object_text"], errors="ignore")


FP5_COLUMNS = [
    "dataset", "frame", "prev_frame", "lidar_ttc", "ttc_lidar", "lidar_reason", "ttc_ref_s",
    "lidar_rel_err", "flagged", "reasons", "d_prev", "d_curr", "ref_d_prev", "ref_d_curr",
    "est_step", "raw_step", "ref_step", "lidar_points_prev", "lidar_points_curr", "lidar_closest_prev",
    "lidar_closest_curr", "lidar_median_prev", "lidar_median_curr", "scan_points_curr",
    "scan_short", "prev_box", "curr_box", "box_w", "box_h", "run_id", "reason_text",
]  # fmt: skip


def _panel_titles(rows: pd.DataFrame, f: int, curr: int) -> list[str]:
    """Text lines above one top view: frame, and for the current frame the flagged TTCs."""
    if f != curr:
        n = int(rows["flagged"].sum())
        return [f"frame {f} (previous)", *[""] * (1 + (n + 1) // 2)]
    row = rows.iloc[0]
    flagged = rows[rows["flagged"]]
    ttcs = [f"{r.lidar_ttc} {r.ttc_lidar:.1f} s" for r in flagged.itertuples()]
    lines = [", ".join(ttcs[i : i + 2]) for i in range(0, len(ttcs), 2)]
    return [f"frame {f} (current), reference TTC {row['ttc_ref_s']:.1f} s", "flagged:", *lines]


def lidar_picture(
    t: pd.DataFrame, runs: pd.DataFrame, ctx: Context, dataset: str, frame: int, reference
) -> np.ndarray:
    """Top views of the lead box's points in the previous and current frame, each with the
    distance every estimator picks and the reference rear."""
    rows = t[(t["dataset"] == dataset) & (t["frame"] == frame)]
    row = rows.iloc[0]
    detail = ctx.detail(runs, row["run_id"], int(row["prev_frame"]), frame)
    settings, _ = setting_of_run(runs, row["run_id"], ctx.root)
    ref = reference.set_index("frame")["distance_m"]
    clouds = {
        detail.prev: box_points(detail, detail.prev, int(row["prev_box"])),
        detail.curr: box_points(detail, detail.curr, detail.lead_box),
    }
    both = np.vstack([c[:, :2] for c in clouds.values()])
    xs = np.append(both[:, 0], ref.reindex([frame]).to_numpy())
    lo = np.floor((np.nanmin(xs) - 0.25) * 10) / 10
    y_hi = float(both[:, 1].max(initial=1.0)) + 0.1
    y_lo = float(both[:, 1].min(initial=-1.0)) - 0.1
    world = ((lo, lo + TOP_VIEW_SPAN_M), (y_lo - (y_hi - y_lo), y_hi))  # labels on the right
    panels = []
    for f, points in clouds.items():
        marks = vis.estimator_marks(points, settings.lidar_ttc) if len(points) else {}
        marks["reference rear"] = float(ref.get(f, np.nan))
        view = vis.top_view(
            [(f"frame {f} box", points)], marks, world, (400, 520), grid=0.5, lateral_grid=1.0
        )
        panels.append(np.vstack([text_band(_panel_titles(rows, f, detail.curr), 400), view]))
    seam = np.full((panels[0].shape[0], 4, 3), 255, np.uint8)
    return np.hstack([panels[0], seam, panels[1]])


def lidar_picture_frames(t: pd.DataFrame, limit: int = MAX_LIDAR_PICTURES) -> pd.DataFrame:
    """The flagged (dataset, frame)s to picture: most estimators flagged, then the largest
    error, then frame order; at most ``limit``."""
    flagged = t[t["flagged"]].assign(err=t["lidar_rel_err"].fillna(np.inf))
    per = flagged.groupby(["dataset", "frame"]).agg(n=("lidar_ttc", "size"), err=("err", "max"))
    per = per.reset_index().sort_values(["n", "err", "dataset", "frame"], ascending=[0, 0, 1, 1])
    return per.head(limit)


def plot_lidar_series(t: pd.DataFrame, reference: pd.DataFrame) -> plt.Figure:
    """Lidar TTC per frame and estimator against the reference; flagged frames crossed,
    invalid TTCs (NaN / inf) as triangles on the top edge, values above it clipped."""
    fig, ax = plt.subplots(figsize=(10, 4.2))
    ref = reference[reference["frame"].isin(t["frame"].unique())]
    finite_ref = ref["ttc_ref_s"].where(np.isfinite(ref["ttc_ref_s"]))
    top = 2.5 * float(finite_ref.max()) if finite_ref.notna().any() else 60.0
    valid = np.isfinite(t["ttc_lidar"])
    shown = t.assign(ttc=t["ttc_lidar"].where(valid).clip(upper=top))
    order = sorted(t["lidar_ttc"].unique())
    sns.lineplot(data=shown[valid], x="frame", y="ttc", hue="lidar_ttc", hue_order=order,
                 style="dataset", marker="o", markersize=4, ax=ax)  # fmt: skip
    bad = shown[~valid]
    sns.scatterplot(x=bad["frame"], y=np.full(len(bad), 0.98 * top), hue=bad["lidar_ttc"],
                    hue_order=order, marker="v", s=50, legend=False, ax=ax)  # fmt: skip
    flagged = shown[shown["flagged"]]
    ax.scatter(flagged["frame"], flagged["ttc"].fillna(0.98 * top), marker="x", s=60,
               color="crimson", label="flagged", zorder=5)  # fmt: skip
    ax.plot(ref["frame"], ref["ttc_ref_s"], color="black", lw=2.5, label="reference")
    ax.set(ylim=(0, top), xlabel="frame", ylabel="TTC (s, clipped)",
           title="FP.5 lidar TTC (triangles on top: invalid TTC)")  # fmt: skip
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    return fig


def lidar_wide(t: pd.DataFrame) -> pd.DataFrame:
    """Frame × estimator table of TTCs (s) beside the reference; flagged values marked '!'."""
    text = _fmt(t["ttc_lidar"], ".2f") + np.where(t["flagged"], " !", "")
    wide = t.assign(v=text).pivot_table(
        index=["dataset", "frame"], columns="lidar_ttc", values="v", aggfunc="first"
    )
    ref = t.groupby(["dataset", "frame"])["ttc_ref_s"].first().map(lambda v: f"{v:.2f}")
    wide.insert(0, "reference", ref)
    return wide.reset_index()


def lidar_metrics(frames: pd.DataFrame, t: pd.DataFrame, reference: pd.DataFrame):
    """Per (dataset, estimator): lidar metrics of the chosen run and its flagged frames."""
    ids = t["run_id"].unique()
    m = metrics.run_metrics(frames[frames["run_id"].isin(ids)], reference)
    cols = ["dataset", "lidar_ttc", "lidar_outlier_rate", "lidar_medae_rel", "lidar_meanae_rel",
            "lidar_false_alarm_rate", "lidar_jitter_s", "lidar_invalid", "n_frames"]  # fmt: skip
    flags = t.groupby("run_id")["flagged"].sum().rename("flagged")
    out = m.merge(flags, on="run_id")[[*cols, "flagged"]]
    return out.sort_values(["dataset", "lidar_ttc"], ignore_index=True)


def fp5_table(data: SweepData, reference: pd.DataFrame, ctx: Context | None) -> pd.DataFrame:
    """The FP.5 table (:func:`lidar_frame_table`) with flags and reasons; empty without an
    ok run. ``ctx`` None skips the reasons that need pair details (other objects)."""
    t = lidar_frame_table(data.frames, data.runs, reference)
    return t if t.empty else lidar_reasons(t, data.runs, ctx)


def fp5_report(
    data: SweepData, reference: pd.DataFrame, ctx: Context, out: Path, pictures: bool = True
) -> pd.DataFrame | None:
    """Write ``fp5_lidar.md``, ``fp5_lidar_ttc.csv/.png`` and the flagged frames' top views;
    return the FP.5 table (None when the sweeps hold no ok run)."""
    t = fp5_table(data, reference, ctx)
    if t.empty:
        return None
    write_csv(t[FP5_COLUMNS], out / "fp5_lidar_ttc.csv")
    save_figure(plot_lidar_series(t, reference), out / "fp5_lidar_ttc.png")
    shutil.rmtree(out / "fp5_pictures", ignore_errors=True)
    drawn = []
    if pictures:
        for r in lidar_picture_frames(t).itertuples():
            path = out / "fp5_pictures" / f"{r.dataset}_frame_{r.frame:04d}.png"
            image = lidar_picture(t, data.runs, ctx, r.dataset, r.frame, reference)
            drawn.append(save_top_view(image, path))
    (out / "fp5_lidar.md").write_text(fp5_markdown(data, t, reference, drawn, out))
    return t


def fp5_markdown(data, t: pd.DataFrame, reference, pictures: list[Path], out: Path) -> str:
    """The FP.5 markdown: per-frame table, estimator summary, flagged frames and pictures."""
    flagged = t[t["flagged"]].copy()
    flagged["ttc"] = _fmt(flagged["ttc_lidar"], ".2f")
    flagged["ref"] = _fmt(flagged["ttc_ref_s"], ".2f")
    listing = flagged[["dataset", "frame", "lidar_ttc", "ttc", "ref", "reasons", "reason_text"]]
    settings = t.groupby("lidar_ttc")["camera_settings"].first()
    parts = [
        provenance_markdown(data, "FP.5: implausible lidar TTC estimates"),
        "Lidar TTC of the lead vehicle per frame for every lidar estimator in the sweeps, "
        "beside the reference TTC ([reference.md](reference.md)). A frame is **flagged** when "
        f"the TTC is invalid or more than {metrics.OUTLIER_REL:.0%} off a finite reference, "
        f"a finite TTC under {metrics.FALSE_ALARM_S:.0f} s where the reference says no "
        "collision course, or the scan is truncated. Each flagged row gets the reasons the "
        "rules of `experiments/report.py` find in the data: points ahead of the bumper "
        f"(closest point > {100 * AHEAD_M:.0f} cm in front of the reference rear and the "
        f"estimate following it by > {100 * ANOMALY_M:.0f} cm), a distance change (of the "
        f"estimate, or of the smoothed reference) below the {100 * NOISE_FLOOR_M:.0f} cm "
        "noise floor, a truncated scan, points of another "
        f"object (clusters of >= {SECOND_CLUSTER_POINTS} points more than {OTHER_GAP_M} m "
        f"off the rear cluster that move the estimator's distance by > {100 * OTHER_EFFECT_M:.0f}"
        " cm), a box "
        f"switch or a box size jump > {BOX_JUMP:.0%}, a step of the measured rear itself (the "
        "estimate following a raw step the smoothed reference does not have); otherwise the "
        "estimate's deviation from its usual offset to the rear (range noise).",
        "",
        "Camera settings per estimator in the sweeps (the lidar TTC uses the first): "
        + ", ".join(f"{k}: {v}" for k, v in settings.items())
        + ".",
        "",
        "## Estimators",
        "",
        markdown_table(lidar_metrics(data.frames, t, reference)),
        "",
        "## TTC per frame (s), flagged values marked `!`",
        "",
        "![lidar TTC](fp5_lidar_ttc.png)",
        "",
        markdown_table(lidar_wide(t)),
        "",
        f"## Flagged frames ({len(flagged)} estimator x frame rows)",
        "",
        markdown_table(listing),
        "",
        "## Top views of flagged frames",
        "",
        "Lead box points from above (x forward), previous frame left, current right; lines: "
        "the distance each estimator picks and the reference rear.",
        "",
    ]
    parts += [f"![{p.stem}]({p.relative_to(out).as_posix()})" for p in pictures]
    return "\n".join(parts) + "\n"


# =========================================================================== FP.6


def camera_frame_table(
    frames: pd.DataFrame, runs: pd.DataFrame, reference: pd.DataFrame
) -> pd.DataFrame:
    """One row per (camera setting, frame) with the reference, errors and ``way_off``."""
    chosen = camera_runs(runs)
    if chosen.empty:
        return pd.DataFrame()
    table = judged_rows(frames, reference, chosen["run_id"])
    table = table.merge(chosen[["run_id", "setting"]], on="run_id")
    ref_finite = np.isfinite(table["ttc_ref_s"]) & (table["ttc_ref_s"] > 0)
    table["way_off"] = (
        table["camera_rel_err"].gt(WAY_OFF_REL)
        | (ref_finite & ~(np.isfinite(table["ttc_camera"]) & table["ttc_camera"].gt(0)))
        | table["camera_false_alarm"].eq(1)
    )
    table["ratio_expected"] = 1.0 + table["dt"] / table["ttc_ref_s"]
    return table.sort_values(["dataset", "setting", "frame"], ignore_index=True)


def camera_rules(t: pd.DataFrame) -> dict[str, pd.Series]:
    """Reason texts per rule for way-off FP.6 rows computed from the rows alone."""
    ok = t["camera_reason"].eq(reasons.OK)
    few = (
        "few matches: " + t["matches_kept"].astype(str) + " kept in the box ("
        + t["matches_in_box"].astype(str) + " in it, " + t["keypoints_curr"].astype(str)
        + " keypoints in the frame)"
    ).where(t["matches_kept"] < FEW_MATCHES, "")  # fmt: skip
    share = t["matches_removed"] / t["matches_in_box"].where(t["matches_in_box"] > 0)
    removed = (
        "many outliers: " + t["matches_removed"].astype(str) + " of "
        + t["matches_in_box"].astype(str) + " matches in the box (" + _fmt(100 * share, ".0f")
        + " %) removed by " + t["keypoint_filter"].astype(str)
    ).where(share > REMOVED_SHARE, "")  # fmt: skip
    hair = ok & (t["camera_ratio"] - 1).abs().lt(RATIO_HAIR)
    near = (
        "median ratio within a hair of 1: r = " + _fmt(t["camera_ratio"], ".5f")
        + " (scale change " + _fmt(100 * (t["camera_ratio"] - 1), ".2f")
        + " % where the reference implies " + _fmt(100 * (t["ratio_expected"] - 1), ".2f")
        + " %): a tenth of a pixel over a 100 px pair moves the TTC by seconds"
    ).where(hair, "")  # fmt: skip
    alarm = (
        "false alarm: " + _fmt(t["ttc_camera"], ".1f") + " s where the cars do not close"
    ).where(t["camera_false_alarm"].eq(1), "")
    return {
        "code": _code_texts(t["camera_reason"].astype(str)),
        "false_alarm": alarm,
        "few_matches": few,
        "many_removed": removed,
        "ratio_near_one": near,
    }


def camera_fallback(t: pd.DataFrame) -> pd.Series:
    """The reason of a way-off row no rule explains: its scale error in pixels."""
    err = t["camera_ratio"] - t["ratio_expected"]
    return (
        "scale error: r = " + _fmt(t["camera_ratio"], ".4f") + " against "
        + _fmt(t["ratio_expected"], ".4f") + " implied by the reference, an error of "
        + _fmt(100 * err, ".2f") + " % or " + _fmt((err * t["box_w"]).abs(), ".1f")
        + " px across the " + t["box_w"].astype(str) + " px box: keypoint position noise"
    )  # fmt: skip


@dataclass(frozen=True)
class MatchGeometry:
    """Measurements on the kept matches of a lead box (shares are 0–1)."""

    kept: int
    exact_share: float
    still: int
    leaving: int
    border: int
    with_depth: int
    background: int


def match_geometry(detail: PairDetail, min_dist: float, ref_distance: float) -> MatchGeometry:
    """Exact-1 ratio share, matches off the box's motion, on its border, on the background."""
    m, kept = detail.matches, np.asarray(detail.kept)
    prev = detail.keypoints[detail.prev][np.asarray(m.prev_idx)[kept]][:, [X, Y]]
    curr = detail.keypoints[detail.curr][np.asarray(m.curr_idx)[kept]][:, [X, Y]]
    if len(kept) == 0 or detail.lead_box < 0:
        return MatchGeometry(0, 0.0, 0, 0, 0, 0, 0)
    ratios = distance_ratios(prev, curr, min_dist)
    exact = float(np.mean(ratios == 1.0)) if len(ratios) else 0.0
    motion = curr - prev
    still = int(np.sum(np.all(motion == 0, axis=1)))
    leaving = int(np.sum(np.hypot(*(motion - np.median(motion, axis=0)).T) > LEAVE_PX))
    x, y, w, h = detail.objects[detail.curr]["roi"][detail.lead_box].astype(float)
    edge = np.minimum(np.minimum(curr[:, 0] - x, x + w - curr[:, 0]) / w,
                      np.minimum(curr[:, 1] - y, y + h - curr[:, 1]) / h)  # fmt: skip
    uv, depth = detail.lane_uv[detail.curr], detail.lane_points[detail.curr][:, 0]
    with_depth = background = 0
    finite = np.isfinite(uv).all(axis=1)
    if finite.any():
        dist, nearest = cKDTree(uv[finite]).query(curr, distance_upper_bound=LIDAR_PX)
        hit = np.isfinite(dist)
        far = depth[finite][nearest[hit]] > ref_distance + BACKGROUND_M
        with_depth, background = int(hit.sum()), int(far.sum())
    return MatchGeometry(len(kept), exact, still, leaving, int(np.sum(edge < BORDER_FRAC)),
                         with_depth, background)  # fmt: skip


def geometry_texts(g: MatchGeometry) -> dict[str, str]:
    """Reason texts the match geometry supports ('' where it does not)."""
    texts = dict.fromkeys(("exact_ratios", "leaving_object", "box_edge", "background"), "")
    if g.kept == 0:
        return texts
    if g.exact_share > EXACT_SHARE:
        texts["exact_ratios"] = (
            f"{100 * g.exact_share:.0f} % of the pair distance ratios are exactly 1 and "
            f"{g.still} of {g.kept} kept keypoints did not move at all (integer positions): "
            "the median ratio is pinned at or next to 1"
        )
    if g.leaving / g.kept > LEAVE_SHARE:
        texts["leaving_object"] = (
            f"matches leaving the object: {g.leaving} of {g.kept} kept matches move more than "
            f"{LEAVE_PX:.0f} px off the box's median motion (mismatches across object borders)"
        )
    if g.border / g.kept > BORDER_SHARE:
        texts["box_edge"] = (
            f"keypoints on the box edge: {g.border} of {g.kept} kept keypoints lie within "
            f"{BORDER_FRAC:.0%} of the box border (silhouette, background behind it)"
        )
    if g.with_depth >= 3 and g.background / g.with_depth > BACKGROUND_SHARE:
        texts["background"] = (
            f"keypoints on the background: {g.background} of {g.with_depth} kept keypoints "
            f"with a lidar point nearby are > {BACKGROUND_M:.0f} m behind the car's rear"
        )
    return texts


def worst_order(t: pd.DataFrame, per_pair: int = PER_PAIR, turns: str = "primary") -> pd.DataFrame:
    """Way-off rows, worst first (invalid first), at most ``per_pair`` per detector ×
    descriptor pair (matcher variants mostly repeat each other), round-robin over the values
    of ``turns`` (``primary``: the first reason code, or an axis such as ``detector``)."""
    w = t[t["way_off"]].copy()
    if w.empty:
        return w
    w["severity"] = w["camera_rel_err"].fillna(np.inf)
    w["primary"] = w["reasons"].str.split(";").str[0]
    w = w.sort_values(["severity", "setting", "frame"], ascending=[0, 1, 1])
    w = w[w.groupby(["dataset", "detector", "descriptor"]).cumcount() < per_pair]
    w["turn"] = w.groupby(turns).cumcount()
    return w.sort_values(["turn", "severity", "setting", "frame"], ascending=[1, 0, 1, 1])


def examine_worst(t: pd.DataFrame, runs, reference, ctx: Context, limit: int) -> pd.DataFrame:
    """Add the match-geometry reasons of the ``limit`` worst way-off rows (``examined``)."""
    t = t.copy()
    t["examined"] = False
    ref = reference.set_index("frame")["distance_smooth_m"]
    order = worst_order(t).head(limit)
    for idx, row in order.iterrows():
        detail = ctx.detail(runs, row["run_id"], int(row["prev_frame"]), int(row["frame"]))
        settings, _ = setting_of_run(runs, row["run_id"], ctx.root)
        geometry = match_geometry(detail, settings.camera_ttc.min_dist, float(ref[row["frame"]]))
        extra = {k: v for k, v in geometry_texts(geometry).items() if v}
        t.at[idx, "examined"] = True
        if extra:
            codes = [c for c in str(t.at[idx, "reasons"]).split(";") if c and c != "scale_error"]
            text = "" if "scale_error" in str(t.at[idx, "reasons"]) else t.at[idx, "reason_text"]
            t.at[idx, "reasons"] = ";".join(codes + list(extra))
            t.at[idx, "reason_text"] = " ".join([text, *(v + "." for v in extra.values())]).strip()
    return t


def camera_reasons(t: pd.DataFrame) -> pd.DataFrame:
    """``t`` with ``reasons`` / ``reason_text`` of the way-off rows from the rows alone."""
    return with_reasons(t, "way_off", camera_rules, "scale_error", camera_fallback)


def camera_ranking(frames: pd.DataFrame, t: pd.DataFrame, reference: pd.DataFrame):
    """Per dataset: metrics, rank and bootstrap rank interval of every camera setting."""
    parts = []
    for _, group in t.groupby("dataset", sort=True):
        ids = group["run_id"].unique()
        subset = frames[frames["run_id"].isin(ids)]
        ranked = metrics.rank_runs(metrics.run_metrics(subset, reference), "camera")
        ci = metrics.bootstrap_rank_intervals(subset, reference, n_boot=N_BOOT, seed=0)
        parts.append(ranked.merge(ci.drop(columns="rank"), on="run_id"))
    ranking = pd.concat(parts, ignore_index=True)
    labels = t.drop_duplicates("run_id").set_index("run_id")["setting"]
    ranking.insert(0, "setting", ranking["run_id"].map(labels))
    way = t.groupby("run_id")["way_off"].sum()
    ranking["way_off_frames"] = ranking["run_id"].map(way)
    return ranking.sort_values(["dataset", "rank"], ignore_index=True)


RANKING_COLUMNS = [
    "dataset", "rank", "rank_lo", "rank_hi", "rank_median", "setting", *CAMERA_AXES[:-1],
    "camera_outlier_rate", "camera_outlier_rate_lo", "camera_outlier_rate_hi",
    "camera_medae_rel", "camera_medae_rel_lo", "camera_medae_rel_hi", "camera_meanae_rel",
    "camera_false_alarm_rate", "camera_jitter_s", "camera_invalid", "way_off_frames",
    "n_frames", "ms_per_frame", "ms_compute_per_frame", "run_id",
]  # fmt: skip
#: Columns of ``fp6_camera_ttc.csv``. Two are left out because the file is the largest of a
#: report (10,780 rows for 0-77) and they follow from others: the run id (``fp6_ranking.csv``
#: has it per dataset and setting) and the ratio the reference implies, 1 + dt / ttc_ref_s
#: with dt = (frame - prev_frame) / 10 Hz.
FP6_COLUMNS = [
    "dataset", "setting", "frame", "prev_frame", "ttc_camera", "camera_reason", "ttc_ref_s",
    "camera_rel_err", "way_off", "reasons", "camera_ratio", "camera_pairs",
    "keypoints_curr", "matches_total", "matches_in_box", "matches_kept", "matches_removed",
    "box_w", "box_h", "detector", "descriptor", "examined", "reason_text",
]  # fmt: skip


def camera_picture(t_row: pd.Series, runs: pd.DataFrame, ctx: Context) -> np.ndarray:
    """The lead box's matches (previous above current) cropped around the box, with the
    setting, TTCs and reasons in a text band on top."""
    detail = ctx.detail(runs, t_row["run_id"], int(t_row["prev_frame"]), int(t_row["frame"]))
    image = vis.draw_keypoint_matches(detail, max_draw=150)
    h = detail.images[detail.prev].shape[0]
    rois = [detail.objects[detail.curr]["roi"][detail.lead_box]] if detail.lead_box >= 0 else []
    prev_box = int(t_row["prev_box"])
    if prev_box >= 0:
        rois.append(detail.objects[detail.prev]["roi"][prev_box])
    x0, x1 = (min(r[0] for r in rois), max(r[0] + r[2] for r in rois)) if rois else (0, 1)
    y0, y1 = (min(r[1] for r in rois), max(r[1] + r[3] for r in rois)) if rois else (0, h)
    width = image.shape[1]
    cx, half = (x0 + x1) // 2, max(280, (x1 - x0) // 2 + 80)
    left, right = max(0, cx - half), min(width, cx + half)
    top, bottom = max(0, y0 - 40), min(h, y1 + 20)
    crop = np.vstack([image[top:bottom, left:right], image[h + top : h + bottom, left:right]])
    lines = [
        f"{t_row['setting']}  frame {int(t_row['prev_frame'])} -> {int(t_row['frame'])}",
        f"TTC camera {vis.format_ttc(float(t_row['ttc_camera']), str(t_row['camera_reason']))}"
        f", reference {t_row['ttc_ref_s']:.2f} s, ratio {t_row['camera_ratio']:.4f}",
        f"{int(t_row['matches_kept'])} kept (green) / {int(t_row['matches_removed'])} removed"
        f" (red) of {int(t_row['matches_in_box'])} in the box; reasons: {t_row['reasons']}",
    ]
    return np.vstack([text_band(lines, crop.shape[1]), crop])


def plot_heatmap(ranking: pd.DataFrame) -> plt.Figure:
    """Detector × descriptor heatmaps of the best setting's outlier rate and median error."""
    best = ranking.sort_values("rank").drop_duplicates(["detector", "descriptor"])
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, (col, label) in zip(
        axes,
        (("camera_outlier_rate", "outlier rate"), ("camera_medae_rel", "median |rel. error|")),
        strict=True,
    ):
        grid = best.pivot(index="detector", columns="descriptor", values=col)
        sns.heatmap(grid, annot=True, fmt=".2f", cmap="rocket_r", vmin=0, ax=ax,
                    cbar_kws={"shrink": 0.8}, annot_kws={"size": 8})  # fmt: skip
        ax.set_title(f"{label} (best over the other axes)", fontsize=10)
    fig.suptitle("FP.6 camera TTC error by detector x descriptor (blank: invalid pair)")
    fig.tight_layout()
    return fig


def plot_top_bottom(t: pd.DataFrame, ranking: pd.DataFrame, reference, n: int = 3):
    """Camera TTC per frame of the ``n`` best and ``n`` worst settings against the reference;
    invalid TTCs as triangles on the top edge, values above it clipped."""
    ranked = ranking.sort_values("rank")["setting"].drop_duplicates().tolist()
    picked = ranked[:n] + [s for s in ranked[-n:] if s not in ranked[:n]]
    sub = t[t["setting"].isin(picked)].copy()
    sub["group"] = np.where(sub["setting"].isin(ranked[:n]), "best", "worst")
    ref = reference[reference["frame"].isin(t["frame"].unique())]
    finite_ref = ref["ttc_ref_s"].where(np.isfinite(ref["ttc_ref_s"]))
    top = 3.0 * float(finite_ref.max()) if finite_ref.notna().any() else 60.0
    valid = np.isfinite(sub["ttc_camera"])
    sub["ttc"] = sub["ttc_camera"].where(valid).clip(upper=top)
    fig, ax = plt.subplots(figsize=(10, 4.5))
    sns.lineplot(data=sub[valid], x="frame", y="ttc", hue="setting", hue_order=picked,
                 style="group", style_order=["best", "worst"], marker="o", markersize=4,
                 ax=ax)  # fmt: skip
    bad = sub[~valid]
    sns.scatterplot(x=bad["frame"], y=np.full(len(bad), 0.98 * top), hue=bad["setting"],
                    hue_order=picked, marker="v", s=50, legend=False, ax=ax)  # fmt: skip
    ax.plot(ref["frame"], ref["ttc_ref_s"], color="black", lw=2.5, label="reference")
    ax.set(ylim=(0, top), xlabel="frame", ylabel="camera TTC (s, clipped)",
           title=f"best {n} and worst {n} settings (triangles on top: invalid TTC)")  # fmt: skip
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    return fig


def pareto_front(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Indices of the points not dominated in (x lower, y lower), by increasing x."""
    order = np.lexsort((y, x))
    best = np.minimum.accumulate(y[order])
    keep = np.r_[True, best[1:] < best[:-1]]
    return order[keep & np.isfinite(y[order])]


def plot_pareto(ranking: pd.DataFrame) -> plt.Figure:
    """Accuracy against time per frame, with the Pareto front of each accuracy metric.

    Time: ``ms_compute_per_frame`` (cached stages at their computing time), else the run's
    own ``ms_per_frame``."""
    time_col = "ms_frame"
    ranking = ranking.assign(
        **{time_col: ranking["ms_compute_per_frame"].fillna(ranking["ms_per_frame"])}
    )
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, col in zip(axes, ("camera_outlier_rate", "camera_medae_rel"), strict=True):
        sns.scatterplot(data=ranking, x=time_col, y=col, hue="detector", style="descriptor",
                        s=40, ax=ax)  # fmt: skip
        front = ranking.iloc[pareto_front(ranking[time_col].to_numpy(float),
                                          ranking[col].to_numpy(float))]  # fmt: skip
        ax.step(front[time_col], front[col], where="post", color="black", lw=1.2,
                label="Pareto front")  # fmt: skip
        for r in front.itertuples():
            ax.annotate(r.setting, (getattr(r, time_col), getattr(r, col)), fontsize=6,
                        xytext=(3, 3), textcoords="offset points")  # fmt: skip
        ax.set(xscale="log", xlabel="time per frame (ms, log; computed stages)", ylabel=col)
        ax.legend(fontsize=6, ncol=2)
    fig.suptitle("accuracy against time per frame")
    fig.tight_layout()
    return fig


def fp6_tables(
    data: SweepData, reference: pd.DataFrame, ctx: Context | None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The FP.6 frame table with way-off reasons and the ranking (both empty without an ok
    run). ``ctx`` None skips the match-geometry examination of the worst frames."""
    t = camera_frame_table(data.frames, data.runs, reference)
    if t.empty:
        return t, pd.DataFrame()
    t = camera_reasons(t)
    if ctx is not None:
        t = examine_worst(t, data.runs, reference, ctx, MAX_EXAMINED)
    else:
        t["examined"] = False
    return t, camera_ranking(data.frames, t, reference)


def fp6_report(
    data: SweepData, reference: pd.DataFrame, ctx: Context, out: Path, pictures: bool = True
) -> tuple[pd.DataFrame, pd.DataFrame] | None:
    """Write ``fp6_camera.md``, ``fp6_camera_ttc.csv``, ``fp6_ranking.csv``, the plots and
    the worst frames' match pictures; return (frame table, ranking)."""
    t, ranking = fp6_tables(data, reference, ctx)
    if t.empty:
        return None
    write_csv(t[FP6_COLUMNS], out / "fp6_camera_ttc.csv")
    write_csv(ranking[RANKING_COLUMNS], out / "fp6_ranking.csv")
    save_figure(plot_heatmap(ranking), out / "fp6_heatmap.png")
    save_figure(plot_top_bottom(t, ranking, reference), out / "fp6_ttc_series.png")
    save_figure(plot_pareto(ranking), out / "fp6_pareto.png")
    shutil.rmtree(out / "fp6_pictures", ignore_errors=True)
    drawn = []
    if pictures:
        for _, row in (
            worst_order(t, per_pair=1, turns="detector").head(MAX_CAMERA_PICTURES).iterrows()
        ):
            name = f"{row['setting'].replace('/', '_')}_frame_{int(row['frame']):04d}.png"
            image = camera_picture(row, data.runs, ctx)
            drawn.append((row, save_picture(image, out / "fp6_pictures" / name)))
    (out / "fp6_camera.md").write_text(fp6_markdown(data, t, ranking, drawn, out))
    return t, ranking


def fp6_markdown(data, t, ranking, pictures, out: Path) -> str:
    """The FP.6 markdown: ranking, best settings, way-off frames with reasons, pictures."""
    show = ["rank", "rank_lo", "rank_hi", "setting", "camera_outlier_rate", "camera_medae_rel",
            "camera_meanae_rel", "camera_jitter_s", "camera_invalid", "way_off_frames",
            "ms_compute_per_frame", "ms_per_frame"]  # fmt: skip
    tied = ranking[ranking["rank_lo"] == 1]
    way = t[t["way_off"]]
    codes = way["reasons"].str.split(";").explode().value_counts().rename_axis("reason")
    worst = worst_order(t).head(40)
    worst = worst.assign(ttc=_fmt(worst["ttc_camera"], ".2f"), ref=_fmt(worst["ttc_ref_s"], ".2f"))
    parts = [
        provenance_markdown(data, "FP.6: camera TTC across detector / descriptor settings"),
        "Camera TTC of the lead vehicle per frame for every camera setting in the sweeps, "
        "judged against the reference TTC ([reference.md](reference.md)).",
        "",
        f"**Ranking rule** (`ttc.evaluation.metrics.RANKING_RULE`): {metrics.RANKING_RULE} Rank intervals: "
        f"90 % paired bootstrap over frames ({N_BOOT} replicates, seed 0).",
        "",
        f"## Best settings ({len(tied)} whose rank interval includes 1)",
        "",
        markdown_table(ranking[show].head(max(10, min(len(tied), 25)))),
        "",
        "![heatmap](fp6_heatmap.png)",
        "",
        "![series](fp6_ttc_series.png)",
        "",
        "![pareto](fp6_pareto.png)",
        "",
        f"## Frames where the camera TTC is way off ({len(way)} of {len(t)} setting x frame rows)",
        "",
        f"Way off: relative error > {WAY_OFF_REL:.0%}, an invalid TTC where the reference is "
        "finite, or a false alarm. Reasons from the rows: the TTC's reason code, fewer than "
        f"{FEW_MATCHES} kept matches, > {REMOVED_SHARE:.0%} of the box's matches removed, "
        f"|r - 1| < {RATIO_HAIR}; otherwise the scale error in pixels. For the "
        f"{int(t['examined'].sum())} worst (at most {PER_PAIR} per detector x descriptor pair, "
        "round-robin over reasons) the match geometry is measured too: pair ratios exactly 1 "
        f"(> {EXACT_SHARE:.0%}), matches leaving the object (> {LEAVE_SHARE:.0%} more than "
        f"{LEAVE_PX:.0f} px off the median motion), keypoints on the box edge "
        f"(> {BORDER_SHARE:.0%} within {BORDER_FRAC:.0%} of the border) or on the background "
        "(lidar depth > 1 m behind the rear). All rows: `fp6_camera_ttc.csv` (run ids per "
        "setting in `fp6_ranking.csv`; the ratio the reference implies is 1 + dt / ttc_ref_s).",
        "",
        markdown_table(codes.reset_index()),
        "",
        "### The worst 40",
        "",
        markdown_table(worst[["setting", "frame", "ttc", "ref", "reasons", "reason_text"]]),
        "",
        "## Matches of the worst frames",
        "",
    ]
    for row, path in pictures:
        parts += [f"**{row['setting']}, frame {int(row['frame'])}**: {row['reason_text']}", "",
                  f"![{path.stem}]({path.relative_to(out).as_posix()})", ""]  # fmt: skip
    return "\n".join(parts) + "\n"


# =========================================================================== reference report


def plot_reference(reference: pd.DataFrame) -> plt.Figure:
    """Distance, closing speed and reference TTC per frame."""
    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    interp = reference["distance_interpolated"].astype(bool)
    axes[0].plot(reference["frame"], reference["distance_m"], "o", ms=3, label="lidar rear")
    axes[0].plot(reference["frame"], reference["distance_smooth_m"], "-", label="smoothed")
    axes[0].plot(reference.loc[interp, "frame"], reference.loc[interp, "distance_smooth_m"],
                 "x", color="crimson", ms=8, label="interpolated")  # fmt: skip
    axes[0].set_ylabel("distance (m)")
    axes[1].plot(reference["frame"], reference["closing_speed_mps"], "-o", ms=3)
    axes[1].axhline(reference_module.MIN_CLOSING_SPEED_MPS, color="grey", ls="--",
                    label="min closing speed")  # fmt: skip
    axes[1].set_ylabel("closing speed (m/s)")
    ttc = reference["ttc_ref_s"].where(np.isfinite(reference["ttc_ref_s"]))
    axes[2].plot(reference["frame"], ttc, "-o", ms=3, color="black")
    no_course = ~reference["collision_course"].astype(bool)
    axes[2].fill_between(
        reference["frame"],
        0,
        1,
        where=no_course,
        color="grey",
        alpha=0.2,
        transform=axes[2].get_xaxis_transform(),
        label="no collision course",
    )
    axes[2].set(ylabel="reference TTC (s)", xlabel="frame", ylim=(0, min(60, ttc.max() * 1.1)))
    for ax in axes:
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.suptitle("reference: lead vehicle distance, closing speed and TTC")
    fig.tight_layout()
    return fig


def reference_report(data: SweepData, reference: pd.DataFrame, out: Path) -> None:
    """``reference.csv``, ``reference.png`` and ``reference.md`` (with the caveats)."""
    write_csv(reference, out / "reference.csv")
    save_figure(plot_reference(reference), out / "reference.png")
    text = [
        provenance_markdown(data, "Reference TTC"),
        reference_module.__doc__.strip().split("\n\n")[0],
        "",
        f"**Caveats.** {reference_module.REFERENCE_CAVEATS}",
        "",
        "![reference](reference.png)",
        "",
        "Per frame: `reference.csv` (distance in m, closing speed in m/s, TTC in s).",
    ]
    (out / "reference.md").write_text("\n".join(text) + "\n")


# =========================================================================== command


def build_report(
    sweep_dirs: list[Path],
    out: Path,
    data_dir: Path | None = None,
    cache_dir: Path | None = None,
    pictures: bool = True,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Metrics beside each sweep and both reports under ``out``; returns what was written and
    the seconds each step took."""
    times: dict[str, float] = {}
    start = last = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal last
        now = time.perf_counter()
        times[name], last = now - last, now

    data = load_sweeps(sweep_dirs)
    if data.runs.empty:
        raise ValueError(f"no runs in {', '.join(map(str, sweep_dirs))}")
    ctx = make_context(data_dir, cache_dir)
    out.mkdir(parents=True, exist_ok=True)
    lap("load")
    reference = reference_for(data, ctx)
    lap("reference")
    written = write_sweep_metrics(data, reference)
    lap("metrics")
    reference_report(data, reference, out)
    lap("reference report")
    fp5 = fp5_report(data, reference, ctx, out, pictures) if not data.frames.empty else None
    lap("fp5")
    fp6 = fp6_report(data, reference, ctx, out, pictures) if not data.frames.empty else None
    lap("fp6")
    times["total"] = time.perf_counter() - start
    summary = {"metrics": written, "out": out, "times": times, "pair_details": ctx.calls,
               "fp5": fp5, "fp6": fp6}  # fmt: skip
    log(f"metrics: {', '.join(map(str, written))}")
    log(f"reports: {out} ({', '.join(sorted(p.name for p in out.glob('*.md')))})")
    log("seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in times.items())
        + f"; {ctx.calls} pair details")  # fmt: skip
    return summary


def main(argv: list[str] | None = None) -> None:
    matplotlib.use("Agg")  # files only; notebooks importing this module keep their backend
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep_dirs", type=Path, nargs="+", help="sweep folders")
    parser.add_argument("--out", type=Path, required=True, help="report folder (results/<name>)")
    parser.add_argument(
        "--data-dir",
        type=Path,
        default=None,
        help="data root (default: $TTC_DATA_DIR or the configured one)",
    )
    parser.add_argument(
        "--cache-dir",
        type=Path,
        default=None,
        help="stage cache (default: $TTC_CACHE_DIR or the configured one)",
    )
    parser.add_argument("--no-pictures", action="store_true", help="tables and plots only")
    args = parser.parse_args(argv)  # fmt: skip
    for d in args.sweep_dirs:
        if not d.is_dir():
            parser.error(f"{d} is not a folder")
    build_report(args.sweep_dirs, args.out, args.data_dir, args.cache_dir, not args.no_pictures)


if __name__ == "__main__":
    main()
