"""The simulator: one consistent truth behind every sensor, and wind that really moves
the airframe (SPEC 5)."""

from __future__ import annotations

import numpy as np
import pytest

from windahrs.conventions import DEG
from windahrs.flight import Flight
from windahrs.rotation import quat_angle, quat_exp, quat_mul, quat_normalize, quat_rotate_inv
from windahrs.sim.atmosphere import Gust, WindConfig
from windahrs.sim.fixedwing import Airframe, FixedWingScenario, Leg
from windahrs.sim.paper import PaperScenario
from windahrs.sim.quadrotor import QuadrotorScenario
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.sim.sensors import GnssModel, SensorSuite

NOISELESS = SensorSuite().noiseless()


def gravity_angle_deg(f: Flight) -> np.ndarray:
    """Angle between the measured specific force and the gravity ('up') direction."""
    up_b = quat_rotate_inv(f.truth.q_nb, [0.0, 0.0, -1.0])
    fb = f.imu.f_b
    c = np.sum(fb * up_b, axis=1) / np.linalg.norm(fb, axis=1)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


@pytest.fixture(scope="module", params=["fixedwing", "quadrotor", "paper"])
def noiseless_flight(request: pytest.FixtureRequest) -> Flight:
    sc = make_scenario(request.param, wind=8.0, duration=60.0)
    suite = (
        NOISELESS
        if request.param != "quadrotor"
        else SensorSuite(pitot=None, vanes=None).noiseless()
    )
    return simulate(sc, np.random.default_rng(11), sensors=suite)


def test_gyro_integration_reproduces_truth_attitude(noiseless_flight: Flight) -> None:
    f = noiseless_flight
    t, w = f.imu.t, f.imu.w_b
    q = f.truth.q_nb[0].copy()
    err = 0.0
    for k in range(1, len(t)):
        q = quat_normalize(quat_mul(q, quat_exp(w[k] * (t[k] - t[k - 1]))))
        if k % 200 == 0:
            err = max(err, float(quat_angle(q, f.truth.q_nb[k])))
    err = max(err, float(quat_angle(q, f.truth.q_nb[-1])))
    assert f.duration == pytest.approx(60.0)
    assert err < 1e-9


def test_accelerometer_is_specific_force_of_the_truth(noiseless_flight: Flight) -> None:
    f = noiseless_flight
    tr = f.truth
    dt = np.diff(tr.t)[:, None]
    a_n = np.diff(tr.v_n, axis=0) / dt  # acceleration over (t[k-1], t[k]]
    expected = quat_rotate_inv(tr.q_nb[1:], a_n - f.site.gravity_n)
    assert np.abs(f.imu.f_b[1:] - expected).max() < 1e-9


def test_air_data_is_air_relative_velocity_and_gnss_is_velocity(noiseless_flight: Flight) -> None:
    f = noiseless_flight
    tr = f.truth
    if f.air is not None:
        idx = np.searchsorted(tr.t, f.air.t)
        v_air_b = quat_rotate_inv(tr.q_nb[idx], tr.v_n[idx] - tr.wind_n[idx])
        assert np.allclose(f.air.tas, np.linalg.norm(v_air_b, axis=1), atol=1e-12)
        assert f.air.aoa is not None and f.air.sideslip is not None
        rebuilt = f.air.tas[:, None] * np.column_stack(
            [
                np.cos(f.air.aoa) * np.cos(f.air.sideslip),
                np.sin(f.air.sideslip),
                np.sin(f.air.aoa) * np.cos(f.air.sideslip),
            ]
        )
        assert np.allclose(rebuilt, v_air_b, atol=1e-9)
    idx = np.searchsorted(tr.t, f.gnss.t)
    assert np.allclose(f.gnss.v_n, tr.v_n[idx], atol=1e-12)
    idx = np.searchsorted(tr.t, f.mag.t)
    assert np.allclose(f.mag.mag_b, quat_rotate_inv(tr.q_nb[idx], f.site.mag_n), atol=1e-18)


def test_wind_moves_the_fixed_wing_level_at_50_m() -> None:
    """W20 = 8 m/s, level flight at 50 m: the accelerometer is off gravity by about
    2.3 deg on average (SPEC 5.2); mean over 3 seeds of 300 s."""
    sc = FixedWingScenario(duration=300.0, altitude=50.0, wind=WindConfig(w20=8.0), plan="level")
    means = [
        gravity_angle_deg(simulate(sc, np.random.default_rng(s), sensors=NOISELESS)).mean()
        for s in range(3)
    ]
    assert 1.5 < float(np.mean(means)) < 3.5
    calm = FixedWingScenario(duration=30.0, altitude=50.0, wind=WindConfig(w20=0.0), plan="level")
    assert (
        gravity_angle_deg(simulate(calm, np.random.default_rng(0), sensors=NOISELESS)).max() < 1e-6
    )


def test_wind_moves_the_quadrotor_holding_at_20_m() -> None:
    sc = QuadrotorScenario(duration=300.0, altitude=20.0, wind=WindConfig(w20=8.0))
    suite = SensorSuite(pitot=None, vanes=None).noiseless()
    rms = [
        np.sqrt(
            np.mean(gravity_angle_deg(simulate(sc, np.random.default_rng(s), sensors=suite)) ** 2)
        )
        for s in range(3)
    ]
    assert 0.5 < float(np.mean(rms)) < 1.5


