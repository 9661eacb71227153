"""Small logs written byte by byte, as their formats' specifications say: a PX4 ULog and
an ArduPilot DataFlash log (seeds of the fuzz tests, fixtures of the reader tests)."""

from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np


def ulog_bytes(
    n: int = 400, *, second_mag: bool = False, decl_deg: float | None = None,
    mag_bias_ga: tuple[float, float, float] | None = None, mag_bias_id: int = 7, prime_mag_id: int = 7,
) -> bytes:
    """A small PX4 ULog (format version 1): IMU at 200 Hz, magnetometer, attitude, airspeed,
    GPS velocity and wind, laid out as the ULog spec says (header, flag bits, info, parameter,
    formats, add-logged and data messages). second_mag: a second vehicle_magnetometer
    instance (multi_id 1, message id 6) reading (0.1, 0.0, 0.5) gauss. decl_deg: an
    EKF2_MAG_DECL parameter (degrees). mag_bias_ga: EKF2's saved magnetometer bias
    (EKF2_MAGBIAS_X/Y/Z, gauss) for the device EKF2_MAGBIAS_ID, the prime magnetometer
    being CAL_MAG_PRIME."""
    out = bytearray(b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 1_000_000))

    def msg(kind: str, payload: bytes) -> None:
        out.extend(struct.pack("<HB", len(payload), ord(kind)) + payload)

    msg("B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    info = [("I", b"char[7] sys_name", b"windsim"), ("P", b"float EKF2_GYR_NOISE", struct.pack("<f", 0.015))]
    if decl_deg is not None:
        info.append(("P", b"float EKF2_MAG_DECL", struct.pack("<f", decl_deg)))
    if mag_bias_ga is not None:
        info += [("P", f"float EKF2_MAGBIAS_{a}".encode(), struct.pack("<f", b))
                 for a, b in zip("XYZ", mag_bias_ga, strict=True)]
        info += [("P", b"int32_t EKF2_MAGBIAS_ID", struct.pack("<i", mag_bias_id)),
                 ("P", b"int32_t CAL_MAG_PRIME", struct.pack("<i", prime_mag_id))]
    for kind, key, value in info:
        msg(kind, bytes([len(key)]) + key + value)
    formats = {
        "sensor_combined": "uint64_t timestamp;float[3] gyro_rad;float[3] accelerometer_m_s2;",
        "vehicle_magnetometer": "uint64_t timestamp;uint64_t timestamp_sample;float[3] magnetometer_ga;",
        "vehicle_attitude": "uint64_t timestamp;float[4] q;",
        "airspeed_validated": "uint64_t timestamp;float true_airspeed_m_s;",
        "vehicle_gps_position": "uint64_t timestamp;float vel_n_m_s;float vel_e_m_s;float vel_d_m_s;"
        "uint8_t vel_ned_valid;",
        "wind": "uint64_t timestamp;float windspeed_north;float windspeed_east;",
    }
    for name, fields in formats.items():
        msg("F", f"{name}:{fields}".encode())
    for i, name in enumerate(formats):
        msg("A", struct.pack("<BH", 0, i) + name.encode())
    if second_mag:
        msg("A", struct.pack("<BH", 1, 6) + b"vehicle_magnetometer")
    rng = np.random.default_rng(0)
    for k in range(n):
        t = 2_000_000 + 5_000 * k
        w = 0.1 * rng.standard_normal(3)
        f = np.array([0.0, 0.0, -9.8]) + 0.1 * rng.standard_normal(3)
        msg("D", struct.pack("<HQ6f", 0, t, *w, *f))
        if k % 4 == 0:
            msg("D", struct.pack("<HQQ3f", 1, t + 10, t, 0.2, 0.02, 0.4))
            if second_mag:
                msg("D", struct.pack("<HQQ3f", 6, t + 15, t, 0.1, 0.0, 0.5))
            c, s = math.cos(0.01 * k), math.sin(0.01 * k)
            msg("D", struct.pack("<HQ4f", 2, t + 20, c, 0.0, 0.0, s))
            msg("D", struct.pack("<HQf", 3, t + 30, 18.0))
        if k % 20 == 0:
            msg("D", struct.pack("<HQ3fB", 4, t + 40, 15.0, 1.0, -0.5, 1))
            msg("D", struct.pack("<HQ2f", 5, t + 50, -3.0, 2.0))
    return bytes(out)


def dataflash_bytes(n: int = 200, *, decl_rad: float | None = None, gpa: bool = False) -> bytes:
    """A small binary ArduPilot DataFlash log: FMT messages (the documented 89-byte message
    0x80), then PARM, IMU, MAG, GPS, ARSP, ATT, XKQ and XKF2 rows; with ``gpa``, a GPA row
    (speed accuracy ``SAcc`` 0.5 m/s, then 0.8 from the second GPS row on) beside each GPS row,
    at its TimeUS."""
    specs = {  # name: (struct of the fields after the 3-byte header, columns)
        "PARM": ("<Q16sf", "TimeUS,Name,Value", "QNf"),
        "IMU": ("<QB6f", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ", "QBffffff"),
        "MAG": ("<QB3h", "TimeUS,I,MagX,MagY,MagZ", "QBhhh"),
        "GPS": ("<QBB3f", "TimeUS,I,Status,Spd,GCrs,VZ", "QBBfff"),
        "ARSP": ("<QBf", "TimeUS,I,Airspeed", "QBf"),
        "ATT": ("<Q3f", "TimeUS,Roll,Pitch,Yaw", "Qfff"),
        "XKQ": ("<QB4f", "TimeUS,C,Q1,Q2,Q3,Q4", "QBffff"),
        "XKF2": ("<QB2f", "TimeUS,C,VWN,VWE", "QBff"),
        **({"GPA": ("<QBf", "TimeUS,I,SAcc", "QBf")} if gpa else {}),
    }
    out = bytearray()

    def put(msg_id: int, layout: str, *vals: Any) -> None:
        out.extend(b"\xa3\x95" + bytes([msg_id]) + struct.pack(layout, *vals))

    fmt_layout = "<BB4s16s64s"
    put(0x80, fmt_layout, 0x80, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns")
    ids = {}
    for i, (name, (layout, cols, chars)) in enumerate(specs.items()):
        ids[name] = 64 + i
        put(0x80, fmt_layout, 64 + i, struct.calcsize(layout) + 3, name.encode(), chars.encode(),
            cols.encode())
    put(ids["PARM"], specs["PARM"][0], 100, b"EK3_GYRO_P_NSE", 0.015)
    if decl_rad is not None:
        put(ids["PARM"], specs["PARM"][0], 100, b"COMPASS_DEC", decl_rad)
    for k in range(n):
        t = 5_000_000 + 10_000 * k
        put(ids["IMU"], specs["IMU"][0], t, 0, 0.1, -0.2, 0.3, 0.5, -0.25, -9.7)
        put(ids["ATT"], specs["ATT"][0], t + 1, 2.0, -1.0, 0.5 * k % 360)
        put(ids["XKQ"], specs["XKQ"][0], t + 2, 0, 1.0, 0.0, 0.0, 0.0)
        if k % 5 == 0:
            put(ids["MAG"], specs["MAG"][0], t + 3, 0, 200, -40, 450)
            put(ids["ARSP"], specs["ARSP"][0], t + 4, 0, 17.5)
        if k % 20 == 0:
            put(ids["GPS"], specs["GPS"][0], t + 5, 0, 3, 5.0, 53.0, -1.0)
            if gpa:
                put(ids["GPA"], specs["GPA"][0], t + 5, 0, 0.5 if k == 0 else 0.8)
            put(ids["XKF2"], specs["XKF2"][0], t + 6, 0, -2.5, 1.5)
    return bytes(out)


#: The DJI log's header as the ANSFL dataset writes it, leading spaces included.
ANSFL_GT_HEADER = (
    "time,distance(meters),speed(m/s), compass_heading(degrees), pitch(degrees), roll(degrees),"
    "height_above_takeoff(meters),North,East,Down"
)
ANSFL_IMU_HEADER = "time,Euler_X,Euler_Y,Euler_Z,Acc_X,Acc_Y,Acc_Z,Gyr_X,Gyr_Y,Gyr_Z"


def write_ansfl_dir(directory: Any, flight: Any, *, imus: tuple[int, ...] = (1,), gt_every: int = 0) -> Any:
    """An ANSFL flight directory (``GT.csv`` and ``IMU_<k>.csv``, as the dataset lays them
    out) written from a simulated Flight with truth: the IMU in the DOT's axes (x forward,
    y left, z up) and deg/s, with garbage in the DOT's own Euler columns; the DJI log at
    ``gt_every`` truth samples (default: 10 Hz) with roll, pitch, compass heading (0-360
    deg) and the NED position from the first sample. IMU k > 1 is IMU 1 with k-1 added to
    the accelerometer's x, so a test can tell them apart."""
    from pathlib import Path

    from windahrs.rotation import euler_from_quat

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    imu, truth = flight.imu, flight.truth
    flu = np.array([1.0, -1.0, -1.0])
    gyr = np.degrees(imu.w_b) * flu
    acc = imu.f_b * flu
    junk = np.full((len(imu.t), 3), 123.0)
    for k in imus:
        a = acc + np.array([k - 1.0, 0.0, 0.0])
        rows = np.column_stack([imu.t, junk, a, gyr])
        np.savetxt(d / f"IMU_{k}.csv", rows, delimiter=",", header=ANSFL_IMU_HEADER, comments="", fmt="%.10g")
    step = gt_every or max(1, round(0.1 / float(np.median(np.diff(truth.t)))))
    t = truth.t[::step]
    rpy = np.degrees(euler_from_quat(truth.q_nb[::step]))
    p = truth.p_n[::step] - truth.p_n[0]
    n = len(t)
    rows = np.column_stack([
        t, np.zeros(n), np.linalg.norm(truth.v_n[::step], axis=1), rpy[:, 2] % 360.0, rpy[:, 1], rpy[:, 0],
        10.0 - p[:, 2], p,
    ])
    np.savetxt(d / "GT.csv", rows, delimiter=",", header=ANSFL_GT_HEADER, comments="", fmt="%.10g")
    return d
