"""Aid source: GNSS velocity (NED), ``h = v_n``, ``H = I`` on the velocity states,
R = gnss_sigma^2 I, gated at gate_gnss sigmas ([ins-wind]). Every filter remembers the last
GNSS velocity and its difference (the accelerometer compensation of :mod:`windahrs.aid.gravity`
and the velocity input of [mekf-air]). Innovation key: ``"gnss"`` (3 rows).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from windahrs.aid.gravity import LOST_COS
from windahrs.core.kalman import (
    _fuse,
)
from windahrs.core.layout import (
    _JIT,
    C_IBG,
    C_IV,
    C_KIND,
    INN_GNSS,
    KIND_INS,
    R_GATE2_GNSS,
    R_GNSS_VAR,
    R_GRAV,
    R_P0_BG,
    S_AGNSS,
    S_VGNSS,
    W_H,
    W_NU,
    W_R,
    X_AGNSS,
    X_FLAST,
    X_Q,
    X_TGNSS,
    X_V,
    X_VGNSS,
)
from windahrs.core.quat import _dcm9
from windahrs.core.reset import accepted_at, clear_rows, level_to, log_reset, set_attitude_cov, timed_out

#: The parameters of this aid source (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = ("gnss_sigma", "gate_gnss", "reset_timeout")


@njit(inline="always", **_JIT)
def remember_gnss(x, flags, t, row):
    """Every filter keeps the last GNSS velocity (row[:3] m/s NED at t s) and its
    difference quotient, the acceleration used to compensate the accelerometer."""
    if flags[S_VGNSS] == 1 and t > x[X_TGNSS]:
        dt = t - x[X_TGNSS]
        for a in range(3):
            x[X_AGNSS + a] = (row[a] - x[X_VGNSS + a]) / dt
        flags[S_AGNSS] = 1
    for a in range(3):
        x[X_VGNSS + a] = row[a]
    x[X_TGNSS] = t
    flags[S_VGNSS] = 1


@njit(inline="always", **_JIT)
def fuse_gnss(cfg, prm, x, flags, P, work, sup, inn, acc, t, row):
    """A GNSS velocity sample (finite) of an initialised filter: row[:3] m/s NED at t s,
    fused where velocity is a state ([ins-wind])."""
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
        if timed_out(prm, x, sensor, t):
            reset_to_gnss(cfg, prm, x, flags, P, work, inn, acc, t, row)
        elif _fuse(cfg, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, prm[R_GATE2_GNSS]):
            accepted_at(x, sensor, t)


@njit(**_JIT)
def reset_to_gnss(cfg, prm, x, flags, P, work, inn, acc, t, row):
    """GNSS velocity kept out by its gate for reset_timeout: the velocity to the measurement
    (spread gnss_sigma), and the attitude's and gyro bias's spreads reopened, so that the
    next samples can correct a tilt the rejected ones could not (PX4 EKF2 resets velocity
    to GNSS after EKF2_NOAID_TOUT)."""
    iv = cfg[C_IV]
    if flags[S_AGNSS] == 1:
        # a tilt the velocity updates cannot undo (beyond 45 deg): level the attitude so that
        # the last specific force f_b = C_bn (a_n - g_n) matches the GNSS acceleration a_n
        g = prm[R_GRAV]
        f0, f1, f2 = x[X_FLAST], x[X_FLAST + 1], x[X_FLAST + 2]
        d0, d1, d2 = -x[X_AGNSS], -x[X_AGNSS + 1], g - x[X_AGNSS + 2]
        c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
        b0 = c[0] * d0 + c[3] * d1 + c[6] * d2
        b1 = c[1] * d0 + c[4] * d1 + c[7] * d2
        b2 = c[2] * d0 + c[5] * d1 + c[8] * d2
        nf, nb = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2), math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        if nf > 0 and -(f0 * b0 + f1 * b1 + f2 * b2) < LOST_COS * nf * nb:
            level_to(x, -f0, -f1, -f2, d0, d1, d2)
    dv2 = 0.0
    clear_rows(cfg, P, iv, 3)
    for a in range(3):
        dv2 += (row[a] - x[X_V + a]) ** 2
        x[X_V + a] = row[a]
        P[iv + a, iv + a] = prm[R_GNSS_VAR]
    set_attitude_cov(cfg, prm, x, P, work)
    i0 = cfg[C_IBG]
    for a in range(3):  # reopen (not reset) the gyro bias: it may have learnt the wrong tilt
        P[i0 + a, i0 + a] = max(P[i0 + a, i0 + a], prm[R_P0_BG])
    log_reset(cfg, flags, inn, acc, work, x, np.int64(INN_GNSS), t, math.sqrt(dv2))
