"""A report keeps a sweep's flattened run configs (experiments.store.flat_configs.flatten_kept):
the next report reads them back instead of parsing them, the same table; a damaged file or
one made by other flattening code is not used; a new config rewrites the file."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest

from experiments.store import flat_configs
from experiments.store.flat_configs import KEPT_FILE, config_table, flatten_kept


def _configs(n: int) -> pd.Series:
    """``n`` run config texts as a sweep stores them (JSON, sorted keys)."""
    texts = [json.dumps({"dataset": {"sequence": f"drive_{i % 3}", "last": 18},
                         "detector": {"name": "fast", "threshold": i}, "extra": {} if i % 2 else
                         {"tags": [i, 2]}}, sort_keys=True) for i in range(n)]  # fmt: skip
    return pd.Series(texts, index=[f"r{i}" for i in range(n)], dtype=object)


@pytest.fixture
def fresh_process(monkeypatch) -> list[int]:
    """An empty table of flattened configs; the list grows by one per config parsed."""
    monkeypatch.setattr(flat_configs, "_FLAT_CONFIGS", [])
    parsed: list[int] = []
    real = flat_configs._flat_text
    monkeypatch.setattr(flat_configs, "_flat_text", lambda text: parsed.append(1) or real(text))
    return parsed


def test_the_next_report_reads_the_flattened_configs_back(tmp_path: Path, fresh_process) -> None:
    configs = _configs(12)
    flatten_kept(tmp_path, configs)
    first = config_table(configs)
    assert len(fresh_process) == 12 and (tmp_path / KEPT_FILE).is_file()
    flat_configs._FLAT_CONFIGS.clear()  # another process
    flatten_kept(tmp_path, configs)
    again = config_table(configs)
    assert len(fresh_process) == 12  # none parsed
    pd.testing.assert_frame_equal(again, first)
    subset = configs.iloc[[5, 1]]
    want = first.loc[["r5", "r1"]].dropna(axis=1, how="all")
    pd.testing.assert_frame_equal(config_table(subset), want)


def test_a_new_config_rewrites_the_file_and_a_bad_one_is_not_used(
    tmp_path: Path, fresh_process, monkeypatch
) -> None:
    configs = _configs(6)
    flatten_kept(tmp_path, configs.iloc[:4])
    flat_configs._FLAT_CONFIGS.clear()
    flatten_kept(tmp_path, configs)  # two new: parsed, and the file holds all six
    assert len(fresh_process) == 4 + 2
    assert pq.read_table(tmp_path / KEPT_FILE).num_rows == 6
    flat_configs._FLAT_CONFIGS.clear()
    monkeypatch.setattr(flat_configs, "_code", lambda: b"other flattening code")
    flatten_kept(tmp_path, configs)
    assert len(fresh_process) == 6 + 6  # not used: parsed again, the file rewritten
    flat_configs._FLAT_CONFIGS.clear()
    (tmp_path / KEPT_FILE).write_bytes((tmp_path / KEPT_FILE).read_bytes()[:100])  # truncated
    flatten_kept(tmp_path, configs)
    table = config_table(configs)
    assert len(fresh_process) == 12 + 6 and table.loc["r3", "detector.threshold"] == "3"
    assert pq.read_table(tmp_path / KEPT_FILE).num_rows == 6  # whole again


def test_configs_added_since_the_file_was_kept_are_kept_without_a_warning(
    tmp_path: Path, fresh_process
) -> None:
    """A report after a re-run added runs: the configs read back and those parsed, of more
    than 100 leaves each (a real config has ~90-130), are kept without pandas' warning of a
    highly fragmented frame (it was printed on the user's terminal)."""
    texts = [json.dumps({f"g{j}": {"v": i if j == 0 else j} for j in range(120)}, sort_keys=True)
             for i in range(10)]  # fmt: skip
    configs = pd.Series(texts, dtype=object)
    flatten_kept(tmp_path, configs.iloc[:5])
    flat_configs._FLAT_CONFIGS.clear()  # another process
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        flatten_kept(tmp_path, configs)
    kept = pq.read_table(tmp_path / KEPT_FILE)
    assert kept.num_rows == 10 and len(kept.column_names) == 121


def test_a_sweep_folder_it_cannot_write_is_read_without_keeping(
    tmp_path: Path, fresh_process
) -> None:
    (tmp_path / KEPT_FILE.parent).write_text("a file where the folder would be")  # even as root
    flatten_kept(tmp_path, _configs(3))
    assert len(config_table(_configs(3))) == 3 and len(fresh_process) == 3
    assert (tmp_path / KEPT_FILE.parent).is_file()


def test_leaves_met_before_keep_their_own_text() -> None:
    """Texts kept by type and value: 1, 1.0 and True, 0.0 and -0.0, NaN and the infinities,
    each met twice (second config in reverse order), give ``json.dumps``' text every time."""
    values = [1, 1.0, True, 0.0, -0.0, float("nan"), float("inf"), -float("inf"), None, "1",
              2.5, [1, 2.5], {}, ""]  # fmt: skip
    configs = [{"g": {f"k{i}": v for i, v in enumerate(values)}, "top": v} for v in values]
    configs += configs[::-1]
    for config in configs:
        flat = flat_configs._flat(json.loads(json.dumps(config)))
        expected = {f"g.k{i}": json.dumps(v, sort_keys=True) for i, v in enumerate(values)}
        assert flat == {**expected, "top": json.dumps(config["top"], sort_keys=True)}


def _whole(text: str) -> dict[str, str]:
    """The definition: the text parsed whole, then flattened."""
    return flat_configs._flat(json.loads(text))


@pytest.mark.parametrize(
    "texts",
    [
        # the previous config's next key inside an entry: the cut is no JSON value
        ['{"a": {"x": 1}, "b": 2}', '{"a": {"x": 0, "b": 1}, "b": 3}', '{"a": {"x": 1}, "b": 2}'],
        # ... inside a string (escaped), and a key the previous config lacks
        ['{"a": 1, "b": 2}', '{"a": "q, \\"b\\": 1", "b": 2}', '{"a": 1, "z": [1, {}], "b": 2}'],
        # fewer keys, more keys, no keys, other spacing, the same key twice
        [
            '{"a": 1, "b": 2}',
            '{"b": 2}',
            '{"a": 1, "b": 2, "c": null}',
            "{}",
            '{"a":1,"b":2}',
            '{\n  "a": 1,\n  "b": 2\n}',
            '{"a": 1, "a": 2, "b": 3}',
            '{"a": 1, "b": 2}',
        ],
        # one entry's text with other types: each keeps its own leaves (1, 1.0, true, NaN)
        [
            '{"a": {"v": 1}, "b": 0}',
            '{"a": {"v": 1.0}, "b": 0}',
            '{"a": {"v": true}, "b": 0}',
            '{"a": {"v": NaN}, "b": -0.0}',
            '{"a": {"v": 1}, "b": 0}',
            '{"a": {}, "b": [1, 2.5]}',
        ],
        # keys JSON escapes are never cut at
        ['{"a\\"b": 1, "c": 2}', '{"a\\"b": 1, "c": 2}', '{"\\u00e9": {"x": 1}, "c": 2}'],
    ],
)
def test_configs_cut_by_entry_flatten_as_parsed_whole(texts: list[str], monkeypatch) -> None:
    """Each text flattened by its entries' texts (:func:`flat_configs._flat_text`) gives the
    leaves of the text parsed whole, in the same order, whatever the config before it."""
    monkeypatch.setattr(flat_configs, "_SECTIONS", {})
    monkeypatch.setattr(flat_configs, "_LAST_KEYS", [()])
    for text in texts:
        got = flat_configs._flat_text(text)
        assert list(got.items()) == list(_whole(text).items()), text


def test_a_config_cut_by_entry_reuses_each_entry_and_fails_as_json_does(monkeypatch) -> None:
    """A sweep's configs share their entries: each distinct entry is parsed once; a text that
    is no JSON object raises as :func:`json.loads` does, whatever the config before it."""
    monkeypatch.setattr(flat_configs, "_SECTIONS", {})
    monkeypatch.setattr(flat_configs, "_LAST_KEYS", [()])
    texts = _configs(40)
    for text in texts:
        assert flat_configs._flat_text(text) == _whole(text)
    # the first config parsed whole; then each distinct entry once: dataset 3 texts,
    # detector 39 (its first never again), extra {} and 19 lists (of even i > 0)
    assert len(flat_configs._SECTIONS) == 3 + 39 + 1 + 19
    bad = [
        '{"dataset": {"last": 18, "sequence": "drive_0"}, "detector": {',
        "",
        "[1, 2]",
        '{"dataset": {"last": 18, "sequence": "drive_0"}, "detector": {}, "extra": {}',
    ]
    for text in bad:
        with pytest.raises(Exception) as whole:
            _whole(text)
        with pytest.raises(whole.type):
            flat_configs._flat_text(text)


def test_every_config_in_order_is_the_table_any_order_gives(fresh_process) -> None:
    """A report asks for all its runs' configs in the order they were flattened: the table is
    then handed out without a copy, the same table a reordering of them gives."""
    configs = _configs(12)
    whole = config_table(configs)
    again = config_table(configs)
    reordered = config_table(configs.iloc[::-1])
    pd.testing.assert_frame_equal(again, whole)
    pd.testing.assert_frame_equal(reordered.loc[configs.index], whole)
    assert len(fresh_process) == 12 and not whole.isna().all().any()
