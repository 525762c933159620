"""FP.7 diagnosis and report: the rules on exact rows, then a real fusion sweep on KITTI
frames 0-18 through the command line and its ``fp7_*`` report files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments.report.report_command import build_report
from tests.browser_cdp import Browser, chromium_path
from tests.test_sweep import hydra_run
from ttc.evaluation import OUTLIER_REL
from ttc.evaluation import fused_diagnosis as fd
from ttc.steps import fusion

INF = np.inf


def rows(**columns: list) -> pd.DataFrame:
    """A flagged FP.7 table of len(columns) rows: the reference 10 s, fused 15 s, inputs at
    the reference, filter updated by both and well started, unless ``columns`` say else."""
    n = max(len(v) for v in columns.values())
    base = {"ttc_ref_s": 10.0, "ttc_fused": 15.0, "ttc_lidar": 10.0, "ttc_camera": 10.0,
            "fused_reason": fusion.FUSED, "since_start": 10, "flagged": True}  # fmt: skip
    t = pd.DataFrame({k: columns.get(k, [v] * n) for k, v in base.items()})
    for s in ("fused", "lidar", "camera"):
        ttc = t[f"ttc_{s}"]
        t[f"{s}_invalid"] = ~np.isfinite(ttc)
        t[f"{s}_rel_err"] = ((ttc - t["ttc_ref_s"]).abs() / t["ttc_ref_s"]).where(np.isfinite(ttc))
    return t


def test_each_rule_names_what_the_filter_was_given() -> None:
    t = rows(
        since_start=[1, 10, 10, 10, 10, 10, 10],
        fused_reason=[
            fusion.FUSED,
            fusion.LIDAR_ONLY,
            fusion.FUSED,
            fusion.FUSED,
            fusion.FUSED,
            fusion.RECEDING,
            fusion.FUSED,
        ],  # fmt: skip
        ttc_fused=[15.0, 15.0, 15.0, 15.0, 15.0, INF, np.nan],
        ttc_camera=[10.0, 10.0, 16.0, 5.0, 12.0, 10.0, np.nan],
        ttc_lidar=[10.0, 10.0, 10.0, 10.0, 10.0, 10.0, 10.0],
    )
    found = fd.fused_reasons(t)["reasons"].tolist()
    assert found == [
        "start",  # the filter began 1 frame before
        "one_sensor",  # only the lidar updated it
        "camera_off",  # the camera 60 % high, the fused high too: it followed the camera
        "lag",  # the camera 50 % low while the fused is high: not what it followed
        "lag",  # the camera 20 % off: within OUTLIER_REL
        "receding",  # fused speed <= 0 while the reference approaches
        "camera_off",  # both invalid
    ]
    text = fd.fused_reasons(t)["reason_text"]
    assert "16.00 s against 10.00 s (60 %)" in text[2]
    assert "the filter's state trails them" in text[3]
    assert fd.fused_reasons(t.assign(flagged=False))["reasons"].eq("").all()


def test_no_fused_run_no_table() -> None:
    runs = pd.DataFrame({"run_id": ["a"], "status": ["ok"], "fusion": ["none"]})
    frames = pd.DataFrame({"run_id": ["a"], "frame": [1], "ttc_fused": [np.nan]})
    assert fd.fused_frame_table(frames, runs, pd.DataFrame()).empty


@pytest.fixture(scope="module")
def fusion_report(tmp_path_factory) -> tuple[Path, dict, str]:
    tmp = tmp_path_factory.mktemp("fp7")
    args = ["-m", "fusion=none,kalman_cv,kalman_ca", "lidar_ttc=median,closest",
            "detector=fast", "descriptor=brief,orb", "sweep_name=fusion"]  # fmt: skip
    done = hydra_run(args, tmp)
    assert done.returncode == 0, done.stderr[-3000:]
    out = tmp / "report"
    (out / "summary.txt").parent.mkdir(parents=True)
    (out / "summary.txt").write_text(done.stdout)
    summary = build_report([tmp / "sweeps" / "fusion"], out, cache_dir=tmp / "cache",
                           pictures=False, log=lambda _: None)  # fmt: skip
    return out, summary


@pytest.mark.slow  # a 12-setting sweep in a subprocess, then the report
def test_the_report_writes_fp7_for_the_fused_runs(fusion_report) -> None:
    out, summary = fusion_report
    compared = pd.read_csv(out / "fp7_fusion.csv")
    assert len(compared) == 8  # the fused runs only: 2 filters x 2 lidar x 2 descriptors
    assert set(compared["setting"].str.split("/").str[-1]) == {"kalman_cv", "kalman_ca"}
    assert compared["rank"].tolist() == sorted(compared["rank"])
    assert summary["fp7"][1]["beats_inputs"].tolist() == compared["beats_inputs"].tolist()

    t = pd.read_csv(out / "fp7_fusion_ttc.csv")
    assert t.groupby("run_id")["frame"].nunique().eq(18).all()  # every pair of 0-18
    assert set(t["run_id"]) == set(compared["run_id"])
    started = t[t["since_start"] >= 0]
    assert started["ttc_fused"].notna().all()  # an estimate every frame once started
    flagged = t[t["flagged"]]
    assert len(flagged) > 0  # fast/brief's and fast/orb's camera TTCs are off on some frames
    assert flagged["reasons"].fillna("").ne("").all()  # every flagged frame explained
    for sensor in ("lidar", "camera"):  # an input blamed is off by the rule's own test
        blamed = flagged[flagged["reasons"].str.contains(f"{sensor}_off")]
        off = blamed[f"{sensor}_rel_err"] > OUTLIER_REL
        assert (off | blamed[f"ttc_{sensor}"].isna() | ~np.isfinite(blamed[f"ttc_{sensor}"])).all()
    unflagged = t[~t["flagged"] & t["fused_rel_err"].notna()]
    assert (unflagged["fused_rel_err"] <= OUTLIER_REL).all()

    text = (out / "fp7_fusion.md").read_text()
    assert "## Fused against its inputs" in text and "fp7_fusion_ttc.png" in text
    assert (out / "fp7_fusion_ttc.png").stat().st_size > 10_000


@pytest.mark.slow
@pytest.mark.skipif(chromium_path() is None, reason="chromium is not installed: `.ci/run` "
                    "installs it (apt-get install -y chromium)")  # fmt: skip
def test_the_fp7_page_in_headless_chromium(fusion_report, tmp_path) -> None:
    out, _ = fusion_report
    compared = pd.read_csv(out / "fp7_fusion.csv")
    with Browser(tmp_path / "profile") as browser:
        browser.open(out / "html" / "index.html")
        assert "fp7.html" in browser.evaluate("[...document.querySelectorAll('nav a')]"
                                              ".map(a => a.getAttribute('href')).join(' ')")  # fmt: skip
        browser.open(out / "html" / "fp7.html")
        rows = "document.querySelectorAll('#fused tbody tr').length"
        assert browser.wait_for(f"document.querySelector('#fused.dataTable') && {rows}") == len(
            compared
        )
        shown = browser.evaluate("[...document.querySelectorAll('#fused tbody tr')]"
                                 ".map(r => r.children[1].textContent)")  # fmt: skip
        assert shown == compared["setting"].tolist()  # ranked on the fused TTC
        image = "document.querySelector('img')"
        assert browser.wait_for(f"{image}.complete && {image}.naturalWidth") >= 600
        assert browser.errors == []


@pytest.mark.slow
def test_the_sweep_summary_adds_the_fused_ranking(fusion_report) -> None:
    """The sweep varies a camera axis besides the lidar estimator and the fusion: its
    summary ranks on the camera (:func:`experiments.summary.collect.ranked_sensor`), then lists the
    fused settings ranked on the fused TTC, in the order of the report's FP.7 table."""
    out, _ = fusion_report
    printed = (out / "summary.txt").read_text()
    assert "settings with a fusion, on the fused TTC" in printed
    assert "reports (FP.5, FP.6, FP.7 fused TTC," in printed
    listed = printed.split("on the fused TTC")[1].split("reports (")[0]
    compared = pd.read_csv(out / "fp7_fusion.csv")
    order = [rid for rid in compared["run_id"] if rid in listed]
    assert order == compared["run_id"].head(3).tolist()
    positions = [listed.index(rid) for rid in order]
    assert positions == sorted(positions)
