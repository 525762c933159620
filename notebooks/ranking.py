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
# Every ok run of the sweep judged against the reference TTC, ranked by
# `ttc.evaluation.RANKING_RULE`, with 90 % bootstrap rank intervals. The same functions of
# `ttc.evaluation` build the tables of `python -m experiments.report`.

# %%
import os

import matplotlib.pyplot as plt
import numpy as np
import seaborn as sns
from IPython.display import Markdown, display

from experiments.report.load import open_sweep
from ttc import evaluation as ev
from ttc.settings import AXES

# %% tags=["parameters"]
SWEEP_DIR = os.environ.get("TTC_SWEEP_DIR", "sweeps/fp6_grid_kitti_0_18")
SENSOR = os.environ.get("TTC_SENSOR", "camera")  # camera or lidar

# %%
data, ctx, reference = open_sweep(SWEEP_DIR)

# %% [markdown]
# ## The rule

# %%
display(Markdown(ev.RANKING_RULE))

# %% [markdown]
# ## Per-run metrics (what `metrics.parquet` beside the sweep holds)

# %%
per_run = ev.sweep_metrics(data.frames, data.runs, reference)
per_run["status"].value_counts()

# %%
ok = per_run[per_run["status"] == "ok"]
ranked = ev.rank_runs(ok, SENSOR)
intervals = ev.bootstrap_rank_intervals(data.frames, reference, n_boot=500, seed=0, sensor=SENSOR)
table = ranked.merge(intervals.drop(columns="rank"), on="run_id")
table.insert(1, "setting", ev.setting_labels(table, AXES))
columns = ["rank", "rank_lo", "rank_hi", "setting", f"{SENSOR}_outlier_rate",
           f"{SENSOR}_medae_rel", f"{SENSOR}_jitter_s", f"{SENSOR}_invalid", "ms_per_frame"]  # fmt: skip
table[[c for c in columns if c in table]].head(20)

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
# ## Time per frame of each setting

# %%
ax = sns.barplot(data=top, y="setting", x="ms_per_frame", color="grey")
ax.set(xscale="log" if np.ptp(top["ms_per_frame"]) > 100 else "linear", ylabel="")
plt.show()
