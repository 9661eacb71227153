"""Additive-quaternion models: the state holds the four quaternion parameters themselves.

This is the parameterisation of the paper's EKF and of the baselines it compares with (a
traditional EKF and an additive UKF), and of the 7-state EKF ``x = [q; b_g]`` (SPEC 2.3).
Everything here is plain numpy on single states: quaternions ``q`` are (4,) arrays
``[w, x, y, z]`` (Hamilton, scalar first, ``q_nb`` maps body to nav), vectors are (3,).

Kinematics (SPEC 2.1): ``q_dot = 1/2 Omega(w) q = 1/2 Xi(q) w`` with ``w`` the body rate
(rad/s). Over one IMU step with the rotation increment ``dtheta = (w_m - b) dt`` (rad) the
exact transition is ``q_k = Phi(dtheta) q_{k-1} = q_{k-1} * Exp(dtheta)`` (SPEC 2.2).

Vector observations (SPEC 3.1): a nav vector ``r_n`` seen in the body, ``C_bn(q) r_n``,
written as the homogeneous quadratic form of ``q`` so that its 4-column Jacobian is exact
for any (also non-unit) ``q``; consequently ``H(q) q = 2 h(q)``, which is why the paper's
printed innovation ``z - H x`` is wrong and ``z - h(x)`` is used.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from windahrs.rotation import right_jacobian

__all__ = [
    "Omega",
    "Xi",
    "att_cov_from_quat_cov",
    "ekf7_jacobian",
    "ekf7_process_noise",
    "normalization_jacobian",
    "quat_cov_from_att_cov",
    "transition_exact",
    "transition_picard4",
    "vector_obs",
    "vector_obs_jacobian",
]

F64 = NDArray[np.float64]


def _vec(x: ArrayLike, n: int, name: str) -> F64:
    a = np.asarray(x, dtype=np.float64)
    if a.shape != (n,):
        raise ValueError(f"{name}: expected shape ({n},), found {a.shape}")
    return a


def Omega(w: ArrayLike) -> F64:
    """The 4x4 matrix of ``q * [0, w] = Omega(w) q`` (SPEC 2.1; paper eq. 5 corrected).

    w: (3,) body rate (rad/s) or rotation increment (rad). Returns (4, 4), skew-symmetric,
    so ``exp(Omega t)`` preserves the quaternion norm.
    """
    x, y, z = _vec(w, 3, "w")
    return np.array(
        [
            [0.0, -x, -y, -z],
            [x, 0.0, z, -y],
            [y, -z, 0.0, x],
            [z, y, -x, 0.0],
        ]
    )


def Xi(q: ArrayLike) -> F64:
    """The 4x3 matrix of ``q * [0, v] = Xi(q) v`` (SPEC 2.1).

    q: (4,). For a unit ``q``: ``Xi^T Xi = I3`` and ``Xi Xi^T = I4 - q q^T``; the columns
    span the tangent space of the unit sphere at ``q``.
    """
    q0, q1, q2, q3 = _vec(q, 4, "q")
    return np.array(
        [
            [-q1, -q2, -q3],
            [q0, -q3, q2],
            [q3, q0, -q1],
            [-q2, q1, q0],
        ]
    )


def transition_exact(dtheta: ArrayLike) -> F64:
    """Exact transition ``exp(1/2 Omega(dtheta)) = cos(a/2) I + sin(a/2)/a Omega(dtheta)``.

    dtheta: (3,) rotation increment over the step, rad; ``a = |dtheta|``. Returns (4, 4);
    ``transition_exact(d) @ q == q * Exp(d)`` for a constant rotation axis over the step.
    """
    d = _vec(dtheta, 3, "dtheta")
    a = float(np.linalg.norm(d))
    # np.sinc(x) = sin(pi x)/(pi x) removes the a -> 0 singularity of sin(a/2)/a.
    s = 0.5 * float(np.sinc(a / (2.0 * np.pi)))
    return np.cos(0.5 * a) * np.eye(4) + s * Omega(d)


def transition_picard4(dtheta: ArrayLike) -> F64:
    """Fourth-order Picard (Taylor) transition of the paper, eq. 6 corrected (SPEC 2.2).

    ``(1 - a^2/8 + a^4/384) I + (1/2 - a^2/48) Omega(dtheta)``, ``a^2 = |dtheta|^2``
    (the paper's undefined ``dtheta_0``). dtheta: (3,) rad. Returns (4, 4). Its error
    against :func:`transition_exact` is O(a^5): 2.6e-9 at a = 0.1 rad.
    """
    d = _vec(dtheta, 3, "dtheta")
    a2 = float(d @ d)
    return (1.0 - a2 / 8.0 + a2 * a2 / 384.0) * np.eye(4) + (0.5 - a2 / 48.0) * Omega(d)


def ekf7_jacobian(q_prev: ArrayLike, dtheta: ArrayLike, dt: float) -> F64:
    """Jacobian (7, 7) of the 7-state transition ``[Phi(dtheta) q; b]`` (SPEC 2.3, exact form).

    q_prev: (4,) quaternion before the step; dtheta: (3,) bias-corrected increment
    ``(w_m - b) dt``, rad; dt: step, s. Returns
    ``[[Phi, -(dt/2) Xi(q_k) J_r(dtheta)], [0, I3]]`` with ``q_k = Phi q_prev``.
    """
    Phi = transition_exact(dtheta)
    q_k = Phi @ _vec(q_prev, 4, "q_prev")
    F = np.eye(7)
    F[:4, :4] = Phi
    # d/db of q * Exp((w - b) dt) = q_k * [0, -1/2 J_r db dt]: the right Jacobian, not
    # the first-order Phi Xi(q_prev), keeps F exact for large increments.
    F[:4, 4:] = -0.5 * dt * Xi(q_k) @ right_jacobian(np.asarray(dtheta, dtype=np.float64))
    return F


def ekf7_process_noise(q: ArrayLike, sigma_g: float, sigma_b: float, dt: float) -> F64:
    """Discrete process noise (7, 7) of ``[q; b_g]`` over one step (SPEC 2.3).

    q: (4,) quaternion (unit); sigma_g: gyro white-noise density, rad/s/sqrt(Hz);
    sigma_b: gyro-bias random-walk density, rad/s^2/sqrt(Hz); dt: s. The quaternion block
    has rank 3 (no noise along ``q``): use Joseph-form updates, never invert it.
    """
    X = Xi(q)
    Q = np.zeros((7, 7))
    Q[:4, :4] = (sigma_g**2 * dt / 4.0 + sigma_b**2 * dt**3 / 12.0) * (X @ X.T)
    Q[:4, 4:] = -(sigma_b**2) * dt**2 / 4.0 * X
    Q[4:, :4] = Q[:4, 4:].T
    Q[4:, 4:] = sigma_b**2 * dt * np.eye(3)
    return Q


def _cross(a: F64, b: F64) -> F64:
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def vector_obs(q: ArrayLike, r_n: ArrayLike) -> F64:
    """A nav vector seen in the body, ``C_bn(q) r_n`` (3,) (SPEC 3.1).

    q: (4,) quaternion; r_n: (3,) vector in NED (any unit). Written as the homogeneous
    quadratic form ``(q0^2 - v.v) r + 2 (v.r) v - 2 q0 v x r`` (``v = q[1:]``), equal to
    ``dcm_from_quat(q).T @ r_n`` and scaled by ``|q|^2`` for a non-unit ``q``: the function
    the Jacobian of :func:`vector_obs_jacobian` differentiates.
    """
    qv = _vec(q, 4, "q")
    r = _vec(r_n, 3, "r_n")
    q0, v = qv[0], qv[1:]
    return (q0 * q0 - v @ v) * r + 2.0 * (v @ r) * v - 2.0 * q0 * _cross(v, r)


def vector_obs_jacobian(q: ArrayLike, r_n: ArrayLike) -> F64:
    """Jacobian (3, 4) of :func:`vector_obs` with respect to ``q`` (SPEC 3.1, additive row).

    ``[2 (q0 r - v x r), 2 ((v . r) I + v r^T - r v^T + q0 [r]x)]`` with ``v = q[1:]``.
    Paper eq. 22 with its magnetometer entries corrected (SPEC 8, T21).
    """
    qv = _vec(q, 4, "q")
    r = _vec(r_n, 3, "r_n")
    q0, v = qv[0], qv[1:]
    r_x = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    H = np.empty((3, 4))
    H[:, 0] = 2.0 * (q0 * r - _cross(v, r))
    H[:, 1:] = 2.0 * ((v @ r) * np.eye(3) + np.outer(v, r) - np.outer(r, v) + q0 * r_x)
    return H


def normalization_jacobian(q: ArrayLike) -> F64:
    """Jacobian (4, 4) of ``q / |q|``: ``(I - u u^T) / |q|`` with ``u = q / |q|``.

    Applied to the covariance after every normalisation, ``P <- J P J^T`` (SPEC 2.3), so
    that P keeps no variance along the (meaningless) norm direction.
    """
    qv = _vec(q, 4, "q")
    n = float(np.linalg.norm(qv))
    u = qv / n
    return (np.eye(4) - np.outer(u, u)) / n


def att_cov_from_quat_cov(q: ArrayLike, P_qq: ArrayLike) -> F64:
    """Body-frame attitude-error covariance (3, 3), rad^2, from a quaternion covariance.

    ``P_dtheta = 4 Xi(q)^T P_qq Xi(q)`` (SPEC 2.3), since ``dtheta ~ 2 Xi(q)^T (q_true - q)``
    for a unit ``q``. q: (4,); P_qq: (4, 4).
    """
    X = Xi(q)
    P = np.asarray(P_qq, dtype=np.float64)
    if P.shape != (4, 4):
        raise ValueError(f"P_qq: expected shape (4, 4), found {P.shape}")
    return 4.0 * X.T @ P @ X


def quat_cov_from_att_cov(q: ArrayLike, P_att: ArrayLike) -> F64:
    """Quaternion covariance (4, 4) of a body-frame attitude-error covariance (3, 3), rad^2.

    ``P_qq = 1/4 Xi(q) P_att Xi(q)^T`` (rank 3, nothing along ``q``); the inverse of
    :func:`att_cov_from_quat_cov` for a unit ``q``.
    """
    X = Xi(q)
    P = np.asarray(P_att, dtype=np.float64)
    if P.shape != (3, 3):
        raise ValueError(f"P_att: expected shape (3, 3), found {P.shape}")
    return 0.25 * X @ P @ X.T
