"""The end-of-sweep summary's lead rows, kept per fragment (:mod:`experiments.summary.kept_tables`).

The summary ranks every run of a sweep on its lead rows (:func:`ttc.evaluation.lead_rows`:
one row per run × frame pair). A fragment's lead rows are computed once, by the first summary
that reads it, and kept under a key of what they depend on: the fragment's SHA-256 and name,
its live runs (a run recomputed since into another fragment is left out), the dataset's
unified schema (the column types) and the code of the reduction and the columns it keeps.
:class:`LeadRows` reads them on demand: all of them, or only some fragments' or columns.
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import json
import pickle
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from experiments.store.dataset import Fragment, fragments, iter_tables, unified_schema
from experiments.summary import kept_tables as kt
from experiments.summary.kept_tables import CACHE_DIR, FRAGMENT
from ttc.atomic import write_bytes_atomic

#: Kind (file name prefix) of the kept lead rows.
KIND = "lead"
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


def sweep_schema(sweep_dir: Path, frags: list[Fragment]) -> pa.Schema | None:
    """The unified schema of a sweep's live fragments ``frags``
    (:func:`experiments.store.dataset.unified_schema`; None: no rows), each fragment's own
    schema read from its file once and kept (:data:`SCHEMAS_FILE`)."""
    known = _kept_schemas(sweep_dir, frags)
    before = len(known)
    schema = unified_schema(frags, known)
    if len(known) > before:
        _keep_schemas(sweep_dir, known, frags)
    return schema


def _code_key(columns: list[str]) -> str:
    """Digest of the reduction's code and the columns it reads."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    code = inspect.getsource(ev.lead_row_positions) + inspect.getsource(lead_table)
    text = code + json.dumps(columns) + pd.__version__ + pa.__version__
    return hashlib.sha256(text.encode()).hexdigest()


def lead_table(rows: pa.Table) -> pa.Table:
    """:func:`ttc.evaluation.lead_rows` of an Arrow table of rows, in Arrow: the rows
    :func:`ttc.evaluation.lead_row_positions` keeps, their
    :data:`~ttc.evaluation.LEAD_BLANKED` estimates null where the row is not a lead row. As
    pandas (``to_pandas``) it is ``lead_rows(rows.to_pandas())`` (test); taking the rows in
    Arrow spares a fragment's 58 columns their trip through pandas and back (the 70
    fragments of an ``fp6_grid`` folder, 29,502 rows: 0.65 → 0.07 s)."""
    from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import, rarely needed)

    if rows.num_rows == 0:
        return rows
    positions, blank = ev.lead_row_positions(
        *(rows[c].to_numpy(zero_copy_only=False) for c in ("run_id", "frame", "is_lead"))
    )
    lead = rows.take(pa.array(positions))
    if blank.any():
        mask = pa.array(blank)
        for name in (c for c in ev.LEAD_BLANKED if c in lead.column_names):
            column = lead[name]
            blanked = pc.if_else(mask, pa.scalar(None, column.type), column)
            lead = lead.set_column(lead.schema.get_field_index(name), name, blanked)
    return lead


def fragment_key(frag: Fragment, key: str) -> str:
    """The key a table derived from ``frag`` is kept under: of the fragment (SHA-256, name,
    live runs) and ``key`` (what else it depends on: schema, code; the lead rows', or the
    report's cuts', :mod:`experiments.report.kept_judged`)."""
    live = json.dumps(sorted(frag.n_rows))
    return hashlib.sha256(f"{frag.sha256}|{frag.path.name}|{live}|{key}".encode()).hexdigest()[:32]


