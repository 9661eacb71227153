"""Error-state filters [mekf], [mekf-air], [ins-wind] and the additive [ekf7], [ekf10]
(reference implementations): Jacobians, zero-noise exactness, consistency, streaming,
bad input, parameters."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from trajectories import flight_in_place
from windahrs.filters.base import InitialState, MissingSensorError, merge_events
from windahrs.filters.ekf7 import Ekf7, Ekf10
from windahrs.filters.eskf import InsWind, Mekf, MekfAir
from windahrs.filters.params import EskfParams, load_params, matched_to
from windahrs.filters.registry import make_estimator
from windahrs.metrics import chi2_band, nees_attitude
from windahrs.models import observations as obs
from windahrs.models.additive import Xi, vector_obs_jacobian
from windahrs.models.error_state import Layout, NominalState, ProcessNoise, predict
from windahrs.rotation import quat_angle, quat_conj, quat_exp, quat_log, quat_mul
from windahrs.sim.atmosphere import WindConfig
from windahrs.sim.fixedwing import FixedWingScenario
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.sim.sensors import AccelModel, MagModel, SensorSuite

FULL = Layout(("att", "v", "bg", "wind", "ba", "bm"))


def random_state(rng: np.random.Generator) -> NominalState:
    q = quat_exp(rng.normal(size=3))
    return NominalState(
        q_nb=q,
        bg=rng.normal(size=3) * 0.01,
        v_n=rng.normal(size=3) * 10 + [15, 0, 0],
        wind_n=rng.normal(size=3) * 3,
        ba=rng.normal(size=3) * 0.05,
        bm=rng.normal(size=3) * 1e-6,
    )


def boxminus(layout: Layout, a: NominalState, b: NominalState) -> np.ndarray:
    """Error-state difference a - b in the layout's coordinates."""
    dx = np.zeros(layout.dim)
    dx[layout.sl("att")] = quat_log(quat_mul(quat_conj(b.q_nb), a.q_nb))
    for name, attr in (("bg", "bg"), ("v", "v_n"), ("wind", "wind_n"), ("ba", "ba"), ("bm", "bm")):
        if layout.has(name):
            dx[layout.sl(name)] = getattr(a, attr) - getattr(b, attr)
    return dx


