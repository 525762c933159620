"""Print a sweep's summary: counts, failures, best settings (also for interrupted sweeps).

Usage::

    python -m experiments.summary.collect sweeps/fp6_grid_kitti_0_18
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from experiments import store
from experiments.host.heap import long_lived
from experiments.host.paths import shown
from experiments.store import progress
from experiments.summary.head import nothing_computed_line, summary_head
from experiments.summary.kept_ranking import kept_ranking
from experiments.summary.lead_rows import LeadRows
from ttc.atomic import remove_stale_temporaries
from ttc.settings import SETTING_AXES, only_sensor_axes

SETTING_COLUMNS = list(SETTING_AXES)


#: The record fields the summary reads (the runs table of 47,040 records: 1.3 s with every
#: field, 0.6 s with these).
SUMMARY_FIELDS = ("run_id", "status", "message", "n_frame_errors", "config", *SETTING_AXES)
#: Settings listed by the summary's second table (the fused ranking of a sweep ranked on
#: another sensor).
FUSED_SHOWN = 3
#: Axes that change only the lidar TTC: a sweep varying nothing else is ranked on the lidar.
LIDAR_ONLY_AXES = only_sensor_axes("lidar")
#: The axis that changes only the fused TTC.
(FUSION_AXIS,) = only_sensor_axes("fused")


def ranked_sensor(runs: pd.DataFrame) -> str:
    """The sensor a sweep's summary ranks on: ``fused`` when the fusion varies along with
    lidar-only axes at most (e.g. ``+experiment=fusion``), ``lidar`` when only lidar-only
    axes vary (e.g. ``fp5_lidar``), else ``camera``."""
    varying = {a for a in SETTING_AXES if a in runs and runs[a].nunique(dropna=False) > 1}
    if FUSION_AXIS in varying and varying <= {FUSION_AXIS, *LIDAR_ONLY_AXES}:
        return "fused"
    return "lidar" if varying and varying <= set(LIDAR_ONLY_AXES) else "camera"


def ranked_runs(frames: pd.DataFrame, reference: pd.DataFrame, sensor: str) -> pd.DataFrame:
    """Runs ranked on ``sensor`` by :data:`ttc.evaluation.RANKING_RULE` against ``reference``
    (rates are fractions, MiD in 10⁻⁴ of the log distance ratio, time in ms)."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    return _ranking(ev.run_metrics(frames, reference), sensor)


def _ranking(metrics: pd.DataFrame, sensor: str) -> pd.DataFrame:
    """:func:`ttc.evaluation.rank_runs` of ``metrics`` on ``sensor``, the summary's columns."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    ranked = ev.rank_runs(metrics, sensor)
    columns = [*summary_columns(sensor), "ms_per_frame"]
    return ranked[[c for c in columns if c in ranked]]


def summary_columns(sensor: str) -> list[str]:
    """The columns the summary shows of a ranking on ``sensor``: rank, run, axes, the ranking
    keys, outlier rate, median relative error, frames."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    keys = [f"{sensor}_{k}" for k in ev.RANKING_KEYS]
    return ["rank", "run_id", *SETTING_COLUMNS, *keys, f"{sensor}_outlier_rate",
            f"{sensor}_medae_rel", "n_frames"]  # fmt: skip


def sweep_references(
    frames: pd.DataFrame, runs: pd.DataFrame, data_dir: Path | None, cache_dir: Path | None
) -> dict[str, pd.DataFrame] | None:
    """What the ok runs of each recording are judged against
    (:func:`experiments.summary.references.recording_references`), or None (with the reason
    printed) when it cannot be built, e.g. the data root is gone."""
    from experiments.summary.references import recording_references  # noqa: PLC0415 (SciPy)
    from ttc.engine.cache import StageCache  # noqa: PLC0415

    cache = StageCache(cache_dir) if cache_dir else None
    try:
        return recording_references(frames, runs[runs["status"] == "ok"], data_dir, cache)
    except (OSError, ValueError) as exc:
        print(f"(no ranking: no reference TTC to judge against: {exc})")
        return None


def pooled_runs(
    frames: pd.DataFrame, runs: pd.DataFrame, references: dict[str, pd.DataFrame], sensor: str
) -> pd.DataFrame:
    """The settings of a sweep over several recordings ranked on ``sensor`` pooled over them
    (:func:`ttc.evaluation.drive_rankings`, each run against its own recording's reference;
    no bootstrap intervals: the report's ``drives.md`` has them); ``run_id`` is the setting
    id shared by its runs on every recording."""
    from experiments.data.datasets import recording_id  # noqa: PLC0415
    from experiments.summary.recordings import runs_drive_rankings  # noqa: PLC0415
    from ttc import evaluation as ev  # noqa: PLC0415

    named = {recording_id(sequence): ref for sequence, ref in references.items()}
    table = runs_drive_rankings(frames, runs, named, sensor, n_boot=0)
    pooled = table[table["drive"] == ev.POOLED]
    columns = summary_columns(sensor)
    return pooled[[c for c in columns if c in pooled]].sort_values("rank", ignore_index=True)


