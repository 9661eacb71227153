"""The estimators' protections against sensor faults (issue 13): the IMU screen
(windahrs.core.imu_screen), the start without a late magnetometer, a GNSS outage that is not
a rejection, the per-sample flags (windahrs.flags) and the covariance kept within its budget."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import windahrs as wa
from windahrs.core.layout import COV_BUDGET, COV_RECORD_HZ, cov_stride
from windahrs.estimate import Estimate, load_estimate, save_estimate
from windahrs.flags import FLAGS, flag_names, flag_spans, stream_flags
from windahrs.flight import Flight, ImuStream
from windahrs.metrics import attitude_errors, nees_attitude
from windahrs.repair import GYRO_RANGE
from windahrs.rotation import quat_conj, quat_mul
from windahrs.sim import faults as F


def _quiet_run(spec: str, flight: Flight, cov_every: int | None = None, **kw: object) -> Estimate:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = wa.estimator(spec, **kw)  # type: ignore[arg-type]
        return est.run(flight) if cov_every is None else est.run(flight, cov_every=cov_every)  # type: ignore[call-arg]


def _with_imu(flight: Flight, w: np.ndarray, f: np.ndarray) -> Flight:
    """The flight with other IMU samples (past the constructor's unit check, as a glitched
    log the edge has not repaired would be)."""
    imu = object.__new__(ImuStream)
    for k, v in (("t", flight.imu.t), ("w_b", w), ("f_b", f)):
        object.__setattr__(imu, k, v)
    out = object.__new__(Flight)
    out.__dict__.update(flight.__dict__)
    object.__setattr__(out, "imu", imu)
    return out


def _total_deg(est: Estimate, flight: Flight) -> float:
    return wa.score(est, flight).rmse_total_deg


@pytest.fixture(scope="module")
def fixedwing() -> Flight:
    return wa.simulate("fixedwing", seed=3, wind=8.0, duration=30.0)


def _bit(name: str) -> np.uint32:
    return np.uint32(1 << FLAGS[name][0])


@pytest.mark.parametrize("size", [3.0, 20.0, 40.0])
@pytest.mark.parametrize("spec", ["ins-wind", "mekf"])
def test_a_single_gyro_spike_is_held_and_costs_nothing(fixedwing: Flight, spec: str, size: float) -> None:
    k = int(np.searchsorted(fixedwing.imu.t, 15.0))
    w = fixedwing.imu.w_b.copy()
    w[k, 1] += size
    faulty = _with_imu(fixedwing, w, fixedwing.imu.f_b)
    clean, est = _quiet_run(spec, fixedwing), _quiet_run(spec, faulty)
    assert abs(_total_deg(est, faulty) / _total_deg(clean, fixedwing) - 1.0) < 0.05  # (issue 13: 10 %)
    held = est.alerts["imu"]
    assert held.shape == (1, 4) and held[0, 0] == fixedwing.imu.t[k]
    assert held[0, 3] == (1 if size > GYRO_RANGE else 2)  # beyond the range, or a spike
    assert est.flags is not None and est.flags[k] & _bit("imu_held")
    assert any("IMU samples not propagated" in line for line in est.warnings())
    if size >= 20 and spec == "ins-wind":  # without the screen the same spike turns the attitude
        raw = _quiet_run(spec, faulty, imu_spike_gate=0.0, gyro_range=1e9)
        assert _total_deg(raw, faulty) > 1.2 * _total_deg(clean, fixedwing)


def test_an_accelerometer_spike_is_held(fixedwing: Flight) -> None:
    k = int(np.searchsorted(fixedwing.imu.t, 15.0))
    f = fixedwing.imu.f_b.copy()
    f[k, 2] += 100.0
    est = _quiet_run("ins-wind", _with_imu(fixedwing, fixedwing.imu.w_b, f))
    held = est.alerts["imu"]
    assert len(held) == 1 and held[0, 2] == pytest.approx(100.0, rel=0.05) and held[0, 3] == 2


def test_a_step_of_the_motion_is_propagated_one_sample_late_not_lost(fixedwing: Flight) -> None:
    """A true step in the angular rate is confirmed by the next sample: the held sample's
    rotation is caught up, so the attitude ends where the unscreened filter's does."""
    t = fixedwing.imu.t
    w = fixedwing.imu.w_b.copy()
    on = (t >= 15.0) & (t < 15.5)
    w[on, 2] += 2.0  # a 2 rad/s step held for 0.5 s (not in the truth: an offset both runs see)
    flight = _with_imu(fixedwing, w, fixedwing.imu.f_b)
    screened, raw = _quiet_run("mekf", flight), _quiet_run("mekf", flight, imu_spike_gate=0.0)
    held = screened.alerts["imu"]
    assert set(held[:, 3]) == {3.0} and len(held) == 2  # the step in and the step out, both motion
    k = int(np.searchsorted(t, 15.6))
    dq = quat_mul(quat_conj(raw.q_nb[k]), screened.q_nb[k])
    assert np.degrees(2 * np.arccos(min(1.0, abs(dq[0])))) < 0.3  # measured 0.18 (dropped: 2 rad/s x 5 ms = 0.57 deg)


