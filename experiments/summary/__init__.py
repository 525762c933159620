"""The end-of-sweep summary and every table derived from a sweep's stored rows.

One entry point: :func:`experiments.summary.collect.summarise_sweep` (``ttc-bench collect``,
and a sweep's end through :mod:`experiments.sweep.callbacks`). What it keeps, and where:

* ``<sweep>/.summary/<kind>-<digest>.parquet``: tables kept per fragment of the append-only
  store, named one way (:mod:`.kept_tables`): ``lead`` (each fragment's lead rows,
  :mod:`.lead_rows`), ``metrics`` (each fragment's runs' metrics, :mod:`.run_metrics`) and
  ``ranked`` (every run's ranking keys and rank, merged with a re-run's new runs,
  :mod:`.kept_ranking`); ``counts.pkl`` and ``schemas.pkl`` beside them;
* the stage cache (``$TTC_CACHE_DIR``): a recording's reference TTC and every object's boxes
  and reference (:mod:`.references`), keyed by the recording's inputs;
* nothing else: which recording a run is on and which report a sweep gets are derived from
  the run records each time (:mod:`.recordings`).

Deleting ``.summary/`` is always safe. The report (:mod:`experiments.report`) reads the same
tables and keeps its own cut of each fragment's rows there, named the same way (kinds
``judged`` and ``boxes``, ``counted-<digest>.pkl`` beside them:
:mod:`experiments.report.kept_judged`); the sweep (:mod:`experiments.sweep`) calls the
summary when it ends. Imports :mod:`experiments.store` and the layers below it only.
"""