def summarise_sweep(
    sweep_dir: Path,
    top: int = 5,
    data_dir: Path | None = None,
    cache_dir: Path | None = None,
    unchanged: bool = False,
) -> pd.DataFrame:
    """Summarise the sweep: print where the dataset is, the run counts, the failures and the
    best settings: ranked against the reference TTC by :mod:`ttc.evaluation`'s rule (no
    ranking, with the reason, when no reference can be built; a ranking that raises is
    reported in one line: the stored data stands). :class:`store.StoreError` names a missing
    or corrupt rows file. ``data_dir`` / ``cache_dir``: None for the configured defaults.

    Nothing is merged or written (the store is append-only); temporary files of killed jobs
    are removed. Only the lead rows are read (the ranking's rows), so a sweep of millions of
    rows is summarised without loading it whole; each fragment's lead rows and, on a real
    drive, its runs' metrics are kept by the first summary that reads it
    (:mod:`experiments.summary.lead_rows`, :mod:`experiments.summary.run_metrics`), so a later summary
    judges only the new runs; the ranking keys are kept too
    (:mod:`experiments.summary.kept_ranking`): only the ``top`` best runs' metrics are read.
    Returns the first table printed, in full (of a sweep on one real recording: its ``top``
    rows). ``unchanged=True`` (nothing was computed): counts only, no ranking (it would be the
    one printed before)."""
    sweep_dir = Path(sweep_dir)
    remove_stale_temporaries(sweep_dir / store.RUNS_DIR)  # left by killed jobs
    with long_lived(collect=False) as keep:
        records = store.list_records(sweep_dir)
        keep()  # the records live to the end: out of the collector's passes
        read = [{k: r[k] for k in SUMMARY_FIELDS if k in r} for r in records]
        runs = store.runs_table(read, texts=("config",))  # configs only parsed: Python strings
        n_rows = store.row_count(records)
        folder = progress.progress_dir(sweep_dir)
        outcomes = progress.progress_outcomes(folder) if folder.is_dir() else None
        statuses = [] if runs.empty else runs["status"].astype(str).tolist()
        print("\n".join(summary_head(sweep_dir, n_rows, statuses, outcomes)))
        for _, run in runs[runs["status"] == "failed"].iterrows() if not runs.empty else []:
            print(f"  failed {run['run_id']}: {run['message']}")
        if "n_frame_errors" in runs:
            for _, run in runs[runs["n_frame_errors"].fillna(0) > 0].iterrows():
                print(f"  frame errors in {run['run_id']} (retried when the input changes): "
                      f"{run['message']}")  # fmt: skip
        if unchanged:
            print(nothing_computed_line(sweep_dir))
            return pd.DataFrame()
        lead = LeadRows(sweep_dir, records) if n_rows else None
        if lead is None or not lead.keys:
            return pd.DataFrame()
        frames = _truth_rows(lead)
        try:
            tables = _best(lead, frames, runs, data_dir, cache_dir, top)
        except Exception as exc:  # the rows stand; the ranking is the report's job
            print(f"\n(no ranking: {type(exc).__name__}: {exc})")
            return pd.DataFrame()
        if not tables:
            return pd.DataFrame()
        with pd.option_context("display.width", 200, "display.max_columns", 20):
            for n, (scores, title) in zip((top, FUSED_SHOWN), tables, strict=False):
                print(f"\nbest {n} settings {title}:")
                print(scores.head(n).to_string(index=False, float_format="%.3g"))
        name = sweep_dir.name
        print(f"\nreports ({report_contents(frames, runs)}):\n"
              f"  python -m experiments.report {shown(sweep_dir)} --out reports/{name}")  # fmt: skip
        return tables[0][0]


def report_contents(frames: pd.DataFrame, runs: pd.DataFrame) -> str:
    """What ``experiments.report`` writes for this sweep, in a few words."""
    from experiments.summary.recordings import REPORT_CONTENTS, report_kind  # noqa: PLC0415
    from ttc.evaluation.fused_diagnosis import fused_runs  # noqa: PLC0415 (SciPy)

    fused = ", FP.7 fused TTC" if not fused_runs(runs[runs["status"] == "ok"]).empty else ""
    return REPORT_CONTENTS[report_kind(frames, runs)].format(fused=fused)


