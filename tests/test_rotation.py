"""Rotation functions against scipy's Rotation, group axioms, Euler and frame conversions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from windahrs import rotation as r
from windahrs.conventions import P_ENU_NED

N = 2000


@pytest.fixture
def qs() -> np.ndarray:
    q = Rotation.random(N, random_state=7).as_quat(scalar_first=True)
    return q


def test_product_conjugate_rotate_match_scipy(qs: np.ndarray) -> None:
    p = Rotation.random(N, random_state=8).as_quat(scalar_first=True)
    R_q = Rotation.from_quat(qs, scalar_first=True)
    R_p = Rotation.from_quat(p, scalar_first=True)
    prod = r.quat_mul(p, qs)
    expected = (R_p * R_q).as_quat(scalar_first=True)
    assert np.allclose(r.quat_normalize(prod), r.quat_normalize(expected), atol=1e-12)
    v = np.random.default_rng(1).normal(size=(N, 3))
    assert np.allclose(r.quat_rotate(qs, v), R_q.apply(v), atol=1e-12)
    assert np.allclose(r.quat_rotate_inv(qs, v), R_q.inv().apply(v), atol=1e-12)
    assert np.allclose(r.dcm_from_quat(qs), R_q.as_matrix(), atol=1e-12)
    assert np.allclose(r.quat_mul(qs, r.quat_conj(qs)), r.quat_identity((N,)), atol=1e-12)


def test_exp_log_match_scipy_rotvec(qs: np.ndarray) -> None:
    R_q = Rotation.from_quat(qs, scalar_first=True)
    assert np.allclose(r.quat_log(qs), R_q.as_rotvec(), atol=1e-12)
    phi = R_q.as_rotvec()
    assert np.allclose(r.quat_normalize(r.quat_exp(phi)), r.quat_normalize(qs), atol=1e-12)
    # small angles: no loss of precision near zero
    tiny = np.array([[1e-14, -2e-14, 3e-15], [0.0, 0.0, 0.0]])
    assert np.allclose(r.quat_log(r.quat_exp(tiny)), tiny, atol=1e-24, rtol=1e-10)


def test_q_and_minus_q_are_the_same_rotation(qs: np.ndarray) -> None:
    assert np.allclose(r.quat_log(qs), r.quat_log(-qs), atol=1e-12)
    assert np.allclose(r.dcm_from_quat(qs), r.dcm_from_quat(-qs), atol=1e-12)
    assert np.allclose(r.euler_from_quat(qs), r.euler_from_quat(-qs), atol=1e-12)
    assert np.allclose(r.quat_angle(qs, -qs), 0.0, atol=1e-7)
    assert (r.quat_normalize(-qs)[:, 0] >= 0).all()


def test_dcm_round_trip_including_180_degree_turns(qs: np.ndarray) -> None:
    assert np.allclose(r.quat_from_dcm(r.dcm_from_quat(qs)), r.quat_normalize(qs), atol=1e-12)
    flips = r.quat_exp(np.pi * np.eye(3))
    assert np.allclose(r.quat_from_dcm(r.dcm_from_quat(flips)), r.quat_normalize(flips), atol=1e-12)


def test_euler_matches_scipy_zyx(qs: np.ndarray) -> None:
    R_q = Rotation.from_quat(qs, scalar_first=True)
    expected = R_q.as_euler("ZYX")[:, ::-1]
    assert np.allclose(r.euler_from_quat(qs), expected, atol=1e-10)
    back = r.quat_from_euler(expected)
    assert np.allclose(r.dcm_from_quat(back), R_q.as_matrix(), atol=1e-12)


@pytest.mark.parametrize("pitch", [np.pi / 2, -np.pi / 2])
def test_euler_round_trip_at_gimbal_lock(pitch: float) -> None:
    rng = np.random.default_rng(3)
    rpy = np.column_stack([rng.uniform(-3, 3, 50), np.full(50, pitch), rng.uniform(-3, 3, 50)])
    q = r.quat_from_euler(rpy)
    e = r.euler_from_quat(q)
    assert np.allclose(e[:, 0], 0.0)  # roll set to zero at the lock
    assert np.allclose(e[:, 1], pitch, atol=1e-7)
    assert np.allclose(r.dcm_from_quat(r.quat_from_euler(e)), r.dcm_from_quat(q), atol=1e-7)


def test_yaw_beyond_90_degrees_uses_atan2() -> None:
    q = r.quat_from_euler([0.1, 0.2, 2.8])
    assert np.allclose(r.euler_from_quat(q), [0.1, 0.2, 2.8], atol=1e-12)


def test_right_jacobian_and_euler_rate_map_by_finite_differences() -> None:
    rng = np.random.default_rng(4)
    h = 1e-6
    for _ in range(20):
        phi = rng.normal(size=3)
        dphi = rng.normal(size=3) * h
        # Exp(phi + dphi) ~= Exp(phi) Exp(J_r dphi)
        lhs = r.quat_exp(phi + dphi)
        rhs = r.quat_mul(r.quat_exp(phi), r.quat_exp(r.right_jacobian(phi) @ dphi))
        assert r.quat_angle(lhs, rhs) < 1e-11
        rpy = rng.uniform([-1, -1, -3], [1, 1, 3])
        q = r.quat_from_euler(rpy)
        T = r.euler_rate_map(rpy[0], rpy[1])
        num = np.empty((3, 3))
        for i in range(3):
            e = np.zeros(3)
            e[i] = h
            num[:, i] = (
                r.euler_from_quat(r.quat_mul(q, r.quat_exp(e)))
                - r.euler_from_quat(r.quat_mul(q, r.quat_exp(-e)))
            ) / (2 * h)
        assert np.allclose(T, num, atol=1e-7)
    assert np.allclose(r.right_jacobian(np.zeros(3)), np.eye(3))


def test_enu_ned_conversions_round_trip(qs: np.ndarray) -> None:
    v = np.random.default_rng(5).normal(size=(N, 3))
    assert np.allclose(r.vec_ned_to_enu(r.vec_enu_to_ned(v)), v)
    assert np.allclose(r.vec_enu_to_ned([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    assert np.allclose(
        r.quat_ned_frd_to_enu_rfu(r.quat_enu_rfu_to_ned_frd(qs)), r.quat_normalize(qs)
    )
    assert np.allclose(
        r.quat_ned_frd_to_enu_flu(r.quat_enu_flu_to_ned_frd(qs)), r.quat_normalize(qs)
    )
    # C_FRD^NED = P C_RFU^ENU P (SPEC 1.5) and = P C_FLU^ENU diag(1,-1,-1)
    C = r.dcm_from_quat(qs)
    assert np.allclose(r.dcm_from_quat(r.quat_enu_rfu_to_ned_frd(qs)), P_ENU_NED @ C @ P_ENU_NED)
    D = np.diag([1.0, -1.0, -1.0])
    assert np.allclose(r.dcm_from_quat(r.quat_enu_flu_to_ned_frd(qs)), P_ENU_NED @ C @ D)


def test_enu_rfu_euler_mapping() -> None:
    """ZXY angles of an RFU body in ENU: roll_NED = gamma', pitch_NED = theta', yaw_NED = -psi'."""
    rng = np.random.default_rng(6)
    for _ in range(200):
        psi_p, theta_p, gamma_p = rng.uniform(-1.2, 1.2, 3)
        C_enu = (
            Rotation.from_euler("z", psi_p).as_matrix()
            @ Rotation.from_euler("x", theta_p).as_matrix()
            @ Rotation.from_euler("y", gamma_p).as_matrix()
        )
        q_enu = r.quat_from_dcm(C_enu)
        rpy = r.euler_from_quat(r.quat_enu_rfu_to_ned_frd(q_enu))
        assert np.allclose(rpy, [gamma_p, theta_p, -psi_p], atol=1e-10)
