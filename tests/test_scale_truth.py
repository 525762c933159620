"""The exact-truth dataset (issue #13): the generator on a real frame, and the unchanged
pipeline (real YOLO, SIFT, lidar estimators) on pairs made from two real frames."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from experiments import store
from experiments.data.scale_truth import materialise
from experiments.store.schema import FRAME_COLUMNS
from tests.conftest import PROJECT_ROOT
from ttc import evaluation as ev
from ttc.engine.cache import StageCache
from ttc.engine.runner import run_settings
from ttc.features.descriptors import DESCRIPTORS
from ttc.features.keypoints import DETECTORS
from ttc.io.frames import (
    TRUTH_COLUMNS,
    TRUTH_FILE,
    frame_files,
    frame_pairs,
    read_image,
    read_truth,
)
from ttc.io.scaled_pairs import ScaleTruthParams, make_pair, scale_image, scale_matrix
from ttc.rows import MEMBER
from ttc.settings import FrameRange, Settings
from ttc.steps.lidar_ttc import LidarTTCParams

SOURCE = 20
CENTRE = (620.0, 190.0)
#: Lidar estimators run on the generated pairs (one batch: SIFT runs once).
ESTIMATORS = ("median", "closest", "quantile_band_mean")


@pytest.fixture(scope="module")
def image(kitti_dir: Path) -> np.ndarray:
    return read_image(frame_files(kitti_dir, SOURCE).image)


@pytest.fixture(scope="module")
def points() -> np.ndarray:
    """A flat rear at 8 m, 40 points (x, y, z, reflectance)."""
    y, z = np.meshgrid(np.linspace(-0.8, 0.8, 8), np.linspace(-1.4, -1.0, 5))
    x = 8.0 + 0.01 * np.arange(y.size)
    return np.column_stack([x, y.ravel(), z.ravel(), np.full(y.size, 0.5)]).astype(np.float32)


def sharpness(image: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image (high-frequency energy)."""
    return float(cv2.Laplacian(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), cv2.CV_64F).var())


def test_noise_off_ratio_is_exact(image, points):
    params = ScaleTruthParams().noiseless()
    for t, target in enumerate(params.targets_s):
        pair = make_pair(image, points, CENTRE, SOURCE, t, params)
        ratio = pair.points_prev[:, 0].astype(float) / pair.points_curr[:, 0]
        np.testing.assert_allclose(ratio, 1.0 + 0.1 / target, rtol=2e-7)
        np.testing.assert_array_equal(pair.points_prev[:, 1:], points[:, 1:])
        np.testing.assert_array_equal(pair.points_curr[:, 1:], points[:, 1:])
        assert pair.ttc_true == pytest.approx(target, rel=1e-12)
        assert pair.outliers_prev.shape == (0, 4)


