"""A sweep's rows as a report reads them, kept per fragment in ``<sweep>/.summary/``
(:mod:`experiments.summary.kept_tables`: kinds ``judged`` and ``boxes``, and ``counted``
pickles beside them).

A report reads of a sweep's rows only each frame pair's judged row, the matched box pairs of
one run per camera setting and the computed stage times of every row
(:func:`experiments.report.judged_rows.cut_fragment`). Cutting them out of ``grand`` 0–18's
3.68 M rows of 66 columns took 7 of the report's 13.4 s of loading. A fragment of the store
never changes, so the first report keeps each fragment's :class:`~experiments.report.judged_rows.Cut`
and a later one reads the kept cuts (a few MB of parquet) and cuts only the fragments it has
not seen. A cut is kept under a key of what it depends on (:func:`cut_keys`): the fragment
(SHA-256, name, live runs), the sweep's unified schema, this code, the fragment's runs the
report leaves out (judged in an earlier sweep of the same report) and those whose box pairs
it reads. A kept file that cannot be read is left out (its fragments cut again); deleting
``.summary/`` is always safe.
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import json
import pickle
from collections.abc import Iterator
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from experiments.host.heap import release_freed_memory
from experiments.report import judged_rows as jr
from experiments.store import schema as row_schema
from experiments.store.dataset import Fragment, fragments, iter_tables
from experiments.summary import kept_tables as kt
from experiments.summary.kept_tables import FRAGMENT
from experiments.summary.lead_rows import fragment_key, sweep_schema
from experiments.summary.run_metrics import code_digest
from ttc import evaluation as ev
from ttc.atomic import write_bytes_atomic

#: Kinds (file name prefixes) of the kept judged rows and box pairs.
JUDGED, BOXES = "judged", "boxes"
#: File name prefix of the kept stage time counts and null columns (pickles, one per kept
#: pair of ``judged`` and ``boxes`` files, named alike).
COUNTED = "counted"
#: Fragments cut between two :func:`~experiments.host.heap.release_freed_memory` calls
#: (``grand`` 0–18: 175 fragments; its load step peaked 0.28 GB higher without them, and a
#: call after every fragment costs ≈ 25 ms of system time each).
TRIM_EVERY = 16

#: A fragment's kept counts: (the stage time counts, the columns with a null).
Counted = tuple[ev.StageCounts, set[str]]


def _code_key(schema: pa.Schema) -> str:
    """Digest of the cutting code and the columns it reads (the rows' schema, the axes, the
    truth columns), the counting code, the library versions and ``schema``."""
    files = ("evaluation/stage_times.py", "evaluation/errors.py", "settings.py", "io/frames.py")
    return code_digest(files, inspect.getsource(jr), inspect.getsource(row_schema),
                       str(schema), pd.__version__, pa.__version__)  # fmt: skip


def cut_keys(
    frags: list[Fragment], schema: pa.Schema, ids: set[str], boxed: set[str]
) -> dict[str, Fragment]:
    """The fragments ``frags`` by the key their cut is kept under
    (:func:`experiments.summary.lead_rows.fragment_key` of the code and ``schema``, and of
    the fragment's live runs that are not in ``ids`` and those in ``boxed``), in order."""
    base = _code_key(schema)
    keyed = {}
    for frag in frags:
        live = set(frag.n_rows)
        runs = json.dumps([sorted(live - ids), sorted(live & boxed)])
        keyed[fragment_key(frag, hashlib.sha256(f"{base}|{runs}".encode()).hexdigest())] = frag
    return keyed


def _counted_path(sweep_dir: Path, keys: list[str]) -> Path:
    """The counts pickle of the kept files of ``keys``."""
    return kt.kept_path(sweep_dir, COUNTED, keys, ".pkl")


def _kept_counted(sweep_dir: Path, wanted: set[str]) -> dict[str, Counted]:
    """The kept counts of the keys ``wanted`` (those found in a readable pickle)."""
    found: dict[str, Counted] = {}
    for path in sorted((Path(sweep_dir) / kt.CACHE_DIR).glob(f"{COUNTED}-*.pkl")):
        try:
            held = pickle.loads(path.read_bytes())  # noqa: S301 (this folder's own cache)
        except Exception:  # noqa: BLE001, S112 - absent or damaged: its fragments cut again
            continue
        found.update({k: v for k, v in held.items() if k in wanted and k not in found})
    return found


def _keep(sweep_dir: Path, cuts: dict[str, jr.Cut]) -> None:
    """Keep ``cuts`` (by key) as one ``judged`` file, one ``boxes`` file and one pickle."""
    keys = list(cuts)
    for kind, part in ((JUDGED, "judged"), (BOXES, "boxes")):
        tables = [_labelled(getattr(c, part), k) for k, c in cuts.items()]
        kt.keep(sweep_dir, kind, pa.concat_tables(tables, promote_options="permissive"), keys)
    counted = {k: (c.counts, c.with_nulls) for k, c in cuts.items()}
    with contextlib.suppress(OSError):  # a read-only sweep folder: nothing kept
        write_bytes_atomic(pickle.dumps(counted), _counted_path(sweep_dir, keys))


def _labelled(table: pa.Table, key: str) -> pa.Table:
    """``table`` with a :data:`~experiments.summary.kept_tables.FRAGMENT` column ``key``."""
    return table.append_column(FRAGMENT, pa.array([key] * table.num_rows, pa.string()))


def _cut(frags: dict[str, Fragment], schema: pa.Schema, ids: set[str],
         boxed: set[str]) -> Iterator[tuple[str, jr.Cut]]:  # fmt: skip
    """Each fragment of ``frags`` (by key) read and cut (on the report's columns that
    ``schema`` has), the freed pages given back every :data:`TRIM_EVERY` fragments."""
    if not frags:
        return
    columns = [c for c in jr.read_columns() if c in schema.names]
    tables = iter_tables(list(frags.values()), schema, columns)
    for i, (key, table) in enumerate(zip(frags, tables, strict=True)):
        yield key, jr.cut_fragment(table, ids, boxed)
        del table
        if (i + 1) % TRIM_EVERY == 0:
            release_freed_memory()


def _in_order(tables: list[pa.Table], keys: list[str]) -> pa.Table:
    """``tables`` (rows of ``keys`` only, labelled) as one, in the order of ``keys``."""
    whole = pa.concat_tables(tables, promote_options="permissive")
    return kt.in_fragment_order(whole, keys)


def _only(tables: list[pa.Table], keys: set[str]) -> list[pa.Table]:
    """``tables`` cut to the rows of ``keys`` where they hold others (a key read from one
    kind of kept file whose other kind could not be read)."""
    held = [set(pc.unique(t[FRAGMENT]).to_pylist()) for t in tables]
    return [t if h <= keys else kt.of_keys(t, keys) for t, h in zip(tables, held, strict=True)]


def read_judged(
    sweep_dir: Path, runs: pd.DataFrame, records: list[dict] | None = None
) -> tuple[pd.DataFrame, pd.DataFrame, ev.StageCounts]:
    """(judged rows, box pairs, stage time counts) of the runs ``runs`` of a sweep, each
    fragment's :class:`~experiments.report.judged_rows.Cut` read where kept, else cut and
    kept; the rows in the fragments' order as one frame each
    (:func:`~experiments.report.judged_rows.as_frame`), the counts of every fragment
    together (:func:`ttc.evaluation.join_counts`). ``records``: the sweep's
    :func:`experiments.store.list_records`, when already read. Empty frames when the sweep
    has no rows."""
    frags = fragments(sweep_dir, records)
    schema = sweep_schema(sweep_dir, frags)
    if schema is None or runs.empty:
        return pd.DataFrame(), pd.DataFrame(), {}
    ids, boxed = set(runs["run_id"]), jr.box_runs(runs)
    keyed = cut_keys(frags, schema, ids, boxed)
    keys = list(keyed)
    files = {kind: kt.kept_files(sweep_dir, kind) for kind in (JUDGED, BOXES)}
    listed = [set().union(*f.values()) if f else set() for f in files.values()]
    counted = _kept_counted(sweep_dir, set(keys).intersection(*listed))
    judged, got_judged = kt.kept_rows(files[JUDGED], list(counted))
    boxes, got_boxes = kt.kept_rows(files[BOXES], list(counted))
    good = set(counted) & got_judged & got_boxes
    judged, boxes = _only(judged, good), _only(boxes, good)
    todo = {k: f for k, f in keyed.items() if k not in good}
    cuts = dict(_cut(todo, schema, ids, boxed))
    if cuts:
        _keep(sweep_dir, cuts)
        judged += [_labelled(c.judged, k) for k, c in cuts.items()]
        boxes += [_labelled(c.boxes, k) for k, c in cuts.items()]
        counted.update({k: (c.counts, c.with_nulls) for k, c in cuts.items()})
    with_nulls = set().union(*(counted[k][1] for k in keys))
    counts = ev.join_counts(counted[k][0] for k in keys)
    whole = {JUDGED: _in_order(judged, keys), BOXES: _in_order(boxes, keys)}
    # the rows held by `whole` alone: as_frame frees each column's buffers as it converts it
    # (grand 0-77's report peaked 0.85 GB higher while the cuts were still held)
    n_files = len(files[JUDGED]) + bool(cuts)
    del judged, boxes, cuts
    if n_files > kt.MAX_KEPT_FILES:  # the cuts used as one file
        for kind, table in whole.items():
            kt.consolidate(sweep_dir, kind, table, keys, list(kt.kept_files(sweep_dir, kind)))
        _consolidate_counted(sweep_dir, {k: counted[k] for k in keys})
    lead = jr.as_frame([whole.pop(JUDGED).drop_columns([FRAGMENT])], with_nulls)
    return lead, jr.as_frame([whole.pop(BOXES).drop_columns([FRAGMENT])], with_nulls), counts


def _consolidate_counted(sweep_dir: Path, counted: dict[str, Counted]) -> None:
    """Keep ``counted`` as one pickle and remove the others."""
    path = _counted_path(sweep_dir, list(counted))
    with contextlib.suppress(OSError):  # a read-only sweep folder: nothing kept
        write_bytes_atomic(pickle.dumps(counted), path)
        for other in (Path(sweep_dir) / kt.CACHE_DIR).glob(f"{COUNTED}-*.pkl"):
            if other != path:
                other.unlink(missing_ok=True)
