"""Tables the end-of-sweep summary keeps per fragment of the store, in ``<sweep>/.summary/``.

A fragment of the append-only store never changes, so what the summary derives from it (its
lead rows: :mod:`experiments.summary.lead_rows`; its runs' metrics: :mod:`experiments.summary.run_metrics`)
is computed once and kept under a key of everything it depends on. The tables a summary
computes go into **one** kept file per kind (a :data:`FRAGMENT` column names each row's key;
the file's metadata lists its keys), not one per fragment: a later summary reads a few files,
not one per fragment (on a 595-fragment folder, 595 reads took 2.0 of the summary's 4.6 s).
When more than :data:`MAX_KEPT_FILES` of a kind are there, the summary writes the rows it used
as one file and removes the others. A kept file that cannot be read is left out (its
fragments computed again); a key found in two files is taken from one; deleting ``.summary/``
is always safe.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from experiments.store.files import write_parquet_atomic

#: Folder of the kept tables, under the sweep folder.
CACHE_DIR = ".summary"
#: Column of a kept file naming each row's fragment key.
FRAGMENT = "__fragment"
#: Schema metadata of a kept file: the JSON list of the keys it holds.
KEYS_META = b"ttc_bench_lead_keys"
#: Kept files of a kind a summary reads before it writes the rows it used as one.
MAX_KEPT_FILES = 8


def kept_files(sweep_dir: Path, kind: str) -> dict[Path, set[str]]:
    """The kept files of ``kind`` (``lead``, ``metrics``) with the keys each lists, read from
    their metadata only (a file whose metadata cannot be read is left out)."""
    out = {}
    for path in sorted((Path(sweep_dir) / CACHE_DIR).glob(f"{kind}-*.parquet")):
        try:
            meta = pq.read_schema(path).metadata or {}
            out[path] = set(json.loads(meta.get(KEYS_META, b"[]")))
        except (OSError, ValueError, pa.ArrowException):
            continue
    return out


def read_kept(
    path: Path, wanted: set[str], columns: list[str] | None = None, whole: bool = False
) -> pa.Table | None:
    """The rows of a kept file whose key is in ``wanted`` (their ``columns`` and
    :data:`FRAGMENT`; None: all), or None when it cannot be read. ``whole``: every key of the
    file is wanted (no filter: a filter copies every column)."""
    try:
        read = None
        if columns is not None:  # only those the file has (its footer read once more)
            names = pq.read_schema(path).names
            read = [c for c in [*columns, FRAGMENT] if c in names]
        table = pq.read_table(path, columns=read)
    except (OSError, ValueError, pa.ArrowException):
        return None
    if FRAGMENT not in table.column_names:
        return None
    return table if whole else of_keys(table, wanted)


def of_keys(table: pa.Table, keys: set[str]) -> pa.Table:
    """The rows of ``table`` whose :data:`FRAGMENT` key is in ``keys`` (a copy of every
    column: take the columns wanted first)."""
    return table.filter(pc.is_in(table[FRAGMENT], pa.array(sorted(keys), pa.string())))


def kept_path(sweep_dir: Path, kind: str, keys: list[str], suffix: str = ".parquet") -> Path:
    """The kept file of ``kind`` that holds the rows of ``keys``: named by their digest
    (``<sweep>/.summary/<kind>-<digest><suffix>``)."""
    digest = hashlib.sha256("|".join(keys).encode()).hexdigest()[:32]
    return Path(sweep_dir) / CACHE_DIR / f"{kind}-{digest}{suffix}"


def keep(sweep_dir: Path, kind: str, table: pa.Table, keys: list[str]) -> Path | None:
    """Write ``table`` (rows of ``keys``, :data:`FRAGMENT` column included) as one kept file
    of ``kind``, named by its keys (:func:`kept_path`); its path, or None where the folder is
    read-only."""
    path = kept_path(sweep_dir, kind, keys)
    with contextlib.suppress(OSError):  # a read-only sweep folder: nothing kept
        write_parquet_atomic(table, path, {KEYS_META: json.dumps(keys).encode()})
        return path
    return None


def consolidate(
    sweep_dir: Path, kind: str, whole: pa.Table, keys: list[str], files: list[Path]
) -> None:
    """Keep ``whole`` (the rows of ``keys``) as one file and remove the other ``files``."""
    kept = keep(sweep_dir, kind, whole, keys)
    for path in files if kept is not None else ():
        if path != kept:
            with contextlib.suppress(OSError):
                path.unlink()


def kept_rows(
    files: dict[Path, set[str]],
    keys: list[str],
    columns: list[str] | None = None,
    each_once: bool = True,
) -> tuple[list[pa.Table], set[str]]:
    """(tables of the kept rows of ``keys`` in ``files`` (:func:`kept_files`), one table per
    file read, in the order of ``files``; the keys found). ``each_once``: each key read from
    one file; else from every file that holds it (for a reader that checks which copy is
    still valid)."""
    tables, found = [], set()
    for path, listed in files.items():
        wanted = (listed & set(keys)) - (found if each_once else set())
        table = read_kept(path, wanted, columns, whole=wanted == listed) if wanted else None
        if table is not None:
            tables.append(table)
            found.update(pc.unique(table[FRAGMENT]).to_pylist())
    return tables, found


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
