"""The record listing's index files (:mod:`experiments.store.record_index`): what the store
writes is listed without parsing its files, a changed record is never hidden, the newest index
files are read first, the collector is paused while listing."""

from __future__ import annotations

import os
import shutil

import pandas as pd
import pytest

from experiments import store
from tests.test_store import record, rows_of, synthetic_sweep


def test_the_records_index_never_hides_a_changed_record(tmp_path, monkeypatch) -> None:
    """Listing through the index gives what reading every record file gives, after a record
    was replaced, with a damaged index file, and after ``compact`` folded the index."""
    import json

    from experiments.store import record_index

    monkeypatch.setattr(record_index, "WRITE_AT_LEAST", 1)
    synthetic_sweep(tmp_path)
    shutil.rmtree(tmp_path / record_index.INDEX_DIR)  # the listing's own index files only

    def from_files() -> list[dict]:
        files = sorted((tmp_path / store.RUNS_DIR).glob("*.json"))
        return [json.loads(p.read_text()) for p in files]

    assert store.list_records(tmp_path) == from_files()
    index_dir = tmp_path / record_index.INDEX_DIR
    assert len(list(index_dir.glob("index-*.pkl"))) == 1
    store.save_run(tmp_path, {"run_id": "f1", "status": "ok", "n_rows": 1}, rows_of("f1", 1, 7.0))
    listed = store.list_records(tmp_path)
    assert listed == from_files() and listed[-1]["status"] == "ok"
    next(index_dir.glob("index-*.pkl")).write_bytes(b"not a pickle")
    assert store.list_records(tmp_path) == from_files()
    store.compact(tmp_path)
    assert len(list(index_dir.glob("index-*.pkl"))) == 1
    assert store.list_records(tmp_path) == from_files()


def test_the_records_index_reads_the_newest_index_files_until_every_record_is_found(
    tmp_path, monkeypatch
) -> None:
    """An index of records since replaced (a copied sweep folder's: every file a new inode)
    is not read once newer index files hold every record; an older index that holds a record
    the newer ones lack is read, and no record file is parsed again."""
    import json
    import pickle

    from experiments.store import record_index

    monkeypatch.setattr(record_index, "WRITE_AT_LEAST", 1)
    synthetic_sweep(tmp_path)
    index_dir = tmp_path / record_index.INDEX_DIR
    shutil.rmtree(index_dir)  # the listing's own index files only
    store.list_records(tmp_path)
    (stale,) = index_dir.glob("index-*.pkl")
    for path in (tmp_path / store.RUNS_DIR).glob("*.json"):  # copies: new inodes
        copy = path.with_suffix(".tmp")
        copy.write_text(path.read_text())
        os.replace(copy, path)
    os.utime(stale, ns=(1, 1))
    files = sorted((tmp_path / store.RUNS_DIR).glob("*.json"))
    expected = [json.loads(p.read_text()) for p in files]
    assert store.list_records(tmp_path) == expected  # each record file read: a new index
    store.save_run(tmp_path, {"run_id": "g1", "status": "ok", "n_rows": 1}, rows_of("g1", 1, 7.0))
    files = sorted((tmp_path / store.RUNS_DIR).glob("*.json"))
    expected = [json.loads(p.read_text()) for p in files]
    assert store.list_records(tmp_path) == expected and "g1" in {r["run_id"] for r in expected}
    assert len(list(index_dir.glob("index-*.pkl"))) == 3
    loaded, parsed = [], []
    real_loads, real_json = pickle.loads, json.loads
    monkeypatch.setattr(record_index.pickle, "loads", lambda b: loaded.append(1) or real_loads(b))
    monkeypatch.setattr(record_index.json, "loads", lambda t: parsed.append(1) or real_json(t))
    assert store.list_records(tmp_path) == expected
    assert len(loaded) == 2 and not parsed  # g1's index, then the copies'; not the stale one


def test_the_records_the_store_writes_are_listed_without_parsing_their_files(
    tmp_path, monkeypatch
) -> None:
    """A batch's records (and the plan's skipped ones, the same writer) come with an index
    file made as they are written: the next listing parses none of them and gives exactly
    what the files hold (JSON round trip: a tuple a list, a path a string); a record another
    writer replaced since is read from its file; with the index folder read-only the batch is
    stored all the same."""
    import json

    from experiments.store import record_index

    inputs = json.dumps([["calib.txt", 502, 17956875946]] * 20)  # a batch's, long
    odd = {"run_id": "a1", "status": "ok", "n_rows": 3, "pair": (1, 2), "where": tmp_path,
           "inputs": inputs}  # fmt: skip
    store.save_batch(tmp_path, "batch-a", [odd, {**record("a2", 2), "inputs": inputs}],
                     pd.concat([rows_of("a1", 3, 10.0), rows_of("a2", 2, 20.0)]))  # fmt: skip
    files = sorted((tmp_path / store.RUNS_DIR).glob("*.json"))
    expected = [json.loads(p.read_text()) for p in files]
    assert expected[0]["pair"] == [1, 2] and expected[0]["where"] == str(tmp_path)
    real_json, parsed = json.loads, []
    monkeypatch.setattr(record_index.json, "loads", lambda t: parsed.append(1) or real_json(t))
    listed = store.list_records(tmp_path)
    assert listed == expected and not parsed
    assert listed[0]["inputs"] is listed[1]["inputs"]  # stored once in the index file
    names = {k for r in listed for k in r}  # and so is each field name: one object each
    assert len({id(k) for r in listed for k in r}) == len(names)
    # another writer replaces a2's record (a new file): read from the file, a1 from the index
    store.write_json_atomic({**expected[1], "status": "failed"}, files[1], indent=None)
    listed = store.list_records(tmp_path)
    assert [r["status"] for r in listed] == ["ok", "failed"] and len(parsed) == 1
    monkeypatch.undo()
    index_dir = tmp_path / record_index.INDEX_DIR
    before = sorted(index_dir.iterdir())
    monkeypatch.setattr(store.files, "write_index", _raise_oserror)
    store.save_batch(tmp_path, "batch-b", [record("b1", 2)], rows_of("b1", 2, 30.0))
    assert sorted(index_dir.iterdir()) == before
    assert [r["run_id"] for r in store.list_records(tmp_path)] == ["a1", "a2", "b1"]


def _raise_oserror(*_args, **_kwargs):
    raise OSError(28, "No space left on device")


# -- real sweeps ----------------------------------------------------------------------------


def test_listing_records_pauses_the_collector_and_restores_it(tmp_path) -> None:
    """The listing makes a million containers and no garbage: the collector is off meanwhile
    (no collection runs), and as it was after, on or off, also when the listing fails."""
    import gc

    from experiments.host.heap import collection_paused
    from experiments.store import record_index

    synthetic_sweep(tmp_path)
    collections: list[int] = []
    callback = lambda phase, info: collections.append(1) if phase == "start" else None  # noqa: E731
    gc.callbacks.append(callback)
    try:
        with collection_paused():
            garbage = [[[]] for _ in range(50_000)]  # would set collections off
            assert not gc.isenabled() and not collections
        assert gc.isenabled() and garbage
        assert len(record_index.list_records(tmp_path)) == 6
        gc.disable()
        with pytest.raises(OSError), collection_paused():
            raise OSError("a listing that fails")
        assert not gc.isenabled()
    finally:
        gc.enable()
        gc.callbacks.remove(callback)
