"""The end-of-sweep summary's run metrics, kept per fragment (:mod:`experiments.summary.kept_tables`).

The summary of a sweep on one recording ranks :func:`ttc.evaluation.run_metrics` of every
run's lead rows against the recording's reference. A run's metrics are its own rows', but for
``ms_compute_per_frame``: a cached stage's load time is replaced by the median time of
computing it over every run's rows (:mod:`ttc.evaluation.stage_times`). So each fragment's
runs' metrics are kept under a key of its lead rows (:mod:`experiments.summary.lead_rows`), the
reference and this code, beside a digest of the computing times its runs look up: per cached
stage and value of its axes (``detector``, ...), every computed time the sweep's rows count
(:func:`counts_digests`). A later summary counts the computed times of every lead row (their
few columns only), and takes a fragment's metrics as kept when its digest is unchanged; only
new fragments, and those whose stages were computed again since, are judged again, from their
kept lead rows, with the times looked up over the whole sweep as before. The table is the one
:func:`ttc.evaluation.run_metrics` gives of all lead rows (test). The counts themselves are
kept too (:func:`lead_counts`): a later summary counts only the new fragments' lead rows.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import pickle
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd
import pyarrow as pa

from experiments.summary import kept_tables as kt
from experiments.summary.kept_tables import FRAGMENT
from experiments.summary.lead_rows import LeadRows
from ttc.atomic import write_bytes_atomic

#: Kind (file name prefix) of the kept run metrics.
KIND = "metrics"
#: Column of a kept file: the digest of the computing times its fragment's runs looked up.
LOOKED_UP = "__looked_up"
#: The computing-time counts of the lead rows the last summary kept, with the fragments
#: they count (:func:`lead_counts`).
COUNTS_FILE = "counts.pkl"
#: The files of the ``ttc`` package whose code the metrics run (besides pandas and NumPy).
CODE_FILES = ("evaluation/metrics.py", "evaluation/errors.py", "evaluation/reference.py",
              "evaluation/stage_times.py", "settings.py")  # fmt: skip


def code_digest(files: tuple[str, ...], *also: str) -> str:
    """Digest of the code of ``files`` (paths in the ``ttc`` package) and ``also`` (versions,
    a sensor): what a kept table of the summary depends on besides its rows."""
    import ttc  # noqa: PLC0415

    root = Path(ttc.__file__).parent
    text = "".join((root / name).read_text() for name in files)
    return hashlib.sha256("|".join([text, *also]).encode()).hexdigest()


def _code_key() -> str:
    """Digest of the metrics' code and the library versions."""
    return code_digest(CODE_FILES, pd.__version__, np.__version__)


def reference_key(reference: pd.DataFrame) -> str:
    """Digest of a reference table: its columns, types and values."""
    values = pd.util.hash_pandas_object(reference, index=True).to_numpy().tobytes()
    head = f"{list(reference.columns)}|{list(map(str, reference.dtypes))}".encode()
    return hashlib.sha256(head + values).hexdigest()


def _count_columns(lead: LeadRows) -> list[str]:
    """The lead row columns the computing times are counted from."""
    from ttc.evaluation.stage_times import CACHED_STAGE_INPUTS  # noqa: PLC0415

    names = set(lead.schema.names)
    wanted = ["frame"]
    for ms, flag, axes in CACHED_STAGE_INPUTS.values():
        wanted += [ms, flag, *axes]
    return [c for c in dict.fromkeys(wanted) if c in names]


def _key_text(values: pd.DataFrame) -> pd.Series:
    """Each row's values as one text (NaN as its own value), for a digest lookup."""
    if values.shape[1] == 0:
        return pd.Series("", index=values.index)
    parts = [values[c].astype(object).where(values[c].notna(), "\0nan").astype(str) for c in values]
    text = parts[0]
    for part in parts[1:]:
        text = text + "\x1f" + part
    return text