def test_a_vibration_setting_in_is_integrated_not_ratcheted(fixedwing: Flight) -> None:
    """Vibration at 2/5 of the IMU rate (the fault matrix's 80 Hz at 200 Hz): each sample
    is far from both neighbours while they are close to each other, the pattern of a lone
    spike, until the gate has opened. Dropping those samples turned the attitude by one
    sample's rotation per cycle, 1.1 deg in the first 50 ms (seed 3 of the matrix); held
    samples in a row are motion, caught up, so the vibration integrates to (nearly) nothing."""
    t = fixedwing.imu.t
    on = (t >= 15.0) & (t < 16.0)
    phase = np.array([0.3, 2.1, 4.4])
    w = fixedwing.imu.w_b.copy()
    w[on] += 0.5 * np.sin(2 * np.pi * 80.0 * t[on, None] + phase)
    f = fixedwing.imu.f_b.copy()
    f[on] += 3 * 9.80665 * np.sin(2 * np.pi * 80.0 * t[on, None] + phase[::-1])
    flight = _with_imu(fixedwing, w, f)
    screened, raw = _quiet_run("mekf", flight), _quiet_run("mekf", flight, imu_spike_gate=0.0)
    assert len(screened.alerts["imu"]) > 5  # the screen did act
    k = int(np.searchsorted(t, 15.1))
    dq = quat_mul(quat_conj(raw.q_nb[k]), screened.q_nb[k])
    assert np.degrees(2 * np.arccos(min(1.0, abs(dq[0])))) < 0.2


def test_late_magnetometer_start_without_it_then_turn_to_it() -> None:
    flight = wa.simulate("quadrotor", seed=4, wind=5.0, duration=25.0, faults=[F.MagAbsent(start=0.0, duration=10.0)])
    assert flight.mag is not None and flight.mag.t[0] >= 10.0
    est = _quiet_run("mekf", flight, cov_every=1)  # (every sample's covariance: read row by row below)
    assert est.cov is not None
    k_init = est.first_initialised
    assert est.init_index == k_init
    assert est.t[k_init] - est.t[0] == pytest.approx(1.0, abs=0.02)  # core.kernel.MAG_WAIT
    # the waiting second has the state it would start from: finite, flagged not_initialised,
    # level within the specific force's tilt, and the covariance the filter starts with
    assert np.isfinite(est.cov).all() and np.isfinite(est.q_nb).all()
    assert est.flags is not None
    assert all(est.flags[:k_init] & _bit("not_initialised")) and not any(est.flags[k_init:] & _bit("not_initialised"))
    tilt = attitude_errors(est, flight).tilt[:k_init]
    assert np.degrees(tilt).max() < 5.0
    # ... with the heading unknown (heading 0 stands for it): pi^2/3 about the vertical
    att = est.att_cov()
    assert att is not None
    top = np.linalg.eigvalsh(att)[:, -1]
    np.testing.assert_allclose(top[:k_init], np.pi**2 / 3.0, rtol=1e-9)
    assert top[k_init] < 0.1
    (row,) = est.resets["mag"]
    assert row[0] == flight.mag.t[0] and np.isnan(row[2])
    assert any("mag taken for the heading (absent at the start" in line for line in est.warnings())
    assert est.flags is not None
    assert all(est.flags[est.t < 9.0] & _bit("mag_absent"))
    assert not any(est.flags[est.t > 10.5] & _bit("mag_absent"))
    # once turned to the field, as good as a run that had it from the start
    clean = _quiet_run("mekf", wa.simulate("quadrotor", seed=4, wind=5.0, duration=25.0))
    err, err0 = attitude_errors(est, flight), attitude_errors(clean, flight)
    late = est.t[err.index] > 15.0
    assert np.degrees(np.abs(err.total[late] - err0.total[late])).max() < 1.5  # measured 1.03 at 15 s


