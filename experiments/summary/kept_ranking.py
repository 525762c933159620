"""The end-of-sweep summary's ranking on one recording, kept (kind ``ranked``).

The summary of a sweep on one real recording prints the best runs of
:func:`ttc.evaluation.rank_runs` of every run's metrics (:mod:`experiments.summary.run_metrics`).
The rule reads three keys of a run: its invalid rate and median MiD on the ranked sensor and its
time (:func:`ttc.evaluation.ranking_time`), then its ``run_id``. So each summary keeps those keys
of every run, with the lookup axes and the rank they got, in one file (:data:`KIND`,
:mod:`experiments.summary.kept_tables`; each run under its fragment's kept-metrics key, the
sensor and the rule's code) beside the digest of the computing times the fragment's runs look
up, as the kept metrics are (:func:`experiments.summary.run_metrics.with_looked_up`). A later
summary takes the kept keys of each fragment still live whose digest is unchanged, in their kept
order; judges only the other fragments' runs (new ones, and those whose looked-up times moved:
from their kept metrics, else computed); ranks their keys alone and merges them into the kept
order (:func:`merged_ranking`: a binary search on a few small columns); keeps the result as the
one file; and reads the full metrics of the best ``top`` runs alone. The ranking is
:func:`ttc.evaluation.rank_runs` of every run's metrics (test); deleting ``.summary/`` is always
safe. On 24,000 runs of 3 frames (18,000 kept, 6,000 new) the ranking step took 0.40–0.69 s
(median 0.45) where reading and ranking every run's metrics took 0.40–0.76 s (0.57): most of
it is judging the new runs; with nothing new, 0.14–0.25 s where it took 0.25–0.54 s.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pandas as pd
import pyarrow as pa

from experiments.summary import kept_tables as kt
from experiments.summary import run_metrics as rm
from experiments.summary.kept_tables import FRAGMENT
from experiments.summary.lead_rows import LeadRows

#: Kind (file name prefix) of the kept ranking keys.
KIND = "ranked"
#: Column of the kept keys: the rule's time key (ms per frame, :func:`ttc.evaluation.ranking_time`).
TIME = "ranking_ms"


def _code_key(sensor: str) -> str:
    """Digest of the rule's code and the sensor ranked on."""
    return rm.code_digest(("evaluation/ranking.py",), sensor)


def key_columns(sensor: str) -> list[str]:
    """The sort keys of :data:`ttc.evaluation.RANKING_RULE` on ``sensor``, as kept: invalid
    rate, median MiD, time (:data:`TIME`)."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import)

    return [*(f"{sensor}_{k}" for k in ev.RANKING_KEYS), TIME]


def lookup_axes(metrics: pd.DataFrame) -> list[str]:
    """The axes of ``metrics`` whose values the computing-time lookups read."""
    from ttc.evaluation.stage_times import CACHED_STAGE_INPUTS  # noqa: PLC0415

    axes = [a for _, _, inputs in CACHED_STAGE_INPUTS.values() for a in inputs]
    return [a for a in dict.fromkeys(axes) if a in metrics]


def ranking_keys(metrics: pd.DataFrame, sensor: str) -> pd.DataFrame:
    """(n runs, run_id and :func:`key_columns`) of ``metrics``
    (:func:`ttc.evaluation.run_metrics`), in their order; float keys, NaN where unknown."""
    from ttc import evaluation as ev  # noqa: PLC0415

    invalid, mid, _ = key_columns(sensor)
    return pd.DataFrame({
        "run_id": metrics["run_id"].to_numpy(),
        invalid: metrics[invalid].to_numpy(dtype=float),
        mid: metrics[mid].to_numpy(dtype=float),
        TIME: ev.ranking_time(metrics).to_numpy(dtype=float),
    })  # fmt: skip


def merged_ranking(kept: pd.DataFrame, new: pd.DataFrame, sensor: str) -> pd.DataFrame:
    """The runs of ``kept`` (ranking keys in the rule's order: a kept ranking's rows in rank
    order) and ``new`` (:func:`ranking_keys` of other runs, any order) ranked together,
    sorted by a new ``rank`` (1..n); other columns carried along. ``new`` alone is ranked by
    :func:`ttc.evaluation.rank_runs` on its keys (the rule's time key as its
    ``ms_per_frame``), then merged into ``kept`` by a binary search on (keys, ``run_id``)
    (:func:`_sortable`): the result is :func:`~ttc.evaluation.rank_runs` of all runs (test)."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import)

    if len(new):
        plain = new.drop(columns=["rank"], errors="ignore").rename(columns={TIME: "ms_per_frame"})
        new = ev.rank_runs(plain, sensor).rename(columns={"ms_per_frame": TIME})
    held, more = _sortable([kept, new], sensor)
    at = np.searchsorted(held, more)  # each new run's place among the kept ones
    n_kept, n_new = len(kept), len(new)
    order = np.empty(n_kept + n_new, dtype=np.int64)
    before = np.searchsorted(at, np.arange(n_kept), side="right")  # new runs ahead of each
    order[np.arange(n_kept) + before] = np.arange(n_kept)
    order[at + np.arange(n_new)] = n_kept + np.arange(n_new)
    parts = [t.reset_index(drop=True) for t in (kept, new) if len(t)]
    if not parts:
        return new.assign(rank=np.zeros(0, dtype=np.int64))
    table = pd.concat(parts, ignore_index=True) if len(parts) > 1 else parts[0]
    return table.iloc[order].reset_index(drop=True).assign(rank=np.arange(1, len(order) + 1))