def lead_counts(lead: LeadRows) -> dict[str, pd.DataFrame]:
    """:func:`ttc.evaluation.stage_time_counts` of every lead row of ``lead``, in parts
    (:func:`ttc.evaluation.stage_times.join_counts`: the digests and medians read from them
    sum a part's counts up as the whole's): those the last summary kept (:data:`COUNTS_FILE`,
    under this code's key and the columns counted) while every fragment they count is still
    live, and those of the fragments since; else every lead row counted again. A ``grand``
    re-run's summary read the counting columns of its 640,000 lead rows: 0.26 s."""
    from ttc.evaluation.stage_times import join_counts, stage_time_counts  # noqa: PLC0415

    columns = _count_columns(lead)
    key = hashlib.sha256(f"{_code_key()}|{json.dumps(columns)}".encode()).hexdigest()
    path = lead.sweep_dir / kt.CACHE_DIR / COUNTS_FILE
    counted, counts = _kept_counts(path, key)
    if not set(counted) <= set(lead.keys):  # a fragment counted is no longer live
        counted, counts = [], {}
    done = set(counted)
    new = [k for k in lead.keys if k not in done]
    if not new:
        return counts
    more = stage_time_counts(lead.frame(new, columns))
    counts = join_counts([counts, more]) if counted else more
    with contextlib.suppress(OSError):  # a read-only sweep folder: nothing kept
        write_bytes_atomic(pickle.dumps((key, [*counted, *new], counts)), path)
    return counts


def _kept_counts(path: Path, key: str) -> tuple[list[str], dict[str, pd.DataFrame]]:
    """(fragment keys, counts) kept in ``path`` under ``key``; none when absent, unreadable
    or kept under another key."""
    try:
        kept_key, counted, counts = pickle.loads(path.read_bytes())  # noqa: S301 (own cache)
    except Exception:  # noqa: BLE001 - absent or damaged: counted again
        return [], {}
    return (list(counted), counts) if kept_key == key else ([], {})


def counts_digests(counts: dict[str, pd.DataFrame]) -> dict[str, dict[str, str]]:
    """Per cached stage, per value of its axes (:func:`_key_text`): a digest of every computed
    time the ``counts`` (:func:`ttc.evaluation.stage_times.stage_time_counts`) hold for it
    (frame, ms, rows), in whatever order the counts came: what a row's compute time looks up."""
    from ttc.evaluation.stage_times import CACHED_STAGE_INPUTS  # noqa: PLC0415

    out: dict[str, dict[str, str]] = {}
    for name, table in counts.items():
        keys = [c for c in CACHED_STAGE_INPUTS[name][2] if c in table]
        summed = table.groupby([*keys, "frame", "ms"], dropna=False, sort=True)["n"].sum()
        summed = summed.reset_index()
        text = _key_text(summed[keys])
        out[name] = {
            k: hashlib.sha256(g[["frame", "ms", "n"]].to_numpy(dtype=float).tobytes()).hexdigest()
            for k, g in summed.groupby(text.to_numpy(), sort=False)
        }
    return out


def looked_up(metrics: pd.DataFrame, digests: dict[str, dict[str, str]]) -> pd.Series:
    """Per run of ``metrics`` (its axis columns): the digest of the computing times its rows'
    lookups read (:func:`counts_digests`). Worked out once per distinct combination of the
    axes (33,600 runs one at a time: 0.13 s; at once: 0.03 s)."""
    from ttc.evaluation.stage_times import CACHED_STAGE_INPUTS, group_codes  # noqa: PLC0415

    axes = [a for _, _, inputs in CACHED_STAGE_INPUTS.values() for a in inputs if a in metrics]
    codes = [pd.factorize(metrics[a], use_na_sentinel=False)[0] for a in dict.fromkeys(axes)]
    group = group_codes(codes) if codes else np.zeros(len(metrics), dtype=np.int64)
    distinct = metrics.iloc[np.unique(group, return_index=True)[1]]  # group g's first row
    text = pd.Series("", index=distinct.index)
    for name, (_, _, inputs) in CACHED_STAGE_INPUTS.items():
        keys = [c for c in inputs if c in metrics]
        found = _key_text(distinct[keys]).map(digests.get(name, {})).astype(object).fillna("-")
        text = text + "|" + found
    return pd.Series(text.to_numpy()[group], index=metrics.index)


def _fragment_digest(runs: pd.DataFrame, per_run: pd.Series) -> pd.Series:
    """Per fragment (``runs[FRAGMENT]``): one digest of its runs' distinct lookups."""
    return per_run.groupby(runs[FRAGMENT].to_numpy()).agg(
        lambda s: hashlib.sha256("\n".join(sorted(set(s))).encode()).hexdigest()
    )


class MetricKeys(NamedTuple):
    """What a sweep's kept run metrics against one reference are named and checked by."""

    #: :func:`lead_counts` of the sweep.
    counts: dict[str, pd.DataFrame]
    #: :func:`counts_digests` of ``counts``.
    digests: dict[str, dict[str, str]]
    #: Each live fragment's kept key (lead rows, reference, code) -> its fragment key, in the
    #: dataset's order.
    keys: dict[str, str]


