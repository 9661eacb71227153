"""The additive-quaternion family: the shipped (numba) models against their numeric twins,
the one Kalman update (as these filters call it) and the unscented steps against textbook
numpy, the paper's printed innovation, the paper's claim on its own scenario, zero-noise
exactness, bad input, and streaming equal to batch."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from scipy.linalg import expm

from windahrs.conventions import DEG, UP_N
from windahrs.core.dense import (
    PIVOT_RTOL,
    psd_root,
    sigma_points,
    ut_mean_cov,
    ut_update,
    ut_weights,
)
from windahrs.core.kalman import _fuse, read_logs
from windahrs.core.kernel import make_state as kernel_state
from windahrs.core.layout import INN_ACCEL, INN_MAG, N_SENSORS, W_HQ, W_NU, W_R
from windahrs.core.predict import _normalise_add, _predict_add
from windahrs.estimate import Estimate
from windahrs.filters.additive import make_state
from windahrs.filters.base import InitialState, MissingSensorError, merge_events
from windahrs.filters.ekf import TraditionalEKF, TraditionalEKFParams
from windahrs.filters.paper import PaperEKF, PaperEKFNoWind, PaperNoWindParams, PaperParams
from windahrs.filters.params import EskfParams
from windahrs.filters.ukf import AdditiveUKF, AdditiveUKFParams
from windahrs.flight import Flight, ImuStream, MagStream, Site
from windahrs.models.additive import (
    Omega,
    Xi,
    att_cov_from_quat_cov,
    quat_cov_from_att_cov,
    transition_picard4,
    vector_obs,
    vector_obs_jacobian,
)
from windahrs.rotation import (
    euler_from_quat,
    quat_angle,
    quat_exp,
    quat_mul,
    quat_rotate_inv,
)
from windahrs.sim.paper import PaperScenario
from windahrs.sim.scenario import simulate
from windahrs.sim.sensors import SensorSuite

RNG_SEED = 20240611


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def _fd_jacobian(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    cols = []
    for i in range(len(x)):
        e = np.zeros(len(x))
        e[i] = h
        cols.append((f(x + e) - f(x - e)) / (2 * h))
    return np.stack(cols, axis=1)


def _rel_err(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# --- (a) models against their numeric twins -------------------------------------------


def test_omega_and_xi_are_the_quaternion_product() -> None:
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(5):
        q, w = rng.normal(size=4), rng.normal(size=3)
        qw = quat_mul(q, np.concatenate([[0.0], w]))
        np.testing.assert_allclose(Omega(w) @ q, qw, atol=1e-14)
        np.testing.assert_allclose(Xi(q) @ w, qw, atol=1e-14)
        np.testing.assert_allclose(Omega(w), -Omega(w).T)  # norm-preserving
        u = q / np.linalg.norm(q)
        np.testing.assert_allclose(Xi(u).T @ Xi(u), np.eye(3), atol=1e-14)
        np.testing.assert_allclose(Xi(u) @ Xi(u).T, np.eye(4) - np.outer(u, u), atol=1e-14)


def _ekf7_state():
    """The compiled core's state of [ekf7] ([q; b_g], core.predict._predict_add with a bias)."""
    caps = np.zeros(N_SENSORS, dtype=np.int64)
    return kernel_state("mekf", True, EskfParams(), Site(), None, frozenset(), caps)


def _ekf_state(n_log: int = 4):
    """The compiled state of [ekf] (the paper's form: H on the quaternion's parameters)."""
    caps = {INN_ACCEL: n_log, INN_MAG: n_log}
    return make_state(TraditionalEKF().config(None), Site(), frozenset({"imu", "mag"}), caps)


def _ukf_state():
    """The compiled state of [ukf] ([q; b_g] in the additive loop)."""
    return make_state(AdditiveUKF().config(None), Site(), frozenset({"imu", "mag"}), {})


def _step(q: np.ndarray, b: np.ndarray, w_m: np.ndarray, dt: float) -> np.ndarray:
    """SPEC 2.3's nominal step (numpy): [normalise(q * Exp((w_m - b) dt)); b]."""
    qk = quat_mul(q, quat_exp((w_m - b) * dt))
    return np.concatenate([qk / np.linalg.norm(qk), b])


