"""FP.7, fused TTC: a Kalman filter over the frames of a run, fed by lidar and camera.

State at frame k: the lead vehicle's distance ``d`` (m) and closing speed ``v`` (m/s, > 0 while
approaching) — ``kalman_cv``, constant velocity — plus the closing acceleration ``a`` (m/s²) for
``kalman_ca``, constant acceleration. Between frames ``dt`` seconds apart the state moves as
``d ← d − v·dt − a·dt²/2``, ``v ← v + a·dt`` with white process noise on the highest derivative
(acceleration for CV, jerk for CA; ``accel_sd`` / ``jerk_sd``).

Two measurements per frame pair, each used when the sensor gave one:

* lidar: the distance ``d_curr`` (m) the FP.2 estimator chose — linear, ``z = d``;
* camera: the log of the scale ratio ``camera_ratio`` = d(t_prev) / d(t_curr) — a measurement
  of the distance ratio between the frames, ``z = ln(d_prev(x)) − ln(d)`` with
  ``d_prev(x) = d + v·dt − a·dt²/2`` the state's own previous distance. It is nonlinear; the
  filter linearises it at the prediction (extended Kalman filter). The camera alone fixes
  ``v / d`` (the TTC), the lidar the scale.

Measurement noise comes from each estimator's variance over the run (``lidar_sd`` /
``camera_sd`` = 0, the default): the robust (MAD) spread of the lidar distances' second
differences and of the camera log-ratios' first differences — both near zero for a smooth
approach, so their spread is the estimator's noise — floored at ``lidar_sd_min`` /
``camera_sd_min``, the sensors' resolution (integer keypoints pin many ratios at exactly 1, which
would otherwise make the camera look noiseless). A positive ``lidar_sd`` / ``camera_sd`` sets it.
An innovation beyond ``gate_sd`` standard deviations is rejected as an outlier.

Output per frame: ``ttc_fused = d / v`` (the constant-velocity TTC of the fused state, as the
two sensors' TTCs and the reference define it; +inf when ``v <= 0``), its standard deviation
by the delta method, and ``fused_ratio = d_prev(x) / d`` (the fused distance ratio, so the
motion-in-depth error is defined like the other sensors').

Why a numpy implementation and not filterpy: the filter has 2–3 states and two scalar
measurements, one nonlinear; the extended-Kalman update is a dozen lines (Joseph form for a
symmetric covariance), and filterpy's ``ExtendedKalmanFilter`` would still need the Jacobian
written here, adding a dependency for the predict/update arithmetic only. The tests check it
against a synthetic approach of known noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ttc.robust import MAD_TO_SIGMA, median

FUSION_METHODS = ("none", "kalman_cv", "kalman_ca")

#: fused_reason codes and their meaning.
OFF = "off"
NOT_LEAD = "not_lead"
NO_LIDAR_YET = "no_lidar_yet"
FUSED = "ok"
LIDAR_ONLY = "lidar_only"
CAMERA_ONLY = "camera_only"
PREDICTED = "predicted"
RECEDING = "receding"
REASONS: dict[str, str] = {
    OFF: "fusion=none: no fused estimate (NaN)",
    NOT_LEAD: "only the lead vehicle's rows are fused (NaN)",
    NO_LIDAR_YET: "no lidar distance yet to start the filter (NaN)",
    FUSED: "finite TTC; lidar and camera both updated the filter this frame",
    LIDAR_ONLY: "finite TTC; only the lidar updated the filter (camera missing or gated)",
    CAMERA_ONLY: "finite TTC; only the camera updated the filter (lidar missing or gated)",
    PREDICTED: "finite TTC predicted from earlier frames; no measurement this frame",
    RECEDING: "fused closing speed <= 0: no collision course (+inf)",
}
FUSED_COLUMNS = ("ttc_fused", "ttc_fused_sd", "fused_ratio", "fused_reason")


@dataclass(frozen=True)
class FusionParams:
    """Kalman fusion of lidar and camera (``name``: ``none``, ``kalman_cv``, ``kalman_ca``).

    ``accel_sd`` (m/s², CV) and ``jerk_sd`` (m/s³, CA): process noise; ``lidar_sd`` (m) and
    ``camera_sd`` (natural-log ratio units): measurement noise, 0 = from the run's own data
    with floors ``lidar_sd_min`` / ``camera_sd_min``; ``gate_sd``: innovation gate in standard
    deviations (0: off); ``init_speed_sd`` (m/s), ``init_accel_sd`` (m/s²): prior spread of
    the state the first lidar distance starts (speed 0, acceleration 0).
    """

    name: str = "none"
    accel_sd: float = 0.5
    jerk_sd: float = 0.5
    lidar_sd: float = 0.0
    camera_sd: float = 0.0
    lidar_sd_min: float = 0.02
    camera_sd_min: float = 0.002
    gate_sd: float = 4.0
    init_speed_sd: float = 3.0
    init_accel_sd: float = 1.0

    def __post_init__(self) -> None:
        if self.name not in FUSION_METHODS:
            raise ValueError(f"fusion name must be one of {FUSION_METHODS}, got {self.name!r}")
        for field in ("accel_sd", "jerk_sd", "lidar_sd_min", "camera_sd_min", "init_speed_sd",
                      "init_accel_sd"):  # fmt: skip
            if not getattr(self, field) > 0:
                raise ValueError(f"{field} must be > 0, got {getattr(self, field)!r}")
        for field in ("lidar_sd", "camera_sd", "gate_sd"):
            if not getattr(self, field) >= 0:
                raise ValueError(f"{field} must be >= 0, got {getattr(self, field)!r}")

    @property
    def n_states(self) -> int:
        """2 (distance, closing speed) or 3 (and closing acceleration)."""
        return 3 if self.name == "kalman_ca" else 2


@dataclass(frozen=True)
class FusedTrack:
    """Per frame (n,): fused TTC (s), its standard deviation (s), the fused distance ratio
    d_prev / d_curr, the state (``state`` (n, S): d m, v m/s[, a m/s²]) and the reason code."""

    ttc: np.ndarray
    ttc_sd: np.ndarray
    ratio: np.ndarray
    state: np.ndarray
    reason: np.ndarray


def robust_sd(values: np.ndarray) -> float:
    """1.4826 × median absolute deviation of the finite ``values`` (NaN with fewer than 3)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) < 3:
        return np.nan
    return float(MAD_TO_SIGMA * median(np.abs(v - median(v))))


