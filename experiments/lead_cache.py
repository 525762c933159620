"""The end-of-sweep summary's lead rows, kept per rows fragment in ``<sweep>/.summary/``.

The summary ranks every run of a sweep on its lead rows (:func:`ttc.evaluation.lead_rows`:
one row per run × frame pair). A fragment of the append-only store never changes, so its lead
rows are computed once, by the first summary that reads it, and kept under a key of what they
depend on: the fragment's SHA-256, its live runs (a run recomputed since into another fragment
is left out), the dataset's unified schema (the column types) and the code of the reduction
and the columns it keeps. A later invocation's summary reads only its own fragments' rows
(≈ 120 rows per run) and the small kept files of the others (one row per run × frame pair).
A kept file that cannot be read is computed again; deleting ``.summary/`` is always safe.
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import json
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from experiments.store.dataset import Fragment, fragments, iter_tables, unified_schema
from experiments.store.files import write_parquet_atomic

#: Folder of the kept lead rows, under the sweep folder.
CACHE_DIR = ".summary"


def _code_key(columns: list[str]) -> str:
    """Digest of the reduction's code and the columns it reads."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    text = inspect.getsource(ev.lead_rows) + json.dumps(columns) + pd.__version__ + pa.__version__
    return hashlib.sha256(text.encode()).hexdigest()


def cache_path(sweep_dir: Path, frag: Fragment, key: str) -> Path:
    """Where the lead rows of ``frag`` are kept under ``key`` (schema and code)."""
    live = json.dumps(sorted(frag.n_rows))
    digest = hashlib.sha256(f"{frag.sha256}|{frag.path.name}|{live}|{key}".encode()).hexdigest()
    return Path(sweep_dir) / CACHE_DIR / f"lead-{digest[:32]}.parquet"


def _read_kept(path: Path) -> pa.Table | None:
    """Kept lead rows, or None when absent or unreadable."""
    try:
        return pq.read_table(path)
    except (OSError, pa.ArrowException):
        return None


def lead_rows(sweep_dir: Path, records: list[dict[str, Any]] | None = None) -> pd.DataFrame:
    """One row per run × frame pair of a sweep, the lead vehicle's
    (:func:`ttc.evaluation.lead_rows`), without the columns no metric reads
    (:data:`ttc.evaluation.NOT_JUDGED_COLUMNS`), fragments in the dataset's order: kept ones
    read, the others computed (a fragment at a time: a run's rows are in one fragment) and
    kept. ``records``: the sweep's :func:`experiments.store.list_records`, when already read.
    :class:`experiments.store.StoreError` names a corrupt fragment."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    frags = fragments(sweep_dir, records)
    schema = unified_schema(frags)
    if schema is None:
        return pd.DataFrame()
    columns = [c for c in schema.names if c not in ev.NOT_JUDGED_COLUMNS]
    key = hashlib.sha256(f"{schema}|{_code_key(columns)}".encode()).hexdigest()
    parts: dict[int, pa.Table] = {}
    todo = []
    for i, frag in enumerate(frags):
        kept = _read_kept(cache_path(sweep_dir, frag, key))
        if kept is None:
            todo.append(i)
        else:
            parts[i] = kept
    for i, table in zip(todo, iter_tables([frags[i] for i in todo], schema, columns), strict=True):
        rows = table.to_pandas()
        lead = ev.lead_rows(rows) if len(rows) else rows
        parts[i] = pa.Table.from_pandas(lead, preserve_index=False)
        with contextlib.suppress(OSError):  # a read-only sweep folder: nothing kept
            write_parquet_atomic(lead, cache_path(sweep_dir, frags[i], key))
    # one conversion of the whole (140 conversions and a concat of frames: 4.9 s against 3.7 s)
    ordered = [parts[i] for i in range(len(frags))]
    return pa.concat_tables(ordered, promote_options="permissive").to_pandas()
