"""The report figures of the sweep benchmark (:mod:`experiments.tools.benchmark`): the report of
a finished sweep folder timed (wall, peak resident and proportional memory), and, given a clone
of the repository at an earlier commit, the same folder's report by that code too, alternating
with today's so that both are measured in one run under the same load."""

from __future__ import annotations

import statistics
import subprocess
from pathlib import Path
from typing import Any

from experiments import store
from experiments.host.paths import base_dir
from experiments.tools.timed import timed_report

#: What each code's report is called in the figures' names (``<prefix>_report<infix>_s``).
INFIXES = {"before": "_before", "after": ""}
#: A measured report's values: wall seconds and its processes' peak memory (MB).
MEASURES = {"s": None, "peak_rss_mb": "rss", "peak_pss_mb": "pss"}


def clone_at(commit: str, parent: Path) -> tuple[Path, str]:
    """This repository at ``commit`` in ``parent/before-<commit>``: ``git clone --shared
    --no-checkout`` then ``git checkout -q`` (a clone already there is checked out again);
    (the clone's folder, the full commit)."""
    repo = base_dir()
    sha = subprocess.run(["git", "rev-parse", "--verify", f"{commit}^{{commit}}"], cwd=repo,
                         capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    clone = parent / f"before-{sha[:12]}"
    if not (clone / ".git").is_dir():
        subprocess.run(["git", "clone", "-q", "--shared", "--no-checkout", str(repo), str(clone)],
                       check=True)  # fmt: skip
    subprocess.run(["git", "checkout", "-q", sha], cwd=clone, check=True)
    return clone, sha


def existing_sweep(sweep_dir: Path) -> Path:
    """``sweep_dir`` when it holds run records; else a :class:`FileNotFoundError` naming it (a
    report-only part needs the sweep made before, in the same ``--workdir``)."""
    if not store.list_records(sweep_dir):
        raise FileNotFoundError(f"{sweep_dir} holds no run records: make its sweep first "
                                "(its part, same --workdir)")  # fmt: skip
    return sweep_dir


def report_figures(
    prefix: str, sweep_dir: Path, out: Path, cache: Path, before: Path | None = None,
    rounds: int = 1,
) -> dict[str, Any]:  # fmt: skip
    """Time the report of ``sweep_dir`` (into ``out``; ``cache``: the sweep's stage cache).

    Alone: ``rounds`` reports by today's code. With ``before`` (a checkout, :func:`clone_at`):
    first one untimed report by each code (each derives what it keeps in the sweep folder and
    the cache, as after a sweep of its own), then ``rounds`` times the before report then
    today's (before's into ``out`` + ``-before``).

    Returns
    -------
    dict
        ``<prefix>_report_s``, ``<prefix>_report_peak_rss_mb``, ``<prefix>_report_peak_pss_mb``
        (the medians of the rounds), with ``before`` also ``<prefix>_report_before_s`` /
        ``_before_peak_rss_mb`` / ``_before_peak_pss_mb`` and the ratios today / before
        ``<prefix>_report_over_before`` (wall) and ``<prefix>_report_peak_pss_over_before``;
        ``<prefix>_report_rounds``: every round's values, ``{"before"|"after": [{measure}]}``.
    """
    codes = {"after": None} if before is None else {"before": before, "after": None}
    outs = {"before": out.with_name(out.name + "-before"), "after": out}
    if before is not None:
        for name, code in codes.items():
            timed_report(sweep_dir, outs[name], cache, code=code)
    rounds_done: dict[str, list[dict[str, float]]] = {name: [] for name in codes}
    for _ in range(rounds):
        for name, code in codes.items():
            memory: dict[str, float] = {}
            wall = timed_report(sweep_dir, outs[name], cache, memory, code)
            rounds_done[name].append(
                {k: wall if src is None else memory[src] for k, src in MEASURES.items()}
            )
    figures: dict[str, Any] = {f"{prefix}_report_rounds": rounds_done}
    for name, done in rounds_done.items():
        for measure in MEASURES:
            value = statistics.median(r[measure] for r in done)
            figures[f"{prefix}_report{INFIXES[name]}_{measure}"] = value
    if before is not None:
        figures[f"{prefix}_report_over_before"] = (
            figures[f"{prefix}_report_s"] / figures[f"{prefix}_report_before_s"]
        )
        figures[f"{prefix}_report_peak_pss_over_before"] = (
            figures[f"{prefix}_report_peak_pss_mb"] / figures[f"{prefix}_report_before_peak_pss_mb"]
        )
    return figures
