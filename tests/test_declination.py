"""The site's magnetic declination: Site.declination, the autopilot readers that take it
from the log's parameters, and the estimators that turn the field they learn by it so that
their heading is true (as an autopilot's reference is) when the field itself is unknown."""

from __future__ import annotations

import math

import numpy as np
import pytest

import windahrs as wa
from synthetic_logs import dataflash_bytes, ulog_bytes
from windahrs.conventions import MAG_DALIAN_N
from windahrs.flight import FlightError, Site
from windahrs.io import read_flight
from windahrs.metrics import attitude_errors
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.store import load_flight, save_flight

DALIAN_DECL = math.atan2(MAG_DALIAN_N[1], MAG_DALIAN_N[0])  # -8.0 deg


def test_site_declination_is_derived_from_the_field_and_checked() -> None:
    assert Site(mag_n=MAG_DALIAN_N).declination == pytest.approx(DALIAN_DECL, abs=1e-15)
    assert Site(mag_n=MAG_DALIAN_N, declination=DALIAN_DECL + 1e-4).declination == pytest.approx(DALIAN_DECL)
    assert Site().declination is None
    assert Site(declination=0.1).declination == 0.1
    with pytest.raises(FlightError, match=r"site.declination.*-8.0.*-3.0"):
        Site(mag_n=MAG_DALIAN_N, declination=math.radians(-3.0))
    for bad in (True, "0.1", math.nan, math.inf, 4.0):
        with pytest.raises(FlightError, match="site.declination"):
            Site(declination=bad)  # type: ignore[arg-type]


def test_declination_survives_the_store(tmp_path) -> None:
    fl = simulate(make_scenario("fixedwing", wind=0.0, duration=2.0), np.random.default_rng(0))
    fl = fl.replace(site=Site(declination=0.2))
    save_flight(fl, tmp_path / "f.h5")
    assert load_flight(tmp_path / "f.h5").site.declination == 0.2


@pytest.mark.parametrize(("decl", "expected"), [(3.5, math.radians(3.5)), (0.0, None), (None, None)])
def test_ulog_site_takes_ekf2_mag_decl(tmp_path, decl, expected) -> None:
    path = tmp_path / "log.ulg"
    path.write_bytes(ulog_bytes(decl_deg=decl))
    fl = read_flight(path)
    if expected is None:
        assert fl.site.declination is None
        assert "site.declination_param" not in fl.meta
    else:
        assert fl.site.declination == pytest.approx(expected, rel=1e-6)  # (a float32 parameter)
        assert fl.meta["site.declination_param"] == "EKF2_MAG_DECL"
    assert fl.site.mag_n is None


def test_dataflash_site_takes_compass_dec(tmp_path) -> None:
    path = tmp_path / "log.bin"
    path.write_bytes(dataflash_bytes(decl_rad=-0.15))
    fl = read_flight(path)
    assert fl.site.declination == pytest.approx(-0.15, rel=1e-6)
    assert fl.meta["site.declination_param"] == "COMPASS_DEC"
    path.write_bytes(dataflash_bytes())
    assert read_flight(path).site.declination is None


@pytest.fixture(scope="module")
def level_flight() -> wa.Flight:
    """A simulated quadrotor at Dalian (declination -8.0 deg), truth in true NED."""
    return simulate(make_scenario("quadrotor", wind=0.0, duration=30.0), np.random.default_rng(4))


def _heading_error_deg(spec: str, flight: wa.Flight) -> float:
    est = wa.estimator(spec).run(flight)
    e = attitude_errors(est, flight)
    yaw = e.euler[e.t > 10.0, 2]
    return math.degrees(math.atan2(np.mean(np.sin(yaw)), np.mean(np.cos(yaw))))


@pytest.mark.parametrize("spec", ["mekf", "paper-nowind", "usque", "vqf"])
def test_estimators_turn_a_learned_field_by_the_site_declination(level_flight, spec) -> None:
    """With the field unknown, the heading is magnetic without the declination and true
    with it: the two differ by the declination (up to how the filter's own heading error
    on this flight, a few degrees with a field learned from the data, moves with it)."""
    if spec == "vqf":
        pytest.importorskip("vqf", reason="the vqf baseline is not installed")
    magnetic = _heading_error_deg(spec, level_flight.replace(site=Site()))
    true = _heading_error_deg(spec, level_flight.replace(site=Site(declination=DALIAN_DECL)))
    assert magnetic - true == pytest.approx(math.degrees(-DALIAN_DECL), abs=0.3)
    assert abs(true) < abs(magnetic) - 4.0


def _csv_dir(tmp_path, flight_keys: str):
    d = tmp_path / "rec"
    d.mkdir(exist_ok=True)
    t = np.arange(20) * 0.01
    rows = "\n".join(f"{x:.2f},0,0,0,0,0,-9.80665" for x in t)
    (d / "imu.csv").write_text("t,wx,wy,wz,ax,ay,az\n" + rows + "\n")
    (d / "windahrs.toml").write_text(
        'format = "windahrs.csv"\nversion = 1\n[flight]\n' + flight_keys + "\n"
        '[imu]\nfile = "imu.csv"\ntime = "t"\ntime_unit = "s"\ngyro = ["wx", "wy", "wz"]\n'
        'gyro_unit = "rad/s"\naccel = ["ax", "ay", "az"]\naccel_unit = "m/s^2"\n'
    )
    return d


def test_csv_manifest_declination(tmp_path) -> None:
    assert read_flight(_csv_dir(tmp_path, "declination_deg = -9.5")).site.declination == pytest.approx(
        math.radians(-9.5)
    )
    for bad in ('"east"', "true", "200.0", "nan"):
        with pytest.raises(wa.io.LogFormatError, match=r"'flight.declination_deg'.*expected degrees"):
            read_flight(_csv_dir(tmp_path, f"declination_deg = {bad}"))
    # given with the field, the two must agree: the error names the field and both values
    with pytest.raises(FlightError, match=r"windahrs.toml.*site.declination.*-8.0.*5.0"):
        read_flight(_csv_dir(tmp_path, "mag_n = [28632e-9, -4032e-9, 44583e-9]\ndeclination_deg = 5.0"))


def test_ulog_mag_less_ekf2_saved_bias_for_its_device(tmp_path) -> None:
    """PX4 EKF2 (1.12 and before) fuses vehicle_magnetometer less its saved learned bias
    EKF2_MAGBIAS_* when EKF2_MAGBIAS_ID is the device: the reader does the same, and only then."""
    path = tmp_path / "log.ulg"
    path.write_bytes(ulog_bytes())
    plain = read_flight(path)
    assert plain.mag is not None and "mag.ekf2_bias_subtracted" not in plain.meta
    bias = (0.05, -0.02, 0.1)
    path.write_bytes(ulog_bytes(mag_bias_ga=bias))
    fl = read_flight(path)
    assert fl.meta["mag.ekf2_bias_subtracted"] is True
    np.testing.assert_allclose(fl.mag.mag_b, plain.mag.mag_b - np.array(bias) * 1e-4, rtol=0, atol=1e-11)
    path.write_bytes(ulog_bytes(mag_bias_ga=bias, mag_bias_id=8))  # learned on another device
    other = read_flight(path)
    np.testing.assert_array_equal(other.mag.mag_b, plain.mag.mag_b)
    assert "mag.ekf2_bias_subtracted" not in other.meta
