"""The end-of-sweep summary ranks on the sensor whose axes vary."""

from __future__ import annotations

import pandas as pd

from experiments.collect import ranked_sensor


def runs_varying(**axes: list[str]) -> pd.DataFrame:
    base = {"detector": "fast", "descriptor": "brief", "lidar_ttc": "median", "camera_ttc": "x"}
    n = max(len(v) for v in axes.values())
    return pd.DataFrame([{**base, **{k: v[i % len(v)] for k, v in axes.items()}} for i in range(n)])


def test_a_lidar_estimator_sweep_ranks_on_the_lidar() -> None:
    assert ranked_sensor(runs_varying(lidar_ttc=["median", "closest", "cluster"])) == "lidar"


def test_camera_axes_rank_on_the_camera() -> None:
    assert ranked_sensor(runs_varying(detector=["fast", "orb"])) == "camera"
    both = runs_varying(detector=["fast", "orb"], lidar_ttc=["median", "closest"])
    assert ranked_sensor(both) == "camera"
    assert ranked_sensor(runs_varying(detector=["fast"])) == "camera"  # one setting


def test_a_fusion_sweep_ranks_on_the_fused_ttc() -> None:
    runs = runs_varying(fusion=["none", "kalman_cv", "kalman_ca"], lidar_ttc=["median"])
    assert ranked_sensor(runs) == "fused"
    assert ranked_sensor(runs_varying(fusion=["none", "kalman_cv"], detector=["fast", "orb"])) == (
        "camera"
    )