def test_deterministic_for_a_seed(image, points):
    params = ScaleTruthParams(outlier_share=1.0)
    a, b = (make_pair(image, points, CENTRE, SOURCE, 1, params) for _ in range(2))
    for field in ("image_prev", "image_curr", "points_prev", "points_curr", "outliers_curr"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    other = make_pair(image, points, CENTRE, SOURCE, 1, dataclasses.replace(params, seed=1))
    assert not np.array_equal(a.image_curr, other.image_curr)
    assert not np.array_equal(a.points_curr, other.points_curr)
    # outliers (noise off): the same points in both scans, ahead of each closest point
    c = make_pair(image, points, CENTRE, SOURCE, 1, dataclasses.replace(params.noiseless(),
                  outlier_share=1.0))  # fmt: skip
    np.testing.assert_array_equal(c.outliers_prev[:, 1:], c.outliers_curr[:, 1:])
    for out, vehicle in ((c.outliers_prev, c.points_prev), (c.outliers_curr, c.points_curr)):
        assert len(out) == params.outlier_points
        assert (out[:, 0] <= vehicle[:, 0].min() - 0.3).all()


def test_both_images_resampled_alike(image, points):
    """Pixel statistics: both images of a pair lose the same high-frequency energy to the
    resampling (neither is the untouched source), at the target whose scales are nearest 1;
    the same check catches one image resampled with another interpolation."""
    params = ScaleTruthParams().noiseless()
    pair = make_pair(image, points, CENTRE, SOURCE, len(params.targets_s) - 1, params)
    prev, curr, source = sharpness(pair.image_prev), sharpness(pair.image_curr), sharpness(image)
    assert abs(prev / curr - 1.0) < 0.05
    assert max(prev, curr) < 0.97 * source
    s = pair.ratio_true
    mixed = scale_image(image, scale_matrix(CENTRE, s**0.5), "nearest")
    assert abs(prev / sharpness(mixed) - 1.0) > 0.05 or sharpness(mixed) > 0.97 * source


def test_photometric_noise_is_the_same_on_both(image, points):
    """With only pixel noise on, both images differ from their noiseless version by noise of
    the configured standard deviation (grey levels)."""
    clean = ScaleTruthParams().noiseless()
    noisy = dataclasses.replace(clean, noise_sigma=3.0)
    a = make_pair(image, points, CENTRE, SOURCE, 0, clean)
    b = make_pair(image, points, CENTRE, SOURCE, 0, noisy)
    for x, y in ((a.image_prev, b.image_prev), (a.image_curr, b.image_curr)):
        assert np.std(y.astype(float) - x) == pytest.approx(3.0, rel=0.05)


@pytest.fixture(scope="module")
def generated(kitti_dir: Path, tmp_path_factory) -> tuple[Path, pd.DataFrame]:
    """Noise off, outliers in about half the pairs: 2 source frames (0, 40) × 4 targets,
    SIFT/SIFT with three lidar estimators (real YOLO, real OpenCV)."""
    cache_dir = tmp_path_factory.mktemp("scale_truth_cache")
    params = dataclasses.replace(
        ScaleTruthParams(first=0, last=40, source_step=40).noiseless(), outlier_share=0.5
    )
    folder = materialise(kitti_dir, params, cache_dir)
    truth = read_truth(folder)
    frames = FrameRange(folder, 0, 2 * len(truth) - 1, min_scan_points=0, pairing="disjoint")
    settings = [
        Settings(detector=DETECTORS["sift"](), descriptor=DESCRIPTORS["sift"](),
                 lidar_ttc=LidarTTCParams(name=name))
        for name in ESTIMATORS
    ]  # fmt: skip
    rows, failed = run_settings(settings, frames, StageCache(cache_dir))
    assert not failed
    lead = rows[rows["is_lead"]].copy()
    lead["estimator"] = lead[MEMBER].map(dict(enumerate(ESTIMATORS)))
    return folder, lead


def rel_error(table: pd.DataFrame, column: str) -> pd.Series:
    return (table[column] / table["ttc_true"] - 1.0).abs()


@pytest.mark.slow
def test_generated_recording(generated, kitti_dir):
    folder, lead = generated
    truth = pd.read_csv(folder / TRUTH_FILE)
    assert len(truth) == 8 and (truth["frame"] == truth["prev_frame"] + 1).all()
    assert set(truth["source_frame"]) == {0, 40}
    assert sorted(set(truth["ttc_target"])) == [3.0, 6.0, 12.0, 24.0]
    # both kinds of pair, so the outlier test below means something
    assert (truth["outliers_injected"] > 0).any() and (truth["outliers_injected"] == 0).any()
    # every pair judged once per estimator, with the truth columns
    assert set(TRUTH_COLUMNS) <= set(lead.columns)
    assert lead.groupby("estimator")["frame"].nunique().eq(8).all()
    # the same source and seed give the same folder (nothing regenerated)
    params = dataclasses.replace(
        ScaleTruthParams(first=0, last=40, source_step=40).noiseless(), outlier_share=0.5
    )
    assert materialise(kitti_dir, params, folder.parents[1]) == folder


@pytest.mark.slow
def test_sift_camera_ttc_matches_the_truth(generated):
    """Noise off, SIFT/SIFT: the camera's distance ratio within MiD 6.6 (the ratio precision
    that is 2 % of the TTC at 3 s) on >= 95 % of the pairs of every target, and the TTC within
    2 % on every 3-s pair. (At 12 and 24 s, 2 % of the TTC needs the scale change to 1e-4 or
    better, which SIFT keypoints do not reach: see docs/scale-truth.md.)"""
    _, lead = generated
    cam = lead[lead["estimator"] == "median"]
    mid = 1e4 * np.abs(np.log(cam["camera_ratio"]) - np.log(cam["ratio_true"]))
    assert (mid < 6.6).mean() >= 0.95, mid.to_list()
    fast = cam[cam["ttc_target"] == 3.0]
    assert (rel_error(fast, "ttc_camera") < 0.02).all(), fast["ttc_camera"].to_list()


@pytest.mark.slow
def test_lidar_estimators_against_the_truth(generated):
    """Noise off: ``median`` within 1 % on every pair without injected outliers; on the pairs
    with outliers ``closest`` is pulled off, ``median`` and ``quantile_band_mean`` stay
    within 2 %."""
    _, lead = generated
    by = {name: table for name, table in lead.groupby("estimator")}
    clean = by["median"][by["median"]["outliers_injected"] == 0]
    assert (rel_error(clean, "ttc_lidar") < 0.01).all(), clean["ttc_lidar"].to_list()
    for name in ("median", "quantile_band_mean"):
        dirty = by[name][by[name]["outliers_injected"] > 0]
        assert (rel_error(dirty, "ttc_lidar") < 0.02).all(), dirty["ttc_lidar"].to_list()
    closest = by["closest"][by["closest"]["outliers_injected"] > 0]
    assert (rel_error(closest, "ttc_lidar") > 0.1).all(), closest["ttc_lidar"].to_list()


def test_ranking_agreement_on_known_rankings():
    """Kendall's tau of identical and of reversed rankings, the moves and the widths."""
    settings = pd.DataFrame({"detector": list("abcd"), "descriptor": "x"})
    same = settings.assign(rank=[1, 2, 3, 4], rank_lo=[1, 1, 2, 3], rank_hi=[2, 3, 4, 4])
    summary, moves = ev.ranking_agreement(same, same, ["detector", "descriptor"], top=2)
    assert summary["kendall_tau"] == pytest.approx(1.0) and (moves["move"] == 0).all()
    assert summary["top_width_synthetic"] == pytest.approx((1 / 4 + 2 / 4) / 2)
    reverse = same.assign(rank=[4, 3, 2, 1])
    summary, moves = ev.ranking_agreement(reverse, same, ["detector", "descriptor"])
    assert summary["kendall_tau"] == pytest.approx(-1.0) and summary["n_settings"] == 4
    assert moves["move"].abs().iloc[0] == 3 and set(moves["detector"].iloc[:2]) == {"a", "d"}


def run(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    """``python -m <args>`` from the project root."""
    return subprocess.run([sys.executable, "-m", *args], cwd=PROJECT_ROOT, env=env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip


@pytest.mark.slow
def test_small_sweep_outputs_carry_the_truth(tmp_path):
    """A sweep on ``dataset=scale_truth`` through the command line (one source frame, two
    lidar estimators): ``frames.parquet`` has the truth columns; the report writes metrics
    per target TTC and overall, beside the sweep and in the report."""
    env = {**os.environ, "TTC_RESULTS_DIR": str(tmp_path), "TTC_CACHE_DIR": str(tmp_path / "c")}
    args = ["dataset=scale_truth", "dataset.last=3", "detector=fast", "descriptor=brief",
            "lidar_ttc=median,closest", "sweep_name=st"]  # fmt: skip
    done = run(["experiments.run", "-m", *args], env)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "reports (truth.md, FP.6 against the truth" in done.stdout
    sweep = tmp_path / "st"
    frames = store.load_sweep(sweep)[0]
    documented = {name for name, *_ in FRAME_COLUMNS}  # the truth's are the only extra columns
    assert set(frames.columns) - documented == set(TRUTH_COLUMNS)
    assert frames.groupby("run_id")["frame"].nunique().eq(4).all()  # 1 source x 4 targets
    assert sorted(frames["ttc_target"].unique()) == [3.0, 6.0, 12.0, 24.0]
    real = PROJECT_ROOT / "results" / "kitti_0_18" / "fp6_ranking.csv"
    report = run(["experiments.report", str(sweep), "--out", str(tmp_path / "report"),
                  "--real", str(real)], env)  # fmt: skip
    assert report.returncode == 0, report.stderr[-3000:]
    by_target = pd.read_parquet(sweep / "metrics_by_target.parquet")
    assert sorted(by_target["target"].unique()) == sorted(["all", "3 s", "6 s", "12 s", "24 s"])
    assert by_target.groupby("run_id").size().eq(5).all()
    for col in ("camera_mid_median", "camera_medae_rel", "camera_invalid_rate",
                "lidar_mid_median", "lidar_medae_rel", "lidar_invalid_rate"):  # fmt: skip
        assert col in by_target
    overall = by_target[by_target["target"] == "all"]
    assert overall["n_frames"].eq(4).all() and overall["lidar_mid_median"].notna().all()
    metrics = pd.read_parquet(sweep / "metrics.parquet")  # ranked against the truth
    assert metrics["n_judged"].eq(4).all()
    ranking = pd.read_csv(tmp_path / "report" / "truth_ranking.csv")
    assert {"rank_lo", "rank_hi", "camera_mid_median_3s", "camera_mid_median_24s"} <= set(ranking)
    text = (tmp_path / "report" / "truth.md").read_text()
    assert "Kendall's tau" in text and "4 generated pairs" in text
    assert "[fp6_camera.md](fp6_camera.md)" in text  # the frames explained, against the truth
    camera = pd.read_csv(tmp_path / "report" / "fp6_camera_ttc.csv")
    assert len(camera) == 4  # one camera setting x 4 pairs
    np.testing.assert_allclose(camera.sort_values("frame")["ttc_ref_s"],
                               frames.drop_duplicates("frame").sort_values("frame")["ttc_true"])  # fmt: skip
    fp6_text = (tmp_path / "report" / "fp6_camera.md").read_text()
    assert "exact truth of the generated pairs" in fp6_text and "reference.md" not in fp6_text
    way_off = camera[camera["way_off"]]
    assert len(way_off) >= 1 and way_off["reasons"].fillna("").ne("").all()
    drawn = list((tmp_path / "report" / "fp6_pictures").glob("*.webp"))
    assert len(drawn) == 1  # the worst frame's matches (one per detector x descriptor)
    worst = way_off.loc[way_off["camera_rel_err"].fillna(np.inf).idxmax()]
    assert drawn[0].stem.endswith(f"frame_{int(worst['frame']):04d}")
    html = tmp_path / "report" / "html"  # the HTML report, the truth as its reference page
    truth_report = (html / "reference.html").read_text()
    assert "Kendall&#x27;s tau" in truth_report or "Kendall's tau" in truth_report
    assert 'href="fp6.html"' in truth_report and "fp6_camera.md" not in truth_report
    for name in ("index.html", "fp6.html", "fp5.html", "fp7.html"):
        assert (html / name).is_file(), name
    assert len(list((html / "settings").glob("*.html"))) == 1


def test_disjoint_frame_pairs():
    assert frame_pairs([0, 1, 2, 3]) == [(0, 1), (1, 2), (2, 3)]
    assert frame_pairs([0, 1, 2, 3], "disjoint") == [(0, 1), (2, 3)]
    assert FrameRange(Path("."), 0, 5, pairing="disjoint").pairs == [(0, 1), (2, 3), (4, 5)]
    with pytest.raises(ValueError, match="even number"):
        frame_pairs([0, 1, 2], "disjoint")
    with pytest.raises(ValueError, match="pairing"):
        frame_pairs([0, 1], "overlapping")


def test_a_kitti_raw_drive_can_be_a_source(kitti_dir: Path, tmp_path: Path) -> None:
    """A source in the official KITTI-raw layout (calibration in the date folder, beside the
    drive) is generated from too: its calibration is found, keyed and copied with the pairs."""
    from tests.test_kitti_raw import make_drive
    from ttc.io.calibration import CAM_TO_CAM, VELO_TO_CAM, load_calibration

    drive = make_drive(kitti_dir, tmp_path, "0052", [0, 1, 2])
    assert not (drive / CAM_TO_CAM).exists()  # only in the date folder
    params = ScaleTruthParams(first=0, last=0, source_step=1, targets_s=(3.0,)).noiseless()
    folder = materialise(drive, params, tmp_path / "cache")
    for name in (CAM_TO_CAM, VELO_TO_CAM):
        assert (folder / name).read_bytes() == (kitti_dir / name).read_bytes()
    np.testing.assert_array_equal(
        load_calibration(folder).velo_to_image, load_calibration(kitti_dir).velo_to_image
    )
    assert len(read_truth(folder)) == 1


def test_show_writes_a_generated_pair_it_has_to_generate_first(tmp_path):
    """``experiments.tools.show dataset=scale_truth`` with an empty cache writes the generated
    recording first, as a run does (it stopped at the missing calibration file)."""
    env = {**os.environ, "TTC_RESULTS_DIR": str(tmp_path), "TTC_CACHE_DIR": str(tmp_path / "c")}
    out = tmp_path / "pictures"
    done = run(["experiments.tools.show", "dataset=scale_truth", "dataset.last=3", "show.frame=1",
                f"show.out_dir={out}"], env)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    pictures = sorted(p.name for p in (out / "frame_0001").iterdir())
    assert "lead_ttc.png" in pictures and "keypoint_matches.png" in pictures
    assert (tmp_path / "c" / "scale_truth").is_dir()  # generated into the configured cache
