"""The compiled twins (windahrs.filters.compiled) equal the readable references sample by
sample: attitude, bias, velocity, wind, covariance, innovations, gate decisions and skipped
counts, on simulated flights (vanes, pitot only, NaN in every stream, quadrotor), from the
truth and with non-default parameters; and a compiled streamer equals its batch run."""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest

from windahrs.estimate import Estimate
from windahrs.filters.base import InitialState, MissingSensorError, merge_events, replay
from windahrs.filters.compiled import Ekf7Fast, Ekf10Fast, InsWindFast, MekfAirFast, MekfFast
from windahrs.filters.ekf7 import Ekf7, Ekf10
from windahrs.filters.eskf import InsWind, Mekf, MekfAir
from windahrs.filters.params import EskfParams
from windahrs.flight import AirDataStream, Flight, GnssStream, ImuStream, MagStream
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.sim.sensors import SensorSuite

PAIRS = {
    "mekf": (Mekf, MekfFast),
    "mekf-air": (MekfAir, MekfAirFast),
    "ins-wind": (InsWind, InsWindFast),
    "ekf7": (Ekf7, Ekf7Fast),
    "ekf10": (Ekf10, Ekf10Fast),
}
NEEDS_AIR = ("mekf-air", "ekf10")
DURATION = 2.5  # s: the reference runs at about 1 ms per sample
TOL = 1e-9


