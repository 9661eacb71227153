"""[usque] (windahrs.filters.usque), the compiled kernels themselves: the GRP maps, the
square root, weights and process noise, the sigma points, point predictions and one
propagation and update against a small dense-numpy oracle (below) and the observation
models, zero-noise convergence, Monte Carlo consistency (NEES and NIS), streaming equal to
batch, modes, NaN samples, bad input, and the same source run with NUMBA_DISABLE_JIT=1
(the readable reference) equal to the JIT run."""

from __future__ import annotations

import dataclasses
import os
import pickle
import subprocess
import sys
import textwrap
from collections.abc import Callable
from functools import cache
from pathlib import Path

import numpy as np
import pytest

import windahrs
from windahrs.conventions import DEG
from windahrs.core.kernel import make_state
from windahrs.core.layout import (
    INN_ACCEL,
    INN_MAG,
    L_CNT,
    N_SENSORS,
    N_WORK,
    N_X,
    NMAX,
    PRM,
    X_BG,
    X_Q,
)
from windahrs.estimate import Estimate
from windahrs.filters.base import InitialState, merge_events, replay
from windahrs.filters.params import EskfParams, matched_to
from windahrs.filters.registry import make_estimator
from windahrs.filters.usque import (
    _W0,
    _WI,
    GRP_A,
    GRP_F,
    U_NU,
    U_Q,
    U_S,
    U_Y,
    Usque,
    _add_process_noise,
    _centre,
    _dq_from_grp,
    _grp_from_dq,
    _predict_heading,
    _predict_vector,
    _propagate,
    _sigma,
    _update,
    _weighted_cov,
    sqrt_cov,
)
from windahrs.flags import FLAGS
from windahrs.flight import Flight, ImuStream, MagStream, Site
from windahrs.metrics import attitude_errors, chi2_band, nees_attitude
from windahrs.models.error_state import NominalState
from windahrs.rotation import (
    dcm_from_quat,
    euler_from_quat,
    quat_conj,
    quat_exp,
    quat_from_euler,
    quat_log,
    quat_mul,
    quat_normalize,
)
from windahrs.sim.gust_response import rates_from_attitude
from windahrs.sim.scenario import default_site, make_scenario, simulate
from windahrs.sim.sensors import AccelModel, MagModel, SensorSuite, TruthTrajectory, measure

SEED = 20240611
F64 = np.ndarray

#: The model-matched suite of the consistency test: white noise and the gyro-bias random
#: walk as simulated; no accelerometer bias and no hard iron (constant offsets the filter
#: does not estimate), no GNSS or air data (the filter does not use them).
MATCHED = SensorSuite(
    imu_rate=50.0,
    accel=AccelModel(bias_init_sigma=0.0),
    mag=MagModel(rate=10.0, hard_iron=0.0),
    gnss=None,
    pitot=None,
    vanes=None,
)


def rotating_in_place(duration: float, rate: float) -> TruthTrajectory:
    """Rotation about a fixed point (a_n = 0): the gravity-only accelerometer model is
    exact. Roll +-29 deg, pitch +-20 deg, yaw sweeping and turning."""
    t = np.arange(round(duration * rate) + 1) / rate
    rpy = np.column_stack(
        [0.5 * np.sin(0.8 * t), 0.35 * np.sin(0.5 * t + 1.0), 1.2 * np.sin(0.2 * t) + 0.25 * t]
    )
    q = quat_from_euler(rpy)
    z = np.zeros((len(t), 3))
    return TruthTrajectory(t=t, q_nb=q, w_b=rates_from_attitude(t, q), a_n=z, v_n=z, p_n=z, wind_n=z)


def flight(suite: SensorSuite, duration: float, seed: int) -> Flight:
    traj = rotating_in_place(duration, suite.imu_rate)
    return measure(traj, suite, default_site(), np.random.default_rng(seed))


