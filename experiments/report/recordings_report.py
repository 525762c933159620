"""The cross-recording page of a sweep over several recordings: ``recordings.md``,
``recordings.csv`` and ``html/recordings.html``.

From the per-drive and pooled rankings (:func:`experiments.report.drives_report.drives_report`)
it writes, per sensor: each setting's rank and median motion-in-depth error per recording and
pooled, Kendall's τ between every pair of recordings' rankings, the best 5 settings of each
recording with their ranks on the others and the settings in the top 10 everywhere
(:mod:`ttc.evaluation.transfer`); and, for the recordings with frame pairs without a vehicle
ahead, the false alarms of every setting there (:func:`ttc.evaluation.no_lead_reports`), also
summed per detector.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from experiments.data.datasets import recording_id, recording_names
from experiments.report.encode import markdown_table, write_csv, write_text
from experiments.report.header import provenance_markdown
from experiments.report.html.page import markdown_html, page, write_assets
from experiments.report.load import SweepData
from experiments.summary.recordings import recording_of
from ttc import evaluation as ev
from ttc.settings import AXES, only_sensor_axes

SENSORS = ("camera", "lidar")
#: How many of each recording's best settings are followed onto the others.
BEST = 5
#: The top every recording must rank a setting in to be "in the top everywhere".
TOP = 10


def wide_ranks(table: pd.DataFrame, sensor: str) -> pd.DataFrame:
    """Setting × (drive, rank / median MiD) of one sensor of :func:`drives_report`'s table:
    one row per setting with its axes, ``rank_<drive>`` and ``mid_<drive>`` columns."""
    key = f"{sensor}_mid_median"
    part = table[table["sensor"] == sensor]
    drives = list(dict.fromkeys(part["drive"]))
    pooled = part[part["drive"] == ev.POOLED].set_index("setting")
    axes = [c for c in _label_axes(sensor) if c in part and part[c].nunique(dropna=False) > 1]
    first = part.drop_duplicates("setting").set_index("setting")[axes]
    out = first.copy()
    for drive in drives:
        mine = part[part["drive"] == drive].set_index("setting")
        judged = mine[key].notna().any()  # a recording with no judged pair ranks nothing
        out[f"rank_{drive}"] = mine["rank"] if judged else float("nan")
        out[f"mid_{drive}"] = mine[key]
    out = out.reset_index().assign(sensor=sensor)
    order = pooled["rank"].reindex(out["setting"]).to_numpy()
    return out.assign(_order=order).sort_values("_order", kind="stable").drop(columns="_order")


def ttc_ranges(data: SweepData, references: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """Per run and reference-TTC range (:func:`ttc.evaluation.binned_metrics`, TSTTC-style
    < 6 s, 6–12, 12–24, > 24 s) of every recording with judged pairs, with its ``drive``."""
    ok = data.runs[data.runs["status"] == "ok"]
    drive = recording_of(ok).map(recording_id)
    parts = []
    for name, reference in references.items():
        mine = data.frames[data.frames["run_id"].isin(drive.index[drive == name])]
        if mine.empty:
            continue
        binned = ev.binned_metrics(ev.judged_frames(mine, reference))
        if not binned.empty:
            parts.append(binned.assign(drive=name))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def _range_lines(binned: pd.DataFrame) -> list[str]:
    """The per-range section: per recording and range, the judged pairs and, per sensor, the
    best run's and the median run's median MiD and the median invalid rate."""
    if binned.empty:
        return []
    groups = binned.groupby(["drive", "ttc_bin"], observed=True)
    summary = pd.DataFrame({"pairs": groups["n_frames"].max()})
    for s in ("camera", "lidar"):
        summary[f"{s}_mid_best"] = groups[f"{s}_mid_median"].min()
        summary[f"{s}_mid_median_run"] = groups[f"{s}_mid_median"].median()
        summary[f"{s}_invalid_median_run"] = groups[f"{s}_invalid_rate"].median()
    return ["## by reference TTC range", "",
            "Judged frame pairs binned by their reference TTC (TSTTC-style ranges; "
            "`ttc.evaluation.ttc_bins`): per recording and range, the best run's and the median "
            "run's median MiD (10⁻⁴) and the median run's invalid rate. Per run: "
            "recordings_ttc_ranges.csv.", "",
            markdown_table(summary.reset_index().round(3)), ""]  # fmt: skip


def false_alarms(data: SweepData, references: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """Per run on a recording with frame pairs without a vehicle ahead: its drive, axes and
    :func:`ttc.evaluation.no_lead_reports` (empty when no recording has such pairs)."""
    ok = data.runs[data.runs["status"] == "ok"]
    drive = recording_of(ok).map(recording_id)
    lead = ev.lead_rows(data.frames[data.frames["run_id"].isin(ok["run_id"])])
    parts = []
    for name, reference in references.items():
        mine = lead[lead["run_id"].map(drive) == name]
        counts = ev.no_lead_reports(mine, reference)
        if not mine.empty and counts["n_no_lead"].sum() > 0:
            parts.append(counts.assign(drive=name))
    if not parts:
        return pd.DataFrame()
    counts = pd.concat(parts, ignore_index=True)
    axes = ok.set_index("run_id")[["detector", "descriptor", "matcher", "selector"]]
    return counts.join(axes, on="run_id")


def with_labels(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` with ``setting`` replaced by a readable label, per sensor: the values of the
    axes that vary among its settings joined by ``/`` (the id when none varies or labels
    collide); the dataset is the recording's, and the camera's label leaves out the axes that
    change only the lidar or the fused TTC (:func:`experiments.summary.recordings.setting_of`)."""
    return pd.concat([_labelled(part, sensor) for sensor, part in table.groupby("sensor")])


