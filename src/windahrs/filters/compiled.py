"""Compiled twins of the error-state filters [mekf], [mekf-air], [ins-wind] and of the
additive [ekf7], [ekf10]: the math and logic of :mod:`windahrs.filters.eskf` and
:mod:`windahrs.filters.ekf7` (the readable references) in numba nopython kernels, with no
Python per sample. Tested equal to the references sample by sample (tests/test_compiled.py).

Structure:

* :class:`KernelState` holds everything a running filter needs in nine arrays: the
  configuration (ints) and parameters (floats) encoded once from :class:`EskfParams`, the
  nominal state with the samples it remembers, flags and counters, the covariance,
  scratch space and the innovation logs.
* One step function per event kind (:func:`step_imu`, :func:`step_mag`,
  :func:`step_gnss`, :func:`step_air`), inlined into the compiled loop :func:`run_events`.
  The batch run feeds it the whole merged event list; :class:`CompiledStreamer` feeds it
  one event at a time (without recording), so a flight streamed equals its batch run bit
  for bit.
* ``MekfFast`` ... ``Ekf10Fast`` subclass the reference estimators (same ``name``,
  ``params``, ``requires``, ``uses``) and replace only ``run`` and ``streamer``.

Cost: the transition matrix is the identity except a few 3x3 blocks in the attitude
(and velocity) rows, so the prediction rewrites only those rows and columns of P (O(n)
work instead of the O(n^3) of a dense ``Phi P Phi^T``). An update with m rows whose
Jacobian touches c columns costs O(n c m + n^2 m); its Joseph form is evaluated expanded,
``P - K U^T - U K^T + K S K^T = P + K G^T + G K^T`` (``U = P H^T``, ``G = K S / 2 - U``):
algebraically the Joseph form, with its insensitivity to gain errors, not the short form
``P - K H P``, and exactly symmetric in floating point. P is kept in a zero-padded
(NMAX, NMAX) array so that the inner loops have a constant length and compile to fast
code. Nothing is allocated inside the loop. The results differ from the references by
rounding only (other summation orders, a cofactor 3x3 inverse instead of an LU solve,
fused multiply-adds in the predictions): about 1e-14 relative after a flight.

Compile time and speed: helpers take the arrays they need, not the KernelState (numba
reference-counts every array taken out of a tuple); functions called from several places
take non-literal arguments (``np.int64(...)``) so that numba compiles each once.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from windahrs.estimate import Estimate, Innovations
from windahrs.filters.base import (
    EVENT_AIR,
    EVENT_GNSS,
    EVENT_IMU,
    EVENT_MAG,
    InitialState,
    StateView,
    Streamer,
    merge_events,
)
from windahrs.filters.ekf7 import Ekf7, Ekf10
from windahrs.filters.eskf import InsWind, Kind, Mekf, MekfAir, _EskfEstimator, effective_mag_mode, layout_for
from windahrs.filters.params import EskfParams
from windahrs.flight import Flight, Site
from windahrs.models.error_state import Layout

__all__ = [
    "SENSORS",
    "CompiledStreamer",
    "Ekf7Fast",
    "Ekf10Fast",
    "InsWindFast",
    "KernelState",
    "MekfAirFast",
    "MekfFast",
    "layout_of",
    "make_state",
    "record",
    "run_events",
    "step_air",
    "step_gnss",
    "step_imu",
    "step_mag",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

_JIT: dict[str, Any] = {"cache": True, "error_model": "numpy"}
#: The predictions may fuse multiply-adds (FMA: different rounding, no other effect; they
#: symmetrise P explicitly). The updates do not: their exact symmetry relies on plain
#: products and sums.
_JIT_FMA: dict[str, Any] = {**_JIT, "fastmath": {"contract"}}

#: Width of the scratch rows: the largest covariance (ins-wind with accelerometer and
#: magnetometer bias: 18; ekf10: 10) plus one.
NMAX = 19

KIND_MEKF, KIND_MEKF_AIR, KIND_INS = 0, 1, 2
COMP_NONE, COMP_GNSS, COMP_AIRSPEED = 0, 1, 2
MAG_3D, MAG_HEADING, MAG_OFF = 0, 1, 2
AIR_AUTO, AIR_VECTOR, AIR_AIRSPEED, AIR_OFF = 0, 1, 2, 3

#: Innovation logs, in this order (the Estimate's ``innovations`` keys).
SENSORS = ("accel", "mag", "gnss", "air", "tas", "sideslip")
INN_ACCEL, INN_MAG, INN_GNSS, INN_AIR, INN_TAS, INN_SIDESLIP = 0, 1, 2, 3, 4, 5

# cfg: configuration (int64), fixed for a run (the log layout changes when a streamer grows).
C_KIND = 0  # KIND_*
C_ADD = 1  # 1: additive quaternion (ekf7/ekf10)
C_COMP = 2  # accelerometer compensation, COMP_* (mekf-air: always airspeed)
C_MAG = 3  # MAG_*
C_AIR = 4  # AIR_*
C_SYN = 5  # synthetic sideslip
C_WAIT_MAG = 6  # initialise only after a magnetometer sample
C_WAIT_GNSS = 7  # initialise only after a GNSS sample
C_INI = 8  # an InitialState was given
C_INI_BG = 9  # ... with a gyro bias
C_INI_V = 10  # ... with a velocity
C_INI_W = 11  # ... with a wind
C_SITE_MAG = 12  # the site's field is known
C_IV = 13  # error-state index of the velocity block (-1: none)
C_IBG = 14  # ... gyro bias
C_IW = 15  # ... wind (-1: none)
C_IBA = 16  # ... accelerometer bias (-1: none)
C_DIM = 17  # error-state dimension
C_N = 18  # covariance dimension (additive: DIM + 1)
C_OFF = 19  # (6,) first row of each sensor's log
C_CAP = 25  # (6,) rows of each sensor's log
C_IBM = 31  # ... magnetometer bias (-1: none)
C_HVERT = 32  # heading model: 1 "vertical", 0 "yaw"
N_CFG = 33

# prm: parameters (float64), fixed for a run; squared in Python as the reference does.
R_SG2 = 0  # gyro noise density^2
R_SB2 = 1  # gyro bias noise^2
R_SA2 = 2  # accel noise^2
R_SBA2 = 3  # accel bias noise^2
R_WH2 = 4  # horizontal wind noise^2
R_WV2 = 5  # vertical wind noise^2
R_ACC_VAR = 6
R_NORM_GATE = 7
R_MAG_SIGMA = 8
R_MAG_VAR = 9
R_GNSS_VAR = 10
R_TAS_VAR = 11
R_VANE_VAR = 12
R_BETA_VAR = 13
R_GATE2_ACC = 14
R_GATE2_MAG = 15
R_GATE2_GNSS = 16
R_GATE2_AIR = 17
R_P0_ATT = 18  # initial variances
R_P0_BG = 19
R_P0_V = 20
R_P0_W = 21
R_P0_BA = 22
R_GRAV = 23
R_SITE_MAG = 24  # (3,)
R_INI_Q = 27  # (4,)
R_INI_BG = 31  # (3,)
R_INI_V = 34  # (3,)
R_INI_W = 37  # (3,)
R_P0_BM = 40
R_SBM2 = 41  # magnetometer bias noise^2
R_ACC_LP = 42  # accel_lowpass, s (0: raw samples)
R_MAG_LP = 43  # mag_lowpass, s (0: raw samples)
R_SCALE2 = 44  # gyro_scale_noise^2
R_MAG_NGATE = 45  # mag_norm_gate (0: off)
R_MAG_DGATE = 46  # mag_dip_gate, rad (0: off)
N_PRM = 47

# x: nominal state and remembered samples (float64).
X_Q = 0  # (4,)
X_BG = 4
X_V = 7
X_W = 10
X_BA = 13
X_MAGN = 16  # nav-frame field reference
X_FLAST = 19  # last specific force
X_VGNSS = 22  # last GNSS velocity
X_AGNSS = 25  # GNSS velocity difference
X_VAIR = 28  # last air-relative velocity, body
X_FMAG = 31  # first magnetometer sample (before initialisation)
X_FV = 34  # first GNSS velocity (before initialisation)
X_TIMU = 37
X_TGNSS = 38
X_BM = 40  # (3,) magnetometer bias
X_FBAR = 43  # (3,) low-passed specific force, body
X_MBAR = 46  # (3,) low-passed magnetic field, body
X_TMBAR = 49  # time of the last magnetometer sample in it
N_X = 50

# flags (int64): which remembered values are set, log counters, skipped samples.
S_INIT = 0
S_FLAST = 1
S_MAGN = 2
S_VGNSS = 3
S_AGNSS = 4
S_VAIR = 5
S_FMAG = 6
S_FV = 7
S_WPEND = 8  # wind to be initialised from the next air sample
S_SEQ = 9  # sensors that have logged so far
L_CNT = 10  # (6,) log rows used per sensor
L_FIRST = 16  # (6,) order of each sensor's first log row (-1: none)
K_SKIP = 22  # (4,) NaN samples skipped: imu, mag, gnss, air
S_FBAR = 26  # the low-passed specific force is set
S_MBAR = 27  # the low-passed magnetic field is set
N_FLAGS = 28

# work: scratch rows of NMAX columns.
W_H = 0  # (3,) measurement Jacobian rows, error-state columns
W_HQ = 3  # (3,) the same in covariance columns (additive)
W_U = 6  # (3,) H P
W_K = 9  # (3,) K^T
W_G = 12  # (3,) G^T = (K S / 2 - P H^T)^T
W_M = 15  # (8,) rows of Phi P; rows 4..7 also Xi(q)
W_X = 23  # (8,) 8x8: attitude/velocity block; rows 4..7 also a 4x4 factor
W_T = 31  # 8 3x3 matrices, in columns 0..2 of rows W_T + 3 i
W_R = 55  # (3,) measurement noise, columns 0..2
W_S = 58  # (3,) innovation covariance
W_SI = 61  # (3,) its inverse
W_NU = 64  # innovation in columns 0..2
W_DX = 65  # error-state correction
N_WORK = 66


class KernelState(NamedTuple):
    """Everything a compiled filter carries between events (arrays, mutated in place);
    the index constants of this module name their entries."""

    cfg: I64  # (N_CFG,) C_*
    prm: F64  # (N_PRM,) R_*
    x: F64  # (N_X,) X_*
    flags: I64  # (N_FLAGS,) S_*, L_*, K_*
    P: F64  # (NMAX, NMAX) covariance in [:n, :n], zero padding
    work: F64  # (N_WORK, NMAX) W_*
    sup: I64  # (2, NMAX) columns where H (row 0) and Hq (row 1) may be non-zero
    inn: F64  # (L, 5) innovation log rows: t, nu (3, NaN-padded), nis
    acc: NDArray[np.bool_]  # (L,) accepted


# --- helpers on scalars (no allocation) -----------------------------------------------


@njit(**_JIT)
def _sinc(x):
    # np.sinc, with its own guard at 0.
    y = math.pi * (1.0e-20 if x == 0.0 else x)
    return math.sin(y) / y


@njit(**_JIT)
def _qmul(a0, a1, a2, a3, b0, b1, b2, b3):
    return (
        a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
        a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
        a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
        a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0,
    )


@njit(**_JIT)
def _qexp(px, py, pz):
    a = math.sqrt(px * px + py * py + pz * pz)
    s = 0.5 * _sinc(a / (2.0 * math.pi))
    return math.cos(0.5 * a), s * px, s * py, s * pz


@njit(**_JIT)
def _qnormalize(q0, q1, q2, q3):
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    s = -1.0 if q0 < 0.0 else 1.0
    return q0 * s / n, q1 * s / n, q2 * s / n, q3 * s / n


@njit(**_JIT)
def _dcm9(w, x, y, z):
    """C_nb entries row by row (rotation.dcm_from_quat)."""
    return (
        w * w + x * x - y * y - z * z,
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        w * w - x * x + y * y - z * z,
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        w * w - x * x - y * y + z * z,
    )


@njit(**_JIT)
def _quat_from_euler(roll, pitch, yaw):
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return _qnormalize(
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    )


@njit(**_JIT)
def _euler(q0, q1, q2, q3):
    """rotation.euler_from_quat (ZYX, with its gimbal-lock rule)."""
    c = _dcm9(q0, q1, q2, q3)
    r31 = min(max(c[6], -1.0), 1.0)
    pitch = -math.asin(r31)
    if abs(r31) > 1.0 - 1e-9:
        return 0.0, pitch, math.atan2(-c[1], c[4])
    return math.atan2(c[7], c[8]), pitch, math.atan2(c[3], c[0])


@njit(**_JIT)
def _triad(fx, fy, fz, use_mag, mx, my, mz, use_ref, rx, ry, rz):
    """base.triad: roll and pitch from the specific force, yaw from the magnetometer."""
    nf = math.sqrt(fx * fx + fy * fy + fz * fz)
    ux, uy, uz = fx / nf, fy / nf, fz / nf
    roll = math.atan2(-uy, -uz)
    pitch = math.asin(min(max(ux, -1.0), 1.0))
    q = _quat_from_euler(roll, pitch, 0.0)
    if not use_mag:
        return q
    c = _dcm9(q[0], q[1], q[2], q[3])
    l0 = c[0] * mx + c[1] * my + c[2] * mz
    l1 = c[3] * mx + c[4] * my + c[5] * mz
    yaw = -math.atan2(l1, l0)
    decl = math.atan2(ry, rx) if use_ref else 0.0
    return _quat_from_euler(roll, pitch, yaw + decl)


@njit(**_JIT)
def _wrap_pi(x):
    """``(x + pi) % (2 pi) - pi`` with numpy's (floored) remainder."""
    two_pi = 2.0 * math.pi
    r = np.fmod(x + math.pi, two_pi)
    if r != 0.0:
        if r < 0.0:
            r += two_pi
    else:
        r = 0.0
    return r - math.pi