def noise_sds(
    lidar_d: np.ndarray, camera_log_ratio: np.ndarray, params: FusionParams
) -> tuple[float, float]:
    """(lidar sd m, camera sd in ln-ratio units) of a run: the configured values when > 0,
    else the robust spread of the lidar distances' second differences / √6 and of the camera
    log-ratios' first differences / √2 (white noise of sd σ gives those spreads), floored at
    the configured minima."""
    lidar = params.lidar_sd
    if lidar <= 0:
        est = robust_sd(np.diff(np.asarray(lidar_d, dtype=float), n=2)) / np.sqrt(6.0)
        lidar = max(params.lidar_sd_min, est) if np.isfinite(est) else params.lidar_sd_min
    camera = params.camera_sd
    if camera <= 0:
        est = robust_sd(np.diff(np.asarray(camera_log_ratio, dtype=float))) / np.sqrt(2.0)
        camera = max(params.camera_sd_min, est) if np.isfinite(est) else params.camera_sd_min
    return float(lidar), float(camera)


def _transition(dt: float, n: int, params: FusionParams) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) for a step of ``dt`` seconds: d ← d − v·dt − a·dt²/2, v ← v + a·dt."""
    if n == 2:
        f = np.array([[1.0, -dt], [0.0, 1.0]])
        g = np.array([-0.5 * dt**2, dt]) * params.accel_sd
    else:
        f = np.array([[1.0, -dt, -0.5 * dt**2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
        g = np.array([-(dt**3) / 6.0, 0.5 * dt**2, dt]) * params.jerk_sd
    return f, np.outer(g, g)


def _previous_distance(x: np.ndarray, dt: float) -> float:
    """The state's distance ``dt`` seconds earlier (m)."""
    a = x[2] if len(x) == 3 else 0.0
    return float(x[0] + x[1] * dt - 0.5 * a * dt**2)


def _camera_model(x: np.ndarray, dt: float) -> tuple[float, np.ndarray]:
    """(predicted ln(d_prev / d), its Jacobian (S,)) at state ``x``."""
    d_prev = _previous_distance(x, dt)
    jac = np.array([1.0 / d_prev - 1.0 / x[0], dt / d_prev, -0.5 * dt**2 / d_prev])
    return float(np.log(d_prev / x[0])), jac[: len(x)]


def _update(
    x: np.ndarray, p: np.ndarray, innovation: float, h: np.ndarray, var: float, gate: float
) -> tuple[np.ndarray, np.ndarray, bool]:
    """One scalar (extended) Kalman update, Joseph form; ``False`` when gated out."""
    s = float(h @ p @ h + var)
    if gate > 0 and innovation**2 > gate**2 * s:
        return x, p, False
    k = p @ h / s
    i_kh = np.eye(len(x)) - np.outer(k, h)
    return x + k * innovation, i_kh @ p @ i_kh.T + var * np.outer(k, k), True


