"""Stage cache: hits, corrupt entries, errors in place, cooperative computation across processes;
the entry file format."""

from __future__ import annotations

import multiprocessing as mp
import time
from pathlib import Path

import numpy as np
import pytest

from ttc.engine.cache import StageCache, Task, cache_key
from ttc.engine.entry_file import MAGIC, EntryError, read_entry, write_entry


def _task(key: str, calls: list[int], value: float = 1.0) -> Task:
    def compute() -> dict:
        calls.append(1)
        return {"a": np.arange(5) * value}

    return Task("stage", key, compute)


def test_second_lookup_is_a_hit(tmp_path: Path) -> None:
    cache = StageCache(tmp_path)
    calls: list[int] = []
    key = cache_key("stage", {"p": 1})
    first = cache.get(_task(key, calls))
    second = cache.get(_task(key, calls))
    assert (first.cached, second.cached) == (False, True)
    assert len(calls) == 1
    np.testing.assert_array_equal(second.arrays["a"], np.arange(5))
    assert not list(tmp_path.rglob("*.tmp"))


def test_keys_depend_on_every_part() -> None:
    assert cache_key("s", {"a": 1, "b": 2}) == cache_key("s", {"b": 2, "a": 1})
    assert cache_key("s", {"a": 1}) != cache_key("s", {"a": 2})
    assert cache_key("s", 1) != cache_key("t", 1)


def test_corrupt_entry_is_recomputed(tmp_path: Path) -> None:
    cache = StageCache(tmp_path, memory_mb=0)  # a new process: nothing kept in memory
    calls: list[int] = []
    key = cache_key("stage", "corrupt")
    cache.get(_task(key, calls))
    path = cache.path("stage", key)
    path.write_bytes(path.read_bytes()[:40])  # truncated
    again = StageCache(tmp_path, memory_mb=0).get(_task(key, calls))
    assert not again.cached and len(calls) == 2
    np.testing.assert_array_equal(again.arrays["a"], np.arange(5))
    assert StageCache(tmp_path, memory_mb=0).get(_task(key, calls)).cached


def test_recent_entries_are_served_from_memory_read_only_within_budget(tmp_path: Path) -> None:
    calls: list[int] = []
    key = cache_key("stage", "memory")
    first = StageCache(tmp_path).get(_task(key, calls))
    StageCache(tmp_path).path("stage", key).unlink()  # gone from disk, kept in memory
    again = StageCache(tmp_path).get(_task(key, calls))
    assert again.cached and len(calls) == 1 and again.arrays["a"] is first.arrays["a"]
    assert not again.arrays["a"].flags.writeable
    # an entry larger than the budget is not kept
    small = StageCache(tmp_path, memory_mb=1e-5)  # 10 bytes
    big = cache_key("stage", "big")
    small.get(_task(big, calls))
    small.path("stage", big).unlink()
    assert small.load("stage", big) is None


def test_derived_work_outlives_a_stream_of_entries_beyond_their_budget(
    tmp_path: Path, monkeypatch
) -> None:
    """Entries (read again from their files when evicted) and derived work (computed again)
    are kept in pools of their own: a job streaming more entries than the entries' budget
    evicts the oldest entries, never the derived work."""
    from ttc.engine import cache as stage_cache

    monkeypatch.setattr(stage_cache, "_RECENT", stage_cache.RecentArrays())  # this test's own
    cache = StageCache(tmp_path, memory_mb=3 * 800 / 2**20)  # three 800-byte entries
    kept = cache.keep(("association", 0), {"points": np.arange(100.0)})  # 800 bytes
    calls: list[int] = []
    keys = [cache_key("stage", i) for i in range(5)]
    for i, key in enumerate(keys):  # 5 entries of 100 float64 streamed through
        cache.get(Task("stage", key, lambda i=i: calls.append(1) or {"a": np.full(100, i * 1.0)}))
    assert cache.recent(("association", 0)) is kept
    for key in keys:  # every entry still on disk
        cache.path("stage", key).unlink()
    in_memory = [cache.load("stage", key) is not None for key in keys]
    assert in_memory == [False, False, True, True, True]  # the last three, within budget
    assert StageCache(tmp_path, memory_mb=0).recent(("association", 0)) is None  # keeps none


