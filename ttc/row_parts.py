"""A batch's rows kept as references to shared parts, made one table at the end.

Every row of a batch (:func:`ttc.engine.runner.run_settings`) is the union of a few *parts*,
column dicts that many rows share (:data:`KINDS`, built by :mod:`ttc.rows`): a frame pair's
columns, a box's own lidar points, the box pair, an FP.2 result, an FP.3/FP.4 result, the
empty result of an unmatched box, the columns of a pair that could not be read. Only
:data:`OWN_COLUMNS` are a row's own. Rows come in :class:`RowBlock` s (a frame pair's rows
under one setting, shared by the settings with the same step keys): one part index per kind
(−1: none) and the box's shared matches per row, one ``error`` text per block; their setting
(:data:`~ttc.rows.MEMBER`) is given with them.

:meth:`RowParts.table` is exactly ``pandas.DataFrame.from_records`` of the rows as dicts
(:meth:`RowParts.records`): columns in order of first appearance, each column's dtype inferred
from its values. Each kind's parts become one small frame (the same inference over the same
distinct values), and a column is taken from those frames by the rows' part indices; a column
that two kinds give with different dtypes, or that some rows lack, is inferred again from its
values. Measured on a ``grand`` re-run's batches (160 settings, 20,000 rows): the rows as dicts
and ``from_records`` were 30 % of a worker's time; the rows as tuples, transposed, 5 %.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from pandas.api.extensions import ExtensionArray

from ttc.rows import MEMBER

#: The kinds of parts, in the order their columns come in a row.
KINDS = ("pair", "object", "box", "lidar", "camera", "unmatched", "error")
#: A row's own columns, after its parts' (``error``: the text of a pair that could not be read).
OWN_COLUMNS = ("box_shared_matches", "error")
#: Up to this many rows the table is made from the rows as dicts: a pair's detail (7 rows)
#: took 0.44 ms so and 3.0 ms by columns (a small frame per kind and a gather per column).
RECORDS_UP_TO = 64


@dataclass(frozen=True)
class RowBlock:
    """Rows with one ``error`` text: ``refs`` (k × :data:`KINDS`, int64) each row's part
    index per kind (−1: none) and ``shared_matches`` (k,) its ``box_shared_matches``."""

    refs: np.ndarray
    shared_matches: np.ndarray
    error: str = ""

    @classmethod
    def of(cls, rows: Sequence[tuple[int, ...]], error: str = "") -> RowBlock:
        """The block of ``rows``, each a part index per kind then its shared matches."""
        table = np.array(rows, dtype=np.int64).reshape(len(rows), len(KINDS) + 1)
        return cls(table[:, : len(KINDS)], table[:, len(KINDS)], error)

    @classmethod
    def unreadable(cls, part: int, error: str) -> RowBlock:
        """The one row of a frame pair that could not be read: its ``error`` part, the text."""
        refs = np.full((1, len(KINDS)), -1, dtype=np.int64)
        refs[0, KINDS.index("error")] = part
        return cls(refs, np.zeros(1, dtype=np.int64), error)


#: Rows by setting: ``(member, its blocks)``, in the order the table holds them.
MemberRows = Sequence[tuple[int, Sequence[RowBlock]]]


class RowParts:
    """The parts of a batch's rows (each kind's column dicts, by index) and the table of rows
    that reference them."""

    def __init__(self) -> None:
        self._parts: dict[str, list[dict[str, Any]]] = {kind: [] for kind in KINDS}

    def add(self, kind: str, columns: dict[str, Any]) -> int:
        """Keep a part of ``kind`` (every part of a kind has the same columns); its index."""
        parts = self._parts[kind]
        parts.append(columns)
        return len(parts) - 1

    def records(self, members: MemberRows) -> list[dict[str, Any]]:
        """The rows as dicts: each the union of its parts, its own columns and its member (what
        :meth:`table` equals, made by ``pandas.DataFrame.from_records``)."""
        out = []
        for member, blocks in members:
            for block in blocks:
                for refs, shared in zip(block.refs.tolist(), block.shared_matches.tolist(),
                                        strict=True):  # fmt: skip
                    record: dict[str, Any] = {}
                    for kind, index in zip(KINDS, refs, strict=True):
                        if index >= 0:
                            record.update(self._parts[kind][index])
                    record.update(zip(OWN_COLUMNS, (shared, block.error), strict=True))
                    out.append({**record, MEMBER: member})
        return out

    def table(self, members: MemberRows) -> pd.DataFrame:
        """One frame of the rows (:meth:`records`' ``from_records``, made by columns); raises
        ValueError when a row's parts share a column or a kind's parts differ in columns."""
        blocks = [(member, block) for member, mine in members for block in mine]
        lengths = [len(block.refs) for _, block in blocks]
        n = sum(lengths)
        if n <= RECORDS_UP_TO:
            return pd.DataFrame.from_records(self.records(members)) if n else pd.DataFrame()
        refs = np.concatenate([block.refs for _, block in blocks]).T  # kinds × rows
        kinds = [self._kind(kind, refs[i]) for i, kind in enumerate(KINDS)]
        at = np.repeat(np.arange(len(blocks)), lengths)  # each row's block
        own = {"error": [block.error for _, block in blocks], MEMBER: [m for m, _ in blocks]}
        columns: dict[str, ExtensionArray | np.ndarray] = {}
        for name in _column_order(kinds, refs):
            if name == "box_shared_matches":  # ints within int64 (a block holds them so)
                columns[name] = np.concatenate([block.shared_matches for _, block in blocks])
            elif name in own:
                columns[name] = _distinct_inferred(own[name]).take(at)
            else:
                columns[name] = _gathered(name, kinds, refs)
        return pd.DataFrame(columns)

    def _kind(self, kind: str, refs: np.ndarray) -> _Kind | None:
        """The parts of ``kind`` that rows reference (``refs``: each row's index, −1: none),
        None when no row has one."""
        used = np.unique(refs[refs >= 0])
        if not len(used):
            return None
        parts = [self._parts[kind][i] for i in used]
        keys = {tuple(p) for p in parts}
        if len(keys) > 1:
            raise ValueError(f"the {kind} parts differ in columns: {sorted(keys)[:2]}")
        return _Kind(parts, pd.DataFrame.from_records(parts), np.searchsorted(used, refs))


@dataclass
class _Kind:
    """The referenced parts of one kind: as dicts, as one frame (``from_records``), and each
    row's position in them (meaningful where the row has a part of this kind)."""

    parts: list[dict[str, Any]]
    frame: pd.DataFrame
    position: np.ndarray


def _column_order(kinds: list[_Kind | None], refs: np.ndarray) -> list[str]:
    """The columns in order of first appearance over the rows (as ``from_records`` has them),
    checked: a row's parts and own columns share none."""
    present = refs >= 0
    shapes, first = np.unique(present.T, axis=0, return_index=True)
    order: dict[str, None] = {}
    for shape in shapes[np.argsort(first)]:
        names = [name for has, kind in zip(shape, kinds, strict=True) if has
                 for name in kind.frame.columns]  # fmt: skip
        names += [*OWN_COLUMNS, MEMBER]
        if len(set(names)) != len(names):
            raise ValueError(f"a row's parts share columns: {sorted(names)}")
        order.update(dict.fromkeys(names))
    return list(order)


def _gathered(name: str, kinds: list[_Kind | None], refs: np.ndarray) -> ExtensionArray:
    """Column ``name`` of every row, taken from the frames of the kinds that have it; inferred
    again from the parts' values where those frames differ in dtype or a row has none (NaN,
    as ``from_records`` fills)."""
    n = refs.shape[1]
    sources = [
        (kind, refs[i] >= 0)
        for i, kind in enumerate(kinds)
        if kind is not None and name in kind.frame.columns
    ]
    dtypes = {kind.frame[name].dtype for kind, _ in sources}
    if sum(int(has.sum()) for _, has in sources) == n and len(dtypes) == 1:
        if len(sources) == 1:
            kind, _ = sources[0]
            return kind.frame[name].array.take(kind.position)
        pieces = [kind.frame[name].array.take(kind.position[has]) for kind, has in sources]
        rows = np.concatenate([np.flatnonzero(has) for _, has in sources])
        return type(pieces[0])._concat_same_type(pieces).take(np.argsort(rows, kind="stable"))
    values = np.full(n, np.nan, dtype=object)
    for kind, has in sources:
        originals = np.empty(len(kind.parts), dtype=object)
        originals[:] = [part[name] for part in kind.parts]
        values[has] = originals[kind.position[has]]
    return _inferred(list(values))


def _inferred(values: list[Any]) -> ExtensionArray:
    """``values`` as ``from_records`` makes a column of them (dtype inferred from them)."""
    return pd.DataFrame.from_records([(v,) for v in values], columns=["v"])["v"].array


def _distinct_inferred(values: Sequence[Any]) -> ExtensionArray:
    """:func:`_inferred` of ``values`` that are ints or texts, each distinct one converted
    once (by type and value: ``1`` and ``True`` stay apart)."""
    codes, distinct = [], {}
    for v in values:
        codes.append(distinct.setdefault((type(v), v), len(distinct)))
    return _inferred([v for _, v in distinct]).take(np.asarray(codes, dtype=np.int64))