@njit(**_JIT)
def _xi_into(q0, q1, q2, q3, X):
    """additive.Xi(q) (4x3) into X[:4, :3]."""
    X[0, 0], X[0, 1], X[0, 2] = -q1, -q2, -q3
    X[1, 0], X[1, 1], X[1, 2] = q0, -q3, q2
    X[2, 0], X[2, 1], X[2, 2] = q3, q0, -q1
    X[3, 0], X[3, 1], X[3, 2] = -q2, q1, q0


# --- logging, initialisation --------------------------------------------------------------


@njit(inline="always", **_JIT)
def _log(cfg, flags, inn, acc, nu, sensor, t, m, nis, accepted):
    """Streamer._log: t, nu[:m] (NaN-padded to 3), nis, accepted."""
    c = flags[L_CNT + sensor]
    if c >= cfg[C_CAP + sensor]:
        raise IndexError("innovation log full")
    if c == 0:
        flags[L_FIRST + sensor] = flags[S_SEQ]
        flags[S_SEQ] += 1
    row = cfg[C_OFF + sensor] + c
    inn[row, 0] = t
    for i in range(3):
        inn[row, 1 + i] = nu[i] if i < m else np.nan
    inn[row, 4] = nis
    acc[row] = accepted
    flags[L_CNT + sensor] = c + 1


@njit(**_JIT)
def _set_mag_reference(cfg, prm, x, flags, mx, my, mz):
    """eskf.mag_reference: the site's field, or the sample's with its horizontal part north."""
    if cfg[C_SITE_MAG] == 1:
        for a in range(3):
            x[X_MAGN + a] = prm[R_SITE_MAG + a]
    else:
        c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
        m0 = c[0] * mx + c[1] * my + c[2] * mz
        m1 = c[3] * mx + c[4] * my + c[5] * mz
        m2 = c[6] * mx + c[7] * my + c[8] * mz
        x[X_MAGN] = math.hypot(m0, m1)
        x[X_MAGN + 1] = 0.0
        x[X_MAGN + 2] = m2
    flags[S_MAGN] = 1


@njit(**_JIT)
def _try_init(cfg, prm, x, flags, P, work):
    """EskfStreamer._try_init (and Ekf7Streamer's covariance on the quaternion)."""
    if flags[S_INIT] == 1 or flags[S_FLAST] == 0:
        return
    if cfg[C_WAIT_MAG] == 1 and flags[S_FMAG] == 0:
        return
    if cfg[C_WAIT_GNSS] == 1 and flags[S_FV] == 0:
        return
    if cfg[C_INI] == 1:
        q = (prm[R_INI_Q], prm[R_INI_Q + 1], prm[R_INI_Q + 2], prm[R_INI_Q + 3])
    else:
        q = _triad(
            x[X_FLAST], x[X_FLAST + 1], x[X_FLAST + 2],
            flags[S_FMAG] == 1, x[X_FMAG], x[X_FMAG + 1], x[X_FMAG + 2],
            cfg[C_SITE_MAG] == 1, prm[R_SITE_MAG], prm[R_SITE_MAG + 1], prm[R_SITE_MAG + 2],
        )  # fmt: skip
    x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = q
    iv, ib, iw, iba = cfg[C_IV], cfg[C_IBG], cfg[C_IW], cfg[C_IBA]
    for a in range(3):
        x[X_BG + a] = prm[R_INI_BG + a] if cfg[C_INI_BG] == 1 else 0.0
        if iv >= 0:
            x[X_V + a] = prm[R_INI_V + a] if cfg[C_INI_V] == 1 else x[X_FV + a]
        if iw >= 0:
            x[X_W + a] = prm[R_INI_W + a] if cfg[C_INI_W] == 1 else 0.0
        x[X_BA + a] = 0.0
        x[X_BM + a] = 0.0
    for i in range(NMAX):
        for j in range(NMAX):
            P[i, j] = 0.0
    off = cfg[C_ADD]  # covariance index = error-state index + 1 after the quaternion
    for a in range(3):
        P[ib + off + a, ib + off + a] = prm[R_P0_BG]
        if iv >= 0:
            P[iv + off + a, iv + off + a] = prm[R_P0_V]
        if iw >= 0:
            P[iw + off + a, iw + off + a] = prm[R_P0_W]
        if iba >= 0:
            P[iba + off + a, iba + off + a] = prm[R_P0_BA]
        if cfg[C_IBM] >= 0:
            P[cfg[C_IBM] + off + a, cfg[C_IBM] + off + a] = prm[R_P0_BM]
    if cfg[C_ADD] == 1:
        # quat_cov_from_att_cov: 1/4 Xi P_att Xi^T with P_att = var I
        Xi = work[W_M + 4 : W_M + 8]
        _xi_into(q[0], q[1], q[2], q[3], Xi)
        var = prm[R_P0_ATT]
        for r in range(4):
            for c in range(4):
                s = 0.0
                for k in range(3):
                    s += Xi[r, k] * var * Xi[c, k]
                P[r, c] = 0.25 * s
    else:
        for a in range(3):
            P[a, a] = prm[R_P0_ATT]
    if flags[S_FMAG] == 1:
        _set_mag_reference(cfg, prm, x, flags, x[X_FMAG], x[X_FMAG + 1], x[X_FMAG + 2])
    elif cfg[C_SITE_MAG] == 1:
        _set_mag_reference(cfg, prm, x, flags, 0.0, 0.0, 0.0)
    if prm[R_ACC_LP] > 0:
        for a in range(3):
            x[X_FBAR + a] = x[X_FLAST + a]
        flags[S_FBAR] = 1
    flags[S_WPEND] = 1 if (iw >= 0 and cfg[C_INI_W] == 0) else 0
    flags[S_INIT] = 1


@njit(**_JIT)
def _lowpass_gain(dt, tau):
    """eskf.lowpass_gain: weight of a new sample in a first-order low-pass after dt."""
    return 1.0 - math.exp(-dt / tau) if dt > 0 else 0.0


@njit(**_JIT)
def _rotate_lowpass(x, flags, wx, wy, wz, dt):
    """EskfStreamer._rotate_lowpass: the low-passed vectors into the new body frame,
    v <- C(Exp(w dt))^T v (w bias-corrected)."""
    e = _qexp(wx * dt, wy * dt, wz * dt)
    c = _dcm9(e[0], e[1], e[2], e[3])
    if flags[S_FBAR] == 1:
        _rotate_into(c, x, np.int64(X_FBAR))
    if flags[S_MBAR] == 1:
        _rotate_into(c, x, np.int64(X_MBAR))


@njit(**_JIT)
def _rotate_into(c, x, i0):
    """x[i0:i0+3] <- C^T x[i0:i0+3] (c: C row-major)."""
    v0, v1, v2 = x[i0], x[i0 + 1], x[i0 + 2]
    x[i0] = c[0] * v0 + c[3] * v1 + c[6] * v2
    x[i0 + 1] = c[1] * v0 + c[4] * v1 + c[7] * v2
    x[i0 + 2] = c[2] * v0 + c[5] * v1 + c[8] * v2


@njit(**_JIT)
def _mag_disturbed(prm, x, cfg, mx, my, mz, rx, ry, rz):
    """EskfStreamer._mag_disturbed: the field to be fused fails the norm or dip check."""
    if cfg[C_IBM] >= 0:
        mx, my, mz = mx - x[X_BM], my - x[X_BM + 1], mz - x[X_BM + 2]
    r_norm = math.sqrt(rx * rx + ry * ry + rz * rz)
    ng = prm[R_MAG_NGATE]
    if ng > 0 and abs(math.sqrt(mx * mx + my * my + mz * mz) - r_norm) > ng * r_norm:
        return True
    dg = prm[R_MAG_DGATE]
    if dg > 0:
        c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
        n0 = c[0] * mx + c[1] * my + c[2] * mz
        n1 = c[3] * mx + c[4] * my + c[5] * mz
        n2 = c[6] * mx + c[7] * my + c[8] * mz
        if abs(math.atan2(n2, math.hypot(n0, n1)) - math.atan2(rz, math.hypot(rx, ry))) > dg:
            return True
    return False