def test_entry_with_foreign_key_is_rejected(tmp_path: Path) -> None:
    cache = StageCache(tmp_path, memory_mb=0)
    calls: list[int] = []
    k1, k2 = cache_key("stage", 1), cache_key("stage", 2)
    cache.get(_task(k1, calls))
    cache.path("stage", k2).parent.mkdir(parents=True, exist_ok=True)
    cache.path("stage", k1).rename(cache.path("stage", k2))
    assert cache.load("stage", k2) is None
    assert cache.corrupt_entries == 1


def test_disabled_cache_always_computes(tmp_path: Path) -> None:
    cache = StageCache(tmp_path, enabled=False)
    calls: list[int] = []
    key = cache_key("stage", "x")
    cache.get(_task(key, calls))
    cache.get(_task(key, calls))
    assert len(calls) == 2
    assert not any(tmp_path.iterdir())


def test_resolve_returns_listed_errors_in_place(tmp_path: Path) -> None:
    def broken() -> dict:
        raise FileNotFoundError("frame 3 missing")

    calls: list[int] = []
    tasks = [_task(cache_key("s", 1), calls), Task("s", cache_key("s", 2), broken)]
    out = StageCache(tmp_path).resolve(tasks, errors=(FileNotFoundError,))
    assert not isinstance(out[0], Exception)
    assert isinstance(out[1], FileNotFoundError)


def _worker(directory: str, n: int, queue) -> None:
    cache = StageCache(directory)
    computed = []

    def make(i: int) -> Task:
        def compute() -> dict:
            time.sleep(0.05)
            computed.append(i)
            return {"v": np.array([i])}

        return Task("slow", cache_key("slow", i), compute)

    results = cache.resolve([make(i) for i in range(n)])
    assert [int(r.arrays["v"][0]) for r in results] == list(range(n))
    queue.put(computed)


def test_two_processes_split_the_work(tmp_path: Path) -> None:
    """Two workers needing the same 16 entries compute each of them once between them."""
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    procs = [ctx.Process(target=_worker, args=(str(tmp_path), 16, queue)) for _ in range(2)]
    for proc in procs:
        proc.start()
    done = [queue.get(timeout=60) for _ in procs]
    for proc in procs:
        proc.join(timeout=60)
        assert proc.exitcode == 0
    computed = sorted(done[0] + done[1])
    assert computed == list(range(16))  # no entry computed twice


def test_entry_file_round_trip_of_every_stored_kind(tmp_path: Path) -> None:
    """Every dtype and shape the stages store (numbers, booleans, strings, 0-d, empty,
    non-contiguous views) comes back equal and writable, with its key; a file cut anywhere,
    another format or a foreign key is never read as good."""
    arrays = {"f4": np.arange(12, dtype=np.float32).reshape(3, 4), "i8": np.array(5),
              "u1": np.arange(256, dtype=np.uint8).reshape(8, 32), "b": np.array([True, False]),
              "U": np.array(["lead", "other_lane"]), "empty": np.zeros((0, 3), np.int32),
              "view": np.arange(12.0).reshape(3, 4).T, "f8": np.array(3.5)}  # fmt: skip
    path = tmp_path / "entry.arr"
    with open(path, "wb") as handle:
        write_entry(handle, "k" * 32, arrays)
    key, got = read_entry(path)
    assert key == "k" * 32 and list(got) == list(arrays)
    for name, value in arrays.items():
        assert got[name].dtype == value.dtype and got[name].shape == value.shape, name
        np.testing.assert_array_equal(got[name], value)
        assert got[name].flags.writeable
    whole = path.read_bytes()
    for cut in range(0, len(whole)):  # every truncation
        path.write_bytes(whole[:cut])
        with pytest.raises(EntryError):
            read_entry(path)
    np.savez(tmp_path / "old.npz", a=np.arange(3))  # the earlier format
    with pytest.raises(EntryError):
        read_entry(tmp_path / "old.npz")
    with pytest.raises(TypeError, match="'obj'"), open(path, "wb") as handle:
        write_entry(handle, "k", {"obj": np.array([{}, 1], dtype=object)})


def test_an_old_npz_entry_is_not_read(tmp_path: Path) -> None:
    """An entry of the earlier ``.npz`` format beside the new one is ignored: computed again."""
    cache = StageCache(tmp_path, memory_mb=0)
    calls: list[int] = []
    key = cache_key("stage", "old")
    path = cache.path("stage", key)
    path.parent.mkdir(parents=True)
    np.savez(path.with_suffix(".npz"), a=np.arange(5), __cache_key__=np.array(key))
    assert not cache.get(_task(key, calls)).cached and len(calls) == 1
    assert path.read_bytes().startswith(MAGIC)
