"""The sweep benchmark script on its reduced grid: it runs and writes a complete JSON report."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import PROJECT_ROOT

pytestmark = pytest.mark.slow


def test_reduced_benchmark_writes_report(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    res = subprocess.run(
        [sys.executable, "-m", "experiments.tools.benchmark", "--reduced", "--out", str(out),
         "--workdir", str(tmp_path / "work")],
        cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    report = json.loads(out.read_text())
    for key in ("cold_s", "floor_s", "floor_unique_s", "cold_over_floor", "nocache_s",
                "nocache_over_cold", "warm_filter_s", "peak_rss_mb", "git_commit", "versions",
                "cold_over_floor_unique", "rerun_s", "small_cold_s", "small_rerun_s",
                "floor_engine_s", "cold_over_floor_engine", "cold_fixed_s",
                "warm_filter_fixed_s", "warm_filter_lead_in_s", "warm_filter_local_s"):  # fmt: skip
        assert key in report, key
    steps = report["floor_ms_by_stage"]["steps"]
    assert 0 < steps < 1e3 * report["cold_s"]  # FP.1-FP.4 once, a part of the cold sweep
    assert report["floor_engine_s"] > report["floor_unique_s"]
    breakdown = report["warm_filter_breakdown"]
    assert report["warm_filter_fixed_s"] == breakdown["lead_in_s"] + breakdown["tail_s"] > 0
    assert report["small_settings"] == 8
    assert report["missing"] == ["grand_cold_s", "grand_warm_s", "grand_warm_fixed_s",
                                 "grand_peak_rss_mb", "grand_peak_pss_mb", "grand_report_s",
                                 "grand_report_peak_rss_mb", "grand_report_peak_pss_mb",
                                 "grand_long_cold_s", "grand_long_report_s",
                                 "grand_long_report_peak_rss_mb",
                                 "grand_long_report_peak_pss_mb", "long_cold_s"]  # not run when reduced  # fmt: skip
    assert report["rerun_s"] < report["cold_s"]  # nothing to compute
    assert report["settings"] == 16 and report["status"] == {"ok": 16}
    stages = report["floor_ms_by_stage"]
    assert all(stages[s] > 0 for s in ("objects", "keypoints", "descriptors", "matching_unique"))
    assert report["nocache_s"] > report["warm_filter_s"]  # the cache saves work
    warm = report["warm_filter_breakdown"]
    assert 0 < warm["jobs_s"] <= warm["span_s"] <= report["warm_filter_s"] and warm["jobs"] == 16
    # the jobs start after the command and end before it (records' times read right)
    assert 0 < warm["lead_in_s"] < report["warm_filter_s"]
    assert 0 < warm["tail_s"] < report["warm_filter_s"]
    assert 0 < report["hydra_compose_s_per_job"] < 5
    print(json.dumps({k: v for k, v in report.items() if isinstance(v, float)}, indent=1))
