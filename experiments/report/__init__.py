"""The FP.5 (lidar) and FP.6 (camera) reports of one or more sweeps: markdown + CSV + pictures,
and an HTML report.

Usage::

    python -m experiments.report sweeps/fp6_grid_kitti_0_18 --out reports/kitti_0_18
    python -m experiments.report sweeps/fp5_lidar_kitti_0_18 sweeps/fp6_grid_kitti_0_18 \\
        --out reports/kitti_0_18

Writes ``metrics.parquet`` beside each sweep (one row per run) and, under ``--out``:

* ``reference.md/.csv/.png``: the reference TTC and its caveats (:mod:`.reference`);
* ``fp5_lidar.md``, ``fp5_lidar_ttc.csv`` (one row per frame × lidar estimator),
  ``fp5_lidar_ttc.png`` and ``fp5_pictures/`` (top views of flagged frames) (:mod:`.fp5`);
* ``fp6_camera.md``, ``fp6_camera_ttc.csv`` (one row per frame × camera setting),
  ``fp6_ranking.csv`` (metrics + bootstrap rank interval per setting), the heatmap, series and
  Pareto plots and ``fp6_pictures/`` (readable WebP pictures of the worst frames' lead-box
  matches) (:mod:`.fp6`);
* with a fused run (``fusion=kalman_*``): ``fp7_fusion.md``, ``fp7_fusion.csv`` (fused against
  its inputs per setting), ``fp7_fusion_ttc.csv/.png`` (flagged fused frames and reasons)
  (:mod:`.fp7`);
* ``html/``: the same as linked HTML pages that open from disk, the ranking sortable and
  filterable, a page per setting (:mod:`.html`).

The judging (reference, metrics, ranking, the FP.5 / FP.6 diagnosis rules) is
:mod:`ttc.evaluation`; the modules here load sweeps (:mod:`.load`), recompute the few frame
pairs the rules measure on, and write: :mod:`.header` (provenance), :mod:`.encode` (markdown,
CSV, PNG), :mod:`.plots`, :mod:`.pictures`, :mod:`.cli` (the command). The CSVs hold no
timestamps and fixed float formats: the same sweep data gives byte-identical CSVs.
"""
