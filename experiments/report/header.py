"""The provenance header every report page starts with: sweeps, code version of the runs and
of the report, command lines, axes, config, dates, machines and package versions."""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Iterable
from typing import Any

import pandas as pd

from experiments.host.paths import shown
from experiments.host.provenance import code_version, machine, package_versions
from experiments.report.load import SweepData
from experiments.store.flat_configs import config_table
from ttc.settings import AXES


def _unique(values: Iterable[Any]) -> str:
    distinct = pd.unique(pd.Series(values if isinstance(values, pd.Series) else list(values)))
    return ", ".join(sorted({str(v) for v in distinct if v is not None and v == v})) or "n/a"


def _common_config(configs: pd.Series) -> tuple[dict[str, Any], list[str]]:
    """Keys (dotted) with one value (JSON text) in every run's config, and the keys that vary
    (:func:`experiments.store.flat_configs.config_table`: each config parsed once per report)."""
    flat = config_table(configs.dropna())
    if flat.empty:
        return {}, []
    first = flat.iloc[0]
    same = flat.eq(first).all()  # NaN (a config without the key) equals nothing
    common = {key: json.loads(first[key]) for key in flat.columns[same.to_numpy()]}
    return common, sorted(set(flat.columns) - common.keys())


#: The last header's data and lines (a report writes the same header on every page).
_LAST: list[tuple[SweepData, list[str]]] = []


def _sweeps_cell(data: SweepData) -> str:
    """Each sweep's run counts by status (and the runs dropped as repeated)."""
    counts = data.runs.groupby("sweep_id")["status"].value_counts().unstack(fill_value=0)
    sweeps = "; ".join(
        f"`{s}` ({', '.join(f'{n} {k}' for k, n in row.items() if n)})"
        for s, row in counts.iterrows()
    )
    if data.repeated:
        sweeps += f" ({data.repeated} runs also in an earlier sweep counted there)"
    return sweeps


def provenance_markdown(data: SweepData, title: str) -> str:
    """The provenance header (markdown) of a report page titled ``title``."""
    if not _LAST or _LAST[0][0] is not data:
        _LAST[:] = [(data, _provenance_lines(data))]
    return "\n".join([f"# {title}", *_LAST[0][1]])


def _provenance_lines(data: SweepData) -> list[str]:
    """The lines of :func:`provenance_markdown` after its title."""
    runs = data.runs
    commits = runs.groupby(["git_commit", "git_dirty"], dropna=False).size()
    code = "; ".join(f"`{c}` dirty={d} ({n} runs)" for (c, d), n in commits.items())
    now = code_version()
    versions = [c for c in runs.columns if c.startswith("version_")]
    pkgs = ", ".join(f"{c.removeprefix('version_')} {_unique(runs[c])}" for c in versions)
    here = machine()
    common, varying = _common_config(runs["config"])
    groups = pd.Series(varying, dtype=str).str.split(".").str[0].value_counts().sort_index()
    varying_text = ", ".join(f"{g}.* ({n})" for g, n in groups.items()) or "none"
    axes = "; ".join(f"{a}: {_unique(runs[a])}" for a in AXES if a in runs)
    overrides = "; ".join(
        f"`{s}`: {' '.join(o) or '(defaults)'}" for s, o in data.overrides.items()
    )
    lines = [
        "",
        "| provenance | |",
        "|---|---|",
        f"| sweeps | {_sweeps_cell(data)} |",
        f"| sweep folders | {', '.join(f'`{shown(d)}`' for d in data.dirs)} |",
        f"| code version (runs) | {code} |",
        f"| code version (report) | `{now['git_commit']}` dirty={now['git_dirty']} |",
        f"| sweep command-line | {overrides} |",
        f"| axes | {axes} |",
        f"| config keys that vary | {varying_text} |",
        f"| runs from / to | {_unique([runs['start'].min()])} / {_unique([runs['end'].max()])} |",
        f"| report date | {dt.datetime.now(dt.UTC).isoformat(timespec='seconds')} |",
        f"| machine (runs) | {_unique(runs['host'])}, {_unique(runs['platform'])}, "
        f"{_unique(runs['cpu_count'])} cores |",
        f"| machine (report) | {here['host']}, {here['platform']}, {here['cpu_count']} cores |",
        f"| package versions (runs) | {pkgs} |",
        f"| package versions (report) | "
        f"{', '.join(f'{k} {v}' for k, v in package_versions().items())} |",
        "",
        "<details><summary>config shared by every run</summary>",
        "",
        "```json",
        json.dumps(common, indent=1, sort_keys=True),
        "```",
        "</details>",
        "",
    ]
    return lines