def test_coordinated_turn_has_no_lateral_specific_force_in_calm_air() -> None:
    sc = FixedWingScenario(
        duration=20.0, wind=WindConfig(), plan=(Leg(20.0, bank=30 * DEG),), transition=1.0
    )
    f = simulate(sc, np.random.default_rng(0), sensors=NOISELESS)
    steady = f.imu.t > 3.0
    assert np.abs(f.imu.f_b[steady, 1]).max() < 0.05  # m/s^2, alpha-induced residual only
    # the gravity-only model is wrong by about the bank angle in the turn
    assert gravity_angle_deg(f)[steady].mean() == pytest.approx(30.0, abs=1.0)


def test_paper_scenario_matches_spec_airflow() -> None:
    a_t, wind_b = PaperScenario(wind_speed=5.0).airflow()
    assert a_t == pytest.approx(5.98, abs=0.01)
    assert np.linalg.norm(wind_b) == pytest.approx(5.0)
    f = simulate(
        PaperScenario(wind_speed=5.0, turbulence=False), np.random.default_rng(0), sensors=NOISELESS
    )
    assert np.allclose(f.air.aoa, 5 * DEG, atol=1e-6) and np.allclose(
        f.air.sideslip, 10 * DEG, atol=1e-6
    )
    # the paper's q0 = [1,0,0,0] starts about 30 deg off
    assert 20 < np.degrees(quat_angle([1.0, 0, 0, 0], f.truth.q_nb[0])) < 40


def test_gust_and_sensor_options() -> None:
    gust = Gust(t_start=5.0, duration=2.0, amplitude_n=(0.0, 3.0, 0.0))
    sc = FixedWingScenario(duration=12.0, wind=WindConfig(w20=0.0, gusts=(gust,)), plan="level")
    suite = SensorSuite(
        gnss=GnssModel(rate=5.0, noise=0.0, latency=0.2), gyro=NOISELESS.gyro, accel=NOISELESS.accel
    )
    f = simulate(sc, np.random.default_rng(0), sensors=suite)
    k = np.argmin(np.abs(f.truth.t - 6.0))
    assert f.truth.wind_n[k, 1] == pytest.approx(3.0, abs=1e-6)
    assert np.abs(f.imu.f_b[:, 1]).max() > 0.5  # the airframe feels the gust sideways
    assert np.median(np.diff(f.gnss.t)) == pytest.approx(0.2)
    i = np.searchsorted(f.truth.t, f.gnss.t[30])
    j = np.searchsorted(f.truth.t, f.gnss.t[30] - 0.2)
    assert np.allclose(f.gnss.v_n[30], f.truth.v_n[j]) and not np.allclose(
        f.gnss.v_n[30], f.truth.v_n[i]
    )


def test_noise_levels_and_determinism() -> None:
    sc = FixedWingScenario(duration=20.0, wind=WindConfig(w20=5.0))
    a = simulate(sc, np.random.default_rng(5))
    b = simulate(sc, np.random.default_rng(5))
    c = simulate(sc, np.random.default_rng(6))
    assert np.array_equal(a.imu.w_b, b.imu.w_b) and np.array_equal(a.air.tas, b.air.tas)
    assert not np.array_equal(a.imu.w_b, c.imu.w_b)
    clean = simulate(sc, np.random.default_rng(5), sensors=NOISELESS)
    gyro_noise = a.imu.w_b - clean.imu.w_b - a.truth.gyro_bias_b
    assert np.std(gyro_noise) == pytest.approx(0.005 * DEG * np.sqrt(200), rel=0.05)
    accel_noise = a.imu.f_b - clean.imu.f_b - a.truth.accel_bias_b
    assert np.std(accel_noise) == pytest.approx(400e-6 * 9.80665 * np.sqrt(200), rel=0.05)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (
            lambda: make_scenario("rocket"),
            "vehicle: expected one of fixedwing, quadrotor, paper, found 'rocket'",
        ),
        (lambda: make_scenario("fixedwing", duration=-1.0), "duration: expected > 0 s, found -1.0"),
        (lambda: make_scenario("quadrotor", wind=-2.0), "wind: expected W20 >= 0 m/s, found -2.0"),
        (lambda: make_scenario("paper", altitude=1e5), "altitude: expected 2 to 300 m"),
        (lambda: WindConfig(w20=float("nan")), "WindConfig.w20"),
        (lambda: Airframe(mass=0.0), "Airframe.mass"),
        (lambda: Leg(duration=5.0, bank=np.pi / 2), "Leg.bank"),
        (lambda: SensorSuite(imu_rate=0.0), "SensorSuite.imu_rate"),
        (lambda: GnssModel(noise=-0.1), "GnssModel.noise"),
        (lambda: Gust(t_start=0.0, duration=0.0, amplitude_n=(1.0, 0.0, 0.0)), "Gust.duration"),
    ],
)
def test_bad_input(call, message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        call()
