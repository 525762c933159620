"""``ttc-bench``: one command name for the ``python -m experiments...`` entry points.

Each subcommand runs its module exactly as ``python -m`` does (same ``__main__`` code, same
arguments, Hydra overrides passed through untouched), so the two spellings never drift::

    ttc-bench run detector=orb descriptor=brisk        # = python -m experiments.run ...
    ttc-bench sweep detector=fast,orb                  # = python -m experiments.run -m ...
    ttc-bench report sweeps/fp6_grid_kitti_0_18 --out reports/kitti_0_18
    ttc-bench run --help                               # each subcommand's own help
"""

from __future__ import annotations

import runpy
import sys
from dataclasses import dataclass


@dataclass(frozen=True)
class Subcommand:
    """A subcommand: the module it runs, a one-line summary, arguments put before the user's."""

    module: str
    summary: str
    prefix: tuple[str, ...] = ()


SUBCOMMANDS: dict[str, Subcommand] = {
    "run": Subcommand("experiments.run", "run one setting, or a sweep with -m / +experiment=..."),
    "sweep": Subcommand(
        "experiments.run", "run a sweep: `run -m` with the same overrides", ("-m",)
    ),
    "collect": Subcommand(
        "experiments.summary.collect", "print a sweep's summary (counts, best settings)"
    ),
    "compact": Subcommand(
        "experiments.tools.compact_command", "merge a sweep's small rows files into larger ones"
    ),
    "report": Subcommand("experiments.report", "write the FP.5 / FP.6 reports of sweeps"),
    "judge": Subcommand(
        "experiments.judge", "judge another implementation's TTC numbers beside the harness's"
    ),
    "compare": Subcommand("experiments.tools.compare", "compare two sweeps setting by setting"),
    "show": Subcommand("experiments.tools.show", "pictures of one frame pair of one setting"),
    "download": Subcommand("experiments.data.download", "download (or complete) the KITTI frames"),
    "benchmark": Subcommand("experiments.tools.benchmark", "time the main sweep (cold and warm)"),
    "schema": Subcommand("experiments.store.schema", "print the columns of the rows dataset"),
    "export": Subcommand(
        "experiments.tools.export", "one setting of a sweep as an MCAP file for Foxglove"
    ),
    "learned-timing": Subcommand(
        "experiments.tools.learned_timing", "per-stage CPU / CUDA times of the learned features"
    ),
}
#: Subcommands whose module reads no arguments: ``--help`` is answered here.
NO_ARGUMENTS = ("schema",)


def usage() -> str:
    """The top-level help: every subcommand with its summary."""
    width = max(map(len, SUBCOMMANDS))
    lines = [
        f"  {name:<{width}}  {sub.summary} (python -m {' '.join([sub.module, *sub.prefix])})"
        for name, sub in SUBCOMMANDS.items()
    ]
    return (
        "usage: ttc-bench SUBCOMMAND [ARGS ...]\n\n"
        "Camera + lidar time-to-collision benchmark on KITTI.\n\nsubcommands:\n"
        + "\n".join(lines)
        + "\n\n`ttc-bench SUBCOMMAND --help` gives a subcommand's own help; Hydra overrides "
        "(key=value) pass through.\n"
    )


#: Subcommands handed to the warm server when one is running (``experiments.warm``).
SERVED = ("run", "sweep")


def run_subcommand(args: list[str]) -> int:
    """Run ``args`` (a subcommand and its arguments) in this process; its exit status
    (``SystemExit`` of the subcommand passes through)."""
    if not args or args[0] in ("-h", "--help", "help"):
        print(usage(), end="")
        return 0 if args else 2
    name, rest = args[0], args[1:]
    if name not in SUBCOMMANDS:
        print(f"ttc-bench: unknown subcommand {name!r}\n\n{usage()}", file=sys.stderr)
        return 1
    sub = SUBCOMMANDS[name]
    if name in NO_ARGUMENTS and rest:
        print(f"usage: ttc-bench {name}\n\n{sub.summary} (takes no arguments).")
        return 0 if rest[0] in ("-h", "--help") else 2
    sys.argv = [f"ttc-bench {name}", *sub.prefix, *rest]
    try:
        runpy.run_module(sub.module, run_name="__main__", alter_sys=True)
    except BrokenPipeError:  # `ttc-bench schema | head`: the reader left, nothing is wrong
        sys.stderr.close()
    return 0


def main(argv: list[str] | None = None) -> None:
    """Dispatch ``argv`` (default ``sys.argv[1:]``) to its subcommand's module: on the warm
    server when one serves this code and environment (``experiments.warm``; ``run`` and
    ``sweep``), else here, starting a server for the next command afterwards."""
    args = sys.argv[1:] if argv is None else list(argv)
    forwarded = None
    if args and args[0] in SERVED and argv is None:
        from experiments.warm.client import forward  # noqa: PLC0415 (standard library only)

        forwarded = forward(args)
        if forwarded.status is not None:
            sys.exit(forwarded.status)
    try:
        sys.exit(run_subcommand(args))
    finally:
        if forwarded is not None and forwarded.start is not None:
            from experiments.warm.client import start_server  # noqa: PLC0415

            start_server(forwarded)


if __name__ == "__main__":
    main()
