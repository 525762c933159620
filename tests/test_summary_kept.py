"""The end-of-sweep summary of a folder built in two invocations, from the metrics the first
one kept (:func:`experiments.lead_cache.run_metrics`), is the summary computed from scratch
and the ranking of every row (real sweep on KITTI frames 0-5)."""

from __future__ import annotations

import contextlib
import io
import shutil

import pandas as pd
import pytest

from experiments import lead_cache, store
from tests.test_batch import run

pytestmark = pytest.mark.slow

FIRST = ["detector=fast", "descriptor=brief,orb", "selector=nn,knn", "lidar_ttc=median,cluster",
         "dataset.last=5", "sweep_name=s"]  # fmt: skip


def _ranking(text: str) -> str:
    """The summary from its first ranking on (the counts above it name this invocation)."""
    return text[text.index("best ") :]


def test_a_summary_from_kept_metrics_is_the_summary_from_scratch(tmp_path, data_dir) -> None:
    from experiments.collect import summarise_sweep
    from experiments.reference_store import recording_references
    from ttc import evaluation as ev
    from ttc.engine.cache import StageCache

    cache, results = tmp_path / "cache", tmp_path / "results"
    first = run(FIRST, results, cache)
    assert first.returncode == 0, first.stderr[-3000:]
    # one downstream axis changed: the new runs load the stages the first ones computed, so
    # their ranking time comes from the first invocation's fragments' computed times
    second = run([*FIRST, "keypoint_filter=zscore"], results, cache)
    assert second.returncode == 0, second.stderr[-3000:]
    sweep = results / "s"
    kept = sorted((sweep / lead_cache.CACHE_DIR).glob("metrics-*.parquet"))
    assert len(kept) >= 2
    frames, runs = store.load_sweep(sweep)
    ok = runs[runs["status"] == "ok"]
    assert len(ok) == 16 and ok["keypoint_filter"].nunique() == 2
    (reference,) = recording_references(frames, ok, data_dir, StageCache(cache)).values()
    # the kept metrics (the second invocation's computed with the first's stage times) are
    # those of every row, computing times included
    whole = ev.run_metrics(frames, reference)
    pd.testing.assert_frame_equal(lead_cache.run_metrics(sweep, reference), whole)
    assert whole["ms_compute_per_frame"].notna().all()

    shutil.rmtree(sweep / lead_cache.CACHE_DIR)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        summarise_sweep(sweep, data_dir=data_dir, cache_dir=cache)
    assert _ranking(second.stdout) == _ranking(out.getvalue())
