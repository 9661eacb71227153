"""Measurement models of the error-state filters: one prediction function per sensor and
its analytic Jacobian in the error state of a :class:`~windahrs.models.error_state.Layout`
(SPEC 3). Each returns ``(z_hat, H)`` with ``H`` of shape (m, layout.dim). The tests check
every ``H`` against central finite differences of the prediction through
``NominalState.inject``.

Where a filter has no velocity state, the GNSS velocity enters the air-data models as a
known input ``v_n`` (its noise then belongs in R).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from windahrs.models.error_state import Layout, NominalState
from windahrs.rotation import dcm_from_quat, euler_from_quat, skew

__all__ = [
    "air_direction_jacobian",
    "airspeed",
    "air_velocity",
    "gnss_velocity",
    "heading",
    "magnetometer",
    "sideslip",
    "specific_force",
    "vector_body",
]

F64 = NDArray[np.float64]


def _zeros(m: int, layout: Layout) -> F64:
    return np.zeros((m, layout.dim))


def vector_body(layout: Layout, x: NominalState, r_n: F64) -> tuple[F64, F64]:
    """A known nav vector seen in the body: ``y = C_bn r_n``; ``H_att = [y]x`` (SPEC 3.1)."""
    y = dcm_from_quat(x.q_nb).T @ r_n
    H = _zeros(3, layout)
    H[:, layout.sl("att")] = skew(y)
    return y, H


def magnetometer(layout: Layout, x: NominalState, mag_n: F64) -> tuple[F64, F64]:
    """3-D magnetometer (SPEC 3.3) with the hard-iron bias when it is a state:
    ``h = C_bn m_n (+ bm)``; ``H_att = [C_bn m_n]x``, ``H_bm = I``."""
    h, H = vector_body(layout, x, mag_n)
    if layout.has("bm") and x.bm is not None:
        h = h + x.bm
        H[:, layout.sl("bm")] = np.eye(3)
    return h, H


def specific_force(
    layout: Layout, x: NominalState, gravity_n: F64, a_b: F64 | None = None
) -> tuple[F64, F64]:
    """Accelerometer with a known (compensation) acceleration ``a_b`` in body axes (zero:
    gravity only, SPEC 3.2.1/3.2.2): ``h = a_b - C_bn g_n (+ ba)``; ``H_att = [-C_bn g]x``,
    ``H_ba = I`` when the accelerometer bias is a state."""
    y, H = vector_body(layout, x, -gravity_n)
    h = y if a_b is None else y + a_b
    if layout.has("ba") and x.ba is not None:
        h = h + x.ba
        H[:, layout.sl("ba")] = np.eye(3)
    return h, H


def gnss_velocity(layout: Layout, x: NominalState) -> tuple[F64, F64]:
    """GNSS velocity of the INS: ``h = v_n``, ``H_v = I`` (SPEC 3.5)."""
    assert x.v_n is not None
    H = _zeros(3, layout)
    H[:, layout.sl("v")] = np.eye(3)
    return x.v_n.copy(), H


def _air_b(layout: Layout, x: NominalState, v_n: F64 | None) -> tuple[F64, F64, F64]:
    """Air-relative velocity in the body, C_bn, and d(v_air_b)/d(error) (3, n)."""
    C_bn = dcm_from_quat(x.q_nb).T
    v = x.v_n if layout.has("v") else v_n
    if v is None:
        raise ValueError("air data: a velocity is needed (a velocity state or a GNSS velocity input)")
    w = x.wind_n if x.wind_n is not None else np.zeros(3)
    y = C_bn @ (v - w)
    J = _zeros(3, layout)
    J[:, layout.sl("att")] = skew(y)
    if layout.has("wind"):
        J[:, layout.sl("wind")] = -C_bn
    if layout.has("v"):
        J[:, layout.sl("v")] = C_bn
    return y, C_bn, J


def air_velocity(layout: Layout, x: NominalState, v_n: F64 | None = None) -> tuple[F64, F64]:
    """Air-relative velocity vector (pitot + vanes, SPEC 3.4.2): ``h = C_bn (v_n - wind_n)``;
    ``H_att = [h]x``, ``H_wind = -C_bn``, ``H_v = C_bn``."""
    y, _, J = _air_b(layout, x, v_n)
    return y, J


def airspeed(layout: Layout, x: NominalState, v_n: F64 | None = None) -> tuple[F64, F64]:
    """True airspeed ``|v_n - wind_n|`` (SPEC 3.4.4): no attitude information;
    ``H = u^T J`` with u the unit air-relative velocity."""
    y, _, J = _air_b(layout, x, v_n)
    a = float(np.linalg.norm(y))
    u = y / max(a, 1e-9)
    H = (u @ J)[None, :]
    H[:, layout.sl("att")] = 0.0  # exactly zero; rounding would leave ~1e-17
    return np.array([a]), H


def sideslip(layout: Layout, x: NominalState, v_n: F64 | None = None) -> tuple[F64, F64]:
    """Synthetic sideslip ``beta_hat = v_b / u_b`` of the predicted air-relative velocity
    (PX4 form, SPEC 3.4.4): fused with z = 0 on fixed wings in coordinated flight."""
    y, _, J = _air_b(layout, x, v_n)
    u = y[0] if abs(y[0]) > 1e-3 else np.copysign(1e-3, y[0])
    g = np.array([-y[1] / u**2, 1.0 / u, 0.0])
    return np.array([y[1] / u]), (g @ J)[None, :]


def air_direction_jacobian(tas: float, aoa: float, beta: float) -> F64:
    """d(tas * d(aoa, beta)) / d(tas, aoa, beta) (3, 3) (SPEC 3.4.1)."""
    ca, sa, cb, sb = np.cos(aoa), np.sin(aoa), np.cos(beta), np.sin(beta)
    return np.array(
        [
            [ca * cb, -tas * sa * cb, -tas * ca * sb],
            [sb, 0.0, tas * cb],
            [sa * cb, tas * ca * cb, -tas * sa * sb],
        ]
    )


def heading(layout: Layout, x: NominalState) -> tuple[F64, F64]:
    """Yaw of the attitude (ZYX) with ``H_att = [0, sin(roll)/cos(pitch), cos(roll)/cos(pitch)]``
    (SPEC 3.3 heading-only fusion). Singular at pitch = +-90 deg."""
    roll, pitch, yaw = euler_from_quat(x.q_nb)
    H = _zeros(1, layout)
    H[0, layout.sl("att")] = [0.0, np.sin(roll) / np.cos(pitch), np.cos(roll) / np.cos(pitch)]
    return np.array([yaw]), H
