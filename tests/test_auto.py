"""``auto``: the estimator the flight's sensors allow, equal to the one it chose, saying which."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

import windahrs as wa
from conftest import require_data
from windahrs.cli import main
from windahrs.core.kernel import CompiledEstimator
from windahrs.estimate import Estimate, load_estimate
from windahrs.filters.auto import (
    ALIGN_MIN_INTERVALS,
    HANDOVER_HEADING_SIGMA,
    LANE_SWITCH_LLR,
    MAX_GNSS_TIMING_S,
    Auto,
    _about_vertical,
    _lanes,
    aligned_index,
    describe_choice,
    gate_closed,
    gnss_heading,
    handover_index,
    lane_choice,
    lane_scores,
    splice,
    usable_streams,
)
from windahrs.filters.base import InitialState, merge_events
from windahrs.filters.eskf import InsWind, Mekf
from windahrs.filters.registry import make_estimator
from windahrs.flight import GnssStream
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.store import save_flight


@pytest.fixture(scope="module")
def fw() -> wa.Flight:
    """A fixed wing in wind: IMU, magnetometer, GNSS velocity, pitot and vanes."""
    return wa.simulate("fixedwing", seed=3, duration=15.0, wind=6.0)


def assert_same(a: Estimate, b: Estimate) -> None:
    """Bit for bit: attitude, bias, velocity, wind, covariance, innovations."""
    for name in ("q_nb", "gyro_bias_b", "v_n", "wind_n", "cov"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=name)
    assert a.state_labels == b.state_labels and a.innovations.keys() == b.innovations.keys()
    for k in a.innovations:
        np.testing.assert_array_equal(a.innovations[k].nu, b.innovations[k].nu)
        np.testing.assert_array_equal(a.innovations[k].accepted, b.innovations[k].accepted)
    assert a.skipped == b.skipped and a.params == b.params


def test_with_gnss_it_is_ins_wind_fusing_everything(fw: wa.Flight) -> None:
    est = wa.estimator("auto").run(fw)
    assert_same(est, wa.estimator("ins-wind").run(fw))
    assert est.filter == "auto"
    assert est.meta == {"auto": "ins-wind", "sensors": "imu,mag,gnss,air", "auto_reason": "GNSS velocity present"}
    assert est.wind_n is not None and set(est.innovations) >= {"gnss", "mag", "air"}
    assert describe_choice(est) == "auto ran ins-wind on imu,mag,gnss,air (GNSS velocity present)"


def test_without_gnss_it_is_mekf(fw: wa.Flight) -> None:
    imu_mag = fw.replace(gnss=None, air=None)
    est = wa.estimator("auto").run(imu_mag)
    assert_same(est, wa.estimator("mekf").run(imu_mag))
    assert est.meta["auto"] == "mekf" and est.meta["sensors"] == "imu,mag"
    assert est.meta["auto_reason"] == "no GNSS velocity"


def test_air_data_without_gnss_compensates_the_turns(fw: wa.Flight) -> None:
    no_gnss = fw.replace(gnss=None)
    est = wa.estimator("auto").run(no_gnss)
    assert est.meta["auto"] == "mekf:accel_compensation=airspeed" and est.meta["sensors"] == "imu,mag,air"
    assert_same(est, make_estimator(est.meta["auto"]).run(no_gnss))
    plain = wa.estimator("mekf").run(no_gnss)  # the compensation acts without GNSS
    assert np.abs(est.q_nb - plain.q_nb).max() > 1e-3


def test_imu_only_runs_and_an_empty_stream_counts_as_absent(fw: wa.Flight) -> None:
    bare = fw.replace(gnss=None, air=None, mag=None)
    est = wa.estimator("auto").run(bare)
    assert est.meta["auto"] == "mekf" and est.meta["sensors"] == "imu"
    assert np.isfinite(est.q_nb).all()
    assert wa.score(est, bare).rmse_tilt_deg < 10.0  # a tilt, not a failure to start
    # a GNSS stream with no finite sample would keep the INS waiting for ever: mekf instead
    assert fw.gnss is not None
    dead = fw.replace(gnss=GnssStream(fw.gnss.t, np.full_like(fw.gnss.v_n, np.nan)), air=None)
    assert usable_streams(dead) == {"imu", "mag"}
    est = wa.estimator("auto").run(dead)
    assert est.meta["auto"] == "mekf" and est.skipped["gnss"] == len(fw.gnss.t)
    assert_same(est, wa.estimator("mekf").run(dead))


def test_overrides_go_to_the_chosen_estimator_when_it_uses_them(fw: wa.Flight) -> None:
    est = make_estimator("auto:gnss_sigma=0.5:accel_lowpass=1")
    assert est.label == "auto:gnss_sigma=0.5:accel_lowpass=1"
    with_gnss = est.run(fw)
    assert with_gnss.filter == "auto:gnss_sigma=0.5:accel_lowpass=1"
    assert with_gnss.meta["auto"] == "ins-wind:gnss_sigma=0.5" and with_gnss.meta["auto_ignored"] == "accel_lowpass"
    assert_same(with_gnss, make_estimator("ins-wind:gnss_sigma=0.5").run(fw))
    imu_mag = fw.replace(gnss=None, air=None)
    without = est.run(imu_mag)
    assert without.meta["auto"] == "mekf:accel_lowpass=1" and without.meta["auto_ignored"] == "gnss_sigma"
    assert_same(without, make_estimator("mekf:accel_lowpass=1").run(imu_mag))
    assert describe_choice(without) == (
        "auto:gnss_sigma=0.5:accel_lowpass=1 ran mekf:accel_lowpass=1 on imu,mag (no GNSS velocity); "
        "not used by it: gnss_sigma"
    )
    # an explicit compensation wins over auto's
    none = make_estimator("auto:accel_compensation=none").run(fw.replace(gnss=None))
    assert none.meta["auto"] == "mekf:accel_compensation=none" and none.meta["sensors"] == "imu,mag"
    # the keyword form is the same
    kw = wa.estimator("auto", gnss_sigma=0.5)
    assert kw.label == "auto:gnss_sigma=0.5" and kw.overrides == {"gnss_sigma": 0.5}  # type: ignore[attr-defined]
    # drag is never on by default, but can be asked for (it needs GNSS, as ins-drag does)
    assert make_estimator("auto:drag=true").choose({"imu", "gnss"}).spec == "ins-wind:drag=true"  # type: ignore[attr-defined]


def test_bad_overrides_fail_when_the_spec_is_built(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"filter 'auto' has no parameter 'nope' \(neither ins-wind nor mekf"):
        make_estimator("auto:nope=1")
    with pytest.raises(ValueError, match="mag_mode: expected one of"):
        make_estimator("auto:mag_mode=sideways")
    with pytest.raises(ValueError, match="filter 'auto' has no parameter 'nope'"):
        wa.estimator("auto", nope=1)
    p = tmp_path / "p.toml"
    p.write_text('[windahrs]\ngnss_sigma = 0.4\n[px4]\nEKF2_GYR_NOISE = 0.015\n')
    est = make_estimator("auto:mag_mode=heading", p)
    assert est.overrides == {  # type: ignore[attr-defined]
        "gnss_sigma": 0.4, "gyro_noise": pytest.approx(0.0015), "mag_mode": "heading"
    }
    p.write_text("[windahrs]\nwind = 3\n")
    with pytest.raises(ValueError, match="unknown parameter 'wind'"):
        make_estimator("auto", p)


def test_streaming_chooses_from_the_announced_streams(fw: wa.Flight) -> None:
    auto = wa.estimator("auto")
    imu_mag = fw.replace(gnss=None, air=None)
    s = auto.stream(fw.site, has={"imu", "mag"})
    assert s.filter_name == "mekf"
    t, kinds, vals = merge_events(imu_mag, frozenset({"imu", "mag"}))
    for i in range(len(t)):
        s.push(int(kinds[i]), float(t[i]), vals[i])
    np.testing.assert_array_equal(s.state.q_nb, wa.estimator("mekf").run(imu_mag).q_nb[-1])
    assert auto.stream(fw.site).filter_name == "ins-wind"  # every stream announced


def test_a_quadrotor_gets_ins_wind_without_drag() -> None:
    quad = wa.simulate("quadrotor", seed=1, duration=4.0, wind=3.0)
    est = wa.estimator("auto").run(quad)
    assert est.meta["auto"] == "ins-wind" and est.meta["sensors"] == "imu,mag,gnss"
    assert "drag" not in est.innovations


def test_cli_estimate_defaults_to_auto_and_says_what_it_ran(
    fw: wa.Flight, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "fw.h5"
    save_flight(fw.replace(gnss=None), f)
    out = tmp_path / "est.h5"
    capsys.readouterr()
    assert main(["estimate", str(f), "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == (
        "auto ran mekf:accel_compensation=airspeed on imu,mag,air (no GNSS velocity; air data compensates the turns)"
    )
    assert lines[-1].startswith("auto: RMSE vs truth from sample 50")
    saved = load_estimate(out)
    assert saved.filter == "auto" and saved.meta["auto"] == "mekf:accel_compensation=airspeed"
    assert main(["filters"]) == 0
    assert capsys.readouterr().out.splitlines()[0].startswith("auto          ins-wind with GNSS velocity, else mekf")


def test_cli_compare_defaults_start_with_auto(
    fw: wa.Flight, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "fw.h5"
    save_flight(fw.replace(gnss=None, air=None), f)
    capsys.readouterr()
    assert main(["compare", str(f)]) == 0
    std = capsys.readouterr()
    rows = [line.split()[0] for line in std.out.splitlines()[2:]]
    assert rows[:2] == ["auto", "mekf"] and "ins-wind" not in rows
    assert "Default filter ins-wind left out" in std.err
    assert "windahrs: auto ran mekf on imu,mag (no GNSS velocity)" in std.err
    auto_row, mekf_row = std.out.splitlines()[2:4]
    assert auto_row.split()[1:] == mekf_row.split()[1:]  # the same numbers



class _LostIns(InsWind):
    """[ins-wind] whose every estimate fails the tilt check from 5 s on, 3/4 of the flight
    (the mechanism under test is auto's, not the check's). No stationary alignment: after
    one, auto's splice would check the tilt again, replacing the alerts made here."""

    default_params = dataclasses.replace(InsWind.default_params, rest_detection="off")

    def run(self, flight, *, initial=None, cov_every=None):  # type: ignore[no-untyped-def]
        est = super().run(flight, initial=initial, cov_every=cov_every)
        return dataclasses.replace(est, alerts={"tilt": np.array([[5.0, est.t[-1], 30.0]])})


