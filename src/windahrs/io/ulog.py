"""PX4 ULog files (``.ulg``) to :class:`~windahrs.flight.Flight`, with pyulog.

Topics read (PX4 uORB names; FRD body and NED already, so only units change):

==============================  ==================================================
Flight field                    ULog topic (fields)
==============================  ==================================================
imu                             ``sensor_combined`` (``gyro_rad``, ``accelerometer_m_s2``)
mag                             ``vehicle_magnetometer`` (``magnetometer_ga``, gauss);
                                else ``sensor_combined.magnetometer_ga`` (old layout);
                                less EKF2's saved bias ``EKF2_MAGBIAS_*`` when it is for
                                this device, as EKF2 (PX4 1.12 and before) fuses it
gnss                            ``vehicle_gps_position`` else ``sensor_gps``
                                (``vel_n/e/d_m_s``, rows with ``vel_ned_valid`` only;
                                ``s_variance_m_s``, the receiver's speed accuracy, as
                                ``v_sigma``)
air                             ``airspeed_validated`` else ``airspeed``
                                (``true_airspeed_m_s``); vanes from ``airflow_aoa`` and
                                ``airflow_slip`` when both are logged
ref_wind                        ``wind`` else ``wind_estimate`` (``windspeed_north/east``;
                                PX4's wind state is the velocity of the air, down = 0)
reference                       ``vehicle_attitude_groundtruth`` (kind "truth", SITL)
                                else ``vehicle_attitude`` (kind "autopilot")
site                            declination from ``EKF2_MAG_DECL`` else
                                ``ATT_MAG_DECL`` (degrees; 0, the default, is unknown):
                                what EKF2 used, saved from its World Magnetic Model lookup
                                (``EKF2_DECL_TYPE``); estimated headings are then true,
                                as ``vehicle_attitude``'s is. The field itself is unknown.
meta                            ``param.EKF2_*`` initial parameters, as floats
==============================  ==================================================

Time: seconds from the log header's start time (``meta["start_time_us"]``, microseconds
since boot). A few topics publish samples stamped just before that start, which get small
negative times. Where a topic logs ``timestamp_sample`` (the sensor time of validity) it is
used instead of the publication ``timestamp``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from windahrs.flight import (
    AirDataStream,
    Flight,
    GnssStream,
    ImuStream,
    MagStream,
    Reference,
    ReferenceKind,
    WindStream,
)
from windahrs.io.edge import (
    LogFormatError,
    autopilot_site,
    captured_output,
    flight_errors_name,
    guard,
    invalid_quat_rows,
    param_float,
    speed_accuracy,
    warn_truncated,
)
from windahrs.repair import (
    ACCEL_RANGE,
    AIRSPEED_RANGE,
    ANGLE_RANGE,
    GNSS_VELOCITY_RANGE,
    GYRO_RANGE,
    MAG_RANGE,
    RepairLog,
    clean_series,
    finite_rows,
)

__all__ = ["ULOG_TOPICS", "read_ulog"]

#: Every topic the reader may use; pyulog parses only these (faster on big logs).
ULOG_TOPICS: tuple[str, ...] = (
    "sensor_combined",
    "vehicle_magnetometer",
    "vehicle_gps_position",
    "sensor_gps",
    "airspeed_validated",
    "airspeed",
    "airflow_aoa",
    "airflow_slip",
    "wind",
    "wind_estimate",
    "vehicle_attitude",
    "vehicle_attitude_groundtruth",
)

#: ``*_timestamp_relative`` value meaning "no sample" (PX4 RELATIVE_TIMESTAMP_INVALID).
_REL_INVALID = 0x7FFFFFFF
_GAUSS = 1e-4  # tesla per gauss
#: The declination parameters, in degrees: EKF2's, then attitude_estimator_q's (PX4 docs,
#: parameter reference).
_DECLINATION_PARAMS = (("EKF2_MAG_DECL", float(np.radians(1.0))), ("ATT_MAG_DECL", float(np.radians(1.0))))
_US = 1e-6
#: Reads without progress after which a ULog parse is stopped (see _ProgressFile).
_IDLE_READS = 300_000
#: Bytes of a ULog message header (uint16 size, uint8 type).
_HEADER = 3


class _MissingField(KeyError):
    """A topic lacks a field the reader needs (a corrupt or foreign format definition)."""

    def __init__(self, topic: str, field: str) -> None:
        super().__init__(field)
        self.topic = topic
        self.field = field


class Data(dict[str, NDArray[Any]]):
    """One topic instance's fields; a missing field raises :class:`_MissingField`."""

    def __init__(self, topic: str, data: dict[str, NDArray[Any]]) -> None:
        super().__init__(data)
        self.topic = topic

    def __missing__(self, key: str) -> NDArray[Any]:
        raise _MissingField(self.topic, key)