# --- prediction ---------------------------------------------------------------------------


@njit(**_JIT_FMA)
def _predict_es(cfg, prm, x, P, work, wmx, wmy, wmz, fmx, fmy, fmz, dt):
    """error_state.predict, using Phi's block structure: only the attitude (and velocity)
    rows and columns of P change before Q is added (layout: att 0..2, v 3..5). The 3x3
    blocks of Phi live in local scalars."""
    n, ib, iv, iw, iba = cfg[C_N], cfg[C_IBG], cfg[C_IV], cfg[C_IW], cfg[C_IBA]
    M, X = work[W_M : W_M + 8], work[W_X : W_X + 8]
    wx, wy, wz = wmx - x[X_BG], wmy - x[X_BG + 1], wmz - x[X_BG + 2]
    e = _qexp(wx * dt, wy * dt, wz * dt)
    q = _qmul(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], e[0], e[1], e[2], e[3])
    x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = _qnormalize(q[0], q[1], q[2], q[3])
    # attitude_transition: phi11 = I + c11 W + c12 W^2, phi12 = -dt I + c21 W + c22 W^2,
    # W = [w]x; W^2 = w w^T - |w|^2 I entry by entry as W @ W evaluates it.
    a = math.sqrt(wx * wx + wy * wy + wz * wz)
    if a * dt < 1e-6:  # series, as the reference
        c11, c12 = -dt, 0.5 * dt**2
        c21, c22 = 0.5 * dt**2, -(dt**3) / 6.0
    else:
        s, c = math.sin(a * dt), math.cos(a * dt)
        c11, c12 = -s / a, (1 - c) / a**2
        c21, c22 = (1 - c) / a**2, -(a * dt - s) / a**3
    xy, xz, yz = wy * wx, wz * wx, wz * wy
    s00, s11, s22 = -(wz * wz) - wy * wy, -(wz * wz) - wx * wx, -(wy * wy) - wx * wx
    p00, p01, p02 = 1.0 + c12 * s00, c11 * -wz + c12 * xy, c11 * wy + c12 * xz
    p10, p11, p12 = c11 * wz + c12 * xy, 1.0 + c12 * s11, c11 * -wx + c12 * yz
    p20, p21, p22 = c11 * -wy + c12 * xz, c11 * wx + c12 * yz, 1.0 + c12 * s22
    r00, r01, r02 = -dt + c22 * s00, c21 * -wz + c22 * xy, c21 * wy + c22 * xz
    r10, r11, r12 = c21 * wz + c22 * xy, -dt + c22 * s11, c21 * -wx + c22 * yz
    r20, r21, r22 = c21 * -wy + c22 * xz, c21 * wx + c22 * yz, -dt + c22 * s22
    # M[0:3] = attitude rows of Phi P = phi11 P[att] + phi12 P[bg], whole padded rows. One
    # output row per loop keeps LLVM's runtime alias checks few enough to vectorise.
    for j in range(NMAX):
        M[0, j] = (
            p00 * P[0, j]
            + p01 * P[1, j]
            + p02 * P[2, j]
            + r00 * P[ib, j]
            + r01 * P[ib + 1, j]
            + (r02 * P[ib + 2, j])
        )
    for j in range(NMAX):
        M[1, j] = (
            p10 * P[0, j]
            + p11 * P[1, j]
            + p12 * P[2, j]
            + r10 * P[ib, j]
            + r11 * P[ib + 1, j]
            + (r12 * P[ib + 2, j])
        )
    for j in range(NMAX):
        M[2, j] = (
            p20 * P[0, j]
            + p21 * P[1, j]
            + p22 * P[2, j]
            + r20 * P[ib, j]
            + r21 * P[ib + 1, j]
            + (r22 * P[ib + 2, j])
        )
    na = 3
    f00 = f01 = f02 = f10 = f11 = f12 = f20 = f21 = f22 = 0.0
    d00 = d01 = d02 = d10 = d11 = d12 = d20 = d21 = d22 = 0.0
    if iv >= 0:
        na = 6
        C = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
        fx, fy, fz = fmx, fmy, fmz
        if iba >= 0:
            fx, fy, fz = fmx - x[X_BA], fmy - x[X_BA + 1], fmz - x[X_BA + 2]
        x[X_V] += (C[0] * fx + C[1] * fy + C[2] * fz + 0.0) * dt
        x[X_V + 1] += (C[3] * fx + C[4] * fy + C[5] * fz + 0.0) * dt
        x[X_V + 2] += (C[6] * fx + C[7] * fy + C[8] * fz + prm[R_GRAV]) * dt
        # Phi[v, att] = CF phi11, Phi[v, bg] = CF phi12 with CF = -C [f]x dt; Phi[v, ba] = -C dt
        f00, f01, f02 = (
            (-C[1] * fz + C[2] * fy) * dt,
            (-C[2] * fx + C[0] * fz) * dt,
            (-C[0] * fy + C[1] * fx) * dt,
        )
        f10, f11, f12 = (
            (-C[4] * fz + C[5] * fy) * dt,
            (-C[5] * fx + C[3] * fz) * dt,
            (-C[3] * fy + C[4] * fx) * dt,
        )
        f20, f21, f22 = (
            (-C[7] * fz + C[8] * fy) * dt,
            (-C[8] * fx + C[6] * fz) * dt,
            (-C[6] * fy + C[7] * fx) * dt,
        )
        d00, d01, d02, d10, d11, d12 = -C[0] * dt, -C[1] * dt, -C[2] * dt, -C[3] * dt, -C[4] * dt, -C[5] * dt
        d20, d21, d22 = -C[6] * dt, -C[7] * dt, -C[8] * dt
        # M[3:6] = velocity rows of Phi P = P[v] + CF M[0:3] (+ Cdt P[ba])
        if iba >= 0:
            for j in range(NMAX):
                M[3, j] = (
                    P[iv, j]
                    + (f00 * M[0, j] + f01 * M[1, j] + f02 * M[2, j])
                    + (d00 * P[iba, j] + d01 * P[iba + 1, j] + d02 * P[iba + 2, j])
                )
            for j in range(NMAX):
                M[4, j] = (
                    P[iv + 1, j]
                    + (f10 * M[0, j] + f11 * M[1, j] + f12 * M[2, j])
                    + (d10 * P[iba, j] + d11 * P[iba + 1, j] + d12 * P[iba + 2, j])
                )
            for j in range(NMAX):
                M[5, j] = (
                    P[iv + 2, j]
                    + (f20 * M[0, j] + f21 * M[1, j] + f22 * M[2, j])
                    + (d20 * P[iba, j] + d21 * P[iba + 1, j] + d22 * P[iba + 2, j])
                )
        else:
            for j in range(NMAX):
                m0, m1, m2 = M[0, j], M[1, j], M[2, j]
                M[3, j] = P[iv, j] + (f00 * m0 + f01 * m1 + f02 * m2)
                M[4, j] = P[iv + 1, j] + (f10 * m0 + f11 * m1 + f12 * m2)
                M[5, j] = P[iv + 2, j] + (f20 * m0 + f21 * m1 + f22 * m2)
    # X = Phi P Phi^T on the attitude/velocity rows and columns (0..na-1)
    for r in range(na):
        t0, t1, t2, g0, g1, g2 = M[r, 0], M[r, 1], M[r, 2], M[r, ib], M[r, ib + 1], M[r, ib + 2]
        x0 = t0 * p00 + t1 * p01 + t2 * p02 + g0 * r00 + g1 * r01 + g2 * r02
        x1 = t0 * p10 + t1 * p11 + t2 * p12 + g0 * r10 + g1 * r11 + g2 * r12
        x2 = t0 * p20 + t1 * p21 + t2 * p22 + g0 * r20 + g1 * r21 + g2 * r22
        X[r, 0], X[r, 1], X[r, 2] = x0, x1, x2
        if iv >= 0:
            X[r, 3] = M[r, 3] + (f00 * x0 + f01 * x1 + f02 * x2)
            X[r, 4] = M[r, 4] + (f10 * x0 + f11 * x1 + f12 * x2)
            X[r, 5] = M[r, 5] + (f20 * x0 + f21 * x1 + f22 * x2)
            if iba >= 0:
                g0, g1, g2 = M[r, iba], M[r, iba + 1], M[r, iba + 2]
                X[r, 3] += d00 * g0 + d01 * g1 + d02 * g2
                X[r, 4] += d10 * g0 + d11 * g1 + d12 * g2
                X[r, 5] += d20 * g0 + d21 * g1 + d22 * g2
    # write back, exactly symmetric; the rest of P is unchanged (Phi is the identity there)
    for j in range(na, n):
        m0, m1, m2 = M[0, j], M[1, j], M[2, j]
        P[0, j], P[1, j], P[2, j] = m0, m1, m2
        P[j, 0], P[j, 1], P[j, 2] = m0, m1, m2
        if na == 6:
            m0, m1, m2 = M[3, j], M[4, j], M[5, j]
            P[3, j], P[4, j], P[5, j] = m0, m1, m2
            P[j, 3], P[j, 4], P[j, 5] = m0, m1, m2
    for r in range(na):
        for c in range(r, na):
            v = 0.5 * (X[r, c] + X[c, r])
            P[r, c] = v
            P[c, r] = v
    # process noise
    sg2, sb2 = prm[R_SG2], prm[R_SB2]
    if prm[R_SCALE2] > 0:  # rate-proportional gyro noise
        sg2 = sg2 + prm[R_SCALE2] * (wx * wx + wy * wy + wz * wz)
    qaa = sg2 * dt + sb2 * dt**3 / 3.0
    qab = -sb2 * dt**2 / 2.0
    qbb = sb2 * dt
    for k in range(3):
        P[k, k] += qaa
        P[k, ib + k] += qab
        P[ib + k, k] += qab
        P[ib + k, ib + k] += qbb
        if iv >= 0:
            P[iv + k, iv + k] += prm[R_SA2] * dt
        if iba >= 0:
            P[iba + k, iba + k] += prm[R_SBA2] * dt
        if cfg[C_IBM] >= 0:
            P[cfg[C_IBM] + k, cfg[C_IBM] + k] += prm[R_SBM2] * dt
    if iw >= 0:
        P[iw, iw] += prm[R_WH2] * dt
        P[iw + 1, iw + 1] += prm[R_WH2] * dt
        P[iw + 2, iw + 2] += prm[R_WV2] * dt


