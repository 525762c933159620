"""``python -m experiments.report SWEEP [SWEEP ...] --out DIR`` (see :mod:`experiments.report.cli`)."""

from experiments.report.cli import main

main()