def read_ulog(
    path: str | os.PathLike[str], *, multi_id: int = 0, air_topic: str | None = None
) -> Flight:
    """Read a PX4 ULog file into a Flight.

    path: the ``.ulg`` file. multi_id: the instance of multi-instance topics to read
    (a topic without that instance falls back to its lowest one; ``meta`` names the topic
    and instance used for each stream). air_topic: force ``"airspeed_validated"`` or
    ``"airspeed"`` (by default the validated one, which PX4 logs at a lower rate on some
    versions).

    A file cut inside its last message is read up to the message before, with a
    TruncatedLogWarning and ``meta["ulog.truncated_bytes"]``; the samples are repaired as
    :mod:`windahrs.repair` says (``Flight.repairs``).

    Raises LogFormatError (file missing, not a ULog, truncated before the IMU data, no
    ``sensor_combined``) and FlightError (values failing validation; field prefixed by
    the file).
    """
    p = Path(path)
    if not p.is_file():
        raise LogFormatError(p, "no such file")
    from pyulog import ULog  # optional dependency (extra "logs")

    try:
        progress_file = _ProgressFile(p)
    except OSError as exc:  # unreadable (permissions, a directory, ...)
        raise LogFormatError(p, f"cannot open: {exc.strerror or exc}") from None
    with captured_output() as chatter, progress_file as fh:
        ulog = guard(
            p,
            "not a readable ULog file (truncated or corrupt?)",
            lambda: ULog(fh, list(ULOG_TOPICS)),
        )
    topics = _Topics(ulog, multi_id)
    cut = progress_file.truncated_bytes()
    t0 = int(ulog.start_timestamp)
    meta: dict[str, Any] = {
        "source": p.name,
        "format": "ulog",
        "start_time_us": t0,
        "ulog.dropouts": len(ulog.dropouts),
        "ulog.dropout_s": float(sum(d.duration for d in ulog.dropouts)) * 1e-3,
        "ulog.file_corruption": bool(ulog.file_corruption),
        "ulog.parser_messages": len(chatter.lines),
        "ulog.data_appended": bool(ulog.has_data_appended),
    }
    for key in ("sys_name", "ver_hw", "ver_sw"):
        if key in ulog.msg_info_dict:
            meta[f"ulog.{key}"] = str(ulog.msg_info_dict[key])
    site = autopilot_site(ulog.initial_parameters, _DECLINATION_PARAMS, meta)
    bad_params = 0
    for name, value in sorted(ulog.initial_parameters.items()):
        if name.startswith("EKF2_"):
            try:
                meta[f"param.{name}"] = param_float(value)
            except (TypeError, ValueError):  # a corrupt parameter type gives bytes
                bad_params += 1
    if bad_params:
        meta["ulog.unreadable_parameters"] = bad_params
    if cut:
        meta["ulog.truncated_bytes"] = cut
        warn_truncated(p, f"its last message is incomplete: read up to byte {p.stat().st_size - cut}, "
                       f"{cut} bytes dropped")

    sc = topics.get("sensor_combined")
    if sc is None or len(sc.get("timestamp", ())) == 0:
        hint = " (the file holds no data messages: truncated?)" if not ulog.data_list else ""
        raise LogFormatError(p, f"no 'sensor_combined' topic (the IMU data a Flight needs){hint}")
    meta["imu.topic"] = topics.used["sensor_combined"]

    rep = RepairLog()
    try:
        with flight_errors_name(p):
            imu = _imu(sc, t0, meta, rep)
            flight = Flight(
                imu=imu,
                mag=_mag(topics, sc, t0, meta, rep, ulog.initial_parameters),
                gnss=_gnss(topics, t0, meta, rep),
                air=_air(topics, t0, meta, rep, air_topic),
                reference=_reference(topics, t0, meta, rep),
                ref_wind=_wind(topics, t0, meta, rep),
                site=site,
                meta=meta,
                repairs=rep.counts,
            )
            flight = rep.attach(flight)
    except _MissingField as exc:
        raise LogFormatError(
            p, f"topic '{exc.topic}' has no field '{exc.field}' (corrupt or unknown message format)"
        ) from None
    return flight


