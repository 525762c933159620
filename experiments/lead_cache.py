"""The end-of-sweep summary's per-fragment results, kept in ``<sweep>/.summary/``: each rows
fragment's lead rows and its runs' metrics against a reference.

The summary ranks every run of a sweep by its metrics (:func:`ttc.evaluation.run_metrics`)
on its lead rows (:func:`ttc.evaluation.lead_rows`: one row per run × frame pair). Both are
per run, and a fragment of the append-only store never changes, so each is computed once, by
the first summary that reads the fragment, and kept under a key of everything it depends on:

- lead rows (``lead-<key>.parquet``): the fragment's SHA-256 and name, its live runs (a run
  recomputed since into another fragment is left out), the dataset's unified schema (the
  column types) and the code of the reduction and the columns it keeps;
- metrics (``metrics-<key>.parquet``): the lead rows' key, the reference's content
  (:func:`frame_digest`) and the source of the modules the metrics are computed by
  (:data:`METRICS_MODULES`) with the pandas, NumPy and pyarrow versions.

So a changed fragment, reference or code never reuses a kept file, and a later invocation's
summary computes only its own fragments' lead rows and metrics and reads one small file per
other fragment (one row per run). A kept file that cannot be read is computed again; deleting
``.summary/`` is always safe.
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from experiments.store.dataset import Fragment, fragments, iter_tables, unified_schema
from experiments.store.files import write_parquet_atomic

if TYPE_CHECKING:
    from ttc.evaluation.stage_times import StageCounts

#: Folder of the kept files, under the sweep folder.
CACHE_DIR = ".summary"
#: Modules whose source the metrics depend on (:func:`ttc.evaluation.run_metrics`, the
#: per-frame errors, the reference's pair ratios and regimes, the axes and cached stages).
METRICS_MODULES = (
    "ttc.evaluation.metrics",
    "ttc.evaluation.errors",
    "ttc.evaluation.reference",
    "ttc.evaluation.stage_times",
    "ttc.settings",
)


def _code_key(columns: list[str]) -> str:
    """Digest of the reduction's code and the columns it reads."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    text = inspect.getsource(ev.lead_rows) + json.dumps(columns) + pd.__version__ + pa.__version__
    return hashlib.sha256(text.encode()).hexdigest()


def _metrics_code_key() -> str:
    """Digest of the source of :data:`METRICS_MODULES` and the library versions."""
    import importlib  # noqa: PLC0415

    text = "".join(inspect.getsource(importlib.import_module(m)) for m in METRICS_MODULES)
    text += pd.__version__ + np.__version__ + pa.__version__
    return hashlib.sha256(text.encode()).hexdigest()


def frame_digest(frame: pd.DataFrame) -> str:
    """SHA-256 of a table's content: its columns, their types and every value (index
    included)."""
    digest = hashlib.sha256(json.dumps([list(map(str, frame.columns)),
                                        [str(t) for t in frame.dtypes]]).encode())  # fmt: skip
    digest.update(pd.util.hash_pandas_object(frame, index=True).to_numpy().tobytes())
    return digest.hexdigest()


def cache_path(sweep_dir: Path, frag: Fragment, key: str, kind: str = "lead") -> Path:
    """Where ``kind`` (``lead`` or ``metrics``) of ``frag`` is kept under ``key`` (what it
    depends on besides the fragment and its live runs)."""
    live = json.dumps(sorted(frag.n_rows))
    digest = hashlib.sha256(f"{frag.sha256}|{frag.path.name}|{live}|{key}".encode()).hexdigest()
    return Path(sweep_dir) / CACHE_DIR / f"{kind}-{digest[:32]}.parquet"


def _read_kept(path: Path) -> pa.Table | None:
    """A kept table, or None when absent or unreadable."""
    try:
        return pq.read_table(path)
    except (OSError, pa.ArrowException):
        return None


def _keep(table: pd.DataFrame, path: Path) -> pa.Table:
    """``table`` as Arrow, kept at ``path`` (nothing kept in a read-only sweep folder)."""
    with contextlib.suppress(OSError):
        write_parquet_atomic(table, path)
    return pa.Table.from_pandas(table, preserve_index=False)


def _whole(parts: list[pa.Table]) -> pd.DataFrame:
    """The parts as one frame: one conversion of the whole (140 conversions and a concat of
    frames: 4.9 s against 3.7 s)."""
    return pa.concat_tables(parts, promote_options="permissive").to_pandas()


