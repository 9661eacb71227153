"""Aid source: true airspeed ``|V_air^b| = |v_n - W_n|`` (PX4 EKF2's airspeed fusion): one
row, no attitude information (``H_att = 0``), R = tas_sigma^2 (+ the GNSS variance when the
GNSS velocity is an input), gated at gate_air sigmas. Used with a pitot and no vanes
(air_mode "airspeed", or "auto" without vanes). Innovation key: ``"tas"`` (1 row).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from windahrs.aid.air_velocity import (
    _air_rows,
)
from windahrs.core.kalman import (
    _fuse,
)
from windahrs.core.layout import (
    _JIT_CORE,
    INN_TAS,
    W_H,
    W_NU,
    W_R,
)

#: The parameters of this aid source (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = ("air_mode", "tas_sigma", "gate_air")


@njit(inline="always", **_JIT_CORE)
def fuse_tas(cfg, prm, x, flags, P, work, sup, inn, acc, t, tas, use_v, extra):
    """Fuse the airspeed tas m/s at t s; extra: variance added (m/s)^2. Returns whether the
    gate accepted it."""
    nu, R = work[W_NU], work[W_R : W_R + 3]
    y0, y1, y2, ns = _air_rows(cfg, x, work, sup[0], use_v, 0.0, 0.0, 0.0, np.int64(0))
    a = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    den = max(a, 1e-9)
    y0, y1, y2, ns = _air_rows(cfg, x, work, sup[0], use_v, y0 / den, y1 / den, y2 / den, np.int64(0))
    work[W_H, 0], work[W_H, 1], work[W_H, 2] = 0.0, 0.0, 0.0
    nu[0] = tas - a
    R[0, 0] = prm["tas_var"] + extra
    return _fuse(cfg, x, flags, P, work, sup, inn, acc, np.int64(INN_TAS), t, np.int64(1), ns, prm["gate_air2"])
