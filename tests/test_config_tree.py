"""Every option of every config group composes and builds the core's objects (in the style of
lightning-hydra-template's config tests): a broken YAML or a schema drift fails here, not in
the middle of a sweep."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from experiments.configs.structured import (
    frame_range_from_config,
    register_configs,
    run_id,
    setting_config,
    settings_from_config,
)
from tests.conftest import PROJECT_ROOT
from ttc.io.ros2_bag import BagSource
from ttc.settings import AXES

CONF = PROJECT_ROOT / "conf"
#: Config groups chosen with ``group=option``: every axis (one folder each) and the launcher.
GROUPS = [*AXES, "hydra/launcher"]
OPTIONS = [(g, p.stem) for g in GROUPS for p in sorted((CONF / g).glob("*.yaml"))]
EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))


def composed(overrides: list[str]) -> DictConfig:
    register_configs()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=overrides, return_hydra_config=True)


def test_the_schemas_are_stored_once_per_config_store(monkeypatch) -> None:
    """A served command runs ``experiments.run`` again as ``__main__`` in a process whose
    ConfigStore holds the schemas: nothing is stored again; a new store (a worker restoring
    Hydra's singletons) gets them."""
    from hydra.core.config_store import ConfigStore

    register_configs()
    store = ConfigStore.instance()
    monkeypatch.setattr(store, "store", lambda *a, **k: pytest.fail("stored again"))
    register_configs()
    monkeypatch.undo()
    fresh = ConfigStore()
    monkeypatch.setitem(type(store)._instances, ConfigStore, fresh)
    register_configs()
    assert "dataset.yaml" in fresh.repo["schema"] and "ttc_schema.yaml" in fresh.repo


def test_every_axis_has_a_config_group_folder() -> None:
    assert all((CONF / axis).is_dir() for axis in AXES)
    assert len(OPTIONS) > 2 * len(GROUPS)


#: Options that need a file the user brings: given a path, so the test reaches the core.
USER_FILES = {
    ("objects", "yolov3"): ["objects.weights_path=/nonexistent/yolov3.weights"],
    ("dataset", "kitti_raw"): ["dataset.last=18"],  # a drive the shared data does not hold
    ("dataset", "ros2_bag"): ["dataset.path=/nonexistent/drive.mcap", "dataset.last=18"],
    ("dataset", "kitti2mcap"): ["dataset.path=/nonexistent/0009.mcap", "dataset.last=15"],
}


@pytest.mark.parametrize(("group", "option"), OPTIONS)
def test_every_option_composes_and_builds_the_core_objects(group: str, option: str) -> None:
    cfg = composed([f"{group}={option}", *USER_FILES.get((group, option), [])])
    if group in AXES and group != "dataset":
        assert cfg[group].name == option
    settings = settings_from_config(cfg)
    frames = frame_range_from_config(cfg)
    assert settings.axes()[AXES[0]] == cfg[AXES[0]].name
    assert isinstance(frames.sequence_dir, Path | BagSource) and frames.first <= frames.last
    assert len(run_id(cfg)) == 16 and set(AXES) <= set(setting_config(cfg))


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_experiment_composes_as_a_multirun(experiment: str) -> None:
    cfg = composed([f"+experiment={experiment}"])
    assert str(cfg.hydra.mode) == "RunMode.MULTIRUN"
    params = cfg.hydra.sweeper.params
    assert params and set(params) <= set(AXES) | {
        "lidar.shrink",
        "dataset.step",
        "dataset.drive",
        "detector.subpixel",
    }
    assert experiment in cfg.sweep_name
    settings_from_config(cfg)