@pytest.mark.parametrize("dt", [0.005, 0.2])
@pytest.mark.parametrize("bias", [True, False], ids=["ekf7", "ekf"])
def test_additive_prediction_is_spec_2_3(dt: float, bias: bool) -> None:
    # core.predict._predict_add, which [ekf7], [ekf10] (gyro-bias state) and [ekf] (none)
    # ship: q -> q * Exp((w_m - b) dt) = exp(Omega(dtheta)/2) q normalised, and with the
    # noise off P -> D P D^T, D the Jacobian of that normalised step (SPEC 2.3's F with
    # J_r, then the normalisation's J), by finite differences.
    rng = np.random.default_rng(RNG_SEED + 4)
    n = 7 if bias else 4
    for _ in range(5):
        st = _ekf7_state() if bias else _ekf_state()
        st.prm["gyro_noise2"] = st.prm["gyro_bias_noise2"] = 0.0
        q = _unit(rng, 4) + np.array([2.0, 0.0, 0.0, 0.0])  # within ~60 deg of identity: no flip
        q /= np.linalg.norm(q)
        b = rng.normal(size=3) * 0.05 if bias else np.zeros(3)
        w_m = rng.normal(size=3) * 3.0  # up to ~0.6 rad per step at dt = 0.2: J_r matters
        A = rng.normal(size=(n, n))
        P = A @ A.T
        st.x[:4] = q
        if bias:
            st.x[4:7] = b
        st.P[:n, :n] = P
        _predict_add(st.cfg, st.prm, st.x, st.P, st.work, w_m[0], w_m[1], w_m[2], dt)
        expected = _step(q, b, w_m, dt)
        assert expected[0] > 0  # (no flip to w >= 0 in this case)
        np.testing.assert_allclose(st.x[:n], expected[:n], atol=1e-14)
        np.testing.assert_allclose(expm(0.5 * Omega((w_m - b) * dt)) @ q, expected[:4], atol=1e-13)
        x0 = np.concatenate([q, b])[:n]
        D = _fd_jacobian(lambda v, w_m=w_m: _step(v[:4], v[4:] if bias else np.zeros(3), w_m, dt)[:n], x0)
        assert _rel_err(st.P[:n, :n], D @ P @ D.T) < 1e-6
        np.testing.assert_array_equal(st.P, st.P.T)


@pytest.mark.parametrize(("a", "spec_error"), [(1e-1, 2.6e-9), (3e-1, 6.3e-7)])
def test_picard4_error_matches_spec_table(a: float, spec_error: float) -> None:
    """SPEC 2.2: ||Phi4 - Phi|| = 2.6e-9 at a = 0.1 rad and 6.3e-7 at 0.3 rad."""
    d = a * _unit(np.random.default_rng(RNG_SEED + 2), 3)
    err = np.linalg.norm(transition_picard4(d) - expm(0.5 * Omega(d)), 2)
    assert err == pytest.approx(spec_error, rel=0.03)


def test_picard4_is_fifth_order() -> None:
    d = _unit(np.random.default_rng(RNG_SEED + 3), 3)
    e1 = np.linalg.norm(transition_picard4(0.2 * d) - expm(0.1 * Omega(d)), 2)
    e2 = np.linalg.norm(transition_picard4(0.1 * d) - expm(0.05 * Omega(d)), 2)
    assert np.log2(e1 / e2) == pytest.approx(5.0, abs=0.1)


def test_vector_obs_and_its_jacobian() -> None:
    rng = np.random.default_rng(RNG_SEED + 5)
    for _ in range(10):
        q = rng.normal(size=4)  # non-unit on purpose: the model is the quadratic form
        r = rng.normal(size=3)
        u = q / np.linalg.norm(q)
        np.testing.assert_allclose(vector_obs(u, r), quat_rotate_inv(u, r), atol=1e-14)
        H = vector_obs_jacobian(q, r)
        assert _rel_err(H, _fd_jacobian(lambda x, r=r: vector_obs(x, r), q)) < 1e-6
        # Euler's theorem for a homogeneous quadratic: why z - H x is wrong (SPEC 3.1).
        np.testing.assert_allclose(H @ q, 2.0 * vector_obs(q, r), atol=1e-12)


@pytest.mark.parametrize("bias", [True, False], ids=["ekf7", "ekf"])
def test_process_noise_equals_van_loan_without_rotation(bias: bool) -> None:
    """At w = 0, Q_d of SPEC 2.3 (core.predict._noise_add, as the prediction adds it to a
    zero P) is the exact Van Loan integral (q constant over the step); without a bias
    state ([ekf]) its quaternion block with sigma_b = 0."""
    q = _unit(np.random.default_rng(RNG_SEED + 7), 4)
    q *= np.sign(q[0])
    sg, sb, dt = 2e-3, (3e-4 if bias else 0.0), 0.05
    F_c = np.zeros((7, 7))
    F_c[:4, 4:] = -0.5 * Xi(q)
    G = np.zeros((7, 6))
    G[:4, :3] = -0.5 * Xi(q)
    G[4:, 3:] = np.eye(3)
    GQG = G @ np.diag([sg**2] * 3 + [sb**2] * 3) @ G.T
    M = expm(np.block([[-F_c, GQG], [np.zeros((7, 7)), F_c.T]]) * dt)
    Phi = M[7:, 7:].T
    Q_vl = Phi @ M[:7, 7:]
    st = _ekf7_state() if bias else _ekf_state()
    st.prm["gyro_noise2"], st.prm["gyro_bias_noise2"] = sg**2, sb**2
    st.x[:4] = q
    st.P[:] = 0.0
    b = np.full(3, 1e-3) if bias else np.zeros(3)
    st.x[4:7] = b if bias else st.x[4:7]
    _predict_add(st.cfg, st.prm, st.x, st.P, st.work, b[0], b[1], b[2], dt)  # w_m = b: no rotation
    n = 7 if bias else 4
    Q = st.P[:n, :n]
    assert _rel_err(Q, Q_vl[:n, :n]) < 1e-9
    assert np.linalg.matrix_rank(Q[:4, :4], tol=1e-12 * np.abs(Q).max()) == 3
    np.testing.assert_allclose(Q[:4, :4] @ q, 0.0, atol=1e-20)


