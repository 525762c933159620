"""``ttc-bench compact SWEEP``: merge a sweep's small rows files into larger ones, atomically
(:func:`experiments.store.compact`: same rows, same order; safe while sweeps write).

Usage::

    ttc-bench compact sweeps/grand_kitti_0_18 [--target-rows 1000000]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from experiments.store import StoreError, compact
from experiments.store.compact import TARGET_ROWS


def main(argv: list[str] | None = None) -> None:
    """Compact the sweep folder given; exit 1 with one line naming a corrupt fragment."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep_dir", type=Path, help="the sweep folder (hydra.sweep.dir)")
    parser.add_argument("--target-rows", type=int, default=TARGET_ROWS,
                        help="rows of a merged file, at most (default %(default)s)")  # fmt: skip
    args = parser.parse_args(argv)
    try:
        done = compact(args.sweep_dir, args.target_rows)
    except StoreError as exc:
        parser.exit(1, f"compact failed: {exc}\n")
    print(f"{args.sweep_dir}: {done.merged} rows files merged into {done.written} "
          f"({done.runs} runs repointed), {done.removed} files no record names removed"
          + (f", {done.skipped_groups} group(s) left: a run was recomputed meanwhile"
             if done.skipped_groups else ""))  # fmt: skip
    sys.stdout.flush()


if __name__ == "__main__":
    main()
