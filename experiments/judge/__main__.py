"""``python -m experiments.judge`` = ``ttc-bench judge``."""

from experiments.judge.cli import main

main()
