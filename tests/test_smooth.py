"""The offline RTS smoother (windahrs.core.smooth): equal to a dense numpy RTS on the same
forward record, consistent (NEES) and better than the forward pass in simulation, a
symmetric positive definite covariance, chain breaks, refusals, and its spec forms."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.linalg import expm

import windahrs as wa
from conftest import require_data
from windahrs.core import smooth as S
from windahrs.core.layout import INN_RESET
from windahrs.estimate import EstimatorWarning
from windahrs.experiments.reproduce import MIN_WIND_NOISE
from windahrs.filters.base import InitialState
from windahrs.filters.params import matched_to
from windahrs.filters.registry import make_estimator
from windahrs.flight import ImuStream
from windahrs.metrics import chi2_band, nees_attitude
from windahrs.rotation import quat_conj, quat_exp, quat_log, quat_mul, quat_rotate_inv
from windahrs.sim.scenario import Scenario, default_sensors, make_scenario, simulate
from windahrs.sim.wind import low_altitude_params, random_walk_density


def _matched_ins_wind(sc: Scenario) -> wa.Estimator:
    """ins-wind with the simulated sensors' noise and the wind random walk of the scenario's
    turbulence, as benchmarks/gnss_outage.py and the reproduction tune it."""
    est: Any = wa.estimator("ins-wind")
    wind_h, wind_v = random_walk_density(low_altitude_params(sc.wind.w20, sc.altitude), sc.airspeed)
    p = matched_to(default_sensors(sc), est.params).replace(
        accel_sigma=est.params.accel_sigma,
        wind_noise=max(wind_h, MIN_WIND_NOISE),
        wind_noise_vertical=max(wind_v, MIN_WIND_NOISE),
    )
    return type(est)(p)  # type: ignore[no-any-return]


def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _rts_oracle(est: wa.Estimator, rec: S.SmoothRecord) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense RTS of the 6-state mekf (attitude, gyro bias) over the forward record, in numpy:
    Phi = expm(F dt) of the continuous error dynamics d(dtheta)/dt = -[w]x dtheta - dbg
    (Van Loan), Q of SPEC 2.4 (the bias's walk about the nav vertical at gyro_bias_noise_vertical's
    density), the prior predicted from the posterior, C by a dense solve."""
    p = est.params  # type: ignore[attr-defined]
    sg2, sb2, sc2 = p.gyro_noise**2, p.gyro_bias_noise**2, p.gyro_scale_noise**2
    sv2 = p.gyro_bias_noise_vertical**2 if p.gyro_bias_noise_vertical > 0 else sb2
    nom, P, aux = rec.nom.copy(), rec.P.copy(), rec.aux
    N = len(nom)
    for k in range(N - 2, -1, -1):
        j = k + 1
        if not S._linked(aux, k, j):
            continue
        dt = aux[j, S.A_DT]
        w = aux[j, S.A_ROW : S.A_ROW + 3] - nom[k, S.N_BG : S.N_BG + 3]
        F = np.zeros((6, 6))
        F[:3, :3], F[:3, 3:] = -_skew(w), -np.eye(3)
        Phi = expm(F * dt)
        g2 = sg2 + sc2 * (w @ w)
        q_prior = quat_mul(nom[k, :4], quat_exp(w * dt))
        q_prior /= np.linalg.norm(q_prior)
        u = quat_rotate_inv(q_prior, np.array([0.0, 0.0, 1.0]))  # the nav vertical in the body
        Sb = sb2 * np.eye(3) + (sv2 - sb2) * np.outer(u, u)
        Q = np.zeros((6, 6))
        Q[:3, :3] = np.eye(3) * g2 * dt + Sb * dt**3 / 3
        Q[:3, 3:] = Q[3:, :3] = -Sb * dt**2 / 2
        Q[3:, 3:] = Sb * dt
        Pp = Phi @ P[k] @ Phi.T + Q
        C = np.linalg.solve(Pp, Phi @ P[k]).T
        dx = np.concatenate([quat_log(quat_mul(quat_conj(q_prior), nom[j, :4])), nom[j, 4:7] - nom[k, 4:7]])
        d = C @ dx
        q = quat_mul(nom[k, :4], quat_exp(d[:3]))
        nom[k, :4] = q / np.linalg.norm(q)
        nom[k, 4:7] += d[3:]
        P[k] = P[k] + C @ (P[j] - Pp) @ C.T
    return nom[:, :4], nom[:, 4:7], P


