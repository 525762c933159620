"""A reference to the ends of every track: one-sided line fits where the smoothing stops short.

The lead's Savitzky–Golay smoothing (:func:`ttc.evaluation.reference.segment_reference`) gives
an object's reference on the frames between its first and last usable distance, and a pair
reference (``D(k−1) / D(k)``) only where both frames lie there. A track therefore lost:

* the pair ending at its first frame (the frame before has no distance of the object),
* the frames before its first and after its last usable distance (a dropped jump, a box
  without points at a track's end),
* every standard deviation of a track too short for a residual (2–4 measured frames: the
  fit passes through every point, no degree of freedom is left to estimate the noise),
* everything of a track with a single measured frame.

:func:`track_reference` keeps every value the smoothing gave, bit for bit, and fills only
those gaps:

* a frame up to :data:`MAX_EXTRAPOLATION_FRAMES` outside the measured span (and the frame
  before the track's first one, for its first pair) gets the value at its time of the
  least-squares line through the :data:`END_FIT_FRAMES` measured frames nearest that end: a
  one-sided local linear fit whose standard error ``σ ‖w‖`` (``w`` the fit's weights on the
  measured distances) grows with the distance from the data;
* a track without a residual degree of freedom takes the recording's distance noise
  (:func:`recording_noise`: the :data:`NOISE_QUANTILE` quantile of the other tracks' own
  residual noise, a conservative pick from a heavy-tailed spread, e.g. drive 0009: 0.03–2.0 m);
  a two-frame track is then the difference quotient of its two distances with that noise;
* a single measured distance is kept as it is (no pair, no TTC).

A box cut by the image border never gets an extrapolated distance (its nearest face may be out
of view), nor one whose own distance was rejected as a jump (:mod:`ttc.evaluation.object_reference`:
beyond a track's last good measurement nothing says the box still holds the object). Each frame's ``fit`` says where its values come from (:data:`FITS`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ttc.evaluation.reference import (
    MAX_REF_REL_SD,
    MIN_CLOSING_SPEED_MPS,
    POLYORDER,
    WINDOW,
    _smoothing,
    find_stop,
    segment_reference,
    two_frame_ttc,
)

#: Measured frames nearest a track's end that its one-sided line is fitted to (0.5 s at 10 Hz:
#: long enough to average the range noise, short enough for a constant speed to hold).
END_FIT_FRAMES = 5
#: Most frames beyond a track's first or last usable distance that get an extrapolated one.
MAX_EXTRAPOLATION_FRAMES = 2
#: Quantile of the tracks' own residual noise taken for a track without one.
NOISE_QUANTILE = 0.75
#: Distance noise (m) when no track of the recording has its own estimate.
DEFAULT_NOISE_M = 0.05
#: Where a frame's reference comes from: ``savgol`` (the smoothing, its own noise), ``short``
#: (the smoothing of a track of 2–4 measured frames, the recording's noise), ``one_sided`` (the
#: frame or the frame before it extrapolated by an end's line), ``single`` (one measured
#: distance, no pair), ``""`` (no reference).
FITS: tuple[str, ...] = ("savgol", "short", "one_sided", "single", "")
#: The columns :func:`track_reference` returns besides ``frame``.
TRACK_COLUMNS: tuple[str, ...] = (
    "distance_smooth_m", "distance_sd_m", "closing_speed_mps", "ratio_ref", "ttc_ref_s",
    "ttc_ref_sd_s", "judgeable", "noise_sd_m", "fit",
)  # fmt: skip


def line_weights(t_fit: np.ndarray, t_at: np.ndarray) -> np.ndarray:
    """(A, F) weights of the least-squares line through values at times ``t_fit`` (F,, s)
    evaluated at times ``t_at`` (A,, s): ``value(t_at) = W @ values``; a constant (the mean)
    when ``t_fit`` holds one time."""
    t_fit, t_at = np.asarray(t_fit, dtype=float), np.atleast_1d(np.asarray(t_at, dtype=float))
    if len(t_fit) < 2:
        return np.full((len(t_at), len(t_fit)), 1.0 / max(len(t_fit), 1))
    origin = t_fit.mean()
    design = np.c_[np.ones(len(t_fit)), t_fit - origin]
    return np.c_[np.ones(len(t_at)), t_at - origin] @ np.linalg.pinv(design)


def recording_noise(noises: np.ndarray) -> float:
    """The distance noise (m) of a track without its own: the :data:`NOISE_QUANTILE`
    quantile of the tracks' own estimates ``noises`` (m, NaN ignored), else
    :data:`DEFAULT_NOISE_M`."""
    noises = np.asarray(noises, dtype=float)
    noises = noises[np.isfinite(noises)]
    return float(np.quantile(noises, NOISE_QUANTILE)) if len(noises) else DEFAULT_NOISE_M


def _operator(frames: np.ndarray, d: np.ndarray, times: np.ndarray, allowed: np.ndarray):
    """The linear map from a track's distances to its reference: ``(rows, filled, lo, hi)``.

    ``rows`` (m + 1, n): row 0 the frame before the track's first (extrapolated where any
    frame is ``allowed``), row ``i + 1`` frame ``frames[i]``; a NaN row where no value is
    given. Columns: the ``n`` frames of the measured span, positions ``lo..hi`` of the track
    (``filled``: their distances, NaN interpolated, as the smoothing takes them)."""
    m = len(frames)
    measured = np.flatnonzero(np.isfinite(d))
    lo, hi = int(measured[0]), int(measured[-1])
    n = hi - lo + 1
    filled = pd.Series(d[lo : hi + 1]).interpolate(limit_direction="both").to_numpy()
    stop = find_stop(d[lo : hi + 1], WINDOW, POLYORDER)
    rows = np.full((m + 1, n), np.nan)
    rows[lo + 1 : hi + 2] = _smoothing(n, stop, WINDOW, POLYORDER)
    pos = np.arange(-1, m)
    frame_of = np.r_[frames[0] - 1, frames]
    ok = np.r_[allowed.any(), allowed] & (frame_of >= 0) & (frame_of < len(times))
    for side, near in (("lo", measured[:END_FIT_FRAMES]), ("hi", measured[-END_FIT_FRAMES:])):
        gap = lo - pos if side == "lo" else pos - hi
        out = ok & (gap >= 1) & (gap <= MAX_EXTRAPOLATION_FRAMES)
        if out.any():
            w = line_weights(times[frames[near]], times[frame_of[out]])
            rows[out] = 0.0
            rows[np.ix_(out, near - lo)] = w
    return rows, filled, lo, hi


def track_reference(
    frames: np.ndarray,
    distances: np.ndarray,
    times: np.ndarray,
    allowed: np.ndarray | None = None,
    noise_m: float | None = None,
    ends: bool = True,
) -> pd.DataFrame:
    """The reference of one track to its ends.

    Parameters
    ----------
    frames
        (m,) consecutive frame indices of the track, ascending.
    distances
        (m,) usable distances of the object (m; NaN: not measured, a jump, a cut box).
    times
        Seconds of every frame of the recording (index = frame).
    allowed
        (m,) bool: frames that may get an extrapolated distance (default: all); a box cut by
        the image border or with a rejected distance is not.
    noise_m
        Distance noise (m) used where the track has no residual degree of freedom
        (:func:`recording_noise`); None: none (its standard deviations stay NaN, its
        ``noise_sd_m`` too).
    ends
        False: the smoothing's values only (no extrapolated frame, nothing for a single
        measured distance), as before this module.

    Returns
    -------
    pandas.DataFrame
        One row per frame: ``frame`` and :data:`TRACK_COLUMNS` (as
        :func:`~ttc.evaluation.reference.segment_reference`'s, plus ``fit``). Every value the
        smoothing of the measured span gives is kept exactly; only its gaps are filled.
    """
    frames = np.asarray(frames, dtype=np.int64)
    d = np.asarray(distances, dtype=float)
    times = np.asarray(times, dtype=float)
    allowed = np.ones(len(frames), bool) if allowed is None else np.asarray(allowed, bool)
    out = pd.DataFrame({"frame": frames})
    for c in TRACK_COLUMNS:
        out[c] = np.nan
    out["judgeable"], out["fit"] = False, ""
    measured = np.isfinite(d)
    if not measured.any():
        return out
    if measured.sum() == 1:
        if not ends:
            return out
        sd = np.nan if noise_m is None else noise_m
        out.loc[measured, ["distance_smooth_m", "distance_sd_m", "noise_sd_m"]] = [
            d[measured][0],
            sd,
            sd,
        ]
        out.loc[measured, "fit"] = "single"
        return out
    rows, filled, lo, hi = _operator(frames, d, times, allowed if ends else np.zeros_like(allowed))
    base = segment_reference(
        pd.DataFrame({"distance_m": d[lo : hi + 1]}, index=pd.Index(frames[lo : hi + 1], name="frame")),
        times[frames[lo] : frames[hi] + 1], WINDOW, POLYORDER, MIN_CLOSING_SPEED_MPS,
    )  # fmt: skip
    own = float(base["noise_sd_m"].iloc[0])
    sigma = own if np.isfinite(own) else (np.nan if noise_m is None else noise_m)
    value = rows @ filled  # NaN rows: NaN
    prev_row, curr_row = rows[:-1], rows[1:]
    dt = times[frames] - np.where(frames >= 1, times[np.maximum(frames - 1, 0)], np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        grad = prev_row / value[:-1, None] - curr_row / value[1:, None]
    pair = two_frame_ttc(value[:-1], value[1:], dt, sigma * np.linalg.norm(grad, axis=1))
    new = {
        "distance_smooth_m": value[1:], "distance_sd_m": sigma * np.linalg.norm(curr_row, axis=1),
        "closing_speed_mps": pair["speed"], "ratio_ref": pair["ratio"], "ttc_ref_s": pair["ttc"],
        "ttc_ref_sd_s": pair["ttc_sd"], "noise_sd_m": np.full(len(frames), sigma),
    }  # fmt: skip
    kept = base.set_index("frame").reindex(frames)
    for c, values in new.items():
        old = kept[c].to_numpy(dtype=float)
        out[c] = np.where(np.isnan(old), values, old)  # the smoothing's values, bit for bit
    ttc, sd = out["ttc_ref_s"].to_numpy(float), out["ttc_ref_sd_s"].to_numpy(float)
    out["judgeable"] = np.isfinite(ttc) & (sd <= MAX_REF_REL_SD * ttc)
    extrapolated = np.isfinite(rows[:, 0]) & ~np.isin(np.arange(-1, len(frames)), range(lo, hi + 1))
    one_sided = extrapolated[1:] | (
        extrapolated[:-1] & np.isfinite(out["ttc_ref_s"].to_numpy(float))
    )
    fit = np.where(one_sided, "one_sided", "savgol" if np.isfinite(own) else "short")
    out["fit"] = np.where(np.isnan(out["distance_smooth_m"]), "", fit)
    return out