def test_a_late_magnetometer_restarts_the_wind_fitted_through_the_heading_it_corrects() -> None:
    # mekf-air on the fixed wing without a field for 30 s: its heading, from the air data
    # through the wind it fitted with it, is 33 deg off. Turning the heading to the first field
    # sample alone left that wind, whose air-data innovations turned it straight back (still
    # 31 deg off 2 s later); with the wind restarted from the next air sample it holds.
    # (the fault matrix's flight: the trajectory depends on the duration)
    flight = wa.simulate("fixedwing", seed=1, wind=8.0, duration=90.0, faults=[F.MagAbsent(start=0.0, duration=30.0)])
    est = _quiet_run("mekf-air", flight)
    err = attitude_errors(est, flight)
    t = est.t[err.index]
    assert np.degrees(np.abs(err.euler[(t > 29.0) & (t < 29.9), 2])).min() > 10.0  # (the case is still there)
    assert np.degrees(np.abs(err.euler[(t > 31.0) & (t < 45.0), 2])).max() < 3.0


def test_a_gnss_outage_is_absence_not_rejection(fixedwing: Flight) -> None:
    faulty = F.inject(fixedwing, [F.GnssOutage(start=10.0, duration=12.0)], seed=0)
    est = _quiet_run("ins-wind", faulty)
    assert "gnss" not in est.resets  # the first sample after it is fused, not a reset
    assert "tilt" not in est.alerts  # a turn through the outage is not a lost tilt
    assert est.flags is not None
    mid = (est.t > 11.0) & (est.t < 21.5)
    assert all(est.flags[mid] & _bit("gnss_absent")) and all(est.flags[mid] & _bit("fallback"))
    assert not any(est.flags[est.t > 23.0] & _bit("gnss_absent"))
    assert wa.score(est, faulty).rmse_tilt_deg < 1.0


def test_a_clean_flight_raises_no_fault_flags(fixedwing: Flight) -> None:
    est = _quiet_run("ins-wind", fixedwing)
    assert est.flags is not None
    names = {s.flag for s in flag_spans(est.t, est.flags)}
    assert names <= {"not_initialised", "accel_rejected", "air_rejected", "gnss_rejected", "mag_rejected"}


@pytest.mark.parametrize(
    ("fault", "flag"),
    [
        (F.ImuStuck(start=10.0, duration=1.0), "imu_stuck"),
        (F.MagMagnet(start=10.0, duration=2.0), "mag_disturbed"),
        (F.PitotBlockage(start=10.0, duration=2.0), "air_stuck"),
        (F.VaneFailure(start=10.0, duration=2.0), "air_stuck"),
        (F.ImuDropout(start=10.0, duration=1.0), "imu_absent"),
        (F.ImuJitter(start=10.0, duration=2.0), "imu_jitter"),
    ],
)
def test_each_fault_raises_its_flag_within_a_second(fixedwing: Flight, fault: F.Fault, flag: str) -> None:
    faulty = F.inject(fixedwing, [fault], seed=1)
    est = _quiet_run("ins-wind", faulty)
    assert est.flags is not None
    on = est.t[(est.flags & _bit(flag)) != 0]
    assert len(on) and 9.97 <= on[0] <= 11.0 and on[-1] <= fault.span[1] + 1.0


def test_a_clipped_axis_is_flagged(fixedwing: Flight) -> None:
    t, f = fixedwing.imu.t, fixedwing.imu.f_b.copy()
    on = (t >= 10.0) & (t < 10.5)
    f[on, 0] = 3.0 * 9.80665  # an axis held at a 3 g full scale
    est = _quiet_run("mekf", _with_imu(fixedwing, fixedwing.imu.w_b, f))
    assert est.flags is not None
    assert np.array_equal((est.flags & _bit("imu_clipped")) != 0, on)


