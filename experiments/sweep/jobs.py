"""The jobs of a multirun, by Hydra's basic sweeper's rule: the cartesian product of the
sweeper's ``params`` and the command line's overrides (``key=a,b``, ``range(...)``,
``glob(...)`` over a group's options), the last override of a key taking its place, the first
key first; in batches of at most ``max_batch_size`` jobs (None: one batch). A test checks it
against Hydra's own basic sweeper."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

from hydra.core.override_parser.types import Override
from hydra.errors import HydraException


def expand(overrides: Sequence[Override]) -> list[list[str]]:
    """Every job's overrides (``key=value`` strings) of parsed sweep ``overrides``."""
    values: dict[str, list[str]] = {}
    for override in overrides:
        key = override.get_key_element()
        if not override.is_sweep_override():
            values[key] = [f"{key}={override.get_value_element_as_str()}"]
        elif override.is_discrete_sweep():
            values[key] = [f"{key}={value}" for value in override.sweep_string_iterator()]
        else:
            assert override.value_type is not None
            raise HydraException(f"the ttc sweeper does not support {override.value_type.name}")
    return [list(job) for job in itertools.product(*values.values())]


def batches(jobs: list[list[str]], max_batch_size: int | None) -> list[list[list[str]]]:
    """``jobs`` in batches of at most ``max_batch_size`` (None: all in one)."""
    if max_batch_size is None:
        return [jobs]
    assert max_batch_size > 0
    return [jobs[i : i + max_batch_size] for i in range(0, len(jobs), max_batch_size)]
