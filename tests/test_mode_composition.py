"""A multirun's config composed once where Hydra composes it twice
(:mod:`experiments.sweep.mode_composition`), with Hydra's own ``get_mode`` and ``multirun``
requests on the project's config tree."""

from __future__ import annotations

import pytest
from hydra._internal.config_loader_impl import ConfigLoaderImpl
from hydra._internal.hydra import Hydra
from hydra._internal.utils import create_config_search_path
from hydra.core.global_hydra import GlobalHydra
from hydra.errors import ConfigCompositionException
from hydra.types import RunMode
from omegaconf import OmegaConf

from experiments.configs.structured import register_configs
from experiments.sweep.mode_composition import compose_once
from tests.conftest import PROJECT_ROOT

OVERRIDES = ["+experiment=fp6_grid", "dataset.last=5", "keypoint_filter=iqr"]


@pytest.fixture
def hydra(monkeypatch):
    """(Hydra's app object on conf/, the list of compositions it really made)."""
    register_configs()
    made: list[list[str]] = []
    impl = ConfigLoaderImpl._load_configuration_impl

    def counted(self, config_name, overrides, *args, **kwargs):
        made.append(list(overrides))
        return impl(self, config_name, overrides, *args, **kwargs)

    monkeypatch.setattr(ConfigLoaderImpl, "_load_configuration_impl", counted)
    monkeypatch.setattr(ConfigLoaderImpl, "load_configuration", ConfigLoaderImpl.load_configuration)
    compose_once()
    compose_once()  # idempotent: one wrapper
    app = Hydra.create_main_hydra2("test", create_config_search_path(str(PROJECT_ROOT / "conf")))
    yield app, made
    GlobalHydra.instance().clear()


def multirun_config(app: Hydra, overrides: list[str]):
    """The composition ``Hydra.multirun`` asks for."""
    return app.compose_config("config", overrides, run_mode=RunMode.MULTIRUN)


def test_get_mode_then_multirun_compose_once(hydra) -> None:
    """Hydra's two requests of a multirun make one composition, equal to a composition of its
    own; a third request composes again."""
    app, made = hydra
    assert app.get_mode("config", list(OVERRIDES)) == RunMode.MULTIRUN
    cfg = multirun_config(app, list(OVERRIDES))
    assert len(made) == 1
    again = multirun_config(app, list(OVERRIDES))
    assert len(made) == 2 and again is not cfg
    assert OmegaConf.to_container(cfg, resolve=False) == OmegaConf.to_container(
        again, resolve=False
    )


def test_other_requests_compose_as_before(hydra) -> None:
    """Another override list or a run's RUN-mode request is composed, never given the kept
    composition."""
    app, made = hydra
    app.get_mode("config", list(OVERRIDES))
    other = multirun_config(app, [*OVERRIDES[:-1], "keypoint_filter=zscore"])
    assert len(made) == 2 and other.keypoint_filter.name == "zscore"
    app.get_mode("config", ["detector=orb"])
    run = app.compose_config("config", ["detector=orb"], run_mode=RunMode.RUN)
    assert len(made) == 4 and run.detector.name == "orb"


def test_sweeping_hydra_config_still_refused(hydra) -> None:
    """The kept composition is checked as Hydra checks its own: sweeping over Hydra's
    config fails in the second request (``get_mode`` does not check)."""
    app, made = hydra
    overrides = [*OVERRIDES, "hydra.job.name=a,b"]
    app.get_mode("config", list(overrides))
    with pytest.raises(ConfigCompositionException, match="Sweeping over Hydra's configuration"):
        multirun_config(app, list(overrides))
    assert len(made) == 1