def test_attitude_covariance_maps() -> None:
    rng = np.random.default_rng(RNG_SEED + 8)
    q = _unit(rng, 4)
    A = rng.normal(size=(3, 3))
    P_att = A @ A.T
    np.testing.assert_allclose(att_cov_from_quat_cov(q, quat_cov_from_att_cov(q, P_att)), P_att)
    # dtheta ~ 2 Xi^T (q_true - q): the map the covariance conversion rests on.
    dtheta = rng.normal(size=3) * 1e-5
    dq = quat_mul(q, quat_exp(dtheta)) - q
    np.testing.assert_allclose(2.0 * Xi(q).T @ dq, dtheta, rtol=1e-4)


@pytest.mark.parametrize("state", [_ekf7_state, _ukf_state, _ekf_state], ids=["ekf7", "ukf", "ekf"])
def test_normalisation_projects_the_covariance(state) -> None:
    # core.predict._normalise_add, the additive filters' one normalisation: q <- q/|q|
    # (w >= 0), P <- T P T^T with T = blkdiag(+-J, I), J = (I - u u^T)/|q| the Jacobian of
    # q/|q| (by finite differences), the sign that of the flip.
    st = state()
    n = st.cfg["n"]
    rng = np.random.default_rng(RNG_SEED + 9)
    q = rng.normal(size=4)
    q[0] = -abs(q[0])  # the sign flip to w >= 0
    A = rng.normal(size=(n, n))
    P = A @ A.T
    st.x[:4] = q
    st.P[:n, :n] = P
    rest = st.x[4:].copy()
    _normalise_add(st.cfg, st.x, st.P, st.work, q[0], q[1], q[2], q[3])
    J = _fd_jacobian(lambda v: v / np.linalg.norm(v), q)
    u = q / np.linalg.norm(q)
    np.testing.assert_allclose(J, (np.eye(4) - np.outer(u, u)) / np.linalg.norm(q), atol=1e-8)
    np.testing.assert_allclose(st.x[:4], -u, rtol=1e-15)
    np.testing.assert_array_equal(st.x[4:], rest)
    # x2 = T x with T = blkdiag(-J, I) to first order (the flip to w >= 0 negates q): the
    # quaternion block is J P J^T, its covariance with the bias changes sign.
    T = np.eye(n)
    T[:4, :4] = -(np.eye(4) - np.outer(u, u)) / np.linalg.norm(q)
    np.testing.assert_allclose(st.P[:n, :n], T @ P @ T.T, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(st.P, st.P.T)
    np.testing.assert_allclose(st.P[:4, :4] @ st.x[:4], 0.0, atol=1e-12)  # nothing along q


def _joseph(x: np.ndarray, P: np.ndarray, H: np.ndarray, nu: np.ndarray, R: np.ndarray):
    """Textbook EKF update: x + K nu, (I - K H) P (I - K H)^T + K R K^T, the NIS."""
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    I_KH = np.eye(len(x)) - K @ H
    return x + K @ nu, I_KH @ P @ I_KH.T + K @ R @ K.T, float(nu @ np.linalg.solve(S, nu))


def test_the_one_update_on_the_quaternion_columns_is_the_joseph_form() -> None:
    # The paper's filters give H (3, 4) on q's parameters to the core's one update
    # (core.kalman._fuse): the Joseph form, then q <- q/|q| (w >= 0), P <- J P J^T.
    rng = np.random.default_rng(RNG_SEED + 10)
    st = _ekf_state()
    q = _unit(rng, 4) * 1.3
    q[0] = -abs(q[0])  # the flip to w >= 0 after the update
    A, B = rng.normal(size=(4, 4)), rng.normal(size=(3, 3))
    P, R = A @ A.T, B @ B.T + np.eye(3)
    H, nu = rng.normal(size=(3, 4)), rng.normal(size=3)
    st.x[:] = q
    st.P[:, :] = P
    st.work[W_HQ : W_HQ + 3, :4] = H
    st.work[W_NU, :3] = nu
    st.work[W_R : W_R + 3, :3] = R
    args = (st.cfg, st.x, st.flags, st.P, st.work, st.sup, st.inn, st.acc)
    assert _fuse(*args, np.int64(INN_MAG), 0.25, np.int64(3), np.int64(4), np.inf)
    x2, P2, nis = _joseph(q, P, H, nu, R)
    u = x2 / np.linalg.norm(x2)
    J = -(np.eye(4) - np.outer(u, u)) / np.linalg.norm(x2)  # the sign of the flip included
    np.testing.assert_allclose(st.x, -u, rtol=1e-12)
    np.testing.assert_allclose(st.P, J @ P2 @ J.T, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(st.P, st.P.T)
    np.testing.assert_allclose(st.P @ st.x, 0.0, atol=1e-12)  # nothing along q
    # logged: t, nu, the NIS, accepted
    log = read_logs(st.cfg, st.flags, st.inn, st.acc)
    assert list(log) == ["mag"]
    np.testing.assert_array_equal(log["mag"].t, [0.25])
    np.testing.assert_array_equal(log["mag"].nu, [nu])
    assert log["mag"].nis[0] == pytest.approx(nis, rel=1e-12)
    assert log["mag"].accepted.tolist() == [True]
    # a finite gate rejects an innovation beyond it: logged, not fused
    x_in, P_in = st.x.copy(), st.P.copy()
    st.work[W_NU, :3] = [1e3, 0.0, 0.0]
    assert not _fuse(*args, np.int64(INN_MAG), 0.5, np.int64(3), np.int64(4), 9.0)
    np.testing.assert_array_equal(st.x, x_in)
    np.testing.assert_array_equal(st.P, P_in)
    assert read_logs(st.cfg, st.flags, st.inn, st.acc)["mag"].accepted.tolist() == [True, False]


def test_unscented_update_equals_the_kalman_update_on_a_linear_model() -> None:
    rng = np.random.default_rng(RNG_SEED + 11)
    n, m = 7, 3
    x, z = rng.normal(size=n), rng.normal(size=m)
    A = rng.normal(size=(n, n))
    P, R = A @ A.T, 0.5 * np.eye(m)
    H = rng.normal(size=(m, n))
    wm, wc, spread = ut_weights(n, 1.0, 0.0, 1.0)
    X = sigma_points(x, P, spread)
    # the sigma points carry the mean and covariance exactly
    x_ut, P_ut = ut_mean_cov(X, wm, wc)
    np.testing.assert_allclose(x_ut, x, atol=1e-12)
    np.testing.assert_allclose(P_ut, P, rtol=1e-10, atol=1e-12)
    x_u, P_u, nu, nis_u = ut_update(x, P, X, X @ H.T, z, R, wm, wc)
    x_k, P_k, nis_k = _joseph(x, P, H, z - H @ x, R)
    np.testing.assert_allclose(nu, z - H @ x, atol=1e-12)
    np.testing.assert_allclose(x_u, x_k, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(P_u, P_k, rtol=1e-8, atol=1e-10)
    assert nis_u == pytest.approx(nis_k, rel=1e-9)


def _ukf_like_covariance(q: np.ndarray, V: np.ndarray) -> np.ndarray:
    """A UKF start covariance: isotropic attitude (rank 3, singular along q) and an
    isotropic bias with the eigenvectors V (3, 3) of the repeated bias eigenvalue."""
    P = np.zeros((7, 7))
    P[:4, :4] = quat_cov_from_att_cov(q, (2.0 * DEG) ** 2 * np.eye(3))
    P[4:, 4:] = V @ ((0.5 * DEG) ** 2 * np.eye(3)) @ V.T
    return P


def test_sigma_points_are_a_function_of_the_covariance_alone() -> None:
    # The start covariance has repeated eigenvalues: an eigen root depends on which basis
    # of each eigenspace is picked, the LDL^T root must not.
    rng = np.random.default_rng(RNG_SEED + 12)
    q = _unit(rng, 4)
    x = np.concatenate([q, rng.normal(scale=1e-3, size=3)])
    wm, wc, spread = ut_weights(7, 1.0, 0.0, 1.0)
    P = _ukf_like_covariance(q, np.eye(3))
    w, V = np.linalg.eigh(P)
    X = sigma_points(x, P, spread)
    for _ in range(3):
        # rotate the eigenvectors within each repeated eigenvalue (the 0 of q, the
        # attitude triple, the bias triple): the same P up to rounding
        W = V.copy()
        for group in (np.flatnonzero(np.isclose(w, v, rtol=1e-9, atol=1e-30)) for v in np.unique(w.round(30))):
            Qr, _ = np.linalg.qr(rng.normal(size=(len(group), len(group))))
            W[:, group] = V[:, group] @ Qr
        P_rot = W @ np.diag(w) @ W.T
        assert not np.array_equal(P_rot, P)  # not bit-equal: last bits move
        X_rot = sigma_points(x, P_rot, spread)
        np.testing.assert_allclose(X_rot, X, rtol=0, atol=1e-12)
        # (the eigen root it replaced moves by the size of the spread)
        assert np.abs(W * np.sqrt(w.clip(0)) - V * np.sqrt(w.clip(0))).max() > 1e-3
        # and with every bit equal, every bit of the points is equal
        np.testing.assert_array_equal(sigma_points(x, P_rot.copy(), spread), X_rot)
    # the points still carry the mean and the (singular) covariance
    x_ut, P_ut = ut_mean_cov(X, wm, wc)
    np.testing.assert_allclose(x_ut, x, atol=1e-15)
    np.testing.assert_allclose(P_ut, P, rtol=0, atol=1e-16)


def test_psd_root_of_a_singular_covariance() -> None:
    rng = np.random.default_rng(RNG_SEED + 13)
    q = _unit(rng, 4)
    P = _ukf_like_covariance(q, np.linalg.qr(rng.normal(size=(3, 3)))[0])
    # the normalisation projection (the UKF's, core.predict._normalise_add): singular
    # along q to within rounding, pivots of either sign at the 1e-20 level
    st = _ukf_state()
    st.x[:4], st.P[:, :] = q, P
    _normalise_add(st.cfg, st.x, st.P, st.work, q[0], q[1], q[2], q[3])
    P = st.P.copy()
    L = psd_root(P)
    assert np.all(np.isfinite(L))
    np.testing.assert_array_equal(L, np.tril(L))
    np.testing.assert_allclose(L @ L.T, P, rtol=0, atol=1e-16)
    assert np.count_nonzero(np.diag(L)) == 6  # one zero pivot: the direction q
    # a positive definite A: the Cholesky factor
    A = rng.normal(size=(7, 7))
    A = A @ A.T + np.eye(7)
    np.testing.assert_allclose(psd_root(A), np.linalg.cholesky(A), rtol=1e-12, atol=1e-14)
    # a pivot below the tolerance is zero, with its column
    B = np.diag([1.0, 0.5 * PIVOT_RTOL, 2.0])
    np.testing.assert_array_equal(psd_root(B), np.diag([1.0, 0.0, np.sqrt(2.0)]))


def test_ukf_answers_are_continuous_in_the_last_bit_of_p0() -> None:
    # With the eigen root a 1-ulp change of the initial bias variance moved the attitudes
    # by ~1e-3 rad (another eigenvector basis at the repeated eigenvalue); now by rounding.
    flight = simulate(PaperScenario(wind_speed=5.0, duration=5.0), np.random.default_rng(RNG_SEED + 14))
    p = AdditiveUKFParams()
    a = AdditiveUKF(p).run(flight).q_nb
    b = AdditiveUKF(AdditiveUKFParams(sigma_bias0=p.sigma_bias0 * (1 + 4e-16))).run(flight).q_nb
    assert quat_angle(a, b).max() < 1e-12


def test_models_reject_wrong_shapes() -> None:
    with pytest.raises(ValueError, match="q: expected shape"):
        Xi(np.zeros(3))
    with pytest.raises(ValueError, match="r_n: expected shape"):
        vector_obs(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(4))
    with pytest.raises(ValueError, match="P_att: expected shape"):
        quat_cov_from_att_cov(np.array([1.0, 0.0, 0.0, 0.0]), np.eye(4))


# --- (b) the paper's printed innovation ---------------------------------------------


def _static_level_flight(seconds: float = 1.0) -> Flight:
    """At rest, level, heading north, perfect sensors."""
    site = Site(mag_n=np.array([28632e-9, -4032e-9, 44583e-9]))
    t = np.arange(0.0, seconds, 0.005)
    n = len(t)
    imu = ImuStream(t=t, w_b=np.zeros((n, 3)), f_b=np.tile([0.0, 0.0, -site.gravity], (n, 1)))
    mag = MagStream(t=t[::4], mag_b=np.tile(site.mag_n, (len(t[::4]), 1)))
    return Flight(imu=imu, mag=mag, site=site)


def test_printed_innovation_is_biased_and_ours_is_not() -> None:
    q = np.array([1.0, 0.0, 0.0, 0.0])
    z = np.array([0.0, 0.0, -9.80665]) / 9.80665  # perfect accelerometer, level, at rest
    H = vector_obs_jacobian(q, UP_N)
    np.testing.assert_allclose(z - H @ q, [0.0, 0.0, 1.0], atol=1e-15)  # paper eq. 26
    np.testing.assert_allclose(z - vector_obs(q, UP_N), 0.0, atol=1e-15)

    # The filter at the true state with perfect data: innovations vanish and the state
    # stays put; with the printed form every accelerometer innovation would be [0, 0, 1].
    flight = _static_level_flight()
    est = PaperEKFNoWind().run(flight, initial=InitialState(q_nb=q))
    acc = est.innovations["accel"]
    assert len(acc.t) == len(flight.imu.t) - 1
    np.testing.assert_allclose(acc.nu, 0.0, atol=1e-12)
    np.testing.assert_allclose(est.innovations["mag"].nu, 0.0, atol=1e-12)
    assert np.degrees(quat_angle(est.q_nb, q)).max() < 1e-9


# --- (c) the paper's claim on its scenario ------------------------------------------


@cache
def _paper_flight(seed: int) -> Flight:
    return simulate(PaperScenario(wind_speed=5.0, duration=10.0), np.random.default_rng(seed))


def _errors_deg(est: Estimate, flight: Flight) -> tuple[np.ndarray, np.ndarray]:
    """Total rotation error (N,) and roll/pitch/yaw errors (N, 3), deg."""
    assert flight.truth is not None
    total = np.degrees(quat_angle(est.q_nb, flight.truth.q_nb))
    d = euler_from_quat(est.q_nb) - euler_from_quat(flight.truth.q_nb)
    return total, np.degrees((d + np.pi) % (2 * np.pi) - np.pi)


def _rms(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(x**2, axis=0))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_paper_claim_wind_considered_beats_wind_ignored(seed: int) -> None:
    """SPEC 7.4: oracle wind 1.7/0.6/0.7 deg vs no wind 2.0/1.0/3.2 (roll/pitch/yaw)."""
    flight = _paper_flight(seed)
    last = flight.imu.t >= flight.imu.t[-1] - 5.0
    with_wind = PaperEKF().run(flight)
    without = PaperEKFNoWind().run(flight)
    tot_w, rpy_w = _errors_deg(with_wind, flight)
    tot_n, rpy_n = _errors_deg(without, flight)
    rmse_w, rmse_n = _rms(tot_w[last]), _rms(tot_n[last])
    print(
        f"seed {seed}: last-5-s RMSE deg total / roll pitch yaw: paper (oracle) {rmse_w:.2f} / "
        f"{np.round(_rms(rpy_w[last]), 2)}; paper-nowind {rmse_n:.2f} / "
        f"{np.round(_rms(rpy_n[last]), 2)}"
    )
    assert rmse_w < rmse_n
    # Heading is where the air-flow row helps (SPEC 7.4: yaw 0.62 vs 2.66 deg).
    assert _rms(rpy_w[last, 2]) < 0.6 * _rms(rpy_n[last, 2])
    assert rmse_w < 3.0
    assert with_wind.meta["wind"] == "oracle"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_paper_filter_converges_from_its_q0(seed: int) -> None:
    flight = _paper_flight(seed)
    total, _ = _errors_deg(PaperEKF().run(flight), flight)
    print(f"seed {seed}: paper error at samples 0/50/100: {total[[0, 50, 100]].round(2)} deg")
    assert total[0] > 20.0  # q0 = [1, 0, 0, 0] really is wrong
    assert total[100] < 10.0
    assert total[100:].max() < 10.0


def test_baselines_on_the_paper_scenario_have_their_shapes() -> None:
    flight = _paper_flight(0)
    last = flight.imu.t >= flight.imu.t[-1] - 5.0
    n = len(flight.imu.t)
    for est, labels in (
        (PaperEKF(), ("q_w", "q_x", "q_y", "q_z")),
        (PaperEKFNoWind(), ("q_w", "q_x", "q_y", "q_z")),
        (TraditionalEKF(), ("att_x", "att_y", "att_z")),
        (AdditiveUKF(), ("att_x", "att_y", "att_z", "bg_x", "bg_y", "bg_z")),
    ):
        out = est.run(flight)
        total, rpy = _errors_deg(out, flight)
        print(
            f"{est.name}: last-5-s RMSE {_rms(total[last]):.2f} deg, "
            f"roll/pitch/yaw {np.round(_rms(rpy[last]), 2)}"
        )
        assert out.filter == est.name
        assert out.state_labels == labels
        assert out.cov is not None and out.cov.shape == (n, len(labels), len(labels))
        assert (out.gyro_bias_b is not None) == isinstance(est, AdditiveUKF)
        np.testing.assert_allclose(np.linalg.norm(out.q_nb, axis=1), 1.0, atol=1e-12)
        assert (out.q_nb[:, 0] >= 0).all()
        assert set(out.innovations) >= {"accel", "mag"}
        assert all(inn.accepted.all() for inn in out.innovations.values())
        assert _rms(total[last]) < 6.0


# --- (d) zero noise, zero wind: exactness from a truth init -------------------------


@cache
def _turntable_flight() -> Flight:
    """The paper's attitude motion, noise-free, with the accelerometer seeing gravity only:
    every filter model is then exact (the paper scenario's own 1 m/s flight has a small
    centripetal acceleration, a model error of ~0.5 deg)."""
    sensors = SensorSuite().noiseless()
    flight = simulate(PaperScenario(wind_speed=0.0, duration=5.0), np.random.default_rng(3), sensors)
    assert flight.truth is not None
    f_b = quat_rotate_inv(flight.truth.q_nb, -flight.site.gravity_n)
    return flight.replace(imu=ImuStream(t=flight.imu.t, w_b=flight.imu.w_b, f_b=f_b))


@pytest.mark.parametrize(
    "est", [TraditionalEKF(), AdditiveUKF(), PaperEKFNoWind()], ids=lambda e: e.name
)
def test_zero_noise_stays_on_truth(est) -> None:
    flight = _turntable_flight()
    assert flight.truth is not None
    assert np.abs(flight.imu.w_b).max() > 3 * DEG  # it does rotate
    out = est.run(flight, initial=InitialState.from_truth(flight, sigma_att=0.1 * DEG))
    err = np.degrees(quat_angle(out.q_nb, flight.truth.q_nb))
    print(f"{est.name}: max error {err.max():.2e} deg")
    assert err.max() < 0.05
    if out.gyro_bias_b is not None:
        assert np.abs(out.gyro_bias_b).max() < 0.01 * DEG


# --- (e) bad input -----------------------------------------------------------------


@cache
def _short_flight(vanes: bool = True) -> Flight:
    sensors = SensorSuite() if vanes else SensorSuite(vanes=None)
    return simulate(PaperScenario(wind_speed=5.0, duration=2.0), np.random.default_rng(7), sensors)


def test_paper_filter_needs_vanes() -> None:
    no_vanes = _short_flight(vanes=False)
    with pytest.raises(MissingSensorError, match="vanes") as info:
        PaperEKF().run(no_vanes)
    assert "paper" in str(info.value) and "air" in str(info.value)
    assert info.value.sensor == "air"
    with pytest.raises(MissingSensorError, match="vanes"):
        PaperEKF().run(no_vanes.replace(air=None))
    # The filter without the air-data rows runs without them.
    PaperEKFNoWind().run(no_vanes.replace(air=None, gnss=None))


def test_missing_magnetometer_is_named() -> None:
    flight = _short_flight().replace(mag=None)
    for est in (PaperEKFNoWind(), TraditionalEKF(), AdditiveUKF()):
        with pytest.raises(MissingSensorError, match="mag") as info:
            est.run(flight)
        assert est.name in str(info.value)


def test_oracle_wind_needs_truth() -> None:
    flight = _short_flight().replace(truth=None)
    with pytest.raises(ValueError, match="oracle.*truth"):
        PaperEKF().run(flight)
    with pytest.raises(ValueError, match="mean_wind_n"):
        PaperEKF(PaperParams(wind="mean")).run(flight)
    out = PaperEKF(PaperParams(wind="mean", mean_wind_n=(-4.0, -2.0, 0.0))).run(flight)
    assert out.meta["wind"] == "mean"
    with pytest.raises(ValueError, match="wind provider"):
        PaperEKF().streamer(flight.site)


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: PaperNoWindParams(process_var=-0.02), "process_var"),
        (lambda: PaperNoWindParams(p0_var=float("nan")), "p0_var"),
        (lambda: PaperNoWindParams(init="identity"), "init"),  # type: ignore[arg-type]
        (lambda: PaperParams(acc_var=0.0), "acc_var"),
        (lambda: PaperParams(air_var=-1.0), "air_var"),
        (lambda: PaperParams(wind="gusty"), "wind"),  # type: ignore[arg-type]
        (lambda: PaperParams(mean_wind_n=(1.0, 2.0)), "mean_wind_n"),  # type: ignore[arg-type]
        (lambda: PaperParams(mean_wind_n=(1.0, 2.0, float("inf"))), "mean_wind_n"),
        (lambda: TraditionalEKFParams(gyro_noise=0.0), "gyro_noise"),
        (lambda: TraditionalEKFParams(accel_sigma_unit=-0.1), "accel_sigma_unit"),
        (lambda: AdditiveUKFParams(alpha=2.0), "alpha"),
        (lambda: AdditiveUKFParams(kappa=-8.0), "kappa"),
        (lambda: AdditiveUKFParams(gyro_bias_rw=float("nan")), "gyro_bias_rw"),
    ],
)
def test_bad_params_name_the_field(make, field: str) -> None:
    with pytest.raises(ValueError, match=f"\\.{field}: expected"):
        make()


