"""Issue 51's proof: ``experiments/`` moved into folders by concern, and the report made to read
only the columns it shows, without changing what the project writes. The same sweep is run by
the code at :data:`BEFORE` (a clone of this repository) and by today's code, each into its own
results folder and stage cache. The rows (every column, every value) and the run records of
the two sweeps are the same, the times they took and the code version aside; and the
end-of-sweep summary and every file of the report that each code makes of one sweep folder
are the same, the report's own provenance lines aside and the one command the summary prints,
which moved with its module."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from experiments import store
from experiments.report import kept_judged
from experiments.tools.report_timing import clone_at
from tests.conftest import PROJECT_ROOT, data_root
from tests.test_report import env_for

#: The last commit before issue 51 (its layout and its report).
BEFORE = "d1732dd"
#: 2 detectors × 2 descriptors × 2 lidar estimators × fusion none / kalman_cv on frames 0–5:
#: every section of a recording's report (FP.5, FP.6, FP.7, every object).
SWEEP = ["-m", "detector=fast,orb", "descriptor=brief,brisk", "lidar_ttc=median,cluster",
         "fusion=none,kalman_cv", "dataset.last=5", "sweep_name=same"]  # fmt: skip
#: Record fields that name the run itself, not its result: times, memory, code version, and
#: the rows file's name and checksum (its rows hold the times).
OWN_FIELDS = re.compile(r"^(start|end|.*_s|.*_mb|ms_.*|git_.*|machine|hostname|pid|rows_.*)$")
#: Row columns that name the run itself: the times a stage took, the code version.
TIMES = re.compile(r"^(ms_|git_)")
#: Report lines that name the report's own run (code version, date, machine, packages).
PROVENANCE = re.compile(
    r"(code version|report date|machine|package versions|commit|generated|\d{4}-\d\d-\d\dT?)"
)
#: The summary's hint naming the module that ranks a sweep (moved: issue 51).
COLLECT_HINT = re.compile(r"python -m experiments\.(summary\.)?collect")


def _clone_before(parent: Path) -> Path:
    """This repository at :data:`BEFORE` in ``parent``
    (:func:`experiments.tools.report_timing.clone_at`, the benchmark's before code); skips in
    a shallow clone without it."""
    if subprocess.run(["git", "cat-file", "-e", f"{BEFORE}^{{commit}}"], cwd=PROJECT_ROOT,
                      capture_output=True).returncode:  # fmt: skip
        pytest.skip(f"commit {BEFORE} is not in this repository (shallow clone?)")
    return clone_at(BEFORE, parent)[0]


def _run(code: Path, module: str, args: list[str], root: Path) -> str:
    """``python -m module args`` of the code in ``code`` with results and cache under
    ``root``; its standard output."""
    env = {**env_for(root), "PYTHONPATH": str(code), "TTC_DATA_DIR": str(data_root()),
           "TTC_BENCH_SERVER": "0"}  # fmt: skip
    done = subprocess.run([sys.executable, "-m", module, *args], cwd=code, env=env,
                          capture_output=True, text=True, timeout=900)  # fmt: skip
    assert done.returncode == 0, f"{code}: {done.stderr[-3000:]}"
    return done.stdout


@pytest.fixture(scope="module")
def both(tmp_path_factory) -> dict[str, dict]:
    """The sweep run by the code at :data:`BEFORE` and by today's (each its own results and
    cache), and today's sweep summarised and reported by each, from one folder (its kept
    tables removed before each: each code derives them itself):
    ``{"before"|"after": {"sweep", "summary", "report"}}``."""
    base = tmp_path_factory.mktemp("same_outputs")
    code = {"before": _clone_before(base), "after": PROJECT_ROOT}
    _run(code["before"], "experiments.run", SWEEP, base / "before")
    _run(code["after"], "experiments.run", SWEEP, base / "work")
    work = base / "work" / "sweeps" / "same"
    out = {"before": {"sweep": base / "before" / "sweeps" / "same"}, "after": {"sweep": work}}
    modules = {"before": "experiments.collect", "after": "experiments.summary.collect"}
    for name, where in code.items():
        for derived in (".summary", ".configs", "metrics.parquet"):
            shutil.rmtree(work / derived, ignore_errors=True)
            (work / derived).unlink(missing_ok=True)
        out[name]["summary"] = _run(where, modules[name], [str(work)], base / "work")
        _run(where, "experiments.report", [str(work), "--out", str(base / "work" / "report"),
                                           "--cache-dir", str(base / "work" / "cache")],
             base / "work")  # fmt: skip
        out[name]["report"] = (base / "work" / "report").rename(base / f"report_{name}")
    # today's report again, from the cuts of the rows its first report kept (kept_judged)
    assert list((work / ".summary").glob(f"{kept_judged.JUDGED}-*.parquet"))
    _run(code["after"], "experiments.report", [str(work), "--out", str(base / "kept"),
                                               "--cache-dir", str(base / "work" / "cache")],
         base / "work")  # fmt: skip
    out["kept"] = {"report": base / "kept"}
    _run(code["after"], "experiments.report", [str(work), "--out", str(base / "one"),
                                               "--cache-dir", str(base / "work" / "cache"),
                                               "--one-process"], base / "work")  # fmt: skip
    out["one_process"] = {"report": base / "one"}
    return out


def _rows(sweep: Path) -> pd.DataFrame:
    """Every stored row of a sweep, in one order (run, frame, box), the index reset."""
    rows, _ = store.load_sweep(sweep)
    keys = [c for c in ("run_id", "frame", "prev_box", "curr_box") if c in rows]
    rows = rows.drop(columns=[c for c in rows if TIMES.match(c)])
    return rows.sort_values(keys, kind="stable", ignore_index=True)


def _records(sweep: Path) -> dict[str, dict]:
    """Every run record by run id, without the fields that name the run itself."""
    return {r["run_id"]: {k: v for k, v in r.items() if not OWN_FIELDS.match(k)}
            for r in store.list_records(sweep)}  # fmt: skip


def _summary(text: str) -> list[str]:
    """The summary's lines, the command naming the summary's module made alike."""
    return [COLLECT_HINT.sub("python -m <collect>", line) for line in text.splitlines()]


def _report_files(folder: Path) -> dict[str, bytes | list[str]]:
    """Every file of a report by its path in the folder: the text files' lines without the
    report's own provenance, the others' bytes."""
    out: dict[str, bytes | list[str]] = {}
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        name = str(path.relative_to(folder))
        if path.suffix in (".md", ".csv", ".html", ".json", ".txt"):
            text = path.read_text(encoding="utf-8")
            out[name] = [line for line in text.splitlines() if not PROVENANCE.search(line)]
        else:
            out[name] = path.read_bytes()
    return out


@pytest.mark.slow
def test_rows_are_the_same(both) -> None:
    before, after = _rows(both["before"]["sweep"]), _rows(both["after"]["sweep"])
    assert len(after) > 100 and list(after.columns) == list(before.columns)
    pd.testing.assert_frame_equal(after, before, check_exact=True)


@pytest.mark.slow
def test_records_are_the_same(both) -> None:
    before, after = _records(both["before"]["sweep"]), _records(both["after"]["sweep"])
    assert len(after) == 16 and sorted(after) == sorted(before)
    for run_id, record in after.items():
        assert json.dumps(record, sort_keys=True, default=str) == json.dumps(
            before[run_id], sort_keys=True, default=str
        ), run_id


@pytest.mark.slow
def test_the_summary_is_the_same(both) -> None:
    before, after = _summary(both["before"]["summary"]), _summary(both["after"]["summary"])
    assert any(line.startswith("best 5 settings") for line in after)
    assert after == before


@pytest.mark.slow
@pytest.mark.parametrize("after_name", ["after", "kept", "one_process"])
def test_every_report_file_is_the_same(both, after_name) -> None:
    """Every file of today's report (``after``: its rows cut from the fragments; ``kept``: a
    second report, from the cuts the first one kept; ``one_process``: a third, every section
    in the report's own process) is the before code's."""
    before = _report_files(both["before"]["report"])
    after = _report_files(both[after_name]["report"])
    assert {"fp5_lidar.md", "fp6_ranking.csv", "fp7_fusion.csv", "objects.csv"} <= set(after)
    assert sorted(after) == sorted(before)
    differ = [name for name in after if after[name] != before[name]]
    assert differ == []