class _NoProgress(RuntimeError):
    """The parser kept reading without getting further into the file."""


class _ProgressFile:
    """The log file as pyulog reads it, failing once the parser stops making progress.

    pyulog (1.3) skips a corrupt message header by seeking back by the message size it
    asked for, not by the bytes it got: near the end of a file that lands before where it
    started, and it reads the same bytes forever. Here every read that does not get past
    the furthest offset reached so far counts, and :data:`_IDLE_READS` of them in a row
    raise :class:`_NoProgress` (a legitimate resynchronisation byte by byte re-reads at
    most 2 x 65538 times: 64 kB is the largest ULog message).
    """

    def __init__(self, path: Path) -> None:
        self._fh = path.open("rb")
        self._pos = 0
        self._furthest = 0
        self._idle = 0
        self._tail = ((0, 0), (0, 0))  # (asked, got) of the last two reads

    def read(self, size: int = -1) -> bytes:
        data = self._fh.read(size)
        self._tail = (self._tail[1], (size, len(data)))
        self._pos += len(data)
        if self._pos > self._furthest:
            self._furthest, self._idle = self._pos, 0
        else:
            self._idle += 1
            if self._idle > _IDLE_READS:
                raise _NoProgress(
                    f"the parser re-read the bytes before offset {self._furthest} "
                    f"{self._idle} times without getting further (corrupt message headers)"
                )
        return data

    def seek(self, offset: int, whence: int = 0) -> int:
        self._pos = self._fh.seek(offset, whence)
        return self._pos

    def truncated_bytes(self) -> int:
        """Bytes of an incomplete last message, once pyulog has stopped (0 when the file
        ends on a whole message). pyulog reads each message as its 3-byte header, then its
        payload, and stops at the first read that comes back short: a short header read
        leaves the bytes it got, a short payload read those and the header."""
        (asked0, got0), (asked1, got1) = self._tail
        if asked1 <= 0 or got1 >= asked1:
            return 0
        if asked1 == _HEADER and got1 == 0:
            return 0  # the end, between messages
        if asked0 == _HEADER and got0 == _HEADER:
            return _HEADER + got1  # inside the payload
        return got1  # inside the header

    def tell(self) -> int:
        return self._pos

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> _ProgressFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self._fh.close()


class _Topics:
    """Topic lookup by name with the instance rule of :func:`read_ulog`."""

    def __init__(self, ulog: Any, multi_id: int) -> None:
        self._by_name: dict[str, dict[int, Data]] = {}
        for d in ulog.data_list:
            self._by_name.setdefault(d.name, {})[int(d.multi_id)] = Data(d.name, d.data)
        self._multi_id = multi_id
        self.used: dict[str, str] = {}

    def get(self, name: str) -> Data | None:
        inst = self._by_name.get(name)
        if not inst:
            return None
        k = self._multi_id if self._multi_id in inst else min(inst)
        self.used[name] = f"{name}[{k}]"
        return inst[k]


def _vec(d: Data, base: str, n: int = 3) -> NDArray[np.float64]:
    return np.column_stack([np.asarray(d[f"{base}[{i}]"], dtype=np.float64) for i in range(n)])


def _stamps(d: Data) -> NDArray[np.int64]:
    """Per-row time of validity, us: ``timestamp_sample`` where logged (non-zero)."""
    t = np.asarray(d["timestamp"]).astype(np.int64)
    if "timestamp_sample" in d:
        ts = np.asarray(d["timestamp_sample"]).astype(np.int64)
        t = np.where(ts > 0, ts, t)
    return t


def _clean(
    name: str, t_us: NDArray[np.int64], t0: int, rep: RepairLog, *values: NDArray[Any]
) -> tuple[NDArray[np.float64], list[NDArray[Any]]]:
    t, vals = rep.series(name, t_us, *values)
    sec = (t - t0).astype(np.float64) * _US
    rep.locate(name, sec)
    return sec, vals