@njit(**_JIT)
def _normalise_add(cfg, x, P, work, q0, q1, q2, q3):
    """Ekf7Streamer._normalise: q <- q/|q| (w >= 0), P <- J P J^T, symmetrised."""
    M, X = work[W_M : W_M + 8], work[W_X : W_X + 8]
    n = cfg[C_N]
    nq = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    u = work[W_DX]  # (free here: any correction was applied before)
    u[0], u[1], u[2], u[3] = q0 / nq, q1 / nq, q2 / nq, q3 / nq
    sign = -1.0 if u[0] < 0.0 else 1.0
    # J = +-(I - u u^T)/|q| in X[4:8, 0:4]
    for r in range(4):
        for c in range(4):
            eye = 1.0 if r == c else 0.0
            X[4 + r, c] = sign * ((eye - u[r] * u[c]) / nq)
    # M[0:4] = J P[0:4, :]
    for r in range(4):
        j0, j1, j2, j3 = X[4 + r, 0], X[4 + r, 1], X[4 + r, 2], X[4 + r, 3]
        for j in range(NMAX):
            M[r, j] = j0 * P[0, j] + j1 * P[1, j] + j2 * P[2, j] + j3 * P[3, j]
    for r in range(4):
        for c in range(4):
            X[r, c] = (
                M[r, 0] * X[4 + c, 0]
                + M[r, 1] * X[4 + c, 1]
                + M[r, 2] * X[4 + c, 2]
                + (M[r, 3] * X[4 + c, 3])
            )
    for r in range(4):
        for j in range(4, n):
            P[r, j] = M[r, j]
            P[j, r] = M[r, j]
        for c in range(r, 4):
            v = 0.5 * (X[r, c] + X[c, r])
            P[r, c] = v
            P[c, r] = v
    x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = sign * u[0], sign * u[1], sign * u[2], sign * u[3]


@njit(**_JIT_FMA)
def _predict_add(cfg, prm, x, P, work, wmx, wmy, wmz, dt):
    """Ekf7Streamer._predict: F = [[Phi4, -(dt/2) Xi(q_k) J_r], [0, I]], Q of SPEC 2.3."""
    M, X, Xi = work[W_M : W_M + 4], work[W_X : W_X + 8], work[W_M + 4 : W_M + 8]
    Jr, K = work[W_T : W_T + 3, 0:3], work[W_T + 3 : W_T + 6, 0:3]
    Fqb = work[W_T + 6 : W_T + 10, 0:3]  # 4x3 (borrows a row of the next matrix)
    n = cfg[C_N]
    ib = cfg[C_IBG] + 1
    iw = cfg[C_IW] + 1 if cfg[C_IW] >= 0 else -1
    dx, dy, dz = (wmx - x[X_BG]) * dt, (wmy - x[X_BG + 1]) * dt, (wmz - x[X_BG + 2]) * dt
    a = math.sqrt(dx * dx + dy * dy + dz * dz)
    s = 0.5 * _sinc(a / (2.0 * math.pi))
    ch = math.cos(0.5 * a)
    # Phi4 = cos(a/2) I + s Omega(d), in X[4:8, 0:4]
    X[4, 0], X[4, 1], X[4, 2], X[4, 3] = ch, -s * dx, -s * dy, -s * dz
    X[5, 0], X[5, 1], X[5, 2], X[5, 3] = s * dx, ch, s * dz, -s * dy
    X[6, 0], X[6, 1], X[6, 2], X[6, 3] = s * dy, -s * dz, ch, s * dx
    X[7, 0], X[7, 1], X[7, 2], X[7, 3] = s * dz, s * dy, -s * dx, ch
    p0, p1, p2, p3 = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
    qk = (
        X[4, 0] * p0 + X[4, 1] * p1 + X[4, 2] * p2 + X[4, 3] * p3,
        X[5, 0] * p0 + X[5, 1] * p1 + X[5, 2] * p2 + X[5, 3] * p3,
        X[6, 0] * p0 + X[6, 1] * p1 + X[6, 2] * p2 + X[6, 3] * p3,
        X[7, 0] * p0 + X[7, 1] * p1 + X[7, 2] * p2 + X[7, 3] * p3,
    )
    # right Jacobian of the increment (rotation.right_jacobian)
    if a < 1e-5:
        c1 = 0.5 - a**2 / 24.0
        c2 = 1.0 / 6.0 - a**2 / 120.0
    else:
        c1 = (1.0 - math.cos(a)) / a**2
        c2 = (a - math.sin(a)) / a**3
    K[0, 0], K[0, 1], K[0, 2] = 0.0, -dz, dy
    K[1, 0], K[1, 1], K[1, 2] = dz, 0.0, -dx
    K[2, 0], K[2, 1], K[2, 2] = -dy, dx, 0.0
    for r in range(3):
        for c in range(3):
            k2 = K[r, 0] * K[0, c] + K[r, 1] * K[1, c] + K[r, 2] * K[2, c]
            Jr[r, c] = (1.0 if r == c else 0.0) - c1 * K[r, c] + c2 * k2
    _xi_into(qk[0], qk[1], qk[2], qk[3], Xi)
    h = -0.5 * dt
    for r in range(4):
        for c in range(3):
            Fqb[r, c] = h * Xi[r, 0] * Jr[0, c] + h * Xi[r, 1] * Jr[1, c] + h * Xi[r, 2] * Jr[2, c]
    # M = quaternion rows of F P
    for r in range(4):
        f0, f1, f2, f3 = X[4 + r, 0], X[4 + r, 1], X[4 + r, 2], X[4 + r, 3]
        g0, g1, g2 = Fqb[r, 0], Fqb[r, 1], Fqb[r, 2]
        for j in range(NMAX):
            M[r, j] = (
                f0 * P[0, j] + f1 * P[1, j] + f2 * P[2, j] + f3 * P[3, j]
                + g0 * P[ib, j] + g1 * P[ib + 1, j] + g2 * P[ib + 2, j]
            )  # fmt: skip
    for r in range(4):
        for c in range(4):
            v = 0.0
            for k in range(4):
                v += M[r, k] * X[4 + c, k]
            for k in range(3):
                v += M[r, ib + k] * Fqb[c, k]
            X[r, c] = v
    for r in range(4):
        for j in range(4, n):
            P[r, j] = M[r, j]
            P[j, r] = M[r, j]
        for c in range(4):
            P[r, c] = X[r, c]
    # process noise (ekf7_process_noise at q_k; wind random walk)
    sg2, sb2 = prm[R_SG2], prm[R_SB2]
    cqq = sg2 * dt / 4.0 + sb2 * dt**3 / 12.0
    cqb = -sb2 * dt**2 / 4.0
    for r in range(4):
        for c in range(4):
            P[r, c] += cqq * (Xi[r, 0] * Xi[c, 0] + Xi[r, 1] * Xi[c, 1] + Xi[r, 2] * Xi[c, 2])
        for k in range(3):
            P[r, ib + k] += cqb * Xi[r, k]
            P[ib + k, r] += cqb * Xi[r, k]
    for k in range(3):
        P[ib + k, ib + k] += sb2 * dt
    if iw >= 0:
        P[iw, iw] += prm[R_WH2] * dt
        P[iw + 1, iw + 1] += prm[R_WH2] * dt
        P[iw + 2, iw + 2] += prm[R_WV2] * dt
    _normalise_add(cfg, x, P, work, qk[0], qk[1], qk[2], qk[3])


# --- update -------------------------------------------------------------------------------


@njit(**_JIT)
def _inverse_small(S, Si, m):
    """Si = S^-1 for m = 1 or 3 (cofactors; S is a well-conditioned innovation covariance)."""
    if m == 1:
        Si[0, 0] = 1.0 / S[0, 0]
        return
    a, b, c = S[0, 0], S[0, 1], S[0, 2]
    d, e, f = S[1, 0], S[1, 1], S[1, 2]
    g, h, i = S[2, 0], S[2, 1], S[2, 2]
    A, B, C = e * i - f * h, f * g - d * i, d * h - e * g
    r = 1.0 / (a * A + b * B + c * C)
    Si[0, 0], Si[0, 1], Si[0, 2] = A * r, (c * h - b * i) * r, (b * f - c * e) * r
    Si[1, 0], Si[1, 1], Si[1, 2] = B * r, (a * i - c * g) * r, (c * d - a * f) * r
    Si[2, 0], Si[2, 1], Si[2, 2] = C * r, (b * g - a * h) * r, (a * e - b * d) * r


