"""Run configs flattened: each stored config (JSON text) as one row of leaves by dotted key.

The report and the summary read a few entries of every run's config (its recording, its
setting without the recording); parsing and flattening a ``grand`` sweep's 33,600 configs
takes 5 s. :func:`config_table` flattens each distinct text once per process, and a report
keeps a sweep's flattened configs in ``<sweep>/.configs/flat.parquet``
(:func:`flatten_kept`, each row under its text's BLAKE2b digest and the flattening
code's): the next report reads them back (0.5 s for those 33,600). Deleting ``.configs/`` is
always safe.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import inspect
import json
import math
import sys
from json.encoder import encode_basestring_ascii
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from experiments.store.files import write_parquet_atomic

#: A config key's cell where the config lacks it, or has an empty dict there (no leaf).
NO_LEAF = "{}"
#: Configs kept flattened at most; past it the table starts again from the configs asked for.
FLAT_CONFIGS_KEPT = 200_000
#: A sweep's configs flattened by a report, under the sweep folder (:func:`flatten_kept`).
KEPT_FILE = Path(".configs") / "flat.parquet"
#: The kept file's column of each config text's digest (:func:`_digest`).
DIGEST = "__digest"
#: The kept file's metadata key naming the flattening code it was made with.
CODE_META = b"ttc_bench_flat_code"

#: The configs :func:`config_table` flattened in this process: (the hash of each config text
#: → its row of the table, the table), rows added as new configs come. The report asks for
#: them in the load step (each recording's runs apart), the references, the "every object"
#: report and each page's header (``grand`` 0–18: 33,600 configs, 2.5 s a pass).
_FLAT_CONFIGS: list[tuple[dict[int, int], pd.DataFrame]] = []


def leaf_text(value: object) -> str:
    """``json.dumps(value, sort_keys=True)``, without building an encoder for a scalar (a
    ``grand`` sweep's setting ids flatten 28,000 configs of 90 leaves each)."""
    if isinstance(value, str):
        return encode_basestring_ascii(value)
    if value is None or isinstance(value, bool):
        return {None: "null", True: "true", False: "false"}[value]
    if type(value) is int or (type(value) is float and math.isfinite(value)):
        return repr(value)
    return json.dumps(value, sort_keys=True)


#: Dotted keys by (prefix, key) and leaf texts by (type, value) of the scalars :func:`_flat`
#: met (a ``grand`` sweep's 40,320 configs of ~130 leaves repeat a few thousand distinct
#: ones: 1.7 → 1.1 s). Not kept: NaN (never equal to itself) and zero (``0.0`` and ``-0.0``
#: are one key, two texts).
_NAMES: dict[tuple[str, str, str], str] = {}
_TEXTS: dict[tuple[type, object], str] = {}


def _flat(tree: dict, prefix: str = "") -> dict[str, str]:
    """``{"a": {"b": 1}}`` → ``{"a.b": "1"}``: each leaf as its JSON text (lists, scalars
    and empty dicts are leaves; keys and texts interned: a sweep's runs share them)."""
    out: dict[str, str] = {}
    names, texts = _NAMES, _TEXTS
    for key, value in tree.items():
        if isinstance(value, dict) and value:
            inner = names.get((prefix, key, "."))
            if inner is None:
                inner = names[prefix, key, "."] = f"{prefix}{key}."
            out.update(_flat(value, inner))
            continue
        name = names.get((prefix, key, ""))
        if name is None:
            name = names[prefix, key, ""] = sys.intern(f"{prefix}{key}")
        kind = type(value)
        if (
            kind is str
            or kind is int
            or (kind is float and value == value and value != 0.0)  # not NaN, 0.0 or -0.0
            or kind is bool
            or value is None
        ):
            text = texts.get((kind, value))
            if text is None:
                text = texts[kind, value] = sys.intern(leaf_text(value))
        else:
            text = sys.intern(leaf_text(value))
        out[name] = text
    return out


#: Each top-level entry's leaves by (entry's key, its value's JSON text) (:func:`_flat_text`),
#: and the top-level keys of the config last parsed whole; up to :data:`SECTIONS_KEPT`.
_SECTIONS: dict[tuple[str, str], dict[str, str]] = {}
_LAST_KEYS: list[tuple[str, ...]] = [()]
SECTIONS_KEPT = 1 << 16


def _flat_text(text: str) -> dict[str, str]:
    """``_flat(json.loads(text))`` of a config text, each top-level entry's value flattened
    once per process by its own text: a sweep's configs repeat a few dozen distinct entries
    (``grand``'s 40,320: 36; 2.6 → 0.6 s) (:func:`_entries`)."""
    entries = _entries(text)
    if entries is None:
        return _flat_whole(text)
    out: dict[str, str] = {}
    for leaves in entries:
        out.update(leaves)
    return out


def entry_leaves(text: str, key: str) -> dict[str, str]:
    """The leaves of the top-level entry ``key`` of a config text (:func:`_flat`'s, by dotted
    key), the entries after it not read (:func:`_entries`): a run's recording is its
    ``dataset`` entry, the third (33,600 configs: 0.22 s parsed up to it, 0.05 s cut)."""
    entries = _entries(text, key)
    if entries is None:
        head = f"{key}."
        return {k: v for k, v in _flat_whole(text).items() if k == key or k.startswith(head)}
    return entries[-1]


def _entries(text: str, until: str | None = None) -> list[dict[str, str]] | None:
    """The leaves of each top-level entry of a config text, in order, up to the entry
    ``until`` (None: all of them); None when the text cannot be cut so. The entries are cut
    where the previous config's next key starts (``, "key": ``, as :func:`json.dumps` writes
    them; such a text inside a string value is escaped), and each is parsed (once per
    process by its text): a cut inside an entry leaves that entry's text no JSON value (it
    holds the cut's ``,`` outside any bracket of its own), so a text whose cuts all parse is
    cut right; keys other than the last config's, other spacing or ``until`` absent: None."""
    keys, at, out = _LAST_KEYS[0], 1, []
    if not keys or not text.startswith("{") or not text.endswith("}"):
        return None
    for i, key in enumerate(keys):
        head = f'"{key}": ' if i == 0 else f', "{key}": '
        if not text.startswith(head, at):
            return None
        start = at + len(head)
        at = text.find(f', "{keys[i + 1]}": ', start) if i + 1 < len(keys) else len(text) - 1
        if at < 0:
            return None
        section = (key, text[start:at])
        leaves = _SECTIONS.get(section)
        if leaves is None:
            try:
                leaves = _flat({key: json.loads(section[1])})
            except ValueError:  # not one JSON value: cut inside an entry
                return None
            if len(_SECTIONS) >= SECTIONS_KEPT:
                _SECTIONS.clear()
            _SECTIONS[section] = leaves
        out.append(leaves)
        if key == until:
            return out
    return out if until is None else None


def _flat_whole(text: str) -> dict[str, str]:
    """:func:`_flat` of the parsed ``text``; its top-level keys are the next cuts'
    (:func:`_flat_text`), when they are plain names (no character JSON escapes)."""
    tree = json.loads(text)
    if isinstance(tree, dict) and all(encode_basestring_ascii(k) == f'"{k}"' for k in tree):
        _LAST_KEYS[0] = tuple(tree)
    return _flat(tree)


def _add(texts: list[str], leaves: pd.DataFrame) -> None:
    """Add config ``texts`` (not yet in the process's table) with their rows ``leaves``."""
    rows, table = _FLAT_CONFIGS[0] if _FLAT_CONFIGS else ({}, pd.DataFrame())
    rows = rows | {hash(t): len(rows) + i for i, t in enumerate(texts)}
    table = pd.concat([table, leaves], ignore_index=True) if len(table) else leaves
    _FLAT_CONFIGS[:] = [(rows, table.reset_index(drop=True))]


def config_table(configs: pd.Series) -> pd.DataFrame:
    """Each stored run config (JSON text; runs.parquet ``config``) flattened (:func:`_flat`):
    one column per dotted key that one of them has, each cell the leaf's JSON text (an empty
    dict's ``{}``), NaN where a config lacks the key or is itself missing; ``configs``' index.
    Each distinct text is parsed once per process (looked up by its hash; up to
    :data:`FLAT_CONFIGS_KEPT` of them kept)."""
    texts = [t if isinstance(t, str) else None for t in configs]
    rows = _FLAT_CONFIGS[0][0] if _FLAT_CONFIGS else {}
    new = list(dict.fromkeys(t for t in texts if t is not None and hash(t) not in rows))
    if new:
        if len(rows) + len(new) > FLAT_CONFIGS_KEPT:
            _FLAT_CONFIGS.clear()
            new = list(dict.fromkeys(t for t in texts if t is not None))
        _add(new, pd.DataFrame([_flat_text(t) for t in new], dtype=object))
    rows, table = _FLAT_CONFIGS[0] if _FLAT_CONFIGS else ({}, pd.DataFrame())
    at = np.array([rows[hash(t)] if t is not None else -1 for t in texts], dtype=np.int64)
    if np.array_equal(at, np.arange(len(table))):  # the whole table, in order (a report's
        # configs, each a run's): every column has a leaf in some row; not copied
        return table.set_axis(configs.index)
    found = table.reindex(at).set_axis(configs.index)  # a missing config (-1): NaN
    return found.dropna(axis=1, how="all")


@functools.lru_cache(maxsize=1 << 12)
def leaf_value(leaf: str) -> str:
    """A string leaf's value from its JSON text (:func:`leaf_text`)."""
    return json.loads(leaf)


def flattened_leaves(configs: pd.Series, key: str) -> list[str] | None:
    """Each config's leaf text at ``key`` from the configs :func:`config_table` flattened,
    None unless every config is there with a string leaf at ``key`` (no config parsed)."""
    if not _FLAT_CONFIGS or key not in _FLAT_CONFIGS[0][1]:
        return None
    rows, table = _FLAT_CONFIGS[0]
    at = [rows.get(hash(t), -1) if isinstance(t, str) else -1 for t in configs]
    if -1 in at:
        return None
    leaves = table[key].to_numpy()[at].tolist() if at else []
    return leaves if all(isinstance(v, str) for v in leaves) else None


def _digest(text: str) -> str:
    """A config text's BLAKE2b digest (hex, 128 bits)."""
    return hashlib.blake2b(text.encode(), digest_size=16).hexdigest()


@functools.cache
def _code() -> bytes:
    """The SHA-256 of the flattening code (a kept file made by other code is not used)."""
    source = "".join(inspect.getsource(f) for f in (leaf_text, _flat, _flat_text, _flat_whole))
    return hashlib.sha256(source.encode()).hexdigest().encode()


def _leaf_columns(path: Path) -> list[str]:
    """The kept file's leaf columns (every column but :data:`DIGEST`)."""
    return [name for name in pq.read_schema(path).names if name != DIGEST]


def _read_kept(path: Path, missing: dict[str, str]) -> set[str]:
    """The digests the kept file ``path`` holds; the configs of ``missing`` (digest → text,
    none in the process's table) it holds are added to the process's table. A file that
    cannot be read, or that other flattening code made, holds none."""
    try:
        digests = pq.read_table(path, columns=[DIGEST])
        if (digests.schema.metadata or {}).get(CODE_META) != _code():
            return set()
        held = set(digests.column(DIGEST).to_pylist())
        if not held & missing.keys():
            return held
        table = pq.read_table(path, read_dictionary=_leaf_columns(path)).to_pandas()
    except (OSError, ValueError, KeyError):  # absent, truncated, not parquet, no digests
        return set()
    table = table[table[DIGEST].isin(missing)].drop_duplicates(DIGEST)
    # from the categories: equal leaves one string object, as parsing interns them (a new
    # string per cell held 160 MB more for grand's 40,320 configs)
    leaves = table.drop(columns=DIGEST).astype(object).dropna(axis=1, how="all")
    _add([missing[d] for d in table[DIGEST]], leaves.reset_index(drop=True))
    return held


def flatten_kept(sweep_dir: Path, configs: pd.Series) -> None:
    """Put every one of ``configs`` (a sweep's runs' config texts) in the process's table:
    those an earlier report kept flattened read from ``<sweep_dir>/`` :data:`KEPT_FILE`, the
    others parsed; when the file lacks some, it is replaced (atomically) by one of all of them
    (not when the folder is read-only). A report calls it first, while it holds little."""
    path = Path(sweep_dir) / KEPT_FILE
    rows = _FLAT_CONFIGS[0][0] if _FLAT_CONFIGS else {}
    texts = list(dict.fromkeys(t for t in configs if isinstance(t, str)))
    digests = [_digest(t) for t in texts]
    missing = {d: t for d, t in zip(digests, texts, strict=True) if hash(t) not in rows}
    if _read_kept(path, missing).issuperset(digests):  # every one now in the process's table
        return
    table = config_table(pd.Series(texts, dtype=object)).reset_index(drop=True)  # others parsed
    # joined, not inserted: the table of configs read back and parsed is made of a block per
    # leaf, and pandas warns of an insert into more than 100 blocks
    table = pd.concat([table, pd.Series(digests, name=DIGEST, dtype=object)], axis=1)
    with contextlib.suppress(OSError):
        write_parquet_atomic(table, path, {CODE_META: _code()})
