"""Hydra sweeper of ttc-bench: the basic sweeper with a cheaper up-front validation.

Hydra's basic sweeper composes every job's config in the main process before launching any
(``validate_batch_is_legal``), ~0.15 s each with this config tree: 25 s of serial work for
the 168-setting ``fp6_grid``, longer than the rest of a warm sweep. This sweeper composes
just enough configs that every distinct override value appears in one of them (the k-th
config takes the k-th distinct value of every swept key): a typo in any key or value still
fails, with Hydra's message, before any job runs, at 7 compositions for the grid (the most
values of one key). The jobs themselves are unchanged.
"""

# No ``from __future__ import annotations``: Hydra loads plugin modules without registering
# them in sys.modules, and dataclasses then cannot resolve string annotations.
from collections.abc import Sequence
from dataclasses import dataclass

from hydra._internal.core_plugins.basic_sweeper import BasicSweeper, BasicSweeperConf
from hydra.core.config_store import ConfigStore
from hydra.plugins.sweeper import Sweeper


@dataclass
class TTCSweeperConf(BasicSweeperConf):
    _target_: str = "hydra_plugins.ttc_sweeper.TTCSweeper"


ConfigStore.instance().store(group="hydra/sweeper", name="ttc", node=TTCSweeperConf, provider="ttc")


def representative_jobs(batch: Sequence[Sequence[str]]) -> list[list[str]]:
    """Jobs that hold every distinct ``key=value`` of ``batch`` at least once: the k-th takes
    the k-th distinct value at every position (the first job's value where a position has
    fewer); as many jobs as the most values of one position. A job whose overrides do not
    line up with the first job's is kept as it is."""
    if not batch:
        return []
    first = list(batch[0])
    values: list[list[str]] = [[item] for item in first]
    odd: list[list[str]] = []
    for job in batch[1:]:
        if len(job) != len(first):
            odd.append(list(job))
            continue
        for position, item in enumerate(job):
            if item not in values[position]:
                values[position].append(item)
    count = max((len(v) for v in values), default=1)
    jobs = [[v[k] if k < len(v) else v[0] for v in values] for k in range(count)]
    return jobs + odd


class TTCSweeper(BasicSweeper):
    """:class:`BasicSweeper` validating one composition per distinct override value."""

    def validate_batch_is_legal(self, batch: Sequence[Sequence[str]]) -> None:
        Sweeper.validate_batch_is_legal(self, representative_jobs(batch))


__all__ = ["TTCSweeper", "TTCSweeperConf", "representative_jobs"]
