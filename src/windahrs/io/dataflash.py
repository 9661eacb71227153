"""ArduPilot DataFlash logs (``.bin`` binary, ``.log`` binary or text) to Flight, with pymavlink.

Messages read (ArduPilot's log messages are FRD body and NED already):

==========  ================================================================================
Flight      DataFlash message (fields, units)
==========  ================================================================================
imu         ``IMU`` (``GyrX/Y/Z`` rad/s, ``AccX/Y/Z`` m/s^2), instance ``I`` = ``instance``
mag         ``MAG`` (``MagX/Y/Z``, milligauss -> tesla x 1e-7)
gnss        ``GPS`` (``Spd`` m/s, ``GCrs`` deg, ``VZ`` m/s down): north = Spd cos(GCrs),
            east = Spd sin(GCrs), down = VZ; only rows with ``Status`` >= 3 (3-D fix);
            the receiver's speed accuracy from ``GPA`` (``SAcc`` m/s, logged with each
            ``GPS`` row at its ``TimeUS``) as ``v_sigma``
air         ``ARSP`` (``Airspeed``). ArduPilot logs the *equivalent* airspeed; it is used as
            the true airspeed, an approximation that under-reads TAS by about
            sqrt(rho0/rho) - 1: 1.5 % per 300 m of density altitude. ``meta["air.tas_is_eas"]``
            says so. No vanes (ArduPilot's ``AOA`` message is an estimate, not a sensor).
reference   ``XKQ`` (``Q1..Q4`` = w, x, y, z, EKF3 core ``core``) else ``XKQ1``/``NKQ1``
            (older EKF3/EKF2 core 0) else ``ATT`` (``Roll``, ``Pitch``, ``Yaw`` deg, ZYX)
            else ``AHR2``: kind "autopilot"
ref_wind    ``XKF2`` (``VWN``, ``VWE`` m/s; the EKF's wind state is the velocity of the air)
            else ``NKF2``; down = 0
site        declination from ``PARM`` ``COMPASS_DEC`` (radians; 0, the default, is unknown):
            what ArduPilot's EKF used, so estimated headings are true, as ``XKQ``'s is;
            the field itself is unknown
meta        ``PARM`` (``Name``, ``Value``): ``param.EK3_*``, ``param.EK2_*`` and
            ``param.COMPASS_DEC``, first value
==========  ================================================================================

Time: ``TimeUS`` (microseconds since boot) minus the earliest ``TimeUS`` of the messages
read, in seconds; the absolute start is ``meta["start_time_us"]``. Newer logs hold all
instances in one message with an ``I`` (sensor) or ``C`` (EKF core) field; older logs use
separate names (``IMU2``, ``XKQ2``), of which the first (unnumbered) one is read.
"""

from __future__ import annotations

import contextlib
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from windahrs.conventions import DEG
from windahrs.flight import (
    AirDataStream,
    Flight,
    GnssStream,
    ImuStream,
    MagStream,
    Reference,
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
    GNSS_VELOCITY_RANGE,
    GYRO_RANGE,
    MAG_RANGE,
    RepairLog,
    finite_rows,
)
from windahrs.rotation import quat_from_euler

__all__ = ["DATAFLASH_MESSAGES", "read_dataflash"]

_MILLIGAUSS = 1e-7  # tesla per milligauss
_US = 1e-6
_HEAD = b"\xa3\x95\x80"  # every binary DataFlash log opens with an FMT message
_GPS_3D_FIX = 3
#: ``TimeUS`` beyond this (2**53 us, 285 years since boot) is a corrupt stamp, not a time.
_MAX_TIME_US = 2**53

#: Fields read from each message (the first column of each row is the message name).
_FIELDS: dict[str, tuple[str, ...]] = {
    "IMU": ("GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"),
    "MAG": ("MagX", "MagY", "MagZ"),
    "GPS": ("Status", "Spd", "GCrs", "VZ"),
    "GPA": ("SAcc",),
    "ARSP": ("Airspeed",),
    "XKQ": ("Q1", "Q2", "Q3", "Q4"),
    "XKQ1": ("Q1", "Q2", "Q3", "Q4"),
    "NKQ1": ("Q1", "Q2", "Q3", "Q4"),
    "ATT": ("Roll", "Pitch", "Yaw"),
    "AHR2": ("Roll", "Pitch", "Yaw"),
    "XKF2": ("VWN", "VWE"),
    "NKF2": ("VWN", "VWE"),
}
#: Every message type the reader uses.
DATAFLASH_MESSAGES: tuple[str, ...] = (*_FIELDS, "PARM")
_PARAM_PREFIXES = ("EK3_", "EK2_")
#: ArduPilot's declination parameter, radians (set by hand, or from its World Magnetic
#: Model table when COMPASS_AUTODEC is on; ArduPilot parameter reference).
_DECLINATION_PARAMS = (("COMPASS_DEC", 1.0),)

_Rows = dict[str, list[tuple[int, tuple[float, ...]]]]