@njit(**_JIT)
def _fuse(cfg, x, flags, P, work, sups, inn, acc, sensor, t, m, nsup, gate2):
    """EskfStreamer._fuse / Ekf7Streamer._fuse: NIS, gate, log, Joseph update, injection.

    The measurement: nu = work[W_NU, :m], R = work[W_R:W_R+m, :m], H = work[W_H:W_H+m]
    on the error-state columns sup[0, :nsup] (the attitude columns 0..2 always written);
    m is 1 or 3. Returns whether the update was accepted.

    Loops run over whole padded rows of P (constant length NMAX) with every row of the
    measurement in one pass, which lets the compiler vectorise them."""
    n = cfg[C_N]
    H, sup = work[W_H : W_H + 3], sups[0]
    Hm, cols, nc = H, sup, nsup
    if cfg[C_ADD] == 1:
        Hq = work[W_HQ : W_HQ + 3]
        cols = sups[1]
        q0, q1, q2, q3 = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
        for k in range(m):  # 2 H_att Xi(q)^T
            h0, h1, h2 = 2.0 * H[k, 0], 2.0 * H[k, 1], 2.0 * H[k, 2]
            Hq[k, 0] = -h0 * q1 - h1 * q2 - h2 * q3
            Hq[k, 1] = h0 * q0 - h1 * q3 + h2 * q2
            Hq[k, 2] = h0 * q3 + h1 * q0 - h2 * q1
            Hq[k, 3] = -h0 * q2 + h1 * q1 + h2 * q0
        for c in range(4):
            cols[c] = c
        nc = 4
        for ci in range(nsup):
            c = sup[ci]
            if c >= 3:
                cols[nc] = c + 1
                nc += 1
                for k in range(m):
                    Hq[k, c + 1] = H[k, c]
        Hm = Hq
    U, Kt, Gt = work[W_U : W_U + 3], work[W_K : W_K + 3], work[W_G : W_G + 3]
    R, S, Si = work[W_R : W_R + 3], work[W_S : W_S + 3], work[W_SI : W_SI + 3]
    nu, dx = work[W_NU], work[W_DX]
    # U = H P, whole padded rows (P is exactly symmetric, so U^T = P H^T exactly)
    for k in range(m):
        for j in range(NMAX):
            U[k, j] = 0.0
    for ci in range(nc):
        c = cols[ci]
        if m == 3:
            h0, h1, h2 = Hm[0, c], Hm[1, c], Hm[2, c]
            for j in range(NMAX):
                p = P[c, j]
                U[0, j] += h0 * p
                U[1, j] += h1 * p
                U[2, j] += h2 * p
        else:
            h0 = Hm[0, c]
            for j in range(NMAX):
                U[0, j] += h0 * P[c, j]
    for k in range(m):
        for l in range(m):
            s = 0.0
            for ci in range(nc):
                c = cols[ci]
                s += Hm[k, c] * U[l, c]
            S[k, l] = s + R[k, l]
    _inverse_small(S, Si, m)
    # NIS, gate (each component within gate sigmas), log
    nis = 0.0
    bad = 0
    for k in range(m):
        v = 0.0
        for l in range(m):
            v += Si[k, l] * nu[l]
        nis += nu[k] * v
        if not (nu[k] * nu[k] <= gate2 * S[k, k]):
            bad += 1
    accepted = bad == 0
    _log(cfg, flags, inn, acc, nu, sensor, t, m, nis, accepted)
    if not accepted:
        return False
    # K^T = S^-1 H P; Joseph form expanded: P - K U^T - U K^T + K S K^T = P + K G^T + G K^T
    # with G = K S / 2 - U^T. Each entry adds K_ik G_jk + G_ik K_jk in the same order as
    # its mirror entry, so P stays exactly symmetric in floating point.
    if m == 3:
        i00, i01, i02, i10, i11, i12 = Si[0, 0], Si[0, 1], Si[0, 2], Si[1, 0], Si[1, 1], Si[1, 2]
        i20, i21, i22 = Si[2, 0], Si[2, 1], Si[2, 2]
        s00, s01, s02, s10, s11, s12 = S[0, 0], S[0, 1], S[0, 2], S[1, 0], S[1, 1], S[1, 2]
        s20, s21, s22 = S[2, 0], S[2, 1], S[2, 2]
        n0, n1, n2 = nu[0], nu[1], nu[2]
        for j in range(NMAX):
            u0, u1, u2 = U[0, j], U[1, j], U[2, j]
            k0 = i00 * u0 + i01 * u1 + i02 * u2
            k1 = i10 * u0 + i11 * u1 + i12 * u2
            k2 = i20 * u0 + i21 * u1 + i22 * u2
            Kt[0, j], Kt[1, j], Kt[2, j] = k0, k1, k2
            dx[j] = k0 * n0 + k1 * n1 + k2 * n2  # K nu
            Gt[0, j] = 0.5 * (s00 * k0 + s10 * k1 + s20 * k2) - u0
            Gt[1, j] = 0.5 * (s01 * k0 + s11 * k1 + s21 * k2) - u1
            Gt[2, j] = 0.5 * (s02 * k0 + s12 * k1 + s22 * k2) - u2
        for i in range(n):
            a0, b0, a1, b1, a2, b2 = Kt[0, i], Gt[0, i], Kt[1, i], Gt[1, i], Kt[2, i], Gt[2, i]
            for j in range(NMAX):
                P[i, j] = ((P[i, j] + (a0 * Gt[0, j] + b0 * Kt[0, j])) + (a1 * Gt[1, j] + b1 * Kt[1, j])) + (
                    a2 * Gt[2, j] + b2 * Kt[2, j]
                )
    else:
        i00, s00, n0 = Si[0, 0], S[0, 0], nu[0]
        for j in range(NMAX):
            k0 = i00 * U[0, j]
            Kt[0, j] = k0
            dx[j] = k0 * n0
            Gt[0, j] = 0.5 * (s00 * k0) - U[0, j]
        for i in range(n):
            a0, b0 = Kt[0, i], Gt[0, i]
            for j in range(NMAX):
                P[i, j] = P[i, j] + (a0 * Gt[0, j] + b0 * Kt[0, j])
    ib, iv, iw, iba = cfg[C_IBG], cfg[C_IV], cfg[C_IW], cfg[C_IBA]
    if cfg[C_ADD] == 1:
        for a in range(3):
            x[X_BG + a] += dx[ib + 1 + a]
            if iw >= 0:
                x[X_W + a] += dx[iw + 1 + a]
        _normalise_add(
            cfg, x, P, work, x[X_Q] + dx[0], x[X_Q + 1] + dx[1], x[X_Q + 2] + dx[2], x[X_Q + 3] + dx[3]
        )
    else:
        e = _qexp(dx[0], dx[1], dx[2])
        q = _qmul(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], e[0], e[1], e[2], e[3])
        x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = _qnormalize(q[0], q[1], q[2], q[3])
        for a in range(3):
            x[X_BG + a] += dx[ib + a]
            if iv >= 0:
                x[X_V + a] += dx[iv + a]
            if iw >= 0:
                x[X_W + a] += dx[iw + a]
            if iba >= 0:
                x[X_BA + a] += dx[iba + a]
            if cfg[C_IBM] >= 0:
                x[X_BM + a] += dx[cfg[C_IBM] + a]
    return True


@njit(**_JIT)
def _vector_rows(work, sup, y0, y1, y2, var):
    """A 3-row measurement with H_att = [y]x and R = var I (accelerometer, magnetometer);
    sup: the support row."""
    H, R = work[W_H : W_H + 3], work[W_R : W_R + 3]
    H[0, 0], H[0, 1], H[0, 2] = 0.0, -y2, y1
    H[1, 0], H[1, 1], H[1, 2] = y2, 0.0, -y0
    H[2, 0], H[2, 1], H[2, 2] = -y1, y0, 0.0
    for k in range(3):
        sup[k] = k
        for l in range(3):
            R[k, l] = var if k == l else 0.0


# --- event steps --------------------------------------------------------------------------


@njit(inline="always", **_JIT)
def step_imu(cfg, prm, x, flags, P, work, sup, inn, acc, t, row):
    """An IMU sample (finite): row = [w_b (3) rad/s, f_b (3) m/s^2], at t s
    (EskfStreamer._imu and _fuse_accel)."""
    fx, fy, fz = row[3], row[4], row[5]
    x[X_FLAST], x[X_FLAST + 1], x[X_FLAST + 2] = fx, fy, fz
    flags[S_FLAST] = 1
    if flags[S_INIT] == 0:
        _try_init(cfg, prm, x, flags, P, work)
        x[X_TIMU] = t
        return
    dt = t - x[X_TIMU]
    x[X_TIMU] = t
    if dt > 0:
        if flags[S_FBAR] == 1 or flags[S_MBAR] == 1:
            _rotate_lowpass(x, flags, row[0] - x[X_BG], row[1] - x[X_BG + 1], row[2] - x[X_BG + 2], dt)
        if cfg[C_ADD] == 1:
            _predict_add(cfg, prm, x, P, work, row[0], row[1], row[2], dt)
        else:
            _predict_es(cfg, prm, x, P, work, row[0], row[1], row[2], fx, fy, fz, dt)
    if cfg[C_KIND] == KIND_INS:
        return
    # the accelerometer as a gravity measurement (or its low-passed mean), gated on |f|
    nu = work[W_NU]
    g = prm[R_GRAV]
    c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    k0, k1, k2 = 0.0, 0.0, 0.0  # compensation acceleration, body
    comp = cfg[C_COMP]
    has_k = False
    if comp == COMP_AIRSPEED and flags[S_VAIR] == 1:  # (w - bg) x V_air
        ux, uy, uz = row[0] - x[X_BG], row[1] - x[X_BG + 1], row[2] - x[X_BG + 2]
        vx, vy, vz = x[X_VAIR], x[X_VAIR + 1], x[X_VAIR + 2]
        k0, k1, k2 = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        has_k = True
    elif comp == COMP_GNSS and flags[S_AGNSS] == 1:  # C_bn a_gnss
        ax, ay, az = x[X_AGNSS], x[X_AGNSS + 1], x[X_AGNSS + 2]
        k0 = c[0] * ax + c[3] * ay + c[6] * az
        k1 = c[1] * ax + c[4] * ay + c[7] * az
        k2 = c[2] * ax + c[5] * ay + c[8] * az
        has_k = True
    if flags[S_FBAR] == 1:  # the mean of the compensated specific force, no compensation after
        a = _lowpass_gain(dt, prm[R_ACC_LP])
        if has_k:
            fx, fy, fz = fx - k0, fy - k1, fz - k2
        x[X_FBAR] = x[X_FBAR] + a * (fx - x[X_FBAR])
        x[X_FBAR + 1] = x[X_FBAR + 1] + a * (fy - x[X_FBAR + 1])
        x[X_FBAR + 2] = x[X_FBAR + 2] + a * (fz - x[X_FBAR + 2])
        fx, fy, fz = x[X_FBAR], x[X_FBAR + 1], x[X_FBAR + 2]
        has_k = False
    if abs(math.sqrt(fx * fx + fy * fy + fz * fz) - g) > prm[R_NORM_GATE] * g:
        nu[0], nu[1], nu[2] = np.nan, np.nan, np.nan
        _log(cfg, flags, inn, acc, nu, np.int64(INN_ACCEL), t, np.int64(3), np.nan, np.bool_(False))
        return
    y0, y1, y2 = c[6] * -g, c[7] * -g, c[8] * -g  # C_bn (-g_n)
    h0, h1, h2 = y0, y1, y2
    if has_k:
        h0, h1, h2 = y0 + k0, y1 + k1, y2 + k2
    _vector_rows(work, sup[0], y0, y1, y2, prm[R_ACC_VAR])
    nsup = 3
    iba = cfg[C_IBA]
    if iba >= 0:  # (no accelerometer fusion in the INS; kept for the general model)
        h0, h1, h2 = h0 + x[X_BA], h1 + x[X_BA + 1], h2 + x[X_BA + 2]
        for k in range(3):
            for a in range(3):
                work[W_H + k, iba + a] = 1.0 if k == a else 0.0
            sup[0, 3 + k] = iba + k
        nsup = 6
    nu[0], nu[1], nu[2] = fx - h0, fy - h1, fz - h2
    sensor, m, ns = np.int64(INN_ACCEL), np.int64(3), np.int64(nsup)
    _fuse(cfg, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, prm[R_GATE2_ACC])


