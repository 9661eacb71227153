"""Aid source: GNSS velocity (NED), ``h = v_n``, ``H = I`` on the velocity states,
R = gnss_sigma^2 I, gated at gate_gnss sigmas ([ins-wind]). Every filter remembers the last
GNSS velocity and its difference (the accelerometer compensation of :mod:`windahrs.aid.gravity`
and the velocity input of [mekf-air]). Innovation key: ``"gnss"`` (3 rows).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from windahrs.core.kalman import (
    _fuse,
)
from windahrs.core.layout import (
    _JIT,
    C_IV,
    C_KIND,
    INN_GNSS,
    KIND_INS,
    R_GATE2_GNSS,
    R_GNSS_VAR,
    S_AGNSS,
    S_VGNSS,
    W_H,
    W_NU,
    W_R,
    X_AGNSS,
    X_TGNSS,
    X_V,
    X_VGNSS,
)

#: The parameters of this aid source (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = ("gnss_sigma", "gate_gnss")


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
        _fuse(cfg, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, prm[R_GATE2_GNSS])
