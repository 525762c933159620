"""Two sweeps side by side: each setting's metrics in both, better / worse / same beyond the
bootstrap intervals (:func:`ttc.evaluation.compare_runs`).

Usage::

    python -m experiments.tools.compare sweeps/fp6_grid_kitti_0_18 sweeps/fp6_grid_new --out cmp.md
    python -m experiments.tools.compare SWEEP_A SWEEP_B --sensor lidar --ignore dataset

Settings are matched on the axis columns both sweeps have (``--ignore AXIS`` drops one, e.g.
``dataset`` to compare frames 0–18 with 0–77). The verdict is B relative to A: ``better``
when B's 90 % bootstrap interval of the outlier rate lies entirely below A's (or, when those
overlap, the same for the median relative error), ``worse`` the other way, ``same`` otherwise.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from experiments.host.paths import shown
from experiments.report.encode import markdown_table, write_text
from experiments.report.header import provenance_markdown
from experiments.report.load import Context, SweepData, load_sweeps, make_context, reference_for
from ttc import evaluation as ev
from ttc.settings import AXES

#: Columns of the comparison shown in the markdown (per sensor ``s``), besides the key.
SHOWN = ("rank_a", "rank_b", "{s}_outlier_rate_a", "{s}_outlier_rate_b",
         "{s}_medae_rel_a", "{s}_medae_rel_b", "{s}_medae_rel_change", "verdict")  # fmt: skip


@dataclass
class SweepMetrics:
    """One sweep's data, per-run metrics and bootstrap intervals against the reference."""

    data: SweepData
    metrics: pd.DataFrame
    intervals: pd.DataFrame


def sweep_metrics(
    sweep_dir: Path, ctx: Context, sensor: str, n_boot: int = ev.N_BOOT
) -> SweepMetrics:
    """Metrics and bootstrap intervals of every ok run of a sweep (sensor: camera / lidar)."""
    data = load_sweeps([sweep_dir])
    if data.frames.empty:
        raise ValueError(f"{sweep_dir} has no ok run")
    reference = reference_for(data, ctx)
    table = ev.run_metrics(data.frames, reference)
    intervals = ev.bootstrap_rank_intervals(
        data.frames, reference, n_boot=n_boot, seed=0, sensor=sensor
    )
    return SweepMetrics(data, table, intervals)


def match_key(a: pd.DataFrame, b: pd.DataFrame, ignore: list[str]) -> list[str]:
    """Axis columns both metric tables have, minus ``ignore``."""
    unknown = sorted(set(ignore) - set(AXES))
    if unknown:
        raise ValueError(f"--ignore {unknown}: not an axis ({', '.join(AXES)})")
    return [x for x in AXES if x in a and x in b and x not in ignore]


def check_unique(table: pd.DataFrame, key: list[str], name: str) -> None:
    """Raise a clear error when ``key`` does not identify the runs of ``table``."""
    duplicated = table.duplicated(key, keep=False)
    if duplicated.any():
        raise ValueError(
            f"sweep {name}: {int(duplicated.sum())} runs share their {', '.join(key)} values; "
            "do not --ignore an axis that varies inside a sweep"
        )


def compare_sweeps(
    a: SweepMetrics, b: SweepMetrics, sensor: str = "camera", ignore: list[str] | None = None
) -> pd.DataFrame:
    """Settings present in both sweeps with both metric sets, changes and verdicts (B vs A)."""
    key = match_key(a.metrics, b.metrics, ignore or [])
    check_unique(a.metrics, key, "A")
    check_unique(b.metrics, key, "B")
    table = ev.compare_runs(a.metrics, b.metrics, a.intervals, b.intervals, key, sensor)
    if table.empty:
        raise ValueError(
            "no setting of A matches one of B on " + ", ".join(key)
            + "; --ignore the axes whose values differ between the sweeps (e.g. dataset)"
        )  # fmt: skip
    varying = [k for k in key if table[k].nunique() > 1] or key[:2]
    table.insert(0, "setting", ev.setting_labels(table, varying))
    order = {"worse": 0, "better": 1, "same": 2}
    return table.sort_values(
        ["verdict", "setting"], key=lambda c: c.map(order) if c.name == "verdict" else c
    ).reset_index(drop=True)


def compare_markdown(table: pd.DataFrame, a: SweepMetrics, b: SweepMetrics, sensor: str) -> str:
    """The comparison as markdown: provenance of both sweeps, verdict counts, the table."""
    both = SweepData(
        a.data.dirs + b.data.dirs,
        a.data.frames.iloc[:0],
        pd.concat([a.data.runs, b.data.runs], ignore_index=True),
        {**a.data.overrides, **b.data.overrides},
    )
    counts = table["verdict"].value_counts()
    columns = ["setting", *[c.format(s=sensor) for c in SHOWN]]
    lines = [
        provenance_markdown(both, f"Sweep comparison ({sensor} TTC): B vs A"),
        f"A = `{shown(a.data.dirs[0])}`, B = `{shown(b.data.dirs[0])}`; "
        f"{len(table)} settings in both "
        f"(A has {len(a.metrics)}, B has {len(b.metrics)} ok runs).",
        "",
        "Verdict of B against A beyond the 90 % paired-bootstrap intervals: the outlier rate "
        "first, the median relative error when those overlap (`ttc.evaluation.ev.compare_runs`). "
        f"**{counts.get('better', 0)} better, {counts.get('worse', 0)} worse, "
        f"{counts.get('same', 0)} same.**",
        "",
        markdown_table(table[columns]),
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep_a", type=Path, help="sweep folder A (the baseline)")
    parser.add_argument("sweep_b", type=Path, help="sweep folder B (judged against A)")
    parser.add_argument("--out", type=Path, default=None, help="markdown file (default: stdout)")
    parser.add_argument("--sensor", choices=ev.SENSORS, default="camera")
    parser.add_argument(
        "--ignore",
        action="append",
        default=[],
        metavar="AXIS",
        help="an axis not to match on (repeatable), e.g. dataset",
    )
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--cache-dir", type=Path, default=None)
    args = parser.parse_args(argv)  # fmt: skip
    for d in (args.sweep_a, args.sweep_b):
        if not d.is_dir():
            parser.error(f"{d} is not a folder")
    ctx = make_context(args.data_dir, args.cache_dir)
    try:
        a = sweep_metrics(args.sweep_a, ctx, args.sensor)
        b = sweep_metrics(args.sweep_b, ctx, args.sensor)
        table = compare_sweeps(a, b, args.sensor, args.ignore)
    except ValueError as exc:
        sys.exit(f"compare: {exc}")
    text = compare_markdown(table, a, b, args.sensor)
    if args.out is None:
        print(text)
        return
    write_text(text, args.out)
    print(f"comparison: {args.out} ({table['verdict'].value_counts().to_dict()})")


if __name__ == "__main__":
    main()