@dataclass
class _Sweep:
    """A sweep's live fragments, their unified schema, the columns the metrics read and the
    key of the lead rows (schema and code)."""

    sweep_dir: Path
    frags: list[Fragment]
    schema: pa.Schema
    columns: list[str]
    key: str

    def lead_tables(self, wanted: list[int]) -> dict[int, pa.Table]:
        """The lead rows of fragments ``wanted`` (indices): kept ones read, the others
        computed (a fragment at a time: a run's rows are in one fragment) and kept."""
        from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import)

        parts: dict[int, pa.Table] = {}
        todo = []
        for i in wanted:
            kept = _read_kept(cache_path(self.sweep_dir, self.frags[i], self.key))
            if kept is None:
                todo.append(i)
            else:
                parts[i] = kept
        tables = iter_tables([self.frags[i] for i in todo], self.schema, self.columns)
        for i, table in zip(todo, tables, strict=True):
            rows = table.to_pandas()
            lead = ev.lead_rows(rows) if len(rows) else rows
            parts[i] = _keep(lead, cache_path(self.sweep_dir, self.frags[i], self.key))
        return parts


def _open(sweep_dir: Path, records: list[dict[str, Any]] | None) -> _Sweep | None:
    """The sweep's :class:`_Sweep`, None when it has no live fragment."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    frags = fragments(sweep_dir, records)
    schema = unified_schema(frags)
    if schema is None:
        return None
    columns = [c for c in schema.names if c not in ev.NOT_JUDGED_COLUMNS]
    key = hashlib.sha256(f"{schema}|{_code_key(columns)}".encode()).hexdigest()
    return _Sweep(Path(sweep_dir), frags, schema, columns, key)


def schema_names(sweep_dir: Path, records: list[dict[str, Any]] | None = None) -> list[str]:
    """The columns of the sweep's rows (its fragments' unified schema; none without one)."""
    sweep = _open(sweep_dir, records)
    return [] if sweep is None else list(sweep.schema.names)


def lead_rows(sweep_dir: Path, records: list[dict[str, Any]] | None = None) -> pd.DataFrame:
    """One row per run × frame pair of a sweep, the lead vehicle's
    (:func:`ttc.evaluation.lead_rows`), without the columns no metric reads
    (:data:`ttc.evaluation.NOT_JUDGED_COLUMNS`), fragments in the dataset's order (kept ones
    read, the others computed and kept). ``records``: the sweep's
    :func:`experiments.store.list_records`, when already read.
    :class:`experiments.store.StoreError` names a corrupt fragment."""
    sweep = _open(sweep_dir, records)
    if sweep is None:
        return pd.DataFrame()
    parts = sweep.lead_tables(list(range(len(sweep.frags))))
    return _whole([parts[i] for i in range(len(sweep.frags))])


def _stages(sweep: _Sweep) -> dict[str, list[str]]:
    """The cached stages whose time and flag columns the sweep's rows have: name → its input
    axes the rows have (:data:`ttc.evaluation.CACHED_STAGE_INPUTS`), as
    :func:`ttc.evaluation.stage_time_counts` counts them."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import)

    have = set(sweep.columns)
    return {name: [c for c in inputs if c in have]
            for name, (ms, flag, inputs) in ev.CACHED_STAGE_INPUTS.items()
            if ms in have and flag in have}  # fmt: skip


