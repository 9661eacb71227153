"""[ins-wind]'s covariance predicted once per cov_period over the IMU steps in it (PX4 EKF2's
EKF2_PREDICT_US; windahrs.core.predict.defer_cov): the same run at a rate that closes the period
at every sample, reads of the state that do not change the run, and answers close to every
sample's prediction."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import windahrs as wa
from windahrs.filters.base import EVENT_AIR, EVENT_GNSS, EVENT_IMU, EVENT_MAG, merge_events
from windahrs.filters.params import load_params
from windahrs.filters.registry import make_estimator
from windahrs.flight import ImuStream
from windahrs.rotation import quat_conj, quat_log, quat_mul


@pytest.fixture(scope="module")
def fw() -> wa.Flight:
    return wa.simulate("fixedwing", seed=2, wind=8.0, duration=40.0)


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(quat_log(quat_mul(quat_conj(a), b)), axis=1)


def test_the_default_period_is_px4s_and_a_100_hz_imu_is_predicted_at_every_sample(fw: wa.Flight) -> None:
    """10 ms by default; an IMU at 100 Hz closes the period at every sample, so its run is
    every sample's prediction bit for bit (its covariance rows too)."""
    assert make_estimator("ins-wind").params.cov_period == 0.01  # type: ignore[attr-defined]
    imu = fw.imu
    slow = fw.replace(imu=ImuStream(t=imu.t[::2], w_b=imu.w_b[::2], f_b=imu.f_b[::2]))
    a = make_estimator("ins-wind").run(slow, cov_every=1)
    b = make_estimator("ins-wind:cov_period=0").run(slow, cov_every=1)
    np.testing.assert_array_equal(a.q_nb, b.q_nb)
    np.testing.assert_array_equal(a.cov, b.cov)


def test_the_period_moves_the_answers_little(fw: wa.Flight) -> None:
    """At 200 Hz the covariance is predicted over pairs of samples: the attitude moves by far
    less than its own spread, and every recorded covariance (at a pair's second sample, and
    between, with the pending step applied to a copy) stays close to every sample's and
    exactly symmetric."""
    a = make_estimator("ins-wind").run(fw, cov_every=1)
    b = make_estimator("ins-wind:cov_period=0").run(fw, cov_every=1)
    d = _angle(a.q_nb, b.q_nb)
    assert 0 < d.max() < 2e-4, d.max()  # (rad: 4.4e-5 measured; the attitude's own 1 sigma is 2.3e-3 and more)
    assert a.cov is not None and b.cov is not None
    np.testing.assert_array_equal(a.cov, a.cov.transpose(0, 2, 1))
    live = a.init_index if a.init_index is not None else 0
    da = np.diagonal(a.cov[live:], axis1=1, axis2=2)
    db = np.diagonal(b.cov[live:], axis1=1, axis2=2)
    ok = db > 0
    assert np.max(np.abs(da[ok] / db[ok] - 1.0)) < 0.01  # (0.29 % measured)


def test_a_vibrating_accelerometers_noise_is_a_density_at_the_sample_step(fw: wa.Flight) -> None:
    """The accelerometer noise measured on line is a variance per sample, a density at the
    sample step: predicted over a period of two samples, the INS velocity's variance is every
    sample's prediction's (within 0.1 %; at the period's step instead, 1.34 times in the
    median, measured), with a 3 m/s^2 white vibration on the accelerometer."""
    rng = np.random.default_rng(5)
    imu = fw.imu
    vib = fw.replace(imu=ImuStream(t=imu.t, w_b=imu.w_b, f_b=imu.f_b + rng.normal(0.0, 3.0, imu.f_b.shape)))
    a = make_estimator("ins-wind").run(vib, cov_every=1)
    b = make_estimator("ins-wind:cov_period=0").run(vib, cov_every=1)
    assert a.cov is not None and b.cov is not None and a.state_labels[3:6] == ("v_n", "v_e", "v_d")
    live = a.init_index or 0
    ratio = np.diagonal(a.cov, axis1=1, axis2=2)[live:, 3:6] / np.diagonal(b.cov, axis1=1, axis2=2)[live:, 3:6]
    assert np.abs(ratio - 1.0).max() < 1e-3, (ratio.min(), ratio.max())


def test_reading_the_state_between_samples_changes_nothing(fw: wa.Flight) -> None:
    """A streamer's state read halfway through a period (the pending prediction applied to a
    copy) leaves the run as it is: fed the same events, with and without a read after every
    one, it ends in the same state bit for bit, the batch run's last row."""
    short = fw
    t_ev, kinds, vals = merge_events(short, frozenset({"imu", "mag", "gnss", "air"}))
    ends = []
    for read in (False, True):
        s = make_estimator("ins-wind").stream(short.site, has=frozenset({"imu", "mag", "gnss", "air"}))
        for t, k, v in zip(t_ev, kinds, vals, strict=True):
            if k == EVENT_IMU:
                s.imu(t, v[:3], v[3:6])
            elif k == EVENT_MAG:
                s.mag(t, v[:3])
            elif k == EVENT_GNSS:
                s.gnss(t, v[:3], v[3])
            elif k == EVENT_AIR:
                s.air(t, v[0], v[1], v[2])
            if read:
                _ = s.state
        ends.append(s.state)
    assert np.array_equal(ends[0].q_nb, ends[1].q_nb) and np.array_equal(ends[0].cov, ends[1].cov)
    batch = make_estimator("ins-wind").run(short, cov_every=1)
    np.testing.assert_array_equal(ends[0].q_nb, batch.q_nb[-1])
    assert batch.cov is not None
    np.testing.assert_array_equal(ends[0].cov, batch.cov[-1])


def test_cov_period_from_px4_and_where_it_is_refused(tmp_path: Path) -> None:
    """EKF2_PREDICT_US (us) sets it; a period beyond PX4's 20 ms, or one on [ins-drag] (whose
    drag update reads the covariance at every sample), is refused naming the field."""
    f = tmp_path / "p.toml"
    f.write_text("[px4]\nEKF2_PREDICT_US = 5000\n")
    assert load_params(f).cov_period == pytest.approx(0.005)
    with pytest.raises(ValueError, match="cov_period: expected at most 0.02 s"):
        make_estimator("ins-wind:cov_period=0.05")
    with pytest.raises(ValueError, match="'ins-drag' does not use parameter 'cov_period'"):
        make_estimator("ins-drag:cov_period=0.01")
    with pytest.raises(ValueError, match="'mekf' does not use parameter 'cov_period'"):
        make_estimator("mekf:cov_period=0.01")
