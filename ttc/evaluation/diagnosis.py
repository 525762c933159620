"""What the FP.5 and FP.6 diagnoses share: which runs stand for a setting, their judged rows,
short setting labels and the reason table a rule set produces.

A diagnosis rule is a function of a frame table (one row per frame of a setting) that returns,
per rule, a Series of reason texts ('' where the rule does not fire).
:func:`with_reasons` turns those texts into two columns: ``reasons`` (the codes of the rules
that fired, ';'-joined) and ``reason_text`` (their texts). Tables in, tables out: no files.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable

import numpy as np
import pandas as pd

from ttc import reasons
from ttc.evaluation.errors import attach_reference, frame_errors, rows_of_runs
from ttc.evaluation.metrics import run_metrics
from ttc.settings import AXES

#: Axes of a camera setting: everything but the lidar estimator and the fusion.
CAMERA_AXES: tuple[str, ...] = tuple(a for a in AXES if a not in ("lidar_ttc", "fusion"))


def fmt(values: pd.Series, spec: str) -> pd.Series:
    """Element-wise ``format(v, spec)`` as strings (reason texts of a few flagged rows)."""
    return values.map(lambda v: format(v, spec)).astype(str)


def centimetres(values: pd.Series) -> pd.Series:
    """Metres as ``"12.3 cm"`` (``"n/a"`` for NaN)."""
    text = fmt(100.0 * values.astype(float), ".1f") + " cm"
    return text.where(values.notna(), "n/a")


def code_texts(codes: pd.Series) -> pd.Series:
    """``"code: description"`` (:data:`ttc.reasons.DESCRIPTIONS`) for non-ok reason codes,
    '' for ``ok`` and ''."""
    described = codes.map(lambda c: f"{c}: {reasons.DESCRIPTIONS.get(c, c)}")
    return described.where(~codes.isin(["", reasons.OK]), "")


def text_before(texts: pd.Series, sep: str) -> pd.Series:
    """Each text's part before its first ``sep`` (all of it without one), object dtype by
    ``texts``' index, missing and non-text values NaN (missing values of an object column as
    they are): ``texts.str.split(sep).str[0]``, each distinct text split once (a sweep's
    reason codes repeat a few dozen texts over 10⁵ rows; pandas splits every row)."""
    values = texts.to_numpy(dtype=object, copy=True)
    codes, distinct = pd.factorize(texts, use_na_sentinel=True)
    heads = np.array([t.split(sep, 1)[0] if isinstance(t, str) else np.nan for t in distinct],
                     dtype=object)  # fmt: skip
    found = codes >= 0
    values[found] = heads[codes[found]]
    return pd.Series(values, index=texts.index, dtype=object)


def combine_reasons(parts: dict[str, pd.Series], index: pd.Index) -> pd.DataFrame:
    """``reasons`` (codes joined by ';') and ``reason_text`` from per-rule texts ('' = no).

    Parameters
    ----------
    parts
        Rule name -> reason texts over ``index`` ('' where the rule does not fire). The rule
        named ``code`` contributes its text's prefix (a :mod:`ttc.reasons` code) as its code.
    index
        Index of the rows.

    Returns
    -------
    DataFrame over ``index`` with the string columns ``reasons`` and ``reason_text``.
    """
    if not parts:
        return pd.DataFrame({"reasons": "", "reason_text": ""}, index=index)
    texts = pd.DataFrame(parts, index=index).fillna("").astype(str)
    fired = texts.ne("")
    names = {c: text_before(texts[c], ":") if c == "code" else c for c in texts.columns}
    codes = functools.reduce(
        lambda a, b: a + b, [np.where(fired[c], names[c] + ";", "") for c in texts.columns]
    )
    text = functools.reduce(
        lambda a, b: a + b, [np.where(fired[c], texts[c] + ". ", "") for c in texts.columns]
    )
    out = pd.DataFrame({"reasons": codes, "reason_text": text}, index=index)
    out["reasons"] = out["reasons"].str.rstrip(";")
    out["reason_text"] = out["reason_text"].str.strip()
    return out


def with_reasons(
    t: pd.DataFrame,
    selected: str,
    rules: Callable[[pd.DataFrame], dict[str, pd.Series]],
    fallback_code: str,
    fallback: Callable[[pd.DataFrame], pd.Series],
) -> pd.DataFrame:
    """``t`` with ``reasons`` / ``reason_text`` on the rows where the boolean column
    ``selected`` is true: the rules that fire, else ``fallback_code`` and the text of
    ``fallback``; '' on the other rows (``t`` left as it is: a shallow copy, pandas copies on
    write)."""
    t = t.copy(deep=False)
    chosen = t[t[selected]]
    found = combine_reasons(rules(chosen), chosen.index)
    none = found["reasons"].eq("")
    found.loc[none, "reasons"] = fallback_code
    found.loc[none, "reason_text"] = fallback(chosen[none])
    t["reasons"], t["reason_text"] = "", ""
    t.loc[chosen.index, ["reasons", "reason_text"]] = found[["reasons", "reason_text"]]
    return t


def setting_labels(table: pd.DataFrame, axes: Iterable[str]) -> pd.Series:
    """A short label per row: the values of the ``axes`` that vary in ``table``, '/'-joined
    (detector/descriptor/matcher/selector when none varies)."""
    axes = [a for a in axes if a in table]
    varying = [a for a in axes if table[a].nunique() > 1]
    shown = varying or [a for a in ("detector", "descriptor", "matcher", "selector") if a in axes]
    return functools.reduce(lambda a, b: a + "/" + b, [table[a].astype(str) for a in shown])


def setting_key(table: pd.DataFrame, axes: Iterable[str]) -> pd.Series:
    """One string per row identifying its values of ``axes`` ('|'-joined; axes the table
    lacks, e.g. one added after its runs were recorded, are left out)."""
    present = [table[a].astype(str) for a in axes if a in table]
    return functools.reduce(lambda a, b: a + "|" + b, present)


def judged_rows(frames: pd.DataFrame, reference: pd.DataFrame, run_ids) -> pd.DataFrame:
    """Lead rows of the runs ``run_ids`` of ``frames`` with the reference attached and the
    per-frame errors (:func:`~ttc.evaluation.attach_reference`,
    :func:`~ttc.evaluation.frame_errors`)."""
    subset = rows_of_runs(frames, run_ids)
    return frame_errors(attach_reference(subset, reference))


def sweep_metrics(
    frames: pd.DataFrame, runs: pd.DataFrame, reference: pd.DataFrame
) -> pd.DataFrame:
    """One row per run of ``runs`` (run records): run id, sweep, axes, status, message and
    the run's :func:`~ttc.evaluation.run_metrics` (NaN for runs without rows), by run id."""
    keep = ["run_id", "sweep_id", *[a for a in AXES if a in runs], "status", "message"]
    table = runs[keep].copy()
    if not frames.empty:
        table = table.merge(
            run_metrics(frames, reference).drop(columns=list(AXES), errors="ignore"),
            on="run_id",
            how="left",
        )
    return table.sort_values("run_id", ignore_index=True)