def numeric_jacobian(fn, layout: Layout, x: NominalState, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for i in range(layout.dim):
        e = np.zeros(layout.dim)
        e[i] = eps
        cols.append((fn(x.inject(layout, e)) - fn(x.inject(layout, -e))) / (2 * eps))
    return np.column_stack(cols)


def assert_jacobian(H: np.ndarray, H_fd: np.ndarray, value: np.ndarray) -> None:
    """Relative 1e-6, with a floor at the finite differences' rounding level
    (eps * |h| / step) for Jacobians that are exactly zero."""
    scale = np.abs(H_fd).max()
    floor = 1e-8 * float(np.abs(value).max())
    assert np.abs(H - H_fd).max() <= 1e-6 * scale + floor, (np.abs(H - H_fd).max(), scale)


@pytest.mark.parametrize("layout", [FULL, Layout(("att", "bg")), Layout(("att", "bg", "wind"))])
def test_measurement_jacobians_match_finite_differences(layout: Layout) -> None:
    rng = np.random.default_rng(1)
    g = np.array([0.0, 0.0, 9.80665])
    m = np.array([20e-6, -3e-6, 45e-6])
    for _ in range(10):
        x = random_state(rng)
        v_in = rng.normal(size=3) * 5 + [15, 0, 0]
        models = {
            "gravity": lambda s: obs.specific_force(layout, s, g, rng_a),
            "mag": lambda s: obs.magnetometer(layout, s, m),
            "vector": lambda s: obs.vector_body(layout, s, m),
            "air": lambda s: obs.air_velocity(layout, s, v_in),
            "tas": lambda s: obs.airspeed(layout, s, v_in),
            "sideslip": lambda s: obs.sideslip(layout, s, v_in),
            "heading": lambda s: obs.heading(layout, s),
        }
        rng_a = rng.normal(size=3)
        if layout.has("v"):
            models["gnss"] = lambda s: obs.gnss_velocity(layout, s)
        if not layout.has("wind") and not layout.has("v"):
            x = NominalState(q_nb=x.q_nb, bg=x.bg)
        if not layout.has("ba"):
            x = NominalState(q_nb=x.q_nb, bg=x.bg, v_n=x.v_n if layout.has("v") else None, wind_n=x.wind_n)
        for name, fn in models.items():
            value, H = fn(x)
            H_fd = numeric_jacobian(lambda s, fn=fn: fn(s)[0], layout, x)
            if name == "heading":  # wrap-safe: the yaw difference is small here
                H_fd = (H_fd + np.pi / 1e-6) % (2 * np.pi / 1e-6) - np.pi / 1e-6
            assert_jacobian(H, H_fd, value)


def test_airspeed_carries_no_attitude_information() -> None:
    x = random_state(np.random.default_rng(2))
    _, H = obs.airspeed(FULL, x)
    assert np.all(H[:, FULL.sl("att")] == 0)


def test_process_transition_matches_finite_differences() -> None:
    rng = np.random.default_rng(3)
    noise = ProcessNoise(
        gyro=1e-4, gyro_bias=1e-5, accel=1e-3, wind_h=0.1, wind_v=0.1, accel_bias=1e-4, mag_bias=1e-8
    )
    g = np.array([0.0, 0.0, 9.80665])
    for dt, w_scale in ((0.005, 1.0), (0.05, 3.0), (0.005, 1e-9)):
        x = random_state(rng)
        w, f = rng.normal(size=3) * w_scale, rng.normal(size=3) * 3 + [0, 0, -9.8]
        P = np.eye(FULL.dim)
        _, P1 = predict(FULL, x, np.zeros_like(P), w, f, dt, noise, g)
        Q = P1  # with P = 0 the prediction is Q alone
        _, P2 = predict(FULL, x, P, w, f, dt, noise, g)
        Phi_PPhiT = P2 - Q
        x1, _ = predict(FULL, x, P, w, f, dt, noise, g)

        def step(s: NominalState) -> np.ndarray:
            return boxminus(FULL, predict(FULL, s, P, w, f, dt, noise, g)[0], x1)

        Phi_fd = numeric_jacobian(step, FULL, x)
        assert np.allclose(Phi_fd @ Phi_fd.T, Phi_PPhiT, atol=1e-6 * np.abs(Phi_PPhiT).max())


def test_additive_jacobian_equals_tangent_form() -> None:
    rng = np.random.default_rng(4)
    for _ in range(10):
        q = quat_exp(rng.normal(size=3))
        r = rng.normal(size=3)
        x = NominalState(q_nb=q, bg=np.zeros(3))
        _, H = obs.vector_body(Layout(("att", "bg")), x, r)
        proj = np.eye(4) - np.outer(q, q)
        assert np.allclose(vector_obs_jacobian(q, r) @ proj, 2 * H[:, :3] @ Xi(q).T, atol=1e-12)


# --- zero noise -----------------------------------------------------------------------

NOISELESS = SensorSuite().noiseless()


@pytest.mark.parametrize("estimator", [Mekf(), Ekf7()], ids=["mekf", "ekf7"])
def test_zero_noise_from_truth_stays_exact_gravity_filters(estimator) -> None:
    fl = flight_in_place(NOISELESS, seed=0, duration=60.0)
    est = estimator.run(fl, initial=InitialState.from_truth(fl))
    err = quat_angle(est.q_nb, fl.truth.q_nb)
    assert fl.duration == pytest.approx(60.0)
    assert err.max() < 1e-6


def test_zero_noise_ins_is_exact_in_gusts_and_with_air_data() -> None:
    """The INS takes the accelerometer as input: exact for any motion, gusts included.
    With air data the wind must be constant for the data to be noise-free (turbulence is
    process noise of the wind states)."""
    gusty = simulate(
        make_scenario("fixedwing", wind=8.0, duration=60.0), np.random.default_rng(5), sensors=NOISELESS
    )
    gusty = gusty.replace(air=None)
    calm = FixedWingScenario(duration=60.0, wind=WindConfig(w20=8.0, turbulence=False, shear=False))
    steady = simulate(calm, np.random.default_rng(5), sensors=NOISELESS)
    for fl in (gusty, steady):
        est = InsWind().run(fl, initial=InitialState.from_truth(fl))
        assert quat_angle(est.q_nb, fl.truth.q_nb).max() < 1e-6
    assert np.abs(est.wind_n - steady.truth.wind_n).max() < 1e-6


@pytest.mark.parametrize("estimator", [MekfAir(), Ekf10()], ids=["mekf-air", "ekf10"])
def test_zero_noise_air_data_filters_stay_close(estimator) -> None:
    """w x V_air compensation is exact in continuous time only (the discrete truth differs
    by O(dt)), so these filters stay close rather than exact."""
    calm = FixedWingScenario(duration=60.0, wind=WindConfig(w20=8.0, turbulence=False, shear=False))
    fl = simulate(calm, np.random.default_rng(5), sensors=NOISELESS)
    est = estimator.run(fl, initial=InitialState.from_truth(fl))
    assert np.degrees(quat_angle(est.q_nb, fl.truth.q_nb).max()) < 0.1


# --- consistency --------------------------------------------------------------------

RUNS = 50


def mc_suite(gnss: bool) -> SensorSuite:
    return SensorSuite(
        imu_rate=100.0,
        accel=AccelModel(bias_init_sigma=0.0),
        mag=MagModel(rate=20.0, hard_iron=0.0),
        gnss=SensorSuite().gnss if gnss else None,
        pitot=None,
        vanes=None,
    )


def consistency(est_cls, suite: SensorSuite, dim: int) -> dict[str, float]:
    params = matched_to(suite, est_cls.default_params)
    nees, nis = [], {}
    for seed in range(RUNS):
        fl = flight_in_place(suite, seed=seed, duration=20.0, phase=0.1 * seed)
        rng = np.random.default_rng(1000 + seed)
        sig = np.radians(2.0)
        truth0 = InitialState.from_truth(fl)
        q0 = quat_mul(truth0.q_nb, quat_exp(rng.normal(size=3) * sig))
        init = InitialState(q_nb=q0, v_n=truth0.v_n, sigma_att=sig)
        est = est_cls(params).run(fl, initial=init)
        nees.append(nees_attitude(est, fl))
        for k, inn in est.innovations.items():
            nis.setdefault(k, []).append(inn.nis[: len(inn.nis) // 10 * 10])
    avg = np.mean(nees, axis=0)
    lo, hi = chi2_band(dim, RUNS)
    out = {
        "nees": float(avg.mean()),
        "in_band": float(np.mean((avg >= lo) & (avg <= hi))),
        "lo": lo,
        "hi": hi,
    }
    for k, rows in nis.items():
        n = min(len(r) for r in rows)
        out[f"nis_{k}"] = float(np.mean([r[:n] for r in rows], axis=0).mean())
    return out


@pytest.mark.parametrize(
    ("est_cls", "gnss"), [(Mekf, False), (Ekf7, False), (InsWind, True)], ids=["mekf", "ekf7", "ins-wind"]
)
def test_nees_and_nis_inside_chi2_bands(est_cls, gnss: bool) -> None:
    res = consistency(est_cls, mc_suite(gnss), 6)
    print(est_cls.name, res)
    assert res["lo"] <= res["nees"] <= res["hi"]
    assert res["in_band"] >= 0.90
    lo3, hi3 = chi2_band(3, RUNS)
    for k, v in res.items():
        if k.startswith("nis_"):
            assert lo3 <= v <= hi3, (k, v)


# --- streaming, bad input, params ---------------------------------------------------------


@pytest.mark.parametrize("name", ["mekf", "mekf-air", "ins-wind", "ekf7", "ekf10"])
def test_streaming_equals_batch(name: str) -> None:
    fl = simulate(make_scenario("fixedwing", wind=5.0, duration=5.0), np.random.default_rng(7))
    est = make_estimator(name)
    batch = est.run(fl)
    has = frozenset(s for s in ("imu", "mag", "gnss", "air") if getattr(fl, s) is not None)
    s = est.streamer(fl.site, has=has)
    t, kinds, vals = merge_events(fl, has & est.uses)
    for i in range(len(t)):
        s.push(int(kinds[i]), float(t[i]), vals[i])
    st = s.state
    assert np.array_equal(st.q_nb, batch.q_nb[-1])
    assert np.array_equal(st.cov, batch.cov[-1])


def test_missing_sensor_errors_name_filter_and_sensor() -> None:
    fl = simulate(make_scenario("quadrotor", wind=0.0, duration=2.0), np.random.default_rng(0))
    with pytest.raises(MissingSensorError, match=r"'mekf-air' needs air data \('air'\)"):
        MekfAir().run(fl)
    with pytest.raises(MissingSensorError, match=r"'ins-wind' needs GNSS velocity \('gnss'\)"):
        InsWind().run(fl.replace(gnss=None))
    with pytest.raises(ValueError, match="unknown 'nope'; known filters: .*ins-wind"):
        make_estimator("nope")


def test_nan_samples_are_skipped_counted_and_never_reach_the_state() -> None:
    fl = simulate(make_scenario("fixedwing", wind=5.0, duration=5.0), np.random.default_rng(8))
    w = fl.imu.w_b.copy()
    w[100:103] = np.nan
    m = fl.mag.mag_b.copy()
    m[10] = np.nan
    v = fl.gnss.v_n.copy()
    v[5] = np.nan
    tas = fl.air.tas.copy()
    tas[7] = np.nan
    bad = fl.replace(
        imu=type(fl.imu)(t=fl.imu.t, w_b=w, f_b=fl.imu.f_b),
        mag=type(fl.mag)(t=fl.mag.t, mag_b=m),
        gnss=type(fl.gnss)(t=fl.gnss.t, v_n=v),
        air=type(fl.air)(t=fl.air.t, tas=tas, aoa=fl.air.aoa, sideslip=fl.air.sideslip),
    )
    for est in (Mekf(), InsWind(), MekfAir(), Ekf7()):
        out = est.run(bad)
        assert np.isfinite(out.q_nb).all() and np.isfinite(out.cov).all()
        assert out.skipped["imu"] == 3 and out.skipped["mag"] == 1
        if est.name in ("ins-wind", "mekf-air"):
            assert out.skipped["gnss"] == 1 and out.skipped["air"] == 1


def test_params_from_toml_with_px4_and_ardupilot_names(tmp_path: Path) -> None:
    f = tmp_path / "p.toml"
    f.write_text(
        '[windahrs]\nmag_mode = "heading"\n[px4]\nEKF2_GYR_NOISE = 0.015\nEKF2_BETA_NOISE = 0.2\n'
        "[ardupilot]\nEK3_EAS_M_NSE = 1.4\nEK3_EAS_I_GATE = 400\n"
    )
    p = load_params(f)
    assert p.mag_mode == "heading" and p.sideslip_sigma == 0.2 and p.tas_sigma == 1.4 and p.gate_air == 4.0
    assert p.gyro_noise == pytest.approx(0.0015)
    f.write_text("[windahrs]\ngyro_nois = 1.0\n")
    with pytest.raises(ValueError, match="unknown parameter 'gyro_nois'"):
        load_params(f)
    f.write_text('[windahrs]\nmag_mode = "sideways"\n')
    with pytest.raises(
        ValueError, match=r"mag_mode: expected one of \('3d', 'heading', 'off'\), found 'sideways'"
    ):
        load_params(f)
    f.write_text("[px4]\nEKF2_FOO = 1\n")
    with pytest.raises(ValueError, match="'EKF2_FOO' has no windahrs equivalent"):
        load_params(f)
    f.write_text("[windahrs\n")
    with pytest.raises(ValueError, match="not valid TOML"):
        load_params(f)
    with pytest.raises(ValueError, match="gyro_noise: expected > 0"):
        EskfParams(gyro_noise=0.0)


def test_heading_only_magnetometer_mode_runs_and_converges() -> None:
    fl = simulate(make_scenario("fixedwing", wind=0.0, duration=30.0), np.random.default_rng(9))
    est = Mekf(EskfParams(mag_mode="heading")).run(fl)
    err = quat_angle(est.q_nb, fl.truth.q_nb)
    assert np.degrees(np.sqrt(np.mean(err[len(err) // 2 :] ** 2))) < 3.0
