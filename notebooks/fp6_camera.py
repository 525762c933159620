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
# # FP.6: camera TTC across detector / descriptor settings
#
# Camera TTC per frame for every camera setting of the sweep, the ranking with bootstrap rank
# intervals, and the frames where the camera TTC is way off with the reasons derived by
# `experiments/report.py` (the functions `python -m experiments.report` uses).

# %%
import os
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd
import seaborn as sns
from IPython.display import Markdown, display

from experiments import report
from ttc.evaluation import metrics

# %% tags=["parameters"]
SWEEP_DIR = os.environ.get("TTC_SWEEP_DIR", "sweeps/fp6_grid_kitti_0_18")

# %%
data, ctx, reference = report.open_sweep(SWEEP_DIR)
display(Markdown(report.provenance_markdown(data, f"Sweep `{Path(SWEEP_DIR).name}`")))

# %% [markdown]
# ## Ranking

# %%
display(Markdown(metrics.RANKING_RULE))
t, ranking = report.fp6_tables(data, reference, ctx)
ranking[
    [
        "rank",
        "rank_lo",
        "rank_hi",
        "setting",
        "camera_outlier_rate",
        "camera_medae_rel",
        "camera_jitter_s",
        "way_off_frames",
        "ms_per_frame",
    ]
].head(15)

# %%
report.plot_heatmap(ranking)
plt.show()

# %%
report.plot_top_bottom(t, ranking, reference)
plt.show()

# %%
report.plot_pareto(ranking)
plt.show()

# %% [markdown]
# ## Relative error per frame and setting

# %%
grid = t.pivot(index="setting", columns="frame", values="camera_rel_err")
order = ranking["setting"].tolist()
fig, ax = plt.subplots(figsize=(10, 0.25 * len(order) + 1.5))
sns.heatmap(
    grid.reindex(order).clip(upper=1.0),
    cmap="rocket_r",
    vmin=0,
    vmax=1,
    ax=ax,
    cbar_kws={"label": "|relative error| (clipped at 1; blank: invalid)"},
)
plt.show()

# %% [markdown]
# ## Way-off frames and their reasons

# %%
way = t[t["way_off"]]
counts = way["reasons"].str.split(";").explode().value_counts()
display(counts)

# %%
worst = report.worst_order(t).head(20)
with pd.option_context("display.max_colwidth", 300):
    display(worst[["setting", "frame", "ttc_camera", "ttc_ref_s", "reasons", "reason_text"]])

# %%
if len(worst):
    image = report.camera_picture(worst.iloc[0], data.runs, ctx)
    plt.figure(figsize=(9, 8))
    plt.imshow(image[:, :, ::-1])
    plt.axis("off")
    plt.show()
