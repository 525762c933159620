"""``ttc-bench judge``: public write-ups' TTC numbers (extracts in tests/data/external, their
sources in its README) read in every layout and judged like the harness's own settings; a
copy of a harness setting's TTCs gets that setting's score and rank interval; every bad
input is one message naming the file, line and column, and exit status 2."""

from __future__ import annotations

import csv
import math
import statistics
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from experiments.judge import judge_command
from experiments.judge.harness import committed_side
from experiments.judge.judging import judge, rank_together, read_inputs
from experiments.judge.layouts import read_long
from experiments.report.load import load_sweeps, make_context, reference_for
from tests.conftest import PROJECT_ROOT
from tests.test_report import env_for, make_sweep, shared_root
from ttc import evaluation as ev

EXTERNAL = PROJECT_ROOT / "tests" / "data" / "external"
CEDRIC = EXTERNAL / "cedric_perauer_data.csv"
ANDIA = EXTERNAL / "andia76_overall_results_1.csv"
KEN = EXTERNAL / "ken_power_output_perf_tables.md"
REFERENCE = PROJECT_ROOT / "results" / "kitti_0_18" / "reference.csv"


@pytest.fixture(scope="module")
def side():
    """The committed results of drive 0052 frames 0-18 (the harness's side)."""
    return committed_side("kitti_0_18")


def _reference_ratios() -> dict[int, float]:
    """The reference's distance ratio per frame, from reference.csv by hand: 1 + dt / TTC."""
    ratios = {}
    with REFERENCE.open() as f:
        for row in csv.DictReader(f):
            frame, ttc, dt = int(row["frame"]), row["ttc_ref_s"], row["dt_s"]
            if 1 <= frame <= 18:
                ratios[frame] = 1 + float(dt) / float(ttc)
    return ratios


def _hand_score(ttcs: dict[int, float]) -> tuple[float, float]:
    """(invalid rate, median motion-in-depth error) of one setting's TTCs (frame: s) over
    frames 1-18, by the metric's definition: r = 1 + 0.1 / TTC, MiD = 1e4 |ln r - ln r_ref|;
    a missing frame or non-finite TTC invalid."""
    ref = _reference_ratios()
    valid = {f: t for f, t in ttcs.items() if math.isfinite(t)}
    mids = [1e4 * abs(math.log(1 + 0.1 / t) - math.log(ref[f])) for f, t in valid.items()]
    return (18 - len(valid)) / 18, statistics.median(mids)


def _judged(side, path: Path, name: str, n_boot: int = 50) -> dict[str, pd.DataFrame]:
    external = read_inputs([path], [name], side.first, side.last, side.reference)
    return judge(side, external, n_boot=n_boot)


def _row(ranking: pd.DataFrame, setting: str) -> pd.Series:
    return ranking.set_index("setting").loc[setting]


# --------------------------------------------------------------------------- formats


def test_long_csv_cedric_perauer(side) -> None:
    long = read_long(CEDRIC)
    assert long["setting"].nunique() == 3 and set(long.groupby("setting").size()) == {18}
    ttcs = {}
    with CEDRIC.open() as f:
        for row in csv.DictReader(f):
            if row["Detector Type"] == "FAST" and row["Descriptor Type"] == "ORB":
                ttcs[int(row["Frame # "])] = float(row["Camera TTC"])
    invalid, mid = _hand_score(ttcs)
    got = _row(_judged(side, CEDRIC, "cedric")["camera"], "ext:cedric/fast/orb")
    assert got["camera_invalid_rate"] == invalid == 0
    assert got["camera_mid_median"] == pytest.approx(mid, rel=1e-9)


def test_wide_csv_andia76_and_its_transposes(side, tmp_path: Path) -> None:
    long = read_long(ANDIA)
    assert long["setting"].nunique() == 9 and set(long.groupby("setting").size()) == {19}
    ttcs = {}
    with ANDIA.open() as f:
        for row in csv.DictReader(f):
            frame = int(row["imgFilename"].split(".")[0])
            if frame:
                ttcs[frame] = float(row["ttcCamera [s] (54: AKAZE/AKAZE)"])
    invalid, mid = _hand_score(ttcs)
    judged = _judged(side, ANDIA, "andia")
    got = _row(judged["camera"], "ext:andia/akaze/akaze")
    assert got["camera_invalid_rate"] == pytest.approx(invalid)
    assert got["camera_mid_median"] == pytest.approx(mid, rel=1e-9)
    # a row per setting and a column per frame, as CSV and as a markdown table: same numbers
    wide = long.pivot(index="setting", columns="frame", values="ttc_camera")
    wide.columns = [str(c) for c in wide.columns]
    as_csv = tmp_path / "by_setting.csv"
    wide.rename_axis("setting").reset_index().to_csv(as_csv, index=False)
    cells = wide.rename_axis("setting").reset_index().astype(str)
    as_md = tmp_path / "by_setting.md"
    as_md.write_text("\n".join(["| " + " | ".join(cells.columns) + " |",
                                "|" + "---|" * len(cells.columns),
                                *("| " + " | ".join(r) + " |" for r in cells.to_numpy())]))  # fmt: skip
    for path in (as_csv, as_md):
        again = read_long(path).set_index(["setting", "frame"])["ttc_camera"].sort_index()
        expected = long.set_index(["setting", "frame"])["ttc_camera"].sort_index()
        pd.testing.assert_series_equal(again, expected, check_names=False)


