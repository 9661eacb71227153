"""The INS's accelerometer input noise measured on line (accel_noise_measured,
windahrs.core.predict.track_accel_noise): a vibrating accelerometer's samples are not
trusted at the datasheet's density."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

import windahrs as wa
from windahrs.sim.sensors import AccelModel, SensorSuite


def test_a_vibrating_accelerometer_keeps_the_gnss_innovations_consistent() -> None:
    # 0.3 m/s^2/sqrt(Hz), ANSFL's quadrotor's (4.2 m/s^2 per sample at 200 Hz), 15 times the
    # INS's default density
    suite = dataclasses.replace(SensorSuite(), accel=dataclasses.replace(AccelModel(), noise_density=0.3))
    flight = wa.simulate("quadrotor", seed=0, wind=8.0, duration=60.0, sensors=suite)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        measured = wa.estimator("ins-wind").run(flight)
        datasheet = wa.estimator("ins-wind:accel_noise_measured=false").run(flight)
    nis_m = float(np.mean(measured.innovations["gnss"].nis))
    nis_d = float(np.mean(datasheet.innovations["gnss"].nis))
    assert 1.0 < nis_m < 5.0 < 8.0 < nis_d  # 3 for a consistent filter; measured 1.8 and 16.0
    assert measured.innovations["gnss"].accepted.all()


def test_a_quiet_accelerometer_leaves_the_ins_as_it_was() -> None:
    flight = wa.simulate("fixedwing", seed=1, wind=8.0, duration=20.0)
    a = wa.estimator("ins-wind").run(flight)
    b = wa.estimator("ins-wind:accel_noise_measured=false").run(flight)
    np.testing.assert_array_equal(a.q_nb, b.q_nb)
