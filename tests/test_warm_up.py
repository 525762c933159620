"""The workers' warm-up fills the stage cache with what every setting of a sweep shares."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.types import RunMode

from experiments.configs.structured import register_configs
from experiments.sweep.warm_up import swept_keys, warm_up
from tests.conftest import PROJECT_ROOT


@pytest.fixture(scope="module")
def master_of():
    """The master config Hydra gives the launcher of a multirun with these overrides."""
    register_configs()
    with initialize_config_dir(config_dir=str(PROJECT_ROOT / "conf"), version_base="1.3"):
        loader = GlobalHydra.instance().config_loader()
        yield lambda overrides: loader.load_configuration(
            "config", overrides, run_mode=RunMode.MULTIRUN
        )


def entries(cache: Path) -> dict[str, int]:
    return {d.name: len(list(d.rglob("*.arr"))) for d in cache.iterdir() if d.is_dir()}


def test_a_cold_sweep_gets_its_shared_stages_and_reference(master_of, data_dir, tmp_path) -> None:
    cache = tmp_path / "cache"
    master = master_of([f"dataset.root={data_dir}", "dataset.last=2", f"cache.dir={cache}",
                        "detector=fast,orb", "matcher=bf,flann"])  # fmt: skip
    assert swept_keys(master) == {"detector", "matcher"}
    warm_up(master)
    # 3 frames' objects and lane points, the recording's reference; no feature stage
    assert entries(cache) == {"objects": 3, "lidar": 3, "reference": 1}


@pytest.mark.parametrize("swept", ["dataset.last=2,3", "objects.confidence_threshold=0.2,0.3",
                                   "lidar.shrink=0.1,0.2"])  # fmt: skip
def test_nothing_is_warmed_up_when_the_shared_stages_vary(
    master_of, data_dir, tmp_path, swept
) -> None:
    cache = tmp_path / "cache"
    master = master_of([f"dataset.root={data_dir}", f"cache.dir={cache}", swept])
    warm_up(master)
    assert not cache.exists() or entries(cache) == {}
