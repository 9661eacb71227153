"""The compiled [usque] (windahrs.filters.compiled_usque) equals the readable reference
(windahrs.filters.usque) sample by sample: attitude, bias, covariance, innovations, gate
decisions and skipped counts, on simulated flights (fixed wing, quadrotor, NaN samples,
no magnetometer, unknown site field), from the truth and with non-default parameters; a
compiled streamer equals its batch run; the registry runs the compiled twin."""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest

from test_compiled import assert_same  # the comparison every compiled twin is held to
from windahrs.estimate import Estimate
from windahrs.filters.base import InitialState, merge_events, replay
from windahrs.filters.compiled_usque import UsqueFast, sqrt_cov
from windahrs.filters.params import EskfParams
from windahrs.filters.registry import make_estimator
from windahrs.filters.usque import Usque, _sqrt_cov
from windahrs.flight import Flight, ImuStream, MagStream, Site
from windahrs.rotation import euler_from_quat
from windahrs.sim.scenario import make_scenario, simulate

DURATION = 2.5  # s: the reference runs at about 0.4 ms per sample
TOL = 1e-9


def _with_nans(f: Flight, rng: np.random.Generator) -> Flight:
    """NaN in the first IMU and magnetometer samples (the initialisation must wait) and in
    a few later ones."""
    assert f.mag is not None
    w, fb, m = f.imu.w_b.copy(), f.imu.f_b.copy(), f.mag.mag_b.copy()
    i = rng.choice(np.arange(1, len(w)), size=len(w) // 40, replace=False)
    w[0, 1] = np.nan
    w[i[::2], 0] = np.nan
    fb[i[1::2], 2] = np.nan
    j = rng.choice(np.arange(1, len(m)), size=max(2, len(m) // 40), replace=False)
    m[np.concatenate([[0], j]), 1] = np.nan
    return f.replace(imu=ImuStream(t=f.imu.t, w_b=w, f_b=fb), mag=MagStream(t=f.mag.t, mag_b=m))


@cache
def flight(name: str) -> Flight:
    if name == "quadrotor":
        return simulate(make_scenario("quadrotor", wind=5.0, duration=DURATION), np.random.default_rng(3))
    f = simulate(make_scenario("fixedwing", wind=8.0, duration=DURATION), np.random.default_rng(1))
    if name == "nan":
        return _with_nans(f, np.random.default_rng(2))
    if name == "no-mag":
        return f.replace(mag=None)
    if name == "unknown-site":  # the field reference from the first magnetometer sample
        return f.replace(site=Site(gravity=f.site.gravity, mag_n=None))
    if name == "south":  # the field's horizontal part reversed: yaw estimates near +-180 deg
        assert f.site.mag_n is not None
        m = f.site.mag_n
        return f.replace(site=Site(gravity=f.site.gravity, mag_n=np.array([-m[0], -m[1], m[2]])))
    return f


@cache
def estimates(
    flight_name: str, params: EskfParams | None = None, initial: str | None = None
) -> tuple[Estimate, Estimate]:
    """(compiled, reference) estimates, computed once per case. initial: None, "truth",
    or "scaled" (the truth's attitude times -2: the filter normalises it)."""
    f = flight(flight_name)
    ini = None if initial is None else InitialState.from_truth(f, sigma_att=0.05)
    if initial == "scaled":
        assert ini is not None
        ini = dataclasses.replace(ini, q_nb=-2.0 * ini.q_nb, gyro_bias_b=None)
    return UsqueFast(params).run(f, initial=ini), Usque(params).run(f, initial=ini)


FLIGHTS = ["fixedwing", "nan", "quadrotor", "no-mag", "unknown-site", "south"]


@pytest.mark.parametrize("flight_name", FLIGHTS)
def test_compiled_equals_reference(flight_name: str) -> None:
    fast, ref = estimates(flight_name)
    assert_same(fast, ref, TOL)
    assert fast.state_labels == ("att_x", "att_y", "att_z", "bg_x", "bg_y", "bg_z")
    # the case exercises what it should
    assert set(ref.innovations) == ({"accel"} if flight_name == "no-mag" else {"accel", "mag"})
    if flight_name == "nan":
        assert ref.skipped["imu"] > 0 and ref.skipped["mag"] > 0
        assert ref.cov is not None and np.isnan(ref.cov[0]).all() and np.isfinite(ref.cov[-1]).all()
    if flight_name == "fixedwing":
        acc = ref.innovations["accel"].accepted
        assert acc.any() and not acc.all()  # accepted and norm-gated samples both occur


@pytest.mark.parametrize("initial", ["truth", "scaled"])
def test_compiled_equals_reference_from_truth(initial: str) -> None:
    fast, ref = estimates("fixedwing", initial=initial)
    assert_same(fast, ref, TOL)


VARIANTS = [
    EskfParams(mag_mode="heading"),
    EskfParams(mag_mode="off"),
    EskfParams(gate_accel=1.0, gate_mag=1.0),  # tight gates reject some updates
    EskfParams(mag_mode="heading", gate_mag=1.0, accel_norm_gate=0.5),
    EskfParams(init_mag_bias=1e-6),  # ignored by [usque]: no magnetometer-bias states
    EskfParams(gyro_noise=1e-3, gyro_bias_noise=1e-4, init_att=0.5, init_bias=0.05, accel_sigma=0.5),
]


@pytest.mark.parametrize("params", VARIANTS)
def test_compiled_equals_reference_with_params(params: EskfParams) -> None:
    fast, ref = estimates("nan", params)
    assert_same(fast, ref, TOL)
    if params.mag_mode == "heading":
        assert fast.innovations["mag"].nu.shape[1] == 1
    if params.mag_mode == "off":
        assert "mag" not in fast.innovations
    if min(params.gate_mag, params.gate_accel) < 5.0:
        assert all(not inn.accepted.all() for inn in ref.innovations.values())


def test_heading_across_180_deg_equals_reference() -> None:
    """Heading only, the estimate about +-180 deg: the sigma points' yaws and the
    innovations wrap."""
    fast, ref = estimates("south", EskfParams(mag_mode="heading"))
    assert_same(fast, ref, TOL)
    yaw = euler_from_quat(ref.q_nb)[:, 2]
    assert (yaw > 3.0).any() and (yaw < -3.0).any()


@pytest.mark.parametrize("mag_mode", ["3d", "heading"])
def test_streaming_equals_batch(mag_mode: str) -> None:
    """The compiled streamer fed sample by sample (through base.replay, reading its state
    at every IMU sample) equals the compiled batch run exactly; GNSS and air-data samples
    fed to it are ignored, as the reference ignores them."""
    params = EskfParams(mag_mode=mag_mode)
    est = UsqueFast(params)
    f = flight("nan")
    t_ev, kinds, vals = merge_events(f, frozenset({"imu", "mag", "gnss", "air"}))
    assert {2, 3} <= set(kinds.tolist())
    streamed = replay(est, est.streamer(f.site, has=frozenset({"imu", "mag"})), f, t_ev, kinds, vals)
    batch, _ = estimates("nan", params)
    assert_same(streamed, batch, tol=0.0)


def test_square_root_equals_reference() -> None:
    """The scalar Cholesky equals LAPACK's to rounding; a covariance made slightly
    indefinite by rounding takes the eigen square root, as in the reference."""
    rng = np.random.default_rng(7)
    A = rng.normal(size=(6, 8))
    L = np.zeros((6, 6))
    sqrt_cov(A @ A.T, 7.0, L)
    np.testing.assert_allclose(L, _sqrt_cov(A @ A.T, 7.0), rtol=0.0, atol=1e-13 * np.abs(L).max())
    B = A[:, :5]
    w, V = np.linalg.eigh(B @ B.T)
    w[0] = -1e-15
    P = (V * w) @ V.T
    sqrt_cov(P, 7.0, L)
    assert np.isfinite(L).all()
    np.testing.assert_allclose(L @ L.T, 7.0 * P, atol=1e-12 * np.abs(P).max())
    np.testing.assert_allclose(L @ L.T, (R := _sqrt_cov(P, 7.0)) @ R.T, atol=1e-12 * np.abs(P).max())


def test_registry_runs_the_compiled_twin() -> None:
    est = make_estimator("usque")
    assert type(est) is UsqueFast and issubclass(UsqueFast, Usque)
    assert (est.name, est.requires, est.uses) == (Usque.name, Usque.requires, Usque.uses)
    assert UsqueFast().params == Usque().params
    spec = "usque:mag_mode=heading:gate_mag=2.5"
    est = make_estimator(spec)
    assert type(est) is UsqueFast and est.params == EskfParams(mag_mode="heading", gate_mag=2.5)
    out = est.run(flight("fixedwing"))
    assert out.filter == spec and out.innovations["mag"].nu.shape[1] == 1


def test_bad_params_refused_like_the_reference() -> None:
    for cls in (Usque, UsqueFast):
        with pytest.raises(ValueError, match="accel_compensation"):
            cls(EskfParams(accel_compensation="gnss"))
        with pytest.raises(TypeError, match="EskfParams"):
            cls(params=object())  # type: ignore[arg-type]
