"""FP.5 / FP.6 reports and sweep comparison: rules on synthetic rows, then real sweeps made by
the real command line (subprocesses), reported by ``python -m experiments.report``."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from experiments import store
from experiments.report import encode
from experiments.report.load import load_sweeps, make_context
from experiments.report.pictures import MAX_CAMERA_PICTURES, MAX_LIDAR_PICTURES
from tests.conftest import PROJECT_ROOT
from ttc import evaluation as ev
from ttc.draw import HIGHLIGHT_COLOUR
from ttc.draw.lead_pair import GAP, crop_scale, lead_region
from ttc.io.frames import frame_files

COMMITTED_FP5 = "results/kitti_0_18/fp5_lidar_ttc.csv"
#: Columns of the FP.5 CSV that a fresh sweep must reproduce exactly.
REPRODUCED = ["ttc_lidar", "lidar_reason", "ttc_ref_s", "d_prev", "d_curr", "flagged", "reasons"]


# --------------------------------------------------------------------------- shared sweeps


def shared_root(tmp_path_factory) -> Path:
    """One folder per test session for sweeps and the stage cache (shared by test modules)."""
    root = tmp_path_factory.getbasetemp() / "report_sweeps"
    root.mkdir(exist_ok=True)
    return root


def env_for(root: Path) -> dict[str, str]:
    return {**os.environ, "TTC_RESULTS_DIR": str(root / "sweeps"),
            "TTC_CACHE_DIR": str(root / "cache"), "MPLBACKEND": "Agg"}  # fmt: skip


def run_module(module: str, args: list[str], root: Path, timeout: float = 600):
    """``python -m <module> args`` in the project with results and cache under ``root``."""
    return subprocess.run(
        [sys.executable, "-m", module, *args], cwd=PROJECT_ROOT, env=env_for(root),
        capture_output=True, text=True, timeout=timeout,
    )  # fmt: skip


def make_sweep(root: Path, args: list[str], name: str) -> Path:
    """A sweep through the real command line (reused when this session already made it)."""
    sweep = root / "sweeps" / name
    if not any((sweep / store.RUNS_DIR).glob("*.json")):
        done = run_module("experiments.run", args, root)
        assert done.returncode == 0, done.stderr[-3000:]
    return sweep


def make_report(root: Path, sweeps: list[Path], out: Path, *extra: str) -> Path:
    """``python -m experiments.report`` into ``out`` (reused when already written)."""
    if not (out / "fp6_camera.md").is_file() or extra:
        args = [*map(str, sweeps), "--out", str(out), "--cache-dir", str(root / "cache"), *extra]
        done = run_module("experiments.report", args, root)
        assert done.returncode == 0, done.stderr[-3000:]
    return out


@pytest.fixture(scope="session")
def fp5_sweep(tmp_path_factory) -> tuple[Path, Path]:
    """Every lidar estimator on frames 0–18 (``+experiment=fp5_lidar``): (root, sweep)."""
    root = shared_root(tmp_path_factory)
    return root, make_sweep(root, ["+experiment=fp5_lidar"], "fp5_lidar_kitti_0_18")


@pytest.fixture(scope="session")
def camera_grid(tmp_path_factory) -> tuple[Path, Path]:
    """A 2 × 2 detector × descriptor grid on frames 0–5: (root, sweep)."""
    root = shared_root(tmp_path_factory)
    args = ["-m", "detector=fast,orb", "descriptor=brief,brisk", "dataset.last=5",
            "sweep_name=grid"]  # fmt: skip
    return root, make_sweep(root, args, "grid")


@pytest.fixture(scope="session")
def fp5_report(fp5_sweep) -> Path:
    root, sweep = fp5_sweep
    return make_report(root, [sweep], root / "reports" / "fp5")


@pytest.fixture(scope="session")
def grid_report(camera_grid) -> Path:
    root, sweep = camera_grid
    return make_report(root, [sweep], root / "reports" / "grid")


# --------------------------------------------------------------------------- encoding (fast)


def test_within_budget_shrinks_a_picture_until_it_fits() -> None:
    noise = np.random.default_rng(0).integers(0, 255, (600, 800, 3), dtype=np.uint8)
    small = encode.within_budget(noise, 200_000)
    assert small.shape[1] < 800
    assert len(cv2.imencode(".png", small)[1]) <= 200_000


def test_markdown_table_formats_cells() -> None:
    table = encode.markdown_table(pd.DataFrame({"a": [1.23456, np.inf], "b": ["x|y", "z"]}))
    assert table.splitlines() == ["| a | b |", "|---|---|", "| 1.23 | x\\|y |", "| inf | z |"]


# --------------------------------------------------------------------------- real sweeps


@pytest.mark.slow
def test_fp5_flags_real_frames_with_derived_reasons(fp5_report: Path) -> None:
    table = pd.read_csv(fp5_report / "fp5_lidar_ttc.csv")
    assert set(table["lidar_ttc"]) == {"closest", "cluster", "median", "quantile",
                                       "quantile_band_mean"}  # fmt: skip
    assert len(table) == 5 * 18
    flagged = table[table["flagged"]]
    assert len(flagged) >= 1
    assert flagged["reasons"].notna().all() and flagged["reason_text"].str.len().gt(20).all()
    assert table.loc[~table["flagged"], "reasons"].isna().all()
    # the closest point reacts to stray returns ahead of the bumper; the median does not
    closest = flagged[flagged["lidar_ttc"] == "closest"]
    assert closest["reasons"].str.contains("points_ahead").any()
    assert len(closest) > (flagged["lidar_ttc"] == "median").sum()


@pytest.mark.slow
def test_fp5_pictures_are_bounded_and_linked(fp5_report: Path) -> None:
    pictures = sorted((fp5_report / "fp5_pictures").glob("*.png"))
    table = pd.read_csv(fp5_report / "fp5_lidar_ttc.csv")
    flagged_frames = table.loc[table["flagged"], "frame"].nunique()
    assert len(pictures) == min(flagged_frames, MAX_LIDAR_PICTURES) >= 1
    assert all(p.stat().st_size <= encode.LIDAR_PICTURE_BYTES for p in pictures)
    text = (fp5_report / "fp5_lidar.md").read_text()
    assert all(f"fp5_pictures/{p.name}" in text for p in pictures)


@pytest.mark.slow
def test_markdown_starts_with_provenance(fp5_report: Path, fp5_sweep) -> None:
    runs = store.load_runs(fp5_sweep[1])
    for name in ("fp5_lidar.md", "fp6_camera.md", "reference.md"):
        text = (fp5_report / name).read_text()
        assert text.startswith("# ")
        head = text[:6000]
        for field in ("| sweeps | `fp5_lidar_kitti_0_18`", "| code version (runs) |",
                      "| sweep command-line |", "+experiment=fp5_lidar", "| report date |",
                      "| machine (runs) |", "| package versions (runs) |", "opencv",
                      "config shared by every run"):  # fmt: skip
            assert field in head, (name, field)
        assert runs["git_commit"].iloc[0] in head
    assert "Caveats" in (fp5_report / "reference.md").read_text()


@pytest.mark.slow
def test_csvs_are_deterministic_with_or_without_pictures(fp5_sweep, fp5_report: Path) -> None:
    root, sweep = fp5_sweep
    again = make_report(root, [sweep], root / "reports" / "fp5_again", "--no-pictures")
    assert not (again / "fp5_pictures").exists() or not list((again / "fp5_pictures").iterdir())
    for name in ("reference.csv", "fp5_lidar_ttc.csv", "fp6_camera_ttc.csv", "fp6_ranking.csv"):
        assert (fp5_report / name).read_bytes() == (again / name).read_bytes(), name


@pytest.mark.slow
def test_metrics_parquet_beside_the_sweep(fp5_report: Path, fp5_sweep) -> None:
    metrics = pd.read_parquet(fp5_sweep[1] / "metrics.parquet")
    assert len(metrics) == 5 and metrics["run_id"].is_unique
    assert metrics["status"].eq("ok").all()
    assert metrics["lidar_outlier_rate"].between(0, 1).all()
    assert metrics["n_frames"].eq(18).all()


@pytest.mark.slow
def test_fp6_report_on_a_camera_grid(grid_report: Path, camera_grid) -> None:
    ranking = pd.read_csv(grid_report / "fp6_ranking.csv")
    assert len(ranking) == 4 and sorted(ranking["rank"]) == [1, 2, 3, 4]
    assert (ranking["rank_lo"] <= ranking["rank"]).all()
    assert (ranking["rank"] <= ranking["rank_hi"]).all()
    frames = pd.read_csv(grid_report / "fp6_camera_ttc.csv")
    assert len(frames) == 4 * 5
    way = frames[frames["way_off"]]
    assert way["reasons"].notna().all()
    assert frames.loc[~frames["way_off"], "reasons"].isna().all()
    for name in ("fp6_heatmap.png", "fp6_ttc_series.png", "fp6_pareto.png", "reference.png"):
        assert 5_000 < (grid_report / name).stat().st_size <= encode.MAX_PICTURE_BYTES
    pictures = list((grid_report / "fp6_pictures").glob("*.webp"))
    assert len(pictures) == min(len(way.groupby(["detector", "descriptor"])), MAX_CAMERA_PICTURES)
    assert all(p.stat().st_size <= 200_000 for p in pictures)
    # one lidar estimator in the sweep still gives its FP.5 section
    lidar = pd.read_csv(grid_report / "fp5_lidar_ttc.csv")
    assert set(lidar["lidar_ttc"]) == {"median"} and len(lidar) == 5
    assert "| kitti_0_18 | median |" in (grid_report / "fp5_lidar.md").read_text()


def test_a_report_holds_no_detector_network_after_the_objects_reference(
    camera_grid, grid_report: Path, tmp_path: Path, monkeypatch
) -> None:
    """A report whose steps detect objects (an empty stage cache: every frame's boxes
    computed again) loads YOLOv3-tiny and holds it in neither process once its detecting
    steps are done (the every-object reference in the second, FP.6's pair details in the
    report's own: ≈ 0.2 GB through the rest otherwise); its tables are those of the report
    made with the sweep's cache."""
    from experiments.report.report_command import build_report
    from ttc.features import objects

    objects.clear_detector_cache()
    loaded = []
    real = objects.read_darknet
    monkeypatch.setattr(objects, "read_darknet", lambda *a: loaded.append(a) or real(*a))
    root, sweep = camera_grid
    out = tmp_path / "report"
    build_report([sweep], out, cache_dir=tmp_path / "empty-cache", pictures=False, html=False,
                 log=lambda _: None)  # fmt: skip
    assert loaded, "no step detected objects: the test did not load the network"
    assert objects._cached_net.cache_info().currsize == 0
    for name in ("fp6_camera_ttc.csv", "fp6_ranking.csv", "objects.csv"):
        assert (out / name).read_bytes() == (grid_report / name).read_bytes(), name


def test_crop_scale_reaches_the_width_without_shrinking() -> None:
    for width in (40, 120, 300, 450, 900, 1242):
        scale = crop_scale(width, 900)
        assert scale >= 1.0
        assert 2 * width * scale + GAP >= 900 or scale == 4.0


def _edges(mask: np.ndarray, length: float) -> np.ndarray:
    """Indices of the rows of ``mask`` with at least 80 % of ``length`` pixels set."""
    return np.flatnonzero(mask.sum(axis=1) >= 0.8 * length)


@pytest.mark.slow
def test_fp6_pictures_are_readable_and_show_both_lead_boxes(grid_report: Path, camera_grid) -> None:
    """Every FP.6 picture is at least 800 px wide and shows the lead box of the previous
    frame (left) and of the current frame (right) at the picture's scale: a yellow outline
    of the box's size (within 4 px) in each half."""
    root, sweep = camera_grid
    pictures = sorted((grid_report / "fp6_pictures").glob("*.webp"))
    assert len(pictures) >= 1
    ranking = pd.read_csv(grid_report / "fp6_ranking.csv")
    frames = pd.read_csv(grid_report / "fp6_camera_ttc.csv")
    run_of = dict(zip(ranking["setting"].str.replace("/", "_"), ranking["run_id"], strict=True))
    data, ctx = load_sweeps([sweep]), make_context(None, root / "cache")
    for path in pictures:
        image = cv2.imread(str(path))
        assert image is not None and image.shape[1] >= 800, path.name
        stem, frame = path.stem.rsplit("_frame_", 1)
        row = frames[(frames["setting"].str.replace("/", "_") == stem)
                     & (frames["frame"] == int(frame))].iloc[0]  # fmt: skip
        detail = ctx.detail(data.runs, run_of[stem], int(row["prev_frame"]), int(row["frame"]))
        x0, _, x1, _ = lead_region(detail)
        scale = crop_scale(x1 - x0)
        half = int(round((x1 - x0) * scale))
        yellow = (np.abs(image.astype(int) - HIGHLIGHT_COLOUR) < 70).all(axis=2)
        yellow[-40:] = False  # the legend's sample box
        for (frame_no, box), part in zip(
            zip((detail.prev, detail.curr), ev.lead_boxes(detail), strict=True),
            (yellow[:, :half], yellow[:, half + GAP :]), strict=True,
        ):  # fmt: skip
            assert box >= 0, f"{path.name}: no lead box in frame {frame_no}"
            w, h = (float(v) * scale for v in detail.objects[frame_no]["roi"][box][2:])
            rows, columns = _edges(part, w), _edges(part.T, h)
            assert len(rows) >= 2 and len(columns) >= 2, f"{path.name}: frame {frame_no}"
            assert abs(rows[-1] - rows[0] - h) <= 4, (path.name, frame_no, rows, h)
            assert abs(columns[-1] - columns[0] - w) <= 4, (path.name, frame_no, columns, w)


@pytest.mark.slow
def test_pair_details_share_each_frame_read_once(camera_grid) -> None:
    """Two settings' details of one frame pair show the same image arrays, equal to the
    frames' files and read-only (drawn on copies); a detail of the next pair shares its
    previous frame; forgetting the details forgets the images."""
    root, sweep = camera_grid
    data, ctx = load_sweeps([sweep]), make_context(None, root / "cache")
    first, second = data.runs.loc[data.runs["status"] == "ok", "run_id"].iloc[:2]
    a, b = ctx.detail(data.runs, first, 0, 1), ctx.detail(data.runs, second, 0, 1)
    c = ctx.detail(data.runs, first, 1, 2)
    assert a.images[0] is b.images[0] and a.images[1] is b.images[1] is c.images[1]
    sequence = ctx.setup(data.runs, first)[1].sequence_dir
    for i in (0, 1, 2):
        image = c.images[i] if i else a.images[0]
        assert not image.flags.writeable
        assert np.array_equal(image, cv2.imread(str(frame_files(sequence, i).image)))
    assert len(ctx.images) == 3
    ctx.drop_details()
    assert not ctx.images and not ctx.details


def test_frame_77_is_flagged_as_a_truncated_scan(tmp_path_factory) -> None:
    root = shared_root(tmp_path_factory)
    args = ["-m", "lidar_ttc=median,closest", "dataset=kitti_0_77", "sweep_name=fp5_0_77"]
    sweep = make_sweep(root, args, "fp5_0_77")
    out = make_report(root, [sweep], root / "reports" / "fp5_0_77", "--no-pictures")
    table = pd.read_csv(out / "fp5_lidar_ttc.csv")
    assert len(table) == 2 * 77
    last = table[table["frame"] == 77]
    assert last["flagged"].all() and last["reasons"].str.contains("scan_short").all()
    assert not table.loc[table["frame"] < 77, "scan_short"].any()


@pytest.mark.slow
def test_compare_two_sweeps(fp5_sweep, camera_grid, tmp_path: Path) -> None:
    root, sweep = fp5_sweep
    out = tmp_path / "cmp.md"
    args = [str(sweep), str(sweep), "--sensor", "lidar", "--out", str(out),
            "--cache-dir", str(root / "cache")]  # fmt: skip
    done = run_module("experiments.tools.compare", args, root)
    assert done.returncode == 0, done.stderr[-3000:]
    text = out.read_text()
    assert "5 settings in both" in text and "0 better, 0 worse, 5 same" in text
    # the grid shares one setting (fast/brief/bf/knn, median) with the FP.5 sweep
    done = run_module("experiments.tools.compare", [str(camera_grid[1]), str(sweep), "--cache-dir",
                      str(root / "cache")], root)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert "1 settings in both" in done.stdout and "| fast/brief |" in done.stdout
    # ignoring an axis that varies inside a sweep leaves settings ambiguous: refused
    done = run_module("experiments.tools.compare", [str(sweep), str(camera_grid[1]), "--ignore",
                      "lidar_ttc", "--cache-dir", str(root / "cache")], root)  # fmt: skip
    assert done.returncode != 0 and "share their" in done.stderr


@pytest.mark.slow
def test_fresh_sweep_reproduces_the_committed_fp5_table(fp5_report: Path) -> None:
    listed = subprocess.run(["git", "ls-files", "--error-unmatch", COMMITTED_FP5],
                            cwd=PROJECT_ROOT, capture_output=True, text=True)  # fmt: skip
    if listed.returncode != 0:
        pytest.skip(f"{COMMITTED_FP5} is not committed yet: nothing to reproduce")
    shown = subprocess.run(["git", "show", f"HEAD:{COMMITTED_FP5}"], cwd=PROJECT_ROOT,
                           capture_output=True, text=True, check=True)  # fmt: skip
    committed = pd.read_csv(io.StringIO(shown.stdout), dtype=str, keep_default_na=False)
    fresh = pd.read_csv(fp5_report / "fp5_lidar_ttc.csv", dtype=str, keep_default_na=False)
    key = ["dataset", "frame", "lidar_ttc"]
    both = fresh.merge(committed, on=key, how="left", suffixes=("", "_committed"),
                       indicator=True)  # fmt: skip
    assert both["_merge"].eq("both").all(), "the committed table lacks rows of a fresh sweep"
    for column in REPRODUCED:
        differ = both[both[column] != both[f"{column}_committed"]]
        assert differ.empty, f"{column} differs:\n{differ[[*key, column]].head()}"


def test_common_config_names_the_shared_values_and_the_varying_keys() -> None:
    from experiments.report.header import _common_config  # noqa: PLC0415

    a = {"detector": {"name": "fast", "threshold": 30}, "dataset": {"last": 18, "step": 1},
         "lane": [2.0, 20.0]}  # fmt: skip
    b = {"detector": {"name": "orb", "threshold": 30}, "dataset": {"last": 18, "step": 1},
         "lane": [2.0, 20.0], "fusion": {"name": "none"}}  # fmt: skip
    configs = pd.Series([json.dumps(a), json.dumps(b), json.dumps(a)])
    common, varying = _common_config(configs)
    assert common == {"detector.threshold": 30, "dataset.last": 18, "dataset.step": 1,
                      "lane": [2.0, 20.0]}  # fmt: skip
    assert varying == ["detector.name", "fusion.name"]
