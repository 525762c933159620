"""Another implementation's TTC numbers as judged rows: the long table a reader of
:mod:`experiments.judge` makes from a user's file, checked against the recording and turned
into the rows :func:`~ttc.evaluation.run_metrics` and
:func:`~ttc.evaluation.bootstrap_rank_intervals` judge, so that an external setting gets the
harness's own metrics, ranking rule and rank intervals (no second metric).

The long table (one row per setting and frame pair): ``setting`` (str), ``frame`` (int, the
pair's current frame), ``prev_frame`` (int; NaN: ``frame - 1``), ``ttc_camera`` and
``ttc_lidar`` (s; either may be absent), ``line`` (the row's line in its file, for messages).

Conventions:

- a TTC belongs to the pair's **current** frame: the first pair of frames 0–18 is frame 1;
  a file whose frames number the pair's previous frame is shifted by
  :func:`with_frame_convention` (``previous``) only when the user says so;
- NaN, ±inf (and a blank cell, read as NaN) are an **invalid estimate**, counted in the
  invalid rate like a harness setting's frame without one; at the recording's first frame
  (where no pair ends) such a value is dropped, a finite one is an error;
- seconds; the distance ratio an estimate rests on is ``r = 1 + dt / ttc`` (the
  constant-velocity model both the lidar and the camera TTC of the Udacity project use,
  ``ttc = dt / (r − 1)``), ``dt`` the seconds between the pair's frames in the reference's
  clock (``time_s``); a negative TTC is a receding lead (r < 1), judged as such.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

#: The columns of a long table that hold estimates (seconds).
TTC_COLUMNS: tuple[str, ...] = ("ttc_camera", "ttc_lidar")
#: How the frame numbers of a file are read: the pair's current frame (the harness's), or its
#: previous frame (shifted by one on reading).
FRAME_CONVENTIONS: tuple[str, ...] = ("current", "previous")
#: A run id's prefix that marks an external setting in a ranking.
EXTERNAL_PREFIX = "ext:"


class ExternalTableError(ValueError):
    """A long table that cannot be judged: ``line`` (1-based line of the file, 0: the
    whole file), ``column`` (its name, '' for none) and what is wrong."""

    def __init__(self, line: int, column: str, message: str) -> None:
        super().__init__(message)
        self.line, self.column, self.message = line, column, message


def external_run_id(name: str, setting: str) -> str:
    """The run id (and label) of an external setting: ``ext:<name>/<setting>``."""
    return f"{EXTERNAL_PREFIX}{name}/{setting}"


def is_external(run_ids: pd.Series) -> pd.Series:
    """(n,) bool: each run id is an external setting's (:func:`external_run_id`)."""
    return run_ids.astype(str).str.startswith(EXTERNAL_PREFIX)


def with_frame_convention(long: pd.DataFrame, convention: str) -> pd.DataFrame:
    """``long`` with its frames numbered by the pair's current frame: ``previous`` adds one
    to ``frame`` and to ``prev_frame`` (``current``: unchanged)."""
    if convention not in FRAME_CONVENTIONS:
        raise ValueError(f"frame convention {convention!r}: one of {', '.join(FRAME_CONVENTIONS)}")
    if convention == "current":
        return long
    out = long.copy()
    out["frame"] = out["frame"] + 1
    if "prev_frame" in out:
        out["prev_frame"] = out["prev_frame"] + 1
    return out


def _first_bad(mask: pd.Series, long: pd.DataFrame) -> pd.Series | None:
    """The first row of ``long`` (by line) where ``mask``, else None."""
    if not mask.any():
        return None
    return long[mask].sort_values("line").iloc[0]


def checked_long_table(
    long: pd.DataFrame, first: int, last: int
) -> tuple[pd.DataFrame, dict[str, int]]:
    """``long`` checked against the recording's frames ``first..last`` (pairs end at
    ``first + 1 .. last``): returns (the rows to judge, counts of the rows dropped:
    ``first_frame``, invalid estimates at ``first``; ``repeated``, exact repeats of an
    earlier row, as a write-up that shows a table twice has). Raises
    :class:`ExternalTableError` at the first row (by line) with a frame outside the
    recording, a finite TTC at ``first`` (the other frame convention), a previous frame not
    before its frame, or a setting and frame given twice with different numbers."""
    present = [c for c in TTC_COLUMNS if c in long]
    if not present:
        raise ExternalTableError(1, "", f"no TTC column: one of {', '.join(TTC_COLUMNS)}")
    long = long.sort_values("line", kind="stable")
    same = [c for c in ("setting", "frame", "prev_frame", *present) if c in long]
    repeated = long[same].astype(str).duplicated(keep="first")
    long = long[~repeated.to_numpy()]
    at_first = long["frame"] == first
    finite = np.isfinite(long[present].to_numpy(dtype=float)).any(axis=1)
    row = _first_bad(at_first & finite, long)
    if row is not None:
        raise ExternalTableError(
            int(row["line"]), "frame",
            f"frame {first} has a TTC but no frame pair ends at the recording's first frame "
            f"{first}: if the file numbers each pair by its previous frame, pass "
            "--frame-convention=previous",
        )  # fmt: skip
    dropped = {"first_frame": int(at_first.sum()), "repeated": int(repeated.sum())}
    long = long[~at_first]
    row = _first_bad((long["frame"] < first) | (long["frame"] > last), long)
    if row is not None:
        raise ExternalTableError(
            int(row["line"]), "frame",
            f"frame {int(row['frame'])} is outside the recording (frame pairs end at "
            f"{first + 1}..{last})",
        )  # fmt: skip
    if "prev_frame" in long:
        prev = long["prev_frame"]
        bad = prev.notna() & ((prev >= long["frame"]) | (prev < first))
        row = _first_bad(bad, long)
        if row is not None:
            raise ExternalTableError(
                int(row["line"]), "prev_frame",
                f"prev_frame {row['prev_frame']:.0f} is not a frame of the recording before "
                f"frame {int(row['frame'])}",
            )  # fmt: skip
    row = _first_bad(long.duplicated(["setting", "frame"], keep="first"), long)
    if row is not None:
        earlier = long[(long["setting"] == row["setting"]) & (long["frame"] == row["frame"])]
        raise ExternalTableError(
            int(row["line"]), "frame",
            f"setting {row['setting']!r} has frame {int(row['frame'])} twice (first on line "
            f"{int(earlier['line'].min())}); one row per setting and frame pair (the lead vehicle)",
        )  # fmt: skip
    return long.reset_index(drop=True), dropped