def test_equals_a_dense_numpy_rts() -> None:
    # a short level flight: the rotation over a step is tiny, the error dynamics linear
    flight = wa.simulate("quadrotor", seed=2, wind=0.0, duration=4.0)
    est = wa.estimator("mekf")
    run, rec = S.forward_record(est, flight)
    q_o, bg_o, P_o = _rts_oracle(est, rec)
    sm = S.smooth(est, flight, method="rts")
    assert sm.meta["smoother"] == "rts"
    ok = rec.aux[:, S.A_INIT] == 1
    assert ok.sum() > 0.9 * len(ok)
    linked = S.backward(run.st.cfg, run.st.prm, rec.nom.copy(), rec.P.copy(), rec.aux, run.st.P.shape[0])
    assert linked.sum() > 0.9 * len(ok)
    ang = np.linalg.norm(quat_log(quat_mul(quat_conj(q_o[ok]), sm.q_nb[ok])), axis=1)
    assert ang.max() < 1e-9
    np.testing.assert_allclose(sm.gyro_bias_b[ok], bg_o[ok], rtol=0, atol=1e-11)
    scale = np.abs(P_o[ok]).max(axis=(1, 2))[:, None, None]
    assert (np.abs(sm.cov[ok] - P_o[ok]) / scale).max() < 1e-7
    # the smoother moved the estimate (it is not the forward one)
    fwd = est.run(flight)
    assert np.linalg.norm(quat_log(quat_mul(quat_conj(fwd.q_nb[ok]), sm.q_nb[ok])), axis=1).max() > 1e-4


