"""Truth of a vehicle whose attitude is held by its autopilot while wind disturbs its
velocity (SPEC 5.2 quasi-steady response; SPEC 7.3 gust-following model).

The nominal flight is an attitude history ``q_nb`` and an air-relative velocity
``v_air_nom_b`` fixed in the body. Wind disturbances ``wd_n`` (deviations from the mean
wind) move the velocity through a linear response

    d(dV_n)/dt = M_k (wd_n - dV_n),        v_n = C_nb v_air_nom_b + mean_wind_n + dV_n

with ``M_k`` given per step (fixed wing: ``-C_nb D C_bn`` from stability derivatives;
paper scenario: a constant gain matrix). The recursion is implicit Euler (stable for any
step). Acceleration, body rates and position are then differenced/summed from the same
samples, so every sensor derived from this truth is exactly consistent with it.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from windahrs.rotation import dcm_from_quat, quat_conj, quat_log, quat_mul
from windahrs.sim.sensors import TruthTrajectory

__all__ = ["fly_attitude_held", "rates_from_attitude"]

F64 = NDArray[np.float64]


def rates_from_attitude(t: F64, q_nb: F64) -> F64:
    """Body rates (N, 3) rad/s, piecewise constant: ``w[k] = Log(q[k-1]^* q[k]) / dt``;
    ``w[0]`` repeats ``w[1]``. Integrating them reproduces ``q_nb`` to rounding."""
    w = np.empty((len(t), 3))
    w[1:] = quat_log(quat_mul(quat_conj(q_nb[:-1]), q_nb[1:])) / np.diff(t)[:, None]
    w[0] = w[1] if len(t) > 1 else 0.0
    return w


@numba.njit(cache=True)
def _implicit_response(m: F64, wd: F64, dt: F64, dv0: F64) -> F64:  # pragma: no cover - compiled
    n = wd.shape[0]
    dv = np.empty((n, 3))
    dv[0] = dv0
    eye = np.eye(3)
    for k in range(1, n):
        a = eye + dt[k] * m[k]
        rhs = dv[k - 1] + dt[k] * (m[k] @ wd[k])
        dv[k] = np.linalg.solve(a, rhs)
    return dv


def fly_attitude_held(
    t: F64,
    q_nb: F64,
    v_air_nom_b: F64,
    mean_wind_n: F64,
    wd_n: F64,
    response_n: F64,
    p0_n: F64 | None = None,
) -> TruthTrajectory:
    """Integrate the gust response and return the truth trajectory.

    t (N,) s; q_nb (N, 4); v_air_nom_b (3,) m/s; mean_wind_n (3,) m/s constant;
    wd_n (N, 3) m/s wind disturbance; response_n (N, 3, 3) or (3, 3) 1/s, the matrix M_k in
    NED; p0_n (3,) initial position m (default origin). The disturbance state starts at
    equilibrium with the first disturbance sample.
    """
    n = len(t)
    m = np.broadcast_to(np.asarray(response_n, dtype=np.float64), (n, 3, 3))
    dt = np.empty(n)
    dt[1:] = np.diff(t)
    dt[0] = dt[1] if n > 1 else 0.0
    # writable C arrays: a read-only one (a contiguous broadcast view) would compile another
    # specialisation of the loop
    m_c, wd_c = np.require(m, requirements=("C", "W")), np.require(wd_n, np.float64, ("C", "W"))
    dv = _implicit_response(m_c, wd_c, dt, wd_n[0].copy())
    C_nb = dcm_from_quat(q_nb)
    v_n = C_nb @ v_air_nom_b + mean_wind_n + dv
    a_n = np.empty((n, 3))
    a_n[1:] = np.diff(v_n, axis=0) / dt[1:, None]
    a_n[0] = a_n[1] if n > 1 else 0.0
    p = np.zeros((n, 3))
    p[1:] = np.cumsum(0.5 * (v_n[1:] + v_n[:-1]) * dt[1:, None], axis=0)
    if p0_n is not None:
        p = p + p0_n
    return TruthTrajectory(
        t=t,
        q_nb=q_nb,
        w_b=rates_from_attitude(t, q_nb),
        a_n=a_n,
        v_n=v_n,
        p_n=p,
        wind_n=mean_wind_n + wd_n,
    )
