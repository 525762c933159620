"""Hydra sweeper plugin of ttc-bench (``hydra/sweeper=ttc``, the project's default): a shim over
:mod:`experiments.sweep.sweeper`, Hydra's basic sweeper with a cheaper validation of values, a
plan before launch, every job run when some fail and a one-line Ctrl-C."""

# No ``from __future__ import annotations``: dataclasses of a plugin module need real types.
from dataclasses import dataclass
from typing import Optional

from hydra._internal.core_plugins.basic_sweeper import BasicSweeperConf
from hydra.core.config_store import ConfigStore

from experiments.sweep.sweeper import SweepSweeper


@dataclass
class TTCSweeperConf(BasicSweeperConf):
    _target_: str = "hydra_plugins.ttc_sweeper.TTCSweeper"
    #: Dotted path of a function(cfg) raising ValueError for a config whose values are wrong.
    validator: Optional[str] = "experiments.config.validate_config"  # noqa: UP045 (Hydra)
    #: Most settings one job computes together (1: one setting per job, no batches).
    max_settings_per_job: int = 200


class TTCSweeper(SweepSweeper):
    """:class:`experiments.sweep.sweeper.SweepSweeper`, where Hydra finds plugins."""


ConfigStore.instance().store(group="hydra/sweeper", name="ttc", node=TTCSweeperConf, provider="ttc")

__all__ = ["TTCSweeper", "TTCSweeperConf"]