def read_dataflash(
    path: str | os.PathLike[str], *, instance: int = 0, core: int = 0
) -> Flight:
    """Read an ArduPilot DataFlash log into a Flight.

    path: ``.bin`` (binary) or ``.log`` (binary or text) log. instance: which sensor
    instance (``I`` field) to read. core: which EKF core (``C`` field) gives the reference
    attitude and wind.

    A binary log cut inside its last message is read up to the message before, with a
    TruncatedLogWarning and ``meta["dataflash.truncated_bytes"]``; the samples are repaired
    as :mod:`windahrs.repair` says (``Flight.repairs``).

    Raises LogFormatError (missing, empty, not DataFlash, no IMU messages) and FlightError
    (values failing validation; field prefixed by the file).
    """
    p = Path(path)
    with captured_output() as chatter:
        log = _open(p)
        try:
            rows, params, bad_time = guard(
                p, "unreadable DataFlash contents", lambda: _collect(log, instance, core)
            )
            cut = _truncated_bytes(log)
        finally:
            with contextlib.suppress(Exception):
                log.close()
    imu_rows = rows.get("IMU", [])
    if not imu_rows:
        dropped = f" ({bad_time} messages with a corrupt TimeUS dropped)" if bad_time else ""
        raise LogFormatError(
            p, f"no 'IMU' messages (the IMU data a Flight needs); truncated?{dropped}"
        )
    t0 = min(min(row[0] for row in r) for r in rows.values())
    meta: dict[str, Any] = {
        "source": p.name,
        "format": "dataflash",
        "start_time_us": t0,
        "dataflash.parser_messages": len(chatter.lines),
    }
    if bad_time:
        meta["dataflash.dropped_bad_time"] = bad_time
    if cut:
        meta["dataflash.truncated_bytes"] = cut
        warn_truncated(p, f"its last message is incomplete: read up to byte {p.stat().st_size - cut}, "
                       f"{cut} bytes dropped")
    meta.update(params)

    rep = RepairLog()
    with flight_errors_name(p):
        t, a = _series("imu", rows["IMU"], t0, rep)
        imu = ImuStream(t=t, w_b=rep.rows("imu", a[:, 0:3], GYRO_RANGE), f_b=rep.rows("imu", a[:, 3:6], ACCEL_RANGE))
        return rep.attach(
            Flight(
                imu=imu,
                mag=_mag(rows, t0, rep),
                gnss=_gnss(rows, t0, meta, rep),
                air=_air(rows, t0, meta, rep),
                reference=_reference(rows, t0, meta, rep),
                ref_wind=_wind(rows, t0, meta, rep),
                site=autopilot_site({k.removeprefix("param."): v for k, v in params.items()},
                                    _DECLINATION_PARAMS, meta),
                meta=meta,
                repairs=rep.counts,
            )
        )


def _truncated_bytes(log: Any) -> int:
    """Bytes of an incomplete last message of a binary log (0 when it ends on a whole one).

    pymavlink's index holds the offset of every message header it met, the last one
    included even when the file ends inside it; its format gives its length."""
    offsets = getattr(log, "offsets", None)
    data_len = getattr(log, "data_len", None)
    if not isinstance(offsets, list) or not isinstance(data_len, int):
        return 0  # a text log: no byte offsets
    last = max(((o[-1], mtype) for mtype, o in enumerate(offsets) if o), default=None)
    if last is None or last[1] not in log.formats:
        return 0
    ofs, mtype = last
    end = ofs + int(log.formats[mtype].len)
    return data_len - ofs if end > data_len else 0


def _open(p: Path) -> Any:
    """Sniff the file and open it with the matching pymavlink reader.

    ``mavutil.mavlink_connection`` picks the reader by extension only and treats a binary
    ``.log`` as a telemetry stream; sniffing the first bytes reads both kinds of ``.log``
    and rejects other files before pymavlink scans them byte by byte.
    """
    if not p.is_file():
        raise LogFormatError(p, "no such file")
    with p.open("rb") as fh:
        head = fh.read(8000)
    if not head:
        raise LogFormatError(p, "empty file")
    from pymavlink import DFReader  # optional dependency (extra "logs")

    if head.startswith(_HEAD):
        cls = DFReader.DFReader_binary
    elif b"FMT," in head:
        cls = DFReader.DFReader_text
    else:
        raise LogFormatError(
            p, "not a DataFlash log (no FMT message: binary logs start with bytes A3 95 80)"
        )
    return guard(p, "not a readable DataFlash log (truncated or corrupt?)", lambda: cls(str(p)))


