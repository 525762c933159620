# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Ranking of the settings of a sweep
#
# Every ok run of the sweep judged against the reference TTC (`ttc.evaluation.reference`), ranked by
# `ttc.evaluation.metrics.RANKING_RULE`, with 90 % paired-bootstrap rank intervals. The same functions
# as `python -m experiments.report` (`experiments/report.py`) build the tables.

# %%
import os
from pathlib import Path

import matplotlib.pyplot as plt
import seaborn as sns
from IPython.display import Markdown, display

from experiments import report
from ttc.evaluation import metrics

# %% tags=["parameters"]
SWEEP_DIR = os.environ.get("TTC_SWEEP_DIR", "sweeps/fp6_grid_kitti_0_18")
SENSOR = os.environ.get("TTC_SENSOR", "camera")  # camera or lidar

# %%
data, ctx, reference = report.open_sweep(SWEEP_DIR)
display(Markdown(report.provenance_markdown(data, f"Sweep `{Path(SWEEP_DIR).name}`")))

# %% [markdown]
# ## The rule

# %%
display(Markdown(metrics.RANKING_RULE))

# %% [markdown]
# ## Per-run metrics (what `metrics.parquet` beside the sweep holds)

# %%
per_run = report.sweep_metrics(data.frames, data.runs, reference)
per_run["status"].value_counts()

# %%
ok = per_run[per_run["status"] == "ok"]
ranked = metrics.rank_runs(ok, SENSOR)
intervals = metrics.bootstrap_rank_intervals(
    data.frames, reference, n_boot=report.N_BOOT, seed=0, sensor=SENSOR
)
table = ranked.merge(intervals.drop(columns="rank"), on="run_id")
table.insert(1, "setting", report.setting_labels(table, metrics.AXES))
columns = [
    "rank",
    "rank_lo",
    "rank_hi",
    "setting",
    f"{SENSOR}_outlier_rate",
    f"{SENSOR}_medae_rel",
    f"{SENSOR}_jitter_s",
    f"{SENSOR}_invalid",
    "ms_per_frame",
]
table[columns].head(20)

# %% [markdown]
# ## Rank intervals of the 25 best

# %%
top = table.head(25)
fig, ax = plt.subplots(figsize=(8, 0.3 * len(top) + 1))
sns.pointplot(data=top, y="setting", x="rank", linestyle="none", color="black", ax=ax)
ax.hlines(range(len(top)), top["rank_lo"], top["rank_hi"], color="steelblue", lw=3)
ax.set(xlabel="rank (point and 90 % bootstrap interval)", ylabel="")
plt.show()

# %% [markdown]
# ## Accuracy against time (camera settings)

# %%
if SENSOR == "camera":
    t, ranking = report.fp6_tables(data, reference, None)
    report.plot_pareto(ranking)
    plt.show()