# --- initialisation variants --------------------------------------------------------


def test_triad_init_starts_near_truth() -> None:
    flight = _paper_flight(0)
    for est in (PaperEKF(PaperParams(init="triad")), TraditionalEKF(), AdditiveUKF()):
        total, _ = _errors_deg(est.run(flight), flight)
        assert total[0] < 5.0, est.name


def test_unknown_site_field_takes_magnetic_north() -> None:
    """Without ``site.mag_n`` heading is magnetic: off by the declination (-8 deg at Dalian)."""
    flight = _paper_flight(1)
    assert flight.site.mag_n is not None and flight.truth is not None
    decl = np.degrees(np.arctan2(flight.site.mag_n[1], flight.site.mag_n[0]))
    out = PaperEKFNoWind().run(flight.replace(site=Site(mag_n=None)))
    _, rpy = _errors_deg(out, flight)
    last = flight.imu.t >= flight.imu.t[-1] - 5.0
    assert np.mean(rpy[last, 2]) == pytest.approx(-decl, abs=1.5)


# --- (f) streaming equals batch -----------------------------------------------------


@pytest.mark.parametrize(
    "est",
    [PaperEKF(), PaperEKF(PaperParams(init="triad")), PaperEKFNoWind(), TraditionalEKF(), AdditiveUKF()],
    ids=lambda e: f"{e.name}-{getattr(e.params, 'init', '')}",
)
def test_streaming_equals_batch(est) -> None:
    flight = _short_flight()
    batch = est.run(flight)
    has = est.uses & frozenset(flight.streams())
    kw = {"wind": est.wind_provider(flight)} if isinstance(est, PaperEKF) else {}
    s = est.streamer(flight.site, has=has, **kw)
    t_ev, kinds, vals = merge_events(flight, has)
    for k, t, v in zip(kinds, t_ev, vals, strict=True):
        s.push(int(k), float(t), v)
    st = s.state
    np.testing.assert_array_equal(st.q_nb, batch.q_nb[-1])
    assert batch.cov is not None and st.cov is not None
    np.testing.assert_array_equal(st.cov, batch.cov[-1])
    if batch.gyro_bias_b is not None:
        np.testing.assert_array_equal(st.gyro_bias_b, batch.gyro_bias_b[-1])
    assert list(s.innovations()) == list(batch.innovations)
    for sensor, inn in s.innovations().items():
        np.testing.assert_array_equal(inn.nu, batch.innovations[sensor].nu)
        np.testing.assert_array_equal(inn.nis, batch.innovations[sensor].nis)
    assert s.skipped == batch.skipped
    if isinstance(est, PaperEKF):
        assert {f"unfused_{k}": v for k, v in s.unfused.items()} == {
            k: v for k, v in batch.meta.items() if k.startswith("unfused_")
        }


