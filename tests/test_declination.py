"""The site's magnetic declination: Site.declination, the autopilot readers that take it
from the log's parameters, and the estimators that turn the field they learn by it so that
their heading is true (as an autopilot's reference is) when the field itself is unknown."""

from __future__ import annotations

import json
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


def test_with_declination_sets_replaces_and_checks(tmp_path) -> None:
    """windahrs.flight.with_declination (the command line's --declination): sets the site's
    declination and says where it came from, replaces a log's, and is refused against a
    known field that disagrees (Site's check) or when not finite or beyond +-180."""
    from windahrs.flight import with_declination

    path = tmp_path / "log.ulg"
    path.write_bytes(ulog_bytes(decl_deg=3.5))
    fl = with_declination(read_flight(path), -4.0, source="--declination")
    assert fl.site.declination == pytest.approx(math.radians(-4.0))
    assert fl.meta["site.declination_param"] == "--declination"
    assert fl.meta["site.declination_replaced"] == "EKF2_MAG_DECL: +3.500 deg"
    for bad in (math.nan, math.inf, 200.0, -180.5, "x", True):
        with pytest.raises(FlightError, match="^--declination: expected degrees east"):
            with_declination(fl, bad, source="--declination")  # type: ignore[arg-type]
    known = wa.Flight(imu=fl.imu, site=Site(mag_n=MAG_DALIAN_N))
    assert with_declination(known, -8.05, source="--declination") is known  # within 0.1 deg: the field's own
    with pytest.raises(FlightError, match=r"^--declination: .*site.mag_n \(-8.0\d\d deg.*found \+5.000 deg"):
        with_declination(known, 5.0, source="--declination")


def _yaw_deg(path) -> np.ndarray:
    from windahrs.estimate import load_estimate
    from windahrs.rotation import euler_from_quat

    return np.degrees(euler_from_quat(load_estimate(path).q_nb)[:, 2])


def test_cli_declination_turns_the_heading(tmp_path, capsys) -> None:
    """On a log without a declination, estimate --declination 10 heads 10 deg east of the
    same run without it; info says where the declination came from."""
    from windahrs.cli import main

    log = tmp_path / "log.ulg"
    log.write_bytes(ulog_bytes())
    assert main(["estimate", str(log), "--filter", "mekf", "--out", str(tmp_path / "mag.h5")]) == 0
    assert main(["estimate", str(log), "--filter", "mekf", "--declination", "10",
                 "--out", str(tmp_path / "true.h5")]) == 0
    turn = np.angle(np.exp(1j * np.radians(_yaw_deg(tmp_path / "true.h5") - _yaw_deg(tmp_path / "mag.h5"))))
    np.testing.assert_allclose(np.degrees(turn), 10.0, atol=0.05)
    capsys.readouterr()
    assert main(["info", str(log), "--declination", "-2.5"]) == 0
    out = capsys.readouterr().out
    assert "declination -2.50 deg" in out and "site.declination_param = --declination" in out


def test_bench_data_declination_applies_to_every_recording(tmp_path, capsys) -> None:
    """bench-data --declination sets every recording's declination; one whose known field
    disagrees is skipped, with the reason naming the option and both values."""
    from windahrs.cli import main

    d = tmp_path / "recs"
    d.mkdir()
    (d / "log.ulg").write_bytes(ulog_bytes())
    sim = simulate(make_scenario("quadrotor", wind=0.0, duration=3.0), np.random.default_rng(0))
    save_flight(sim, d / "sim.h5")  # Dalian's field: -8.0 deg
    assert main(["bench-data", str(d), "--filters", "mekf", "--declination", "5", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert [(t["trial"], "error" in t) for t in res["trials"]] == [("log", False)]
    [skip] = res["skipped"]
    assert skip["path"].endswith("sim.h5")
    assert skip["reason"].startswith("--declination: expected the declination of the flight's known field "
                                     "site.mag_n (-8.0")
    assert skip["reason"].endswith("found +5.000 deg")
