"""On-disk cache of the expensive pipeline stages, shared by jobs, workers and sweeps.

An entry is a dict of numpy arrays stored as one ``.arr`` file (:mod:`ttc.engine.entry_file`:
read in one call, ≈ 0.04 ms, where an ``.npz`` took 0.4-0.55 ms), named by the hash of its key
(the stage name plus the identity of the input files and the stage's resolved parameters);
the file holds the key too. Entries of the earlier ``.npz`` format are not read (computed
again once). Safety under concurrent workers:

* writes go to a temporary file in the same folder and are renamed into place, so a reader
  sees a whole entry or none;
* a corrupt or foreign entry (unreadable, or storing another key) is deleted and recomputed;
* computation is *cooperative*: before computing an entry a worker takes a non-blocking
  ``flock`` on ``<entry>.lock``. If another worker holds it, the caller can do other work first
  (:meth:`StageCache.resolve` defers such entries) and only then wait, so two workers that
  start on the same detector split its frames instead of computing each of them twice.

Each process also keeps the entries it loaded or computed most recently in memory (up to
``memory_mb``, least recently used out first), as read-only arrays: a worker that runs many
settings in a row loads the frames' objects, lane points and shared keypoints once. An entry's
key names the content of its input files and parameters, so a kept entry cannot go stale.
Work derived from entries and never written (:meth:`StageCache.keep`: each frame's lidar
association, each box pair's lidar TTC) is kept in a pool of its own (up to
:data:`DERIVED_MB`): an evicted entry is read again from its file in milliseconds, evicted
derived work is computed again, so the entries a job streams never push it out.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import time
import warnings
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ttc.atomic import atomic_write
from ttc.engine.entry_file import EntryError, read_entry, write_entry

try:
    import fcntl
except ImportError:  # pragma: no cover - non-POSIX systems: no cross-process locking
    fcntl = None

Arrays = dict[str, np.ndarray]
#: Suffix of an entry's file (:mod:`ttc.engine.entry_file`).
SUFFIX = ".arr"
#: Default memory budget of a process's recently used entries (MB; 0 disables): what a
#: worker keeps of the frames its jobs stream (``grand`` 0-18: 270 MB of entries in all).
MEMORY_MB = 96
#: Memory budget of a process's derived work (MB; :meth:`StageCache.keep`): ``grand``
#: 0-18 keeps ≈ 2.3 MB of it per worker, a 78-frame sweep ≈ 9 MB per lidar setting.
DERIVED_MB = 64


def _nbytes(arrays: Arrays) -> int:
    return sum(a.nbytes for a in arrays.values())


class RecentArrays:
    """Least-recently-used sets of arrays of this process (by any hashable name), bounded by
    their bytes per *pool* (each pool its own order and budget); kept arrays are read-only."""

    def __init__(self) -> None:
        self.pools: dict[str, OrderedDict[Hashable, Arrays]] = {}
        self.nbytes: dict[str, int] = {}

    def get(self, name: Hashable, pool: str = "") -> Arrays | None:
        entries = self.pools.get(pool)
        arrays = entries.get(name) if entries is not None else None
        if arrays is not None:
            entries.move_to_end(name)
        return arrays

    def put(self, name: Hashable, arrays: Arrays, budget: int, pool: str = "") -> Arrays:
        """Keep ``arrays`` (made read-only) in ``pool`` and return them; evict the pool's
        least recently used beyond ``budget`` bytes."""
        arrays = {field: np.asarray(value) for field, value in arrays.items()}  # as loaded
        for array in arrays.values():
            array.flags.writeable = False
        size = _nbytes(arrays)
        if size > budget:
            return arrays
        entries = self.pools.setdefault(pool, OrderedDict())
        held = self.nbytes.get(pool, 0)
        if name in entries:
            held -= _nbytes(entries.pop(name))
        entries[name] = arrays
        held += size
        while held > budget:
            held -= _nbytes(entries.popitem(last=False)[1])
        self.nbytes[pool] = held
        return arrays


_RECENT = RecentArrays()
#: The pool of :data:`_RECENT` holding derived work (:meth:`StageCache.keep`).
DERIVED = "derived"
#: Cache folders this process found unwritable (warned once each).
_UNWRITABLE: set[str] = set()


def cache_key(stage: str, *parts: Any) -> str:
    """Stable hex digest of a stage name and JSON-serialisable key parts."""
    text = json.dumps([stage, *parts], sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:32]


@dataclass
class Lookup:
    """What one cache request returned: the arrays, whether they came from disk, time (ms),
    and the entry's key (what its content depends on)."""

    arrays: Arrays
    cached: bool
    ms: float
    key: str = ""


@dataclass
class Task:
    """A cache entry to produce: ``compute()`` returns its arrays when it is not on disk."""

    stage: str
    key: str
    compute: Callable[[], Arrays]
    result: Lookup | None = field(default=None, repr=False)