@cache
def fixedwing(name: str = "plain", duration: float = 2.5) -> Flight:
    """A simulated fixed wing (wind 8 m/s), plain or with "nan" in the first IMU and
    magnetometer samples (the initialisation must wait) and in a few later ones, or with
    the site's field's horizontal part reversed ("south": yaw estimates near +-180 deg)."""
    f = simulate(make_scenario("fixedwing", wind=8.0, duration=duration), np.random.default_rng(1))
    assert f.mag is not None and f.site.mag_n is not None
    if name == "nan":
        rng = np.random.default_rng(2)
        w, fb, m = f.imu.w_b.copy(), f.imu.f_b.copy(), f.mag.mag_b.copy()
        i = rng.choice(np.arange(1, len(w)), size=len(w) // 40, replace=False)
        w[0, 1] = np.nan
        w[i[::2], 0] = np.nan
        fb[i[1::2], 2] = np.nan
        j = rng.choice(np.arange(1, len(m)), size=max(2, len(m) // 40), replace=False)
        m[np.concatenate([[0], j]), 1] = np.nan
        return f.replace(imu=ImuStream(t=f.imu.t, w_b=w, f_b=fb), mag=MagStream(t=f.mag.t, mag_b=m))
    if name == "south":
        m_n = f.site.mag_n
        return f.replace(site=Site(gravity=f.site.gravity, mag_n=np.array([-m_n[0], -m_n[1], m_n[2]])))
    return f


# --- the dense-numpy oracle (SPEC 4.1 as written: general a, f; matrices, no scratch rows) ---

#: weights lambda/(n + lambda) and 1/(2(n + lambda)), n = 6, lambda = 1
W = np.full(13, 1.0 / 14.0)
W[0] = 1.0 / 7.0


def dq_oracle(p: F64) -> F64:
    s = float(p @ p)
    q0 = (-GRP_A * s + GRP_F * np.sqrt(GRP_F**2 + (1.0 - GRP_A**2) * s)) / (GRP_F**2 + s)
    return np.concatenate([[q0], (GRP_A + q0) * p / GRP_F])


def grp_oracle(dq: F64) -> F64:
    dq = dq if dq[0] >= 0.0 else -dq
    return GRP_F * dq[1:] / (GRP_A + dq[0])


def wrap(a: F64) -> F64:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def sigma_oracle(q: F64, bg: F64, P: F64) -> tuple[F64, F64, F64]:
    L = np.linalg.cholesky(7.0 * P)
    S = np.vstack([np.zeros(6), L.T, -L.T])
    return S, np.array([quat_mul(q, dq_oracle(s[:3])) for s in S]), bg + S[:, 3:]


def process_noise_oracle(sg: float, sb: float, dt: float) -> F64:
    """The [att, bg] process noise of the error-state model (SPEC 2.4, Farrenkopf)."""
    Q = np.zeros((6, 6))
    Q[:3, :3] = (sg**2 * dt + sb**2 * dt**3 / 3.0) * np.eye(3)
    Q[:3, 3:] = Q[3:, :3] = -(sb**2) * dt**2 / 2.0 * np.eye(3)
    Q[3:, 3:] = sb**2 * dt * np.eye(3)
    return Q


def body_oracle(x: NominalState, r_n: F64) -> F64:
    """A known nav vector seen in the body, ``C_bn r_n`` (SPEC 3.1): the accelerometer as
    gravity (r = -g_n) and the 3-D magnetometer (r = m_n)."""
    return np.asarray(dcm_from_quat(x.q_nb).T @ r_n)


def yaw_oracle(x: NominalState) -> F64:
    """The ZYX yaw (1,) of the attitude (SPEC 3.3, heading-only fusion)."""
    return np.array([euler_from_quat(x.q_nb)[2]])


def propagate_oracle(q: F64, bg: F64, P: F64, w_b: F64, dt: float, sg: float, sb: float) -> tuple[F64, F64, F64]:
    _, Q, B = sigma_oracle(q, bg, P)
    Q = np.array([quat_mul(Q[i], quat_exp((w_b - B[i]) * dt)) for i in range(13)])
    X = np.column_stack([[grp_oracle(quat_mul(quat_conj(Q[0]), Qi)) for Qi in Q], B])
    x = W @ X
    D = X - x
    P_new = D.T @ (W[:, None] * D) + process_noise_oracle(sg, sb, dt)
    return quat_normalize(quat_mul(Q[0], dq_oracle(x[:3]))), x[3:], P_new


def update_oracle(
    q: F64, bg: F64, P: F64, z: F64, h: Callable[[NominalState], F64], var: float, angle: bool
) -> tuple[F64, F64, F64, F64, float]:
    S, Q, B = sigma_oracle(q, bg, P)
    Y = np.array([h(NominalState(q_nb=Q[i], bg=B[i])) for i in range(13)])
    if angle:
        Y = Y[0] + wrap(Y - Y[0])
    y = W @ Y
    dY = Y - y
    Pyy = dY.T @ (W[:, None] * dY) + var * np.eye(len(z))
    Pxy = S.T @ (W[:, None] * dY)
    nu = wrap(z - y) if angle else z - y
    K = Pxy @ np.linalg.inv(Pyy)
    dx = K @ nu
    return (quat_normalize(quat_mul(q, dq_oracle(dx[:3]))), bg + dx[3:], P - K @ Pyy @ K.T, nu,
            float(nu @ np.linalg.solve(Pyy, nu)))  # fmt: skip


def random_state(rng: np.random.Generator) -> tuple[F64, F64, F64]:
    """A unit quaternion (pitch well away from +-90 deg), a bias (rad/s) and a covariance
    (6, 6) of a few degrees and a few mrad/s, correlated."""
    q = quat_from_euler(rng.uniform([-1.0, -0.8, -np.pi], [1.0, 0.8, np.pi]))
    A = rng.normal(size=(6, 6)) * np.r_[[0.05] * 3, [0.005] * 3][:, None]
    return q, rng.normal(size=3) * 0.01, A @ A.T + 1e-6 * np.eye(6)


def kernel_arrays(q: F64, bg: F64, P: F64) -> tuple[F64, F64, F64]:
    """x (N_X,), P (NMAX, NMAX) and work (N_WORK, NMAX) as the kernels take them."""
    x, Pk, work = np.zeros(N_X), np.zeros((NMAX, NMAX)), np.zeros((N_WORK, NMAX))
    x[X_Q : X_Q + 4], x[X_BG : X_BG + 3], Pk[:6, :6] = q, bg, P
    return x, Pk, work


# --- (a) GRP, square root, weights, process noise ---------------------------------------------


def quat_from_grp(dp: F64) -> F64:
    return np.array([_dq_from_grp(*p) for p in dp])


def grp_from_quat(dq: F64) -> F64:
    return np.array([_grp_from_dq(*q) for q in dq])


def test_grp_round_trip_and_small_angle() -> None:
    rng = np.random.default_rng(SEED)
    dq = quat_normalize(rng.normal(size=(500, 4)))
    dq[:, 0] = np.abs(dq[:, 0])  # w >= 0: every rotation up to 180 deg
    dp = grp_from_quat(dq)
    assert np.all(np.linalg.norm(dp, axis=1) <= 4.0 + 1e-12)
    np.testing.assert_allclose(quat_from_grp(dp), dq, atol=1e-12)
    np.testing.assert_allclose(grp_from_quat(-dq), dp, atol=1e-12)  # q and -q: one rotation
    np.testing.assert_allclose(np.linalg.norm(quat_from_grp(dp), axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(dp, [grp_oracle(d) for d in dq], rtol=1e-14, atol=1e-15)

    p = rng.normal(size=(500, 3))
    p *= (rng.uniform(0.0, 3.9, 500) / np.linalg.norm(p, axis=1))[:, None]
    np.testing.assert_allclose(grp_from_quat(quat_from_grp(p)), p, atol=1e-12)
    np.testing.assert_allclose(quat_from_grp(p), [dq_oracle(v) for v in p], rtol=0.0, atol=1e-15)

    # a = 1, f = 4: dp = 4 tan(|dtheta|/4) e exactly, so dp - dtheta = |dtheta|^3/48 + ...
    theta = rng.normal(size=(500, 3)) * rng.uniform(1e-6, 1.0, (500, 1))
    ang = np.linalg.norm(theta, axis=1, keepdims=True)
    dp = grp_from_quat(quat_exp(theta))
    np.testing.assert_allclose(dp, 4.0 * np.tan(ang / 4.0) * theta / ang, rtol=1e-12, atol=1e-15)
    small = ang[:, 0] < 0.05
    err = np.linalg.norm(dp - theta, axis=1)
    assert np.all(err[small] <= 1.01 * ang[small, 0] ** 3 / 48.0 + 1e-16)
    assert _grp_from_dq(1.0, 0.0, 0.0, 0.0) == (0.0, 0.0, 0.0)


def test_square_root_equals_lapack_and_survives_rounding() -> None:
    """The scalar Cholesky equals LAPACK's to rounding; a covariance made slightly indefinite
    by rounding takes the eigen square root and still gives sigma points."""
    rng = np.random.default_rng(SEED + 6)
    A = rng.normal(size=(6, 8))
    L = np.zeros((NMAX, NMAX))
    sqrt_cov(A @ A.T, 7.0, L)
    L6 = L[:6, :6]
    np.testing.assert_allclose(L6, np.linalg.cholesky(7.0 * A @ A.T), rtol=0.0, atol=1e-13 * np.abs(L6).max())
    B = A[:, :5]
    w, V = np.linalg.eigh(B @ B.T)  # rank 5
    w[0] = -1e-15
    P = (V * w) @ V.T
    sqrt_cov(P, 7.0, L)
    assert np.isfinite(L6).all()
    np.testing.assert_allclose(L6 @ L6.T, 7.0 * P, atol=1e-12 * np.abs(P).max())


def test_weights_and_process_noise() -> None:
    assert _W0 == pytest.approx(1.0 / 7.0, abs=1e-16) and _WI == pytest.approx(1.0 / 14.0, abs=1e-16)
    assert _W0 + 12 * _WI == pytest.approx(1.0, abs=1e-15)
    rng = np.random.default_rng(SEED + 7)
    D = rng.normal(size=(13, 6))
    mean, C = np.zeros(NMAX), np.zeros((NMAX, NMAX))
    Y = np.zeros((13, NMAX))
    Y[:, :6] = D
    _centre(Y, 6, mean)
    np.testing.assert_allclose(mean[:6], W @ D, atol=1e-15)
    np.testing.assert_allclose(Y[:, :6], D - W @ D, atol=1e-15)
    _weighted_cov(Y, 6, C)
    np.testing.assert_allclose(C[:6, :6], (D - W @ D).T @ (W[:, None] * (D - W @ D)), atol=1e-14)
    assert np.array_equal(C, C.T)
    for dt in (0.005, 0.01, 0.2):
        Q = np.zeros((NMAX, NMAX))
        _add_process_noise(1.3e-4**2, 2e-5**2, dt, Q)
        np.testing.assert_allclose(Q[:6, :6], process_noise_oracle(1.3e-4, 2e-5, dt), rtol=1e-14, atol=0.0)
        assert not Q[6:].any() and not Q[:, 6:].any()


# --- (b) sigma points, point predictions, one propagation and one update ------------------------


def test_sigma_points_equal_oracle() -> None:
    rng = np.random.default_rng(SEED + 8)
    for _ in range(5):
        q, bg, P = random_state(rng)
        x, Pk, work = kernel_arrays(q, bg, P)
        _sigma(x, Pk, work)
        S, Q, _ = sigma_oracle(q, bg, P)
        np.testing.assert_allclose(work[U_S : U_S + 13, :6], S, rtol=0.0, atol=1e-14)
        np.testing.assert_allclose(work[U_Q : U_Q + 13, :4], Q, rtol=0.0, atol=1e-14)


def test_point_predictions_equal_observation_models() -> None:
    rng = np.random.default_rng(SEED + 1)
    Q = quat_normalize(rng.normal(size=(13, 4)))
    site = default_site()
    g_n, m_n = site.gravity_n, site.mag_n
    assert m_n is not None
    work = np.zeros((N_WORK, NMAX))
    Y = work[U_Y : U_Y + 13]
    for r_n, model in (
        (-g_n, lambda x: body_oracle(x, -g_n)),
        (m_n, lambda x: body_oracle(x, m_n)),
    ):
        work[U_Q : U_Q + 13, :4] = Q
        _predict_vector(work, *r_n)
        ref = np.array([model(NominalState(q_nb=q, bg=np.zeros(3))) for q in Q])
        np.testing.assert_allclose(Y[:, :3], ref, rtol=0.0, atol=1e-15 * float(np.linalg.norm(r_n)))
    # heading: the points' yaw about a centre near 180 deg, unwrapped about the centre's
    Q = np.array([quat_mul(quat_from_euler([0.2, -0.1, np.pi - 0.01]), quat_exp(v))
                  for v in np.vstack([np.zeros(3), rng.normal(size=(12, 3)) * 0.05])])  # fmt: skip
    work[U_Q : U_Q + 13, :4] = Q
    _predict_heading(work)
    yaw = np.array([yaw_oracle(NominalState(q_nb=q, bg=np.zeros(3)))[0] for q in Q])
    assert (yaw < -3.0).any() and (yaw > 3.0).any()  # the points straddle +-180 deg
    np.testing.assert_allclose(Y[:, 0], yaw[0] + wrap(yaw - yaw[0]), rtol=0.0, atol=1e-14)


def test_propagation_equals_oracle() -> None:
    rng = np.random.default_rng(SEED + 9)
    prm = np.zeros(1, PRM)[0]
    sg, sb = 2e-3, 1e-4
    prm["gyro_noise2"], prm["gyro_bias_noise2"] = sg**2, sb**2
    for dt in (0.005, 0.02, 0.1):
        q, bg, P = random_state(rng)
        w_b = rng.normal(size=3)
        x, Pk, work = kernel_arrays(q, bg, P)
        _propagate(prm, x, Pk, work, *w_b, dt)
        q_ref, bg_ref, P_ref = propagate_oracle(q, bg, P, w_b, dt, sg, sb)
        np.testing.assert_allclose(x[X_Q : X_Q + 4], q_ref, rtol=0.0, atol=1e-14)
        np.testing.assert_allclose(x[X_BG : X_BG + 3], bg_ref, rtol=0.0, atol=1e-16)
        np.testing.assert_allclose(Pk[:6, :6], P_ref, rtol=1e-11, atol=1e-12 * np.abs(P_ref).max())
        assert np.array_equal(Pk[:6, :6], Pk[:6, :6].T)


@pytest.mark.parametrize("model", ["accel", "mag", "heading"])
def test_update_equals_oracle(model: str) -> None:
    """One update: innovation, NIS, log, state and covariance; a too tight gate refuses it and
    leaves the state alone."""
    rng = np.random.default_rng(SEED + 10)
    site = default_site()
    g_n, m_n = site.gravity_n, site.mag_n
    assert m_n is not None
    caps = np.full(N_SENSORS, 4, dtype=np.int64)
    st = make_state("mekf", False, EskfParams(), site, None, frozenset({"imu", "mag"}), caps)
    q, bg, P = random_state(rng)
    h: Callable[[NominalState], F64]
    if model == "heading":
        h, sensor, m, var, angle = yaw_oracle, INN_MAG, 1, 0.05**2, True
        z = np.array([euler_from_quat(q)[2] + 0.1])
    else:
        r_n = -g_n if model == "accel" else m_n
        h = (lambda s: body_oracle(s, -g_n)) if model == "accel" else (lambda s: body_oracle(s, m_n))
        sensor, m, angle = (INN_ACCEL if model == "accel" else INN_MAG), 3, False
        var = (0.3 if model == "accel" else 2e-6) ** 2
        z = h(NominalState(q_nb=quat_mul(q, quat_exp(rng.normal(size=3) * 0.05)), bg=bg))
    q_ref, bg_ref, P_ref, nu_ref, nis_ref = update_oracle(q, bg, P, z, h, var, angle)
    for gate2, accepted in ((1e6, True), (1e-12, False)):
        x, Pk, work = kernel_arrays(q, bg, P)
        _sigma(x, Pk, work)
        if model == "heading":
            _predict_heading(work)
        else:
            _predict_vector(work, *r_n)
        work[U_NU, :m] = z
        ok = _update(st.cfg, x, st.flags, Pk, work, st.inn, st.acc, np.int64(sensor), 1.5, np.int64(m), var, gate2,
                     angle)  # fmt: skip
        assert ok is accepted
        row = int(st.cfg["log_off"][sensor] + st.flags[L_CNT + sensor]) - 1  # the row just logged
        assert st.inn[row, 0] == 1.5 and st.acc[row] == accepted
        assert st.inn[row, 4] == pytest.approx(nis_ref, rel=1e-10)
        np.testing.assert_allclose(st.inn[row, 1 : 1 + m], nu_ref, rtol=1e-12, atol=1e-15 * np.abs(z).max())
        assert np.isnan(st.inn[row, 1 + m : 4]).all()
        if not accepted:
            assert np.array_equal(x[X_Q : X_Q + 4], q) and np.array_equal(Pk[:6, :6], P)
            continue
        np.testing.assert_allclose(work[U_NU, :m], nu_ref, rtol=1e-12, atol=1e-15 * np.abs(z).max())
        np.testing.assert_allclose(x[X_Q : X_Q + 4], q_ref, rtol=0.0, atol=1e-13)
        np.testing.assert_allclose(x[X_BG : X_BG + 3], bg_ref, rtol=0.0, atol=1e-14)
        np.testing.assert_allclose(Pk[:6, :6], P_ref, rtol=0.0, atol=1e-11 * np.abs(P).max())
        assert np.array_equal(Pk[:6, :6], Pk[:6, :6].T)


# --- (c) zero noise ------------------------------------------------------------------------------


def test_zero_noise_converges_to_truth() -> None:
    """Noiseless sensors, started at the truth. Unlike the MEKF the UKF is not exact here:
    its predicted measurement is the sigma-point mean of h, which differs from h at the
    estimate by O(P), so the estimate moves away by O(P) and returns as P shrinks."""
    base = SensorSuite(imu_rate=50.0, gnss=None, pitot=None, vanes=None)
    fl = flight(base.noiseless(), 60.0, SEED)
    est = Usque(matched_to(base)).run(fl, initial=InitialState.from_truth(fl, sigma_att=2.0 * DEG))
    err = attitude_errors(est, fl).total
    assert err.max() < 1e-3  # the O(P0) excursion of the first updates
    assert err[fl.imu.t >= 50.0].max() < 1e-6
    assert est.gyro_bias_b is not None and fl.truth is not None
    assert np.abs(est.gyro_bias_b[-1] - fl.truth.gyro_bias_b[-1]).max() < 1e-6  # type: ignore[index]
    assert set(est.innovations) == {"accel", "mag"}
    assert est.innovations["accel"].accepted.all() and est.innovations["mag"].accepted.all()


# --- (d) Monte Carlo consistency --------------------------------------------------------------


RUNS = 50
MC_DURATION = 8.0


@cache
def monte_carlo() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run-averaged NEES (N,) and accelerometer / magnetometer NIS (per sample) of RUNS
    seeds. Each run starts from an attitude drawn about the truth with the filter's own
    sigma and from a zero bias estimate (the simulated initial bias is N(0, sigma_bias^2)),
    so the initial error is distributed as P0 says."""
    params = matched_to(MATCHED)
    est = Usque(params)
    traj = rotating_in_place(MC_DURATION, MATCHED.imu_rate)
    sigma_att = 2.0 * DEG
    nees, nis_acc, nis_mag = [], [], []
    for run in range(RUNS):
        rng = np.random.default_rng(SEED + 100 + run)
        fl = measure(traj, MATCHED, default_site(), rng)
        assert fl.truth is not None
        q0 = quat_mul(fl.truth.q_nb[0], quat_exp(rng.normal(size=3) * sigma_att))
        ini = InitialState(
            q_nb=q0, gyro_bias_b=np.zeros(3), sigma_att=sigma_att, sigma_bias=MATCHED.gyro.bias_init_sigma
        )
        e = est.run(fl, initial=ini)
        nees.append(nees_attitude(e, fl))
        nis_acc.append(e.innovations["accel"].nis)
        nis_mag.append(e.innovations["mag"].nis)
    return np.mean(nees, axis=0), np.nanmean(nis_acc, axis=0), np.nanmean(nis_mag, axis=0)


def test_nees_consistent() -> None:
    nees, _, _ = monte_carlo()
    lo, hi = chi2_band(6, RUNS)
    assert lo <= nees.mean() <= hi, (nees.mean(), lo, hi)
    inside = np.mean((nees >= lo) & (nees <= hi))
    assert inside >= 0.9, inside


@pytest.mark.parametrize("sensor", ["accel", "mag"])
def test_nis_consistent(sensor: str) -> None:
    _, nis_acc, nis_mag = monte_carlo()
    nis = nis_acc if sensor == "accel" else nis_mag
    lo, hi = chi2_band(3, RUNS)
    assert np.isfinite(nis).all()
    assert lo <= nis.mean() <= hi, (sensor, nis.mean(), lo, hi)


# --- (e) streaming equals batch ------------------------------------------------------------------


def assert_identical(a: Estimate, b: Estimate) -> None:
    """Every output equal bit for bit (NaN where NaN)."""
    assert a.state_labels == b.state_labels and a.skipped == b.skipped
    for key in ("t", "q_nb", "gyro_bias_b", "cov"):
        assert np.array_equal(getattr(a, key), getattr(b, key), equal_nan=True), key
    assert list(a.innovations) == list(b.innovations)
    for k, ia in a.innovations.items():
        ib = b.innovations[k]
        for key in ("t", "nu", "nis", "accepted"):
            assert np.array_equal(getattr(ia, key), getattr(ib, key), equal_nan=True), (k, key)


def _stream(est: Usque, fl: Flight, has: frozenset[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Feed merge_events sample by sample; the state after the last sample at or before each
    IMU time (q, bias, cov per IMU row)."""
    t_ev, kinds, vals = merge_events(fl, has)
    s = est.streamer(fl.site, initial=None, has=has)
    q, b, P = [], [], []
    for i in range(len(t_ev)):
        s.push(int(kinds[i]), float(t_ev[i]), vals[i])
        if i + 1 == len(t_ev) or kinds[i + 1] == 0:
            st = s.state
            q.append(st.q_nb)
            b.append(st.gyro_bias_b)
            P.append(st.cov)
    return np.array(q), np.array(b), np.array(P)


def test_streaming_equals_batch() -> None:
    fl = flight(MATCHED, 5.0, SEED)
    est = Usque(matched_to(MATCHED))
    batch = est.run(fl)  # no initial state: TRIAD once the first magnetometer sample is in
    q, b, P = _stream(est, fl, frozenset({"imu", "mag"}))
    assert batch.gyro_bias_b is not None and batch.cov is not None
    assert np.array_equal(q, batch.q_nb)
    assert np.array_equal(b, batch.gyro_bias_b)
    assert np.array_equal(P, batch.cov, equal_nan=True)
    assert batch.state_labels == ("att_x", "att_y", "att_z", "bg_x", "bg_y", "bg_z")
    assert np.isfinite(batch.cov).all()


@pytest.mark.parametrize("mag_mode", ["3d", "heading"])
def test_streaming_with_every_sensor_equals_batch(mag_mode: str) -> None:
    """Through base.replay, NaN samples included; GNSS and air-data samples fed to the
    streamer are ignored."""
    est = Usque(EskfParams(mag_mode=mag_mode))
    f = fixedwing("nan")
    t_ev, kinds, vals = merge_events(f, frozenset({"imu", "mag", "gnss", "air"}))
    assert {2, 3} <= set(kinds.tolist())
    streamed = replay(est, est.streamer(f.site, has=frozenset({"imu", "mag"})), f, t_ev, kinds, vals)
    assert_identical(streamed, est.run(f))


# --- (f) modes, initial states, bad parameters and bad input ---------------------------------


def test_heading_and_off_modes() -> None:
    fl = flight(MATCHED, 20.0, SEED + 3)
    p = matched_to(MATCHED)
    heading = Usque(p.replace(mag_mode="heading")).run(fl)
    assert heading.innovations["mag"].nu.shape[1] == 1
    err = attitude_errors(heading, fl).total
    assert err[fl.imu.t >= 15.0].max() < 1.0 * DEG
    off = Usque(p.replace(mag_mode="off")).run(fl)
    assert "mag" not in off.innovations


def test_heading_across_180_deg() -> None:
    """Heading only, the site's field reversed: the attitude the sensors agree with is the
    plain site's turned 180 deg about the vertical, so the estimate lives about +-180 deg,
    where the sigma points' yaws and the innovations wrap; it equals the plain site's
    estimate turned."""
    p = EskfParams(mag_mode="heading")
    south, plain = Usque(p).run(fixedwing("south", 10.0)), Usque(p).run(fixedwing("plain", 10.0))
    yaw = euler_from_quat(south.q_nb)[:, 2]
    assert (yaw > 3.0).any() and (yaw < -3.0).any()
    turned = quat_mul(np.array([0.0, 0.0, 0.0, 1.0]), plain.q_nb)
    err = np.linalg.norm(quat_log(quat_mul(quat_conj(turned), south.q_nb)), axis=1)
    assert err.max() < 1e-8, err.max()
    np.testing.assert_allclose(south.innovations["mag"].nu, plain.innovations["mag"].nu, rtol=0.0, atol=1e-8)


def test_gates() -> None:
    """The fixed wing's manoeuvres trip the ``| |f| - g |`` gate of raw samples (EskfParams():
    no low-pass); tight gates reject some updates of each sensor."""
    acc = Usque(EskfParams()).run(fixedwing()).innovations["accel"].accepted
    assert acc.any() and not acc.all()
    for params in (EskfParams(gate_accel=1.0, gate_mag=1.0),
                   EskfParams(mag_mode="heading", gate_mag=1.0, accel_norm_gate=0.5)):  # fmt: skip
        est = Usque(params).run(fixedwing("nan"))
        assert set(est.innovations) == {"accel", "mag"}
        assert all(not inn.accepted.all() and inn.accepted.any() for inn in est.innovations.values())


def test_initial_state_normalised_and_mag_bias_ignored() -> None:
    """A given attitude is normalised (-2 q is q); init_mag_bias adds no states."""
    f = fixedwing()
    ini = InitialState.from_truth(f, sigma_att=0.05)
    a = Usque().run(f, initial=ini)
    b = Usque().run(f, initial=dataclasses.replace(ini, q_nb=-2.0 * ini.q_nb))
    np.testing.assert_allclose(quat_log(quat_mul(quat_conj(a.q_nb), b.q_nb)), 0.0, atol=1e-12)
    c = Usque(Usque.default_params.replace(init_mag_bias=1e-6)).run(f)
    assert c.state_labels == ("att_x", "att_y", "att_z", "bg_x", "bg_y", "bg_z")
    assert_identical(c, Usque().run(f))


def test_nan_samples_skipped_and_counted() -> None:
    fl = flight(MATCHED, 4.0, SEED + 4)
    imu, mag = fl.imu, fl.mag
    assert mag is not None
    w, f, m = imu.w_b.copy(), imu.f_b.copy(), mag.mag_b.copy()
    w[[10, 11, 60], 1] = np.nan
    f[100, 2] = np.nan
    m[[3, 7], 0] = np.nan
    bad = fl.replace(imu=ImuStream(t=imu.t, w_b=w, f_b=f), mag=MagStream(t=mag.t, mag_b=m))
    est = Usque(matched_to(MATCHED)).run(bad)
    assert est.skipped == {"imu": 4, "mag": 2, "gnss": 0, "air": 0}
    assert np.isfinite(est.q_nb).all() and np.isfinite(est.cov).all()  # type: ignore[arg-type]
    assert attitude_errors(est, bad).total[-1] < 1.0 * DEG
    # NaN in the very first samples: the initialisation waits (the rows until then hold the
    # state it would start from, flagged not_initialised)
    est = Usque().run(fixedwing("nan"))
    assert est.skipped["imu"] > 0 and est.skipped["mag"] > 0
    assert est.cov is not None and np.isfinite(est.cov).all() and est.first_initialised == est.init_index > 0
    assert est.flags is not None and all(est.flags[: est.init_index] & (1 << FLAGS["not_initialised"][0]))


def test_imu_only_unknown_site_and_bad_params() -> None:
    fl = flight(MATCHED, 2.0, SEED + 5)
    est = Usque().run(fl.replace(mag=None))  # only the IMU is required
    assert set(est.innovations) == {"accel"} and len(est.t) == len(fl.imu.t)
    # unknown site field: the reference from the first magnetometer sample, 3-D fusion
    f = fixedwing()
    est = Usque().run(f.replace(site=Site(gravity=f.site.gravity, mag_n=None)))
    assert est.innovations["mag"].nu.shape[1] == 3 and np.isfinite(est.q_nb).all()
    with pytest.raises(ValueError, match="accel_compensation"):
        Usque(EskfParams(accel_compensation="gnss"))
    with pytest.raises(TypeError, match="EskfParams"):
        Usque(params=object())  # type: ignore[arg-type]
    s = Usque().streamer(fl.site)
    s.imu(1.0, np.zeros(3), np.array([0.0, 0.0, -9.8]))
    with pytest.raises(ValueError, match="imu.t"):
        s.imu(0.5, np.zeros(3), np.array([0.0, 0.0, -9.8]))


def test_registry_runs_usque() -> None:
    est = make_estimator("usque")
    assert type(est) is Usque and est.params == Usque().params == Usque.default_params
    assert Usque.default_params == EskfParams(accel_lowpass=3.0, accel_noise_online=True)
    spec = "usque:mag_mode=heading:gate_mag=2.5"
    est = make_estimator(spec)
    assert type(est) is Usque and est.params == Usque.default_params.replace(mag_mode="heading", gate_mag=2.5)
    out = est.run(fixedwing())
    assert out.filter == spec and out.innovations["mag"].nu.shape[1] == 1


# --- (g) the readable reference: the same source with NUMBA_DISABLE_JIT=1 ---------------------

_BRIDGE = textwrap.dedent(
    """
    import pickle, sys
    import numpy as np
    from numba.core import config
    from windahrs.filters import usque
    from windahrs.filters.params import EskfParams
    assert config.DISABLE_JIT and not hasattr(usque.run_usque, "py_func")
    with open(sys.argv[1], "rb") as fh:
        f = pickle.load(fh)
    out = {}
    for mode in ("3d", "heading"):
        e = usque.Usque(EskfParams(mag_mode=mode)).run(f)
        out[mode] = (e.q_nb, e.gyro_bias_b, e.cov, e.innovations["accel"].nis, e.innovations["mag"].nis,
                     e.innovations["accel"].accepted, e.innovations["mag"].accepted, e.skipped)
    with open(sys.argv[2], "wb") as fh:
        pickle.dump(out, fh)
    """
)


def test_jit_disabled_equals_jit(tmp_path: Path) -> None:
    """The readable reference (interpreted, about 1 s of fixed-wing flight with NaN samples,
    3-D and heading) equals the compiled run to 1e-9 rad."""
    f = fixedwing("nan", 1.0)
    src, dst = tmp_path / "flight.pkl", tmp_path / "out.pkl"
    src.write_bytes(pickle.dumps(f))
    env = dict(os.environ, NUMBA_DISABLE_JIT="1", PYTHONPATH=str(Path(windahrs.__file__).parents[1]))
    subprocess.run([sys.executable, "-c", _BRIDGE, str(src), str(dst)], env=env, check=True, timeout=120)
    ref = pickle.loads(dst.read_bytes())
    for mode in ("3d", "heading"):
        e = Usque(EskfParams(mag_mode=mode)).run(f)
        q, bg, cov, nis_a, nis_m, acc_a, acc_m, skipped = ref[mode]
        assert skipped == e.skipped and skipped["imu"] > 0
        err = np.linalg.norm(quat_log(quat_mul(quat_conj(q), e.q_nb)), axis=1)
        assert np.isfinite(err[1:]).all() and err[np.isfinite(err)].max() <= 1e-9, mode
        np.testing.assert_allclose(e.gyro_bias_b, bg, rtol=0.0, atol=1e-12)
        np.testing.assert_allclose(e.cov, cov, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(e.innovations["accel"].nis, nis_a, rtol=1e-8)
        np.testing.assert_allclose(e.innovations["mag"].nis, nis_m, rtol=1e-8)
        assert np.array_equal(e.innovations["accel"].accepted, acc_a)
        assert np.array_equal(e.innovations["mag"].accepted, acc_m)
