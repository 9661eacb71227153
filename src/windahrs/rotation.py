"""Quaternion and SO(3) functions on arrays.

Every function broadcasts over leading axes: quaternions are ``(..., 4)`` arrays
``[w, x, y, z]`` (Hamilton, scalar first), rotation vectors and 3-vectors ``(..., 3)``,
matrices ``(..., 3, 3)``. ``q_nb`` maps body to nav (see :mod:`windahrs.conventions`).
Functions return new arrays and never modify their inputs.

Composition order: ``quat_mul(p, q)`` is ``p * q``; ``dcm(quat_mul(p, q)) ==
dcm(p) @ dcm(q)``. Body-frame (right) perturbation: ``q = q_hat * Exp(dtheta)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from windahrs.conventions import P_ENU_NED

__all__ = [
    "air_direction",
    "circular_mean",
    "dcm_from_quat",
    "euler_from_quat",
    "euler_rate_map",
    "quat_angle",
    "quat_conj",
    "quat_exp",
    "quat_from_dcm",
    "quat_from_euler",
    "quat_identity",
    "quat_log",
    "quat_mul",
    "quat_normalize",
    "quat_ned_frd_to_enu_flu",
    "quat_ned_frd_to_enu_rfu",
    "quat_enu_flu_to_ned_frd",
    "quat_enu_rfu_to_ned_frd",
    "quat_nav_enu_to_ned",
    "quat_rotate",
    "quat_rotate_inv",
    "right_jacobian",
    "skew",
    "twist_angle",
    "vec_enu_to_ned",
    "vec_ned_to_enu",
]

F64 = NDArray[np.float64]

#: |R31| above ``1 - GIMBAL_EPS`` is treated as gimbal lock when extracting Euler angles.
GIMBAL_EPS = 1e-9

_Q_P = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])  # quaternion of P_ENU_NED
_Q_X180 = np.array([0.0, 1.0, 0.0, 0.0])  # FLU <-> FRD body axes, diag(1, -1, -1)


def _arr(x: ArrayLike) -> F64:
    return np.asarray(x, dtype=np.float64)


def quat_identity(shape: tuple[int, ...] = ()) -> F64:
    """Identity quaternion(s) of shape ``shape + (4,)``."""
    q = np.zeros((*shape, 4))
    q[..., 0] = 1.0
    return q


def quat_mul(p: ArrayLike, q: ArrayLike) -> F64:
    """Hamilton product ``p * q`` of ``(..., 4)`` quaternions."""
    p, q = _arr(p), _arr(q)
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_conj(q: ArrayLike) -> F64:
    """Conjugate ``q^*`` (the inverse of a unit quaternion)."""
    q = _arr(q)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_normalize(q: ArrayLike) -> F64:
    """Unit quaternion with ``w >= 0`` (``q`` and ``-q`` are the same rotation)."""
    q = _arr(q)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    sign = np.where(q[..., :1] < 0.0, -1.0, 1.0)
    return q * sign / n


def quat_rotate(q_nb: ArrayLike, v_b: ArrayLike) -> F64:
    """Rotate body vectors into nav: ``v_n = C_nb v_b = q v q^*``; shapes (...,4), (...,3)."""
    q, v = _arr(q_nb), _arr(v_b)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * _cross(u, v)
    return v + w * t + _cross(u, t)


def _cross(a: F64, b: F64) -> F64:
    """``np.cross`` of 3-vectors (..., 3), the same products and differences, without its
    generic axis handling (which made it most of the tilt check's rotation)."""
    a0, a1, a2, b0, b1, b2 = a[..., 0], a[..., 1], a[..., 2], b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def quat_rotate_inv(q_nb: ArrayLike, v_n: ArrayLike) -> F64:
    """Rotate nav vectors into body: ``v_b = C_bn v_n = q^* v q``."""
    return quat_rotate(quat_conj(q_nb), v_n)


def quat_exp(phi: ArrayLike) -> F64:
    """``Exp``: rotation vector (..., 3) in rad to unit quaternion (..., 4)."""
    phi = _arr(phi)
    a = np.linalg.norm(phi, axis=-1, keepdims=True)
    # sin(a/2)/a without a removable singularity: np.sinc(x) = sin(pi x)/(pi x).
    s = 0.5 * np.sinc(a / (2.0 * np.pi))
    return np.concatenate([np.cos(0.5 * a), s * phi], axis=-1)


def quat_log(q: ArrayLike) -> F64:
    """``Log``: unit quaternion (..., 4) to the shortest rotation vector (..., 3), rad.

    ``q`` and ``-q`` give the same result; the angle lies in [0, pi].
    """
    q = _arr(q)
    sign = np.where(q[..., :1] < 0.0, -1.0, 1.0)
    w = q[..., :1] * sign
    u = q[..., 1:] * sign
    n = np.linalg.norm(u, axis=-1, keepdims=True)
    # angle/n -> 2/w as n -> 0; w > 0 there, so no division by zero.
    safe_n = np.where(n > 1e-12, n, 1.0)
    scale = np.where(n > 1e-12, 2.0 * np.arctan2(n, w) / safe_n, 2.0 / np.maximum(w, 1e-300))
    return scale * u


def twist_angle(q: ArrayLike) -> F64:
    """The angle (..., ) rad of each quaternion's twist about the z axis (the part of a
    nav-frame rotation ``q_a * q_b^-1`` that is a heading change): ``2 atan2(q_z, q_w)``, in
    (-2 pi, 2 pi]."""
    q = _arr(q)
    return 2.0 * np.arctan2(q[..., 3], q[..., 0])


def circular_mean(angle: ArrayLike) -> float:
    """The mean direction of angles (rad): ``atan2(mean sin, mean cos)``, in [-pi, pi]."""
    a = _arr(angle)
    return math.atan2(float(np.mean(np.sin(a))), float(np.mean(np.cos(a))))


def quat_angle(q_a: ArrayLike, q_b: ArrayLike) -> F64:
    """Angle (rad) of the rotation between two attitudes, in [0, pi]; shape (...)."""
    d = quat_mul(quat_conj(q_a), q_b)
    return np.linalg.norm(quat_log(d), axis=-1)


def skew(v: ArrayLike) -> F64:
    """Skew matrix ``[v]x`` (..., 3, 3) with ``[v]x u = v x u``."""
    v = _arr(v)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(
        [np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2
    )


def right_jacobian(phi: ArrayLike) -> F64:
    """Right Jacobian of SO(3), ``J_r(phi)`` (..., 3, 3) (SPEC 2.3)."""
    phi = _arr(phi)
    a = np.linalg.norm(phi, axis=-1)[..., None, None]
    small = a < 1e-5
    a_safe = np.where(small, 1.0, a)
    c1 = np.where(small, 0.5 - a**2 / 24.0, (1.0 - np.cos(a_safe)) / a_safe**2)
    c2 = np.where(small, 1.0 / 6.0 - a**2 / 120.0, (a_safe - np.sin(a_safe)) / a_safe**3)
    k = skew(phi)
    return np.eye(3) - c1 * k + c2 * (k @ k)


def dcm_from_quat(q_nb: ArrayLike) -> F64:
    """Direction cosine matrix ``C_nb`` (..., 3, 3) from unit ``q_nb`` (SPEC 1.3)."""
    q = _arr(q_nb)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z], -1),
        ],
        -2,
    )