def test_markdown_tables_under_headings_ken_power(side) -> None:
    long = read_long(KEN)
    assert long["setting"].nunique() == 35 and len(long) == 32 * 18 + 3 * 9  # SIFT: 9 frames
    # the write-up's HARRIS/FREAK table shows frame 7 twice (the same numbers) and no frame 8
    ttcs, setting = {}, None
    for line in KEN.read_text().splitlines():
        if line.startswith("## "):
            setting = line
        elif setting and "HARRIS, Descriptor = FREAK" in setting and line[:1].isdigit():
            cells = [c.strip() for c in line.split("|")]
            ttcs[int(cells[0])] = float(cells[3])
    assert sorted(ttcs) == [1, 2, 3, 4, 5, 6, 7, *range(9, 19)]
    invalid, mid = _hand_score(ttcs)
    got = _row(_judged(side, KEN, "ken")["camera"], "ext:ken/harris/freak")
    assert got["camera_invalid_rate"] == pytest.approx(invalid) and invalid == pytest.approx(
        11 / 18
    )
    assert got["camera_mid_median"] == pytest.approx(mid, rel=1e-9)


def test_long_parquet_reads_as_its_csv(tmp_path: Path) -> None:
    long = read_long(CEDRIC)
    path = tmp_path / "long.parquet"
    long.drop(columns="line").to_parquet(path)
    again = read_long(path)
    pd.testing.assert_frame_equal(again.drop(columns="line"), long.drop(columns="line"))


def test_committed_side_reproduces_the_committed_ranking(side) -> None:
    """The harness's side read back from results/kitti_0_18's CSVs ranks its 140 settings as
    the report did (its six-digit numbers move a median error by < 1e-3)."""
    empty = side.rows["camera"].iloc[:0].assign(ttc_camera=float("nan"))
    again = rank_together(
        side.rows["camera"], empty, side.reference, "camera", side.labels["camera"], 50
    )
    committed = pd.read_csv(PROJECT_ROOT / "results" / "kitti_0_18" / "fp6_ranking.csv")
    both = again.merge(committed, on="setting", suffixes=("", "_committed"))
    assert len(both) == len(committed) == 140
    assert (both["rank"] == both["rank_committed"]).all()
    assert (both["camera_mid_median"] - both["camera_mid_median_committed"]).abs().max() < 1e-3
    assert (both["camera_invalid_rate"] - both["camera_invalid_rate_committed"]).abs().max() < 1e-6


# --------------------------------------------------------------------------- beside a sweep


@pytest.fixture(scope="module")
def small_sweeps(tmp_path_factory) -> tuple[Path, Path, Path]:
    """Three Shi-Tomasi settings on frames 0-18, and the same without BRIEF: (root, both)."""
    root = shared_root(tmp_path_factory)
    three = make_sweep(root, ["-m", "detector=shitomasi", "descriptor=brief,orb,freak",
                              "sweep_name=judge_three"], "judge_three")  # fmt: skip
    two = make_sweep(root, ["-m", "detector=shitomasi", "descriptor=orb,freak",
                            "sweep_name=judge_two"], "judge_two")  # fmt: skip
    return root, three, two