def _ttc_and_sd(x: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """(d / v s, its delta-method sd s); (+inf, NaN) when v <= 0."""
    d, v = x[0], x[1]
    if v <= 0:
        return np.inf, np.nan
    grad = np.zeros(len(x))
    grad[0], grad[1] = 1.0 / v, -d / v**2
    return float(d / v), float(np.sqrt(max(grad @ p @ grad, 0.0)))


def _initial_state(d0: float, params: FusionParams, lidar_sd: float) -> tuple:
    n = params.n_states
    x = np.zeros(n)
    x[0] = d0
    sds = [lidar_sd, params.init_speed_sd, params.init_accel_sd][:n]
    return x, np.diag(np.square(sds))


def kalman_fuse(
    dt: np.ndarray,
    lidar_d: np.ndarray,
    camera_ratio: np.ndarray,
    params: FusionParams,
    lidar_d0: float = np.nan,
) -> FusedTrack:
    """Fuse a run's consecutive frame pairs (n,) into per-frame TTC estimates.

    ``dt`` (s) between the pair's frames, ``lidar_d`` (m) the lidar distance at each pair's
    current frame, ``camera_ratio`` the camera's d_prev / d_curr; NaN (or a non-positive
    value) where a sensor gave none. ``lidar_d0`` (m) is the lidar distance at the first pair's
    previous frame, if any. The filter starts at the first lidar distance (frames before it
    get reason ``no_lidar_yet``) and then gives an estimate for every frame, predicting through
    frames without measurements.
    """
    if params.name == "none":
        raise ValueError("kalman_fuse needs fusion kalman_cv or kalman_ca, got none")
    dt = np.asarray(dt, dtype=float)
    lidar = np.asarray(lidar_d, dtype=float)
    ratio = np.asarray(camera_ratio, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_ratio = np.where(np.isfinite(ratio) & (ratio > 0), np.log(ratio), np.nan)
    lidar = np.where(np.isfinite(lidar) & (lidar > 0), lidar, np.nan)
    lidar_sd, camera_sd = noise_sds(np.r_[lidar_d0, lidar], log_ratio, params)
    n, s = len(dt), params.n_states
    out = FusedTrack(np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan),
                     np.full((n, s), np.nan), np.full(n, NO_LIDAR_YET, dtype=object))  # fmt: skip
    x = p = None
    if np.isfinite(lidar_d0) and lidar_d0 > 0:
        x, p = _initial_state(float(lidar_d0), params, lidar_sd)
    for k in range(n):
        if x is None:
            if not np.isfinite(lidar[k]):
                continue
            x, p = _initial_state(float(lidar[k]), params, lidar_sd)
            used_lidar = True
        else:
            f, q = _transition(dt[k], s, params)
            x, p = f @ x, f @ p @ f.T + q
            used_lidar = False
            if np.isfinite(lidar[k]):
                h = np.eye(s)[0]
                x, p, used_lidar = _update(x, p, lidar[k] - x[0], h, lidar_sd**2, params.gate_sd)
        used_camera = False
        if np.isfinite(log_ratio[k]) and x[0] > 0 and _previous_distance(x, dt[k]) > 0:
            z_hat, h = _camera_model(x, dt[k])
            x, p, used_camera = _update(x, p, log_ratio[k] - z_hat, h, camera_sd**2, params.gate_sd)
        out.state[k] = x
        out.ttc[k], out.ttc_sd[k] = _ttc_and_sd(x, p)
        if x[0] > 0 and _previous_distance(x, dt[k]) > 0:
            out.ratio[k] = _previous_distance(x, dt[k]) / x[0]
        out.reason[k] = _reason(x, used_lidar, used_camera)
    return out


def _reason(x: np.ndarray, used_lidar: bool, used_camera: bool) -> str:
    if x[1] <= 0:
        return RECEDING
    if used_lidar and used_camera:
        return FUSED
    return LIDAR_ONLY if used_lidar else CAMERA_ONLY if used_camera else PREDICTED


#: The columns of a run's rows :func:`fused_columns` reads.
FUSION_INPUTS = ("is_lead", "frame", "dt", "d_prev", "d_curr", "camera_ratio")


def fused_columns(rows: pd.DataFrame, params: FusionParams) -> dict[str, np.ndarray]:
    """The :data:`FUSED_COLUMNS` of the rows of one run (N,), as arrays (N,) by name.

    The lead vehicle's rows (``is_lead``), in frame order, are one track through the filter;
    every other row gets NaN with reason ``not_lead``, every row NaN with reason ``off`` for
    ``fusion=none``. Reads :data:`FUSION_INPUTS` (none of them for ``fusion=none``).
    """
    n = len(rows)
    ttc, ttc_sd, ratio, reason = FUSED_COLUMNS
    out = {ttc: np.full(n, np.nan), ttc_sd: np.full(n, np.nan), ratio: np.full(n, np.nan),
           reason: np.full(n, OFF if params.name == "none" else NOT_LEAD, dtype=object)}  # fmt: skip
    if params.name == "none" or n == 0:
        return out
    lead = np.flatnonzero(rows["is_lead"].to_numpy(dtype=bool))
    lead = lead[np.argsort(rows["frame"].to_numpy()[lead], kind="stable")]
    column = {c: rows[c].to_numpy(dtype=float)[lead] for c in ("dt", "d_prev", "d_curr",
                                                                "camera_ratio")}  # fmt: skip
    track = kalman_fuse(column["dt"], column["d_curr"], column["camera_ratio"], params,
                        lidar_d0=float(column["d_prev"][0]) if len(lead) else np.nan)  # fmt: skip
    out[ttc][lead], out[ttc_sd][lead], out[ratio][lead] = track.ttc, track.ttc_sd, track.ratio
    out[reason][lead] = track.reason.astype(str)
    return out