def test_nees_in_band_and_rmse_below_the_forward_pass() -> None:
    sc = make_scenario("fixedwing", wind=5.0, duration=60.0)
    est = _matched_ins_wind(sc)
    runs = 6
    nees, fwd_rmse, sm_rmse = [], [], []
    for seed in range(runs):
        flight = simulate(sc, np.random.default_rng(seed))
        fwd, sm = est.run(flight), S.smooth(est, flight)
        nees.append(nees_attitude(sm, flight, with_bias=False))
        fwd_rmse.append(wa.score(fwd, flight).rmse_total_deg)
        sm_rmse.append(wa.score(sm, flight).rmse_total_deg)
    A = np.array(nees)[:, len(nees[0]) // 2 :]  # second half, as the reproduction's check
    lo, hi = chi2_band(3, runs)
    mean = A.mean(axis=0)
    assert lo < A.mean() < hi
    assert np.mean((mean > lo) & (mean < hi)) > 0.9
    assert all(s < 0.5 * f for s, f in zip(sm_rmse, fwd_rmse, strict=True)), (sm_rmse, fwd_rmse)


@pytest.mark.parametrize("spec", ["mekf", "mekf-air", "ins-wind", "ins-drag"])
def test_covariance_symmetric_positive_definite(spec: str) -> None:
    vehicle = "quadrotor" if spec == "ins-drag" else "fixedwing"
    flight = wa.simulate(vehicle, seed=4, wind=5.0, duration=30.0)
    est = make_estimator(spec + "-smooth").run(flight)
    assert est.filter == spec + "-smooth"
    ok = np.isfinite(est.cov[:, 0, 0])
    assert ok.sum() > 0.9 * len(ok)
    C = est.cov[ok]
    np.testing.assert_array_equal(C, C.transpose(0, 2, 1))
    # positive definite on the states with a spread (the vertical wind may be held at zero)
    live = np.diagonal(C, axis1=1, axis2=2).min(axis=0) > 0
    assert np.linalg.eigvalsh(C[:, live][:, :, live]).min() > 0
    # smoothed spread no larger than its forward pass's (a smoother adds information): every
    # sample's covariance, predicted at every sample as the smoother's forward pass does (the
    # INS's run by default predicts it once per cov_period)
    own = spec + ":cov_period=0" if spec == "ins-wind" else spec
    fwd = make_estimator(own).run(flight, cov_every=1)
    att = slice(0, 3)
    tr_s = np.trace(C[:, att, att], axis1=1, axis2=2)
    tr_f = np.trace(fwd.cov[ok][:, att, att], axis1=1, axis2=2)
    assert np.all(tr_s <= tr_f * (1 + 1e-9))


def test_resets_break_the_chain() -> None:
    flight = wa.simulate("quadrotor", seed=3, wind=0.0, duration=20.0)
    ini = InitialState.from_truth(flight)
    upside = InitialState(q_nb=quat_mul(ini.q_nb, np.array([0.0, 1.0, 0.0, 0.0])))
    est = wa.estimator("mekf")
    run, rec = S.forward_record(est, flight, upside)  # (the warnings come with the Estimate)
    linked = S.backward(run.st.cfg, run.st.prm, rec.nom.copy(), rec.P.copy(), rec.aux, run.st.P.shape[0])
    t_reset = run.st.inn[run.st.cfg["log_off"][INN_RESET], 0]
    k = int(np.searchsorted(flight.imu.t, t_reset))
    assert not linked[k - 1] and linked[k + 5 : k + 100].all()
    with pytest.warns(EstimatorWarning):
        sm = S.smooth(est, flight, initial=upside, method="rts")
    # before the reset the RTS pass does not carry the levelled attitude back
    fwd_q = rec.nom[: k - 1, :4]
    np.testing.assert_allclose(np.abs(np.sum(sm.q_nb[k - 10 : k - 1] * fwd_q[-9:], axis=1)), 1.0, atol=0.05)
    # the two-filter smoother takes the backward pass where the forward's reset says it was lost
    with pytest.warns(EstimatorWarning):
        tf = S.smooth(est, flight, initial=upside)
    assert tf.meta["smoother"] == "two-filter"
    err = np.degrees(np.linalg.norm(quat_log(quat_mul(quat_conj(flight.truth.q_nb), tf.q_nb)), axis=1))
    fwd_err = np.degrees(np.linalg.norm(quat_log(quat_mul(quat_conj(flight.truth.q_nb), rec.nom[:, :4])), axis=1))
    assert fwd_err[: k - 1].min() > 150.0 and err[: k - 1].max() < 10.0


def test_refusals() -> None:
    flight = wa.simulate("fixedwing", seed=0, wind=0.0, duration=5.0)
    for name in ("ekf7", "ekf10", "usque", "paper", "ukf", "vqf"):
        with pytest.raises(ValueError, match=f"estimator '{name}' cannot be smoothed"):
            make_estimator(name + "-smooth")
    with pytest.raises(ValueError, match="estimator 'ekf7' cannot be smoothed"):
        S.smooth(make_estimator("ekf7"), flight)
    with pytest.raises(ValueError, match=r"smooth: expected true or false, found 2"):
        make_estimator("mekf:smooth=2")
    with pytest.raises(ValueError, match="no streamer"):
        make_estimator("mekf-smooth").stream()
    budget = S.SMOOTH_BUDGET
    try:
        S.SMOOTH_BUDGET = 1000
        with pytest.raises(ValueError, match=r"smoothing 'mekf': 1001 IMU samples need .* bytes per sample"):
            S.smooth(make_estimator("mekf"), flight)
    finally:
        S.SMOOTH_BUDGET = budget


def test_spec_forms_and_auto() -> None:
    flight = wa.simulate("fixedwing", seed=1, wind=5.0, duration=20.0)
    a = make_estimator("mekf:mag_mode=heading:smooth=true").run(flight)
    b = wa.smooth("mekf:mag_mode=heading", flight)
    assert a.filter == "mekf:mag_mode=heading:smooth=true" and b.filter == "mekf:mag_mode=heading:smooth=true"
    np.testing.assert_array_equal(a.q_nb, b.q_nb)
    auto = make_estimator("auto-smooth").run(flight)
    ins = make_estimator("ins-wind-smooth").run(flight)
    assert auto.filter == "auto-smooth" and auto.meta["auto"].startswith("ins-wind")
    np.testing.assert_array_equal(auto.q_nb, ins.q_nb)
    assert auto.wind_n is not None and np.isfinite(auto.wind_n[-1]).all()


def test_cli_smooth(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from windahrs.cli import main

    f = tmp_path / "fw.h5"
    assert main(["simulate", "--vehicle", "fixedwing", "--wind", "5", "--duration", "20", "--seed", "1",
                 "--out", str(f)]) == 0  # fmt: skip
    capsys.readouterr()
    assert main(["estimate", str(f), "--filter", "ins-wind", "--smooth", "--out", str(tmp_path / "e.h5")]) == 0
    assert "ins-wind-smooth: RMSE vs truth" in capsys.readouterr().out
    assert main(["estimate", str(f), "--filter", "ekf7", "--smooth"]) == 2
    assert "--smooth: smoothing: estimator 'ekf7' cannot be smoothed" in capsys.readouterr().err
    assert main(["compare", str(f), "--filters", "mekf,ekf7", "--smooth", "--json"]) == 0
    io = capsys.readouterr()
    assert '"mekf-smooth"' in io.out and '"ekf7"' in io.out
    assert "--smooth: ekf7 runs unsmoothed" in io.err
    assert main(["bench-data", str(tmp_path), "--filters", "mekf,auto", "--smooth"]) == 0
    out = capsys.readouterr().out
    assert "mekf-smooth" in out and "auto-smooth" in out


# --- the two-filter smoother ---------------------------------------------------------------


def test_reversed_flight() -> None:
    flight = wa.simulate("fixedwing", seed=0, wind=5.0, duration=5.0)
    rev = S.reversed_flight(flight)
    t = flight.imu.t
    np.testing.assert_allclose(rev.imu.t, (t[0] + t[-1]) - t[::-1], rtol=0, atol=1e-12)
    # reversed row j ends at the original t[N-1-j] and spans the original interval after it
    np.testing.assert_array_equal(rev.imu.w_b[1:], -flight.imu.w_b[::-1][:-1])
    np.testing.assert_array_equal(rev.imu.f_b, flight.imu.f_b[::-1])
    np.testing.assert_array_equal(rev.gnss.v_n, -flight.gnss.v_n[::-1])
    np.testing.assert_array_equal(rev.mag.mag_b, flight.mag.mag_b[::-1])
    assert rev.air is None and rev.truth is None
    # a rotation whose rate is exact over every interval: integrated backwards from the final
    # attitude, the reversed gyro retraces it
    tt = np.arange(400) * 0.01
    phi = np.column_stack([np.sin(3 * tt), 0.7 * np.cos(2 * tt), 0.5 * np.sin(tt)])
    q_true = quat_exp(phi)
    w = np.zeros((len(tt), 3))
    w[1:] = quat_log(quat_mul(quat_conj(q_true[:-1]), q_true[1:])) / 0.01
    f = quat_rotate_inv(q_true, np.array([0.0, 0.0, -9.81]))
    rev = S.reversed_flight(wa.Flight(imu=ImuStream(tt, w, f)))
    q = q_true[-1]
    for j in range(1, len(tt)):
        q = quat_mul(q, quat_exp(rev.imu.w_b[j] * 0.01))
        assert np.linalg.norm(quat_log(quat_mul(quat_conj(q_true[-1 - j]), q))) < 1e-9


def test_two_filter_nees_in_band_and_better_than_rts() -> None:
    # ins-wind on GNSS velocity without air data: every aid source reversible
    sc = make_scenario("fixedwing", wind=5.0, duration=60.0)
    est = _matched_ins_wind(sc)
    runs = 6
    nees, fwd_rmse, tf_rmse, rts_rmse = [], [], [], []
    for seed in range(runs):
        flight = simulate(sc, np.random.default_rng(seed)).replace(air=None)
        fwd, tf, rts = est.run(flight), S.smooth(est, flight), S.smooth(est, flight, method="rts")
        assert tf.meta["smoother"] == "two-filter" and rts.meta["smoother"] == "rts"
        nees.append(nees_attitude(tf, flight, with_bias=False))
        fwd_rmse.append(wa.score(fwd, flight).rmse_total_deg)
        tf_rmse.append(wa.score(tf, flight).rmse_total_deg)
        rts_rmse.append(wa.score(rts, flight).rmse_total_deg)
    A = np.array(nees)[:, len(nees[0]) // 2 :]
    lo, hi = chi2_band(3, runs)
    assert lo < A.mean() < hi
    assert np.mean((A.mean(axis=0) > lo) & (A.mean(axis=0) < hi)) > 0.9
    assert all(s < 0.5 * f for s, f in zip(tf_rmse, fwd_rmse, strict=True)), (tf_rmse, fwd_rmse)
    assert np.mean(tf_rmse) < np.mean(rts_rmse), (tf_rmse, rts_rmse)


def test_two_filter_keeps_an_unobserved_heading() -> None:
    flight = wa.simulate("quadrotor", seed=1, wind=0.0, duration=20.0)
    flight = flight.replace(mag=None, gnss=None, air=None)
    est = wa.estimator("mekf")
    fwd, tf = est.run(flight), S.smooth(est, flight)
    assert tf.meta["smoother"] == "two-filter"
    e = quat_mul(tf.q_nb, quat_conj(fwd.q_nb))  # nav-frame difference: tilt only
    ok = np.isfinite(e[:, 0])
    np.testing.assert_allclose(e[ok, 3], 0.0, atol=1e-9)
    assert np.degrees(np.abs(2 * np.arccos(np.clip(np.abs(e[ok, 0]), 0, 1)))).max() > 0.01  # it did smooth


def test_method_choice_and_refusals() -> None:
    flight = wa.simulate("fixedwing", seed=2, wind=5.0, duration=10.0)
    assert S.reversible(make_estimator("mekf"), flight) is None  # mekf leaves the air data alone
    assert "air data" in (S.reversible(make_estimator("ins-wind"), flight) or "")
    assert "drag" in (S.reversible(make_estimator("ins-drag"), flight.replace(air=None)) or "")
    assert S.smooth(make_estimator("ins-wind"), flight).meta["smoother"] == "rts"
    with pytest.raises(ValueError, match="smoothing 'ins-wind' by two filters: the flight's air data"):
        S.smooth(make_estimator("ins-wind"), flight, method="two-filter")
    with pytest.raises(ValueError, match=r"method: expected one of auto, two-filter, rts, found 'fb'"):
        S.smooth(make_estimator("mekf"), flight, method="fb")
    # the method in a spec (the command line's way): smoother= implies smooth=true
    rts = make_estimator("mekf-smooth:smoother=rts").run(flight)
    tf = make_estimator("mekf:smoother=two-filter").run(flight)
    assert rts.meta["smoother"] == "rts" and tf.meta["smoother"] == "two-filter"
    assert rts.filter == "mekf-smooth:smoother=rts" and not np.array_equal(rts.q_nb, tf.q_nb)
    np.testing.assert_array_equal(rts.q_nb, S.smooth(make_estimator("mekf"), flight, method="rts").q_nb)
    with pytest.raises(ValueError, match=r"smoother: expected one of auto, two-filter, rts, found 'fb'"):
        make_estimator("mekf:smoother=fb")
    with pytest.raises(ValueError, match="smoothing 'ins-wind' by two filters"):
        make_estimator("ins-wind:smoother=two-filter").run(flight)


def test_two_filter_on_broad() -> None:
    from windahrs.experiments.benchdata import broad_errors

    flight = wa.read(require_data("broad", "15_undisturbed_fast_translation_A.hdf5"))
    est = make_estimator("mekf")
    fwd, tf = est.run(flight), S.smooth(est, flight)
    f, s = broad_errors(fwd, flight), broad_errors(tf, flight)

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x**2)))

    assert rms(s.inclination) < 0.95 * rms(f.inclination) and rms(s.total) < 0.95 * rms(f.total)