class LeadRows:
    """The lead rows of a sweep's live fragments, each fragment's kept
    (:mod:`experiments.summary.kept_tables`): those not kept yet are computed and kept as this is made
    (a fragment at a time: a run's rows are in one fragment), all of them read on demand.
    ``records``: the sweep's :func:`experiments.store.list_records`, when already read.
    :class:`experiments.store.StoreError` names a corrupt fragment."""

    def __init__(self, sweep_dir: Path, records: list[dict[str, Any]] | None = None) -> None:
        from ttc import evaluation as ev  # noqa: PLC0415 (SciPy: slow to import)

        self.sweep_dir = Path(sweep_dir)
        frags = fragments(sweep_dir, records)
        #: The dataset's unified schema (None: no rows).
        self.schema = sweep_schema(sweep_dir, frags)
        if self.schema is None:
            frags = []
        columns = [c for c in self.schema.names if c not in ev.NOT_JUDGED_COLUMNS] if frags else []
        key = hashlib.sha256(f"{self.schema}|{_code_key(columns)}".encode()).hexdigest()
        self._frags = {fragment_key(f, key): f for f in frags}
        self._columns = columns
        #: Each live fragment's key, in the dataset's order.
        self.keys: list[str] = list(self._frags)
        self._files = kt.kept_files(sweep_dir, KIND)
        self._fresh: list[tuple[set[str], pa.Table]] = []  # (its keys, lead rows) computed
        listed = set().union(*self._files.values()) if self._files else set()
        self._compute([k for k in self.keys if k not in listed])
        self._whole: pd.DataFrame | None = None
        if self.keys and len(self._files) > kt.MAX_KEPT_FILES:  # the rows used as one file
            whole = self.table()
            kt.consolidate(sweep_dir, KIND, whole, self.keys, list(self._files))
            self._files = kt.kept_files(sweep_dir, KIND)

    def runs(self, key: str) -> list[str]:
        """The live run ids of fragment ``key``, sorted."""
        return sorted(self._frags[key].n_rows)

    def _compute(self, todo: list[str]) -> pa.Table | None:
        """Compute and keep the lead rows of the fragments ``todo``; their table, or None."""
        if not todo:
            return None
        new = []
        frags = [self._frags[k] for k in todo]
        for k, table in zip(todo, iter_tables(frags, self.schema, self._columns), strict=True):
            lead = lead_table(table)
            new.append(lead.append_column(FRAGMENT, pa.array([k] * lead.num_rows, pa.string())))
        table = pa.concat_tables(new, promote_options="permissive")
        path = kt.keep(self.sweep_dir, KIND, table, todo)
        if path is not None:
            self._files[path] = set(todo)
        self._fresh.append((set(todo), table))
        return table

    def table(self, keys: list[str] | None = None, columns: list[str] | None = None) -> pa.Table:
        """The kept lead rows of fragments ``keys`` (None: all), in the dataset's order, with
        :data:`~experiments.summary.kept_tables.FRAGMENT`; ``columns``: only these (and it)."""
        keys = self.keys if keys is None else keys
        tables, found = [], set()
        for held, fresh in self._fresh:  # columns taken first: a filter copies each one
            wanted = (held & set(keys)) - found
            if not wanted:
                continue
            part = fresh if columns is None else fresh.select([*columns, FRAGMENT])
            if wanted != held:
                part = kt.of_keys(part, wanted)
            tables.append(part)
            found |= wanted
        kept, got = kt.kept_rows(self._files, [k for k in keys if k not in found], columns)
        tables += kept
        found |= got
        redone = self._compute([k for k in keys if k not in found])  # a kept file unreadable
        if redone is not None:
            tables.append(redone if columns is None else redone.select([*columns, FRAGMENT]))
        whole = pa.concat_tables(tables, promote_options="permissive")
        return kt.in_fragment_order(whole, keys)

    def frame(
        self, keys: list[str] | None = None, columns: list[str] | None = None
    ) -> pd.DataFrame:
        """:meth:`table` without :data:`~experiments.summary.kept_tables.FRAGMENT`, as pandas (all
        rows and columns: read once)."""
        if not self.keys:
            return pd.DataFrame()
        if keys is None and columns is None:
            if self._whole is None:
                self._whole = self.table().drop_columns([FRAGMENT]).to_pandas()
            return self._whole
        return self.table(keys, columns).drop_columns([FRAGMENT]).to_pandas()


def lead_rows(sweep_dir: Path, records: list[dict[str, Any]] | None = None) -> pd.DataFrame:
    """One row per run × frame pair of a sweep, the lead vehicle's
    (:func:`ttc.evaluation.lead_rows`), without the columns no metric reads
    (:data:`ttc.evaluation.NOT_JUDGED_COLUMNS`), fragments in the dataset's order
    (:class:`LeadRows`)."""
    return LeadRows(sweep_dir, records).frame()
