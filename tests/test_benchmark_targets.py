"""The sweep benchmark's targets, parts and before / after report timing, without timing
anything: :func:`experiments.tools.benchmark._judged` on made-up figures, ``--parts`` parsing,
the clone of an earlier commit, and the order and medians of the report rounds (the report
command replaced by a stand-in)."""

from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

import pytest

from experiments.tools import benchmark, report_timing
from tests.conftest import PROJECT_ROOT

#: Issue 51's targets (figure: largest value met).
ISSUE_51 = {"grand_report_s": 10.0, "grand_report_peak_pss_mb": 1024.0,
            "grand_long_report_peak_pss_mb": 1536.0, "grand_warm_s": 6.0,
            "cold_over_floor_unique": 1.15}  # fmt: skip


def test_issue_51_targets_are_set() -> None:
    for figure, limit in ISSUE_51.items():
        assert benchmark.TARGETS[f"{figure}_max"] == limit, figure


def test_every_target_is_judged_and_absent_figures_are_missing() -> None:
    report = {"grand_report_s": 10.0, "grand_report_peak_pss_mb": 1100.0, "grand_warm_s": 5.9,
              "cold_over_floor_unique": 1.2, "grand_report_peak_rss_mb": 900.0}  # fmt: skip
    judged = benchmark._judged(dict(report))
    assert judged["meets"] == {"grand_report_s": True, "grand_report_peak_pss_mb": False,
                               "grand_warm_s": True, "cold_over_floor_unique": False,
                               "grand_report_peak_rss_mb": True}  # fmt: skip
    missing = judged["missing"]
    assert "grand_long_report_peak_pss_mb" in missing and "grand_report_s" not in missing
    assert set(missing) == set(benchmark.FIGURES) - report.keys()
    everything = benchmark._judged({k.removesuffix("_max"): 0.0 for k in benchmark.TARGETS})
    assert everything["meets"].keys() == {k.removesuffix("_max") for k in benchmark.TARGETS}
    assert {"grand_report_peak_pss_mb", "grand_long_report_peak_pss_mb"} <= set(benchmark.FIGURES)


def _parts(text: str | None, reduced: bool = False, workdir: Path | None = None):
    return benchmark.parse_parts(argparse.ArgumentParser(), text, reduced, workdir)


def test_parts_parsing() -> None:
    assert _parts(None) == ("fp6", "small", "grand", "grand_long", "long")
    assert _parts(None, reduced=True) == ("fp6", "small")
    both = _parts("grand_report,grand_long_report", workdir=Path("w"))
    assert both == ("grand_report", "grand_long_report")
    assert _parts("grand,grand_long_report", workdir=Path("w")) == ("grand", "grand_long_report")
    for wrong in ("fp7", "grand,grand_report", "grand_report"):  # unknown, twice, no workdir
        with pytest.raises(SystemExit):
            _parts(wrong)


def test_clone_at_an_earlier_commit(tmp_path: Path) -> None:
    sha = subprocess.run(["git", "rev-parse", "HEAD~1"], cwd=PROJECT_ROOT, capture_output=True,
                         text=True, check=True).stdout.strip()  # fmt: skip
    clone, full = report_timing.clone_at(sha[:10], tmp_path)
    assert full == sha and clone == tmp_path / f"before-{sha[:12]}"
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=clone, capture_output=True,
                          text=True, check=True).stdout.strip()  # fmt: skip
    assert head == sha and (clone / "experiments" / "report").is_dir()
    assert report_timing.clone_at(sha, tmp_path) == (clone, sha)  # there already: re-used


def test_report_rounds_alternate_and_take_medians(tmp_path: Path, monkeypatch) -> None:
    calls: list[tuple[str, bool]] = []
    walls = {"before": iter([20.0, 30.0, 10.0]), "after": iter([5.0, 4.0, 6.0])}

    def fake_report(sweep_dir, out, cache, memory=None, code=None) -> float:
        name = "before" if code is not None else "after"
        assert out.name == ("grand-report-before" if code else "grand-report")
        calls.append((name, memory is not None))
        if memory is None:
            return 99.0  # the untimed first report of each code
        memory.update(rss=2000.0 if code else 800.0, pss=1000.0 if code else 500.0)
        return next(walls[name])

    monkeypatch.setattr(report_timing, "timed_report", fake_report)
    figures = report_timing.report_figures(
        "grand", tmp_path, tmp_path / "grand-report", tmp_path / "cache", tmp_path / "clone", 3
    )
    assert calls == [("before", False), ("after", False)] + [("before", True), ("after", True)] * 3
    assert figures["grand_report_before_s"] == 20.0 and figures["grand_report_s"] == 5.0
    assert figures["grand_report_over_before"] == 0.25
    assert figures["grand_report_peak_pss_mb"] == 500.0
    assert figures["grand_report_before_peak_rss_mb"] == 2000.0
    assert figures["grand_report_peak_pss_over_before"] == 0.5
    assert [r["s"] for r in figures["grand_report_rounds"]["before"]] == [20.0, 30.0, 10.0]

    calls.clear()
    walls["after"] = iter([7.0])
    alone = report_timing.report_figures("grand", tmp_path, tmp_path / "grand-report",
                                         tmp_path / "cache")  # fmt: skip
    assert calls == [("after", True)] and "grand_report_before_s" not in alone
    assert alone["grand_report_s"] == 7.0 and alone["grand_report_peak_pss_mb"] == 500.0


def test_a_report_only_part_needs_its_sweep(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="no run records"):
        benchmark.grand_report_figures(tmp_path)