def _collect(log: Any, instance: int, core: int) -> tuple[_Rows, dict[str, float], int]:
    """One pass over the log: rows ``(TimeUS, values)`` per message type (the types seen),
    the parameters kept, and how many rows were dropped for a corrupt ``TimeUS`` (negative
    or beyond :data:`_MAX_TIME_US`)."""
    rows: _Rows = {k: [] for k in _FIELDS}
    params: dict[str, float] = {}
    bad_time = 0
    while True:
        m = log.recv_match(type=list(DATAFLASH_MESSAGES))
        if m is None:
            break
        name = m.get_type()
        cols = m.get_fieldnames()
        if name == "PARM":
            pname = str(m.Name)
            keep = pname.startswith(_PARAM_PREFIXES) or pname in dict(_DECLINATION_PARAMS)
            if keep and f"param.{pname}" not in params:
                params[f"param.{pname}"] = param_float(m.Value)
            continue
        if name not in rows or "TimeUS" not in cols:
            continue
        if "I" in cols and int(m.I) != instance:
            continue
        if "C" in cols and int(m.C) != core:
            continue
        t_us = int(m.TimeUS)
        if not 0 <= t_us <= _MAX_TIME_US:
            bad_time += 1
            continue
        vals = tuple(_num(getattr(m, f)) for f in _FIELDS[name])
        rows[name].append((t_us, vals))
    return {k: v for k, v in rows.items() if v}, params, bad_time


def _num(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _series(
    name: str, rows: list[tuple[int, tuple[float, ...]]], t0: int, rep: RepairLog
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Time (s from t0) and values (N, k) of one message type, sorted, duplicates dropped
    (counted on ``name``)."""
    t_us = np.array([r[0] for r in rows], dtype=np.int64)
    vals = np.array([r[1] for r in rows], dtype=np.float64)
    t_us, (vals,) = rep.series(name, t_us, vals)
    sec = (t_us - t0).astype(np.float64) * _US
    rep.locate(name, sec)  # (before a reader drops rows: GNSS without a fix)
    return sec, vals


def _mag(rows: _Rows, t0: int, rep: RepairLog) -> MagStream | None:
    if "MAG" not in rows:
        return None
    t, a = _series("mag", rows["MAG"], t0, rep)
    return MagStream(t=t, mag_b=rep.rows("mag", a * _MILLIGAUSS, MAG_RANGE))


def _gnss(rows: _Rows, t0: int, meta: dict[str, Any], rep: RepairLog) -> GnssStream | None:
    if "GPS" not in rows:
        return None
    t, a = _series("gnss", rows["GPS"], t0, rep)
    ok = a[:, 0] >= _GPS_3D_FIX
    meta["gnss.dropped_no_3d_fix"] = int(np.count_nonzero(~ok))
    if not ok.any():
        return None
    spd, crs, vz = a[ok, 1], a[ok, 2] * DEG, a[ok, 3]
    v_n = np.column_stack([spd * np.cos(crs), spd * np.sin(crs), vz])
    sigma = None if "GPA" not in rows else speed_accuracy(_gpa_sacc(rows["GPA"], t0, t[ok]), meta, "GPA.SAcc")
    return GnssStream(t=t[ok], v_n=rep.rows("gnss", v_n, GNSS_VELOCITY_RANGE), v_sigma=sigma)


def _gpa_sacc(gpa: list[tuple[int, tuple[float, ...]]], t0: int, t: NDArray[np.float64]) -> NDArray[np.float64]:
    """``GPA.SAcc`` (m/s) at the GNSS times t (s from t0), from the GPA rows (at least one):
    ArduPilot logs a GPA row with each GPS row at the same ``TimeUS``; NaN where none
    matches."""
    t_us = np.array([r[0] for r in gpa], dtype=np.int64)
    s = np.array([r[1][0] for r in gpa], dtype=np.float64)
    order = np.argsort(t_us, kind="stable")
    sec, s = (t_us[order] - t0).astype(np.float64) * _US, s[order]
    i = np.clip(np.searchsorted(sec, t), 0, len(sec) - 1)
    return np.asarray(np.where(sec[i] == t, s[i], np.nan), dtype=np.float64)


def _air(rows: _Rows, t0: int, meta: dict[str, Any], rep: RepairLog) -> AirDataStream | None:
    if "ARSP" not in rows:
        return None
    t, a = _series("air", rows["ARSP"], t0, rep)
    meta["air.tas_is_eas"] = True
    return AirDataStream(t=t, tas=rep.rows("air", a[:, 0], AIRSPEED_RANGE))


def _reference(rows: _Rows, t0: int, meta: dict[str, Any], rep: RepairLog) -> Reference | None:
    for name in ("XKQ", "XKQ1", "NKQ1", "ATT", "AHR2"):
        if name not in rows:
            continue
        t, a = _series("reference", rows[name], t0, rep)
        if name in ("ATT", "AHR2"):
            q = quat_from_euler(a * DEG)
        else:
            q = a
        q, n_bad = invalid_quat_rows(q)
        meta["reference.message"] = name
        if n_bad:
            meta["reference.invalid_quaternions"] = n_bad
        return Reference(t=t, q_nb=q, kind="autopilot")
    return None


def _wind(rows: _Rows, t0: int, meta: dict[str, Any], rep: RepairLog) -> WindStream | None:
    for name in ("XKF2", "NKF2"):
        if name not in rows:
            continue
        t, a = _series("ref_wind", rows[name], t0, rep)
        meta["ref_wind.message"] = name
        wind = np.column_stack([a[:, 0], a[:, 1], np.zeros(len(t))])
        return WindStream(t=t, wind_n=finite_rows(wind))
    return None
