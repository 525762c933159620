"""Judging TTC estimates: the reference, per-frame errors, per-run metrics, the ranking and its
intervals, and the FP.5 / FP.6 diagnosis rules. Tables and arrays in, tables out: no files,
no Hydra (the writers in :mod:`experiments.report` turn the tables into reports)."""
