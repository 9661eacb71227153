"""The 6-D mode (no magnetometer): rest detection measures the gyro bias, the vertical one
included (windahrs.aid.rest), and gravity updates correct the tilt only
(windahrs.core.kalman._tilt_only), so the heading drifts with the residual bias only."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import windahrs as wa
from conftest import require_data
from windahrs.experiments.benchdata import broad_errors

BIAS = np.radians([0.2, -0.1, 0.3])  # rad/s


def _still_then_turning(rate_z: float = 0.0, seed: int = 0) -> wa.Flight:
    """200 Hz, 20 s still (or turning steadily at rate_z rad/s about the vertical), a gyro
    with BIAS and 0.01 deg/s/sqrt(Hz) noise, an accelerometer with 0.02 m/s^2 noise."""
    rng = np.random.default_rng(seed)
    n, fs = 4000, 200.0
    gyro = BIAS + np.array([0.0, 0.0, rate_z]) + rng.normal(0.0, np.radians(0.01) * np.sqrt(fs), (n, 3))
    accel = np.array([0.0, 0.0, -9.80665]) + rng.normal(0.0, 0.02, (n, 3))
    return wa.Flight.from_arrays(rate=fs, gyro=gyro, accel=accel)


def test_rest_measures_the_vertical_gyro_bias_without_a_magnetometer() -> None:
    flight = _still_then_turning()
    est = wa.estimator("mekf").run(flight)
    rest = est.innovations["rest"]
    assert 15 <= len(rest.t) <= 40 and rest.accepted.all()  # once per 0.5 s after 1.5 s at rest
    assert np.degrees(abs(est.gyro_bias_b[-1, 2] - BIAS[2])) < 0.01
    off = wa.estimator("mekf:rest_detection=off").run(flight)
    assert "rest" not in off.innovations
    assert np.degrees(abs(off.gyro_bias_b[-1, 2] - BIAS[2])) > 0.2  # unobservable without it


def test_a_steady_turn_is_not_rest() -> None:
    est = wa.estimator("mekf").run(_still_then_turning(rate_z=np.radians(10.0)))
    assert "rest" not in est.innovations  # the mean rate is beyond any bias (rest_bias_clip)


def test_rest_is_off_by_default_with_a_magnetometer_and_refused_where_unused() -> None:
    flight = wa.simulate("quadrotor", seed=1, wind=0.0, duration=5.0)
    assert "rest" not in wa.estimator("mekf").run(flight).innovations
    with pytest.raises(ValueError, match="rest_detection"):
        wa.estimator("mekf:rest_detection=maybe")
    with pytest.raises(ValueError, match="usque.*rest_detection|rest_detection.*usque"):
        wa.estimator("usque:rest_detection=on")


def test_six_d_heading_on_a_real_trial_beats_the_gyro_alone() -> None:
    path = require_data("broad", "02_undisturbed_slow_rotation_B.hdf5")
    flight = wa.read(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        six_d = wa.estimator("mekf:mag_mode=off").run(flight)
        old = wa.estimator("mekf:mag_mode=off:rest_detection=off").run(flight)
    def heading_deg(est: wa.Estimate) -> float:  # BROAD's metric, a constant heading offset removed
        e = broad_errors(est, flight, remove_heading=True)
        return float(np.degrees(np.sqrt(np.mean(e.heading**2))))

    new_h, old_h = heading_deg(six_d), heading_deg(old)
    assert new_h < 2.0 and new_h < old_h, (new_h, old_h)


def test_start_mode_stops_at_the_first_motion() -> None:
    rng = np.random.default_rng(3)
    fs, n = 200.0, 5000  # 10 s still, 5 s turning at 20 deg/s about z, 10 s still
    rate = np.zeros((n, 3))
    rate[2000:3000, 2] = np.radians(20.0)
    gyro = BIAS + rate + rng.normal(0.0, np.radians(0.01) * np.sqrt(fs), (n, 3))
    accel = np.array([0.0, 0.0, -9.80665]) + rng.normal(0.0, 0.02, (n, 3))
    flight = wa.Flight.from_arrays(rate=fs, gyro=gyro, accel=accel)
    on = wa.estimator("mekf:rest_detection=on").run(flight).innovations["rest"].t
    start = wa.estimator("mekf:rest_detection=start").run(flight).innovations["rest"].t
    assert on.max() > 15.0 and (on < 10.0).any()  # both rests
    assert start.max() < 10.0 and len(start) == int((on < 10.0).sum())  # the first only
