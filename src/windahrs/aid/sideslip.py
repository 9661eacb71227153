"""Aid source: synthetic zero sideslip (PX4 EKF2's sideslip fusion, EKF2_BETA_NOISE):
``beta = V_y / V_x = 0`` for a fixed wing in coordinated flight, one row with the Jacobian
of the ratio, R = sideslip_sigma^2 (+ the GNSS variance over tas^2 when the GNSS velocity
is an input), gated at gate_air sigmas; fused after the airspeed (synthetic_sideslip).
Innovation key: ``"sideslip"`` (1 row).
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
    INN_SIDESLIP,
    W_NU,
    W_R,
)

#: The parameters of this aid source (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = ("synthetic_sideslip", "sideslip_sigma")


@njit(inline="always", **_JIT_CORE)
def fuse_sideslip(cfg, prm, x, flags, P, work, sup, inn, acc, t, tas, use_v, extra):
    """Fuse a zero sideslip at t s (tas m/s scales the GNSS part of R; extra: the GNSS
    variance (m/s)^2 when it is an input)."""
    nu, R = work[W_NU], work[W_R : W_R + 3]
    y0, y1, _, ns = _air_rows(cfg, x, work, sup[0], use_v, 0.0, 0.0, 0.0, np.int64(0))
    u = y0 if abs(y0) > 1e-3 else math.copysign(1e-3, y0)
    _, y1, _, ns = _air_rows(cfg, x, work, sup[0], use_v, -y1 / u**2, 1.0 / u, 0.0, np.int64(0))
    nu[0] = -(y1 / u)
    R[0, 0] = prm["sideslip_var"] + extra / max(tas, 1.0) ** 2
    _fuse(cfg, x, flags, P, work, sup, inn, acc, np.int64(INN_SIDESLIP), t, np.int64(1), ns, prm["gate_air2"])
