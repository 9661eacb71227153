"""Additive-quaternion models: the state holds the four quaternion parameters themselves.

This is the parameterisation of the paper's EKF and of the baselines it compares with (a
traditional EKF and an additive UKF), and of the 7-state EKF ``x = [q; b_g]`` (SPEC 2.3).
Quaternions ``q`` are (4,) float64 arrays ``[w, x, y, z]`` (Hamilton, scalar first,
``q_nb`` maps body to nav), vectors are (3,) float64 arrays.

Every function is a numba ``@njit`` function: the compiled filters call them from their
event loops and Python calls the very same functions (the tests check these, e.g. against
finite differences). With ``NUMBA_DISABLE_JIT=1`` the same source runs as plain Python.
Arguments must be float64 numpy arrays (no lists); a wrong shape raises ValueError naming
the argument.

Kinematics (SPEC 2.1): ``q_dot = 1/2 Omega(w) q = 1/2 Xi(q) w`` with ``w`` the body rate
(rad/s). Over one IMU step with the rotation increment ``dtheta = (w_m - b) dt`` (rad) the
exact transition is ``q_k = Phi(dtheta) q_{k-1} = q_{k-1} * Exp(dtheta)`` (SPEC 2.2).

Vector observations (SPEC 3.1): a nav vector ``r_n`` seen in the body, ``C_bn(q) r_n``,
written as the homogeneous quadratic form of ``q`` so that its 4-column Jacobian is exact
for any (also non-unit) ``q``; consequently ``H(q) q = 2 h(q)``, which is why the paper's
printed innovation ``z - H x`` is wrong and ``z - h(x)`` is used.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from windahrs.core.dense import project_leading

__all__ = [
    "Omega",
    "Xi",
    "att_cov_from_quat_cov",
    "ekf7_jacobian",
    "ekf7_process_noise",
    "normalization_jacobian",
    "normalize_state",
    "project_normalization",
    "quat_cov_from_att_cov",
    "sinc",
    "transition_exact",
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
def sinc(x):
    """numpy.sinc of a float, with numpy's arithmetic: ``sin(pi x)/(pi x)``, 1 at 0."""
    y = np.pi * x
    if y == 0.0:
        y = np.finfo(np.float64).eps
    return math.sin(y) / y


@njit(**_JIT)
def _diag_plus(c, s, M):
    """``c I + s M`` for a (4, 4) M."""
    out = s * M
    for i in range(4):
        out[i, i] += c
    return out


@njit(**_JIT)
def transition_exact(dtheta):
    """Exact transition ``exp(1/2 Omega(dtheta)) = cos(a/2) I + sin(a/2)/a Omega(dtheta)``.

    dtheta: (3,) rotation increment over the step, rad; ``a = |dtheta|``. Returns (4, 4);
    ``transition_exact(d) @ q == q * Exp(d)`` for a constant rotation axis over the step.
    """
    _check(dtheta, 3, "dtheta: expected shape (3,)")
    a = math.sqrt(dtheta[0] ** 2 + dtheta[1] ** 2 + dtheta[2] ** 2)
    # sinc(x) = sin(pi x)/(pi x) removes the a -> 0 singularity of sin(a/2)/a.
    s = 0.5 * sinc(a / (2.0 * np.pi))
    return _diag_plus(math.cos(0.5 * a), s, Omega(dtheta))


@njit(**_JIT)
def transition_picard4(dtheta):
    """Fourth-order Picard (Taylor) transition of the paper, eq. 6 corrected (SPEC 2.2).

    ``(1 - a^2/8 + a^4/384) I + (1/2 - a^2/48) Omega(dtheta)``, ``a^2 = |dtheta|^2``
    (the paper's undefined ``dtheta_0``). dtheta: (3,) rad. Returns (4, 4). Its error
    against :func:`transition_exact` is O(a^5): 2.6e-9 at a = 0.1 rad.
    """
    _check(dtheta, 3, "dtheta: expected shape (3,)")
    a2 = dtheta[0] ** 2 + dtheta[1] ** 2 + dtheta[2] ** 2
    return _diag_plus(1.0 - a2 / 8.0 + a2 * a2 / 384.0, 0.5 - a2 / 48.0, Omega(dtheta))


@njit(**_JIT)
def _right_jacobian(phi):
    """Right Jacobian of SO(3), ``J_r(phi)`` (3, 3) (SPEC 2.3), as rotation.right_jacobian."""
    a = math.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    if a < 1e-5:
        c1, c2 = 0.5 - a**2 / 24.0, 1.0 / 6.0 - a**2 / 120.0
    else:
        c1, c2 = (1.0 - math.cos(a)) / a**2, (a - math.sin(a)) / a**3
    k = np.zeros((3, 3))
    k[0, 1], k[0, 2], k[1, 2] = -phi[2], phi[1], -phi[0]
    k[1, 0], k[2, 0], k[2, 1] = phi[2], -phi[1], phi[0]
    return np.eye(3) - c1 * k + c2 * (k @ k)


