"""The harness's side of a judge run: its settings' lead rows and the recording's reference,
from a sweep (``--with SWEEP``) or from the committed report of the recording
(``results/<dataset>/``: ``fp6_camera_ttc.csv``, ``fp6_ranking.csv``, ``fp5_lidar_ttc.csv``,
``reference.csv``), and the frame range a dataset covers (``conf/dataset/<name>.yaml``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from experiments.host.paths import CONF_DIR, SOURCE_ROOT
from ttc import evaluation as ev
from ttc.evaluation.external import distance_ratio

#: The committed reports, one folder per dataset name.
RESULTS_DIR = SOURCE_ROOT / "results"


@dataclass
class HarnessSide:
    """Lead rows per sensor (``camera``, ``lidar``: run_id, frame, estimates, times), per
    sensor a label per run id, the reference, the frames judged and where they came from."""

    rows: dict[str, pd.DataFrame]
    labels: dict[str, dict[str, str]]
    reference: pd.DataFrame
    first: int
    last: int
    source: str
    extra: dict[str, str] = field(default_factory=dict)


def dataset_range(name: str) -> tuple[int, int]:
    """The first and last frame of ``dataset=<name>`` (its config in ``conf/dataset``); a
    ValueError naming the configs when there is none."""
    path = CONF_DIR / "dataset" / f"{name}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in (CONF_DIR / "dataset").glob("*.yaml"))
        raise ValueError(f"dataset={name}: no such dataset (one of {', '.join(known)})")
    doc = yaml.safe_load(path.read_text()) or {}
    first, last = int(doc.get("first", 0) or 0), doc.get("last")
    return first, int(last) if last is not None else -1


def _with_dt(rows: pd.DataFrame, reference: pd.DataFrame) -> pd.Series:
    """Seconds between each row's ``prev_frame`` and ``frame`` in the reference's clock."""
    times = reference.set_index("frame")["time_s"].astype(float)
    return pd.Series(
        times.reindex(rows["frame"]).to_numpy() - times.reindex(rows["prev_frame"]).to_numpy(),
        index=rows.index,
    )


def committed_side(dataset: str, results_dir: Path = RESULTS_DIR) -> HarnessSide:
    """The committed report of ``dataset`` as lead rows: every FP.6 camera setting (its ratio
    from its TTC, ``1 + dt / ttc``, where the TTC is finite: the CSV's six digits of the TTC
    keep the ratio to 1e-8, those of the ratio only to 5e-6; else its ``camera_ratio``, e.g.
    exactly 1 with an infinite TTC) with its ``ms_compute_per_frame``, and every FP.5 lidar
    estimator (``d_prev``, ``d_curr``). A FileNotFoundError names the missing file."""
    folder = Path(results_dir) / dataset
    for name in ("fp6_camera_ttc.csv", "fp6_ranking.csv", "reference.csv"):
        if not (folder / name).is_file():
            raise FileNotFoundError(f"{folder / name}: no committed results of dataset={dataset}"
                                    " (use --with SWEEP)")  # fmt: skip
    reference = pd.read_csv(folder / "reference.csv")
    ttc_ref = reference["ttc_ref_s"].to_numpy(dtype=float)  # its ratio, to 1e-8 (see above)
    ratio_ref = distance_ratio(ttc_ref, reference["dt_s"].to_numpy(dtype=float))
    reference["ratio_ref"] = np.where(np.isfinite(ratio_ref), ratio_ref, reference["ratio_ref"])
    cam = pd.read_csv(folder / "fp6_camera_ttc.csv")
    times = pd.read_csv(folder / "fp6_ranking.csv").set_index("setting")
    cam = cam.assign(run_id=cam["setting"], is_lead=True, dt=_with_dt(cam, reference))
    ratio = distance_ratio(cam["ttc_camera"], cam["dt"])
    cam["camera_ratio"] = np.where(np.isfinite(ratio), ratio, cam["camera_ratio"])
    for col in ("ms_per_frame", "ms_compute_per_frame"):
        cam[col] = cam["setting"].map(times[col])
    keep = ["run_id", "frame", "prev_frame", "dt", "is_lead", "ttc_camera", "camera_ratio",
            "ms_per_frame", "ms_compute_per_frame"]  # fmt: skip
    rows = {"camera": cam[keep]}
    labels = {"camera": dict(zip(cam["run_id"], cam["setting"], strict=False))}
    lidar_path = folder / "fp5_lidar_ttc.csv"
    if lidar_path.is_file():
        lid = pd.read_csv(lidar_path)
        lid = lid.assign(run_id="lidar_ttc=" + lid["lidar_ttc"], is_lead=True,
                         dt=_with_dt(lid, reference), ms_per_frame=0.0)  # fmt: skip
        rows["lidar"] = lid[["run_id", "frame", "prev_frame", "dt", "is_lead", "ttc_lidar",
                             "d_prev", "d_curr", "ms_per_frame"]]  # fmt: skip
        labels["lidar"] = dict(zip(rows["lidar"]["run_id"], rows["lidar"]["run_id"], strict=False))
    frames = cam["frame"]
    return HarnessSide(rows, labels, reference, int(frames.min()) - 1, int(frames.max()),
                       f"committed results {folder}")  # fmt: skip


def sweep_side(
    sweep: Path, data_dir: Path | None = None, cache_dir: Path | None = None
) -> HarnessSide:
    """A sweep's camera settings (one run each, :func:`ttc.evaluation.camera_runs`) and lidar
    estimators (one run each) as lead rows, with the reference of its recording (through the
    stage cache, as ``ttc-bench report`` computes it)."""
    from experiments.report.load import load_sweeps, make_context, reference_for  # noqa: PLC0415

    data = load_sweeps([sweep])
    if data.frames.empty:
        raise ValueError(f"{sweep}: no rows (not a sweep folder, or no run finished)")
    reference = reference_for(data, make_context(data_dir, cache_dir))
    chosen = ev.camera_runs(data.runs)
    rows = ev.rows_of_runs(data.frames, chosen["run_id"])
    labels = {"camera": dict(zip(chosen["run_id"], chosen["setting"], strict=False))}
    ok = data.runs[data.runs["status"] == "ok"].sort_values("run_id")
    lidar = ok.drop_duplicates("lidar_ttc")  # one run per lidar estimator
    labels["lidar"] = {
        r: f"lidar_ttc={e}" for r, e in zip(lidar["run_id"], lidar["lidar_ttc"], strict=False)
    }
    frames = rows["frame"]
    return HarnessSide({"camera": rows, "lidar": ev.rows_of_runs(data.frames, lidar["run_id"])},
                       labels, reference, int(frames.min()) - 1, int(frames.max()),
                       f"sweep {sweep}")  # fmt: skip