@njit(inline="always", **_JIT)
def step_mag(cfg, prm, x, flags, P, work, sup, inn, acc, t, row):
    """A magnetometer sample (finite): row[:3] tesla, body, at t s (EskfStreamer._mag)."""
    mx, my, mz = row[0], row[1], row[2]
    if flags[S_INIT] == 0:
        if flags[S_FMAG] == 0:
            x[X_FMAG], x[X_FMAG + 1], x[X_FMAG + 2] = mx, my, mz
            flags[S_FMAG] = 1
        _try_init(cfg, prm, x, flags, P, work)
        return
    mode = cfg[C_MAG]
    if mode == MAG_OFF:
        return
    if flags[S_MAGN] == 0:
        _set_mag_reference(cfg, prm, x, flags, mx, my, mz)
    rx, ry, rz = x[X_MAGN], x[X_MAGN + 1], x[X_MAGN + 2]
    nu = work[W_NU]
    if prm[R_MAG_LP] > 0:  # fuse the low-passed field
        if flags[S_MBAR] == 0:
            x[X_MBAR], x[X_MBAR + 1], x[X_MBAR + 2] = mx, my, mz
            flags[S_MBAR] = 1
        else:
            a = _lowpass_gain(t - x[X_TMBAR], prm[R_MAG_LP])
            x[X_MBAR] = x[X_MBAR] + a * (mx - x[X_MBAR])
            x[X_MBAR + 1] = x[X_MBAR + 1] + a * (my - x[X_MBAR + 1])
            x[X_MBAR + 2] = x[X_MBAR + 2] + a * (mz - x[X_MBAR + 2])
        x[X_TMBAR] = t
        mx, my, mz = x[X_MBAR], x[X_MBAR + 1], x[X_MBAR + 2]
    if (prm[R_MAG_NGATE] > 0 or prm[R_MAG_DGATE] > 0) and _mag_disturbed(prm, x, cfg, mx, my, mz, rx, ry, rz):
        nu[0], nu[1], nu[2] = np.nan, np.nan, np.nan
        md = np.int64(3) if mode == MAG_3D else np.int64(1)
        _log(cfg, flags, inn, acc, nu, np.int64(INN_MAG), t, md, np.nan, np.bool_(False))
        return
    if mode == MAG_3D:
        c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
        y0 = c[0] * rx + c[3] * ry + c[6] * rz
        y1 = c[1] * rx + c[4] * ry + c[7] * rz
        y2 = c[2] * rx + c[5] * ry + c[8] * rz
        _vector_rows(work, sup[0], y0, y1, y2, prm[R_MAG_VAR])
        nsup = 3
        h0, h1, h2 = y0, y1, y2
        ibm = cfg[C_IBM]
        if ibm >= 0:  # + bm, H_bm = I
            h0, h1, h2 = y0 + x[X_BM], y1 + x[X_BM + 1], y2 + x[X_BM + 2]
            for k in range(3):
                for a in range(3):
                    work[W_H + k, ibm + a] = 1.0 if k == a else 0.0
                sup[0, 3 + k] = ibm + k
            nsup = 6
        nu[0], nu[1], nu[2] = mx - h0, my - h1, mz - h2
        sensor, m, ns = np.int64(INN_MAG), np.int64(3), np.int64(nsup)
        _fuse(cfg, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, prm[R_GATE2_MAG])
        return
    sigma = prm[R_MAG_SIGMA] / max(math.hypot(rx, ry), 1e-9)
    if cfg[C_HVERT] == 1:
        # the field's heading in the nav frame against the reference's, corrected about
        # the nav vertical only: H_att = third row of C_nb
        c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
        n0 = c[0] * mx + c[1] * my + c[2] * mz
        n1 = c[3] * mx + c[4] * my + c[5] * mz
        nu[0] = _wrap_pi(math.atan2(ry, rx) - math.atan2(n1, n0))
        work[W_H, 0], work[W_H, 1], work[W_H, 2] = c[6], c[7], c[8]
        sup[0, 0], sup[0, 1], sup[0, 2] = 0, 1, 2
        work[W_R, 0] = sigma**2
        sensor, m, ns = np.int64(INN_MAG), np.int64(1), np.int64(3)
        _fuse(cfg, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, prm[R_GATE2_MAG])
        return
    # heading only (ZYX yaw): tilt-compensate with the current roll/pitch estimate
    roll, pitch, yaw = _euler(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    ql = _quat_from_euler(roll, pitch, 0.0)
    c = _dcm9(ql[0], ql[1], ql[2], ql[3])
    m0 = c[0] * mx + c[1] * my + c[2] * mz
    m1 = c[3] * mx + c[4] * my + c[5] * mz
    psi_m = math.atan2(ry, rx) - math.atan2(m1, m0)
    nu[0] = _wrap_pi(psi_m - yaw)
    cp = math.cos(pitch)
    work[W_H, 0], work[W_H, 1], work[W_H, 2] = 0.0, math.sin(roll) / cp, math.cos(roll) / cp
    sup[0, 0], sup[0, 1], sup[0, 2] = 0, 1, 2
    work[W_R, 0] = sigma**2
    sensor, m, ns = np.int64(INN_MAG), np.int64(1), np.int64(3)
    _fuse(cfg, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, prm[R_GATE2_MAG])


@njit(inline="always", **_JIT)
def step_gnss(cfg, prm, x, flags, P, work, sup, inn, acc, t, row):
    """A GNSS velocity sample (finite): row[:3] m/s NED, at t s (EskfStreamer._gnss)."""
    if flags[S_VGNSS] == 1 and t > x[X_TGNSS]:
        dt = t - x[X_TGNSS]
        for a in range(3):
            x[X_AGNSS + a] = (row[a] - x[X_VGNSS + a]) / dt
        flags[S_AGNSS] = 1
    for a in range(3):
        x[X_VGNSS + a] = row[a]
    x[X_TGNSS] = t
    flags[S_VGNSS] = 1
    if flags[S_INIT] == 0:
        if flags[S_FV] == 0:
            for a in range(3):
                x[X_FV + a] = row[a]
            flags[S_FV] = 1
        _try_init(cfg, prm, x, flags, P, work)
        return
    if cfg[C_KIND] == KIND_INS:
        iv = cfg[C_IV]
        H, R = work[W_H : W_H + 3], work[W_R : W_R + 3]
        for k in range(3):
            H[k, 0], H[k, 1], H[k, 2] = 0.0, 0.0, 0.0
            for a in range(3):
                H[k, iv + a] = 1.0 if k == a else 0.0
                R[k, a] = prm[R_GNSS_VAR] if k == a else 0.0
            sup[0, k] = iv + k
            work[W_NU, k] = row[k] - x[X_V + k]
        sensor, m, ns = np.int64(INN_GNSS), np.int64(3), np.int64(3)
        _fuse(cfg, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, prm[R_GATE2_GNSS])


@njit(**_JIT)
def _air_rows(cfg, x, work, sup, use_state_v, g0, g1, g2, row):
    """observations._air_b: returns y = C_bn (v - wind) (v: the velocity state or the
    last GNSS velocity) and writes row ``row`` of H as g^T J, J = d y / d(error) =
    [[y]x, -C_bn (wind), C_bn (velocity)]; sets the support; returns (y, support size)."""
    c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    vv = X_V if use_state_v else X_VGNSS
    dx, dy, dz = x[vv] - x[X_W], x[vv + 1] - x[X_W + 1], x[vv + 2] - x[X_W + 2]
    y0 = c[0] * dx + c[3] * dy + c[6] * dz
    y1 = c[1] * dx + c[4] * dy + c[7] * dz
    y2 = c[2] * dx + c[5] * dy + c[8] * dz
    H = work[W_H : W_H + 3]
    iv, iw = cfg[C_IV], cfg[C_IW]
    H[row, 0] = g1 * y2 - g2 * y1
    H[row, 1] = g2 * y0 - g0 * y2
    H[row, 2] = g0 * y1 - g1 * y0
    gc = (
        g0 * c[0] + g1 * c[1] + g2 * c[2],
        g0 * c[3] + g1 * c[4] + g2 * c[5],
        g0 * c[6] + g1 * c[7] + g2 * c[8],
    )
    H[row, iw], H[row, iw + 1], H[row, iw + 2] = -gc[0], -gc[1], -gc[2]  # g^T (-C_bn)
    sup[0], sup[1], sup[2], sup[3], sup[4], sup[5] = 0, 1, 2, iw, iw + 1, iw + 2
    if iv < 0:
        return y0, y1, y2, np.int64(6)
    H[row, iv], H[row, iv + 1], H[row, iv + 2] = gc
    sup[6], sup[7], sup[8] = iv, iv + 1, iv + 2
    return y0, y1, y2, np.int64(9)


@njit(inline="always", **_JIT)
def step_air(cfg, prm, x, flags, P, work, sup, inn, acc, t, tas, aoa, beta):
    """An air-data sample: tas m/s (finite), aoa and sideslip rad (NaN: no vanes), at t s
    (EskfStreamer._air and _init_wind)."""
    vanes = math.isfinite(aoa) and math.isfinite(beta)
    ca = cb = sa = sb = 0.0
    if vanes:
        ca, sa, cb, sb = math.cos(aoa), math.sin(aoa), math.cos(beta), math.sin(beta)
        x[X_VAIR], x[X_VAIR + 1], x[X_VAIR + 2] = tas * (ca * cb), tas * sb, tas * (sa * cb)
    else:
        x[X_VAIR], x[X_VAIR + 1], x[X_VAIR + 2] = tas, 0.0, 0.0
    flags[S_VAIR] = 1
    kind = cfg[C_KIND]
    if flags[S_INIT] == 0 or kind == KIND_MEKF or cfg[C_AIR] == AIR_OFF:
        return
    extra = 0.0
    if kind == KIND_MEKF_AIR:  # GNSS velocity as an input
        if flags[S_VGNSS] == 0:
            return
        extra = prm[R_GNSS_VAR]
    use_v = cfg[C_IV] >= 0
    if flags[S_WPEND] == 1:  # wind from the first air sample: W = V - C_nb V_air
        c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
        vv = X_V if use_v else X_VGNSS
        ax, ay, az = x[X_VAIR], x[X_VAIR + 1], x[X_VAIR + 2]
        x[X_W] = x[vv] - (c[0] * ax + c[1] * ay + c[2] * az)
        x[X_W + 1] = x[vv + 1] - (c[3] * ax + c[4] * ay + c[5] * az)
        x[X_W + 2] = x[vv + 2] - (c[6] * ax + c[7] * ay + c[8] * az) if vanes else 0.0
        flags[S_WPEND] = 0
    mode = cfg[C_AIR]
    if mode == AIR_AUTO:
        mode = AIR_VECTOR if vanes else AIR_AIRSPEED
    nu, R = work[W_NU], work[W_R : W_R + 3]
    gate2 = prm[R_GATE2_AIR]
    if mode == AIR_VECTOR and vanes:
        ns = np.int64(0)
        y0 = y1 = y2 = 0.0
        for k in range(3):  # g = e_k: row k of J
            e0, e1, e2 = 1.0 if k == 0 else 0.0, 1.0 if k == 1 else 0.0, 1.0 if k == 2 else 0.0
            y0, y1, y2, ns = _air_rows(cfg, x, work, sup[0], use_v, e0, e1, e2, np.int64(k))
        nu[0], nu[1], nu[2] = x[X_VAIR] - y0, x[X_VAIR + 1] - y1, x[X_VAIR + 2] - y2
        # R = J diag(tas^2, vane^2, vane^2) J^T + extra I, J = d V_air / d(tas, aoa, beta)
        J = work[W_T + 21 : W_T + 24, 0:3]
        J[0, 0], J[0, 1], J[0, 2] = ca * cb, -tas * sa * cb, -tas * ca * sb
        J[1, 0], J[1, 1], J[1, 2] = sb, 0.0, tas * cb
        J[2, 0], J[2, 1], J[2, 2] = sa * cb, tas * ca * cb, -tas * sa * sb
        d0, d1 = prm[R_TAS_VAR], prm[R_VANE_VAR]
        for k in range(3):
            for l in range(3):
                r = J[k, 0] * d0 * J[l, 0] + J[k, 1] * d1 * J[l, 1] + J[k, 2] * d1 * J[l, 2]
                R[k, l] = r + extra if k == l else r
        _fuse(cfg, x, flags, P, work, sup, inn, acc, np.int64(INN_AIR), t, np.int64(3), ns, gate2)
        return
    # true airspeed (no attitude information: H_att = 0) ...
    y0, y1, y2, ns = _air_rows(cfg, x, work, sup[0], use_v, 0.0, 0.0, 0.0, np.int64(0))
    a = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    den = max(a, 1e-9)
    y0, y1, y2, ns = _air_rows(cfg, x, work, sup[0], use_v, y0 / den, y1 / den, y2 / den, np.int64(0))
    work[W_H, 0], work[W_H, 1], work[W_H, 2] = 0.0, 0.0, 0.0
    nu[0] = tas - a
    R[0, 0] = prm[R_TAS_VAR] + extra
    _fuse(cfg, x, flags, P, work, sup, inn, acc, np.int64(INN_TAS), t, np.int64(1), ns, gate2)
    # ... and the synthetic zero sideslip, at the state after the airspeed update
    if cfg[C_SYN] == 1:
        y0, y1, y2, ns = _air_rows(cfg, x, work, sup[0], use_v, 0.0, 0.0, 0.0, np.int64(0))
        u = y0 if abs(y0) > 1e-3 else math.copysign(1e-3, y0)
        y0, y1, y2, ns = _air_rows(cfg, x, work, sup[0], use_v, -y1 / u**2, 1.0 / u, 0.0, np.int64(0))
        nu[0] = -(y1 / u)
        R[0, 0] = prm[R_BETA_VAR] + extra / max(tas, 1.0) ** 2
        _fuse(cfg, x, flags, P, work, sup, inn, acc, np.int64(INN_SIDESLIP), t, np.int64(1), ns, gate2)


# --- recording and the batch loop ---------------------------------------------------------


@njit(inline="always", **_JIT)
def record(cfg, x, flags, P, work, k, out_q, out_bg, out_v, out_w, out_cov):
    """The current state (EskfStreamer.state) into row k of the outputs: q (N, 4), bias
    (N, 3), velocity and wind (N, 3) (written only when in the layout), tangent-space
    covariance (N, d, d) (additive: T P T^T, T = blkdiag(2 Xi(q)^T, I))."""
    d = cfg[C_DIM]
    iv, iw = cfg[C_IV], cfg[C_IW]
    if flags[S_INIT] == 0:
        q = (1.0, 0.0, 0.0, 0.0)
        if flags[S_FLAST] == 1:
            no = np.bool_(False)
            q = _triad(x[X_FLAST], x[X_FLAST + 1], x[X_FLAST + 2], no, 0.0, 0.0, 0.0, no, 0.0, 0.0, 0.0)
        out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = q
        for a in range(3):
            out_bg[k, a] = 0.0
            if iv >= 0:
                out_v[k, a] = np.nan
            if iw >= 0:
                out_w[k, a] = np.nan
        for i in range(d):
            for j in range(d):
                out_cov[k, i, j] = np.nan
        return
    # (the covariance first, then the vectors, loaded before they are stored: measurably
    # faster code)
    if cfg[C_ADD] == 0:
        for i in range(d):
            for j in range(d):
                out_cov[k, i, j] = P[i, j]
    else:
        _record_tangent_cov(cfg, x, P, work, k, out_cov)
    q0, q1, q2, q3 = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
    b0, b1, b2 = x[X_BG], x[X_BG + 1], x[X_BG + 2]
    out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = q0, q1, q2, q3
    out_bg[k, 0], out_bg[k, 1], out_bg[k, 2] = b0, b1, b2
    if iv >= 0:
        out_v[k, 0], out_v[k, 1], out_v[k, 2] = x[X_V], x[X_V + 1], x[X_V + 2]
    if iw >= 0:
        out_w[k, 0], out_w[k, 1], out_w[k, 2] = x[X_W], x[X_W + 1], x[X_W + 2]


@njit(**_JIT)
def _record_tangent_cov(cfg, x, P, work, k, out_cov):
    """Ekf7Streamer._tangent_cov into out_cov[k]: T P T^T, T = blkdiag(2 Xi(q)^T, I)."""
    Xi = work[W_M + 4 : W_M + 8]
    _xi_into(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], Xi)
    n = cfg[C_N]
    for r in range(3):
        for j in range(4, n):
            v = (
                2.0 * Xi[0, r] * P[0, j]
                + 2.0 * Xi[1, r] * P[1, j]
                + 2.0 * Xi[2, r] * P[2, j]
                + (2.0 * Xi[3, r] * P[3, j])
            )
            out_cov[k, r, j - 1] = v
            out_cov[k, j - 1, r] = v
        for c in range(3):
            s = 0.0
            for a in range(4):
                for b in range(4):
                    s += Xi[a, r] * P[a, b] * Xi[b, c]
            out_cov[k, r, c] = 4.0 * s
    for i in range(4, n):
        for j in range(4, n):
            out_cov[k, i - 1, j - 1] = P[i, j]


