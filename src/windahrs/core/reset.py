"""Resets of the compiled filters' state: what an aid source does when its gate has kept its
measurement out for longer than ``reset_timeout`` (PX4 EKF2 resets to its aiding after
EKF2_NOAID_TOUT of rejections; ArduPilot's EKF3 likewise), and the attitude covariance that
initialisation and every reset set.

A gate that trusts a wrong state rejects every measurement that would fix it: after an
upside-down start, a gyro spike or a long outage, the innovations stay beyond the gate for
good. Each aid source therefore remembers when it last agreed with the state
(``x[X_TOK + sensor]``, NaN until initialisation: the accelerometer's gravity direction and
the magnetometer's heading within 45 deg of the state's, GNSS velocity accepted by its gate)
and, past the timeout, resets the states it observes to its measurement, reopens their
spread, and logs the reset in the ``reset`` log (the sensor, the size of the reset, how long
the sensor had been out), which :class:`~windahrs.estimate.Estimate` carries as ``resets``
and warns about.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from windahrs.core.kalman import _log
from windahrs.core.layout import (
    _JIT_CORE,
    INN_MAG,
    INN_RESET,
    S_MAGN,
    W_M,
    W_NU,
    X_BG,
    X_NFUSE,
    X_NMFUSE,
    X_Q,
    X_TOK,
)
from windahrs.core.quat import _dcm9, _qmul, _qnormalize, _xi_into


@njit(**_JIT_CORE)
def accepted_at(x, sensor, t):
    """Remember that ``sensor`` agreed with the state at t s (module docstring)."""
    x[X_TOK + sensor] = t


@njit(**_JIT_CORE)
def timed_out(prm, x, sensor, t):
    """Whether ``sensor`` has not agreed with the state for longer than reset_timeout
    (never before initialisation, nor with reset_timeout 0)."""
    tout = prm["reset_timeout"]
    return tout > 0 and t - x[X_TOK + sensor] > tout


@njit(inline="always", **_JIT_CORE)
def restart_after_absence(prm, x, sensor, t, t_last):
    """A sample of ``sensor`` at t s, its previous one at t_last s: after none for longer than
    reset_timeout (an outage) the reset's clock restarts at t, the sensor was absent, not kept
    out by its gate (PX4 EKF2 likewise times a fusion out only while it has samples to fuse)."""
    if t - t_last > prm["reset_timeout"]:
        accepted_at(x, sensor, t)


@njit(**_JIT_CORE)
def log_reset(cfg, flags, inn, acc, work, x, sensor, t, size):
    """Log a reset to ``sensor`` at t s of the given size (rad or m/s) and restart its clock.
    Logged "out for": t minus the clock (NaN for a clock at minus infinity: retake_heading's,
    or NaN: the heading absent; negative for the start check's, aid.gravity.start_check)."""
    nu = work[W_NU]
    out_for = t - x[X_TOK + sensor]
    if math.isinf(out_for):
        out_for = np.nan
    nu[0], nu[1], nu[2] = float(sensor), size, out_for
    _log(cfg, flags, inn, acc, nu, np.int64(INN_RESET), t, np.int64(3), np.nan, np.bool_(True))
    x[X_TOK + sensor] = t


@njit(**_JIT_CORE)
def clear_rows(cfg, P, i0, k):
    """Zero the k rows and columns of P from covariance index i0 (before setting their spread)."""
    n = cfg["n"]
    for i in range(i0, i0 + k):
        for j in range(n):
            P[i, j] = 0.0
            P[j, i] = 0.0


@njit(**_JIT_CORE)
def reopen(cfg, P, i0, var, var_last):
    """The 3 error states from error-state index i0 made uncorrelated with spread var
    (the third var_last: a vertical wind held at zero has 0); additive form: covariance
    index i0 + 1."""
    j0 = i0 + cfg["add_form"]
    clear_rows(cfg, P, j0, 3)
    P[j0, j0], P[j0 + 1, j0 + 1], P[j0 + 2, j0 + 2] = var, var, var_last


@njit(**_JIT_CORE)
def set_attitude_cov(cfg, prm, x, P, work):
    """The attitude's spread to init_att^2 per axis, uncorrelated with the other states
    (additive form: on the quaternion, ``1/4 Xi var Xi^T``); with init_yaw > 0, init_yaw^2
    about the nav vertical (body direction ``d = C_bn e_3``: ``var I + (var_yaw - var) d d^T``).
    The low-passed means' samples not yet fused (core.kalman.samples_to_fuse) are dropped:
    the information they stood for is what the reopened spread discards, and the next
    fusion, in the large-gain regime, stands for its own sample only."""
    x[X_NFUSE] = 0.0
    x[X_NMFUSE] = 0.0
    var = prm["init_att_var"]
    if prm["init_yaw_var"] > 0.0:
        _set_attitude_cov_yaw(cfg, prm, x, P, work)
        return
    if cfg["add_form"] == 1:
        clear_rows(cfg, P, 0, 4)
        Xi = work[W_M + 4 : W_M + 8]
        _xi_into(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], Xi)
        for r in range(4):
            for c in range(4):
                s = 0.0
                for k in range(3):
                    s += Xi[r, k] * var * Xi[c, k]
                P[r, c] = 0.25 * s
    else:
        clear_rows(cfg, P, 0, 3)
        for a in range(3):
            P[a, a] = var


