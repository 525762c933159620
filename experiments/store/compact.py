"""A sweep's small rows files merged into larger ones, atomically (``ttc-bench compact``,
:mod:`experiments.tools.compact_command`).

Consecutive fragments (in the dataset's order, :func:`experiments.store.dataset.fragments`)
are merged into ``runs/compact-<first 12 hex digits of its SHA-256>.parquet`` of at most
``--target-rows`` rows, their live rows in their order (so every reader gets the same rows,
byte for byte, in the same order), in row groups of one detector × descriptor. Each merged
file is complete before any record names it; then, under the exclusive store lock (no writer
between the check and the change), the records of its runs are checked to still name the
old files and are repointed one by one (each record names one valid file at every moment:
a reader sees each run once), and the old files are removed. Rows no record names (a run
recomputed since, a job killed between its rows and its records) are dropped, so
``runs/*.parquet`` then holds exactly the live rows; the records' index files are folded into
one (:mod:`experiments.store.record_index`). A corrupt fragment is named and nothing
is changed. Safe while sweeps write into the folder.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import os
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from experiments.store.dataset import (
    Fragment,
    check_fragments,
    fragments,
    iter_tables,
    unified_schema,
)
from experiments.store.files import (
    LEGACY_MERGED_FILES,
    RUNS_DIR,
    StoreError,
    read_record,
    rows_path,
    run_paths,
    store_lock,
    write_json_atomic,
)
from experiments.store.record_index import fold_index, list_records
from ttc.atomic import remove_stale_temporaries, temporary_prefix

try:
    import fcntl
except ImportError:  # pragma: no cover - non-POSIX systems: no cross-process locking
    fcntl = None

#: Rows of a merged file, at most (a fragment larger than this is left alone).
TARGET_ROWS = 1_000_000
#: Columns of a row group: consecutive rows of one detector × descriptor.
PARTITION_COLUMNS = ("detector", "descriptor")
#: Consecutive rows of one partition are written as one row group up to this many rows.
ROW_GROUP_ROWS = 200_000
#: Held (non-blocking) by the one compaction of a folder.
COMPACT_LOCK = ".compact.lock"


@dataclass
class Compaction:
    """What a compaction did: fragments merged, files written, runs repointed, files
    removed (merged ones and those no record named)."""

    merged: int = 0
    written: int = 0
    runs: int = 0
    removed: int = 0
    skipped_groups: int = 0


def groups_to_merge(frags: list[Fragment], target_rows: int) -> list[list[Fragment]]:
    """Runs of consecutive fragments of at most ``target_rows`` live rows together; a group
    of one is kept only when its file also holds rows no record names (dropped by the
    rewrite)."""
    groups: list[list[Fragment]] = []
    current: list[Fragment] = []
    for frag in frags:
        if current and sum(f.rows for f in current) + frag.rows > target_rows:
            groups.append(current)
            current = []
        current.append(frag)
    if current:
        groups.append(current)
    return [g for g in groups if len(g) > 1 or _holds_dead_rows(g[0])]


def _holds_dead_rows(frag: Fragment) -> bool:
    return pq.ParquetFile(frag.path).metadata.num_rows != frag.rows


def _partitions(table: pa.Table) -> Iterator[tuple[tuple, pa.Table]]:
    """``(key, rows)`` of each run of consecutive rows of one :data:`PARTITION_COLUMNS`
    value (the whole table, key ``()``, when it lacks those columns)."""
    if not set(PARTITION_COLUMNS) <= set(table.column_names) or table.num_rows == 0:
        yield (), table
        return
    keys = table.select(list(PARTITION_COLUMNS)).to_pandas()
    change = (keys != keys.shift()).any(axis=1).to_numpy()
    starts = [*change.nonzero()[0].tolist(), len(keys)]
    for begin, end in itertools.pairwise(starts):
        yield tuple(keys.iloc[begin]), table.slice(begin, end - begin)


def _write_rows(path: str, group: list[Fragment]) -> None:
    """Stream the live rows of ``group`` into one parquet file at ``path``, a row group per
    run of consecutive rows of one partition (at most :data:`ROW_GROUP_ROWS` rows)."""
    schema = unified_schema(group)
    buffer: list[pa.Table] = []
    buffered: tuple | None = None
    with pq.ParquetWriter(path, schema) as writer:
        for table in iter_tables(group, schema):
            for key, piece in _partitions(table):
                if buffer and (
                    key != buffered or sum(t.num_rows for t in buffer) >= ROW_GROUP_ROWS
                ):
                    writer.write_table(pa.concat_tables(buffer), row_group_size=ROW_GROUP_ROWS)
                    buffer.clear()
                buffer.append(piece)
                buffered = key
        if buffer:
            writer.write_table(pa.concat_tables(buffer), row_group_size=ROW_GROUP_ROWS)


def write_merged(group: list[Fragment], runs_dir: Path) -> tuple[Path, str]:
    """Write the live rows of ``group`` (in order) into one new file, named by its content;
    (its path, SHA-256)."""
    fd, tmp = tempfile.mkstemp(dir=runs_dir, prefix=temporary_prefix("compact"), suffix=".tmp")
    os.close(fd)
    try:
        _write_rows(tmp, group)
        with open(tmp, "rb") as handle:
            sha = hashlib.file_digest(handle, "sha256").hexdigest()
        os.chmod(tmp, 0o644)
        path = runs_dir / f"compact-{sha[:12]}.parquet"
        os.replace(tmp, path)
        return path, sha
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def swap(sweep_dir: Path, group: list[Fragment], path: Path, sha: str) -> bool:
    """Repoint the records of ``group``'s runs to the merged file and remove the old files,
    under the exclusive store lock; False (the merged file removed, nothing changed) when a
    record no longer names its old file (the run was recomputed meanwhile)."""
    with store_lock(sweep_dir, exclusive=True):
        records = {}
        for frag in group:
            for run_id in frag.n_rows:
                record = read_record(sweep_dir, run_id)
                if (record is None or record.get("status") != "ok"
                        or rows_path(sweep_dir, record) != frag.path
                        or record.get("rows_sha256") != frag.sha256):  # fmt: skip
                    path.unlink(missing_ok=True)
                    return False
                records[run_id] = record
        for run_id, record in records.items():
            record.update(rows_file=path.name, rows_sha256=sha)
            write_json_atomic(record, run_paths(sweep_dir, run_id)[1], indent=None)
        for frag in group:
            if frag.path != path:
                frag.path.unlink(missing_ok=True)
    return True


def remove_dead_files(sweep_dir: Path) -> int:
    """Remove rows files no ``ok`` record names, temporary files of killed writers
    (:func:`ttc.atomic.remove_stale_temporaries`) and the merged files of earlier versions;
    how many."""
    runs_dir = Path(sweep_dir) / RUNS_DIR
    removed = remove_stale_temporaries(runs_dir)
    for name in LEGACY_MERGED_FILES:
        if (Path(sweep_dir) / name).is_file():
            (Path(sweep_dir) / name).unlink()
            removed += 1
    with store_lock(sweep_dir, exclusive=True):
        named = {
            rows_path(sweep_dir, r) for r in list_records(sweep_dir) if r.get("status") == "ok"
        }
        for path in runs_dir.glob("*.parquet"):
            if path not in named:
                path.unlink()
                removed += 1
    return removed


def compact(sweep_dir: Path, target_rows: int = TARGET_ROWS) -> Compaction:
    """Compact a sweep folder (module docstring); :class:`StoreError` names a corrupt
    fragment (nothing changed) or says another compaction of the folder runs."""
    sweep_dir = Path(sweep_dir)
    runs_dir = sweep_dir / RUNS_DIR
    if not runs_dir.is_dir():
        raise StoreError(sweep_dir, f"no {RUNS_DIR}/ folder: not a sweep folder")
    with open(runs_dir / COMPACT_LOCK, "a") as lock:
        if fcntl is not None:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise StoreError(runs_dir / COMPACT_LOCK, "another compaction runs") from None
        frags = fragments(sweep_dir)
        check_fragments(frags)
        done = Compaction()
        for group in groups_to_merge(frags, target_rows):
            path, sha = write_merged(group, runs_dir)
            if swap(sweep_dir, group, path, sha):
                done.merged += len(group)
                done.written += 1
                done.runs += sum(len(f.n_rows) for f in group)
            else:
                done.skipped_groups += 1
        done.removed = remove_dead_files(sweep_dir) + fold_index(sweep_dir)
    return done