@njit(**_JIT)
def run_events(st, t_ev, kinds, vals, out_q, out_bg, out_v, out_w, out_cov, rec):
    """base.replay, compiled: feed the merged events (t_ev (E,), kinds (E,), vals (E, 6)),
    skip and count NaN samples, and (rec) record for IMU sample k the state after every
    event with t <= t_imu[k] (before the next IMU sample).

    The streamer calls it with one event at a time and rec=False: the per-kind step
    functions are inlined into this one compiled function, which batch and stream share
    (and numba compiles the filter once)."""
    k = np.int64(-1)
    cfg, prm, x, flags, P, work, sup, inn, acc = st  # once: each extraction costs refcounting
    n_ev = t_ev.shape[0]
    for i in range(n_ev):
        kind = kinds[i]
        t = t_ev[i]
        row = vals[i]
        if kind == EVENT_IMU:
            k += 1
            ok = True
            for a in range(6):
                if not math.isfinite(row[a]):
                    ok = False
            if ok:
                step_imu(cfg, prm, x, flags, P, work, sup, inn, acc, t, row)
            else:
                flags[K_SKIP] += 1
        elif kind == EVENT_MAG:
            if math.isfinite(row[0]) and math.isfinite(row[1]) and math.isfinite(row[2]):
                step_mag(cfg, prm, x, flags, P, work, sup, inn, acc, t, row)
            else:
                flags[K_SKIP + 1] += 1
        elif kind == EVENT_GNSS:
            if math.isfinite(row[0]) and math.isfinite(row[1]) and math.isfinite(row[2]):
                step_gnss(cfg, prm, x, flags, P, work, sup, inn, acc, t, row)
            else:
                flags[K_SKIP + 2] += 1
        elif kind == EVENT_AIR:
            if math.isfinite(row[0]):
                step_air(cfg, prm, x, flags, P, work, sup, inn, acc, t, row[0], row[1], row[2])
            else:
                flags[K_SKIP + 3] += 1
        # IMU sample k gets the state after the last event before the next IMU sample
        if rec and k >= 0 and (i + 1 == n_ev or kinds[i + 1] == EVENT_IMU):
            record(cfg, x, flags, P, work, k, out_q, out_bg, out_v, out_w, out_cov)


# --- Python side: encoding, estimators, streamer -------------------------------------------


_KINDS = {"mekf": KIND_MEKF, "mekf-air": KIND_MEKF_AIR, "ins-wind": KIND_INS}
_COMP = {"none": COMP_NONE, "gnss": COMP_GNSS, "airspeed": COMP_AIRSPEED}
_MAG = {"3d": MAG_3D, "heading": MAG_HEADING, "off": MAG_OFF}
_AIR = {"auto": AIR_AUTO, "vector": AIR_VECTOR, "airspeed": AIR_AIRSPEED, "off": AIR_OFF}
_STREAMS = ("imu", "mag", "gnss", "air")


def layout_of(kind: Kind, params: EskfParams, additive: bool = False) -> Layout:
    """The error-state layout of the compiled filter: :func:`eskf.layout_for`, checked
    against what the kernels assume (attitude at 0, velocity at 3)."""
    L = layout_for(kind, params, additive=additive)
    if L.sl("att").start != 0 or (L.has("v") and L.sl("v").start != 3) or L.dim + int(additive) >= NMAX:
        raise AssertionError(f"compiled kernels cannot run the layout {L.blocks}")
    return L


def _vec(a: Any, n: int, name: str) -> F64:
    v = np.asarray(a, dtype=np.float64)
    if v.shape != (n,):
        raise ValueError(f"initial.{name}: expected shape ({n},), found {v.shape}")
    return v


def _log_layout(cfg: I64, caps: I64) -> int:
    cfg[C_CAP : C_CAP + 6] = caps
    cfg[C_OFF : C_OFF + 6] = np.concatenate([[0], np.cumsum(caps)[:-1]])
    return int(caps.sum())


