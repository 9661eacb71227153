"""[usque]: the GRP maps, its models against the error-state ones, zero-noise convergence,
Monte Carlo consistency (NEES and NIS), streaming equal to batch, the per-point reference
equal to the batch predictions, and bad input."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from windahrs.conventions import DEG
from windahrs.estimate import Estimate
from windahrs.filters.base import InitialState, merge_events
from windahrs.filters.params import EskfParams, matched_to
from windahrs.filters.usque import (
    Usque,
    _rotate_inv,
    _sqrt_cov,
    grp_from_quat,
    process_noise,
    quat_from_grp,
    sigma_weights,
)
from windahrs.flight import Flight, ImuStream, MagStream
from windahrs.metrics import attitude_errors, chi2_band, nees_attitude
from windahrs.models import observations as obs
from windahrs.models.error_state import Layout, NominalState, ProcessNoise, predict
from windahrs.rotation import quat_exp, quat_from_euler, quat_log, quat_mul, quat_normalize
from windahrs.sim.gust_response import rates_from_attitude
from windahrs.sim.scenario import default_site
from windahrs.sim.sensors import AccelModel, MagModel, SensorSuite, TruthTrajectory, measure

SEED = 20240611
LAYOUT = Layout(("att", "bg"))

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


# --- (a) generalised Rodrigues parameters and the shared models ------------------------------


def test_grp_round_trip_and_small_angle() -> None:
    rng = np.random.default_rng(SEED)
    dq = quat_normalize(rng.normal(size=(500, 4)))  # w >= 0: every rotation up to 180 deg
    dp = grp_from_quat(dq)
    assert np.all(np.linalg.norm(dp, axis=1) <= 4.0 + 1e-12)
    np.testing.assert_allclose(quat_from_grp(dp), dq, atol=1e-12)
    np.testing.assert_allclose(grp_from_quat(-dq), dp, atol=1e-12)  # q and -q: one rotation
    np.testing.assert_allclose(np.linalg.norm(quat_from_grp(dp), axis=1), 1.0, atol=1e-14)

    p = rng.normal(size=(500, 3))
    p *= (rng.uniform(0.0, 3.9, 500) / np.linalg.norm(p, axis=1))[:, None]
    np.testing.assert_allclose(grp_from_quat(quat_from_grp(p)), p, atol=1e-12)

    # a = 1, f = 4: dp = 4 tan(|dtheta|/4) e exactly, so dp - dtheta = |dtheta|^3/48 + ...
    theta = rng.normal(size=(500, 3)) * rng.uniform(1e-6, 1.0, (500, 1))
    ang = np.linalg.norm(theta, axis=1, keepdims=True)
    dp = grp_from_quat(quat_exp(theta))
    np.testing.assert_allclose(dp, 4.0 * np.tan(ang / 4.0) * theta / ang, rtol=1e-12, atol=1e-15)
    small = ang[:, 0] < 0.05
    err = np.linalg.norm(dp - theta, axis=1)
    assert np.all(err[small] <= 1.01 * ang[small, 0] ** 3 / 48.0 + 1e-16)
    assert np.all(grp_from_quat(np.array([1.0, 0.0, 0.0, 0.0])) == 0.0)


def test_square_root_survives_rounding() -> None:
    """A covariance made slightly indefinite by rounding still gives sigma points."""
    rng = np.random.default_rng(SEED + 6)
    A = rng.normal(size=(6, 5))
    P = A @ A.T  # rank 5
    w, V = np.linalg.eigh(P)
    w[0] = -1e-15
    P = (V * w) @ V.T
    L = _sqrt_cov(P, 7.0)
    assert np.isfinite(L).all()
    np.testing.assert_allclose(L @ L.T, 7.0 * P, atol=1e-12 * np.abs(P).max())


def test_weights_and_process_noise() -> None:
    w = sigma_weights()
    assert w.shape == (13,) and w.sum() == pytest.approx(1.0, abs=1e-15)
    assert w[0] == pytest.approx(1.0 / 7.0) and w[1] == pytest.approx(1.0 / 14.0)
    # Q_d equals the [att, bg] blocks the error-state model builds (predict with P = 0).
    x = NominalState(q_nb=quat_normalize(np.array([0.9, 0.1, -0.2, 0.3])), bg=np.array([0.01, 0.0, -0.02]))
    noise = ProcessNoise(gyro=1.3e-4, gyro_bias=2e-5)
    for dt in (0.005, 0.01, 0.2):
        w_m, g_n = np.array([0.3, -0.5, 1.1]), np.array([0.0, 0.0, 9.8])
        _, Q = predict(LAYOUT, x, np.zeros((6, 6)), w_m, np.zeros(3), dt, noise, g_n)
        np.testing.assert_allclose(process_noise(1.3e-4, 2e-5, dt), Q, rtol=1e-14, atol=0.0)


def test_point_predictions_equal_observation_models() -> None:
    rng = np.random.default_rng(SEED + 1)
    Q = quat_normalize(rng.normal(size=(13, 4)))
    site = default_site()
    g_n = site.gravity_n
    assert site.mag_n is not None
    for r_n, model in (
        (-g_n, lambda x: obs.specific_force(LAYOUT, x, g_n)[0]),
        (site.mag_n, lambda x: obs.vector_body(LAYOUT, x, site.mag_n)[0]),
    ):
        ref = np.array([model(NominalState(q_nb=q, bg=np.zeros(3))) for q in Q])
        tol = 1e-15 * float(np.linalg.norm(r_n))
        np.testing.assert_allclose(_rotate_inv(Q, r_n), ref, rtol=0.0, atol=tol)


# --- (b) zero noise ------------------------------------------------------------------------------


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


# --- (c) Monte Carlo consistency --------------------------------------------------------------


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


# --- (d) streaming equals batch; reference equals batch --------------------------------------


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


def _assert_close_runs(a: Estimate, b: Estimate) -> None:
    assert a.gyro_bias_b is not None and b.gyro_bias_b is not None
    assert a.cov is not None and b.cov is not None
    np.testing.assert_allclose(quat_log(quat_mul(a.q_nb * [1, -1, -1, -1], b.q_nb)), 0.0, atol=1e-12)
    np.testing.assert_allclose(a.gyro_bias_b, b.gyro_bias_b, atol=1e-12)
    np.testing.assert_allclose(a.cov, b.cov, rtol=1e-9, atol=1e-18)
    for k in a.innovations:
        np.testing.assert_allclose(a.innovations[k].nis, b.innovations[k].nis, rtol=1e-8)


@pytest.mark.parametrize("mag_mode", ["3d", "heading"])
def test_reference_points_equal_batch(mag_mode: str) -> None:
    """The per-point calls of the model functions and the batch predictions, whole runs."""
    fl = flight(MATCHED, 3.0, SEED + 2)
    p = matched_to(MATCHED).replace(mag_mode=mag_mode)
    _assert_close_runs(Usque(p, reference=True).run(fl), Usque(p).run(fl))


# --- (e) modes, bad parameters and bad input ---------------------------------------------------


def test_heading_and_off_modes() -> None:
    fl = flight(MATCHED, 20.0, SEED + 3)
    p = matched_to(MATCHED)
    heading = Usque(p.replace(mag_mode="heading")).run(fl)
    assert heading.innovations["mag"].nu.shape[1] == 1
    err = attitude_errors(heading, fl).total
    assert err[fl.imu.t >= 15.0].max() < 1.0 * DEG
    off = Usque(p.replace(mag_mode="off")).run(fl)
    assert "mag" not in off.innovations


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


def test_imu_only_and_bad_params() -> None:
    fl = flight(MATCHED, 2.0, SEED + 5)
    est = Usque().run(fl.replace(mag=None))  # only the IMU is required
    assert "mag" not in est.innovations and len(est.t) == len(fl.imu.t)
    with pytest.raises(ValueError, match="accel_compensation"):
        Usque(EskfParams(accel_compensation="gnss"))
    with pytest.raises(TypeError, match="EskfParams"):
        Usque(params=object())  # type: ignore[arg-type]
    s = Usque().streamer(fl.site)
    s.imu(1.0, np.zeros(3), np.array([0.0, 0.0, -9.8]))
    with pytest.raises(ValueError, match="imu.t"):
        s.imu(0.5, np.zeros(3), np.array([0.0, 0.0, -9.8]))
