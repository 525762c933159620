"""The summary's first and last lines, without pandas: printed by the summary
(:mod:`.collect`) and by a finished sweep command recognised before Hydra starts
(:mod:`experiments.sweep.finished`), which must stay light to import."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from pathlib import Path


def count_lines(statuses: Sequence[str], outcomes: Sequence[str] | None) -> list[str]:
    """The summary's count lines: settings by status, and (``outcomes``: this invocation's
    progress markers) how many were computed and how many resumed."""
    counts = Counter(statuses)
    lines = [
        f"settings: {len(statuses)} total, {counts['ok']} ok, {counts['skipped']} skipped, "
        f"{counts['failed']} failed"
    ]
    if outcomes is not None:
        resumed = sum(o == "resumed" for o in outcomes)
        lines.append(
            f"this invocation: {len(outcomes) - resumed} computed, {resumed} already "
            "complete (resumed)"
        )
    return lines


def summary_head(
    sweep_dir: Path, rows: int, statuses: Sequence[str], outcomes: Sequence[str] | None
) -> list[str]:
    """The sweep summary's first lines: where the dataset (``rows`` rows) and the run
    records are, then :func:`count_lines`."""
    from experiments import store  # noqa: PLC0415 (pandas: imported once a sweep exists)

    return [
        f"\nsweep dataset: {Path(sweep_dir) / store.ROWS_GLOB} ({rows} rows; "
        "experiments.store.load_sweep reads it)",
        f"run records:   {Path(sweep_dir) / store.RECORDS_GLOB}",
        *count_lines(statuses, outcomes),
    ]


def nothing_computed_line(sweep_dir: Path) -> str:
    """The summary's last line when nothing was computed (no ranking printed)."""
    return f"\n(nothing computed: `python -m experiments.summary.collect {sweep_dir}` ranks it)"
