"""Every run record of a sweep, listed without reading 28,000 JSON files each time.

The records' JSON files (``runs/<run_id>.json``) stay the authority. A listing keeps the
records it had to read from their files, each with its file's identity (inode, size, mtime
in ns: a record is only ever replaced by a rename, which makes a new inode), in a new index
file ``<sweep>/.records/index-<sha>.pkl`` (written atomically, never rewritten); the next
listing stats every record file (one ``scandir``) and reads only those whose identity no
index holds. The store writes an index file of the records it writes
(:func:`experiments.store.files.save_records`: a batch's, the plan's skipped settings'), so
a sweep's own summary parses none of them. ``ttc-bench compact`` folds the index files into
one. An unreadable index file is ignored (its records are read from their files); deleting
``.records/`` is always safe.
Measured on a synthetic sweep of 28,000 records (2 cores, loaded by other work): reading and
parsing every JSON file 4.1-9.8 s; from the index 1.9 s. (A sweep folder is the user's own
data: its pickles, like ``.plan/``'s, are trusted.)
"""

from __future__ import annotations

import json
import os
import pickle
from pathlib import Path
from typing import Any

from experiments.host.heap import collection_paused
from experiments.store.files import INDEX_DIR, RUNS_DIR, Identity, keep_index, write_index

#: A listing writes an index file when it read at least this many records from their files.
WRITE_AT_LEAST = 64


def _mtime(path: Path) -> int:
    """A file's mtime (ns), 0 when it vanished (a compaction removed it)."""
    try:
        return path.stat().st_mtime_ns
    except OSError:
        return 0


def _load_index(sweep_dir: Path, wanted: dict[str, Identity]) -> dict[str, dict[str, Any]]:
    """``{file name: record}`` of the records ``wanted`` (file name → identity of its file now)
    that a readable index file holds at that identity. The newest index files are read first,
    and no more once every one is found (an index of records since replaced, as a copied
    sweep folder's, 233 MB for ``grand`` 0–18, is then not read at all)."""
    found: dict[str, dict[str, Any]] = {}
    paths = sorted((Path(sweep_dir) / INDEX_DIR).glob("index-*.pkl"))
    for path in sorted(paths, key=_mtime, reverse=True):
        if len(found) == len(wanted):
            break
        try:
            entries = pickle.loads(path.read_bytes())
        except Exception:  # noqa: BLE001 - damaged or vanished (compacted): read the files
            continue
        for name, (identity, record) in entries.items():
            if name not in found and wanted.get(name) == tuple(identity):
                found[name] = record
    return found


def list_with_identities(sweep_dir: Path) -> dict[str, tuple[Identity, dict[str, Any]]]:
    """``{file name: (identity, record)}`` of every readable record, by file name; writes an
    index file of those read from their files when they are :data:`WRITE_AT_LEAST` or more
    (nothing when the folder is read-only). The collector paused meanwhile
    (:func:`experiments.host.heap.collection_paused`)."""
    with collection_paused():
        return _listed(sweep_dir)


def _listed(sweep_dir: Path) -> dict[str, tuple[Identity, dict[str, Any]]]:
    """:func:`list_with_identities`."""
    runs_dir = Path(sweep_dir) / RUNS_DIR
    try:
        with os.scandir(runs_dir) as scan:
            entries = sorted((e for e in scan if e.name.endswith(".json")), key=lambda e: e.name)
    except FileNotFoundError:
        return {}
    identities: dict[str, Identity] = {}
    for entry in entries:
        try:
            stat = entry.stat()
        except OSError:
            continue
        identities[entry.name] = (stat.st_ino, stat.st_size, stat.st_mtime_ns)
    known = _load_index(sweep_dir, identities) if identities else {}
    out: dict[str, tuple[Identity, dict[str, Any]]] = {}
    fresh: dict[str, tuple[Identity, dict[str, Any]]] = {}
    for name, identity in identities.items():
        record = known.get(name)
        if record is None:
            try:
                record = json.loads((runs_dir / name).read_text())
            except (OSError, ValueError):
                continue
            fresh[name] = (identity, record)
        out[name] = (identity, record)
    if len(fresh) >= WRITE_AT_LEAST:
        keep_index(sweep_dir, fresh)
    return out


def list_records(sweep_dir: Path) -> list[dict[str, Any]]:
    """Every readable run record of a sweep, sorted by run id (its file name)."""
    return [record for _, record in list_with_identities(sweep_dir).values()]


def fold_index(sweep_dir: Path) -> int:
    """Replace the index files by one of every record listed now; how many files removed."""
    old = list((Path(sweep_dir) / INDEX_DIR).glob("index-*.pkl"))
    entries = list_with_identities(sweep_dir)
    if not entries:
        return 0
    new = write_index(sweep_dir, entries)
    removed = 0
    for path in old:
        if path != new:
            path.unlink(missing_ok=True)
            removed += 1
    return removed
