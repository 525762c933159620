"""A report step in a forked process (:mod:`experiments.report.forked`): its result comes
back, its exception is raised in the report's process, a process that dies is named."""

from __future__ import annotations

import os

import numpy as np
import pandas as pd
import pytest

from experiments.report import forked


def test_the_result_comes_back_and_the_parent_memory_is_read() -> None:
    table = pd.DataFrame({"a": np.arange(100_000)})  # made before the fork: shared, not sent
    step = forked.start(lambda: (os.getpid(), int(table["a"].sum())), "sum")
    pid, total = step.result()
    assert pid != os.getpid() and total == 4_999_950_000


def test_a_step_not_forked_runs_in_this_process_when_its_result_is_asked_for() -> None:
    ran = []
    step = forked.start(lambda: ran.append(os.getpid()) or len(ran), "inline", fork=False)
    assert ran == []
    assert step.result() == 1 and ran == [os.getpid()]


def test_an_exception_is_raised_again_with_where_it_came_from() -> None:
    def broken() -> None:
        raise FileNotFoundError(2, "no such file", "/nowhere/objects.csv")

    step = forked.start(broken, "objects")
    with pytest.raises(FileNotFoundError) as info:
        step.result()
    assert info.value.filename == "/nowhere/objects.csv"
    assert any("'objects'" in note and "broken" in note for note in info.value.__notes__)


def test_an_exception_that_cannot_be_pickled_travels_as_its_text() -> None:
    class Local(Exception):  # defined in a function: cannot be pickled
        pass

    def broken() -> None:
        raise Local("the detector's files are gone")

    with pytest.raises(RuntimeError, match="Local: the detector's files are gone"):
        forked.start(broken, "objects").result()


def test_a_process_that_dies_is_named() -> None:
    with pytest.raises(forked.StepDied, match=r"'objects'.*exit code 7"):
        forked.start(lambda: os._exit(7), "objects").result()
