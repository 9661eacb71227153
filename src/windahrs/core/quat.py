"""Quaternion and rotation helpers on scalars for the compiled core (no allocation): the
scalar forms of :mod:`windahrs.rotation`'s conventions (Hamilton, scalar first, ``q_nb``),
returning tuples so that numba keeps them in registers."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from windahrs.core.layout import _JIT_CORE


@njit(**_JIT_CORE)
def _sinc(x):
    # np.sinc, with its own guard at 0.
    y = math.pi * (1.0e-20 if x == 0.0 else x)
    return math.sin(y) / y


@njit(**_JIT_CORE)
def _qmul(a0, a1, a2, a3, b0, b1, b2, b3):
    return (
        a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
        a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
        a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
        a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0,
    )


@njit(**_JIT_CORE)
def _qexp_half(px, py, pz):
    """Exp(p), the unit quaternion of the rotation vector p (rad), and sin(|p| / 2): its
    half angle's sine and cosine from one sincos, which the error-state prediction's
    transition reuses (sin a = 2 sin(a/2) cos(a/2), 1 - cos a = 2 sin^2(a/2))."""
    a = math.sqrt(px * px + py * py + pz * pz)
    h = 0.5 * a
    ch, sh = math.cos(h), math.sin(h)
    s = sh / a if a > 0.0 else 0.5
    return (ch, s * px, s * py, s * pz), sh


@njit(**_JIT_CORE)
def _qexp(px, py, pz):
    return _qexp_half(px, py, pz)[0]


@njit(**_JIT_CORE)
def _qlog(q0, q1, q2, q3):
    """Log(q), the rotation vector (rad) of a unit quaternion, the shorter way round (the
    inverse of :func:`_qexp`)."""
    if q0 < 0.0:
        q0, q1, q2, q3 = -q0, -q1, -q2, -q3
    s = math.sqrt(q1 * q1 + q2 * q2 + q3 * q3)
    if s < 1e-12:
        return 2.0 * q1, 2.0 * q2, 2.0 * q3
    g = 2.0 * math.atan2(s, q0) / s
    return g * q1, g * q2, g * q3


@njit(**_JIT_CORE)
def _qnormalize(q0, q1, q2, q3):
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    s = -1.0 if q0 < 0.0 else 1.0
    return q0 * s / n, q1 * s / n, q2 * s / n, q3 * s / n


@njit(**_JIT_CORE)
def _dcm9(w, x, y, z):
    """C_nb entries row by row (rotation.dcm_from_quat)."""
    return (
        w * w + x * x - y * y - z * z,
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        w * w - x * x + y * y - z * z,
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        w * w - x * x - y * y + z * z,
    )


@njit(**_JIT_CORE)
def _quat_from_euler(roll, pitch, yaw):
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return _qnormalize(
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    )


@njit(**_JIT_CORE)
def _euler(q0, q1, q2, q3):
    """rotation.euler_from_quat (ZYX, with its gimbal-lock rule)."""
    c = _dcm9(q0, q1, q2, q3)
    r31 = min(max(c[6], -1.0), 1.0)
    pitch = -math.asin(r31)
    if abs(r31) > 1.0 - 1e-9:
        return 0.0, pitch, math.atan2(-c[1], c[4])
    return math.atan2(c[7], c[8]), pitch, math.atan2(c[3], c[0])


@njit(**_JIT_CORE)
def _triad(fx, fy, fz, use_mag, mx, my, mz, use_ref, rx, ry, rz):
    """filters.base.triad on scalars: roll and pitch from the specific force, yaw from the magnetometer."""
    nf = math.sqrt(fx * fx + fy * fy + fz * fz)
    ux, uy, uz = fx / nf, fy / nf, fz / nf
    roll = math.atan2(-uy, -uz)
    pitch = math.asin(min(max(ux, -1.0), 1.0))
    q = _quat_from_euler(roll, pitch, 0.0)
    if not use_mag:
        return q
    c = _dcm9(q[0], q[1], q[2], q[3])
    l0 = c[0] * mx + c[1] * my + c[2] * mz
    l1 = c[3] * mx + c[4] * my + c[5] * mz
    yaw = -math.atan2(l1, l0)
    decl = math.atan2(ry, rx) if use_ref else 0.0
    return _quat_from_euler(roll, pitch, yaw + decl)


@njit(**_JIT_CORE)
def _wrap_pi(x):
    """``(x + pi) % (2 pi) - pi`` with numpy's (floored) remainder."""
    two_pi = 2.0 * math.pi
    r = np.fmod(x + math.pi, two_pi)
    if r != 0.0:
        if r < 0.0:
            r += two_pi
    else:
        r = 0.0
    return r - math.pi


@njit(**_JIT_CORE)
def _xi_into(q0, q1, q2, q3, X):
    """Xi(q) (4x3, SPEC 2.3: q_dot = Xi(q) w / 2) into X[:4, :3]."""
    X[0, 0], X[0, 1], X[0, 2] = -q1, -q2, -q3
    X[1, 0], X[1, 1], X[1, 2] = q0, -q3, q2
    X[2, 0], X[2, 1], X[2, 2] = q3, q0, -q1
    X[3, 0], X[3, 1], X[3, 2] = -q2, q1, q0


# --- logging, initialisation --------------------------------------------------------------

