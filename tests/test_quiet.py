"""What a user reads from a sweep and its report (issue 29, items 3 and 4): no library warning
on the terminal, and every recording named by what it is.

The sweep: two settings on frames 0-3 of the three real recordings (drive 0052 in the Udacity
layout, odometry sequence 04, drive 0009), six jobs in two workers. Drive 0009 has no lead
vehicle, so nothing is judged there: the case that made seaborn warn about an all-NaN heatmap.
It runs with loky's memory-leak limit lowered to 1 MB in every process (a ``sitecustomize``):
a worker the launcher does not give its memory allowance
(``experiments.sweep.workers.allow_worker_growth``) is then replaced after its first job while
other jobs wait, and loky warns ``A worker stopped while some jobs were given to the
executor``, as a cold ``+experiment=fp6_grid`` did after ~110 s (its workers' caches grew them
from ≈ 350 to 630-710 MB, past loky's 300 MB).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import warnings
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd
import pytest
from joblib.externals.loky import process_executor

from experiments.data.datasets import recording_id, recording_names
from experiments.report.plots import NOTHING_JUDGED, plot_heatmap
from experiments.sweep.workers import LOKY_LEAK_LIMIT, WORKER_GROWTH_BYTES, allow_worker_growth
from tests.conftest import PROJECT_ROOT
from tests.test_config_tree import composed

#: Lowers loky's memory-leak limit in every Python process of the test's sweep.
LOW_LEAK_LIMIT = f"""\
from joblib.externals.loky import process_executor
process_executor.{LOKY_LEAK_LIMIT} = 2**20
"""
#: The three real recordings: dataset option, id (CSV columns, folders), name (pages).
RECORDINGS = {
    "kitti_0_18": ("2011_09_26_drive_0052", "drive 0052"),
    "kitti_odometry": ("odometry_04", "odometry 04"),
    "kitti_raw_0009": ("2011_09_26_drive_0009", "drive 0009"),
}


def test_worker_growth_allowance_raises_lokys_limit() -> None:
    """The global loky reads after each call of a worker exists (a joblib upgrade that renames
    it fails here) and the allowance raises it, never lowers it."""
    before = getattr(process_executor, LOKY_LEAK_LIMIT)
    try:
        setattr(process_executor, LOKY_LEAK_LIMIT, 2**20)
        allow_worker_growth()
        assert getattr(process_executor, LOKY_LEAK_LIMIT) == WORKER_GROWTH_BYTES
        setattr(process_executor, LOKY_LEAK_LIMIT, 4 * WORKER_GROWTH_BYTES)
        allow_worker_growth()
        assert getattr(process_executor, LOKY_LEAK_LIMIT) == 4 * WORKER_GROWTH_BYTES
    finally:
        setattr(process_executor, LOKY_LEAK_LIMIT, before)


def test_the_real_recordings_are_named_by_what_they_are() -> None:
    """From each dataset option's ``dataset.sequence``; the Udacity copy's folder names only
    its date and is drive 0052. Two dates' drives of one number keep their dates."""
    ids = {}
    for option, (expected_id, _) in RECORDINGS.items():
        ids[option] = recording_id(composed([f"dataset={option}"]).dataset.sequence)
        assert ids[option] == expected_id, option
    assert recording_names(ids.values()) == dict(RECORDINGS.values())
    assert recording_id("kitti_raw/2011_09_28/2011_09_28_drive_0009_sync") == (
        "2011_09_28_drive_0009"
    )
    assert recording_names(["2011_09_26_drive_0009", "2011_09_28_drive_0009"]) == {
        "2011_09_26_drive_0009": "2011_09_26 drive 0009",
        "2011_09_28_drive_0009": "2011_09_28 drive 0009",
    }


def _run(args: list[str], tmp: Path) -> subprocess.CompletedProcess:
    """``python <args>`` in the project root, results and cache under ``tmp``, two workers,
    loky's leak limit lowered (module docstring)."""
    site = tmp / "site"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(LOW_LEAK_LIMIT)
    path = os.pathsep.join(p for p in (str(site), os.environ.get("PYTHONPATH")) if p)
    env = {**os.environ, "PYTHONPATH": path, "TTC_RESULTS_DIR": str(tmp / "sweeps"),
           "TTC_CACHE_DIR": str(tmp / "cache"), "TTC_JOBS": "2"}  # fmt: skip
    return subprocess.run([sys.executable, *args], cwd=PROJECT_ROOT, env=env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip


@pytest.fixture(scope="module")
def sweep_and_report(tmp_path_factory) -> tuple[Path, list[subprocess.CompletedProcess]]:
    """The sweep (module docstring) and its report: (report folder, [sweep, report])."""
    tmp = tmp_path_factory.mktemp("quiet")
    sweep = _run(["-m", "experiments.run", "-m", f"dataset={','.join(RECORDINGS)}",
                  "dataset.last=3", "detector=fast,orb", "sweep_name=quiet"], tmp)  # fmt: skip
    assert sweep.returncode == 0, sweep.stderr[-3000:]
    assert "settings: 6 total, 6 ok" in sweep.stdout
    out = tmp / "report"
    report = _run(["-m", "experiments.report", str(tmp / "sweeps" / "quiet"), "--out", str(out)],
                  tmp)  # fmt: skip
    assert report.returncode == 0, report.stderr[-3000:]
    return out, [sweep, report]


@pytest.mark.slow
def test_sweep_and_report_print_no_warning(sweep_and_report) -> None:
    out, done = sweep_and_report
    for process in done:
        assert "Warning" not in process.stderr, process.stderr[-3000:]

    # nothing is judged on drive 0009: its median MiD panel says so in one line
    ranking = pd.read_csv(out / "2011_09_26_drive_0009" / "fp6_ranking.csv")
    assert ranking["camera_mid_median"].isna().all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fig = plot_heatmap(ranking)
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    plt.close(fig)
    assert texts.count(NOTHING_JUDGED) == 1


@pytest.mark.slow
def test_no_recording_is_shown_only_as_a_date(sweep_and_report) -> None:
    """The pages name the recordings ``drive 0052``, ``odometry 04``, ``drive 0009``; the CSVs
    and folders by id; no table cell, heading or CSV value is a bare date or ``04``."""
    out, _ = sweep_and_report
    ids = [rid for rid, _ in RECORDINGS.values()]
    assert all((out / rid / "fp6_camera.md").is_file() for rid in ids)
    wide = pd.read_csv(out / "recordings.csv")
    per_recording = {c.split("_", 1)[1] for c in wide if c.startswith(("rank_", "mid_"))}
    assert per_recording == {*ids, "pooled"}
    for name in ("drives_ranking.csv", "recordings_ttc_ranges.csv",
                 "recordings_false_alarms.csv"):  # fmt: skip
        assert set(pd.read_csv(out / name)["drive"]) <= {*ids, "pooled"}, name
    bare = re.compile(
        r"\| *(2011_09_26|04) *\||## \w+: (2011_09_26|04)\n"
        r"|(?<!odometry )(?<!drive )\b(2011_09_26|04)'s best"
    )
    for page in ("drives.md", "recordings.md", "html/recordings.html"):
        text = (out / page).read_text()
        assert not bare.search(text), (page, bare.search(text))
        for _, name in RECORDINGS.values():
            assert name in text, (page, name)
    text = (out / "recordings.md").read_text()
    assert "| drive_a | drive_b |" in text and "| drive 0052 | odometry 04 |" in text
