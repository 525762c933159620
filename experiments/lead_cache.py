"""The end-of-sweep summary's lead rows, kept in ``<sweep>/.summary/``.

The summary ranks every run of a sweep on its lead rows (:func:`ttc.evaluation.lead_rows`:
one row per run × frame pair). A fragment of the append-only store never changes, so its lead
rows are computed once, by the first summary that reads it, and kept under a key of what they
depend on: the fragment's SHA-256 and name, its live runs (a run recomputed since into another
fragment is left out), the dataset's unified schema (the column types) and the code of the
reduction and the columns it keeps.

The rows a summary computes go into **one** kept file (a ``fragment`` column names each row's
key; the file's metadata lists its keys), not one per fragment: a later summary reads a few
files, not one per fragment of the sweep (on a 595-fragment folder, 595 reads took 2.0 of the
summary's 4.6 s). When more than :data:`MAX_KEPT_FILES` are there, the summary writes the rows
it used as one file and removes the others. A kept file that cannot be read is left out (its
fragments computed again); a key found in two files is taken from one; deleting
``.summary/`` is always safe.
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import json
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from experiments.store.dataset import Fragment, fragments, iter_tables, unified_schema
from experiments.store.files import write_parquet_atomic
from ttc.atomic import write_bytes_atomic

#: Folder of the kept lead rows, under the sweep folder.
CACHE_DIR = ".summary"
#: Column of a kept file naming each row's fragment key (:func:`fragment_key`).
FRAGMENT = "__fragment"
#: Schema metadata of a kept file: the JSON list of the keys it holds.
KEYS_META = b"ttc_bench_lead_keys"
#: Kept files a summary reads before it writes the rows it used as one.
MAX_KEPT_FILES = 8
#: The fragments' schemas, kept by their SHA-256 (distinct schemas once, each fragment's
#: index and file size and time): the summary unifies them on every call, and reading 739
#: files' footers took 0.84 s.
SCHEMAS_FILE = "schemas.pkl"


def _identity(path: Path) -> tuple[int, int] | None:
    """(size, modification time in ns) of a file, None when it cannot be read."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns


def _kept_schemas(sweep_dir: Path, frags: list[Fragment]) -> dict[str, pa.Schema]:
    """The schemas kept by :func:`_keep_schemas` of the fragments whose file is as it was
    when its schema was read (size, modification time), by SHA-256: a fragment changed or cut
    since is read again (and named as corrupt). Empty when absent or unreadable."""
    try:
        with open(Path(sweep_dir) / CACHE_DIR / SCHEMAS_FILE, "rb") as handle:
            distinct, index = pickle.load(handle)  # noqa: S301 (this folder's own cache)
        kept = {sha: (distinct[i], tuple(seen)) for sha, (i, seen) in index.items()}
    except (OSError, pickle.UnpicklingError, EOFError, ValueError, TypeError, IndexError,
            AttributeError, pa.ArrowException):  # fmt: skip
        return {}
    return {f.sha256: kept[f.sha256][0] for f in frags
            if f.sha256 in kept and kept[f.sha256][1] == _identity(f.path)}  # fmt: skip


def _keep_schemas(sweep_dir: Path, known: dict[str, pa.Schema], frags: list[Fragment]) -> None:
    """Keep ``known`` (schemas by fragment SHA-256, each distinct schema once) with each
    fragment file's size and modification time."""
    seen = {f.sha256: _identity(f.path) for f in frags}
    distinct: list[pa.Schema] = []
    index = {}
    for sha, schema in known.items():
        if seen.get(sha) is None:
            continue
        found = next((i for i, d in enumerate(distinct) if d.equals(schema)), None)
        if found is None:
            distinct.append(schema)
            found = len(distinct) - 1
        index[sha] = (found, seen[sha])
    with contextlib.suppress(OSError):  # a read-only sweep folder: nothing kept
        write_bytes_atomic(
            pickle.dumps((distinct, index)), Path(sweep_dir) / CACHE_DIR / SCHEMAS_FILE
        )