def test_an_axis_clipped_on_both_sides_is_flagged(fixedwing: Flight) -> None:
    """Vibration through a 250 deg/s range: the axis alternates between +range and -range,
    so no two consecutive values are equal, only their magnitudes."""
    t, w = fixedwing.imu.t, fixedwing.imu.w_b.copy()
    on = (t >= 10.0) & (t < 10.1)
    w[on, 0] = np.radians(250.0) * np.where(np.arange(on.sum()) % 2 == 0, 1.0, -1.0)
    on_flags = stream_flags(_with_imu(fixedwing, w, fixedwing.imu.f_b))["imu_clipped"][1]
    assert np.array_equal(on_flags, on)


def test_an_axis_held_at_a_small_value_is_flagged(fixedwing: Flight) -> None:
    """A range set below the motion (or a stuck axis): one gyro axis holds one value for
    0.5 s while the others move; 0.2 s (flags.STUCK_S) later it is flagged."""
    t, w = fixedwing.imu.t, fixedwing.imu.w_b.copy()
    on = (t >= 10.0) & (t < 10.5)
    w[on, 2] = 0.05
    est = _quiet_run("mekf", _with_imu(fixedwing, w, fixedwing.imu.f_b))
    assert est.flags is not None
    hit = est.t[(est.flags & _bit("imu_clipped")) != 0]
    assert len(hit) and hit[0] >= 9.99 and hit[-1] < 10.5 and not any(est.flags[t > 10.6] & _bit("imu_clipped"))


def test_a_gnss_velocity_jump_is_flagged_even_by_a_filter_without_gnss(fixedwing: Flight) -> None:
    """mekf fuses no GNSS velocity; the jump is still flagged at its two steps, from the
    IMU's acceleration in mekf's attitude (drift.gnss_jump), and not on the clean flight."""
    faulty = F.inject(fixedwing, [F.GnssJump(start=10.0, duration=5.0)], seed=0)
    for spec in ("mekf", "ins-wind"):
        clean, est = _quiet_run(spec, fixedwing), _quiet_run(spec, faulty)
        assert clean.flags is not None and est.flags is not None
        assert not any(clean.flags & _bit("gnss_jump"))
        hit = est.t[(est.flags & _bit("gnss_jump")) != 0]
        assert len(hit) == 2 and abs(hit[0] - 10.0) < 0.11 and abs(hit[1] - 15.0) < 0.11, hit


def test_flag_names_and_spans() -> None:
    t = np.arange(10) * 0.1
    flags = np.zeros(10, dtype=np.uint32)
    flags[2:5] |= _bit("reset")
    flags[4] |= _bit("imu_held")
    assert flag_names(flags[4]) == ["imu_held", "reset"]
    spans = flag_spans(t, flags)
    assert [(s.flag, s.t0, s.t1) for s in spans] == [("reset", 0.2, pytest.approx(0.4)), ("imu_held", 0.4, 0.4)]


