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
# implausible frames flagged and the reason the rules of `experiments/report.py` derive from
# the data (the same functions `python -m experiments.report` uses).

# %%
import os
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd
import seaborn as sns
from IPython.display import Markdown, display

from experiments import report
from ttc.evaluation.reference import REFERENCE_CAVEATS

# %% tags=["parameters"]
SWEEP_DIR = os.environ.get("TTC_SWEEP_DIR", "sweeps/fp5_lidar_kitti_0_18")

# %%
data, ctx, reference = report.open_sweep(SWEEP_DIR)
display(Markdown(report.provenance_markdown(data, f"Sweep `{Path(SWEEP_DIR).name}`")))

# %% [markdown]
# ## Reference

# %%
display(Markdown(f"**Caveats.** {REFERENCE_CAVEATS}"))
report.plot_reference(reference)
plt.show()

# %% [markdown]
# ## TTC per frame and estimator (`!`: flagged)

# %%
t = report.fp5_table(data, reference, ctx)
report.lidar_metrics(data.frames, t, reference)

# %%
report.plot_lidar_series(t, reference)
plt.show()

# %%
report.lidar_wide(t)

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

# %%
frames = report.lidar_picture_frames(t, limit=1)
if len(frames):
    first = frames.iloc[0]
    image = report.lidar_picture(
        t, data.runs, ctx, first["dataset"], int(first["frame"]), reference
    )
    plt.figure(figsize=(10, 7))
    plt.imshow(image[:, :, ::-1])
    plt.axis("off")
    plt.show()
