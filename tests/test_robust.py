"""ttc.robust.median is numpy.median, and ttc.robust.quantile / quantiles are numpy.quantile, bit
for bit, on every kind of array the rows reduce.

Synthetic arrays: an exact check of each function against NumPy's (sizes 1–401, odd and
even, float64 and the lidar's float32, integers, ties, NaN, strided views, empty; for the
quantiles also every q from 0 to 1, one or several, Python and NumPy numbers)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from ttc.robust import column_medians, median, quantile, quantiles


def _same(ours, theirs) -> bool:
    """Equal bit for bit, dtype included (NaN equal to NaN)."""
    ours, theirs = np.asarray(ours), np.asarray(theirs)
    return ours.dtype == theirs.dtype and ours.tobytes() == theirs.tobytes()


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_median_is_numpys_on_random_arrays(dtype):
    rng = np.random.default_rng(7)
    for n in [*range(1, 40), 64, 65, 200, 401]:
        for scale in (1e-3, 1.0, 37.5, 1e6):
            v = (rng.normal(size=n) * scale).astype(dtype)
            assert _same(median(v), np.median(v)), (n, scale)
            ties = np.round(v[: max(1, n // 2)]).repeat(2)  # equal middle values
            assert _same(median(ties), np.median(ties)), (n, scale)


def test_median_of_integers_strided_views_and_columns():
    rng = np.random.default_rng(3)
    ints = rng.integers(-1000, 1000, size=51)
    assert _same(median(ints), np.median(ints))
    assert _same(median(ints[:-1]), np.median(ints[:-1]))
    points = rng.normal(size=(31, 4)).astype(np.float32) * 20  # a scan's x column: a view
    assert _same(median(points[:, 0]), np.median(points[:, 0]))
    for n in (1, 2, 9, 10):
        xy = rng.normal(size=(n, 2)) * 5
        assert _same(column_medians(xy), np.median(xy, axis=0))
        assert _same(column_medians(xy.astype(np.float32)), np.median(xy.astype(np.float32), 0))


def test_median_with_nan_and_empty():
    for zeros in ([-0.0], [-0.0, -0.0], [0.0, -0.0], [-0.0, 1.0, -0.0]):  # NumPy gives +0.0
        assert _same(median(np.array(zeros)), np.median(np.array(zeros))), zeros
    v = np.array([1.0, np.nan, 3.0, 2.0])
    assert np.isnan(median(v)) and np.isnan(np.median(v))
    assert np.isnan(median(v[:3]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # NumPy warns on an empty mean; ours is silent
        assert np.isnan(median(np.empty(0)))
        assert median(np.empty(0, np.float32)).dtype == np.float32
    unchanged = np.array([3.0, 1.0, 2.0])
    median(unchanged)
    assert unchanged.tolist() == [3.0, 1.0, 2.0]  # the input is not reordered


#: Quantiles the steps ask for (the Tukey fences, the nearest face, the spread, the lidar's
#: default estimator) and others in between, both ends included.
QS = [0.0, 0.05, 0.1, 0.1234, 0.25, 0.3, 0.5, 0.75, 0.9, 0.95, 0.99, 1.0]


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.int64])
def test_quantiles_are_numpys_on_random_arrays(dtype):
    rng = np.random.default_rng(11)
    for n in [*range(1, 40), 64, 65, 200, 401]:
        for scale in (1e-3, 1.0, 37.5, 1e6):
            v = (rng.normal(size=n) * scale).astype(dtype)
            ties = np.round(v[: max(1, n // 2)]).repeat(2)
            for values in (v, ties):
                for q in QS:  # a Python number (NumPy's "weak" q) and a NumPy one
                    assert _same(quantile(values, q), np.quantile(values, q)), (n, q)
                    assert _same(
                        quantile(values, np.float64(q)), np.quantile(values, np.float64(q))
                    )
                for pair in ((0.25, 0.75), (0.05, 0.95), (0.5,), (0.0, 0.3, 1.0)):
                    assert _same(quantiles(values, pair), np.quantile(values, list(pair))), n


def test_quantiles_with_nan_views_and_empty():
    rng = np.random.default_rng(5)
    points = rng.normal(size=(31, 4)).astype(np.float32) * 20
    x = points[:, 0]  # a view
    assert _same(quantile(x, 0.05), np.quantile(x, 0.05))
    assert _same(quantiles(x, (0.05, 0.95)), np.quantile(x, [0.05, 0.95]))
    v = np.array([1.0, np.nan, 3.0, 2.0])
    assert _same(quantiles(v, (0.25, 0.75)), np.quantile(v, [0.25, 0.75]))  # NaN, NaN
    assert _same(quantile(v.astype(np.float32), 0.5), np.quantile(v.astype(np.float32), 0.5))
    with pytest.raises(IndexError):
        np.quantile(np.empty(0), [0.25])
    with pytest.raises(IndexError):
        quantiles(np.empty(0), (0.25,))
    unchanged = np.array([3.0, 1.0, 2.0])
    quantiles(unchanged, (0.25, 0.75))
    assert unchanged.tolist() == [3.0, 1.0, 2.0]