@pytest.mark.slow  # two sweeps of frames 0-18 in subprocesses (≈ 80 s on 2 cores)
def test_copy_of_a_harness_setting_gets_its_score_and_interval(small_sweeps, tmp_path) -> None:
    root, three, two = small_sweeps
    data = load_sweeps([three])
    reference = reference_for(data, make_context(cache_dir=root / "cache"))
    table = ev.camera_frame_table(data.frames, data.runs, reference)
    own = ev.camera_ranking(data.frames, table, reference).set_index("setting")  # the report's
    brief = table[table["descriptor"] == "brief"]
    assert len(brief) == 18 and brief["ttc_camera"].map(math.isfinite).all()
    copy = tmp_path / "copy.csv"
    brief.assign(setting="brief_copy")[["setting", "frame", "ttc_camera"]].to_csv(
        copy, index=False, float_format="%.17g"
    )
    out = tmp_path / "judged"
    done = subprocess.run(
        [sys.executable, "-m", "experiments.cli", "judge", str(copy), "dataset=kitti_0_18",
         "--with", str(two), "--name", "me", "--out", str(out), "--cache-dir", str(root / "cache")],
        cwd=PROJECT_ROOT, env=env_for(root), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    ranking = pd.read_csv(out / "judge_camera_ranking.csv").set_index("setting")
    assert len(ranking) == 3 and ranking["external"].sum() == 1  # beside the sweep's two
    got, want = ranking.loc["ext:me/brief_copy"], own.loc[brief["setting"].iloc[0]]
    for col in ("camera_invalid_rate", "camera_mid_median", "camera_mid_median_lo",
                "camera_mid_median_hi", "camera_medae_rel"):  # fmt: skip
        assert got[col] == pytest.approx(want[col], rel=1e-5), col  # the CSV: 6 digits
    assert (got["rank"], got["rank_lo"], got["rank_hi"]) == (
        want["rank"], want["rank_lo"], want["rank_hi"])  # fmt: skip
    assert (out / "judge.md").is_file() and (out / "judge_camera_series.png").stat().st_size > 0
    assert "ext:me/brief_copy" in (out / "html" / "judge.html").read_text()


# --------------------------------------------------------------------------- bad input


BAD = {
    "misnamed column": ("setting,frame,ttc_cam\nfast/brief,1,12.0\n",
                        "line 1, column 'ttc_camera/ttc_lidar': no such column"),
    "text for a number": ("setting,frame,ttc_camera\nfast/brief,1,12.0\nfast/brief,2,abc\n",
                          "line 3, column 'ttc_camera': text where a number (a TTC in seconds) "
                          "belongs: 'abc'"),
    "frame outside": ("setting,frame,ttc_camera\nfast/brief,1,12.0\nfast/brief,40,11.0\n",
                      "line 3, column 'frame': frame 40 is outside the recording"),
    "setting and frame twice": ("setting,frame,ttc_camera\nfast/brief,2,12.0\n"
                                "fast/brief,2,11.0\n", "line 3, column 'frame': setting "
                                "'fast/brief' has frame 2 twice (first on line 2)"),
    "TTC on frame 0": ("setting,frame,ttc_camera\nfast/brief,0,12.0\n",
                       "line 2, column 'frame': frame 0 has a TTC but no frame pair ends"),
    "empty file": ("\n  \n", ": the file is empty"),
    "binary file": (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", ": not a text file (binary content)"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_one_message_and_status_2(case, tmp_path: Path, capsys) -> None:
    content, message = BAD[case]
    path = tmp_path / "numbers.csv"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(SystemExit) as exit_:
        judge_command.main([str(path), "dataset=kitti_0_18", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert exit_.value.code == judge_command.BAD_INPUT
    assert err.startswith(f"ttc-bench judge: {path}") and message in err
    assert err.count("\n") == 1 and not (tmp_path / "out").exists()


def test_bad_input_through_the_command_has_no_traceback(tmp_path: Path) -> None:
    path = tmp_path / "numbers.csv"
    path.write_text("setting,frame,ttc_camera\nfast/brief,1,twelve\n")
    done = subprocess.run([sys.executable, "-m", "experiments.cli", "judge", str(path)],
                          cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr == (f"ttc-bench judge: {path}, line 2, column 'ttc_camera': text where a "
                           "number (a TTC in seconds) belongs: 'twelve'\n")  # fmt: skip


def test_previous_frame_convention_only_when_asked(tmp_path: Path, side) -> None:
    path = tmp_path / "zero_based.csv"
    path.write_text("setting,frame,ttc_camera\n" + "".join(
        f"a/b,{f},{12.0 - 0.1 * f}\n" for f in range(18)))  # fmt: skip
    external = read_inputs([path], ["z"], side.first, side.last, side.reference, "previous")
    assert sorted(external.rows["frame"]) == list(range(1, 19))


def test_minus_inf_is_invalid_unless_read_as_ratio_one(tmp_path: Path, side) -> None:
    """ken-power's Shi-Tomasi/BRISK prints -inf on frames 6, 7, 8 and 10: invalid by default,
    a ratio of exactly 1 (no scale change) with the option."""
    plain = read_inputs([KEN], ["ken"], side.first, side.last, side.reference).rows
    as_one = read_inputs([KEN], ["ken"], side.first, side.last, side.reference, "current", True)
    for rows, expected in ((plain, float("nan")), (as_one.rows, 1.0)):
        own = rows[rows["run_id"] == "ext:ken/shi_tomasi/brisk"].set_index("frame")
        assert own.loc[[6, 7, 8, 10], "ttc_camera"].tolist() == [float("-inf")] * 4
        assert own.loc[[6, 7, 8, 10], "camera_ratio"].tolist() == pytest.approx(
            [expected] * 4, nan_ok=True
        )
        assert own.loc[1, "camera_ratio"] == pytest.approx(1 + 0.1 / 14.1119)


def test_with_a_folder_that_is_no_sweep_is_one_message(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        judge_command.main([str(CEDRIC), "--with", str(tmp_path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert exit_.value.code == judge_command.BAD_INPUT
    assert err == f"ttc-bench judge: {tmp_path}: no runs/ folder: not a sweep folder\n"