class _AutoWithLostIns(Auto):
    candidates: ClassVar[dict[str, type[CompiledEstimator]]] = {"ins-wind": _LostIns, "mekf": Mekf}


def test_auto_falls_back_without_gnss_when_the_ins_fails_its_tilt_check() -> None:
    flight = simulate(make_scenario("quadrotor", wind=5.0, duration=20.0), np.random.default_rng(6))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = _AutoWithLostIns().run(flight)
        mekf = make_estimator("mekf").run(flight)
    assert est.meta["auto"] == "mekf" and "tilt disagreed with the mean specific force for" in est.meta["auto_fallback"]
    np.testing.assert_array_equal(est.q_nb, mekf.q_nb)
    assert "fell back from the INS" in (describe_choice(est) or "")
    kept = Auto().run(flight)  # the real INS passes the check here, and is kept
    assert kept.meta["auto"] == "ins-wind" and "auto_fallback" not in kept.meta


def test_auto_leaves_out_a_gnss_stream_declared_unsynchronised() -> None:
    """ANSFL: GNSS velocity differentiated from positions on the DJI's clock; the reader
    declares its timing uncertain by 0.5 s."""
    flight = wa.read(require_data("ansfl", "Horizontal", "path_10"))
    assert flight.gnss is not None and flight.meta["gnss.timing_sigma_s"] > MAX_GNSS_TIMING_S
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = wa.estimator("auto").run(flight)
    assert est.meta["auto"] == "mekf" and "another clock" in est.meta["auto_reason"]