def _may_carry_truth(lead: LeadRows) -> bool:
    """Whether the sweep's rows have a truth column (a generated recording's,
    :func:`ttc.evaluation.has_truth`): a real drive's rows have none."""
    return "ttc_true" in lead.schema.names


def _truth_rows(lead: LeadRows) -> pd.DataFrame:
    """What :func:`experiments.summary.recordings.report_kind` and the references read of the lead
    rows to tell a generated recording (a truth): every column when the sweep's rows carry
    one, else none (an empty ``run_id`` column: all they need of a real drive's rows is that
    they carry no truth, which the schema says; reading a ``grand`` re-run's 640,000 run ids
    took 0.15 s)."""
    if _may_carry_truth(lead):
        return lead.frame()
    return pd.DataFrame({"run_id": pd.Series([], dtype=object)})


def _ranked(
    lead: LeadRows,
    runs: pd.DataFrame,
    references: dict[str, pd.DataFrame],
    sensor: str,
    top: int,
) -> pd.DataFrame:
    """The runs ranked on ``sensor``: against a real drive's reference its ``top`` best from
    the kept ranking (:mod:`experiments.summary.kept_ranking`), else every run from the rows
    (:func:`_unkept`)."""
    if len(references) > 1 or _may_carry_truth(lead):
        return _unkept(lead.frame(), runs, references, sensor)
    return _ranking(kept_ranking(lead, next(iter(references.values())), sensor, top)[1], sensor)


def _best(
    lead: LeadRows, frames: pd.DataFrame, runs: pd.DataFrame, data_dir, cache_dir, top: int
) -> list[tuple]:
    """[(ranked settings, title)] by :data:`ttc.evaluation.RANKING_RULE`: against the
    reference (pooled over the recordings of a sweep over several), none when no reference
    can be built; when the sweep is ranked on another sensor and holds runs with a fusion,
    also those runs ranked on the fused TTC. ``frames``: :func:`_truth_rows` of ``lead``;
    ``top``: the settings listed (of a sweep on one real recording, the only ones ranked
    in full: :func:`_ranked`)."""
    from experiments.summary.recordings import report_kind  # noqa: PLC0415
    from ttc.evaluation.fused_diagnosis import fused_runs  # noqa: PLC0415 (SciPy)

    references = sweep_references(frames, runs, data_dir, cache_dir)
    if not references:
        return []
    ok = runs[runs["status"] == "ok"]
    sensor = ranked_sensor(ok)
    against = {
        "truth": "the exact truth",
        "drives": f"its recording's reference, pooled over {len(references)} recordings",
        "recording": "the reference",
    }[report_kind(frames, runs)]
    rule = "(ttc.evaluation.RANKING_RULE)"
    tables = [(_ranked(lead, runs, references, sensor, top),
               f"on the {sensor} TTC against {against} {rule}")]  # fmt: skip
    fused = fused_runs(ok)
    if sensor != "fused" and not fused.empty:  # ms_compute over the fused runs' rows alone
        frames = lead.frame()
        mine = frames[frames["run_id"].isin(set(fused["run_id"]))]
        tables.append((_unkept(mine, fused, references, "fused"),
                       f"with a fusion, on the fused TTC {rule} (FP.7: the report's "
                       "fp7_fusion.md)"))  # fmt: skip
    return tables


def _unkept(
    frames: pd.DataFrame, runs: pd.DataFrame, references: dict[str, pd.DataFrame], sensor: str
) -> pd.DataFrame:
    """The runs of ``frames`` ranked on ``sensor`` from the rows themselves (a subset of the
    sweep: its computing times are counted over its own rows)."""
    if len(references) > 1:
        return pooled_runs(frames, runs, references, sensor)
    return ranked_runs(frames, next(iter(references.values())), sensor)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep_dir", type=Path, help="the sweep folder (hydra.sweep.dir)")
    parser.add_argument("--top", type=int, default=5, help="how many settings to list")
    args = parser.parse_args(argv)
    if not (args.sweep_dir / store.RUNS_DIR).is_dir():
        parser.error(f"{args.sweep_dir} has no {store.RUNS_DIR}/ folder: not a sweep folder")
    try:
        summarise_sweep(args.sweep_dir, args.top)
    except store.StoreError as exc:
        parser.exit(1, f"collect failed: {exc}\n(re-run the sweep to recompute that run)\n")


if __name__ == "__main__":
    main()
