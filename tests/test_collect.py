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


def test_lead_rows_read_by_row_group_are_the_whole_files(tmp_path) -> None:
    """The summary's rows (read a row group at a time, without the columns no metric reads)
    are :func:`ttc.evaluation.lead_rows` of the whole file: a pair without a lead row keeps
    its first row, blanked, also when the pair's rows straddle two row groups."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    from experiments import store
    from experiments.collect import lead_rows
    from ttc import evaluation as ev

    rows = pd.DataFrame(
        {
            "run_id": ["a", "a", "a", "a", "b", "b", "b", "b"],
            "frame": [1, 1, 2, 2, 1, 2, 2, 2],
            "is_lead": [False, True, False, False, True, False, False, True],
            "ttc_camera": [9.0, 1.0, 8.0, 7.0, 2.0, 6.0, 5.0, 3.0],
            "git_commit": ["c0ffee"] * 8,  # read by no metric: left unread
        }
    )
    pq.write_table(pa.Table.from_pandas(rows), tmp_path / store.FRAMES_FILE, row_group_size=3)
    assert pq.ParquetFile(tmp_path / store.FRAMES_FILE).num_row_groups == 3
    got = lead_rows(tmp_path).sort_values(["run_id", "frame"], ignore_index=True)
    whole = ev.lead_rows(rows.drop(columns="git_commit"))
    pd.testing.assert_frame_equal(got, whole.sort_values(["run_id", "frame"], ignore_index=True))
    np.testing.assert_array_equal(got["ttc_camera"], [1.0, np.nan, 2.0, 3.0])  # a/2: no lead