def fragment_times(lead: pd.DataFrame) -> pd.DataFrame:
    """What a fragment's runs' computing times (``ms_compute_per_frame``) take from and give
    to the sweep, as one table (column ``stage``, the stages' axes, ``frame``, ``ms``, ``n``):
    its lead rows' computed stage times counted (:func:`ttc.evaluation.stage_time_counts`,
    ``n`` ≥ 1), and with ``n`` 0 (``frame`` -1, no ``ms``) the stage inputs its cached rows
    look up."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import)

    parts, axes = [], []
    for name, counted in ev.stage_time_counts(lead).items():
        _, flag, inputs = ev.CACHED_STAGE_INPUTS[name]
        keys = [c for c in inputs if c in lead]
        axes += [c for c in keys if c not in axes]
        looked_up = lead.loc[lead[flag].astype(bool).to_numpy(), keys]
        looked_up = looked_up.drop_duplicates() if keys else looked_up.iloc[:1]
        uses = looked_up.assign(frame=-1, ms=np.nan, n=0)
        parts += [counted.assign(stage=name), uses.assign(stage=name)]
    columns = ["stage", *axes, "frame", "ms", "n"]
    if not parts:
        return pd.DataFrame(columns=columns)
    filled = [p for p in parts if len(p)] or parts[:1]  # no empty table sets a type
    return pd.concat(filled, ignore_index=True).reindex(columns=columns)


def _split_times(
    kept: pa.Table, stages: dict[str, list[str]], schema: pa.Schema
) -> tuple[StageCounts, StageCounts]:
    """A :func:`fragment_times` table as (its counts, the stage inputs it looks up), by
    stage: the stage's axes and ``frame`` in the types of the sweep's rows (``schema``), as
    :func:`ttc.evaluation.stage_time_counts` of its lead rows gives them."""
    from ttc.evaluation.stage_times import COUNT_COLUMNS  # noqa: PLC0415 (SciPy: slow)

    counts, uses = {}, {}
    for name, keys in stages.items():
        types = [pa.field(c, schema.field(c).type) for c in [*keys, "frame"]]
        types += [pa.field("ms", pa.float64()), pa.field("n", pa.int64())]
        mine = kept.filter(pc.equal(kept["stage"], name)).select([*keys, *COUNT_COLUMNS])
        table = mine.cast(pa.schema(types)).to_pandas()
        looked_up = table["n"].to_numpy() == 0
        counts[name] = table[~looked_up].reset_index(drop=True)
        uses[name] = table.loc[looked_up, keys].reset_index(drop=True)
    return counts, uses


def _depends(counts: StageCounts, uses: list[StageCounts]) -> list[str]:
    """Per fragment (the stage inputs it looks up, :func:`_split_times`): a digest of the
    sweep's computed times (``counts``, :func:`ttc.evaluation.join_counts` of every
    fragment's) of those stage inputs, on every frame: all its runs' computing times depend
    on."""
    digests = [hashlib.sha256() for _ in uses]
    for name, table in sorted(counts.items()):
        keys = [c for c in table.columns if c not in ("frame", "ms", "n")]
        times = table.groupby([*keys, "frame", "ms"], dropna=False)["n"].sum().reset_index()
        parts = [u[name].assign(part=i) for i, u in enumerate(uses) if len(u.get(name, ()))]
        if not parts:
            continue
        asked = pd.concat(parts, ignore_index=True).drop_duplicates()
        found = asked.merge(times, on=keys) if keys else asked.merge(times, how="cross")
        for part, rows in found.groupby("part", sort=True):
            rows = rows.drop(columns="part").sort_values([*keys, "frame", "ms"])
            digests[part].update(name.encode())
            digests[part].update(pd.util.hash_pandas_object(rows, index=False).to_numpy())
    return [d.hexdigest() for d in digests]


def run_metrics(
    sweep_dir: Path, reference: pd.DataFrame, records: list[dict[str, Any]] | None = None
) -> pd.DataFrame:
    """:func:`ttc.evaluation.run_metrics` of the sweep's :func:`lead_rows` against
    ``reference`` (one row per run with lead rows, sorted by run id), computed a fragment at a
    time and kept (module docstring): only the fragments without kept metrics have their lead
    rows read or computed, all at once, their computing times looked up
    (:func:`ttc.evaluation.compute_times`) over every fragment's counted computed stage times
    (:func:`fragment_times`, kept too): the times counting every lead row at once gives."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    sweep = _open(sweep_dir, records)
    if sweep is None:
        return pd.DataFrame()
    n = len(sweep.frags)
    code = _metrics_code_key()
    times_key = hashlib.sha256((sweep.key + code + inspect.getsource(fragment_times)).encode())
    times_paths = [cache_path(sweep.sweep_dir, f, times_key.hexdigest(), "times")
                   for f in sweep.frags]  # fmt: skip
    times = {i: t for i, p in enumerate(times_paths) if (t := _read_kept(p)) is not None}
    leads = sweep.lead_tables([i for i in range(n) if i not in times])
    for i, table in leads.items():
        times[i] = _keep(fragment_times(table.to_pandas()), times_paths[i])
    stages = _stages(sweep)
    split = [_split_times(times[i], stages, sweep.schema) for i in range(n)]
    counts = ev.join_counts(c for c, _ in split)
    key = f"{sweep.key}|{frame_digest(reference)}|{code}"
    paths = [cache_path(sweep.sweep_dir, f, f"{key}|{d}", "metrics")
             for f, d in zip(sweep.frags, _depends(counts, [u for _, u in split]), strict=True)]  # fmt: skip
    parts = {i: t for i, p in enumerate(paths) if (t := _read_kept(p)) is not None}
    todo = [i for i in range(n) if i not in parts]
    if todo:
        leads.update(sweep.lead_tables([i for i in todo if i not in leads]))
        lead = _whole([leads[i] for i in todo])
        if len(lead):
            lead = lead.assign(ms_compute_per_frame=ev.compute_times(lead, counts))
        metrics = ev.run_metrics(lead, reference) if len(lead) else pd.DataFrame({"run_id": []})
        for i in todo:
            mine = metrics["run_id"].isin(list(sweep.frags[i].n_rows)).to_numpy()
            parts[i] = _keep(metrics[mine].reset_index(drop=True), paths[i])
    whole = _whole([parts[i] for i in range(n)])
    return whole.sort_values("run_id", ignore_index=True)
