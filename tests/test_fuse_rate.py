"""The low-passed means fused at a rate (accel_fuse_rate, mag_fuse_rate;
windahrs.core.kalman.samples_to_fuse): once the gain is small, one fusion with R / k stands
for the k samples since the last one, so the estimate is the one of fusing every sample, at
a fraction of the updates; at a start (large gains) every sample is fused."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

import windahrs as wa
from windahrs.estimate import Innovations
from windahrs.metrics import attitude_errors


def _runs(flight: wa.Flight, *specs: str) -> list[wa.Estimate]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return [wa.estimator(s).run(flight) for s in specs]


@pytest.fixture(scope="module")
def quad() -> wa.Flight:
    return wa.simulate("quadrotor", wind=8.0, duration=40.0, seed=3)


def test_the_decimated_mean_gives_the_every_sample_estimate(quad: wa.Flight) -> None:
    rate, every = _runs(quad, "mekf:accel_fuse_rate=50:mag_fuse_rate=0", "mekf:accel_fuse_rate=0:mag_fuse_rate=0")
    fs = 1.0 / float(np.median(np.diff(quad.imu.t)))
    n_rate, n_every = len(rate.innovations["accel"].t), len(every.innovations["accel"].t)
    assert n_every > 0.95 * len(quad.imu.t)
    # about 50 fusions per second once the gain is small, every sample before that
    assert 50.0 * 40.0 * 0.9 < n_rate < 0.5 * n_every
    assert fs > 150.0
    diff = np.degrees(np.abs(attitude_errors(rate, quad).tilt - attitude_errors(every, quad).tilt))
    assert diff.max() < 0.05  # measured 0.011 deg
    tilt_rate = np.degrees(np.sqrt(np.mean(attitude_errors(rate, quad).tilt[50:] ** 2)))
    tilt_every = np.degrees(np.sqrt(np.mean(attitude_errors(every, quad).tilt[50:] ** 2)))
    assert abs(tilt_rate - tilt_every) < 0.02 * tilt_every
    # the NIS is logged per sample: its median does not grow with the samples a fusion stands for
    nis_rate = np.nanmedian(rate.innovations["accel"].nis)
    nis_every = np.nanmedian(every.innovations["accel"].nis)
    assert 0.5 < nis_rate / nis_every < 2.0


def test_a_start_fuses_every_sample(quad: wa.Flight) -> None:
    (rate,) = _runs(quad, "mekf:accel_fuse_rate=50")
    t = rate.innovations["accel"].t
    dt = float(np.median(np.diff(quad.imu.t)))
    # just after the start, consecutive samples while the initial attitude's spread (10 deg)
    # is above a tenth of the sample's noise (measured: the first 80 ms, 16 samples fused at
    # 200 Hz bring it there)
    first = t[:12]
    assert np.all(np.diff(first) < 1.5 * dt)
    # ... and later a fusion every 20 ms
    late = np.diff(t[t > t[-1] - 10.0])
    assert np.median(late) == pytest.approx(0.02, abs=0.6 * dt)


def test_the_field_mean_at_its_rate_gives_the_every_sample_estimate(quad: wa.Flight) -> None:
    rate, every = _runs(quad, "mekf:mag_fuse_rate=10", "mekf:mag_fuse_rate=0")
    n_rate, n_every = len(rate.innovations["mag"].t), len(every.innovations["mag"].t)
    assert 10.0 * 40.0 * 0.9 < n_rate < 0.5 * n_every  # the magnetometer at 50 Hz
    tilt = np.degrees(np.abs(attitude_errors(rate, quad).tilt - attitude_errors(every, quad).tilt))
    total = np.degrees(np.abs(attitude_errors(rate, quad).total - attitude_errors(every, quad).total))
    assert tilt.max() < 0.05 and total.max() < 0.1  # measured 0.004 and 0.012 deg
    nis_rate = np.nanmedian(rate.innovations["mag"].nis)
    nis_every = np.nanmedian(every.innovations["mag"].nis)
    assert 0.5 < nis_rate / nis_every < 2.0


def test_only_the_error_state_filters_take_it() -> None:
    with pytest.raises(ValueError, match="accel_fuse_rate"):
        wa.estimator("ekf7:accel_fuse_rate=50")
    with pytest.raises(ValueError, match="mag_fuse_rate"):
        wa.estimator("ekf7:mag_fuse_rate=10")
    with pytest.raises(ValueError, match=r"accel_fuse_rate: expected a finite number >= 0"):
        wa.estimator("mekf:accel_fuse_rate=-1")


def _field_turned(flight: wa.Flight, deg: float, after: float) -> wa.Flight:
    """``flight`` with its magnetometer turned by ``deg`` about body z from ``after`` s on (a
    heading the disturbance checks pass, off the state's: a heading reset after reset_timeout)."""
    mb = flight.mag.mag_b.copy()
    late = flight.mag.t > after
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    mb[late] = np.c_[c * mb[late, 0] - s * mb[late, 1], s * mb[late, 0] + c * mb[late, 1], mb[late, 2]]
    return flight.replace(mag=dataclasses.replace(flight.mag, mag_b=mb))


def test_a_reset_drops_the_samples_not_yet_fused() -> None:
    """A reset reopens the attitude's spread: the samples the means took since their last
    fusion were information that spread discards, so the next fusion (large gain: every
    sample) stands for its own sample only, not for R / k with the k of before the reset.
    Measured before the fix: 4 magnetometer and 2 IMU samples still counted at the reset."""
    from windahrs.core.kernel import _resets
    from windahrs.core.layout import X_NFUSE, X_NMFUSE

    flight = _field_turned(wa.simulate("quadrotor", wind=3.0, duration=40.0, seed=3), 90.0, 20.0)
    st = wa.estimator("mekf").streamer(flight.site, has=frozenset({"imu", "mag"}))
    events = sorted([(t, 0, i) for i, t in enumerate(flight.imu.t)] + [(t, 1, i) for i, t in enumerate(flight.mag.t)])
    seen, counted = 0, []
    for t, kind, i in events:
        if kind == 0:
            st.imu(t, flight.imu.w_b[i], flight.imu.f_b[i])
        else:
            st.mag(t, flight.mag.mag_b[i])
        n = len(_resets(st._st).get("mag", ()))
        if n > seen:  # (the step of the reset: nothing fused after it yet)
            seen = n
            counted.append((st._st.x[X_NFUSE], st._st.x[X_NMFUSE]))
    assert counted == [(0.0, 0.0)]


def test_the_accepted_share_is_of_the_samples_not_of_the_rows() -> None:
    """A field the disturbance checks keep out is logged at every sample, the fused mean once
    per fusion (of up to k samples): the share of accepted rows undercounts the fused
    samples and warned (measured: 36 % of 2110 rows with mag_fuse_rate 10, 55 % of 3000 with
    0). Estimate.warnings and the log report take the share of the logged time."""
    flight = wa.simulate("quadrotor", wind=3.0, duration=60.0, seed=3)
    mb = flight.mag.mag_b.copy()
    mb[(flight.mag.t > 15.0) & (flight.mag.t < 35.0)] *= 1.4  # its norm off by 40 % for 20 s
    flight = flight.replace(mag=dataclasses.replace(flight.mag, mag_b=mb))
    rate, every = _runs(flight, "mekf", "mekf:mag_fuse_rate=0")
    rows_every = float(np.mean(every.innovations["mag"].accepted))
    assert every.innovations["mag"].accepted_share() == pytest.approx(rows_every, abs=0.01)
    assert float(np.mean(rate.innovations["mag"].accepted)) < rows_every - 0.1  # (the rows)
    assert rate.innovations["mag"].accepted_share() == pytest.approx(rows_every, abs=0.03)
    assert not [m for m in rate.warnings() if "accepted" in m]
    assert Innovations(np.empty(0), np.empty((0, 3)), np.empty(0), np.empty(0, bool)).accepted_share() == 1.0
