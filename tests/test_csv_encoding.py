"""write_csv: byte for byte what pandas' to_csv writes (every column kind, real report tables)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from experiments.report.encode import FLOAT_FORMAT, _csv_text, write_csv

REPO = Path(__file__).resolve().parents[1]

NASTY = [-0.0, 0.0, 1e-7, 1e21, -1e21, 123456.5, 1234565.0, 0.000123456789, 1e-5, 999999.5]
SPECIAL = [np.nan, np.inf, -np.inf, 5e-324, 1.7976931348623157e308, 1e16, 1e-300]


def pandas_text(df: pd.DataFrame) -> bytes:
    """What write_csv wrote before: pandas' own to_csv."""
    return df.to_csv(index=False, float_format=FLOAT_FORMAT, lineterminator="\n").encode()


def assert_identical(df: pd.DataFrame, tmp_path: Path, fast: bool = False) -> None:
    """write_csv of ``df`` is pandas' text; ``fast``: written without pandas' writer."""
    path = write_csv(df, tmp_path / "table.csv")
    assert path.read_bytes() == pandas_text(df)
    if fast:
        assert _csv_text(df) is not None


def random_floats(n: int, seed: int) -> np.ndarray:
    """(n,) floats over 40 decades with NaN, ±inf, -0.0 and rounding ties mixed in."""
    rng = np.random.default_rng(seed)
    values = rng.normal(size=n) * 10.0 ** rng.integers(-20, 20, size=n)
    values[rng.integers(0, n, size=n // 10)] = rng.integers(-(10**7), 10**7, size=n // 10) + 0.5
    extra = np.array(NASTY + SPECIAL)
    values[: len(extra)] = extra
    return values


def test_float_columns(tmp_path: Path) -> None:
    values = random_floats(20_000, 0)
    df = pd.DataFrame(
        {
            "f64": values,
            "f32": np.clip(values, -3e38, 3e38).astype(np.float32),
            "f16": np.clip(values, -6e4, 6e4).astype(np.float16),
            "all_nan": np.full(len(values), np.nan),
            "repeated": np.resize([-0.0, 0.0, np.nan, -np.nan, 1.5, -np.inf, 1e-7], len(values)),
            "ints_as_float": np.round(np.nan_to_num(values) % 1000),
        }
    )
    assert_identical(df, tmp_path, fast=True)


def test_integer_bool_and_string_columns(tmp_path: Path) -> None:
    strings = ["plain", "a,b", 'say "hi"', "two\nlines", "cr\rhere", " pad ", "tab\tx", "'", "",
               "nan", "ünï", None, np.nan]  # fmt: skip
    n = len(strings)
    df = pd.DataFrame(
        {
            "i64": np.arange(n, dtype=np.int64) * -(10**17),
            "u64": np.full(n, 2**64 - 1, dtype=np.uint64),
            "i8": np.arange(n, dtype=np.int8),
            "flag": np.arange(n) % 2 == 0,
            "obj": pd.Series(strings, dtype=object),
            "text": pd.Series(strings, dtype="str"),
            "name with, comma": np.linspace(0, 1, n),
            'quote"d': np.zeros(n),
        }
    )
    assert_identical(df, tmp_path, fast=True)


def test_other_column_kinds(tmp_path: Path) -> None:
    n = 7
    df = pd.DataFrame(
        {
            "cat": pd.Categorical(["a", None, "b,c", "a", None, "d", "a"]),
            "bool_none": pd.Series([True, None, False, True, None, False, True], dtype=object),
            "mixed": pd.Series([0.1, np.float64(1 / 3), None, "x", 7, True, np.nan], dtype=object),
            "Float64": pd.array([0.1, None, 1e21, -0.0, 1 / 3, np.inf, 2.5], dtype="Float64"),
            "Int64": pd.array([1, None, -(2**62), 0, 5, None, 7], dtype="Int64"),
            "boolean": pd.array([True, None, False, True, None, False, True], dtype="boolean"),
            "when": pd.to_datetime(
                ["2011-09-26", None, "2020-01-01 10:00:01.5"] * 2 + [None], format="ISO8601"
            ),
            "f": np.arange(n) / 3,
        }
    )
    assert_identical(df, tmp_path)
    for name in df.columns:  # each kind alone, beside a float column, and as the only column
        assert_identical(df[[name, "f"]], tmp_path)
        assert_identical(df[[name]], tmp_path)


def test_shapes_and_headers(tmp_path: Path) -> None:
    assert_identical(pd.DataFrame(), tmp_path)
    assert_identical(pd.DataFrame({"a": [], "b": []}), tmp_path)
    assert_identical(pd.DataFrame({"a": pd.Series([], dtype=float)}), tmp_path)
    assert_identical(pd.DataFrame({"": [np.nan, 1.0]}), tmp_path)
    assert_identical(pd.DataFrame({"only": [np.nan, np.nan]}), tmp_path)
    assert_identical(pd.DataFrame({"s": ["", None, "x"]}), tmp_path)
    assert_identical(pd.DataFrame({"a": [np.nan], "b": [None]}), tmp_path)
    assert_identical(pd.DataFrame([[1.5, 2.5]], columns=["x", "x"]), tmp_path)
    assert_identical(pd.DataFrame({0: [1.5], 1.5: [2.0], "s": ["a"]}), tmp_path)
    columns = pd.MultiIndex.from_tuples([("a", "x"), ("a", "y")])
    assert_identical(pd.DataFrame([[0.1, 0.2]], columns=columns), tmp_path)


def test_rounding_agrees_with_pandas_on_many_values(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    bits = rng.integers(0, 2**63, size=50_000, dtype=np.int64) * rng.choice([-1, 1], 50_000)
    df = pd.DataFrame({"bits": bits.view(np.float64), "x": random_floats(50_000, 2)})
    assert_identical(df, tmp_path, fast=True)


def report_csvs() -> list[Path]:
    """The biggest committed report tables under results/ (at most four)."""
    listed = subprocess.run(
        ["git", "ls-files", "results"], cwd=REPO, capture_output=True, text=True, check=False
    ).stdout.split()
    paths = [REPO / name for name in listed if name.endswith(".csv") and (REPO / name).is_file()]
    return sorted(paths, key=lambda path: path.stat().st_size, reverse=True)[:4]


@pytest.mark.parametrize("path", report_csvs(), ids=lambda path: path.parent.name + "/" + path.name)
def test_real_report_tables(path: Path, tmp_path: Path) -> None:
    df = pd.read_csv(path)
    assert len(df) > 0
    assert_identical(df, tmp_path, fast=True)
