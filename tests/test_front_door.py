"""``import windahrs as wa``: the front door's names, raw arrays to a Flight, estimators
with keyword overrides, streaming with snapshot/restore, simulate and compare."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import windahrs as wa
from windahrs.cli import main
from windahrs.flight import FlightError
from windahrs.rotation import quat_ned_frd_to_enu_flu


@pytest.fixture(scope="module")
def flight() -> wa.Flight:
    return wa.simulate("fixedwing", seed=3, duration=6.0, wind=5.0)


def test_import_does_no_work_and_every_name_resolves() -> None:
    heavy = "('numpy', 'scipy', 'numba', 'windahrs.flight')"
    code = f"import sys, windahrs; print(sorted(m for m in {heavy} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
    for name in wa.__all__:
        assert getattr(wa, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        wa.nope  # noqa: B018


# ---------------------------------------------------------------------------------------
# Flight.from_arrays


def _on_imu_grid(flight: wa.Flight) -> np.ndarray:
    """The magnetometer on the IMU time grid, NaN (missing) between its samples."""
    assert flight.mag is not None
    m = np.full((len(flight.imu.t), 3), np.nan)
    m[np.searchsorted(flight.imu.t, flight.mag.t)] = flight.mag.mag_b
    return m


def test_from_arrays_units_and_frames_give_the_same_flight(flight: wa.Flight) -> None:
    imu = flight.imu
    mag = _on_imu_grid(flight)
    base = wa.Flight.from_arrays(imu.t, imu.w_b, imu.f_b, mag, site=flight.site)
    np.testing.assert_array_equal(base.imu.w_b, imu.w_b)
    flu = np.diag([1.0, -1.0, -1.0])
    other = wa.Flight.from_arrays(
        None, np.degrees(imu.w_b @ flu), imu.f_b @ flu / 9.80665, mag @ flu * 1e4, rate=200.0,
        gyro_units="deg/s", accel_units="g", mag_units="gauss", frame="FLU", site=flight.site,
    )
    np.testing.assert_allclose(other.imu.t, imu.t, atol=1e-12)
    np.testing.assert_allclose(other.imu.w_b, imu.w_b, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(other.imu.f_b, imu.f_b, rtol=1e-12)
    np.testing.assert_allclose(other.mag.mag_b, base.mag.mag_b, rtol=1e-12)  # type: ignore[union-attr]
    assert other.meta["source"] == "arrays"


def test_from_arrays_reference_in_ros_frames_becomes_ned_frd(flight: wa.Flight) -> None:
    assert flight.truth is not None
    imu = flight.imu
    q_ros = quat_ned_frd_to_enu_flu(flight.truth.q_nb)
    f = wa.Flight.from_arrays(imu.t, imu.w_b, imu.f_b, reference=q_ros, frame="FLU", reference_kind="mocap")
    assert f.reference is not None and f.reference.kind == "mocap"
    same = np.abs(np.sum(f.reference.q_nb * flight.truth.q_nb, axis=1))
    np.testing.assert_allclose(same, 1.0, atol=1e-12)


def test_estimate_from_arrays_equals_the_estimate_of_the_flight(flight: wa.Flight) -> None:
    """The magnetometer on the IMU grid with NaN between samples: the same events, so the
    same attitude bit for bit (the NaN rows are only counted as skipped)."""
    imu = flight.imu
    raw = wa.Flight.from_arrays(imu.t, imu.w_b, imu.f_b, _on_imu_grid(flight), site=flight.site)
    a, b = wa.estimator("mekf").run(flight), wa.estimator("mekf").run(raw)
    np.testing.assert_array_equal(a.q_nb, b.q_nb)
    assert b.skipped["mag"] == len(imu.t) - len(flight.mag.t)  # type: ignore[union-attr]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"gyro": np.zeros((5, 3)), "accel": np.tile([0, 0, -9.8], (5, 1))},
         "t, rate: expected time stamps t (s) or a sample rate rate (Hz), one of them, found neither"),
        ({"t": np.arange(5.0), "rate": 10.0}, "t, rate: expected time stamps t (s) or a sample rate rate (Hz), "
         "one of them, found both"),
        ({"rate": 10.0, "gyro": None}, "gyro: expected an (N, 3) array, found none"),
        ({"rate": 10.0, "gyro": np.zeros((5, 2))}, "gyro: expected shape (N, 3), found (5, 2)"),
        ({"rate": 10.0, "accel": np.zeros((4, 3))}, "accel: expected 5 rows (one per gyro row), found 4 rows"),
        ({"rate": 10.0, "gyro": np.full((5, 3), np.nan)},
         "gyro: expected at least one finite sample, found only NaN in 5 rows"),
        ({"rate": 10.0, "mag": np.full((5, 3), np.nan)},
         "mag: expected at least one finite sample, found only NaN in 5 rows"),
        ({"t": [0.0, 0.1, 0.1, 0.3, 0.4], "strict": True},
         "t: expected strictly increasing time, found t[1] = 0.1 then t[2] = 0.1"),
        ({"t": [0.0, 0.1, 0.2, 0.3, np.inf], "strict": True},
         "t: expected finite values or NaN for a missing sample, found inf at row 4"),
        ({"t": np.arange(4.0)}, "t: expected 5 time stamps (one per gyro row), found 4"),
        ({"rate": -1.0}, "rate: expected a sample rate > 0 Hz, found -1.0"),
        ({"rate": 10.0, "gyro_units": "rpm"}, "gyro_units: expected one of 'rad/s', 'deg/s', found 'rpm'"),
        ({"rate": 10.0, "frame": "NWU"}, "frame: expected 'FRD' or 'FLU', found 'NWU'"),
        ({"rate": 10.0, "accel": np.tile([0.0, 0.0, -1.0], (5, 1))},
         "accel: expected m/s^2 (median |f| between 2 and 300), found 1: in g? pass accel_units='g'"),
        ({"rate": 10.0, "gyro": np.full((5, 3), 90.0)},
         "gyro: expected rad/s (|component| within 38.4 rad/s on 99 % of the samples), found 100 % beyond, "
         "max 90: deg/s? pass gyro_units='deg/s'"),
        ({"rate": 10.0, "mag": np.full((5, 3), 30.0)},
         "mag: expected tesla (median |m| between 1e-7 and 1e-2), found 51.96: in microtesla? pass mag_units='uT'"),
    ],
)
def test_from_arrays_bad_input_names_the_field(kwargs: dict[str, object], message: str) -> None:
    args: dict[str, object] = {"gyro": np.zeros((5, 3)), "accel": np.tile([0.0, 0.0, -9.8], (5, 1))}
    args.update(kwargs)
    with pytest.raises(FlightError) as info:
        wa.Flight.from_arrays(**args)  # type: ignore[arg-type]
    assert message in str(info.value)


# ---------------------------------------------------------------------------------------
# estimator, stream, snapshot / restore


def test_estimator_keyword_overrides(flight: wa.Flight) -> None:
    from windahrs.filters.registry import make_estimator

    est = wa.estimator("mekf", accel_sigma=0.5, mag_mode="heading")
    ref = make_estimator("mekf:accel_sigma=0.5:mag_mode=heading")
    assert type(est) is type(ref) and est.params == ref.params  # type: ignore[attr-defined]
    assert est.label == "mekf:accel_sigma=0.5:mag_mode=heading"
    assert wa.estimator("paper:wind=mean").label == "paper:wind=mean"
    with pytest.raises(ValueError) as mine:
        wa.estimator("mekf", nope=1)
    with pytest.raises(ValueError) as registry:
        make_estimator("mekf:nope=1")
    assert str(mine.value) == str(registry.value)
    with pytest.raises(ValueError, match="unknown 'nope'; known filters"):
        wa.estimator("nope")


def _events(flight: wa.Flight, est: wa.Estimator) -> tuple[np.ndarray, np.ndarray, np.ndarray, frozenset[str]]:
    from windahrs.filters.base import merge_events

    has = frozenset(s for s in ("imu", "mag", "gnss", "air") if getattr(flight, s) is not None) & est.uses
    return (*merge_events(flight, has), has)


def _feed(s: wa.Streamer, t: np.ndarray, kinds: np.ndarray, vals: np.ndarray, a: int, b: int) -> None:
    for i in range(a, b):
        s.push(int(kinds[i]), float(t[i]), vals[i])


def _assert_same(a: wa.Streamer, b: wa.Streamer) -> None:
    sa, sb = a.state, b.state
    assert sa.t == sb.t
    np.testing.assert_array_equal(sa.q_nb, sb.q_nb)
    for x, y in ((sa.cov, sb.cov), (sa.gyro_bias_b, sb.gyro_bias_b), (sa.wind_n, sb.wind_n)):
        assert (x is None) == (y is None)
        if x is not None:
            np.testing.assert_array_equal(x, y)
    ia, ib = a.innovations(), b.innovations()
    assert ia.keys() == ib.keys()
    for k in ia:
        np.testing.assert_array_equal(ia[k].nu, ib[k].nu)
        np.testing.assert_array_equal(ia[k].nis, ib[k].nis)
    assert a.skipped == b.skipped


@pytest.mark.parametrize("name", ["mekf", "ins-wind", "vqf", "madgwick"])
def test_snapshot_restore_continues_bit_for_bit(flight: wa.Flight, name: str) -> None:
    if name == "vqf":
        pytest.importorskip("vqf", reason="vqf is an optional baseline (pip install 'windahrs[baselines]')")
    if name == "madgwick":
        pytest.importorskip("ahrs", reason="ahrs is an optional baseline (pip install 'windahrs[baselines]')")
    est = wa.estimator(name)
    t, kinds, vals, has = _events(flight, est)
    half = len(t) // 2
    straight = est.stream(flight.site, has=has)
    _feed(straight, t, kinds, vals, 0, len(t))
    s = est.stream(flight.site, has=has)
    _feed(s, t, kinds, vals, 0, half)
    snap = s.snapshot()
    before = snap.state.q_nb.copy()
    _feed(s, t, kinds, vals, half, half + 400)  # wander off, then come back
    np.testing.assert_array_equal(snap.state.q_nb, before)  # the snapshot is independent
    s.restore(snap)
    _feed(s, t, kinds, vals, half, len(t))
    _assert_same(straight, s)
    s.restore(snap)  # a snapshot can be restored again
    _feed(s, t, kinds, vals, half, len(t))
    _assert_same(straight, s)


def test_stream_defaults_equal_run_and_restore_checks_the_type(flight: wa.Flight) -> None:
    est = wa.estimator("mekf")
    t, kinds, vals, _ = _events(flight, est)
    s = est.stream(flight.site)  # has: every stream mekf uses, all present here
    _feed(s, t, kinds, vals, 0, len(t))
    np.testing.assert_array_equal(s.state.q_nb, est.run(flight).q_nb[-1])
    with pytest.raises(ValueError, match="snapshot: expected a snapshot of a CompiledStreamer"):
        s.restore(wa.estimator("madgwick").stream())
    with pytest.raises(ValueError, match=r"has: expected stream names .* found \['gps'\]"):
        est.stream(has={"imu", "gps"})


# ---------------------------------------------------------------------------------------
# simulate, read, compare


def test_simulate_seed_or_rng() -> None:
    a = wa.simulate("paper", seed=7, duration=1.0, wind=5.0)
    b = wa.simulate("paper", rng=np.random.default_rng(7), duration=1.0, wind=5.0)
    np.testing.assert_array_equal(a.imu.w_b, b.imu.w_b)
    assert a.meta["seed"] == 7 and a.meta["vehicle"] == "paper"
    from windahrs.sim.scenario import make_scenario

    c = wa.simulate(make_scenario("paper", wind=5.0, duration=1.0), seed=7)
    np.testing.assert_array_equal(a.imu.f_b, c.imu.f_b)
    with pytest.raises(ValueError, match="seed, rng: expected one .* found neither"):
        wa.simulate("paper")
    with pytest.raises(ValueError, match="found both"):
        wa.simulate("paper", seed=1, rng=np.random.default_rng(1))
    with pytest.raises(ValueError, match="wind: expected to be set in the Scenario object"):
        wa.simulate(make_scenario("paper"), seed=1, wind=3.0)
    with pytest.raises(ValueError, match="vehicle: expected one of"):
        wa.simulate("blimp", seed=1)


def test_compare_is_what_the_command_prints(flight: wa.Flight, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    from windahrs.store import save_flight

    path = save_flight(flight, tmp_path / "f.h5")
    read = wa.read(path)
    np.testing.assert_array_equal(read.imu.w_b, flight.imu.w_b)
    specs = ["mekf", "ins-wind", "paper:wind=mean"]
    res = wa.compare(path, specs)
    assert [r.filter for r in res.rows] == specs and [s for s, _ in res.estimates] == specs
    capsys.readouterr()
    assert main(["compare", str(path), "--filters", ",".join(specs)]) == 0
    assert capsys.readouterr().out == str(res) + "\n"
    assert str(res) == res.table()  # no alignment line on a simulation's truth
    assert main(["compare", str(path), "--filters", "mekf,ins-wind", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == wa.compare(flight, "mekf,ins-wind").as_json()
    assert wa.score(res.estimates[0][1], flight) == res.rows[0]