def _imu(sc: Data, t0: int, meta: dict[str, Any], rep: RepairLog) -> ImuStream:
    w = _vec(sc, "gyro_rad")
    f = _vec(sc, "accelerometer_m_s2")
    if "accelerometer_timestamp_relative" in sc:
        # One time vector for gyro and accel: the accelerometer's own offset (0 on the
        # logs seen) is recorded so a user can judge the approximation.
        rel = np.asarray(sc["accelerometer_timestamp_relative"]).astype(np.int64)
        rel = rel[rel != _REL_INVALID]
        meta["imu.accel_offset_max_s"] = float(np.abs(rel).max() * _US) if rel.size else 0.0
    t, (w, f) = _clean("imu", _stamps(sc), t0, rep, w, f)
    return ImuStream(t=t, w_b=rep.rows("imu", w, GYRO_RANGE), f_b=rep.rows("imu", f, ACCEL_RANGE))


def _ekf2_mag_bias(params: dict[str, Any], device_id: Any, meta: dict[str, Any]) -> NDArray[np.float64]:
    """The hard-iron bias (gauss, body) that EKF2 (PX4 1.12 and before) subtracts from the
    magnetometer before fusing it: its learned bias saved at disarm, ``EKF2_MAGBIAS_X/Y/Z``,
    applied when ``EKF2_MAGBIAS_ID`` is the device read (``vehicle_magnetometer``'s
    ``device_id``, else ``CAL_MAG_PRIME``), as ekf2_main.cpp does; zero otherwise (newer PX4
    saves it into the calibration that ``vehicle_magnetometer`` already applies). The
    estimators then see the field the autopilot's reference was estimated from.
    ``meta["mag.ekf2_bias_subtracted"]`` says it was (the values are ``param.EKF2_MAGBIAS_*``)."""
    try:
        bias_id = int(params.get("EKF2_MAGBIAS_ID", 0))
        dev = int(device_id if device_id is not None else params.get("CAL_MAG_PRIME", 0))
        b = np.array([float(params.get(f"EKF2_MAGBIAS_{a}", 0.0)) for a in "XYZ"])
    except (TypeError, ValueError):  # a corrupt parameter
        return np.zeros(3)
    if bias_id == 0 or dev != bias_id or not np.isfinite(b).all() or not b.any():
        return np.zeros(3)
    meta["mag.ekf2_bias_subtracted"] = True
    return b


def _mag(
    topics: _Topics, sc: Data, t0: int, meta: dict[str, Any], rep: RepairLog, params: dict[str, Any]
) -> MagStream | None:
    vm = topics.get("vehicle_magnetometer")
    if vm is not None and len(vm["timestamp"]):
        meta["mag.topic"] = topics.used["vehicle_magnetometer"]
        dev = int(np.asarray(vm["device_id"])[0]) if "device_id" in vm else None
        m = (_vec(vm, "magnetometer_ga") - _ekf2_mag_bias(params, dev, meta)) * _GAUSS
        t, (m,) = _clean("mag", _stamps(vm), t0, rep, m)
        return MagStream(t=t, mag_b=rep.rows("mag", m, MAG_RANGE))
    if "magnetometer_ga[0]" not in sc:
        return None
    # Old layout: the magnetometer rides in sensor_combined, held between its own samples;
    # its sample time is timestamp + magnetometer_timestamp_relative, and a repeated time
    # is the same sample published again (expected, so counted apart from duplicates).
    t_us = np.asarray(sc["timestamp"]).astype(np.int64)
    m = (_vec(sc, "magnetometer_ga") - _ekf2_mag_bias(params, None, meta)) * _GAUSS
    if "magnetometer_timestamp_relative" in sc:
        rel = np.asarray(sc["magnetometer_timestamp_relative"]).astype(np.int64)
        ok = rel != _REL_INVALID
        t_us, m = t_us[ok] + rel[ok], m[ok]
    t_us, (m,), counts = clean_series(t_us, m)
    meta["mag.topic"] = "sensor_combined.magnetometer_ga"
    meta["mag.held_repeats"] = counts["duplicates"]
    rep.add("mag", "reordered", counts["reordered"])
    if t_us.size == 0:
        return None
    return MagStream(t=(t_us - t0).astype(np.float64) * _US, mag_b=rep.rows("mag", m, MAG_RANGE))


