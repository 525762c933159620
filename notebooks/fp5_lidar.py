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
# # FP.5: implausible lidar TTC estimates
#
# Lidar TTC per frame for every lidar estimator in the sweep, beside the reference, with the
# implausible frames flagged and the reasons the FP.5 rules of `ttc.evaluation` derive from
# the rows (`python -m experiments.report` also measures other objects' points in the box on
# the recomputed frame pairs; see its `fp5_lidar.md`).

# %%
import os

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import seaborn as sns
from IPython.display import Markdown, display

from experiments.report.load import open_sweep
from ttc import draw
from ttc import evaluation as ev

# %% tags=["parameters"]
SWEEP_DIR = os.environ.get("TTC_SWEEP_DIR", "sweeps/fp5_lidar_kitti_0_18")

# %%
data, ctx, reference = open_sweep(SWEEP_DIR)
data.runs["status"].value_counts()

# %% [markdown]
# ## Reference

# %%
display(Markdown(f"**Caveats.** {ev.REFERENCE_CAVEATS}"))
fig, ax = plt.subplots(figsize=(9, 3))
ax.plot(reference["frame"], reference["distance_m"], "o", ms=3, label="lidar rear")
ax.plot(reference["frame"], reference["distance_smooth_m"], "-", label="smoothed")
ax.set(xlabel="frame", ylabel="distance (m)")
ax.legend()
plt.show()

# %% [markdown]
# ## TTC per frame and estimator (`!`: flagged)

# %%
t = ev.lidar_reasons(ev.lidar_frame_table(data.frames, data.runs, reference))
ev.lidar_metrics(data.frames, t, reference)

# %%
valid = t[np.isfinite(t["ttc_lidar"])]
fig, ax = plt.subplots(figsize=(10, 4))
sns.lineplot(data=valid, x="frame", y="ttc_lidar", hue="lidar_ttc", marker="o", ax=ax)
ref = reference[reference["frame"].isin(t["frame"])]
ax.plot(ref["frame"], ref["ttc_ref_s"], color="black", lw=2.5, label="reference")
ax.set(ylim=(0, 2.5 * ref["ttc_ref_s"].replace(np.inf, np.nan).max()), ylabel="TTC (s)")
ax.legend(fontsize=7)
plt.show()

# %%
ev.lidar_wide(t)

# %% [markdown]
# ## Flagged frames and their reasons

# %%
flagged = t[t["flagged"]]
with pd.option_context("display.max_colwidth", 300):
    display(flagged[["frame", "lidar_ttc", "ttc_lidar", "ttc_ref_s", "reasons", "reason_text"]])

# %%
counts = flagged.assign(reason=flagged["reasons"].str.split(";")).explode("reason")
if len(counts):
    sns.countplot(data=counts, y="reason", hue="lidar_ttc")
    plt.show()

# %% [markdown]
# ## Top view of the most flagged frame
#
# The lead box's points in the previous and current frame, with the distance every estimator
# picks on them (`ev.estimator_marks`) and the reference rear.

# %%
frames = ev.most_flagged_frames(t, limit=1)
if len(frames):
    row = t[t["frame"] == frames["frame"].iloc[0]].iloc[0]
    detail = ctx.detail(data.runs, row["run_id"], int(row["prev_frame"]), int(row["frame"]))
    rear = reference.set_index("frame")["distance_m"]
    views = []
    for f, points in ev.lead_clouds(detail).items():
        marks = ev.estimator_marks(points) if len(points) else {}
        marks["reference rear"] = float(rear.get(f, np.nan))
        x0 = float(np.floor(np.nanmin([points[:, 0].min(initial=np.inf), rear[f]]) * 4) / 4)
        world = ((x0 - 0.25, x0 + 1.25), (-2.0, 2.0))
        views.append(draw.top_view([(f"frame {f} box", points)], marks, world, (400, 520),
                                   grid=0.5, lateral_grid=1.0))  # fmt: skip
    plt.figure(figsize=(10, 7))
    plt.imshow(np.hstack(views)[:, :, ::-1])
    plt.axis("off")
    plt.show()
