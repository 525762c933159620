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
# intervals, and the frames where the camera TTC is way off with the reasons the FP.6 rules of
# `ttc.evaluation` derive (from the rows, and for the worst frame from its matches).

# %%
import os

import matplotlib.pyplot as plt
import pandas as pd
import seaborn as sns
from IPython.display import Markdown, display

from experiments.report.load import open_sweep
from ttc import draw
from ttc import evaluation as ev

# %% tags=["parameters"]
SWEEP_DIR = os.environ.get("TTC_SWEEP_DIR", "sweeps/fp6_grid_kitti_0_18")

# %%
data, ctx, reference = open_sweep(SWEEP_DIR)
data.runs["status"].value_counts()

# %% [markdown]
# ## Ranking

# %%
display(Markdown(ev.RANKING_RULE))
t = ev.camera_reasons(ev.camera_frame_table(data.frames, data.runs, reference))
ranking = ev.camera_ranking(data.frames, t, reference, n_boot=500)
columns = ["rank", "rank_lo", "rank_hi", "setting", "camera_outlier_rate", "camera_medae_rel",
           "camera_jitter_s", "way_off_frames", "ms_per_frame"]  # fmt: skip
ranking[columns].head(15)

# %%
best = ranking.sort_values("rank").drop_duplicates(["detector", "descriptor"])
grid = best.pivot(index="detector", columns="descriptor", values="camera_outlier_rate")
sns.heatmap(grid, annot=True, fmt=".2f", cmap="rocket_r", vmin=0)
plt.title("outlier rate of the best setting per detector x descriptor")
plt.show()

# %%
time_ms = ranking["ms_compute_per_frame"].fillna(ranking["ms_per_frame"])
front = ranking.iloc[ev.pareto_front(time_ms.to_numpy(float),
                                     ranking["camera_outlier_rate"].to_numpy(float))]  # fmt: skip
ax = sns.scatterplot(x=time_ms, y=ranking["camera_outlier_rate"], hue=ranking["detector"])
ax.step(time_ms[front.index], front["camera_outlier_rate"], where="post", color="black")
ax.set(xscale="log", xlabel="time per frame (ms)", title="accuracy against time, Pareto front")
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
worst = ev.worst_order(t).head(20)
with pd.option_context("display.max_colwidth", 300):
    display(worst[["setting", "frame", "ttc_camera", "ttc_ref_s", "reasons", "reason_text"]])

# %% [markdown]
# ## The worst frame's matches, measured and drawn

# %%
if len(worst):
    row = worst.iloc[0]
    detail = ctx.detail(data.runs, row["run_id"], int(row["prev_frame"]), int(row["frame"]))
    min_dist = ctx.settings(data.runs, row["run_id"]).camera_ttc.min_dist
    rear = float(reference.set_index("frame").loc[row["frame"], "distance_smooth_m"])
    geometry = ev.match_geometry(detail, min_dist, rear)
    display(geometry, {k: v for k, v in ev.geometry_texts(geometry).items() if v})
    image = draw.draw_keypoint_matches(detail, max_draw=150)
    plt.figure(figsize=(12, 6))
    plt.imshow(image[:, :, ::-1])
    plt.axis("off")
    plt.show()
