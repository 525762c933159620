"""Hydra launcher plugin of ttc-bench (``hydra/launcher=ttc_joblib``, the default through
``conf/hydra/launcher/local.yaml``): a shim over :mod:`experiments.sweep.launcher`, Hydra's
joblib launcher with cheaper per-job set-up. It takes the joblib launcher's options;
``override hydra/launcher: joblib`` gives the stock one back."""

# No ``from __future__ import annotations``: dataclasses of a plugin module need real types.
from dataclasses import dataclass

from hydra.core.config_store import ConfigStore
from hydra_plugins.hydra_joblib_launcher.config import JobLibLauncherConf

from experiments.sweep.launcher import SweepLauncher


@dataclass
class TTCLauncherConf(JobLibLauncherConf):
    """``hydra/launcher=ttc_joblib``: the joblib launcher's options."""

    _target_: str = "hydra_plugins.ttc_launcher.TTCLauncher"


class TTCLauncher(SweepLauncher):
    """:class:`experiments.sweep.launcher.SweepLauncher`, where Hydra finds plugins."""


ConfigStore.instance().store(
    group="hydra/launcher", name="ttc_joblib", node=TTCLauncherConf, provider="ttc"
)

__all__ = ["TTCLauncher", "TTCLauncherConf"]
