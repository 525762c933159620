"""``python -m experiments.report SWEEP [SWEEP ...] --out DIR`` (see :mod:`experiments.report.report_command`)."""

from experiments.report.report_command import main

main()
