"""``ttc-bench judge FILE... dataset=kitti_0_18 [--name NAME] [--out DIR] [--with SWEEP]``:
another implementation's TTC numbers judged like the harness's own settings and ranked with
them. A file that cannot be read gets one line naming the file, line and column (exit 2)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

from experiments import store
from experiments.judge.harness import (
    RESULTS_DIR,
    HarnessSide,
    committed_side,
    dataset_range,
    sweep_side,
)
from experiments.judge.judging import judge, read_inputs
from experiments.judge.readers import InputError
from experiments.judge.report import write_judge_report
from ttc.evaluation.external import FRAME_CONVENTIONS

#: Exit status of a command whose input cannot be judged.
BAD_INPUT = 2


def parser() -> argparse.ArgumentParser:
    """The command-line options."""
    p = argparse.ArgumentParser(
        prog="ttc-bench judge",
        description="Judge TTC numbers of another implementation (long CSV/parquet, wide "
        "FP.6 CSV or markdown tables) against the recording's reference, ranked with the "
        "harness's settings (docs/judge.md).",
    )
    p.add_argument("inputs", nargs="+", help="files, and dataset=NAME (default kitti_0_18)")
    p.add_argument("--name", default=None, help="name of the external implementation "
                   "(default: each file's stem)")  # fmt: skip
    p.add_argument(
        "--out", type=Path, default=None, help="report folder (default reports/judge_<name>)"
    )
    p.add_argument("--with", dest="sweep", type=Path, default=None,
                   help="rank beside this sweep's settings (default: the committed results "
                   "of the dataset, results/<dataset>)")  # fmt: skip
    p.add_argument("--frame-convention", choices=FRAME_CONVENTIONS, default="current",
                   help="what a file's frame numbers name: the pair's current frame (default) "
                   "or its previous frame")  # fmt: skip
    p.add_argument("--first-frame-is-pair-0", action="store_true",
                   help="the same as --frame-convention=previous")  # fmt: skip
    p.add_argument("--minus-inf-is-ratio-one", action="store_true",
                   help="read -inf as a distance ratio of exactly 1 (the C++ starter's TTC for "
                   "no scale change), not as an invalid estimate")  # fmt: skip
    p.add_argument("--results-dir", type=Path, default=None, help="committed reports' folder")
    p.add_argument("--data-dir", type=Path, default=None, help="data root (with --with)")
    p.add_argument("--cache-dir", type=Path, default=None, help="stage cache (with --with)")
    p.add_argument("--n-boot", type=int, default=None, help=argparse.SUPPRESS)
    return p


def _split(inputs: list[str]) -> tuple[list[Path], str]:
    """The files and the dataset name of the positional arguments."""
    files, dataset = [], "kitti_0_18"
    for arg in inputs:
        if arg.startswith("dataset=") and not Path(arg).exists():
            dataset = arg.split("=", 1)[1]
        else:
            files.append(Path(arg))
    return files, dataset


def harness_side(args: argparse.Namespace, dataset: str) -> HarnessSide:
    """The harness's settings and reference the external ones are ranked with."""
    if args.sweep is not None:
        return sweep_side(args.sweep, args.data_dir, args.cache_dir)
    return committed_side(dataset, args.results_dir or RESULTS_DIR)


def main(argv: list[str] | None = None) -> None:
    """Run the command (``argv``: the arguments, default ``sys.argv[1:]``)."""
    matplotlib.use("Agg")
    args = parser().parse_args(argv)
    files, dataset = _split(args.inputs)
    if not files:
        parser().error("no file to judge")
    names = [args.name or f.stem for f in files]
    convention = "previous" if args.first_frame_is_pair_0 else args.frame_convention
    try:
        first, last = dataset_range(dataset)
        side = harness_side(args, dataset)
        last = side.last if last < 0 else min(last, side.last)
        external = read_inputs(files, names, max(first, side.first), last, side.reference,
                               convention, args.minus_inf_is_ratio_one)  # fmt: skip
    except (InputError, ValueError, FileNotFoundError, store.StoreError) as exc:
        print(f"ttc-bench judge: {exc}", file=sys.stderr)
        sys.exit(BAD_INPUT)
    kwargs = {"n_boot": args.n_boot} if args.n_boot else {}
    rankings = judge(side, external, **kwargs)
    if not rankings:
        print("ttc-bench judge: no estimate of a sensor the harness side has", file=sys.stderr)
        sys.exit(BAD_INPUT)
    out = args.out or Path("reports") / f"judge_{names[0]}"
    written = write_judge_report(side, external, rankings, out)
    for sensor, ranking in rankings.items():
        ext = ranking[ranking["external"]].sort_values("rank")
        for _, row in ext.iterrows():
            print(f"{sensor}: {row['setting']}: rank {row['rank']:.0f} "
                  f"({row['rank_lo']:.0f}-{row['rank_hi']:.0f}) of {len(ranking)}")  # fmt: skip
    print(f"report: {written[0]}")
