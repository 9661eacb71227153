"""The air-relative velocity that the air-data aid sources share (SPEC 3.4): the model
``V_air^b = C_bn (v_n - W_n)``, with v_n the velocity state or the last GNSS velocity, and
its Jacobian on the error state ``[[y]x, C_bn (velocity), -C_bn (wind)]``; and the sample's
own air-relative velocity from airspeed and the vanes. Used by :mod:`windahrs.aid.air_vector`,
:mod:`windahrs.aid.tas` and :mod:`windahrs.aid.sideslip`, and by the airspeed compensation of
:mod:`windahrs.aid.gravity`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from windahrs.core.layout import (
    _JIT_CORE,
    S_VAIR,
    W_H,
    X_Q,
    X_V,
    X_VAIR,
    X_VGNSS,
    X_W,
)
from windahrs.core.quat import (
    _dcm9,
)


@njit(**_JIT_CORE)
def _air_rows(cfg, x, work, sup, use_state_v, g0, g1, g2, row):
    """Returns y = C_bn (v - wind) (v: the velocity state or the
    last GNSS velocity) and writes row ``row`` of H as g^T J, J = d y / d(error) =
    [[y]x, -C_bn (wind), C_bn (velocity)]; sets the support; returns (y, support size)."""
    c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    vv = X_V if use_state_v else X_VGNSS
    dx, dy, dz = x[vv] - x[X_W], x[vv + 1] - x[X_W + 1], x[vv + 2] - x[X_W + 2]
    y0 = c[0] * dx + c[3] * dy + c[6] * dz
    y1 = c[1] * dx + c[4] * dy + c[7] * dz
    y2 = c[2] * dx + c[5] * dy + c[8] * dz
    H = work[W_H : W_H + 3]
    iv, iw = cfg["i_v"], cfg["i_w"]
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



@njit(inline="always", **_JIT_CORE)
def remember_air(x, flags, tas, aoa, beta):
    """The sample's air-relative velocity into X_VAIR: tas m/s, aoa and sideslip rad
    (NaN: no vanes, the air then taken as along the body x axis; an angle of attack alone:
    in the body x-z plane). Returns whether both vanes were present and cos/sin of aoa and
    sideslip (0 without both vanes)."""
    vanes = math.isfinite(aoa) and math.isfinite(beta)
    ca = cb = sa = sb = 0.0
    if vanes:
        ca, sa, cb, sb = math.cos(aoa), math.sin(aoa), math.cos(beta), math.sin(beta)
        x[X_VAIR], x[X_VAIR + 1], x[X_VAIR + 2] = tas * (ca * cb), tas * sb, tas * (sa * cb)
    elif math.isfinite(aoa):
        x[X_VAIR], x[X_VAIR + 1], x[X_VAIR + 2] = tas * math.cos(aoa), 0.0, tas * math.sin(aoa)
    else:
        x[X_VAIR], x[X_VAIR + 1], x[X_VAIR + 2] = tas, 0.0, 0.0
    flags[S_VAIR] = 1
    return vanes, ca, sa, cb, sb