class StageCache:
    """Cache rooted at ``directory``; ``directory=None`` or ``enabled=False`` computes always."""

    def __init__(
        self, directory: Path | str | None, enabled: bool = True, memory_mb: float = MEMORY_MB
    ) -> None:
        self.directory = Path(directory) if directory is not None else None
        self.enabled = enabled and directory is not None
        self.memory_bytes = int(memory_mb * 2**20) if self.enabled else 0
        # a cache keeping no entries in memory keeps no derived work either
        self.derived_bytes = int(DERIVED_MB * 2**20) if self.memory_bytes else 0
        self.corrupt_entries = 0
        self.writable = self.enabled and str(self.directory) not in _UNWRITABLE

    def _name(self, stage: str, key: str) -> tuple[str, str]:
        return (str(self.directory), f"{stage}/{key}")

    # -- paths -------------------------------------------------------------------------------
    def path(self, stage: str, key: str) -> Path:
        assert self.directory is not None
        return self.directory / stage / key[:2] / f"{key}{SUFFIX}"

    # -- read / write ------------------------------------------------------------------------
    def load(self, stage: str, key: str) -> Arrays | None:
        """The stored arrays, or None when absent; a corrupt entry is deleted and None returned."""
        if not self.enabled:
            return None
        if self.memory_bytes and (kept := _RECENT.get(self._name(stage, key))) is not None:
            return kept
        path = self.path(stage, key)
        try:
            stored, arrays = read_entry(path)
        except FileNotFoundError:
            return None
        except (OSError, EntryError):
            self._discard(path)
            return None
        if stored != key:
            self._discard(path)
            return None
        return self._remember(stage, key, arrays)

    def _remember(self, stage: str, key: str, arrays: Arrays) -> Arrays:
        if not self.memory_bytes:
            return arrays
        return _RECENT.put(self._name(stage, key), arrays, self.memory_bytes)

    def recent(self, name: Hashable) -> Arrays | None:
        """Arrays this process kept under ``name`` (:meth:`keep`), or None: work derived from
        cached entries and shared by the jobs a worker runs, never written to disk."""
        return _RECENT.get(name, DERIVED) if self.derived_bytes else None

    def keep(self, name: Hashable, arrays: Arrays) -> Arrays:
        """Keep ``arrays`` in this process's memory under ``name`` (a name that holds the keys
        of every input, so it cannot go stale); the read-only arrays kept."""
        if not self.derived_bytes:
            return arrays
        return _RECENT.put(name, arrays, self.derived_bytes, DERIVED)

    def store(self, stage: str, key: str, arrays: Arrays) -> None:
        """Write an entry atomically (temporary file + rename)."""
        if not self.writable:
            return
        path = self.path(stage, key)

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as handle:
                write_entry(handle, key, arrays)

        try:
            atomic_write(path, write)
        except OSError as exc:  # read-only or full: go on without storing
            self._unwritable(exc)

    def _unwritable(self, exc: OSError) -> None:
        """Stop writing to this cache folder in this process, with one warning."""
        self.writable = False
        if str(self.directory) not in _UNWRITABLE:
            _UNWRITABLE.add(str(self.directory))
            warnings.warn(
                f"stage cache {self.directory} cannot be written ({exc.strerror or exc}): "
                "computing without caching",
                RuntimeWarning,
                stacklevel=3,
            )

    def _discard(self, path: Path) -> None:
        self.corrupt_entries += 1
        with contextlib.suppress(FileNotFoundError):
            path.unlink()

    # -- locking -----------------------------------------------------------------------------
    @contextlib.contextmanager
    def _lock(self, stage: str, key: str, blocking: bool) -> Iterator[bool]:
        if not self.writable or fcntl is None:
            yield True
            return
        lock_path = self.path(stage, key).with_suffix(".lock")
        try:
            lock_path.parent.mkdir(parents=True, exist_ok=True)
            handle = open(lock_path, "a+b")  # noqa: SIM115 (closed below)
        except OSError as exc:
            self._unwritable(exc)
            yield True
            return
        with handle:
            flags = fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB)
            try:
                fcntl.flock(handle, flags)
            except BlockingIOError:
                yield False
                return
            try:
                yield True
            finally:
                fcntl.flock(handle, fcntl.LOCK_UN)

    # -- high level --------------------------------------------------------------------------
    def get(self, task: Task, blocking: bool = True) -> Lookup | None:
        """Load or compute ``task``'s entry; None when not blocking and another worker has it."""
        if task.result is not None:
            return task.result
        start = time.perf_counter()
        arrays = self.load(task.stage, task.key)
        if arrays is None:
            with self._lock(task.stage, task.key, blocking) as locked:
                if not locked:
                    return None
                arrays = self.load(task.stage, task.key)  # another worker may have finished
                if arrays is None:
                    start = time.perf_counter()
                    arrays = task.compute()
                    self.store(task.stage, task.key, arrays)
                    arrays = self._remember(task.stage, task.key, arrays)
                    ms = 1e3 * (time.perf_counter() - start)
                    task.result = Lookup(arrays, False, ms, task.key)
                    return task.result
        task.result = Lookup(arrays, True, 1e3 * (time.perf_counter() - start), task.key)
        return task.result

    def resolve(
        self, tasks: Sequence[Task], errors: tuple[type[Exception], ...] = ()
    ) -> list[Lookup | Exception]:
        """Produce every task, deferring those another worker is computing right now.

        An exception of a type in ``errors`` raised by a task's computation is returned in
        that task's place (e.g. one unreadable frame), so the other tasks still complete.
        """
        outcome: dict[int, Lookup | Exception] = {}
        deferred = []
        for i, task in enumerate(tasks):
            try:
                if self.get(task, blocking=False) is None:
                    deferred.append(i)
            except errors as exc:
                outcome[i] = exc
        for i in deferred:
            try:
                self.get(tasks[i], blocking=True)
            except errors as exc:
                outcome[i] = exc
        return [outcome.get(i, task.result) for i, task in enumerate(tasks)]  # type: ignore[misc]