def _code_key(columns: list[str]) -> str:
    """Digest of the reduction's code and the columns it reads."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    text = inspect.getsource(ev.lead_rows) + json.dumps(columns) + pd.__version__ + pa.__version__
    return hashlib.sha256(text.encode()).hexdigest()


def fragment_key(frag: Fragment, key: str) -> str:
    """The key the lead rows of ``frag`` are kept under (``key``: schema and code)."""
    live = json.dumps(sorted(frag.n_rows))
    return hashlib.sha256(f"{frag.sha256}|{frag.path.name}|{live}|{key}".encode()).hexdigest()[:32]


def _kept_path(sweep_dir: Path, keys: list[str]) -> Path:
    """Where the kept rows of ``keys`` go (named by them: the same rows, the same file)."""
    digest = hashlib.sha256("|".join(keys).encode()).hexdigest()[:32]
    return Path(sweep_dir) / CACHE_DIR / f"lead-{digest}.parquet"


def _read_kept(path: Path, wanted: set[str]) -> pa.Table | None:
    """The rows of a kept file whose key is in ``wanted`` (``fragment`` column kept), or None
    when it has none of them or cannot be read."""
    try:
        meta = pq.read_schema(path).metadata or {}
        keys = set(json.loads(meta.get(KEYS_META, b"[]")))
        if not keys & wanted:
            return None
        table = pq.read_table(path)
    except (OSError, ValueError, pa.ArrowException):
        return None
    if FRAGMENT not in table.column_names:
        return None
    return table if keys <= wanted else table.filter(pc.is_in(table[FRAGMENT], pa.array(wanted)))


def _keep(sweep_dir: Path, table: pa.Table, keys: list[str]) -> Path | None:
    """Write ``table`` (rows of ``keys``, ``fragment`` column included) as one kept file;
    its path, or None where the folder is read-only."""
    path = _kept_path(sweep_dir, keys)
    with contextlib.suppress(OSError):  # a read-only sweep folder: nothing kept
        write_parquet_atomic(table, path, {KEYS_META: json.dumps(keys).encode()})
        return path
    return None


def _consolidate(sweep_dir: Path, whole: pa.Table, keys: list[str], files: list) -> None:
    """Keep ``whole`` (the rows of ``keys``) as one file and remove the other ``files``."""
    kept = _keep(sweep_dir, whole, keys)
    for path in files if kept is not None else ():
        if path is not None and path != kept:
            with contextlib.suppress(OSError):
                path.unlink()


def _kept_rows(
    sweep_dir: Path, keys: list[str]
) -> tuple[list[pa.Table], set[str], list[Path | None]]:
    """(tables of kept rows, the keys they hold, each a single time; the kept files there)."""
    files: list[Path | None] = sorted((Path(sweep_dir) / CACHE_DIR).glob("lead-*.parquet"))
    tables, found = [], set()
    for path in files:
        table = _read_kept(path, set(keys) - found)
        if table is not None:
            tables.append(table)
            found.update(pc.unique(table[FRAGMENT]).to_pylist())
    return tables, found, files


def lead_rows(sweep_dir: Path, records: list[dict[str, Any]] | None = None) -> pd.DataFrame:
    """One row per run × frame pair of a sweep, the lead vehicle's
    (:func:`ttc.evaluation.lead_rows`), without the columns no metric reads
    (:data:`ttc.evaluation.NOT_JUDGED_COLUMNS`), fragments in the dataset's order: kept ones
    read, the others computed (a fragment at a time: a run's rows are in one fragment) and
    kept in one file. ``records``: the sweep's :func:`experiments.store.list_records`, when
    already read. :class:`experiments.store.StoreError` names a corrupt fragment."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    frags = fragments(sweep_dir, records)
    known = _kept_schemas(sweep_dir, frags)
    before = len(known)
    schema = unified_schema(frags, known)
    if len(known) > before:
        _keep_schemas(sweep_dir, known, frags)
    if schema is None:
        return pd.DataFrame()
    columns = [c for c in schema.names if c not in ev.NOT_JUDGED_COLUMNS]
    key = hashlib.sha256(f"{schema}|{_code_key(columns)}".encode()).hexdigest()
    keys = [fragment_key(frag, key) for frag in frags]
    tables, found, files = _kept_rows(sweep_dir, keys)
    todo = [i for i, k in enumerate(keys) if k not in found]
    new = []
    for i, table in zip(todo, iter_tables([frags[i] for i in todo], schema, columns), strict=True):
        rows = table.to_pandas()
        lead = pa.Table.from_pandas(ev.lead_rows(rows) if len(rows) else rows, preserve_index=False)
        new.append(lead.append_column(FRAGMENT, pa.array([keys[i]] * lead.num_rows, pa.string())))
    if new:
        tables.append(pa.concat_tables(new, promote_options="permissive"))
        files.append(_keep(sweep_dir, tables[-1], [keys[i] for i in todo]))
    whole = pa.concat_tables(tables, promote_options="permissive")
    if len(files) > MAX_KEPT_FILES:  # one file of the rows used, the others removed
        _consolidate(sweep_dir, whole, keys, files)
    return in_fragment_order(whole, keys).drop_columns([FRAGMENT]).to_pandas()


def in_fragment_order(table: pa.Table, keys: list[str]) -> pa.Table:
    """``table``'s rows in the dataset's order: grouped by their :data:`FRAGMENT` key in the
    order of ``keys``, each fragment's rows in their order in ``table`` (a stable sort by key
    position). A fragment's rows lie in runs of consecutive rows, so the table is cut into
    those runs (zero-copy slices) and put together again: a row-wise take of ``grand`` 0–18's
    604,800 lead rows (58 columns, 15 of them strings) took 1.2 s."""
    position = pc.index_in(table[FRAGMENT], value_set=pa.array(keys)).to_numpy()
    if len(position) < 2 or not (np.diff(position) < 0).any():
        return table
    starts = np.flatnonzero(np.r_[True, np.diff(position) != 0])
    ends = np.r_[starts[1:], len(position)]
    order = np.argsort(position[starts], kind="stable")  # runs by key position, stable
    return pa.concat_tables([table.slice(starts[i], ends[i] - starts[i]) for i in order])