@njit(**_JIT)
def ekf7_jacobian(q_prev, dtheta, dt):
    """Jacobian (7, 7) of the 7-state transition ``[Phi(dtheta) q; b]`` (SPEC 2.3, exact form).

    q_prev: (4,) quaternion before the step; dtheta: (3,) bias-corrected increment
    ``(w_m - b) dt``, rad; dt: step, s. Returns
    ``[[Phi, -(dt/2) Xi(q_k) J_r(dtheta)], [0, I3]]`` with ``q_k = Phi q_prev``.
    """
    _check(q_prev, 4, "q_prev: expected shape (4,)")
    Phi = transition_exact(dtheta)
    q_k = Phi @ np.ascontiguousarray(q_prev)
    F = np.eye(7)
    F[:4, :4] = Phi
    # d/db of q * Exp((w - b) dt) = q_k * [0, -1/2 J_r db dt]: the right Jacobian, not
    # the first-order Phi Xi(q_prev), keeps F exact for large increments.
    F[:4, 4:] = -0.5 * dt * Xi(q_k) @ _right_jacobian(dtheta)
    return F


@njit(**_JIT)
def ekf7_process_noise(q, sigma_g, sigma_b, dt):
    """Discrete process noise (7, 7) of ``[q; b_g]`` over one step (SPEC 2.3).

    q: (4,) quaternion (unit); sigma_g: gyro white-noise density, rad/s/sqrt(Hz);
    sigma_b: gyro-bias random-walk density, rad/s^2/sqrt(Hz); dt: s. The quaternion block
    has rank 3 (no noise along ``q``): use Joseph-form updates, never invert it.
    """
    X = Xi(q)
    Q = np.zeros((7, 7))
    c = sigma_g**2 * dt / 4.0 + sigma_b**2 * dt**3 / 12.0
    for i in range(4):  # c X X^T, in loops (a BLAS call per step was a third of the UKF's time)
        for j in range(4):
            Q[i, j] = c * (X[i, 0] * X[j, 0] + X[i, 1] * X[j, 1] + X[i, 2] * X[j, 2])
    Q[:4, 4:] = -(sigma_b**2) * dt**2 / 4.0 * X
    Q[4:, :4] = Q[:4, 4:].T
    for i in range(4, 7):
        Q[i, i] = sigma_b**2 * dt
    return Q


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
def _norm_q(q):
    """|q| (4,) as numpy.linalg.norm computes it (a BLAS dot)."""
    qc = np.ascontiguousarray(q)
    return math.sqrt(np.dot(qc, qc))


@njit(**_JIT)
def _jacobian_of_norm(q, n):
    J = np.empty((4, 4))
    for i in range(4):
        ui = q[i] / n
        for j in range(4):
            J[i, j] = ((1.0 if i == j else 0.0) - ui * (q[j] / n)) / n
    return J


@njit(**_JIT)
def normalization_jacobian(q):
    """Jacobian (4, 4) of ``q / |q|``: ``(I - u u^T) / |q|`` with ``u = q / |q|``.

    Applied to the covariance after every normalisation, ``P <- J P J^T`` (SPEC 2.3), so
    that P keeps no variance along the (meaningless) norm direction.
    """
    _check(q, 4, "q: expected shape (4,)")
    return _jacobian_of_norm(q, _norm_q(q))


@njit(**_JIT)
def _project(P, J4):
    n = P.shape[0]
    if n == 4:
        # the paper's and the traditional EKF's 4x4: plain loops, no BLAS call
        A = np.empty((4, 4))
        for i in range(4):
            for j in range(4):
                A[i, j] = J4[i, 0] * P[0, j] + J4[i, 1] * P[1, j] + J4[i, 2] * P[2, j] + J4[i, 3] * P[3, j]
        out = np.empty((4, 4))
        for i in range(4):
            for j in range(4):
                out[i, j] = A[i, 0] * J4[j, 0] + A[i, 1] * J4[j, 1] + A[i, 2] * J4[j, 2] + A[i, 3] * J4[j, 3]
        return out
    return project_leading(P, J4)


@njit(**_JIT)
def project_normalization(P, q):
    """``J P J^T`` (n, n) with ``J = blkdiag(normalization_jacobian(q), I)``: the
    covariance P (n, n) of a state starting with the quaternion q (4,), carried through
    ``q -> q/|q|``. Returns a new array (the 4x4 unrolled, larger ones by
    :func:`windahrs.core.dense.project_leading`)."""
    return _project(P, normalization_jacobian(q))


@njit(**_JIT)
def normalize_state(x, P):
    """``q <- q/|q|`` (w >= 0) and ``P <- J P J^T`` symmetrised (SPEC 2.3), for a state x
    (n,) starting with the quaternion and its covariance P (n, n). Returns new (x, P)."""
    n = _norm_q(x[:4])
    P2 = _project(P, _jacobian_of_norm(x, n))  # (n == 4: unrolled)
    x2 = x.copy()
    c = math.copysign(1.0, x[0]) / n
    for i in range(4):
        x2[i] = x[i] * c
    m = P2.shape[0]
    # The sign flip to w >= 0 is J -> -J on the quaternion: its own block is unchanged,
    # its covariance with the rest (the UKF's bias) changes sign.
    if c < 0.0:
        for i in range(4):
            for j in range(4, m):
                P2[i, j] = -P2[i, j]
                P2[j, i] = -P2[j, i]
    out = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            out[i, j] = 0.5 * (P2[i, j] + P2[j, i])
    return x2, out


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
