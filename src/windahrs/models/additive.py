"""Additive-quaternion models: the state holds the four quaternion parameters themselves.

This is the parameterisation of the paper's EKF and of the baselines it compares with (a
traditional EKF and an additive UKF). This module holds what is theirs alone: the paper's
Picard-4 transition (eq. 6), the vector observations on the quaternion's four parameters
and the maps between the quaternion's covariance and the
attitude error's. The exact transition, its Jacobian, SPEC 2.3's process noise and the
normalisation with its covariance projection are the compiled core's
(``windahrs.core.predict``: ``_predict_add``, ``_noise_add``, ``_normalise_add``), which
[ekf7], [ekf10], [ekf] and [ukf] share.
Quaternions ``q`` are (4,) float64 arrays ``[w, x, y, z]`` (Hamilton, scalar first,
``q_nb`` maps body to nav), vectors are (3,) float64 arrays.

Every function is a numba ``@njit`` function: the compiled filters call them from their
event loops and Python calls the very same functions (the tests check these, e.g. against
finite differences). With ``NUMBA_DISABLE_JIT=1`` the same source runs as plain Python.
Arguments must be float64 numpy arrays (no lists); a wrong shape raises ValueError naming
the argument.

Kinematics (SPEC 2.1): ``q_dot = 1/2 Omega(w) q = 1/2 Xi(q) w`` with ``w`` the body rate
(rad/s). Over one IMU step with the rotation increment ``dtheta = (w_m - b) dt`` (rad) the
exact transition is ``q_k = exp(1/2 Omega(dtheta)) q_{k-1} = q_{k-1} * Exp(dtheta)``
(SPEC 2.2); the paper truncates it to fourth order (:func:`transition_picard4`).

Vector observations (SPEC 3.1): a nav vector ``r_n`` seen in the body, ``C_bn(q) r_n``,
written as the homogeneous quadratic form of ``q`` so that its 4-column Jacobian is exact
for any (also non-unit) ``q``; consequently ``H(q) q = 2 h(q)``, which is why the paper's
printed innovation ``z - H x`` is wrong and ``z - h(x)`` is used.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit

__all__ = [
    "Omega",
    "Xi",
    "att_cov_from_quat_cov",
    "quat_cov_from_att_cov",
    "transition_picard4",
    "vector_obs",
    "vector_obs_jacobian",
]

_JIT: dict[str, Any] = {"cache": True, "error_model": "numpy"}


@njit(**_JIT)
def _check(a, n, msg):
    if a.ndim != 1 or a.shape[0] != n:
        raise ValueError(msg)


@njit(**_JIT)
def Omega(w):
    """The 4x4 matrix of ``q * [0, w] = Omega(w) q`` (SPEC 2.1; paper eq. 5 corrected).

    w: (3,) body rate (rad/s) or rotation increment (rad). Returns (4, 4), skew-symmetric,
    so ``exp(Omega t)`` preserves the quaternion norm.
    """
    _check(w, 3, "w: expected shape (3,)")
    x, y, z = w[0], w[1], w[2]
    M = np.zeros((4, 4))
    M[0, 1], M[0, 2], M[0, 3] = -x, -y, -z
    M[1, 0], M[1, 2], M[1, 3] = x, z, -y
    M[2, 0], M[2, 1], M[2, 3] = y, -z, x
    M[3, 0], M[3, 1], M[3, 2] = z, y, -x
    return M


@njit(**_JIT)
def Xi(q):
    """The 4x3 matrix of ``q * [0, v] = Xi(q) v`` (SPEC 2.1).

    q: (4,). For a unit ``q``: ``Xi^T Xi = I3`` and ``Xi Xi^T = I4 - q q^T``; the columns
    span the tangent space of the unit sphere at ``q``.
    """
    _check(q, 4, "q: expected shape (4,)")
    q0, q1, q2, q3 = q[0], q[1], q[2], q[3]
    X = np.empty((4, 3))
    X[0, 0], X[0, 1], X[0, 2] = -q1, -q2, -q3
    X[1, 0], X[1, 1], X[1, 2] = q0, -q3, q2
    X[2, 0], X[2, 1], X[2, 2] = q3, q0, -q1
    X[3, 0], X[3, 1], X[3, 2] = -q2, q1, q0
    return X


@njit(**_JIT)
def _diag_plus(c, s, M):
    """``c I + s M`` for a (4, 4) M."""
    out = s * M
    for i in range(4):
        out[i, i] += c
    return out


@njit(**_JIT)
def transition_picard4(dtheta):
    """Fourth-order Picard (Taylor) transition of the paper, eq. 6 corrected (SPEC 2.2).

    ``(1 - a^2/8 + a^4/384) I + (1/2 - a^2/48) Omega(dtheta)``, ``a^2 = |dtheta|^2``
    (the paper's undefined ``dtheta_0``). dtheta: (3,) rad. Returns (4, 4). Its error
    against the exact ``exp(1/2 Omega(dtheta))`` is O(a^5): 2.6e-9 at a = 0.1 rad.
    """
    _check(dtheta, 3, "dtheta: expected shape (3,)")
    a2 = dtheta[0] ** 2 + dtheta[1] ** 2 + dtheta[2] ** 2
    return _diag_plus(1.0 - a2 / 8.0 + a2 * a2 / 384.0, 0.5 - a2 / 48.0, Omega(dtheta))


@njit(**_JIT)
def vector_obs(q, r_n):
    """A nav vector seen in the body, ``C_bn(q) r_n`` (3,) (SPEC 3.1).

    q: (4,) quaternion; r_n: (3,) vector in NED (any unit). Written as the homogeneous
    quadratic form ``(q0^2 - v.v) r + 2 (v.r) v - 2 q0 v x r`` (``v = q[1:]``), equal to
    ``dcm_from_quat(q).T @ r_n`` and scaled by ``|q|^2`` for a non-unit ``q``: the function
    the Jacobian of :func:`vector_obs_jacobian` differentiates.
    """
    _check(q, 4, "q: expected shape (4,)")
    _check(r_n, 3, "r_n: expected shape (3,)")
    q0, v0, v1, v2 = q[0], q[1], q[2], q[3]
    r0, r1, r2 = r_n[0], r_n[1], r_n[2]
    a = q0 * q0 - (v0 * v0 + v1 * v1 + v2 * v2)
    b = 2.0 * (v0 * r0 + v1 * r1 + v2 * r2)
    out = np.empty(3)
    out[0] = a * r0 + b * v0 - 2.0 * q0 * (v1 * r2 - v2 * r1)
    out[1] = a * r1 + b * v1 - 2.0 * q0 * (v2 * r0 - v0 * r2)
    out[2] = a * r2 + b * v2 - 2.0 * q0 * (v0 * r1 - v1 * r0)
    return out


@njit(**_JIT)
def vector_obs_jacobian(q, r_n):
    """Jacobian (3, 4) of :func:`vector_obs` with respect to ``q`` (SPEC 3.1, additive row).

    ``[2 (q0 r - v x r), 2 ((v . r) I + v r^T - r v^T + q0 [r]x)]`` with ``v = q[1:]``.
    Paper eq. 22 with its magnetometer entries corrected (SPEC 8, T21).
    """
    _check(q, 4, "q: expected shape (4,)")
    _check(r_n, 3, "r_n: expected shape (3,)")
    q0, v0, v1, v2 = q[0], q[1], q[2], q[3]
    r0, r1, r2 = r_n[0], r_n[1], r_n[2]
    vr = v0 * r0 + v1 * r1 + v2 * r2
    H = np.empty((3, 4))
    # column 0: 2 (q0 r - v x r)
    H[0, 0] = 2.0 * (q0 * r0 - (v1 * r2 - v2 * r1))
    H[1, 0] = 2.0 * (q0 * r1 - (v2 * r0 - v0 * r2))
    H[2, 0] = 2.0 * (q0 * r2 - (v0 * r1 - v1 * r0))
    # columns 1..3: 2 ((v . r) I + v r^T - r v^T + q0 [r]x)
    H[0, 1] = 2.0 * vr
    H[0, 2] = 2.0 * (v0 * r1 - r0 * v1 - q0 * r2)
    H[0, 3] = 2.0 * (v0 * r2 - r0 * v2 + q0 * r1)
    H[1, 1] = 2.0 * (v1 * r0 - r1 * v0 + q0 * r2)
    H[1, 2] = 2.0 * vr
    H[1, 3] = 2.0 * (v1 * r2 - r1 * v2 - q0 * r0)
    H[2, 1] = 2.0 * (v2 * r0 - r2 * v0 - q0 * r1)
    H[2, 2] = 2.0 * (v2 * r1 - r2 * v1 + q0 * r0)
    H[2, 3] = 2.0 * vr
    return H


@njit(**_JIT)
def att_cov_from_quat_cov(q, P_qq):
    """Body-frame attitude-error covariance (3, 3), rad^2, from a quaternion covariance.

    ``P_dtheta = 4 Xi(q)^T P_qq Xi(q)`` (SPEC 2.3), since ``dtheta ~ 2 Xi(q)^T (q_true - q)``
    for a unit ``q``. q: (4,); P_qq: (4, 4).
    """
    if P_qq.shape != (4, 4):
        raise ValueError("P_qq: expected shape (4, 4)")
    X = Xi(q)
    PX = np.zeros((4, 3))
    for a in range(4):
        for j in range(3):
            s = 0.0
            for b in range(4):
                s += P_qq[a, b] * X[b, j]
            PX[a, j] = s
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            s = 0.0
            for a in range(4):
                s += X[a, i] * PX[a, j]
            out[i, j] = 4.0 * s
    return out


@njit(**_JIT)
def quat_cov_from_att_cov(q, P_att):
    """Quaternion covariance (4, 4) of a body-frame attitude-error covariance (3, 3), rad^2.

    ``P_qq = 1/4 Xi(q) P_att Xi(q)^T`` (rank 3, nothing along ``q``); the inverse of
    :func:`att_cov_from_quat_cov` for a unit ``q``.
    """
    if P_att.shape != (3, 3):
        raise ValueError("P_att: expected shape (3, 3)")
    X = Xi(q)
    return 0.25 * X @ np.ascontiguousarray(P_att) @ X.T