@pytest.fixture(scope="module")
def headless() -> wa.Flight:
    """A quadrotor with GNSS velocity and no magnetometer: the INS starts with its heading unknown."""
    return wa.simulate("quadrotor", seed=3, duration=20.0, wind=6.0).replace(mag=None)


def _inclination_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The tilt between attitudes a and b (N, 4), deg (BROAD's inclination of a b^-1)."""
    from windahrs.experiments.benchdata import split_error
    from windahrs.rotation import quat_conj, quat_mul

    return np.degrees(split_error(quat_mul(a, quat_conj(b)))[2])


def _heading_deg(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q.T
    return np.degrees(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def _vertical_body(q: np.ndarray) -> np.ndarray:
    """C_bn e_3 (N, 3) of attitudes q_nb (N, 4), written out (the oracle of the code's)."""
    w, x, y, z = q.T
    return np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z], axis=1)


def _runs(flight: wa.Flight, *names: str) -> list[Estimate]:
    """The estimates of ``names`` on ``flight``, their warnings silenced; the compiled
    filters' with every sample's covariance, as auto runs them (its handover reads it)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return [make_estimator(n).run(flight, cov_every="budget") if n != "auto" else  # type: ignore[call-arg]
                make_estimator(n).run(flight) for n in names]


def test_without_a_magnetometer_mekf_hands_over_to_the_ins_once_it_knows_its_heading(headless: wa.Flight) -> None:
    est, mekf, ins = _runs(headless, "auto", "mekf", "ins-wind")
    k = handover_index(ins)
    assert k is not None and 0 < k < len(ins.t)
    # the INS's own covariance: its heading's 1 sigma first under 15 deg at k
    assert est.meta["auto"] == "ins-wind" and est.meta["sensors"] == "imu,gnss"
    assert est.meta["auto_handover_s"] == pytest.approx(ins.t[k] - ins.t[0])
    assert "tilt with the INS's heading until" in est.meta["auto_reason"]
    # from k on, the INS (its GNSS gate never closed here); before, mekf's tilt with the INS's heading
    assert not gate_closed(ins).any() and est.meta["auto_gate_closed_s"] == 0.0
    np.testing.assert_array_equal(est.q_nb[k:], ins.q_nb[k:])
    np.testing.assert_allclose(_inclination_deg(est.q_nb[:k], mekf.q_nb[:k]), 0.0, atol=1e-4)  # (arccos near 1)
    np.testing.assert_allclose(np.cos(np.radians(_heading_deg(est.q_nb[:k]) - _heading_deg(ins.q_nb[:k]))), 1.0,
                               atol=1e-9)
    np.testing.assert_array_equal(est.gyro_bias_b[:k], mekf.gyro_bias_b[:k])
    assert est.v_n is not None and est.wind_n is not None  # the INS's states, the whole flight
    # the output is checked again: its tilt alerts are those of its own attitude, not the INS's
    from windahrs.filters.checks import tilt_alerts

    np.testing.assert_array_equal(est.alerts.get("tilt", np.empty((0, 3))), tilt_alerts(est, headless))
    assert "ins-wind" in (describe_choice(est) or "")


def test_the_handover_is_at_the_first_sample_whose_heading_sigma_is_under_15_deg(headless: wa.Flight) -> None:
    (ins,) = _runs(headless, "ins-wind")
    k = handover_index(ins)
    assert ins.cov is not None and k is not None
    d = _vertical_body(ins.q_nb)
    sd = np.sqrt(np.einsum("ni,nij,nj->n", d, ins.cov[:, :3, :3], d))
    assert sd[k] < HANDOVER_HEADING_SIGMA and not (sd[:k] < HANDOVER_HEADING_SIGMA).any()
    assert handover_index(dataclasses.replace(ins, cov=None)) is None
    assert handover_index(ins, sigma=1e-9) is None  # never that sure: no handover


def test_the_spliced_covariance_is_mekfs_before_the_handover_with_the_ins_heading_variance(
    headless: wa.Flight,
) -> None:
    mekf, ins = _runs(headless, "mekf", "ins-wind")
    k = 200
    take = np.arange(len(ins.t)) < k
    out = splice(mekf, ins, take)
    assert out.cov is not None and ins.cov is not None and mekf.cov is not None
    att, bg = [0, 1, 2], [ins.state_labels.index(f"bg_{a}") for a in "xyz"]
    # after the handover: the INS's, untouched
    np.testing.assert_array_equal(out.cov[k:], ins.cov[k:])
    # before: mekf's bias block, no correlation with the INS's other states
    np.testing.assert_array_equal(out.cov[:k][:, bg][:, :, bg], mekf.cov[:k, 3:6, 3:6])
    others = [i for i in range(len(ins.state_labels)) if i not in att + bg]
    assert not out.cov[:k][:, att + bg][:, :, others].any()
    np.testing.assert_array_equal(out.cov[:k][:, others][:, :, others], ins.cov[:k][:, others][:, :, others])
    # ... its attitude block mekf's but along the vertical, where the INS's heading variance is
    d = _vertical_body(out.q_nb[:k])
    along = lambda c: np.einsum("ni,nij,nj->n", d, c[:, :3, :3], d)  # noqa: E731
    np.testing.assert_allclose(along(out.cov[:k]), along(ins.cov[:k]), rtol=1e-9)
    e = np.cross(d, [0.0, 0.0, 1.0]) + np.cross(d, [1.0, 0.0, 0.0])  # a direction off the vertical
    e -= np.sum(e * d, axis=1, keepdims=True) * d
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("ni,nij,nj->n", e, out.cov[:k, :3, :3], e),
                               np.einsum("ni,nij,nj->n", e, mekf.cov[:k, :3, :3], e), rtol=1e-9)
    assert "tilt" not in out.alerts and "bias" not in out.alerts


def test_without_a_magnetometer_the_smoother_is_the_ins_one(fw: wa.Flight) -> None:
    """The smoother's backward pass carries the heading back to the start: auto-smooth runs
    [ins-wind]'s smoother on GNSS without a magnetometer, bit for bit."""
    headless = fw.replace(mag=None, air=None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        smoothed = make_estimator("auto-smooth").run(headless)
        ins = make_estimator("ins-wind-smooth").run(headless)
        off = make_estimator("auto-smooth:mag_mode=off").run(fw.replace(air=None))
    assert smoothed.meta["auto"] == "ins-wind" and smoothed.meta["sensors"] == "imu,gnss"
    assert "smoothed: the backward pass carries the heading" in smoothed.meta["auto_reason"]
    assert "auto_handover_s" not in smoothed.meta
    np.testing.assert_array_equal(smoothed.q_nb, ins.q_nb)
    assert off.meta["auto"].startswith("ins-wind")  # a magnetometer it is told not to fuse: the same rule


def test_gate_closed_is_where_the_latest_sample_was_rejected() -> None:
    from windahrs.estimate import Innovations

    t = np.arange(0.0, 2.0, 0.1)  # IMU samples
    gnss = Innovations(t=np.array([0.25, 0.55, 0.85, 1.15]), nu=np.zeros((4, 3)), nis=np.zeros(4),
                       accepted=np.array([True, False, False, True]))
    from types import SimpleNamespace

    est = SimpleNamespace(t=t, innovations={"gnss": gnss})  # (what gate_closed reads of an Estimate)
    closed = gate_closed(est)  # type: ignore[arg-type]
    np.testing.assert_array_equal(np.flatnonzero(closed), np.flatnonzero((t >= 0.55) & (t < 1.15)))
    assert not gate_closed(est, "mag").any()  # type: ignore[arg-type]  # no such log: never closed


def test_mekf_tilt_stands_in_while_the_ins_gnss_gate_is_closed(headless: wa.Flight) -> None:
    """After the handover, an INS whose GNSS is rejected (here: GNSS 20 m/s off for 3 s)
    gives way to mekf's tilt (with its own heading) until GNSS passes its gate again."""
    g = headless.gnss
    assert g is not None
    v = g.v_n.copy()
    jump = (g.t > 12.0) & (g.t < 15.0)
    v[jump, 0] += 20.0
    faulty = headless.replace(gnss=dataclasses.replace(g, v_n=v))
    est, mekf, ins = _runs(faulty, "auto", "mekf", "ins-wind")
    closed = gate_closed(ins)
    k = handover_index(ins)
    assert k is not None and closed.any() and not closed[:k].any()
    assert est.meta["auto_gate_closed_s"] > 1.0
    np.testing.assert_allclose(_inclination_deg(est.q_nb[closed], mekf.q_nb[closed]), 0.0, atol=1e-4)
    open_ = ~closed & (np.arange(len(ins.t)) >= k)
    np.testing.assert_array_equal(est.q_nb[open_], ins.q_nb[open_])


class _BrokenIns(InsWind):
    def run(self, flight, *, initial=None, cov_every=None):  # type: ignore[no-untyped-def]
        raise ValueError("gnss: nothing to fuse")


class _AutoWithBrokenIns(Auto):
    candidates: ClassVar[dict[str, type[CompiledEstimator]]] = {"ins-wind": _BrokenIns, "mekf": Mekf}


def test_an_ins_that_cannot_run_beside_mekf_leaves_mekf(headless: wa.Flight) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = _AutoWithBrokenIns().run(headless)
        mekf = make_estimator("mekf").run(headless)
    assert est.meta["auto"] == "mekf" and "the INS beside it: gnss: nothing to fuse" in est.meta["auto_reason"]
    np.testing.assert_array_equal(est.q_nb, mekf.q_nb)


def _circling(psi0: float, v_sigma: float, seed: int = 0) -> tuple[wa.Flight, Estimate]:
    """A level sensor whose velocity turns on a 2 m/s^2 circle (3 m/s, 0.67 rad/s), 100 Hz IMU,
    10 Hz GNSS velocity with v_sigma m/s of white noise; and an Estimate of its exact
    attitude but for a heading psi0 rad off (as [mekf]'s without a magnetometer is)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 20.0, 0.01)
    w, r = 2.0 / 3.0, 3.0  # rad/s; velocity radius m/s
    a_n = np.stack([-r * w * np.sin(w * t), r * w * np.cos(w * t), np.zeros_like(t)], axis=1)
    f_b = a_n - np.array([0.0, 0.0, 9.80665])  # heading 0, level: body = nav
    imu_flight = wa.Flight.from_arrays(t, np.zeros((len(t), 3)), f_b)
    tg = t[::10]
    v = np.stack([r * np.cos(w * tg), r * np.sin(w * tg), np.zeros_like(tg)], axis=1)
    flight = imu_flight.replace(gnss=GnssStream(t=tg, v_n=v + v_sigma * rng.standard_normal(v.shape)))
    q = np.tile([np.cos(-psi0 / 2), 0.0, 0.0, np.sin(-psi0 / 2)], (len(t), 1))
    return flight, Estimate(filter="x", t=t, q_nb=q)


def test_gnss_heading_matches_the_velocity_changes_and_says_how_well() -> None:
    psi0 = np.radians(-120.0)
    flight, est = _circling(psi0, 0.0)
    h = gnss_heading(flight, est)
    assert h is not None and len(h.t) == 199
    err = np.degrees(np.angle(np.exp(1j * (h.psi - psi0))))
    assert np.all(np.abs(err) < 0.01)  # noiseless: from the first interval (the integration's error alone)
    # with 0.1 m/s of GNSS noise: its sigma falls as the intervals add up, and tells the error
    flight, est = _circling(psi0, 0.1, seed=1)
    h = gnss_heading(flight, est)
    assert h is not None
    err = np.degrees(np.angle(np.exp(1j * (h.psi - psi0))))
    s = np.degrees(h.sigma)
    assert s[-1] < s[20] < s[5] < 15.0  # (0.14 m/s of noise on 0.2 m/s changes: 0.7 rad / sqrt(k))
    assert np.all(np.abs(err[10:]) < 3.0 * s[10:])
    j = aligned_index(h)
    assert j == ALIGN_MIN_INTERVALS - 1  # the first row on enough intervals, its sigma already under 15 deg
    assert aligned_index(h, sigma=np.radians(1e-3)) is None
    # at rest nothing is matched: no horizontal acceleration, sigma never falls
    still = flight.replace(gnss=GnssStream(t=flight.gnss.t, v_n=np.zeros_like(flight.gnss.v_n)))
    rest = Estimate(filter="x", t=est.t, q_nb=est.q_nb)
    from windahrs.flight import ImuStream

    still = still.replace(imu=ImuStream(t=still.imu.t, w_b=still.imu.w_b,
                                        f_b=np.tile([0.0, 0.0, -9.80665], (len(still.imu.t), 1))))
    h = gnss_heading(still, rest)
    assert h is not None and aligned_index(h) is None
    assert gnss_heading(flight.replace(gnss=None), est) is None


def test_lane_scores_sum_the_nis_from_a_time_a_rejected_sample_at_the_gate() -> None:
    from types import SimpleNamespace

    from windahrs.estimate import Innovations

    t = np.arange(0.0, 2.0, 0.1)
    inn = Innovations(t=np.array([0.25, 0.55, 0.85, 1.15, 1.45]), nu=np.zeros((5, 3)),
                      nis=np.array([3.0, 30.0, np.nan, 6.0, 400.0]),
                      accepted=np.array([True, False, True, True, True]))
    est = SimpleNamespace(t=t, innovations={"gnss": inn})
    s = lane_scores(est, 0.5, 25.0)  # type: ignore[arg-type]
    # from 0.5 s: the rejected 30 counts as every component at the gate (3 x 25), the NaN as
    # nothing, 6 as itself, an accepted 400 at most 3 x 25; the 0.25 one is before 0.5 s
    expect = np.select([t >= 1.45, t >= 1.15, t >= 0.55], [75.0 + 6.0 + 75.0, 75.0 + 6.0, 75.0], 0.0)
    np.testing.assert_array_equal(s, expect)
    assert not lane_scores(est, 0.0, 25.0, "mag").any()  # type: ignore[arg-type]


def test_the_lane_moves_only_once_the_likelihood_ratio_passes_its_bound() -> None:
    # half the difference of the scores is the log-likelihood ratio (b's favour when positive)
    llr = np.array([0.0, 2.0, 3.5, 1.0, -2.0, -3.5, 0.5, 3.0])
    a, b = 2.0 * llr, np.zeros_like(llr)
    on_b = lane_choice(a, b)
    bound = LANE_SWITCH_LLR  # ln 19
    assert 2.9 < bound < 3.0
    np.testing.assert_array_equal(on_b, [False, False, True, True, True, False, False, True])
    np.testing.assert_array_equal(lane_choice(a, b, start_b=True), [True, True, True, True, True, False, False, True])
    assert not lane_choice(np.zeros(3), np.zeros(3)).any()  # even evidence: where it started


def test_two_lanes_make_one_estimate_by_sample_with_their_logs() -> None:
    from windahrs.estimate import Innovations

    t = np.arange(10.0)

    def run(c: float, extra: str | None = None) -> Estimate:
        q = np.tile([np.cos(c), 0.0, 0.0, np.sin(c)], (10, 1))
        inn = Innovations(t=t + 0.5, nu=np.full((10, 3), c), nis=np.full(10, c), accepted=np.ones(10, bool))
        inns = {"gnss": inn, **({extra: inn} if extra else {})}
        return Estimate(filter="x", t=t, q_nb=q, gyro_bias_b=np.full((10, 3), c), v_n=np.full((10, 3), c),
                        wind_n=np.full((10, 3), -c), cov=np.full((5, 3, 3), c), cov_index=np.arange(0, 10, 2),
                        state_labels=("att_x", "att_y", "att_z"), innovations=inns,
                        resets={"gnss": np.array([[2.5, c, 1.0], [7.5, c, 1.0]])})
    use_b = t >= 5
    a, b = run(1.0, "only_a"), run(2.0, "only_b")
    out = _lanes(a, b, use_b)
    np.testing.assert_array_equal(out.q_nb, np.where(use_b[:, None], b.q_nb, a.q_nb))
    for name, sign in (("gyro_bias_b", 1.0), ("v_n", 1.0), ("wind_n", -1.0)):
        np.testing.assert_array_equal(getattr(out, name)[:, 0], sign * np.where(use_b, 2.0, 1.0))
    np.testing.assert_array_equal(out.cov[:, 0, 0], [1.0, 1.0, 1.0, 2.0, 2.0])  # rows at samples 0, 2, .., 8
    np.testing.assert_array_equal(out.innovations["gnss"].nis, np.where(use_b, 2.0, 1.0))  # logged at t + 0.5
    # a log one run kept: its rows where that run is taken
    np.testing.assert_array_equal(out.innovations["only_a"].t, t[:5] + 0.5)
    np.testing.assert_array_equal(out.innovations["only_b"].t, t[5:] + 0.5)
    np.testing.assert_array_equal(out.resets["gnss"][:, 1], [1.0, 2.0])


def test_without_a_magnetometer_the_ins_starts_again_from_the_heading_gnss_velocity_matches() -> None:
    """ANSFL path_16: the INS, started with its heading unknown, claimed it to 15 deg at 1.6 s
    while about 110 deg off and stayed 20 deg off in tilt for 8 s (docs/RESULTS.md section 40).
    auto also runs the INS from the heading that the GNSS velocity changes match against
    [mekf]'s attitude, replayed from the start once matched, and takes that run while its GNSS
    innovations sum smaller: here for most of the flight, and its tilt is then no worse than
    [mekf]'s, the better of the two single estimators on this flight."""
    from windahrs.experiments.benchdata import aligned_recordings
    from windahrs.metrics import attitude_errors

    root = require_data("ansfl", "Horizontal", "path_16")
    ((_, flight, scored),) = list(aligned_recordings(root))
    est, mekf, ins = _runs(flight, "auto", "mekf", "ins-wind")
    assert est.meta["auto_heading_matched_s"] < 3.0 and est.meta["auto_matched_share"] > 0.5
    assert "the INS also ran from the heading GNSS velocity matched then" in est.meta["auto_reason"]

    def tilt(e: Estimate) -> float:
        x = attitude_errors(e, scored).tilt[50:]
        return float(np.degrees(np.sqrt(np.mean(x[np.isfinite(x)] ** 2))))

    assert tilt(est) <= tilt(mekf) < tilt(ins)
    # the matched run, made here from its parts: where it is taken (and its GNSS gate open),
    # the output is it
    (alone,) = _runs(flight.replace(gnss=None), "mekf")
    h = gnss_heading(flight, alone)
    assert h is not None
    j = aligned_index(h)
    assert j is not None and est.meta["auto_heading_matched_s"] == pytest.approx(h.t[j] - flight.imu.t[0], abs=1e-3)
    init_att = make_estimator("ins-wind").params.init_att  # (the matched start's tilt no surer than the INS's own)
    q0 = _about_vertical(alone.q_nb[0], float(h.psi[j]))
    start = InitialState(q_nb=q0, sigma_att=max(float(h.sigma[j]), init_att))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        matched = make_estimator("ins-wind").run(flight, initial=start)
    # the lanes start on the first run when it had claimed its heading by the match (here
    # 2.5 ms before it), and the matched run outweighs it soon after
    k = handover_index(ins)
    first_knew = k is not None and k <= int(np.searchsorted(ins.t, h.t[j]))
    use = lane_choice(lane_scores(ins, h.t[j], 25.0), lane_scores(matched, h.t[j], 25.0), start_b=not first_knew)
    use &= ins.t >= h.t[j]
    assert est.meta["auto_matched_share"] == pytest.approx(use.mean(), abs=1e-3)
    own = use & ~gate_closed(_lanes(ins, matched, use))
    assert own.mean() > 0.5
    np.testing.assert_array_equal(est.q_nb[own], matched.q_nb[own])