def test_nan_samples_are_skipped_and_counted() -> None:
    flight = _short_flight()
    assert flight.air is not None and flight.air.aoa is not None
    aoa = flight.air.aoa.copy()
    aoa[5] = np.nan
    f_b = flight.imu.f_b.copy()
    f_b[40] = np.nan
    bad = flight.replace(
        air=type(flight.air)(t=flight.air.t, tas=flight.air.tas, aoa=aoa, sideslip=flight.air.sideslip),
        imu=ImuStream(t=flight.imu.t, w_b=flight.imu.w_b, f_b=f_b),
    )
    out = PaperEKF().run(bad)
    assert out.skipped["air"] == 1 and out.skipped["imu"] == 1
    assert np.isfinite(out.q_nb).all()


def test_params_load_from_toml(tmp_path) -> None:
    good = tmp_path / "paper.toml"
    good.write_text('[windahrs]\nwind = "mean"\nmean_wind_n = [-4.0, -2.0, 0.0]\nair_var = 5.0\n')
    p = PaperEKF.load_params(good)
    assert p == PaperParams(wind="mean", mean_wind_n=(-4.0, -2.0, 0.0), air_var=5.0)
    ukf = tmp_path / "ukf.toml"
    ukf.write_text("[windahrs]\nkappa = 2.0\n")
    assert AdditiveUKF.load_params(ukf).kappa == 2.0
    bad = tmp_path / "bad.toml"
    bad.write_text("[windahrs]\nprocess_var = 0.01\nairspeed_var = 3.0\n")
    with pytest.raises(ValueError, match="airspeed_var"):
        PaperEKF.load_params(bad)
    bad.write_text("[px4]\nEKF2_GYR_NOISE = 0.015\n")
    with pytest.raises(ValueError, match="px4"):
        TraditionalEKF.load_params(bad)
    bad.write_text("[windahrs]\nacc_var = -1.0\n")
    with pytest.raises(ValueError, match="acc_var"):
        PaperEKFNoWind.load_params(bad)