def _sortable(tables: list[pd.DataFrame], sensor: str) -> list[np.ndarray]:
    """Each table's runs as records (invalid rate, median MiD, time, ``run_id``) of one
    dtype, NaN keys as +inf: NumPy orders records field by field, so their order is
    :data:`ttc.evaluation.RANKING_RULE`'s (:func:`ttc.evaluation.ranks`: NaN last within its
    key, then ``run_id``)."""
    ids = [t["run_id"].to_numpy(dtype=str) if len(t) else np.array([], dtype=str) for t in tables]
    width = max((i.dtype.itemsize // 4 for i in ids), default=1)
    dtype = [("invalid", "f8"), ("mid", "f8"), ("ms", "f8"), ("run_id", f"U{max(width, 1)}")]
    out = []
    for table, run_ids in zip(tables, ids, strict=True):
        records = np.empty(len(table), dtype=dtype)
        for field, column in zip(("invalid", "mid", "ms"), key_columns(sensor), strict=True):
            values = table[column].to_numpy(dtype=float) if len(table) else np.zeros(0)
            records[field] = np.where(np.isnan(values), np.inf, values)
        records["run_id"] = run_ids
        out.append(records)
    return out


def kept_ranking(
    lead: LeadRows, reference: pd.DataFrame, sensor: str, top: int
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(every run's ranking keys and ``rank`` sorted by it, with :data:`FRAGMENT`; the full
    metrics of the ``top`` best runs, in rank order): :func:`ttc.evaluation.rank_runs` of
    :func:`experiments.summary.run_metrics.kept_run_metrics` of ``lead`` against
    ``reference`` on ``sensor``, from the kept keys where still valid (module docstring)."""
    known = rm.metric_keys(lead, reference)
    code = _code_key(sensor)
    named = {k: hashlib.sha256(f"{k}|{code}".encode()).hexdigest()[:32] for k in known.keys}
    files = kt.kept_files(lead.sweep_dir, KIND)
    kept = rm.valid_kept(kt.kept_rows(files, list(named.values()), each_once=False)[0],
                         known.digests)  # fmt: skip
    done = set(kept[FRAGMENT]) if len(kept) else set()
    todo = [k for k, n in named.items() if n not in done]
    if len(kt.kept_files(lead.sweep_dir, rm.KIND)) > kt.MAX_KEPT_FILES:
        todo = list(known.keys)  # every run's metrics read: their files put together as one
    whole = len(todo) == len(known.keys)
    metrics = pd.DataFrame()
    if todo:
        metrics = rm.kept_run_metrics(lead, reference, None if whole else todo, known)
    if not todo and list(files.values()) == [set(named.values())]:  # the ranking kept
        ranked = kept.sort_values("rank", ignore_index=True)
    else:  # the keys of every live run as one file, the others removed
        new = _new_keys(lead, known, named, todo, metrics, sensor)
        kept = kept.iloc[:0] if whole or not len(kept) else kept.sort_values("rank")
        if len(files) > 1 and len(kept):  # ranks of several files: ranked again as new
            kept, new = kept.iloc[:0], pd.concat([kept, new] if len(new) else [kept])
        ranked = merged_ranking(kept, new, sensor)
        table = pa.Table.from_pandas(ranked, preserve_index=False)
        kt.consolidate(lead.sweep_dir, KIND, table, list(named.values()), list(files))
    best = ranked.head(top if top else 1)  # --top 0: the columns of none
    return ranked, _best_metrics(lead, reference, known, named, best, metrics)


def _new_keys(
    lead: LeadRows,
    known: rm.MetricKeys,
    named: dict[str, str],
    todo: list[str],
    metrics: pd.DataFrame,
    sensor: str,
) -> pd.DataFrame:
    """The ranking keys (:func:`ranking_keys`) of the runs of ``metrics`` (those of the
    fragments ``todo``), with their fragment's ranking key (:data:`FRAGMENT`), the lookup
    axes and the lookups' digest, as kept."""
    if not len(metrics):
        return pd.DataFrame()
    fragment_of = {r: named[k] for k in todo for r in lead.runs(known.keys[k])}
    new = ranking_keys(metrics, sensor)
    new[FRAGMENT] = new["run_id"].map(fragment_of)
    return rm.with_looked_up(new.join(metrics[lookup_axes(metrics)]), known.digests)


def _best_metrics(
    lead: LeadRows,
    reference: pd.DataFrame,
    known: rm.MetricKeys,
    named: dict[str, str],
    best: pd.DataFrame,
    judged: pd.DataFrame,
) -> pd.DataFrame:
    """The full metrics of the runs of ``best`` (ranked keys with :data:`FRAGMENT`), in its
    order: from ``judged`` (the metrics this summary read or computed) where there, else read
    from the kept metrics of their fragments (``named``: kept-metrics key -> ranked key)."""
    wanted = set(best["run_id"])
    found = judged[judged["run_id"].isin(wanted)] if len(judged) else judged
    parts = [found] if len(found) else []  # no empty part: it would count in the types
    missing = wanted - set(found["run_id"]) if len(found) else wanted
    if missing:
        fragments = set(best.loc[best["run_id"].isin(missing), FRAGMENT])
        only = [k for k, n in named.items() if n in fragments]
        read = rm.kept_run_metrics(lead, reference, only, known)
        parts.append(read[read["run_id"].isin(missing)])
    table = pd.concat(parts, ignore_index=True) if len(parts) > 1 else parts[0]
    order = pd.Series(range(len(best)), index=best["run_id"].to_numpy())
    return table.iloc[order[table["run_id"]].to_numpy().argsort()].reset_index(drop=True)
