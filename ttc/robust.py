"""Robust statistics of the small 1-D arrays each box pair reduces: the median, quantiles and the
scale of a median absolute deviation.

A box pair's FP.2–FP.4 take medians of a few to a few hundred values (lidar x, distance
ratios, displacement lengths), several per row and thousands of rows per setting.
:func:`numpy.median` costs ≈ 17 µs a call whatever the size (its axis and NaN handling in
Python); :func:`median` returns the same value, bit for bit, in ≈ 3.5 µs: one
:func:`numpy.partition` and, for an even count, the mean of the two middle values computed
as NumPy computes it. :func:`numpy.quantile` costs ≈ 55 µs a call (NumPy 2.4); :func:`quantile`
and :func:`quantiles` return its linear-interpolation values, bit for bit, in 6–9 µs: one
:func:`numpy.partition` and NumPy's own interpolation formula on the two order statistics.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Scales a median absolute deviation to a Gaussian standard deviation.
MAD_TO_SIGMA = 1.4826


def median(values: np.ndarray) -> np.floating:
    """:func:`numpy.median` of a 1-D array, the same value and dtype (float64 for integers;
    NaN when any value is NaN or the array is empty, without a warning).

    Parameters
    ----------
    values : (N,) array of numbers, any unit.
    """
    v = np.asarray(values)
    if v.dtype.kind != "f":
        v = v.astype(np.float64)
    n = v.size
    if n == 0:
        return v.dtype.type(np.nan)
    half = n // 2
    # NumPy's mean of the middle value(s), in v's dtype: a sum from +0.0 (so −0.0 gives
    # +0.0), divided by the count
    if n % 2:
        part = np.partition(v, (half, n - 1))  # the largest last: a NaN sorts there
        middle = part[half] + 0.0
    else:
        part = np.partition(v, (half - 1, half, n - 1))
        middle = (part[half - 1] + part[half] + 0.0) / 2
    return v.dtype.type(np.nan) if np.isnan(part[-1]) else middle


def column_medians(values: np.ndarray) -> np.ndarray:
    """``numpy.median(values, axis=0)`` of an (N × D) array, column by column (D,)."""
    v = np.asarray(values)
    return np.array([median(v[:, j]) for j in range(v.shape[1])])


def _order_statistics(values: np.ndarray, qs: Sequence[float]) -> tuple[np.ndarray, list]:
    """The values as NumPy's linear quantile partitions them and, per ``q``, the positions
    of the two order statistics it interpolates and the weight of the second (NumPy's
    ``_get_indexes`` / ``_get_gamma``: past the last position both are the last value and
    the weight is counted from position −1)."""
    v = np.asarray(values)
    if v.dtype.kind != "f":
        v = v.astype(np.float64)
    n = v.size
    if n == 0:
        raise IndexError("quantile of an empty array")
    picks, kth = [], {0, n - 1}
    for q in qs:
        virtual = (n - 1) * q
        below = int(np.floor(virtual))
        if virtual >= n - 1:
            below = above = -1
        else:
            above = below + 1
        picks.append((below, above, virtual - below))
        kth.update((below % n, above % n))
    return np.partition(v, sorted(kth)), picks


def _lerp(a: np.generic, b: np.generic, t: float) -> np.generic:
    """NumPy's ``_lerp``: ``a + (b − a)·t``, or ``b − (b − a)·(1 − t)`` from t = 0.5 on."""
    diff = b - a
    return b - diff * (1 - t) if t >= 0.5 else a + diff * t


def quantiles(values: np.ndarray, qs: Sequence[float]) -> tuple[np.float64, ...]:
    """``numpy.quantile(values, list(qs))`` of a 1-D array (linear interpolation), the same
    float64 values, one per ``q`` (NaN when any value is NaN; ``IndexError`` when empty).

    Parameters
    ----------
    values : (N,) array of numbers, any unit.
    qs : quantiles in [0, 1].
    """
    part, picks = _order_statistics(values, qs)
    if np.isnan(part[-1]):
        return tuple(np.float64(np.nan) for _ in picks)
    return tuple(np.float64(_lerp(part[i], part[j], np.float64(t))) for i, j, t in picks)


def quantile(values: np.ndarray, q: float) -> np.floating:
    """``numpy.quantile(values, q)`` of a 1-D array for one ``q`` (linear interpolation): the
    same value and dtype (NaN when any value is NaN; ``IndexError`` when empty). As NumPy's,
    a plain Python ``q`` interpolates in the array's float dtype (float32 stays float32), a
    NumPy number in float64."""
    part, ((i, j, t),) = _order_statistics(values, (q,))
    weak = type(q) in (int, float)
    dtype = part.dtype.type if weak else np.float64
    if np.isnan(part[-1]):
        return dtype(np.nan)
    return dtype(_lerp(part[i], part[j], float(t) if weak else np.float64(t)))