def metric_keys(lead: LeadRows, reference: pd.DataFrame) -> MetricKeys:
    """The :class:`MetricKeys` of ``lead``'s runs judged against ``reference``."""
    counts = lead_counts(lead)
    base = hashlib.sha256(f"{reference_key(reference)}|{_code_key()}".encode()).hexdigest()
    keys = {hashlib.sha256(f"{k}|{base}".encode()).hexdigest()[:32]: k for k in lead.keys}
    return MetricKeys(counts, counts_digests(counts), keys)


def kept_run_metrics(
    lead: LeadRows,
    reference: pd.DataFrame,
    only: list[str] | None = None,
    known: MetricKeys | None = None,
) -> pd.DataFrame:
    """:func:`ttc.evaluation.run_metrics` of every lead row of ``lead`` against
    ``reference``, each fragment's runs' metrics kept and taken back while what they depend
    on is unchanged (module docstring). ``only``: the runs of these fragments alone (kept
    keys of :func:`metric_keys`, not empty; the kept files are then never put together as
    one); ``known``: :func:`metric_keys` of ``lead`` and ``reference`` when already made."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import)
    from ttc.evaluation.stage_times import compute_times  # noqa: PLC0415

    known = metric_keys(lead, reference) if known is None else known
    counts, digests = known.counts, known.digests
    keys = known.keys if only is None else {k: known.keys[k] for k in only}
    files = kt.kept_files(lead.sweep_dir, KIND)
    kept = valid_kept(kt.kept_rows(files, list(keys), each_once=False)[0], digests)
    done = set(kept[FRAGMENT]) if len(kept) else set()
    todo = [k for k in keys if k not in done]
    parts = [kept.drop(columns=[LOOKED_UP])] if len(kept) else []
    if todo:
        rows = lead.frame([keys[k] for k in todo])
        rows["ms_compute_per_frame"] = compute_times(rows, counts)
        new = ev.run_metrics(rows, reference)
        fragment_of = {r: k for k in todo for r in lead.runs(keys[k])}
        parts.append(new.assign(**{FRAGMENT: new["run_id"].map(fragment_of)}))
        path = kt.keep(lead.sweep_dir, KIND, stored(parts[-1], digests), todo)
        if path is not None:
            files[path] = set(todo)
    metrics = pd.concat(parts, ignore_index=True)
    if only is None and len(files) > kt.MAX_KEPT_FILES:  # one file of the metrics used
        kt.consolidate(lead.sweep_dir, KIND, stored(metrics, digests), list(keys), list(files))
    return metrics.drop(columns=[FRAGMENT]).sort_values("run_id", ignore_index=True)


#: Column of :func:`valid_kept`'s table: the kept file a row came from.
_FILE = "__file"


def valid_kept(tables: list[pa.Table], digests: dict[str, dict[str, str]]) -> pd.DataFrame:
    """The kept rows of ``tables`` (metrics, or any table kept by :func:`stored`; one per
    kept file, in order) still valid under ``digests``: each fragment's copy whose lookups'
    digest is unchanged, from the first file that holds one (an earlier summary's copy may be
    stale, a later one's valid)."""
    if not tables:
        return pd.DataFrame()
    kept = pd.concat([t.to_pandas().assign(**{_FILE: i}) for i, t in enumerate(tables)],
                     ignore_index=True)  # fmt: skip
    copy = kept[FRAGMENT] + "|" + kept[_FILE].astype(str)
    now = _fragment_digest(kept.assign(**{FRAGMENT: copy}), looked_up(kept, digests))
    kept = kept[(copy.map(now) == kept[LOOKED_UP]).to_numpy(dtype=bool)]
    first = kept.groupby(FRAGMENT)[_FILE].transform("min")
    return kept[(kept[_FILE] == first).to_numpy(dtype=bool)].drop(columns=[_FILE])


def with_looked_up(table: pd.DataFrame, digests: dict[str, dict[str, str]]) -> pd.DataFrame:
    """``table`` (rows with :data:`FRAGMENT` and the axes the lookups read) with each
    fragment's lookups' digest (:data:`LOOKED_UP`)."""
    digest = _fragment_digest(table, looked_up(table, digests))
    return table.assign(**{LOOKED_UP: table[FRAGMENT].map(digest)})


def stored(metrics: pd.DataFrame, digests: dict[str, dict[str, str]]) -> pa.Table:
    """``metrics`` (with :data:`FRAGMENT` and the axes the lookups read) as kept
    (:func:`with_looked_up`)."""
    return pa.Table.from_pandas(with_looked_up(metrics, digests), preserve_index=False)
