"""Aid source: the gyro at rest as a measurement of its own bias (zero-rate update; VQF's
rest detection and rest bias estimation, Laidig and Seel 2023, section 3.3; PX4 EKF2 and
ArduPilot EKF3 learn the bias on the ground in the same spirit).

Rest detection, at every IMU sample of an initialised filter: first-order low-passes of the
angular rate and of the specific force (``rest_tau``, VQF's restFilterTau 0.5 s); the
vehicle is still while every sample stays within ``rest_gyro_threshold`` (VQF's restThGyr,
2 deg/s) and ``rest_accel_threshold`` (restThAcc, 0.5 m/s^2) of those means, and the mean
angular rate is a plausible bias (``rest_bias_clip``, VQF's biasClip 2 deg/s: a vehicle
turning steadily is not at rest); it is at rest after ``rest_min_time`` (restMinT 1.5 s)
of that.

Measurement, at rest: the low-passed angular rate is the gyro bias, ``h = b_g``, ``H = I``
on the bias columns, ``R = (rest_bias_sigma^2 + gyro_noise^2 / (2 rest_tau)) I``: VQF's
biasSigmaRest (0.03 deg/s, the motion a still-standing body keeps) plus the gyro's white
noise left in the mean. It is fused once per ``rest_tau``, the time over which the mean's
samples are correlated (fused at every IMU sample, the same mean would count hundreds of
times). Gated at gate_accel sigmas (a measurement of the same IMU). Innovation key:
``"rest"`` (3 rows, rad/s).

This is what makes the heading of a 6-D filter (no magnetometer) drift with the true
vertical gyro bias only: the vertical bias is not observable from gravity, but a body at
rest measures it directly.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from windahrs.core.kalman import _bias_rows, _fuse
from windahrs.core.layout import (
    _JIT_CORE,
    INN_REST,
    REST_START,
    W_H,
    W_NU,
    W_R,
    X_BG,
    X_RF,
    X_RN,
    X_RW,
    X_TREST,
    X_TRFUSE,
)
from windahrs.core.predict import _lowpass_gain

#: The parameters of this aid source (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = (
    "rest_detection",
    "rest_gyro_threshold",
    "rest_accel_threshold",
    "rest_tau",
    "rest_min_time",
    "rest_bias_sigma",
    "rest_bias_clip",
)


@njit(inline="always", **_JIT_CORE)
def fuse_rest(cfg, prm, x, flags, P, work, sup, inn, acc, t, row, dt):
    """IMU sample ``row`` = [w_b, f_b] at t s, dt s after the last one: rest detection,
    and at rest (once per rest_tau) the low-passed angular rate fused as the gyro bias."""
    if x[X_RN] < 0.0:  # (rest_detection "start", after the first motion)
        return
    if x[X_RN] == 0.0:
        for i in range(3):
            x[X_RW + i] = row[i]
            x[X_RF + i] = row[3 + i]
        x[X_RN] = 1.0
        return
    tau = prm["rest_tau"]
    a = _lowpass_gain(dt, tau)
    dw2, df2, clip = 0.0, 0.0, 0.0
    for i in range(3):
        x[X_RW + i] += a * (row[i] - x[X_RW + i])
        x[X_RF + i] += a * (row[3 + i] - x[X_RF + i])
        dw2 += (row[i] - x[X_RW + i]) ** 2
        df2 += (row[3 + i] - x[X_RF + i]) ** 2
        clip = max(clip, abs(x[X_RW + i]))
    x[X_RN] += 1.0
    if not (dw2 < prm["rest_w2"] and df2 < prm["rest_f2"] and clip <= prm["rest_clip"]):
        x[X_TREST] = np.nan  # moving
        if cfg["rest"] == REST_START and x[X_TRFUSE] > -np.inf:
            x[X_RN] = -1.0  # the start's rest is over: no more rest updates
        return
    if math.isnan(x[X_TREST]):
        x[X_TREST] = t
    if t - x[X_TREST] < prm["rest_min_t"] or t - x[X_TRFUSE] < tau:
        return
    x[X_TRFUSE] = t
    H, R, nu = work[W_H : W_H + 3], work[W_R : W_R + 3], work[W_NU]
    ib = cfg["i_bg"]
    var = prm["rest_var"] + prm["gyro_noise2"] / (2.0 * tau)
    for k in range(3):
        H[k, 0], H[k, 1], H[k, 2] = 0.0, 0.0, 0.0  # (the additive form reads the attitude's columns)
        nu[k] = x[X_RW + k] - x[X_BG + k]
        for l in range(3):
            R[k, l] = var if k == l else 0.0
    nsup = _bias_rows(work, sup[0], ib, np.int64(0))
    _fuse(cfg, x, flags, P, work, sup, inn, acc, np.int64(INN_REST), t, np.int64(3), np.int64(nsup),
          prm["gate_accel2"])