def distance_ratio(
    ttc: np.ndarray, dt: np.ndarray, minus_inf_is_ratio_one: bool = False
) -> np.ndarray:
    """The distance ratio ``d_prev / d_curr`` (n,) behind a constant-velocity TTC (s, (n,))
    over ``dt`` seconds (n,): ``1 + dt / ttc``; NaN where the TTC is not finite (an invalid
    estimate), except ``-inf`` with ``minus_inf_is_ratio_one``: 1, what the Udacity starter's
    ``TTC = -dT / (1 - r)`` prints for a median ratio of exactly 1 (no scale change)."""
    ttc, dt = np.asarray(ttc, dtype=float), np.asarray(dt, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(np.isfinite(ttc), 1.0 + dt / ttc, np.nan)
    if minus_inf_is_ratio_one:
        ratio[np.isneginf(ttc)] = 1.0
    return ratio


def judged_external_rows(
    long: pd.DataFrame, reference: pd.DataFrame, name: str, minus_inf_is_ratio_one: bool = False
) -> pd.DataFrame:
    """The rows of a checked long table (:func:`checked_long_table`) in the form a sweep's
    lead rows have, for :func:`~ttc.evaluation.run_metrics`: ``run_id``
    (:func:`external_run_id`), ``setting``, ``frame``, ``prev_frame``, ``dt`` (s, from the
    reference's ``time_s``), ``is_lead`` (True), ``ttc_camera`` with ``camera_ratio``
    (:func:`distance_ratio`, ``minus_inf_is_ratio_one`` passed on), ``ttc_lidar`` with ``d_prev`` = that ratio and ``d_curr`` = 1
    (distances in units of the current one: the lidar metrics read their ratio), and
    ``ms_compute_per_frame`` +inf: an unknown time, which loses every tie of the ranking
    rule's time key (:data:`~ttc.evaluation.ranking.RANKING_RULE`)."""
    times = reference.set_index("frame")["time_s"].astype(float)
    prev = long["prev_frame"] if "prev_frame" in long else pd.Series(np.nan, index=long.index)
    prev = prev.fillna(long["frame"] - 1).astype(int)
    dt = times.reindex(long["frame"]).to_numpy() - times.reindex(prev).to_numpy()
    out = pd.DataFrame(
        {
            "run_id": [external_run_id(name, s) for s in long["setting"]],
            "setting": long["setting"].astype(str).to_numpy(),
            "frame": long["frame"].astype(int).to_numpy(),
            "prev_frame": prev.to_numpy(),
            "dt": dt,
            "is_lead": True,
        }
    )
    if "ttc_camera" in long:
        out["ttc_camera"] = long["ttc_camera"].to_numpy(dtype=float)
        out["camera_ratio"] = distance_ratio(out["ttc_camera"], dt, minus_inf_is_ratio_one)
    if "ttc_lidar" in long:
        out["ttc_lidar"] = long["ttc_lidar"].to_numpy(dtype=float)
        out["d_prev"] = distance_ratio(out["ttc_lidar"], dt, minus_inf_is_ratio_one)
        out["d_curr"] = 1.0
    out["ms_per_frame"] = np.inf
    out["ms_compute_per_frame"] = np.inf
    return out


def missing_pairs(rows: pd.DataFrame, frames: np.ndarray) -> pd.DataFrame:
    """``rows`` (:func:`judged_external_rows`) with a row (NaN estimates: invalid) for every
    pair of ``frames`` (the frames the harness's settings are judged on) a setting left out,
    so that every setting is judged on the same frames; rows of other frames dropped."""
    parts = []
    for run_id, own in rows.groupby("run_id", sort=True):
        full = pd.DataFrame({"frame": np.asarray(frames, dtype=int)})
        merged = full.merge(own, on="frame", how="left")
        merged["run_id"], merged["setting"] = run_id, own["setting"].iloc[0]
        merged["is_lead"] = True
        merged["prev_frame"] = merged["prev_frame"].fillna(merged["frame"] - 1).astype(int)
        for col in ("ms_per_frame", "ms_compute_per_frame"):
            merged[col] = np.inf
        parts.append(merged)
    return pd.concat(parts, ignore_index=True) if parts else rows.iloc[:0]
