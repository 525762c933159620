"""Hydra sweeper plugin of ttc-bench (``hydra/sweeper=ttc``, the project's default): a shim over
:mod:`experiments.sweep.sweeper`, Hydra's basic sweeper with a cheaper validation of values, a
plan before launch, every job run when some fail and a one-line Ctrl-C."""

# No ``from __future__ import annotations``: dataclasses of a plugin module need real types.
from dataclasses import dataclass
from typing import Optional

from hydra.core.config_store import ConfigStore

from experiments.sweep.sweeper import SweepSweeper


@dataclass
class TTCSweeperConf:
    """``hydra/sweeper=ttc``: the basic sweeper's options and the ttc sweeper's own."""

    _target_: str = "hydra_plugins.ttc_sweeper.TTCSweeper"
    #: Most jobs launched at once (None: all of them), as Hydra's basic sweeper.
    max_batch_size: Optional[int] = None  # noqa: UP045 (Hydra)
    #: The swept overrides, ``{key: values}`` (an experiment's ``hydra.sweeper.params``).
    params: Optional[dict[str, str]] = None  # noqa: UP045 (Hydra)
    #: Dotted path of a function(cfg) raising ValueError for a config whose values are wrong.
    validator: Optional[str] = "experiments.configs.structured.validate_config"  # noqa: UP045 (Hydra)
    #: Most settings one job computes together (1: one setting per job, no batches).
    max_settings_per_job: int = 200


class TTCSweeper(SweepSweeper):
    """:class:`experiments.sweep.sweeper.SweepSweeper`, where Hydra finds plugins."""


ConfigStore.instance().store(group="hydra/sweeper", name="ttc", node=TTCSweeperConf, provider="ttc")

__all__ = ["TTCSweeper", "TTCSweeperConf"]
