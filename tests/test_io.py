"""Log readers: real recordings parse into the documented streams, frames and signs are
right (checked against physics, not only against the code), the generic CSV format
round-trips, and every malformed input gives LogFormatError or FlightError naming the file.

Real-data tests read $WINDAHRS_DATA (default ../shared/data) and skip where it is absent.
"""

from __future__ import annotations

import csv
import math
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import require_data
from synthetic_logs import ulog_bytes
from windahrs.conventions import DEG, G0
from windahrs.flight import (
    AirDataStream,
    Flight,
    FlightError,
    GnssStream,
    ImuStream,
    MagStream,
    Reference,
    WindStream,
)
from windahrs.io import (
    FORMATS,
    LogFormatError,
    broad_movement_mask,
    detect_format,
    read_alfa,
    read_broad,
    read_csv_dir,
    read_dataflash,
    read_flight,
    read_ulog,
)
from windahrs.io.edge import TruncatedLogWarning
from windahrs.repair import clean_series
from windahrs.rotation import (
    euler_from_quat,
    quat_angle,
    quat_exp,
    quat_from_euler,
    quat_ned_frd_to_enu_flu,
    quat_rotate,
    vec_ned_to_enu,
)
from windahrs.store import save_flight

ALFA_SEQ = "carbonZ_2018-07-18-15-53-31_1_engine_failure"
BROAD_TRIALS = (
    "02_undisturbed_slow_rotation_B.hdf5",
    "07_undisturbed_fast_rotation_B.hdf5",
    "10_undisturbed_slow_translation_A.hdf5",
    "15_undisturbed_fast_translation_A.hdf5",
    "24_disturbed_tapping_A.hdf5",
    "30_disturbed_stationary_magnet_C.hdf5",
    "32_disturbed_attached_magnet_1cm.hdf5",
)


def mean_rate(t: np.ndarray) -> float:
    return (len(t) - 1) / float(t[-1] - t[0])


