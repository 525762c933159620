"""``python -m experiments.judge`` = ``ttc-bench judge``."""

from experiments.judge.judge_command import main

main()