def quat_from_dcm(C_nb: ArrayLike) -> F64:
    """Unit quaternion (w >= 0) from a rotation matrix ``C_nb`` (..., 3, 3).

    Shepperd's method: row ``j`` of the table below equals ``4 q_j q``; the row with the
    largest ``q_j`` is normalised, so every rotation (180 deg turns included) is accurate.
    """
    C = _arr(C_nb)
    m00, m01, m02 = C[..., 0, 0], C[..., 0, 1], C[..., 0, 2]
    m10, m11, m12 = C[..., 1, 0], C[..., 1, 1], C[..., 1, 2]
    m20, m21, m22 = C[..., 2, 0], C[..., 2, 1], C[..., 2, 2]
    rows = np.stack(
        [
            np.stack([1 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01], -1),
            np.stack([m21 - m12, 1 + m00 - m11 - m22, m01 + m10, m02 + m20], -1),
            np.stack([m02 - m20, m01 + m10, 1 - m00 + m11 - m22, m12 + m21], -1),
            np.stack([m10 - m01, m02 + m20, m12 + m21, 1 - m00 - m11 + m22], -1),
        ],
        -2,
    )
    diag = np.stack([rows[..., j, j] for j in range(4)], -1)
    k = np.argmax(diag, axis=-1)
    best = np.take_along_axis(rows, k[..., None, None], axis=-2)[..., 0, :]
    return quat_normalize(best)