def make_state(
    kind: Kind,
    additive: bool,
    params: EskfParams,
    site: Site,
    initial: InitialState | None,
    has: frozenset[str],
    caps: I64,
) -> KernelState:
    """A fresh KernelState, parameters and modes encoded once. kind: "mekf", "mekf-air"
    or "ins-wind"; additive: the quaternion-additive form (ekf7/ekf10); has: the streams
    that will be fed; caps (6,): innovation log rows per sensor (SENSORS order)."""
    p, ini = params, initial
    L = layout_of(kind, p, additive)
    dim = L.dim
    n = dim + 1 if additive else dim
    cfg = np.zeros(N_CFG, dtype=np.int64)
    cfg[C_KIND] = _KINDS[kind]
    cfg[C_ADD] = int(additive)
    cfg[C_COMP] = COMP_AIRSPEED if kind == "mekf-air" else _COMP[p.accel_compensation]
    cfg[C_MAG] = _MAG[effective_mag_mode(p, site)]
    cfg[C_HVERT] = int(p.heading_model == "vertical")
    cfg[C_AIR] = _AIR[p.air_mode]
    cfg[C_SYN] = int(p.synthetic_sideslip)
    cfg[C_WAIT_MAG] = int("mag" in has and p.mag_mode != "off" and ini is None)
    cfg[C_WAIT_GNSS] = int(kind == "ins-wind" and (ini is None or ini.v_n is None))
    cfg[C_INI] = int(ini is not None)
    cfg[C_INI_BG] = int(ini is not None and ini.gyro_bias_b is not None)
    cfg[C_INI_V] = int(ini is not None and ini.v_n is not None)
    cfg[C_INI_W] = int(ini is not None and ini.wind_n is not None)
    cfg[C_SITE_MAG] = int(site.mag_n is not None)
    cfg[C_IV] = L.sl("v").start if L.has("v") else -1
    cfg[C_IBG] = L.sl("bg").start
    cfg[C_IW] = L.sl("wind").start if L.has("wind") else -1
    cfg[C_IBA] = L.sl("ba").start if L.has("ba") else -1
    cfg[C_IBM] = L.sl("bm").start if L.has("bm") else -1
    cfg[C_DIM] = dim
    cfg[C_N] = n
    total = _log_layout(cfg, np.asarray(caps, dtype=np.int64))

    def sig(given: float | None, default: float) -> float:
        return default if given is None else given

    prm = np.zeros(N_PRM)
    prm[R_SG2] = p.gyro_noise**2
    prm[R_SB2] = p.gyro_bias_noise**2
    prm[R_SA2] = p.accel_noise**2
    prm[R_SBA2] = p.accel_bias_noise**2
    prm[R_WH2] = p.wind_noise**2
    prm[R_WV2] = p.wind_noise_vertical**2
    prm[R_ACC_VAR] = p.accel_sigma**2
    prm[R_NORM_GATE] = p.accel_norm_gate
    prm[R_MAG_SIGMA] = p.mag_sigma
    prm[R_MAG_VAR] = p.mag_sigma**2
    prm[R_GNSS_VAR] = p.gnss_sigma**2
    prm[R_TAS_VAR] = p.tas_sigma**2
    prm[R_VANE_VAR] = p.vane_sigma**2
    prm[R_BETA_VAR] = p.sideslip_sigma**2
    prm[R_GATE2_ACC] = p.gate_accel**2
    prm[R_GATE2_MAG] = p.gate_mag**2
    prm[R_GATE2_GNSS] = p.gate_gnss**2
    prm[R_GATE2_AIR] = p.gate_air**2
    # EskfStreamer._try_init's defaults
    prm[R_P0_ATT] = sig(ini.sigma_att if ini else None, p.init_att) ** 2
    prm[R_P0_BG] = sig(ini.sigma_bias if ini else None, p.init_bias) ** 2
    prm[R_P0_V] = sig(ini.sigma_v if ini else None, p.init_v if ini is None else p.gnss_sigma) ** 2
    prm[R_P0_W] = sig(ini.sigma_wind if ini else None, p.init_wind) ** 2
    prm[R_P0_BA] = p.init_accel_bias**2
    prm[R_P0_BM] = p.init_mag_bias**2
    prm[R_SBM2] = p.mag_bias_noise**2
    prm[R_ACC_LP] = p.accel_lowpass
    prm[R_MAG_LP] = p.mag_lowpass
    prm[R_SCALE2] = p.gyro_scale_noise**2
    prm[R_MAG_NGATE] = p.mag_norm_gate
    prm[R_MAG_DGATE] = p.mag_dip_gate
    prm[R_GRAV] = site.gravity_n[2]
    if site.mag_n is not None:
        prm[R_SITE_MAG : R_SITE_MAG + 3] = site.mag_n
    if ini is not None:
        prm[R_INI_Q : R_INI_Q + 4] = _vec(ini.q_nb, 4, "q_nb")
        if ini.gyro_bias_b is not None:
            prm[R_INI_BG : R_INI_BG + 3] = _vec(ini.gyro_bias_b, 3, "gyro_bias_b")
        if ini.v_n is not None:
            prm[R_INI_V : R_INI_V + 3] = _vec(ini.v_n, 3, "v_n")
        if ini.wind_n is not None:
            prm[R_INI_W : R_INI_W + 3] = _vec(ini.wind_n, 3, "wind_n")
    flags = np.zeros(N_FLAGS, dtype=np.int64)
    flags[L_FIRST : L_FIRST + 6] = -1
    return KernelState(
        cfg=cfg,
        prm=prm,
        x=np.zeros(N_X),
        flags=flags,
        P=np.zeros((NMAX, NMAX)),
        work=np.zeros((N_WORK, NMAX)),
        sup=np.zeros((2, NMAX), dtype=np.int64),
        inn=np.empty((total, 5)),
        acc=np.zeros(total, dtype=np.bool_),
    )


def _innovations(st: KernelState, mag_mode: str) -> dict[str, Innovations]:
    """The logs as Estimate innovations, keyed in the order sensors first logged (as the
    reference's dict)."""
    dims = {
        "accel": 3,
        "mag": 1 if mag_mode == "heading" else 3,
        "gnss": 3,
        "air": 3,
        "tas": 1,
        "sideslip": 1,
    }
    cnt, first = st.flags[L_CNT : L_CNT + 6], st.flags[L_FIRST : L_FIRST + 6]
    out: dict[str, Innovations] = {}
    for s in sorted((s for s in range(6) if cnt[s] > 0), key=lambda s: int(first[s])):
        o, c = int(st.cfg[C_OFF + s]), int(cnt[s])
        name = SENSORS[s]
        out[name] = Innovations(
            t=st.inn[o : o + c, 0].copy(),
            nu=st.inn[o : o + c, 1 : 1 + dims[name]].copy(),
            nis=st.inn[o : o + c, 4].copy(),
            accepted=st.acc[o : o + c].copy(),
        )
    return out


def _grow(st: KernelState) -> KernelState:
    """The same state with twice the log capacity for every full sensor log."""
    cnt = st.flags[L_CNT : L_CNT + 6]
    caps = st.cfg[C_CAP : C_CAP + 6].copy()
    caps[cnt >= caps] *= 2
    cfg = st.cfg.copy()
    total = _log_layout(cfg, caps)
    inn, acc = np.empty((total, 5)), np.zeros(total, dtype=np.bool_)
    for s in range(6):
        o, c, o2 = int(st.cfg[C_OFF + s]), int(cnt[s]), int(cfg[C_OFF + s])
        inn[o2 : o2 + c] = st.inn[o : o + c]
        acc[o2 : o2 + c] = st.acc[o : o + c]
    return st._replace(cfg=cfg, inn=inn, acc=acc)


class CompiledStreamer(Streamer):
    """A compiled filter fed sample by sample through the same step functions as the
    batch run (so a flight streamed equals its batch estimate)."""

    def __init__(
        self,
        name: str,
        kind: Kind,
        additive: bool,
        params: EskfParams,
        site: Site,
        initial: InitialState | None,
        has: frozenset[str],
    ) -> None:
        super().__init__(name)
        self.kind = kind
        self.params = params
        self.layout = layout_of(kind, params, additive)
        self._st = make_state(kind, additive, params, site, initial, has, np.full(6, 256, dtype=np.int64))
        self._mag_fusion = effective_mag_mode(params, site)
        # one event at a time through the batch loop, without recording
        self._t = np.zeros(1)
        self._kind = np.zeros(1, dtype=np.int64)
        self._row = np.zeros((1, 6))
        self._none = (
            np.empty((0, 4)),
            np.empty((0, 3)),
            np.empty((0, 3)),
            np.empty((0, 3)),
            np.empty((0, 0, 0)),
        )

    def _step(self, kind: int, t: float) -> None:
        if (self._st.flags[L_CNT : L_CNT + 6] >= self._st.cfg[C_CAP : C_CAP + 6]).any():
            self._st = _grow(self._st)  # an event logs at most one row per sensor
        self._t[0] = t
        self._kind[0] = kind
        run_events(self._st, self._t, self._kind, self._row, *self._none, False)

    def _imu(self, t: float, w_b: F64, f_b: F64) -> None:
        self._row[0, :3] = w_b
        self._row[0, 3:6] = f_b
        self._step(EVENT_IMU, t)

    def _mag(self, t: float, mag_b: F64) -> None:
        self._row[0, :3] = mag_b
        self._step(EVENT_MAG, t)

    def _gnss(self, t: float, v_n: F64) -> None:
        self._row[0, :3] = v_n
        self._step(EVENT_GNSS, t)

    def _air(self, t: float, tas: float, aoa: float, sideslip: float) -> None:
        self._row[0, :3] = (tas, aoa, sideslip)
        self._step(EVENT_AIR, t)

    def innovations(self) -> dict[str, Innovations]:
        return _innovations(self._st, self._mag_fusion)

    @property
    def state(self) -> StateView:
        d = self.layout.dim
        q, bg, v, w = np.empty((1, 4)), np.empty((1, 3)), np.empty((1, 3)), np.empty((1, 3))
        cov = np.empty((1, d, d))
        st = self._st
        record(st.cfg, st.x, st.flags, st.P, st.work, 0, q, bg, v, w, cov)
        return StateView(
            t=self._t_last,
            q_nb=q[0],
            gyro_bias_b=bg[0],
            v_n=v[0] if self.layout.has("v") else None,
            wind_n=w[0] if self.layout.has("wind") else None,
            cov=cov[0],
            state_labels=self.layout.labels(),
        )


class _Compiled(_EskfEstimator):
    """run() and streamer() on the compiled kernels; all else from the reference class."""

    additive: ClassVar[bool] = False

    def run(self, flight: Flight, *, initial: InitialState | None = None) -> Estimate:
        """Estimate the whole flight in one compiled loop (the reference's output)."""
        self.check(flight)
        has = frozenset(s for s in _STREAMS if getattr(flight, s) is not None) & self.uses
        t_ev, kinds, vals = merge_events(flight, has)
        counts = np.bincount(kinds, minlength=4)
        caps = np.array(
            [counts[EVENT_IMU], counts[EVENT_MAG], counts[EVENT_GNSS], *[counts[EVENT_AIR]] * 3],
            dtype=np.int64,
        )
        st = make_state(self.kind, self.additive, self.params, flight.site, initial, has, caps)
        L = layout_of(self.kind, self.params, self.additive)
        N, d = len(flight.imu.t), L.dim
        q, bg = np.empty((N, 4)), np.empty((N, 3))
        v = np.empty((N, 3)) if L.has("v") else np.empty((0, 3))
        w = np.empty((N, 3)) if L.has("wind") else np.empty((0, 3))
        cov = np.empty((N, d, d))
        run_events(st, t_ev, kinds, np.ascontiguousarray(vals), q, bg, v, w, cov, True)
        skipped = st.flags[K_SKIP : K_SKIP + 4]
        return Estimate(
            filter=self.label,
            t=flight.imu.t.copy(),
            q_nb=q,
            gyro_bias_b=bg,
            v_n=v if L.has("v") else None,
            wind_n=w if L.has("wind") else None,
            cov=cov,
            state_labels=L.labels(),
            innovations=_innovations(st, effective_mag_mode(self.params, flight.site)),
            skipped={s: int(c) for s, c in zip(_STREAMS, skipped, strict=True)},
            params=self.params_text(),
        )

    # The reference annotates ``-> EskfStreamer``; the compiled streamer offers the same
    # Streamer interface without EskfStreamer's Python internals.
    def streamer(  # type: ignore[override]
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> CompiledStreamer:
        return CompiledStreamer(self.name, self.kind, self.additive, self.params, site, initial, has)


class MekfFast(_Compiled, Mekf):
    """[mekf], compiled: same name, parameters and output as :class:`Mekf`."""


class MekfAirFast(_Compiled, MekfAir):
    """[mekf-air], compiled: same name, parameters and output as :class:`MekfAir`."""


class InsWindFast(_Compiled, InsWind):
    """[ins-wind], compiled: same name, parameters and output as :class:`InsWind`."""


class Ekf7Fast(_Compiled, Ekf7):  # type: ignore[misc]
    """[ekf7], compiled: same name, parameters and output as :class:`Ekf7`."""

    additive = True


class Ekf10Fast(_Compiled, Ekf10):  # type: ignore[misc]
    """[ekf10], compiled: same name, parameters and output as :class:`Ekf10`."""

    additive = True