def nearest(t_ref: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index of the reference sample nearest to each time in ``t``."""
    k = np.clip(np.searchsorted(t_ref, t), 1, len(t_ref) - 1)
    return np.where(np.abs(t_ref[k - 1] - t) < np.abs(t_ref[k] - t), k - 1, k)


def specific_force_nav(flight: Flight) -> np.ndarray:
    """IMU specific force rotated to NED with the reference attitude nearest in time."""
    ref = flight.reference
    assert ref is not None
    q = ref.q_nb[nearest(ref.t, flight.imu.t)]
    ok = np.isfinite(q).all(axis=1) & np.isfinite(flight.imu.f_b).all(axis=1)
    return quat_rotate(q[ok], flight.imu.f_b[ok])


# --- PX4 ULog --------------------------------------------------------------------------


def test_ulog_sample_quadrotor() -> None:
    f = read_ulog(require_data("px4", "sample.ulg"))
    assert mean_rate(f.imu.t) == pytest.approx(248.0, abs=1.0)
    assert f.duration == pytest.approx(69.0, abs=0.5)
    assert f.mag is not None and f.meta["mag.topic"] == "sensor_combined.magnetometer_ga"
    # Gauss -> tesla: a field of 20-70 uT (MagStream would reject gauss outright).
    assert 20e-6 < np.median(np.linalg.norm(f.mag.mag_b, axis=1)) < 70e-6
    assert f.reference is not None and f.reference.kind == "autopilot"
    assert f.gnss is None and f.air is None and f.ref_wind is None
    assert f.meta["start_time_us"] == 112500176
    assert f.meta["ulog.dropouts"] == 4
    # FRD/NED and the w,x,y,z order: the mean specific force in NED is "up", -g.
    f_n = specific_force_nav(f).mean(axis=0)
    np.testing.assert_allclose(f_n, [0.0, 0.0, -G0], atol=0.35)
    roll = euler_from_quat(f.reference.q_nb)[:, 0]
    assert np.nanmax(np.abs(roll)) < 25 * DEG  # README: roll within +-22 deg


def test_ulog_small_vtol_air_data_topics() -> None:
    f = read_ulog(require_data("px4", "sample_log_small.ulg"))
    assert f.air is not None and f.gnss is not None and f.ref_wind is not None
    assert f.mag is not None and f.meta["mag.topic"] == "vehicle_magnetometer[0]"
    assert f.meta["air.topic"] == "airspeed_validated[0]"
    assert not f.air.has_vanes
    # On the ground: the airspeed reads a small negative offset, the wind estimate is 0.
    assert np.all(np.abs(f.air.tas) < 5.0)
    np.testing.assert_array_equal(f.ref_wind.wind_n, 0.0)
    assert np.all(np.linalg.norm(f.gnss.v_n, axis=1) < 1.0)
    assert f.duration == pytest.approx(6.5, abs=0.1)  # not the header's 19 min
    assert f.meta["param.EKF2_GYR_NOISE"] == 0.015
    raw = read_ulog(require_data("px4", "sample_log_small.ulg"), air_topic="airspeed")
    assert raw.air is not None and mean_rate(raw.air.t) > 50.0


def test_ulog_sitl_has_truth_reference() -> None:
    f = read_ulog(require_data("px4", "sample_logging_tagged_and_default_params.ulg"))
    assert f.reference is not None and f.reference.kind == "truth"
    assert f.meta["reference.topic"] == "vehicle_attitude_groundtruth[0]"
    assert f.gnss is not None and f.mag is not None
    np.testing.assert_allclose(specific_force_nav(f).mean(axis=0), [0, 0, -G0], atol=0.2)


def test_ulog_duplicates_dropped_and_counted(tmp_path: Path) -> None:
    pyulog = pytest.importorskip("pyulog")
    ulog = pyulog.ULog(str(require_data("px4", "sample.ulg")))
    sc = next(d for d in ulog.data_list if d.name == "sensor_combined")
    sc.data["timestamp"][11] = sc.data["timestamp"][10]
    sc.data["timestamp"][21] = sc.data["timestamp"][20]
    out = tmp_path / "dup.ulg"
    ulog.write_ulog(str(out))
    f = read_ulog(out)
    assert f.repairs["imu"]["duplicates"] == 2
    assert len(f.imu.t) == len(sc.data["timestamp"]) - 2


def test_ulog_multi_instance_topics_pick_the_asked_instance(tmp_path: Path) -> None:
    """Two vehicle_magnetometer instances: multi_id picks one (meta names it); a topic
    without that instance (here every other one) falls back to its lowest instance."""
    path = tmp_path / "two_mags.ulg"
    path.write_bytes(ulog_bytes(second_mag=True))
    first, second = read_ulog(path), read_ulog(path, multi_id=1)
    assert first.mag is not None and second.mag is not None
    assert first.meta["mag.topic"] == "vehicle_magnetometer[0]"
    assert second.meta["mag.topic"] == "vehicle_magnetometer[1]"
    np.testing.assert_allclose(first.mag.mag_b[0], np.array([0.2, 0.02, 0.4]) * 1e-4, rtol=1e-6)
    np.testing.assert_allclose(second.mag.mag_b[0], np.array([0.1, 0.0, 0.5]) * 1e-4, rtol=1e-6)
    assert second.meta["imu.topic"] == "sensor_combined[0]"  # no instance 1: the lowest
    np.testing.assert_array_equal(first.imu.f_b, second.imu.f_b)


def test_ulog_missing_topic_names_file_and_topic(tmp_path: Path) -> None:
    pyulog = pytest.importorskip("pyulog")
    ulog = pyulog.ULog(str(require_data("px4", "sample.ulg")))
    ulog.data_list[:] = [d for d in ulog.data_list if d.name != "sensor_combined"]
    out = tmp_path / "no_imu.ulg"
    ulog.write_ulog(str(out))
    with pytest.raises(LogFormatError, match="sensor_combined") as exc:
        read_flight(out)
    assert "no_imu.ulg" in str(exc.value)


def test_clean_series_sorts_and_keeps_first() -> None:
    t = np.array([0, 2, 1, 3, 3, 4])
    v = np.array([10.0, 12.0, 11.0, 13.0, 99.0, 14.0])
    t2, (v2,), counts = clean_series(t, v)
    np.testing.assert_array_equal(t2, [0, 1, 2, 3, 4])
    np.testing.assert_array_equal(v2, [10, 11, 12, 13, 14])
    assert counts == {"unsortable": 0, "reordered": 2, "duplicates": 1}
    # a non-finite stamp cannot be placed in time: dropped and counted
    _, (v3,), counts = clean_series(np.array([0.0, np.nan, 1.0]), np.array([1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(v3, [1.0, 3.0])
    assert counts == {"unsortable": 1, "reordered": 0, "duplicates": 0}


# --- BROAD -----------------------------------------------------------------------------


@pytest.mark.parametrize("trial", BROAD_TRIALS)
def test_broad_trial(trial: str) -> None:
    path = require_data("broad", trial)
    f = read_broad(path)
    assert mean_rate(f.imu.t) == pytest.approx(285.714, abs=0.01)
    assert f.mag is not None and f.gnss is None and f.air is None
    ref = f.reference
    assert ref is not None and ref.kind == "mocap" and ref.heading_free
    gaps = int((~np.isfinite(ref.q_nb).all(axis=1)).sum())
    assert gaps == f.meta["reference.gaps"] > 0
    assert gaps / len(ref.t) < 0.10  # 0.08 % (trial 10) to 8.4 % (trial 24)
    assert ref.mask is not None
    np.testing.assert_array_equal(ref.mask, broad_movement_mask(path))
    # microtesla -> tesla (|B| in Berlin about 50 uT; magnets disturb trials 30 and 32).
    assert 30e-6 < np.median(np.linalg.norm(f.mag.mag_b, axis=1)) < 70e-6
    # ENU -> NED of the reference frame: at rest or moving, the mean specific force is up.
    np.testing.assert_allclose(specific_force_nav(f).mean(axis=0), [0, 0, -G0], atol=0.3)
    everything = read_broad(path, score="all").reference
    assert everything is not None and everything.mask is None


# --- ALFA (mavros CSV) -------------------------------------------------------------------


def alfa_column(name: str, col: str) -> tuple[np.ndarray, np.ndarray]:
    path = require_data("alfa", ALFA_SEQ, name)
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    return (
        np.array([int(r["%time"]) for r in rows]),
        np.array([float(r[col]) for r in rows]),
    )


def test_alfa_streams_and_failure_time() -> None:
    f = read_flight(require_data("alfa", ALFA_SEQ))
    assert f.meta["format"] == "alfa"
    assert f.air is not None and f.gnss is not None and f.ref_wind is not None
    assert f.mag is not None
    assert f.reference is not None and f.reference.kind == "autopilot"
    assert f.meta["failure_time"] == pytest.approx(116.0, abs=1.0)
    assert f.duration == pytest.approx(132.0, abs=1.0)
    assert mean_rate(f.imu.t) == pytest.approx(10.0, abs=0.2)
    speed = np.linalg.norm(f.ref_wind.wind_n, axis=1)
    assert 0.5 < speed.mean() < 15.0


def test_alfa_topics_exported_without_a_sample_are_absent(tmp_path: Path) -> None:
    """A topic file with a header and no row (the export of a topic that published nothing)
    is an absent stream, said in a warning and in ``meta["absent_files"]``; an empty failure
    flag is no failure; an IMU file without a row is still an error."""
    d = tmp_path / "seq"
    d.mkdir()
    gyro = [f"field.angular_velocity.{c}" for c in "xyz"]
    accel = [f"field.linear_acceleration.{c}" for c in "xyz"]
    t0 = 1_531_000_000_000_000_000
    rows = [f"{t0 + k * 10_000_000},0,0,0,0,0,9.80665" for k in range(200)]
    (d / "mavros-imu-data_raw.csv").write_text("%time," + ",".join(gyro + accel) + "\n" + "\n".join(rows) + "\n")
    (d / "mavros-imu-mag.csv").write_text("%time," + ",".join(f"field.magnetic_field.{c}" for c in "xyz") + "\n")
    (d / "mavros-nav_info-airspeed.csv").write_text("%time,field.measured\n")
    air = [f"{t0 + k * 100_000_000},15.0" for k in range(20)]
    (d / "mavros-vfr_hud.csv").write_text("%time,field.airspeed\n" + "\n".join(air) + "\n")
    (d / "failure_status-engines.csv").write_text("%time,field.data\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        f = read_alfa(d)
    said = [str(w.message) for w in caught if issubclass(w.category, UserWarning)]
    for name in ("mavros-imu-mag.csv", "mavros-nav_info-airspeed.csv"):
        assert sum(f"{name}: no data rows; read as absent" in m for m in said) == 1, said
    assert f.mag is None and f.air is not None and f.meta["air.file"] == "mavros-vfr_hud.csv"
    assert f.meta["absent_files"] == (
        "mavros-imu-mag.csv: no data rows; mavros-nav_info-airspeed.csv: no data rows"
    )
    assert "failure_time" not in f.meta
    assert not any("failure_status" in m for m in said)
    (d / "mavros-imu-data_raw.csv").write_text("%time," + ",".join(gyro + accel) + "\n")
    with pytest.raises(LogFormatError, match="mavros-imu-data_raw.csv: no data rows"):
        read_alfa(d)


def test_alfa_files_named_as_the_dataset_publishes_them(tmp_path: Path) -> None:
    """The published sequences prefix every topic file with the sequence's name
    (``<seq>-mavros-imu-data_raw.csv``, ``<seq>-failure_status-engines.csv``): the same
    Flight as the bare names give, and found by format detection."""
    bare, named = tmp_path / "bare", tmp_path / "carbonZ_x_engine_failure"
    bare.mkdir()
    named.mkdir()
    gyro = [f"field.angular_velocity.{c}" for c in "xyz"]
    accel = [f"field.linear_acceleration.{c}" for c in "xyz"]
    t0 = 1_531_000_000_000_000_000
    files = {
        "mavros-imu-data_raw.csv": "%time," + ",".join(gyro + accel) + "\n"
        + "\n".join(f"{t0 + k * 10_000_000},0.01,0,0,0,0,9.80665" for k in range(200)) + "\n",
        "mavros-vfr_hud.csv": "%time,field.airspeed\n"
        + "\n".join(f"{t0 + k * 100_000_000},15.0" for k in range(20)) + "\n",
        "failure_status-engines.csv": "%time,field.data\n" + f"{t0 + 1_500_000_000},1\n",
    }
    for name, text in files.items():
        (bare / name).write_text(text)
        (named / f"{named.name}-{name}").write_text(text)
    (named / "other_seq-mavros-imu-data_raw.csv").write_text("not read: named after another sequence")
    assert detect_format(named) == "alfa"
    a, b = read_alfa(bare), read_alfa(named)
    np.testing.assert_array_equal(a.imu.w_b, b.imu.w_b)
    assert a.air is not None and b.air is not None and np.array_equal(a.air.tas, b.air.tas)
    assert b.meta["failure_time"] == a.meta["failure_time"] == pytest.approx(1.5)
    assert b.meta["failure_type"] == "engines" and b.meta["air.file"] == f"{named.name}-mavros-vfr_hud.csv"


def test_alfa_frames_against_physics() -> None:
    f = read_alfa(require_data("alfa", ALFA_SEQ))
    assert f.reference is not None and f.mag is not None and f.gnss is not None
    assert f.air is not None and f.ref_wind is not None
    # FLU -> FRD of the IMU and ENU/FLU -> NED/FRD of the attitude: gravity is "up".
    np.testing.assert_allclose(specific_force_nav(f).mean(axis=0), [0, 0, -G0], atol=0.5)
    # The attitude equals ArduPilot's own NED Euler angles (mavros nav_info, degrees).
    t_ns, roll = alfa_column("mavros-nav_info-roll.csv", "field.measured")
    t_s = (t_ns - f.meta["start_time_ns"]) * 1e-9
    rpy = euler_from_quat(f.reference.q_nb)
    k = nearest(t_s, f.reference.t)
    close = np.abs(t_s[k] - f.reference.t) < 0.03
    assert close.sum() > 50
    err = np.angle(np.exp(1j * (rpy[close, 0] - roll[k[close]] * DEG)))
    assert np.median(np.abs(err)) < 1.0 * DEG
    # Magnetometer scale (mavros logs mG x 1000) and frame: |B| near 50 uT, dip ~60-70 deg.
    q = f.reference.q_nb[nearest(f.reference.t, f.mag.t)]
    m_n = quat_rotate(q, f.mag.mag_b).mean(axis=0)
    assert 40e-6 < np.linalg.norm(m_n) < 60e-6
    assert 55 * DEG < math.atan2(m_n[2], math.hypot(m_n[0], m_n[1])) < 75 * DEG
    # Wind sign: the air velocity fitted from GNSS and airspeed along the nose (before the
    # engine failure) points the same way as the logged wind after negation.
    sel = f.gnss.t < f.meta["failure_time"]
    tg = f.gnss.t[sel]
    nose = quat_rotate(f.reference.q_nb[nearest(f.reference.t, tg)], np.array([1.0, 0, 0]))
    tas = np.interp(tg, f.air.t, f.air.tas)
    a = np.zeros((2 * len(tg), 3))
    a[0::2, 0], a[1::2, 0] = tas * nose[:, 0], tas * nose[:, 1]
    a[0::2, 1], a[1::2, 2] = 1.0, 1.0
    b = f.gnss.v_n[sel, :2].reshape(-1)
    _, wn, we = np.linalg.lstsq(a, b, rcond=None)[0]
    logged = f.ref_wind.wind_n[f.ref_wind.t < f.meta["failure_time"], :2].mean(axis=0)
    cos = (wn * logged[0] + we * logged[1]) / (math.hypot(wn, we) * np.linalg.norm(logged))
    assert cos > 0.7


def test_alfa_gnss_vertical_flag_and_mag_offset() -> None:
    f = read_alfa(require_data("alfa", ALFA_SEQ))
    assert f.gnss is not None and f.mag is not None and f.reference is not None
    # mavros raw/gps_vel has no vertical speed: the logged 0 is kept and flagged.
    assert f.meta["gnss.vertical_measured"] is False
    assert np.all(f.gnss.v_n[:, 2] == 0.0)
    # The magnetometer is passed through as logged: fitting m_b = C_nb^T m_n + b over the
    # flight leaves ~2 uT RMS (frame and scale right) with a ~10 uT body offset (motor
    # interference, documented in read_alfa), which the reader must not remove.
    q_bn = f.reference.q_nb[nearest(f.reference.t, f.mag.t)] * np.array([1.0, -1, -1, -1])
    c_bn = np.stack([quat_rotate(q_bn, e) for e in np.eye(3)], axis=2)  # C_nb^T per row
    a = np.zeros((3 * len(f.mag.t), 6))
    a[:, :3] = c_bn.reshape(-1, 3)
    a[:, 3:] = np.tile(np.eye(3), (len(f.mag.t), 1))
    x, *_ = np.linalg.lstsq(a, f.mag.mag_b.reshape(-1), rcond=None)
    rms = np.sqrt(np.mean((f.mag.mag_b.reshape(-1) - a @ x) ** 2))
    assert rms < 3e-6
    assert 5e-6 < np.linalg.norm(x[3:]) < 20e-6
    assert 40e-6 < np.linalg.norm(x[:3]) < 55e-6


# --- generic CSV -------------------------------------------------------------------------


def make_flight(rng: np.random.Generator) -> Flight:
    """A multi-rate flight with every stream, in SI and NED/FRD, starting at t = 0."""
    n = 400
    t = np.arange(n, dtype=np.float64) * 0.01
    w = 0.3 * rng.standard_normal((n, 3))
    f = np.array([0.0, 0.0, -G0]) + 0.5 * rng.standard_normal((n, 3))
    tm = t[::4] + 0.002
    m = np.array([20e-6, -3e-6, 45e-6]) + 1e-6 * rng.standard_normal((len(tm), 3))
    tg = t[::20] + 0.005
    tr = t[::5]
    q = quat_exp(np.column_stack([0.3 * np.sin(tr), 0.2 * np.cos(tr), 2.0 * tr - 3.0]))
    return Flight(
        imu=ImuStream(t=t, w_b=w, f_b=f),
        mag=MagStream(t=tm, mag_b=m),
        gnss=GnssStream(t=tg, v_n=rng.normal(0, 10, (len(tg), 3))),
        air=AirDataStream(
            t=tm, tas=15 + rng.random(len(tm)), aoa=0.1 * rng.standard_normal(len(tm)),
            sideslip=0.05 * rng.standard_normal(len(tm)),
        ),
        reference=Reference(t=tr, q_nb=q, kind="mocap", heading_free=True),
        ref_wind=WindStream(t=tg, wind_n=rng.normal(0, 3, (len(tg), 3))),
    )


def write_csv(path: Path, header: list[str], columns: list[np.ndarray]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for row in zip(*columns, strict=True):
            w.writerow([repr(float(x)) if isinstance(x, float | np.floating) else str(x)
                        for x in row])


MANIFEST = """\
format = "windahrs.csv"
version = 1
[flight]
meta = {{ vehicle = "test" }}
[imu]
file = "imu.csv"
time = "t_ms"
time_unit = "ms"
frame = "enu_flu"
gyro = ["wx", "wy", "wz"]
gyro_unit = "{gyro_unit}"
accel = ["ax", "ay", "az"]
accel_unit = "g"
[mag]
file = "mag.csv"
time = "t_us"
time_unit = "us"
frame = "enu_flu"
columns = ["mx", "my", "mz"]
unit = "uT"
[gnss]
file = "gnss.csv"
time = "t"
time_unit = "s"
frame = "enu_flu"
velocity = ["ve", "vn", "vu"]
[air]
file = "air.csv"
time = "t_us"
time_unit = "us"
tas = "tas_kmh"
unit = "km/h"
aoa = "alpha"
sideslip = "beta"
angle_unit = "deg"
[reference]
file = "att.csv"
time = "t"
time_unit = "s"
frame = "enu_flu"
kind = "mocap"
heading_free = true
quaternion = ["qx", "qy", "qz", "qw"]
quaternion_order = "xyzw"
[ref_wind]
file = "wind.csv"
time = "t"
time_unit = "s"
frame = "enu_flu"
columns = ["we_from", "wn_from", "wu_from"]
convention = "from"
"""


def write_csv_dir(flight: Flight, d: Path, gyro_unit: str = "deg/s") -> Path:
    """Write ``flight`` as ENU/FLU, deg/s, g, uT, km/h, ms/us stamps: the test's own
    conversions, independent of the reader's."""
    flu = np.array([1.0, -1.0, -1.0])
    imu, mag, gnss, air = flight.imu, flight.mag, flight.gnss, flight.air
    ref, wind = flight.reference, flight.ref_wind
    assert mag and gnss and air and ref and wind and air.aoa is not None
    assert air.sideslip is not None
    d.mkdir(parents=True, exist_ok=True)
    scale = 1.0 / DEG if gyro_unit == "deg/s" else 1.0
    write_csv(d / "imu.csv", ["t_ms", "wx", "wy", "wz", "ax", "ay", "az"],
              [imu.t * 1e3, *(imu.w_b * flu * scale).T, *(imu.f_b * flu / G0).T])
    t_us = np.round(mag.t * 1e6).astype(np.int64)
    write_csv(d / "mag.csv", ["t_us", "mx", "my", "mz"], [t_us, *(mag.mag_b * flu * 1e6).T])
    write_csv(d / "gnss.csv", ["t", "ve", "vn", "vu"], [gnss.t, *vec_ned_to_enu(gnss.v_n).T])
    t_us = np.round(air.t * 1e6).astype(np.int64)
    write_csv(d / "air.csv", ["t_us", "tas_kmh", "alpha", "beta"],
              [t_us, air.tas * 3.6, air.aoa / DEG, air.sideslip / DEG])
    q = quat_ned_frd_to_enu_flu(ref.q_nb)
    write_csv(d / "att.csv", ["t", "qx", "qy", "qz", "qw"], [ref.t, *q[:, [1, 2, 3, 0]].T])
    write_csv(d / "wind.csv", ["t", "we_from", "wn_from", "wu_from"],
              [wind.t, *(-vec_ned_to_enu(wind.wind_n)).T])
    (d / "windahrs.toml").write_text(MANIFEST.format(gyro_unit=gyro_unit))
    return d


def assert_flights_equal(a: Flight, b: Flight) -> None:
    """Every stream of ``b`` equals ``a`` to 1e-9 (relative for tesla)."""
    def close(x: np.ndarray | None, y: np.ndarray | None, rtol: float = 0.0) -> None:
        assert x is not None and y is not None
        np.testing.assert_allclose(x, y, rtol=rtol, atol=0.0 if rtol else 1e-9)

    for s in ("imu", "mag", "gnss", "air", "ref_wind", "reference"):
        close(getattr(a, s).t, getattr(b, s).t)
    close(a.imu.w_b, b.imu.w_b)
    close(a.imu.f_b, b.imu.f_b)
    assert a.mag and b.mag and a.gnss and b.gnss and a.air and b.air
    assert a.ref_wind and b.ref_wind and a.reference and b.reference
    close(a.mag.mag_b, b.mag.mag_b, rtol=1e-9)
    close(a.gnss.v_n, b.gnss.v_n)
    close(a.air.tas, b.air.tas)
    close(a.air.aoa, b.air.aoa)
    close(a.air.sideslip, b.air.sideslip)
    close(a.ref_wind.wind_n, b.ref_wind.wind_n)
    assert np.max(quat_angle(a.reference.q_nb, b.reference.q_nb)) < 1e-9
    assert (a.reference.kind, a.reference.heading_free) == (b.reference.kind, True)


def test_csv_round_trip_units_and_frames(tmp_path: Path, rng: np.random.Generator) -> None:
    flight = make_flight(rng)
    d = write_csv_dir(flight, tmp_path / "rec")
    assert detect_format(d) == "csv"
    back = read_flight(d)
    assert_flights_equal(flight, back)
    assert back.meta["vehicle"] == "test" and back.meta["start_time_ns"] == 0
    assert_flights_equal(flight, read_csv_dir(d / "windahrs.toml"))


def test_csv_gnss_velocity_from_positions(tmp_path: Path) -> None:
    t = np.arange(50) * 0.2
    v_n = np.array([12.0, -5.0, -1.0])  # NED, m/s
    lat0, lon0, r = 47.0 * DEG, 8.0 * DEG, 6378137.0
    # Straight line on a sphere is enough at this scale: 100 m, ~1e-5 relative curvature.
    lat = (lat0 + v_n[0] * t / r) / DEG
    lon = (lon0 + v_n[1] * t / (r * np.cos(lat0))) / DEG
    alt = 400.0 - v_n[2] * t
    d = tmp_path / "pos"
    d.mkdir()
    write_csv(d / "imu.csv", ["t", "wx", "wy", "wz", "ax", "ay", "az"],
              [t, *np.zeros((3, 50)), np.zeros(50), np.zeros(50), np.full(50, -G0)])
    write_csv(d / "gps.csv", ["t", "lat", "lon", "alt"], [t, lat, lon, alt])
    (d / "windahrs.toml").write_text(
        'format = "windahrs.csv"\nversion = 1\n'
        '[imu]\nfile = "imu.csv"\ntime = "t"\ntime_unit = "s"\n'
        'gyro = ["wx", "wy", "wz"]\ngyro_unit = "rad/s"\naccel = ["ax", "ay", "az"]\n'
        'accel_unit = "m/s^2"\n'
        '[gnss]\nfile = "gps.csv"\ntime = "t"\ntime_unit = "s"\n'
        'position = ["lat", "lon", "alt"]\n'
    )
    f = read_csv_dir(d)
    assert f.gnss is not None and f.meta["gnss.derived_from"] == "position"
    np.testing.assert_allclose(f.gnss.v_n, np.tile(v_n, (50, 1)), atol=0.05)


@pytest.mark.parametrize(
    ("old", "new", "key", "found"),
    [
        ('gyro_unit = "deg/s"', 'gyro_unit = "dps"', "imu.gyro_unit", "'dps'"),
        ('accel_unit = "g"', 'accel_units = "g"', "imu.accel_units", "unknown key"),
        ('frame = "enu_flu"\ncolumns = ["mx"', 'frame = "nwu"\ncolumns = ["mx"',
         "mag.frame", "'nwu'"),
        ('gyro = ["wx", "wy", "wz"]', 'gyro = ["wx", "wy"]', "imu.gyro", "['wx', 'wy']"),
        ('time_unit = "ms"', 'time_unit = "min"', "imu.time_unit", "'min'"),
        ('kind = "mocap"', 'kind = "vicon"', "reference.kind", "'vicon'"),
        ('version = 1', 'version = 7', "version", "7"),
    ],
)
def test_csv_bad_manifest_entry(
    tmp_path: Path, rng: np.random.Generator, old: str, new: str, key: str, found: str
) -> None:
    d = write_csv_dir(make_flight(rng), tmp_path / "rec")
    manifest = d / "windahrs.toml"
    text = manifest.read_text()
    assert old in text
    manifest.write_text(text.replace(old, new, 1))
    with pytest.raises(LogFormatError) as exc:
        read_flight(d)
    msg = str(exc.value)
    assert "windahrs.toml" in msg and repr(key) in msg and "expected" in msg and found in msg


def test_csv_missing_column_and_bad_value(tmp_path: Path, rng: np.random.Generator) -> None:
    d = write_csv_dir(make_flight(rng), tmp_path / "rec")
    text = (d / "mag.csv").read_text()
    (d / "mag.csv").write_text(text.replace("mz", "m_z", 1))
    with pytest.raises(LogFormatError, match=r"mag\.csv.*missing column.*'mz'"):
        read_flight(d)
    lines = text.splitlines()
    lines[5] = lines[5].rsplit(",", 1)[0] + ",abc"
    (d / "mag.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(LogFormatError, match=r"mag\.csv: line 6, column 'mz'.*'abc'"):
        read_flight(d)


def test_csv_missing_cells_order_and_truncation(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    flight = make_flight(rng)
    d = write_csv_dir(flight, tmp_path / "rec")
    lines = (d / "imu.csv").read_text().splitlines()
    cells = lines[3].split(",")
    lines[3] = ",".join([cells[0], "", *cells[2:]])  # sample 2: gyro x missing
    lines[10], lines[11] = lines[11], lines[10]  # out of order
    lines.insert(20, lines[20])  # a repeated stamp
    lines.append(lines[-1][:5])  # a last row cut while being written
    (d / "imu.csv").write_text("\n".join(lines) + "\n\n")
    with pytest.warns(TruncatedLogWarning, match=r"imu\.csv: truncated: .*1 row dropped"):
        f = read_flight(d)
    assert f.repairs["imu"] == {"reordered": 2, "duplicates": 1}  # the empty cell: missing, not a repair
    assert f.meta["imu.dropped_truncated_row"] == 1
    np.testing.assert_allclose(f.imu.t, flight.imu.t, atol=1e-9)
    # One empty cell makes the row a missing sample (the Flight's NaN policy), per sensor.
    assert np.isnan(f.imu.w_b[2]).all() and np.isfinite(f.imu.f_b[2]).all()
    np.testing.assert_allclose(f.imu.w_b[3:], flight.imu.w_b[3:], atol=1e-9)


def test_csv_wrong_declared_unit_is_flight_error(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    # deg/s data declared as rad/s: the Flight's plausibility check names manifest and field.
    flight = make_flight(rng)
    big = flight.imu.w_b * 20.0
    flight = flight.replace(imu=ImuStream(t=flight.imu.t, w_b=big, f_b=flight.imu.f_b))
    d = write_csv_dir(flight, tmp_path / "rec")
    text = (d / "windahrs.toml").read_text().replace('"deg/s"', '"rad/s"')
    (d / "windahrs.toml").write_text(text)
    with pytest.raises(FlightError, match=r"windahrs\.toml:imu\.w_b") as exc:
        read_flight(d)
    assert "deg/s" in str(exc.value)


# --- DataFlash ---------------------------------------------------------------------------


def dataflash_log(path: Path, *, with_xkq: bool = True) -> dict[str, np.ndarray]:
    """Write a small binary DataFlash log; return the truth it encodes.

    Layouts come from pymavlink's DFFormat (struct strings of the format characters); the
    FMT record is the documented 89-byte message 0x80: Type, Length, Name[4], Format[16],
    Columns[64]. Modern layout: instances in an ``I``/``C`` field.
    """
    from pymavlink.DFReader import DFFormat

    specs = {
        "PARM": ("QNf", "TimeUS,Name,Value"),
        "IMU": ("QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
        "MAG": ("QBhhh", "TimeUS,I,MagX,MagY,MagZ"),
        "GPS": ("QBBfff", "TimeUS,I,Status,Spd,GCrs,VZ"),
        "ARSP": ("QBf", "TimeUS,I,Airspeed"),
        "ATT": ("QccccCC", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw"),
        "XKQ": ("QBffff", "TimeUS,C,Q1,Q2,Q3,Q4"),
        "XKF2": ("QBff", "TimeUS,C,VWN,VWE"),
    }
    fmts = {name: DFFormat(64 + i, name, 0, f, c) for i, (name, (f, c)) in enumerate(specs.items())}
    fmt_fmt = DFFormat(0x80, "FMT", 89, "BBnNZ", "Type,Length,Name,Format,Columns")
    out = bytearray()

    def put(fmt: DFFormat, *vals: object) -> None:
        out.extend(b"\xa3\x95" + bytes([fmt.type]) + struct.pack(fmt.msg_struct, *vals))

    put(fmt_fmt, 0x80, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns")
    for fm in fmts.values():
        size = struct.calcsize(fm.msg_struct) + 3
        put(fmt_fmt, fm.type, size, fm.name.encode(), fm.format.encode(),
            ",".join(fm.columns).encode())
    put(fmts["PARM"], 100, b"EK3_GYRO_P_NSE", 0.015)
    put(fmts["PARM"], 100, b"SERIAL0_BAUD", 115.0)
    n = 200
    t_us = 5_000_000 + 10_000 * np.arange(n)
    rpy = np.column_stack([0.3 * np.sin(t_us * 1e-6), 0.1 * np.cos(t_us * 1e-6),
                           np.linspace(-3.0, 3.0, n)])
    rpy_cd = np.round(rpy / DEG * 100)  # ATT logs centidegrees; 'C' yaw is 0..360 deg
    yaw_cd = np.mod(rpy_cd[:, 2], 36000)
    q = quat_from_euler(rpy_cd * 0.01 * DEG)
    for k in range(n):
        tk = int(t_us[k])
        put(fmts["IMU"], tk, 0, 0.1, -0.2, 0.3, 0.5, -0.25, -9.7)
        put(fmts["IMU"], tk + 1, 1, 9.0, 9.0, 9.0, 0.0, 0.0, -9.8)  # instance 1: ignored
        put(fmts["ATT"], tk + 2, 0, int(rpy_cd[k, 0]), 0, int(rpy_cd[k, 1]), 0, int(yaw_cd[k]))
        if with_xkq:
            put(fmts["XKQ"], tk + 3, 0, *q[k])
            put(fmts["XKQ"], tk + 3, 1, 1.0, 0.0, 0.0, 0.0)  # core 1: ignored
        if k % 5 == 0:
            put(fmts["MAG"], tk + 4, 0, 200, -40, 450)
            put(fmts["ARSP"], tk + 5, 0, 17.5)
        if k % 20 == 0:
            status = 1 if k == 0 else 3  # no fix at first: dropped
            put(fmts["GPS"], tk + 6, 0, status, 5.0, math.degrees(math.atan2(4, 3)), -1.0)
            put(fmts["XKF2"], tk + 7, 0, -2.5, 1.5)
    path.write_bytes(bytes(out))
    return {"t_us": t_us, "q": q}


def test_dataflash_synthetic_log(tmp_path: Path) -> None:
    path = tmp_path / "flight.bin"
    truth = dataflash_log(path)
    f = read_flight(path)
    assert f.meta["format"] == "dataflash" and f.meta["start_time_us"] == 5_000_000
    assert len(f.imu.t) == 200 and mean_rate(f.imu.t) == pytest.approx(100.0)
    np.testing.assert_allclose(f.imu.t, (truth["t_us"] - 5_000_000) * 1e-6)
    np.testing.assert_allclose(f.imu.w_b[0], [0.1, -0.2, 0.3], rtol=1e-6)
    np.testing.assert_allclose(f.imu.f_b[0], [0.5, -0.25, -9.7], rtol=1e-6)
    assert f.mag is not None
    np.testing.assert_allclose(f.mag.mag_b[0], [20e-6, -4e-6, 45e-6], rtol=1e-12)
    assert f.gnss is not None and len(f.gnss.t) == 9 and f.meta["gnss.dropped_no_3d_fix"] == 1
    np.testing.assert_allclose(f.gnss.v_n, np.tile([3.0, 4.0, -1.0], (9, 1)), atol=1e-5)
    assert f.air is not None and f.meta["air.tas_is_eas"] is True
    np.testing.assert_allclose(f.air.tas, 17.5)
    assert f.ref_wind is not None
    np.testing.assert_allclose(f.ref_wind.wind_n[0], [-2.5, 1.5, 0.0])
    assert f.reference is not None and f.meta["reference.message"] == "XKQ"
    assert np.max(quat_angle(f.reference.q_nb, truth["q"])) < 1e-6
    assert f.meta["param.EK3_GYRO_P_NSE"] == 0.015 and "param.SERIAL0_BAUD" not in f.meta


def test_dataflash_att_fallback(tmp_path: Path) -> None:
    path = tmp_path / "att.log"  # a binary .log is read as DataFlash too
    truth = dataflash_log(path, with_xkq=False)
    f = read_dataflash(path)
    assert f.reference is not None and f.meta["reference.message"] == "ATT"
    # Same attitude from centidegree Euler angles (ZYX, yaw 0..360).
    assert np.max(quat_angle(f.reference.q_nb, truth["q"])) < 1e-6


def test_dataflash_text_log(tmp_path: Path) -> None:
    lines = [
        "FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns",
        "FMT, 65, 35, IMU, QBffffff, TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ",
        "FMT, 66, 20, ATT, QccccCC, TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw",
    ]
    for k in range(50):
        lines.append(f"IMU, {1000 + k * 10000}, 0, 0.1, 0.2, 0.3, 0.0, 0.0, -9.8")
        lines.append(f"ATT, {1000 + k * 10000}, 0, 10.5, 0, -3.2, 0, 270.0")
    path = tmp_path / "text.log"
    path.write_text("\n".join(lines) + "\n")
    f = read_flight(path)
    assert len(f.imu.t) == 50 and f.reference is not None
    rpy = euler_from_quat(f.reference.q_nb[0]) / DEG
    np.testing.assert_allclose(rpy, [10.5, -3.2, -90.0], atol=1e-9)


def test_dataflash_truncated(tmp_path: Path) -> None:
    full = tmp_path / "full.bin"
    dataflash_log(full)
    data = full.read_bytes()
    cut = tmp_path / "cut.bin"
    cut.write_bytes(data[: len(data) // 2 + 7])  # cut mid-message: the rest is read, and said
    with pytest.warns(TruncatedLogWarning, match=r"cut\.bin: truncated: .* bytes dropped"):
        f = read_dataflash(cut)
    assert 50 < len(f.imu.t) < 200 and f.meta["dataflash.truncated_bytes"] > 0
    head = tmp_path / "head.bin"
    head.write_bytes(data[: 9 * 89])  # the nine FMT messages only
    with pytest.raises(LogFormatError, match=r"head\.bin.*'IMU'"):
        read_flight(head)


# --- dispatch and bad input ----------------------------------------------------------------


def test_formats_and_windahrs_file(tmp_path: Path, rng: np.random.Generator) -> None:
    assert set(FORMATS) == {"ulog", "dataflash", "broad", "windahrs", "alfa", "csv", "ansfl", "asl"}
    flight = make_flight(rng).replace(meta={"source": "sim"})
    path = save_flight(flight, tmp_path / "f.h5")
    assert detect_format(path) == "windahrs"
    back = read_flight(path)
    np.testing.assert_array_equal(back.imu.w_b, flight.imu.w_b)
    assert back.meta == {"source": "sim"}


def text_file(path: Path) -> Path:
    path.write_text("time,gyro\n0.0,1.0\nthis is not a flight log\n" * 20)
    return path


def truncated_copy(path: Path, src: Path) -> Path:
    path.write_bytes(src.read_bytes()[:1000])
    return path


BAD_INPUTS = {
    "empty.ulg": lambda p: p.write_bytes(b"") or p,
    "empty.bin": lambda p: p.write_bytes(b"") or p,
    "empty.hdf5": lambda p: p.write_bytes(b"") or p,
    "empty.dat": lambda p: p.write_bytes(b"") or p,
    "text.ulg": text_file,
    "text.bin": text_file,
    "text.log": text_file,
    "text.h5": text_file,
    "notes.txt": text_file,
    "missing.ulg": lambda p: p,
    "plain_dir": lambda p: p.mkdir() or p,
}


@pytest.mark.parametrize("name", sorted(BAD_INPUTS))
def test_bad_input_names_the_file(tmp_path: Path, name: str) -> None:
    path = BAD_INPUTS[name](tmp_path / name)
    with pytest.raises(LogFormatError) as exc:
        read_flight(path)
    assert name in str(exc.value)


@pytest.mark.parametrize(
    ("src", "name"),
    [(("px4", "sample.ulg"), "cut.ulg"), (("broad", BROAD_TRIALS[0]), "cut.hdf5")],
)
def test_truncated_real_file(tmp_path: Path, src: tuple[str, str], name: str) -> None:
    path = truncated_copy(tmp_path / name, require_data(*src))
    with pytest.raises(LogFormatError) as exc:
        read_flight(path)
    assert name in str(exc.value)


def test_corrupt_bytes_are_quiet_and_reported(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(7)
    garbage = tmp_path / "garbage.bin"  # a valid DataFlash start, then noise
    garbage.write_bytes(b"\xa3\x95\x80" + rng.bytes(100_000))
    with pytest.raises(LogFormatError, match=r"garbage\.bin"):
        read_flight(garbage)
    src = require_data("px4", "sample.ulg").read_bytes()
    mid = len(src) // 2
    bad = tmp_path / "corrupt.ulg"  # 50 kB of noise in the data section
    bad.write_bytes(src[:mid] + rng.bytes(50_000) + src[mid + 50_000 :])
    f = read_flight(bad)
    assert f.meta["ulog.file_corruption"] is True
    assert 8000 < len(f.imu.t) < 17070  # at least the half before the damage
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # parser chatter is counted, not printed


def test_unknown_fmt_and_option(tmp_path: Path) -> None:
    src = text_file(tmp_path / "x.ulg")  # options are checked before the file is read
    with pytest.raises(LogFormatError, match="fmt: expected one of"):
        read_flight(src, fmt="tlog")
    with pytest.raises(LogFormatError, match="option not known"):
        read_flight(src, colour="red")



# --- CSV: mounting rotation, unknown magnetometer units, header blanks, one vane -------------


def _with_manifest(d: Path, old: str, new: str) -> None:
    text = (d / "windahrs.toml").read_text()
    assert old in text
    (d / "windahrs.toml").write_text(text.replace(old, new, 1))


def test_csv_imu_mount_rotation_reads_back_the_body_frame(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    # An IMU (and its magnetometer) pitched 7.5 deg and yawed 2 deg against the body: the
    # sensor reads v_s = C_bs^T v_b with C_bs = Rz(2) Ry(7.5) Rx(0) (scipy as the oracle).
    flight = make_flight(rng)
    c_bs = Rotation.from_euler("ZYX", [2.0, 7.5, 0.0], degrees=True).as_matrix()
    assert flight.mag is not None
    mounted = flight.replace(
        imu=ImuStream(t=flight.imu.t, w_b=flight.imu.w_b @ c_bs, f_b=flight.imu.f_b @ c_bs),
        mag=MagStream(t=flight.mag.t, mag_b=flight.mag.mag_b @ c_bs),
    )
    d = write_csv_dir(mounted, tmp_path / "rec")
    _with_manifest(d, 'accel_unit = "g"', 'accel_unit = "g"\nmount_rpy_deg = [0, 7.5, 2]')
    back = read_flight(d)
    assert_flights_equal(flight, back)  # the magnetometer takes the IMU's mount by default
    assert back.meta["imu.mount_rpy_deg"] == back.meta["mag.mount_rpy_deg"] == "0, 7.5, 2"
    # A magnetometer of its own, mounted along the body: [mag] mount_rpy_deg = [0, 0, 0].
    d2 = write_csv_dir(mounted.replace(mag=flight.mag), tmp_path / "rec2")
    _with_manifest(d2, 'accel_unit = "g"', 'accel_unit = "g"\nmount_rpy_deg = [0, 7.5, 2]')
    _with_manifest(d2, 'unit = "uT"', 'unit = "uT"\nmount_rpy_deg = [0, 0, 0]')
    assert_flights_equal(flight, read_flight(d2))
    _with_manifest(d2, "mount_rpy_deg = [0, 0, 0]", 'mount_rpy_deg = [0, "7.5"]')
    with pytest.raises(LogFormatError, match=r"'mag\.mount_rpy_deg': expected a list of 3 finite"):
        read_flight(d2)


def test_csv_magnetometer_in_arbitrary_units(tmp_path: Path, rng: np.random.Generator) -> None:
    flight = make_flight(rng)
    assert flight.mag is not None
    d = write_csv_dir(flight, tmp_path / "rec")  # written in uT: 1e6 x tesla
    raw_norm = float(np.median(np.linalg.norm(flight.mag.mag_b, axis=1))) * 1e6
    for unit in ("normalised", "arbitrary"):
        _with_manifest(d, 'unit = "uT"' if unit == "normalised" else 'unit = "normalised"',
                       f'unit = "{unit}"')
        back = read_flight(d)
        assert back.mag is not None and back.site.mag_n is None
        # One factor: the median norm becomes the 50 uT placeholder; directions unchanged.
        np.testing.assert_allclose(np.median(np.linalg.norm(back.mag.mag_b, axis=1)), 50e-6, rtol=1e-12)
        np.testing.assert_allclose(back.mag.mag_b, flight.mag.mag_b * (50e-6 / (raw_norm * 1e-6)),
                                   rtol=1e-9)
        assert back.meta["mag.unit"] == "normalised"
        assert back.meta["mag.raw_median_norm"] == pytest.approx(raw_norm, rel=1e-12)
    # With the site's field given, the placeholder is its magnitude (the two agree).
    _with_manifest(d, "[flight]\n", "[flight]\nmag_n = [20e-6, 0.0, 40e-6]\n")
    back = read_flight(d)
    assert back.mag is not None
    np.testing.assert_allclose(np.median(np.linalg.norm(back.mag.mag_b, axis=1)),
                               np.hypot(20e-6, 40e-6), rtol=1e-12)
    _with_manifest(d, 'unit = "arbitrary"', 'unit = "counts"')
    with pytest.raises(LogFormatError, match=r"'mag\.unit'.*'normalised', 'arbitrary'.*'counts'"):
        read_flight(d)


def test_csv_header_blanks_are_stripped_with_one_warning(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    flight = make_flight(rng)
    d = write_csv_dir(flight, tmp_path / "rec")
    text = (d / "mag.csv").read_text()
    (d / "mag.csv").write_text(text.replace("t_us,mx,my,mz", "t_us, mx ,my,\tmz", 1))
    match = r"mag\.csv: column\(s\) 'mx', 'mz' matched the header only after stripping"
    with pytest.warns(UserWarning, match=match) as rec:
        back = read_flight(d)
    assert len([w for w in rec if "mag.csv" in str(w.message)]) == 1
    assert_flights_equal(flight, back)
    lines = text.splitlines()  # the same through the row-by-row reader (an empty cell)
    lines[0] = "t_us, mx ,my,\tmz"
    lines[3] = ",".join([*lines[3].split(",")[:3], ""])
    (d / "mag.csv").write_text("\n".join(lines) + "\n")
    with pytest.warns(UserWarning, match=r"mag\.csv: column\(s\) 'mx', 'mz'"):
        read_flight(d)


def test_csv_angle_of_attack_vane_without_sideslip(tmp_path: Path, rng: np.random.Generator) -> None:
    flight = make_flight(rng)
    d = write_csv_dir(flight, tmp_path / "rec")
    _with_manifest(d, 'sideslip = "beta"\n', "")
    back = read_flight(d)
    assert back.air is not None and flight.air is not None and back.air.sideslip is not None
    np.testing.assert_allclose(back.air.aoa, flight.air.aoa, atol=1e-9)
    assert np.isnan(back.air.sideslip).all() and not back.air.has_vanes
    np.testing.assert_allclose(back.air.tas, flight.air.tas, atol=1e-9)