def _labelled(part: pd.DataFrame, sensor: str) -> pd.DataFrame:
    """:func:`with_labels` of one sensor's rows."""
    axes = [a for a in _label_axes(sensor) if a in part and part[a].nunique(dropna=False) > 1]
    if not axes:
        return part
    label = part[axes].astype(str).agg("/".join, axis=1)
    if label.groupby(part["setting"]).nunique().max() > 1 or (
        part.assign(label=label).groupby("label")["setting"].nunique().max() > 1
    ):
        return part
    return part.assign(setting=label)


def _label_axes(sensor: str) -> list[str]:
    """The axes that can tell ``sensor``'s settings apart."""
    other = set(only_sensor_axes("lidar")) | set(only_sensor_axes("fused"))
    return [a for a in AXES if a != "dataset" and not (sensor == "camera" and a in other)]


def recordings_report(
    data: SweepData, references: dict[str, pd.DataFrame], table: pd.DataFrame, out: Path
) -> str:
    """Write ``recordings.md``, ``recordings.csv`` and ``html/recordings.html`` from the
    drives report's ``table`` (settings named by :func:`with_labels`); return the
    one-sentence finding on the camera ranking."""
    table = with_labels(table)
    wide = pd.concat([wide_ranks(table, s) for s in SENSORS], ignore_index=True)
    write_csv(wide, out / "recordings.csv")
    binned = ttc_ranges(data, references)
    if not binned.empty:
        write_csv(binned, out / "recordings_ttc_ranges.csv")
    alarms = false_alarms(data, references)
    if not alarms.empty:
        write_csv(alarms, out / "recordings_false_alarms.csv")
    names = recording_names(references)
    shown = table.assign(drive=table["drive"].replace(names))  # the page names recordings
    finding = ev.transfer_sentence(shown[shown["sensor"] == "camera"], "camera_mid_median", TOP)
    lines = [
        provenance_markdown(data, "Across recordings: how far a ranking carries"),
        f"Recordings: {_named(names)}; each setting ranked on each by "
        "`ttc.evaluation.RANKING_RULE` against its own reference, and pooled (drives.md has the "
        "intervals). A recording where no frame pair can be judged ranks nothing.",
        "",
        f"**Camera:** {finding}",
        "",
    ]
    for sensor in SENSORS:
        part = shown[shown["sensor"] == sensor]
        key = f"{sensor}_mid_median"
        lines += [f"## {sensor}", "", ev.transfer_sentence(part, key, TOP), "",
                  "Kendall's τ between the recordings' rankings:", "",
                  markdown_table(ev.recording_agreement(part, key)), "",
                  f"The best {BEST} on one recording: their ranks on the others:", "",
                  markdown_table(ev.best_elsewhere(part, key, BEST)), "",
                  f"In the top {TOP} on every recording: "
                  f"{', '.join(ev.top_everywhere(part, key, TOP)) or 'none'}", ""]  # fmt: skip
    lines += _range_lines(_with_names(binned, names))
    lines += _false_alarm_lines(_with_names(alarms, names))
    lines += ["## every setting: rank and median MiD per recording", "",
              markdown_table(_wide_named(wide, names).drop(columns="sensor").head(40)),
              "", "(all settings and sensors: recordings.csv)"]  # fmt: skip
    text = "\n".join(lines) + "\n"
    write_text(text, out / "recordings.md")
    html = out / "html"
    write_assets(html, write_text)
    write_text(page("recordings", markdown_html(text), here="recordings.html"),
               html / "recordings.html")  # fmt: skip
    return finding


def _named(names: dict[str, str]) -> str:
    """The recordings in words, each name with its id (the CSVs' columns and folders)."""
    return ", ".join(f"{name} (`{rid}`)" for rid, name in names.items())


def _with_names(table: pd.DataFrame, names: dict[str, str]) -> pd.DataFrame:
    """``table`` with its ``drive`` column (recording ids) as the recordings' names."""
    return table.assign(drive=table["drive"].replace(names)) if "drive" in table else table


def _wide_named(wide: pd.DataFrame, names: dict[str, str]) -> pd.DataFrame:
    """:func:`wide_ranks` with ``rank_<id>`` / ``mid_<id>`` as ``rank <name>`` / ``mid <name>``."""
    renamed = {f"{kind}_{rid}": f"{kind} {name}" for rid, name in names.items()
               for kind in ("rank", "mid")}  # fmt: skip
    return wide.rename(columns=renamed)


def _false_alarm_lines(alarms: pd.DataFrame) -> list[str]:
    """The false-alarm section: totals per drive and detector, then the worst settings."""
    if alarms.empty:
        return ["## false alarms without a lead vehicle", "",
                "No recording of the sweep has frame pairs without a vehicle ahead.", ""]  # fmt: skip
    counts = [c for c in alarms if c.endswith(("_reported", "_warnings"))]
    per_detector = alarms.groupby(["drive", "detector"])[["n_no_lead", *counts]].sum()
    worst = alarms.sort_values(counts[0], ascending=False).head(10)
    return [
        "## false alarms without a lead vehicle",
        "",
        "On frame pairs where the reference finds no vehicle ahead, any lead TTC reported is a "
        f"false alarm (`_reported`), and a TTC below {ev.WARNING_TTC_S:g} s a false collision "
        "warning (`_warnings`).",
        "",
        markdown_table(per_detector.reset_index()),
        "",
        markdown_table(
            worst[
                [
                    "drive",
                    "run_id",
                    "detector",
                    "descriptor",
                    "matcher",
                    "selector",
                    "n_no_lead",
                    *counts,
                ]
            ]
        ),  # fmt: skip
        "",
    ]
