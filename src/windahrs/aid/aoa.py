"""Aid source: the angle of attack of a vane flown without a sideslip vane,
``alpha = atan2(V_z, V_x)`` of the body-frame air velocity ``V_air^b = C_bn (v_n - W_n)``
(SPEC 3.4's vane model, its first angle alone): one row, ``H = g^T J`` with ``g = d alpha /
d V_air^b = (-V_z, 0, V_x) / (V_x^2 + V_z^2)`` and J the air velocity's Jacobian of
:mod:`windahrs.aid.air_velocity`; R = vane_sigma^2 (+ the GNSS velocity's variance over
tas^2 when it is an input, [mekf-air]), gated at gate_air sigmas. Fused after the airspeed
when a sample's angle of attack is finite and its sideslip NaN (a flight with one vane: the
air-data vector of :mod:`windahrs.aid.air_vector` needs both). The vane carries pitch and
vertical-wind information the airspeed alone does not. Innovation key: ``"aoa"`` (1 row).

Noise: vane_sigma, the vanes' of the air-data vector (1 deg): SPEC 5's sensor table puts
flow-angle vanes at 0.5 to 1 deg, and the upper end allows for the flow a small airframe
bends at its vane. Neither PX4 EKF2 nor ArduPilot EKF3 fuses a vane, so neither has a
default to take.
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
    INN_AOA,
    W_NU,
    W_R,
)

#: The parameters of this aid source (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = ("air_mode", "vane_sigma", "gate_air")


@njit(inline="always", **_JIT_CORE)
def fuse_aoa(cfg, prm, x, flags, P, work, sup, inn, acc, t, aoa, tas, use_v, extra):
    """Fuse the angle of attack aoa rad at t s (tas m/s scales the GNSS part of R; extra:
    the GNSS velocity's variance (m/s)^2 when it is an input)."""
    nu, R = work[W_NU], work[W_R : W_R + 3]
    y0, _, y2, ns = _air_rows(cfg, x, work, sup[0], use_v, 0.0, 0.0, 0.0, np.int64(0))
    r2 = max(y0 * y0 + y2 * y2, 1e-6)  # (an air velocity along the body y axis has no angle of attack)
    y0, _, y2, ns = _air_rows(cfg, x, work, sup[0], use_v, -y2 / r2, 0.0, y0 / r2, np.int64(0))
    d = aoa - math.atan2(y2, y0)
    nu[0] = (d + math.pi) % (2.0 * math.pi) - math.pi
    R[0, 0] = prm["vane_var"] + extra / max(tas, 1.0) ** 2
    _fuse(cfg, x, flags, P, work, sup, inn, acc, np.int64(INN_AOA), t, np.int64(1), ns, prm["gate_air2"])