def _with_nans(f: Flight, rng: np.random.Generator) -> Flight:
    """NaN samples in every stream: the first IMU, magnetometer and GNSS samples (the
    initialisation must wait) and a few later ones; one air sample without vanes."""

    def holes(n: int, first: bool) -> np.ndarray:
        idx = rng.choice(np.arange(1, n), size=max(2, n // 40), replace=False)
        return np.concatenate([[0], idx]) if first else idx

    assert f.mag is not None and f.gnss is not None and f.air is not None and f.air.aoa is not None
    w, fb = f.imu.w_b.copy(), f.imu.f_b.copy()
    i = holes(len(w), True)
    w[i[::2]] = np.nan
    fb[i[1::2]] = np.nan
    w[0] = np.nan
    m = f.mag.mag_b.copy()
    m[holes(len(m), True)] = np.nan
    v = f.gnss.v_n.copy()
    v[holes(len(v), True), 1] = np.nan
    tas, aoa, beta = f.air.tas.copy(), f.air.aoa.copy(), f.air.sideslip.copy()
    j = holes(len(tas), False)
    tas[j[:-1]] = np.nan
    aoa[j[-1]] = np.nan  # a sample without vanes: airspeed + sideslip instead of the vector
    return dataclasses.replace(
        f,
        imu=ImuStream(t=f.imu.t, w_b=w, f_b=fb),
        mag=MagStream(t=f.mag.t, mag_b=m),
        gnss=GnssStream(t=f.gnss.t, v_n=v),
        air=AirDataStream(t=f.air.t, tas=tas, aoa=aoa, sideslip=beta),
    )


@cache
def flight(name: str) -> Flight:
    if name == "quadrotor":
        return simulate(make_scenario("quadrotor", wind=5.0, duration=DURATION), np.random.default_rng(3))
    sensors = SensorSuite(vanes=None) if name == "pitot" else SensorSuite()
    f = simulate(make_scenario("fixedwing", wind=8.0, duration=DURATION), np.random.default_rng(1), sensors)
    return _with_nans(f, np.random.default_rng(2)) if name == "nan" else f


@cache
def estimates(
    kind: str, flight_name: str, params: EskfParams | None = None, truth: bool = False
) -> tuple[Estimate, Estimate]:
    """(compiled, reference) estimates, computed once per case."""
    ref_cls, fast_cls = PAIRS[kind]
    f = flight(flight_name)
    ini = InitialState.from_truth(f) if truth else None
    return fast_cls(params).run(f, initial=ini), ref_cls(params).run(f, initial=ini)


def assert_same(fast: Estimate, ref: Estimate, tol: float = TOL) -> None:
    """Sample by sample: states to tol, covariance to tol relative (to sqrt(P_ii P_jj)),
    innovations to tol relative, gate decisions and everything else identical."""
    assert fast.filter == ref.filter and fast.params == ref.params
    assert fast.state_labels == ref.state_labels
    assert fast.skipped == ref.skipped
    np.testing.assert_array_equal(fast.t, ref.t)
    for name in ("q_nb", "gyro_bias_b", "v_n", "wind_n"):
        a, b = getattr(fast, name), getattr(ref, name)
        assert (a is None) == (b is None), name
        if b is not None:
            np.testing.assert_allclose(a, b, rtol=0, atol=tol, err_msg=name)
    assert fast.cov is not None and ref.cov is not None
    np.testing.assert_array_equal(np.isnan(fast.cov), np.isnan(ref.cov))
    d = np.sqrt(np.abs(np.diagonal(ref.cov, axis1=1, axis2=2)))
    scale = d[:, :, None] * d[:, None, :]
    err = np.abs(fast.cov - ref.cov)
    assert np.nanmax(err / np.where(scale > 0, scale, 1.0)) <= tol
    assert list(fast.innovations) == list(ref.innovations)
    for sensor, b in ref.innovations.items():
        a = fast.innovations[sensor]
        np.testing.assert_array_equal(a.t, b.t, err_msg=sensor)
        np.testing.assert_array_equal(a.accepted, b.accepted, err_msg=sensor)
        assert a.nu.shape == b.nu.shape, sensor
        np.testing.assert_array_equal(np.isnan(a.nu), np.isnan(b.nu), err_msg=sensor)
        nu_scale = float(np.nanmax(np.abs(b.nu), initial=0.0))
        np.testing.assert_allclose(a.nu, b.nu, rtol=tol, atol=tol * nu_scale, err_msg=sensor)
        np.testing.assert_allclose(a.nis, b.nis, rtol=tol, atol=tol, err_msg=sensor)  # (NIS is unitless)


CASES = [
    (k, f)
    for f in ("vanes", "pitot", "nan", "quadrotor")
    for k in PAIRS
    if not (f == "quadrotor" and k in NEEDS_AIR)
]


@pytest.mark.parametrize(("kind", "flight_name"), CASES)
def test_compiled_equals_reference(kind: str, flight_name: str) -> None:
    fast, ref = estimates(kind, flight_name)
    assert_same(fast, ref)
    # the case exercises what it should
    if flight_name == "nan":
        assert all(v > 0 for s, v in ref.skipped.items() if s in PAIRS[kind][0].uses)
        assert np.isnan(ref.q_nb).sum() == 0 and np.isnan(ref.cov[0]).all()
    raw = PAIRS[kind][0].default_params.accel_lowpass == 0  # [mekf]'s 3-s mean stays inside
    if kind in ("mekf", "ekf7", "mekf-air", "ekf10") and flight_name != "quadrotor" and raw:
        acc = ref.innovations["accel"].accepted
        assert acc.any() and not acc.all()  # accepted and norm-gated samples both occur
    if flight_name == "pitot" and kind in ("mekf-air", "ins-wind", "ekf10"):
        assert {"tas", "sideslip"} <= set(ref.innovations) and "air" not in ref.innovations


@pytest.mark.parametrize("kind", list(PAIRS))
def test_compiled_equals_reference_from_truth(kind: str) -> None:
    fast, ref = estimates(kind, "vanes", truth=True)
    assert_same(fast, ref)


VARIANTS = [
    ("mekf", EskfParams(mag_mode="heading", accel_compensation="gnss")),
    ("mekf", EskfParams(accel_compensation="airspeed", gate_mag=1.0, mag_mode="3d")),
    ("ekf7", EskfParams(mag_mode="heading", accel_compensation="gnss", gate_accel=1.0)),
    ("ins-wind", EskfParams(accel_bias_noise=0.0, mag_mode="heading")),
    ("ins-wind", EskfParams(air_mode="airspeed", synthetic_sideslip=False, gate_air=1.0, mag_mode="off")),
    ("mekf-air", EskfParams(accel_compensation="airspeed", air_mode="airspeed", gate_air=2.0)),
    ("ekf10", EskfParams(accel_compensation="airspeed", mag_mode="off", gate_air=1.5)),
    # magnetometer-bias states (the additive ekf7 carries none)
    ("mekf", EskfParams(init_mag_bias=1e-6)),
    ("mekf-air", EskfParams(accel_compensation="airspeed", init_mag_bias=2e-6, mag_bias_noise=1e-7)),
    ("ekf7", EskfParams(init_mag_bias=1e-6)),
    # low-passed vectors, rate-proportional gyro noise, heading about the vertical, tight
    # magnetic disturbance checks (so that they reject)
    (
        "mekf",
        EskfParams(
            accel_lowpass=0.5,
            accel_norm_gate=0.01,
            accel_compensation="gnss",
            gyro_scale_noise=1e-3,
            mag_mode="heading",
            heading_model="vertical",
            mag_lowpass=1.0,
            mag_norm_gate=0.01,
        ),
    ),
    (
        "ekf7",
        EskfParams(accel_lowpass=1.0, mag_lowpass=2.0, mag_mode="heading", heading_model="vertical", mag_dip_gate=0.01),
    ),
    ("mekf-air", EskfParams(accel_compensation="airspeed", accel_lowpass=1.0, init_mag_bias=1e-6, mag_norm_gate=0.01)),
    ("ins-wind", EskfParams(mag_lowpass=1.0, gyro_scale_noise=1e-3, mag_dip_gate=0.01)),
]


@pytest.mark.parametrize(("kind", "params"), VARIANTS)
def test_compiled_equals_reference_with_params(kind: str, params: EskfParams) -> None:
    fast, ref = estimates(kind, "nan", params)
    assert_same(fast, ref)
    if params.mag_mode == "heading":
        assert fast.innovations["mag"].nu.shape[1] == 1
    if min(params.gate_mag, params.gate_air, params.gate_accel) < 5.0:  # tight gates reject some
        assert any(not inn.accepted.all() for inn in ref.innovations.values())


def test_compiled_equals_reference_without_a_site_field() -> None:
    """[mekf]'s defaults when the site's field is unknown: heading only, about the vertical."""
    f = flight("nan")
    f = dataclasses.replace(f, site=dataclasses.replace(f.site, mag_n=None))
    fast, ref = MekfFast().run(f), Mekf().run(f)
    assert_same(fast, ref)
    assert ref.innovations["mag"].nu.shape[1] == 1


@pytest.mark.parametrize("kind", list(PAIRS))
def test_streaming_equals_batch(kind: str) -> None:
    """The compiled streamer fed sample by sample (through base.replay, reading its state
    at every IMU sample) equals the compiled batch run exactly."""
    est = PAIRS[kind][1]()
    f = flight("nan")
    has = frozenset(s for s in ("imu", "mag", "gnss", "air") if getattr(f, s) is not None) & est.uses
    t_ev, kinds, vals = merge_events(f, has)
    streamed = replay(est, est.streamer(f.site, has=has), f, t_ev, kinds, vals)
    batch, _ = estimates(kind, "nan")
    assert_same(streamed, batch, tol=0.0)


def test_quadrotor_without_air_data_is_refused_like_the_reference() -> None:
    for kind in NEEDS_AIR:
        ref_cls, fast_cls = PAIRS[kind]
        with pytest.raises(MissingSensorError) as ref_err:
            ref_cls().run(flight("quadrotor"))
        with pytest.raises(MissingSensorError) as fast_err:
            fast_cls().run(flight("quadrotor"))
        assert str(fast_err.value) == str(ref_err.value)


def test_fast_classes_keep_the_reference_identity() -> None:
    for ref_cls, fast_cls in PAIRS.values():
        assert issubclass(fast_cls, ref_cls)
        assert (fast_cls.name, fast_cls.requires, fast_cls.uses) == (
            ref_cls.name,
            ref_cls.requires,
            ref_cls.uses,
        )
        assert fast_cls().params == ref_cls().params


def test_estimates_are_labelled_with_the_registry_spec() -> None:
    from windahrs.filters.registry import make_estimator

    spec = "mekf:mag_mode=heading"
    assert make_estimator(spec).run(flight("nan")).filter == spec