def test_the_covariance_is_kept_at_20_hz_within_its_budget(fixedwing: Flight, tmp_path: object) -> None:
    n, d = len(fixedwing.imu.t), 18
    assert cov_stride(n, d) == 1 and cov_stride(10 * COV_BUDGET, 4) == 160
    # by default at COV_RECORD_HZ (20 Hz): every 10th of 200 Hz, every one of a 10 Hz stream
    assert COV_RECORD_HZ == 20.0
    assert cov_stride(n, d, rate_hz=200.0) == 10 and cov_stride(n, d, rate_hz=10.0) == 1
    assert cov_stride(n, d, rate_hz=39.9) == 1 and cov_stride(10 * COV_BUDGET, 4, rate_hz=200.0) == 160
    assert cov_stride(n, d, 3, rate_hz=200.0) == 3  # (asked for: as asked)
    # "budget": every sample's within the budget, else the finest stride within it that the
    # default's divides (auto's runs, thinned to the default afterwards)
    assert cov_stride(n, d, "budget", rate_hz=200.0) == 1
    long = 3 * COV_BUDGET // (d * d)  # (3 x the budget's samples: every 3rd within it; default 10)
    assert cov_stride(long, d, rate_hz=200.0) == 10 and cov_stride(long, d, "budget", rate_hz=200.0) == 5
    with pytest.raises(ValueError, match="cov_every"):
        cov_stride(n, d, "every")
    with pytest.raises(ValueError, match="cov_every"):
        cov_stride(n, d, 0)
    full = _quiet_run("ins-wind", fixedwing, cov_every=1)
    default = _quiet_run("ins-wind", fixedwing)
    rate = (n - 1) / (fixedwing.imu.t[-1] - fixedwing.imu.t[0])
    every = int(rate // COV_RECORD_HZ)
    assert every > 1 and default.cov is not None and full.cov is not None
    assert np.array_equal(default.cov, full.cov[::every]) and np.array_equal(default.q_nb, full.q_nb)
    thin = wa.estimator("ins-wind").run(fixedwing, cov_every=7)
    assert full.cov is not None and thin.cov is not None and thin.cov_index is not None
    assert np.array_equal(thin.q_nb, full.q_nb)
    assert np.array_equal(thin.cov, full.cov[::7]) and np.array_equal(thin.cov_t, full.t[::7])
    np.testing.assert_array_equal(nees_attitude(thin, fixedwing), nees_attitude(full, fixedwing)[::7])
    path = save_estimate(thin, f"{tmp_path}/e.h5")
    back = load_estimate(path)
    assert back.cov_index is not None and np.array_equal(back.cov_index, thin.cov_index)
    assert back.flags is not None and thin.flags is not None and np.array_equal(back.flags, thin.flags)
    assert back.init_index == thin.init_index == thin.first_initialised
    with pytest.raises(ValueError, match="estimate.cov"):
        Estimate(filter="x", t=full.t, q_nb=full.q_nb, cov=full.cov, state_labels=full.state_labels,
                 cov_index=np.arange(0, n, 7))


def test_flags_are_built_when_first_read_and_equal_the_eager_ones(fixedwing: Flight, monkeypatch) -> None:
    import pickle

    import windahrs.filters.checks as checks
    from windahrs.flags import estimate_flags

    calls = []

    def counted(est: Estimate, flight: Flight) -> np.ndarray:
        calls.append(1)
        return estimate_flags(est, flight)

    monkeypatch.setattr(checks, "estimate_flags", counted)
    est = wa.estimator("ins-wind").run(fixedwing)
    assert calls == []  # a run that never reads them does not build them
    first = est.flags
    assert first is not None and first.dtype == np.uint32 and len(calls) == 1
    assert est.flags is first and len(calls) == 1  # built once
    np.testing.assert_array_equal(first, estimate_flags(est, fixedwing))
    again = pickle.loads(pickle.dumps(wa.estimator("ins-wind").run(fixedwing)))  # (Dask pickles Estimates)
    np.testing.assert_array_equal(again.flags, first)


def test_repaired_stamps_and_values_are_flagged_where_they_were(fixedwing: Flight, tmp_path: object) -> None:
    from windahrs.io import read_flight

    faults = [F.DuplicateStamps(start=10.0, duration=5.0, count=3), F.OutOfOrder(start=18.0, duration=5.0, count=2),
              F.DuplicateStamps(start=12.0, duration=5.0, count=2, stream="mag")]
    raw = F.inject_raw(fixedwing, faults, seed=2)
    k = int(np.searchsorted(raw.imu["t"], 25.0))
    raw.imu["w_b"][k, 0] = np.inf  # one value the edge sets to NaN
    repaired = read_flight(raw.write_csv_dir(f"{tmp_path}/rec"))
    where = repaired.repair_times
    assert len(where["imu"]["duplicates"]) == 3 and len(where["imu"]["reordered"]) == 4
    assert len(where["mag"]["duplicates"]) == 2 and len(where["imu"]["infinite"]) == 1
    est = _quiet_run("ins-wind", repaired)
    assert est.flags is not None
    stamps = est.t[(est.flags & _bit("stamps_repaired")) != 0]
    expected = np.concatenate([where["imu"]["duplicates"], where["imu"]["reordered"], where["mag"]["duplicates"]])
    assert len(stamps) >= 5 and all(np.min(np.abs(stamps[:, None] - expected), axis=1) < 0.01)
    assert np.all((stamps >= 10.0) & (stamps <= 23.0))
    values = est.t[(est.flags & _bit("values_repaired")) != 0]
    assert len(values) == 1 and abs(values[0] - where["imu"]["infinite"][0]) < 0.01
    clean = _quiet_run("ins-wind", fixedwing)
    assert clean.flags is not None and not any(clean.flags & (_bit("stamps_repaired") | _bit("values_repaired")))


@pytest.fixture(scope="module")
def fixedwing60() -> Flight:
    return wa.simulate("fixedwing", seed=3, wind=8.0, duration=60.0)


# mekf on a fixed wing without air data reads the turns' acceleration as tilt (5.6-7.8 deg),
# which by itself moves the field residual near the detector's 20 % (max 0.19 with the core's
# bias walk, 0.26 with mekf's field default, gyro_bias_noise 1e-4): the detector is tested
# with the walk held at the core's
@pytest.mark.parametrize("spec", ["ins-wind", "mekf:gyro_bias_noise=2e-5:gyro_bias_noise_vertical=0"])
def test_a_drifting_field_is_flagged_and_a_clean_one_is_not(fixedwing60: Flight, spec: str) -> None:
    faulty = F.inject(fixedwing60, [F.MagDrift(start=25.0, duration=30.0)], seed=0)
    est = _quiet_run(spec, faulty)
    assert est.flags is not None
    on = est.t[(est.flags & _bit("mag_drift")) != 0]
    assert len(on) and 25.0 < on[0] < 45.0 and on[-1] < 60.0  # within the drift (mekf: from 29.6 s)
    clean = _quiet_run(spec, fixedwing60)
    assert clean.flags is not None and not any(clean.flags & (_bit("mag_drift") | _bit("air_drift")))


def test_a_ramping_pitot_is_flagged(fixedwing60: Flight) -> None:
    # both ports blocked in a 4.5 m/s climb at 15 m/s: about 3 m/s per s (sim.faults.PitotBlockage)
    faulty = F.inject(fixedwing60, [F.PitotBlockage(start=25.0, duration=10.0, mode="ramp", rate=3.0)], seed=0)
    est = _quiet_run("ins-wind", faulty)
    assert est.flags is not None
    on = est.t[(est.flags & _bit("air_drift")) != 0]
    assert len(on) and 25.0 < on[0] < 35.0
    assert not any(est.flags[est.t < 25.0] & _bit("air_drift"))


def test_a_fading_field_disturbance_meets_the_re_entry_gate() -> None:
    """The fault matrix's 20 uT field bump over 30 s on the quadrotor, seed 0: kept out at its
    height, the field re-entered the full gate at 5 sigma while still several uT off and
    turned the heading and the gyro bias, 13.2 s to recover; with the re-entry gate (half
    the gate until the field has passed it for 0.5 s, EskfParams.mag_reentry_gate) 0 s."""
    from windahrs.experiments.faults import FaultCase, run_fault_matrix

    case = FaultCase("mag-drift-30s", (F.MagDrift(30.0, 30.0),))
    res = run_fault_matrix("quadrotor", ["ins-wind"], duration=90.0, seed=0, cases=[case])  # (the flight depends on it)
    (row,) = res.rows
    assert row.recover_s is not None and row.recover_s < 6.0


def test_a_lone_field_outlier_costs_about_one_more_sample(fixedwing: Flight) -> None:
    # ten one-sample +50 uT outliers: each is rejected and arms the re-entry gate (half of
    # ins-wind's gate_mag 3: 1.5 sigma per component for 0.5 s), which at the default
    # mag_sigma keeps out none of the next samples (with mag_sigma at the simulator's true
    # 0.5 uT, 153 more of 1500: docs/ROBUSTNESS.md section 10)
    spikes = [F.MagMagnet(start=3.0 + 2.5 * k, duration=0.015) for k in range(10)]
    est = _quiet_run("ins-wind", F.inject(fixedwing, spikes, seed=0))
    mag = est.innovations["mag"]
    assert 10 <= int((~mag.accepted).sum()) <= 13
