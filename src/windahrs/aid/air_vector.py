"""Aid source: the paper's air-data vector ``V_T^b = C_bn (V_n - W_n)`` (SPEC 3.4), from
pitot and both vanes: 3 rows with the Jacobian of :mod:`windahrs.aid.air_velocity`, and
``R = J diag(tas_sigma^2, vane_sigma^2, vane_sigma^2) J^T (+ gnss_sigma^2 I when the GNSS
velocity is an input, [mekf-air])``, J the Jacobian of V_air^b on (tas, aoa, sideslip).
Gate: gate_air sigmas per component. Also the wind's initial value from the first air
sample, ``W = V - C_nb V_air``, and the wind's reset to the same once the air data has been
kept out by its gate for reset_timeout while GNSS held the velocity (:func:`wind_lost`,
:func:`reset_wind`; for every air aid source, the airspeed's too). Innovation key: ``"air"``
(3 rows).
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
    INN_AIR,
    S_VGNSS,
    S_WPEND,
    W_NU,
    W_R,
    W_T,
    X_Q,
    X_TAIR,
    X_TGNSS,
    X_TGOK,
    X_V,
    X_VAIR,
    X_VGNSS,
    X_W,
)
from windahrs.core.quat import (
    _dcm9,
)
from windahrs.core.reset import log_reset, reopen, restart_after_absence, timed_out

#: The parameters of this aid source (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = ("air_mode", "tas_sigma", "vane_sigma", "gate_air")
#: The oldest GNSS velocity, s, that still holds the velocity for a wind reset (:func:`wind_lost`):
#: PX4 EKF2's GNSS_MAX_INTERVAL, the longest it waits for a GNSS sample (windahrs.flags'
#: ABSENT_MIN_S).
GNSS_FRESH = 0.5


@njit(inline="always", **_JIT_CORE)
def air_clock(prm, x, t):
    """A sample about to be offered to the gate at t s: after none for reset_timeout (an
    outage, or a vehicle too slow to fuse its airspeed) the wind reset's clock restarts
    (:func:`~windahrs.core.reset.restart_after_absence`, as the GNSS clock's)."""
    restart_after_absence(prm, x, np.int64(INN_AIR), t, x[X_TAIR])
    x[X_TAIR] = t


@njit(inline="always", **_JIT_CORE)
def wind_lost(cfg, prm, x, flags, t):
    """Whether the air data has been kept out by its gate for reset_timeout while the
    velocity is known: the wind is what is wrong, and the gate, trusting it, would keep the
    air data out until the wind's random walk had reopened it (24 s after the fault matrix's
    gyro saturation, seed 3). The velocity is known when the last GNSS sample is at most
    GNSS_FRESH s old and, in an INS, passed its gate (it agreed with the state; X_TGOK, not
    the reset clock, which restarts after an outage or a reset without a sample passing)."""
    if cfg["i_w"] < 0 or flags[S_VGNSS] == 0 or t - x[X_TGNSS] > GNSS_FRESH:
        return False
    if cfg["i_v"] >= 0 and x[X_TGOK] != x[X_TGNSS]:
        return False
    return timed_out(prm, x, np.int64(INN_AIR), t)


@njit(**_JIT_CORE)
def reset_wind(cfg, prm, x, flags, P, work, inn, acc, t, use_v, vanes):
    """The wind from this air sample, ``W = V - C_nb V_air``, its spread reopened
    (init_wind, init_wind_vertical): PX4 EKF2 likewise resets its wind to the airspeed
    (``resetWindUsingAirspeed``) once airspeed fusion has failed for 10 s with other aiding
    holding the velocity; logged as a reset of the air data (its size: the wind's change, m/s)."""
    w0, w1, w2 = x[X_W], x[X_W + 1], x[X_W + 2]
    init_wind(x, flags, use_v, vanes)
    reopen(cfg, P, cfg["i_w"], prm["init_wind_var"], prm["init_wind_vertical_var"])
    dw = math.sqrt((x[X_W] - w0) ** 2 + (x[X_W + 1] - w1) ** 2 + (x[X_W + 2] - w2) ** 2)
    log_reset(cfg, flags, inn, acc, work, x, np.int64(INN_AIR), t, dw)


@njit(inline="always", **_JIT_CORE)
def init_wind(x, flags, use_v, vanes):
    """W = V - C_nb V_air from the first air sample (vertical wind 0 without vanes)."""
    c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    vv = X_V if use_v else X_VGNSS
    ax, ay, az = x[X_VAIR], x[X_VAIR + 1], x[X_VAIR + 2]
    x[X_W] = x[vv] - (c[0] * ax + c[1] * ay + c[2] * az)
    x[X_W + 1] = x[vv + 1] - (c[3] * ax + c[4] * ay + c[5] * az)
    x[X_W + 2] = x[vv + 2] - (c[6] * ax + c[7] * ay + c[8] * az) if vanes else 0.0
    flags[S_WPEND] = 0


@njit(inline="always", **_JIT_CORE)
def fuse_air_vector(cfg, prm, x, flags, P, work, sup, inn, acc, t, tas, ca, sa, cb, sb, use_v, extra):
    """Fuse the air-relative velocity of the sample (X_VAIR; tas m/s, cos/sin of aoa and
    sideslip) at t s; extra: variance added per axis (m/s)^2. Returns whether the gate
    accepted it."""
    nu, R = work[W_NU], work[W_R : W_R + 3]
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
    d0, d1 = prm["tas_var"], prm["vane_var"]
    for k in range(3):
        for l in range(3):
            r = J[k, 0] * d0 * J[l, 0] + J[k, 1] * d1 * J[l, 1] + J[k, 2] * d1 * J[l, 2]
            R[k, l] = r + extra if k == l else r
    return _fuse(cfg, x, flags, P, work, sup, inn, acc, np.int64(INN_AIR), t, np.int64(3), ns, prm["gate_air2"])