@njit(**_JIT_CORE)
def _set_attitude_cov_yaw(cfg, prm, x, P, work):
    """set_attitude_cov with a separate spread about the nav vertical (init_yaw)."""
    attitude_cov_about_vertical(cfg, x, P, work, prm["init_att_var"], prm["init_yaw_var"])


@njit(**_JIT_CORE)
def attitude_cov_about_vertical(cfg, x, P, work, var, var_yaw):
    """The attitude's spread to var per axis and var_yaw about the nav vertical (body
    direction ``d = C_bn e_3``: ``var I + (var_yaw - var) d d^T``), uncorrelated with the
    other states (additive form: on the quaternion, ``1/4 Xi (.) Xi^T``)."""
    dv = var_yaw - var
    w, qx, qy, qz = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
    d = (2.0 * (qx * qz - w * qy), 2.0 * (qy * qz + w * qx), w * w - qx * qx - qy * qy + qz * qz)
    # the 3x3 spread var I + dv d d^T, entry by entry (nothing allocated: the core runs
    # without numba's reference counting, layout._JIT_CORE)
    if cfg["add_form"] == 1:
        clear_rows(cfg, P, 0, 4)
        Xi = work[W_M + 4 : W_M + 8]
        _xi_into(w, qx, qy, qz, Xi)
        for r in range(4):
            for c in range(4):
                s = 0.0
                for k in range(3):
                    for m in range(3):
                        s += Xi[r, k] * (dv * d[k] * d[m] + (var if k == m else 0.0)) * Xi[c, m]
                P[r, c] = 0.25 * s
    else:
        clear_rows(cfg, P, 0, 3)
        for r in range(3):
            for c in range(3):
                P[r, c] = dv * d[r] * d[c] + (var if r == c else 0.0)


@njit(**_JIT_CORE)
def reset_gyro_bias(cfg, prm, x, P):
    """The gyro bias to zero with its initial spread: a bias learnt while the attitude was
    lost is not to be trusted."""
    restart(cfg, x, P, X_BG, cfg["i_bg"], prm["init_bias_var"])


@njit(**_JIT_CORE)
def restart(cfg, x, P, ix, i0, var):
    """A 3-vector state x[ix:ix+3] (a bias) back to zero, its error states from index i0
    reopened with spread var: learnt while the attitude was lost, it is not to be trusted."""
    for a in range(3):
        x[ix + a] = 0.0
    reopen(cfg, P, i0, var, var)


@njit(**_JIT_CORE)
def retake_heading(cfg, prm, x, flags, t):
    """After a reset that levelled the attitude: a heading held while the tilt was lost is
    no better than the tilt was, so the next field sample that disagrees with it by more
    than the magnetometer's LOST_HEADING turns it at once (windahrs.aid.mag.heading_reset),
    and a reference field taken under the lost tilt (site field unknown) is taken again. Its
    clock is set to minus infinity: the reset is logged as out for NaN s, which
    Estimate.warnings() says as "taken for the heading ... after a reset" (not as a field
    off the state for reset_timeout, which nothing measured)."""
    x[X_TOK + INN_MAG] = -np.inf
    if cfg["site_mag_known"] == 0:
        flags[S_MAGN] = 0


@njit(**_JIT_CORE)
def level_to(x, ux, uy, uz, dx=0.0, dy=0.0, dz=1.0):
    """Rotate the attitude by the smallest body-frame rotation that makes the nav-frame
    direction d (default: down) point along (ux, uy, uz) in body axes (neither need be
    unit), keeping the heading as far as a tilt change allows; returns the angle turned, rad."""
    c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    # C_bn d: the estimated direction of d in the body
    bx, by, bz = c[0] * dx + c[3] * dy + c[6] * dz, c[1] * dx + c[4] * dy + c[7] * dz, c[2] * dx + c[5] * dy + c[8] * dz
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    bx, by, bz = bx / nb, by / nb, bz / nb
    n = math.sqrt(ux * ux + uy * uy + uz * uz)
    ax, ay, az = ux / n, uy / n, uz / n
    # C_nb_new = C_nb C(d): d turns the measured down a onto the estimated b
    dot = ax * bx + ay * by + az * bz
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    if dot < -1.0 + 1e-12:  # opposite: half a turn about any axis normal to a
        if abs(ax) < 0.9:
            cx, cy, cz = 0.0, -az, ay
        else:
            cx, cy, cz = az, 0.0, -ax
        s = math.sqrt(cx * cx + cy * cy + cz * cz)
        d = (0.0, cx / s, cy / s, cz / s)
    else:
        d = _qnormalize(1.0 + dot, cx, cy, cz)
    q = _qmul(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], d[0], d[1], d[2], d[3])
    x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = _qnormalize(q[0], q[1], q[2], q[3])
    return math.acos(min(1.0, max(-1.0, dot)))