def euler_from_quat(q_nb: ArrayLike, *, gimbal_eps: float = GIMBAL_EPS) -> F64:
    """Aerospace ZYX Euler angles ``[roll, pitch, yaw]`` (..., 3), rad (SPEC 1.4).

    ``C_nb = Rz(yaw) Ry(pitch) Rx(roll)``; roll and yaw in (-pi, pi], pitch in
    [-pi/2, pi/2]. At gimbal lock (``|C31| > 1 - gimbal_eps``) only yaw -/+ roll is
    defined: roll is set to 0 and yaw takes the whole angle, which reproduces ``C_nb``.
    """
    C = dcm_from_quat(q_nb)
    r31 = np.clip(C[..., 2, 0], -1.0, 1.0)
    pitch = -np.arcsin(r31)
    lock = np.abs(r31) > 1.0 - gimbal_eps
    roll = np.where(lock, 0.0, np.arctan2(C[..., 2, 1], C[..., 2, 2]))
    yaw = np.where(
        lock, np.arctan2(-C[..., 0, 1], C[..., 1, 1]), np.arctan2(C[..., 1, 0], C[..., 0, 0])
    )
    return np.stack([roll, pitch, yaw], -1)


def quat_from_euler(rpy: ArrayLike) -> F64:
    """Unit quaternion from ZYX Euler angles ``[roll, pitch, yaw]`` (..., 3), rad."""
    rpy = _arr(rpy)
    h = 0.5 * rpy
    cr, sr = np.cos(h[..., 0]), np.sin(h[..., 0])
    cp, sp = np.cos(h[..., 1]), np.sin(h[..., 1])
    cy, sy = np.cos(h[..., 2]), np.sin(h[..., 2])
    q = np.stack(
        [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ],
        -1,
    )
    return quat_normalize(q)


def euler_rate_map(roll: ArrayLike, pitch: ArrayLike) -> F64:
    """``T = d(roll, pitch, yaw)/d(dtheta_body)`` (..., 3, 3) (SPEC 1.4).

    Maps a body-frame attitude error (or body rate) to Euler angle errors (rates);
    ``P_euler = T P_dtheta T^T``. Singular at pitch = +-90 deg.
    """
    r, p = _arr(roll), _arr(pitch)
    sr, cr, tp, cp = np.sin(r), np.cos(r), np.tan(p), np.cos(p)
    one, zero = np.ones_like(r), np.zeros_like(r)
    return np.stack(
        [
            np.stack([one, sr * tp, cr * tp], -1),
            np.stack([zero, cr, -sr], -1),
            np.stack([zero, sr / cp, cr / cp], -1),
        ],
        -2,
    )


def air_direction(aoa: ArrayLike, sideslip: ArrayLike) -> F64:
    """Unit air-relative velocity in FRD body axes (..., 3) from angle of attack and
    sideslip (rad): ``C_wb [1, 0, 0] = [cos a cos b, sin b, sin a cos b]`` (SPEC 3.4.1)."""
    a, b = _arr(aoa), _arr(sideslip)
    return np.stack([np.cos(a) * np.cos(b), np.sin(b), np.sin(a) * np.cos(b)], -1)


# --- frame conversions at the I/O edge (SPEC 1.5) ------------------------------------


def vec_enu_to_ned(v: ArrayLike) -> F64:
    """ENU vector(s) to NED (also RFU body to FRD body): ``[e, n, u] -> [n, e, -u]``."""
    return _arr(v) @ P_ENU_NED.T


def vec_ned_to_enu(v: ArrayLike) -> F64:
    """NED vector(s) to ENU (also FRD to RFU); the same matrix, its own inverse."""
    return _arr(v) @ P_ENU_NED.T


def quat_nav_enu_to_ned(q_enu_b: ArrayLike) -> F64:
    """Re-express an attitude of body ``b`` w.r.t. ENU as one w.r.t. NED (body unchanged)."""
    return quat_normalize(quat_mul(_Q_P, q_enu_b))


def quat_enu_rfu_to_ned_frd(q: ArrayLike) -> F64:
    """Attitude of an RFU body in ENU (the paper's frames) to FRD body in NED."""
    return quat_normalize(quat_mul(quat_mul(_Q_P, q), quat_conj(_Q_P)))


def quat_ned_frd_to_enu_rfu(q: ArrayLike) -> F64:
    """Inverse of :func:`quat_enu_rfu_to_ned_frd`."""
    return quat_normalize(quat_mul(quat_mul(quat_conj(_Q_P), q), _Q_P))


def quat_enu_flu_to_ned_frd(q: ArrayLike) -> F64:
    """Attitude of a FLU body in ENU (ROS REP-103) to FRD body in NED."""
    return quat_normalize(quat_mul(quat_mul(_Q_P, q), _Q_X180))


def quat_ned_frd_to_enu_flu(q: ArrayLike) -> F64:
    """Inverse of :func:`quat_enu_flu_to_ned_frd`."""
    return quat_normalize(quat_mul(quat_mul(quat_conj(_Q_P), q), quat_conj(_Q_X180)))
