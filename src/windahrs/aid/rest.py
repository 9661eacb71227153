"""Aid source: the vehicle at rest. The gyro as a measurement of its own bias (zero-rate
update; VQF's rest detection and rest bias estimation, Laidig and Seel 2023, section 3.3;
PX4 EKF2 and ArduPilot EKF3 learn the bias on the ground in the same spirit), and in the INS
the accelerometers as a measurement of gravity (its stationary alignment).

Rest detection, at every IMU sample of an initialised filter: first-order low-passes of the
angular rate and of the specific force (``rest_tau``, VQF's restFilterTau 0.5 s); the
vehicle is still while every sample stays within ``rest_gyro_threshold`` (VQF's restThGyr,
2 deg/s) and ``rest_accel_threshold`` (restThAcc, 0.5 m/s^2) of those means, and the mean
angular rate is a plausible bias (``rest_bias_clip``, VQF's biasClip 2 deg/s: a vehicle
turning steadily is not at rest). It is at rest after ``rest_min_time`` (restMinT 1.5 s) of
that, when the low-passed rate has also been steady for the last rest_min_time - rest_tau
(1 s): within the rest measurement's own gate (gate_accel sigmas of the difference of two
rest measurements, below: 0.22 deg/s at the defaults) of its value at the start of that
time, which starts again when it is not (and first rest_tau after the stillness began, when
the mean has forgotten the motion before).
VQF's thresholds alone pass a multirotor hovering smoothly in gusts, whose attitude loop
moves: on the simulated quadrotor in 8 m/s wind the low-passed rate wanders by 0.8-3.0
deg/s within 1.5-10 s of such a "rest", against 0.02-0.13 deg/s on the ground (PX4 logs,
BROAD's still phases) and in calm air (docs/RESULTS.md section 38); fused, that hover's slow
turns became gyro bias and its accelerations tilt (section 33).

Measurement, at rest (fused once per ``rest_tau``, the time over which the means' samples
are correlated: fused at every IMU sample, the same mean would count hundreds of times;
gated at gate_accel sigmas, a measurement of the same IMU):

* the filters that fuse gravity: the low-passed angular rate is the gyro bias, ``h = b_g``,
  ``H = I`` on the bias columns, ``R = (rest_bias_sigma^2 + gyro_noise^2 / (2 rest_tau))
  I``: VQF's biasSigmaRest (0.03 deg/s, the motion a still-standing body keeps) plus the
  gyro's white noise left in the mean. Innovation key: ``"rest"`` (3 rows, rad/s). This is
  what makes the heading of a 6-D filter (no magnetometer) drift with the true vertical
  gyro bias only: the vertical bias is not observable from gravity, but a body at rest
  measures it directly.
* the INS: the low-passed specific force is gravity plus the accelerometer's bias
  (:func:`windahrs.aid.gravity.fuse_level`), R its white noise left in the mean (the
  INS's input density, :func:`windahrs.core.predict.ins_accel_density2`, over 2 rest_tau).
  Innovation key: ``"level"``. The INS takes the accelerometer as its input and otherwise
  sees its tilt only through GNSS velocity, slowly at rest: a strapdown INS levels on its
  accelerometers while it stands still before it moves (stationary, or "fine", alignment;
  PX4 EKF2 aligns its tilt on the ground before it fuses GNSS). Its gyro bias is not
  fused at rest: a 0.5 s mean of a real gyro can be off by several times biasSigmaRest
  (PX4 ``sample_logging_tagged_and_default_params.ulg``: 0.13 deg/s, which tilted the INS
  by 0.3 deg over 4 s), and GNSS and the magnetometer observe the INS's bias in motion.
  By default (rest_detection "auto") the INS aligns at the start only ("align": detection
  ends at the first motion), and not when its start is given (:class:`InitialState`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from windahrs.aid.gravity import fuse_level
from windahrs.core.kalman import _bias_rows, _fuse
from windahrs.core.layout import (
    _JIT_CORE,
    INN_REST,
    KIND_INS,
    REST_ALIGN,
    REST_START,
    W_H,
    W_NU,
    W_R,
    X_BG,
    record_dtype,
)
from windahrs.core.predict import _lowpass_gain, ins_accel_density2

#: The parameters of this aid source (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = (
    "rest_detection",
    "rest_gyro_threshold",
    "rest_accel_threshold",
    "rest_tau",
    "rest_min_time",
    "rest_bias_sigma",
    "rest_bias_clip",
    "gate_accel",  # (the rest gate: its measurements and the steady rate)
)

#: The detector's state (KernelState.rest, a (1,) array of :data:`REST`; float64 fields, as
#: the flat state they came from). (name, size, meaning)
REST_FIELDS: tuple[tuple[str, int, str], ...] = (
    ("w", 3, "low-passed angular rate, rad/s"),
    ("f", 3, "low-passed specific force, m/s^2"),
    ("n", 1, "samples in those low-passes (0: not started; -1: \"start\" or \"align\" after the first motion)"),
    ("t_rest", 1, "when the current rest began, s (NaN: moving)"),
    ("t_fuse", 1, "when the rest measurement was last fused, s (-inf: never)"),
    ("w0", 3, "the low-passed rate rest_tau after the current rest began, rad/s (NaN: not yet)"),
    ("t_steady", 1, "since when the low-passed rate has stayed within the rest gate of w0, s"),
)
REST = record_dtype(REST_FIELDS)


def rest_state() -> NDArray[np.void]:
    """A fresh detector state: not started, not at rest, never fused."""
    rs = np.zeros(1, REST)
    rs["t_rest"], rs["t_fuse"] = np.nan, -np.inf
    return rs


@njit(inline="always", **_JIT_CORE)
def fuse_rest(cfg, prm, x, flags, P, work, sup, inn, acc, rs, t, row, dt):
    """IMU sample ``row`` = [w_b, f_b] at t s, dt s after the last one: rest detection,
    and at rest (once per rest_tau) the low-passed angular rate fused as the gyro bias (the
    INS: the low-passed specific force as gravity, :func:`~windahrs.aid.gravity.fuse_level`).
    rs: the detector's record (:data:`REST`), read and written in place."""
    if rs["n"] < 0.0:  # (rest_detection "start" or "align", after the first motion)
        return
    if rs["n"] == 0.0:
        for i in range(3):
            rs["w"][i] = row[i]
            rs["f"][i] = row[3 + i]
        rs["n"] = 1.0
        return
    tau = prm["rest_tau"]
    a = _lowpass_gain(dt, tau)
    dw2, df2, clip = 0.0, 0.0, 0.0
    for i in range(3):
        rs["w"][i] += a * (row[i] - rs["w"][i])
        rs["f"][i] += a * (row[3 + i] - rs["f"][i])
        dw2 += (row[i] - rs["w"][i]) ** 2
        df2 += (row[3 + i] - rs["f"][i]) ** 2
        clip = max(clip, abs(rs["w"][i]))
    rs["n"] += 1.0
    if not (dw2 < prm["rest_w2"] and df2 < prm["rest_f2"] and clip <= prm["rest_clip"]):
        rs["t_rest"] = np.nan  # moving
        if (cfg["rest"] == REST_START and rs["t_fuse"] > -np.inf) or cfg["rest"] == REST_ALIGN:
            rs["n"] = -1.0  # the start's rest is over: no more rest updates
        return
    if math.isnan(rs["t_rest"]):
        rs["t_rest"] = t
        rs["w0"][0] = np.nan
    if t - rs["t_rest"] < tau:
        return
    # a steady rate (the bias) for rest_min_time: the low-passed rate within the rest gate of
    # its value w0 at the window's start, gate_accel sigmas of the difference of two rest
    # measurements (rest_var and the gyro's white noise left in each mean); beyond it, the
    # window starts again
    var = prm["rest_var"] + prm["gyro_noise2"] / (2.0 * tau)  # (a rest measurement's variance, below)
    lim2 = prm["gate_accel2"] * 2.0 * var
    steady = not math.isnan(rs["w0"][0])
    for i in range(3):
        steady = steady and (rs["w"][i] - rs["w0"][i]) ** 2 <= lim2
    if not steady:
        for i in range(3):
            rs["w0"][i] = rs["w"][i]
        rs["t_steady"] = t
    if t - rs["t_rest"] < prm["rest_min_t"] or t - rs["t_steady"] < prm["rest_min_t"] - tau or t - rs["t_fuse"] < tau:
        return
    rs["t_fuse"] = t
    if cfg["kind"] == KIND_INS:  # the INS levels on the mean specific force (its gyro bias: below)
        var_f = ins_accel_density2(cfg, prm, x, dt) / (2.0 * tau)
        fuse_level(cfg, prm, x, flags, P, work, sup, inn, acc, t, rs["f"][0], rs["f"][1], rs["f"][2], var_f)
        return
    H, R, nu = work[W_H : W_H + 3], work[W_R : W_R + 3], work[W_NU]
    ib = cfg["i_bg"]
    for k in range(3):
        H[k, 0], H[k, 1], H[k, 2] = 0.0, 0.0, 0.0  # (the additive form reads the attitude's columns)
        nu[k] = rs["w"][k] - x[X_BG + k]
        for l in range(3):
            R[k, l] = var if k == l else 0.0
    nsup = _bias_rows(work, sup[0], ib, np.int64(0))
    _fuse(cfg, x, flags, P, work, sup, inn, acc, np.int64(INN_REST), t, np.int64(3), np.int64(nsup),
          prm["gate_accel2"])
