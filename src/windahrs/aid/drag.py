"""Aid source: multirotor drag (PX4 EKF2's drag fusion, EKF2_DRAG_CTRL). A multirotor's
accelerometer does not read gravity: along the body x and y axes it reads the aerodynamic
force per unit mass, set by the air-relative velocity ``u = C_bn (v_n - W_n)`` (body):

    ``f_k = -mu u_k - k_k u_k |u_k| (+ b_a,k)``, k = x, y,

the rotor momentum drag ``mu`` (EKF2_MCOEF, 1/s: linear in the airspeed, dominant at low
speed; the drag :mod:`windahrs.sim.quadrotor` simulates) plus the bluff-body drag
``k_k = rho / (2 B_k)`` of the ballistic coefficients B_x, B_y (EKF2_BCOEF_X/Y, kg/m^2).
Two rows, ``H = diag(dh/du) J`` with J the air-relative velocity's Jacobian
(:mod:`windahrs.aid.air_velocity`: attitude, velocity and wind), plus ``I`` on the
accelerometer-bias states; R = drag_sigma^2 I (EKF2_DRAG_NOISE, the rotors' vibration);
gated at gate_drag sigmas per axis. Fused at every IMU sample of the INS, where the
accelerometer also drives the velocity prediction (as in EKF2). It makes the wind
observable without a pitot and ties the tilt to the GNSS velocity through the drag.
Innovation key: ``"drag"`` (2 rows). Valid in flight only (on the ground the rotors stop).
"""

from __future__ import annotations

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
    INN_DRAG,
    W_H,
    W_NU,
    W_R,
    X_BA,
)

#: The parameters of this aid source (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = ("drag", "drag_mcoef", "drag_bcoef_x", "drag_bcoef_y", "drag_sigma", "gate_drag", "air_density")


@njit(inline="always", **_JIT_CORE)
def fuse_drag(cfg, prm, x, flags, P, work, sup, inn, acc, t, row):
    """Fuse the specific force of IMU sample ``row`` = [w_b, f_b] along body x and y at t s."""
    u0, u1, _, ns = _air_rows(cfg, x, work, sup[0], True, 0.0, 0.0, 0.0, np.int64(0))
    mu, kx, ky = prm["drag_mcoef"], prm["drag_kx"], prm["drag_ky"]
    d0 = -mu - 2.0 * kx * abs(u0)  # dh_k / du_k
    d1 = -mu - 2.0 * ky * abs(u1)
    _air_rows(cfg, x, work, sup[0], True, d0, 0.0, 0.0, np.int64(0))
    _, _, _, ns = _air_rows(cfg, x, work, sup[0], True, 0.0, d1, 0.0, np.int64(1))
    h0 = -mu * u0 - kx * u0 * abs(u0)
    h1 = -mu * u1 - ky * u1 * abs(u1)
    iba = cfg["i_ba"]
    H = work[W_H : W_H + 3]
    if iba >= 0:
        h0, h1 = h0 + x[X_BA], h1 + x[X_BA + 1]
        H[0, iba], H[0, iba + 1], H[1, iba], H[1, iba + 1] = 1.0, 0.0, 0.0, 1.0
        sup[0, ns], sup[0, ns + 1] = iba, iba + 1
        ns += 2
    nu, R = work[W_NU], work[W_R : W_R + 3]
    nu[0], nu[1] = row[3] - h0, row[4] - h1
    var = prm["drag_var"]
    R[0, 0], R[0, 1], R[1, 0], R[1, 1] = var, 0.0, 0.0, var
    _fuse(cfg, x, flags, P, work, sup, inn, acc, np.int64(INN_DRAG), t, np.int64(2), ns, prm["gate_drag2"])