def _gnss(topics: _Topics, t0: int, meta: dict[str, Any], rep: RepairLog) -> GnssStream | None:
    for name in ("vehicle_gps_position", "sensor_gps"):
        d = topics.get(name)
        if d is None or len(d["timestamp"]) == 0:
            continue
        v = np.column_stack([d[f"vel_{c}_m_s"] for c in "ned"]).astype(np.float64)
        # the receiver's speed accuracy, m/s (a standard deviation despite its name; EKF2's sacc)
        s = np.asarray(d["s_variance_m_s"], dtype=np.float64) if "s_variance_m_s" in d else np.full(len(v), np.nan)
        t_us = _stamps(d)
        if "vel_ned_valid" in d:
            ok = np.asarray(d["vel_ned_valid"]) != 0
            meta["gnss.dropped_invalid"] = int(np.count_nonzero(~ok))
            t_us, v, s = t_us[ok], v[ok], s[ok]
        if t_us.size == 0:
            continue
        meta["gnss.topic"] = topics.used[name]
        t, (v, s) = _clean("gnss", t_us, t0, rep, v, s[:, None])
        sigma = speed_accuracy(s[:, 0], meta, "s_variance_m_s")
        return GnssStream(t=t, v_n=rep.rows("gnss", v, GNSS_VELOCITY_RANGE), v_sigma=sigma)
    return None


def _air(
    topics: _Topics, t0: int, meta: dict[str, Any], rep: RepairLog, air_topic: str | None
) -> AirDataStream | None:
    names = (air_topic,) if air_topic else ("airspeed_validated", "airspeed")
    for name in names:
        d = topics.get(name)
        if d is None or len(d["timestamp"]) == 0 or "true_airspeed_m_s" not in d:
            continue
        meta["air.topic"] = topics.used[name]
        tas = np.asarray(d["true_airspeed_m_s"], dtype=np.float64)
        t, (tas,) = _clean("air", _stamps(d), t0, rep, tas)
        aoa, slip = _vanes(topics, t, t0, meta, rep)
        return AirDataStream(t=t, tas=rep.rows("air", tas, AIRSPEED_RANGE), aoa=aoa, sideslip=slip)
    return None


def _vanes(
    topics: _Topics, t: NDArray[np.float64], t0: int, meta: dict[str, Any], rep: RepairLog
) -> tuple[NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """Angle of attack and sideslip (rad) on the airspeed's time grid, or (None, None).

    PX4 logs the vanes as their own topics; AirDataStream holds one time vector, so they
    are interpolated linearly onto the airspeed samples (NaN outside the vanes' span and
    where a vane reports itself invalid).
    """
    d_aoa, d_slip = topics.get("airflow_aoa"), topics.get("airflow_slip")
    if d_aoa is None or d_slip is None:
        return None, None
    out = []
    for d, key in ((d_aoa, "aoa_rad"), (d_slip, "slip_rad")):
        if key not in d or len(d["timestamp"]) == 0:
            return None, None
        a = np.asarray(d[key], dtype=np.float64)
        if "valid" in d:
            a = np.where(np.asarray(d["valid"]) != 0, a, np.nan)
        tv, (a,), _ = clean_series(_stamps(d), a)
        a = rep.rows("air", a, ANGLE_RANGE)
        out.append(np.interp(t, (tv - t0) * _US, a, left=np.nan, right=np.nan))
    meta["air.vanes"] = "airflow_aoa/airflow_slip interpolated onto airspeed times"
    return out[0], out[1]


def _wind(topics: _Topics, t0: int, meta: dict[str, Any], rep: RepairLog) -> WindStream | None:
    for name in ("wind", "wind_estimate"):
        d = topics.get(name)
        if d is None or len(d["timestamp"]) == 0:
            continue
        n = np.asarray(d["windspeed_north"], dtype=np.float64)
        w = np.column_stack([n, d["windspeed_east"], np.zeros_like(n)])
        meta["ref_wind.topic"] = topics.used[name]
        t, (w,) = _clean("ref_wind", _stamps(d), t0, rep, w)
        return WindStream(t=t, wind_n=finite_rows(w))
    return None


_REFERENCE_TOPICS: tuple[tuple[str, ReferenceKind], ...] = (
    ("vehicle_attitude_groundtruth", "truth"),
    ("vehicle_attitude", "autopilot"),
)


def _reference(topics: _Topics, t0: int, meta: dict[str, Any], rep: RepairLog) -> Reference | None:
    for name, kind in _REFERENCE_TOPICS:
        d = topics.get(name)
        if d is None or len(d["timestamp"]) == 0:
            continue
        q, n_bad = invalid_quat_rows(_vec(d, "q", 4))
        meta["reference.topic"] = topics.used[name]
        if n_bad:
            meta["reference.invalid_quaternions"] = n_bad
        t, (q,) = _clean("reference", _stamps(d), t0, rep, q)
        return Reference(t=t, q_nb=q, kind=kind)
    return None
