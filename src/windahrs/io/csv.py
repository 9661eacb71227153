"""CSV recordings to Flight: the ALFA mavros export, and windahrs' generic CSV directory.

:func:`read_alfa` reads one sequence of the ALFA fixed-wing dataset (Keipour et al., IJRR
2021), recorded through ROS/mavros and exported one CSV file per topic, ``%time`` in ns.

:func:`read_csv_dir` reads a directory of CSV files described by a ``windahrs.toml``
manifest: units, frames and columns of each stream are declared, so any logger's export can
be read without code. The format is documented in ``docs/csv-format.md``.
"""

from __future__ import annotations

import csv
import io
import math
import os
import tomllib
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from windahrs.conventions import (
    ACCEL_UNITS,
    DEG,
    G0,
    GYRO_UNITS,
    MAG_RELATIVE_UNITS,
    MAG_UNITS,
    SPEED_UNITS,
)
from windahrs.flight import (
    DECLINATION_DEG_EXPECTED,
    AirDataStream,
    Flight,
    FlightError,
    GnssStream,
    ImuStream,
    MagStream,
    Reference,
    Site,
    WindStream,
    declination_radians,
    mag_to_tesla,
)
from windahrs.io.edge import (
    LogFormatError,
    flight_errors_name,
    invalid_quat_rows,
    velocity_from_positions,
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
    finite_rows,
)
from windahrs.rotation import (
    dcm_from_quat,
    quat_enu_flu_to_ned_frd,
    quat_enu_rfu_to_ned_frd,
    quat_from_euler,
    vec_enu_to_ned,
)

__all__ = [
    "ALFA_IMU_FILE",
    "alfa_prefix",
    "CSV_FORMAT",
    "CSV_MANIFEST",
    "MAVROS_MAG_TESLA_PER_UNIT",
    "read_alfa",
    "read_csv_dir",
]

F64 = NDArray[np.float64]

#: The file that marks a directory as an ALFA (mavros CSV) sequence: this name, or the
#: sequence's name and a dash before it, as the dataset publishes its files
#: (``carbonZ_2018-07-18-15-53-31_1_engine_failure-mavros-imu-data_raw.csv``, castacks'
#: alfa-dataset-tools; :func:`alfa_prefix`).
ALFA_IMU_FILE = "mavros-imu-data_raw.csv"
#: The manifest file of a generic CSV directory, and its ``format`` value.
CSV_MANIFEST = "windahrs.toml"
CSV_FORMAT = "windahrs.csv"
_CSV_VERSIONS = (1,)

#: mavros (before 2024) published magnetometer readings in milligauss times 1000 while
#: labelling them tesla (its ``MILLIT_TO_TESLA = 1000`` factor, mavros issue #1855):
#: one logged unit is 1e-3 mG = 1e-10 T. Checked on the ALFA data: |B| = 50 uT and a
#: 67 deg dip once rotated to NED with the autopilot attitude, as expected near Pittsburgh.
MAVROS_MAG_TESLA_PER_UNIT = 1e-10

_FLU_TO_FRD = np.array([1.0, -1.0, -1.0])  # diag(1, -1, -1): FLU body axes to FRD


# --- CSV columns ------------------------------------------------------------------------


@dataclass(frozen=True)
class _Table:
    """Columns read from one CSV file: raw time stamps and float value columns."""

    path: Path
    time: NDArray[Any]  # int64 when every stamp is an integer, else float64
    values: dict[str, F64]
    dropped_last_row: bool
    stripped: tuple[str, ...] = ()  # wanted columns whose header entry has blanks around
    untimed_rows: int = 0  # rows dropped for an empty or non-finite time stamp


class EmptyTableError(LogFormatError):
    """A CSV file that holds no sample: empty, a header alone, or no row with a time stamp."""


def _read_optional(
    path: Path, time_col: str, columns: Sequence[str], absent: dict[str, str] | None
) -> _Table | None:
    """:func:`_read_table` of a topic a recording may lack: None when the file is missing,
    or holds no sample (an exported topic that published nothing), the reason then in
    ``absent`` under the file's name and said in a UserWarning (``absent`` None: neither,
    for a topic whose silence is its message, as a failure flag's); any other problem
    raises."""
    if not path.is_file():
        return None
    try:
        return _read_table(path, time_col, columns)
    except EmptyTableError as exc:
        if absent is not None:
            absent[path.name] = exc.problem
            warnings.warn(f"{path}: {exc.problem}; read as absent", UserWarning, stacklevel=3)
        return None


def _read_table(
    path: Path, time_col: str, columns: Sequence[str], *, warn_stripped: bool = True
) -> _Table:
    """Read ``time_col`` and ``columns`` of a CSV file with a header row.

    Empty cells are NaN (missing samples). A row whose time stamp is empty, NaN or inf
    cannot be placed in time: it is dropped and counted (``untimed_rows``). A final row
    with too few fields (a file cut while being written) is dropped and flagged; any other
    malformed row is an error.
    Header names are compared after stripping blanks (spaces, tabs) around them; a column
    found only that way is named in one warning per file (``warn_stripped``; off for
    formats whose files are known to pad their header, e.g. ANSFL's DJI log).

    Well-formed numeric files are parsed by numpy (:func:`_read_table_fast`); anything
    else (empty cells, text columns, quotes, a cut last row, errors) row by row here.
    """
    if not path.is_file():
        raise LogFormatError(path, "no such file")
    fast = _read_table_fast(path, time_col, columns)
    table = fast if fast is not None else _read_table_rows(path, time_col, columns)
    if table.stripped and warn_stripped:
        names = ", ".join(repr(c) for c in table.stripped)
        warnings.warn(
            f"{path}: column(s) {names} matched the header only after stripping the blanks "
            "around the header's names",
            UserWarning,
            stacklevel=3,
        )
    return table


def _stripped(raw_header: Sequence[str], wanted: Sequence[str]) -> tuple[str, ...]:
    """The wanted columns that the raw header spells with blanks around them."""
    return tuple(c for c in wanted if c not in raw_header)


def _read_table_rows(path: Path, time_col: str, columns: Sequence[str]) -> _Table:
    """:func:`_read_table` row by row with the csv module: every file, every error."""
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            # (line number, fields); blank lines (e.g. a trailing newline) carry no sample.
            lines = [(n, r) for n, r in enumerate(csv.reader(fh), start=1) if r]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise LogFormatError(path, f"not a readable CSV file: {exc}") from None
    if not lines:
        raise EmptyTableError(path, "empty file (expected a header row)")
    header = [h.strip() for h in lines[0][1]]
    wanted = [time_col, *columns]
    stripped = _stripped(lines[0][1], wanted)
    missing = [c for c in wanted if c not in header]
    if missing:
        shown = ", ".join(header[:12]) + (", ..." if len(header) > 12 else "")
        raise LogFormatError(path, f"missing column(s) {missing}; the header has: {shown}")
    idx = [header.index(c) for c in wanted]
    rows = lines[1:]
    dropped = False
    if rows and len(rows[-1][1]) < len(header):
        rows, dropped = rows[:-1], True
    if not rows:
        raise EmptyTableError(path, "no data rows")
    cells: list[list[str]] = [[] for _ in wanted]
    for lineno, row in rows:
        if len(row) != len(header):
            raise LogFormatError(
                path, f"line {lineno}: expected {len(header)} fields, found {len(row)}"
            )
        for k, i in enumerate(idx):
            cells[k].append(row[i].strip())
    linenos = [n for n, _ in rows]
    timed = [k for k, c in enumerate(cells[0]) if not _untimed(c)]
    untimed = len(linenos) - len(timed)
    if untimed:
        cells = [[col[k] for k in timed] for col in cells]
        linenos = [linenos[k] for k in timed]
    if not linenos:
        raise EmptyTableError(path, f"no data rows with a time stamp in column {time_col!r}")
    time = _parse_time(path, time_col, cells[0], linenos)
    values = {
        c: _parse_floats(path, c, v, linenos) for c, v in zip(columns, cells[1:], strict=True)
    }
    return _Table(path, time, values, dropped, stripped, untimed)


def _untimed(cell: str) -> bool:
    """An empty, NaN or infinite time stamp (a number, but not a time)."""
    if not cell:
        return True
    try:
        return not math.isfinite(float(cell))
    except ValueError:
        return False  # not a number: an error, named by _parse_time


def _read_table_fast(path: Path, time_col: str, columns: Sequence[str]) -> _Table | None:
    """The table of a well-formed, all-numeric CSV file, parsed in C by ``numpy.loadtxt``
    (about 10 times faster than row by row: 1.5 s for an hour of 200 Hz IMU); None for any
    other file, which :func:`_read_table` then reads row by row with its exact rules and
    error messages.

    Same result as the row-by-row reader: the header is the first line, every row has as
    many fields as the header (else numpy raises and the slow path reports the line), blank
    lines are skipped, integer time stamps stay int64 (decimal ones become float64).
    """
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None
    first, sep, body = text.partition("\n")
    if not sep or not first.strip() or '"' in text:  # quoting: the csv module's rules
        return None
    raw_header = first.rstrip("\r").split(",")
    header = [h.strip() for h in raw_header]
    wanted = [time_col, *columns]
    if any(c not in header for c in wanted):
        return None
    idx = [header.index(c) for c in wanted]
    table = None
    for time_type in (np.int64, np.float64):
        dtype = np.dtype([(f"f{i}", time_type if i == idx[0] else np.float64) for i in range(len(header))])
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # "input contained no data": the slow path says so
                # numpy < 2.? parses "0.005" as int64 0 with only a DeprecationWarning: a failure here
                warnings.simplefilter("error", DeprecationWarning)
                table = np.loadtxt(io.StringIO(body), delimiter=",", dtype=dtype, comments=None, ndmin=1)
            break
        except (ValueError, DeprecationWarning):
            continue
    if table is None or len(table) == 0:
        return None
    time = np.ascontiguousarray(table[f"f{idx[0]}"])
    if time.dtype.kind == "f" and not np.isfinite(time).all():
        return None  # the slow path names the line of the bad stamp
    values = {c: np.ascontiguousarray(table[f"f{i}"]) for c, i in zip(columns, idx[1:], strict=True)}
    return _Table(path, time, values, False, _stripped(raw_header, wanted))


def _parse_time(path: Path, name: str, cells: list[str], linenos: list[int]) -> NDArray[Any]:
    # Integer stamps (ns since the epoch) keep every digit; float64 would round them.
    try:
        return np.array([int(c) for c in cells], dtype=np.int64)
    except (ValueError, OverflowError):
        pass
    t = _parse_floats(path, name, cells, linenos)
    if not np.isfinite(t).all():
        i = int(np.argmax(~np.isfinite(t)))
        raise LogFormatError(
            path, f"line {linenos[i]}, column {name!r}: expected a time stamp, found {cells[i]!r}"
        )
    return t


def _parse_floats(path: Path, name: str, cells: list[str], linenos: list[int]) -> F64:
    out = np.empty(len(cells))
    for i, c in enumerate(cells):
        if not c:
            out[i] = math.nan
            continue
        try:
            out[i] = float(c)
        except ValueError:
            raise LogFormatError(
                path, f"line {linenos[i]}, column {name!r}: expected a number, found {c!r}"
            ) from None
    return out


def _seconds(
    table: _Table, scale_ns: int, origin_ns: int, name: str, meta: dict[str, Any], rep: RepairLog
) -> tuple[F64, dict[str, F64]]:
    """Times in s from ``origin_ns`` (cleaned: sorted, duplicates dropped, counted in
    ``rep``) and values."""
    keys = list(table.values)
    t, vals = rep.series(name, table.time, *[table.values[k] for k in keys])
    rep.add(name, "unsortable", table.untimed_rows)
    if table.dropped_last_row:
        meta[f"{name}.dropped_truncated_row"] = 1
        warn_truncated(table.path, f"its last row has too few fields: read up to line {len(table.time) + 1}, "
                       "1 row dropped")
    if t.dtype.kind == "i":
        sec = (t * scale_ns - origin_ns).astype(np.float64) * 1e-9
    else:
        sec = t * (scale_ns * 1e-9) - origin_ns * 1e-9
    rep.locate(name, sec)
    return sec, dict(zip(keys, vals, strict=True))


def _first_ns(table: _Table, scale_ns: int) -> int:
    t0 = table.time.min()
    return int(t0) * scale_ns if table.time.dtype.kind == "i" else round(float(t0) * scale_ns)


def _stack(vals: dict[str, F64], cols: Sequence[str]) -> F64:
    return np.column_stack([vals[c] for c in cols])


# --- ALFA -------------------------------------------------------------------------------

_ALFA_GYRO = [f"field.angular_velocity.{c}" for c in "xyz"]
_ALFA_ACCEL = [f"field.linear_acceleration.{c}" for c in "xyz"]
_ALFA_MAG = [f"field.magnetic_field.{c}" for c in "xyz"]
_ALFA_TWIST = [f"field.twist.linear.{c}" for c in "xyz"]
_ALFA_QUAT = [f"field.orientation.{c}" for c in "wxyz"]


def alfa_prefix(d: Path) -> str | None:
    """What precedes the topic names of the ALFA sequence in directory d: "" for bare names
    (``mavros-imu-data_raw.csv``), the published ``<sequence>-`` otherwise (the one ending in
    ``-mavros-imu-data_raw.csv``; with several, the one named after the directory); None
    when d holds no ALFA IMU file."""
    if (d / ALFA_IMU_FILE).is_file():
        return ""
    try:
        found = sorted(p.name[: -len(ALFA_IMU_FILE)] for p in d.iterdir()
                       if p.name.endswith("-" + ALFA_IMU_FILE) and p.is_file())
    except OSError:
        return None
    if len(found) > 1 and f"{d.name}-" in found:
        return f"{d.name}-"
    return found[0] if found else None


def read_alfa(
    dirpath: str | os.PathLike[str],
    *,
    wind_points_from: bool = True,
    mag_tesla_per_unit: float = MAVROS_MAG_TESLA_PER_UNIT,
) -> Flight:
    """Read one ALFA sequence (a directory of mavros CSV files) into a Flight.

    ============  ==============================================================================
    Flight        file (columns; conversion)
    ============  ==============================================================================
    imu           ``mavros-imu-data_raw.csv`` (angular_velocity, linear_acceleration; ROS FLU
                  body -> FRD: x, -y, -z)
    mag           ``mavros-imu-mag.csv`` (magnetic_field, FLU -> FRD; x ``mag_tesla_per_unit``)
    gnss          ``mavros-global_position-raw-gps_vel.csv`` (twist.linear, ENU -> NED; see
                  "vertical" below)
    air           ``mavros-nav_info-airspeed.csv`` (measured) else ``mavros-vfr_hud.csv``
                  (airspeed); ArduPilot's equivalent airspeed used as TAS (``air.tas_is_eas``)
    reference     ``mavros-imu-data.csv`` (orientation x, y, z, w: ENU/FLU -> NED/FRD), kind
                  "autopilot"
    ref_wind      ``mavros-wind_estimation.csv`` (twist.linear: east, north, up)
    meta          ``failure_time`` (s): first sample of ``failure_status-*.csv``
    ============  ==============================================================================

    wind_points_from: mavros before 2019 (issue #1292; ALFA was recorded in 2018) published
    the vector pointing where the wind comes FROM, so it is negated to get the velocity of
    the air. A wind-triangle check on the ALFA sequence agrees (ground speed peaks flying
    south, with the negated vector pointing south). Pass False for later mavros recordings.
    mag_tesla_per_unit: see :data:`MAVROS_MAG_TESLA_PER_UNIT`.

    Vertical GNSS velocity: mavros builds ``global_position/raw/gps_vel`` from GPS_RAW_INT,
    which carries ground speed and course only, and leaves ``twist.linear.z`` at 0. That 0
    is not a measurement, but the Flight NaN policy makes a row with any NaN a missing
    sample, so a NaN there would drop every GNSS sample. The reader keeps the 0 as logged
    and sets ``meta["gnss.vertical_measured"]`` (False when the whole column is exactly 0).
    On the ALFA sequence the aircraft climbs and sinks at 1.3-1.7 m/s RMS (up to 8 m/s).

    Data quality, passed through as logged (the reader does not correct data): the ALFA
    magnetometer (ArduPilot's RAW_IMU field, after its own offsets) has |B| ~ 50 uT and the
    right frame, but a residual body-frame offset of about (-9, -3, +3) uT that grows with
    throttle (x: -7 uT below 20 % throttle, -17 uT at 60-80 %; -1 uT after the engine
    failure), i.e. uncompensated motor interference. Against a 18 uT horizontal field that
    is a heading error of up to ~30 deg, so magnetometer updates gated for a calibrated
    sensor are rejected. The reference yaw is true heading (ArduPilot applies the
    declination, about -9.5 deg here); the flight has no ``site.mag_n``.

    File names: as above, or each after the sequence's name and a dash, as the dataset
    publishes them (``<sequence>-mavros-imu-data_raw.csv``: :func:`alfa_prefix`).

    Time: ``%time`` (ROS receive time, ns) minus the earliest ``%time`` of the files read
    (``meta["start_time_ns"]``). Every topic but the IMU's may be missing, or exported with
    no sample (a header alone): read as absent, with a UserWarning and
    ``meta["absent_files"]`` (an empty ``failure_status-*.csv``: no failure, silently).
    Raises LogFormatError (no such directory, missing IMU file or column, an IMU file
    without a sample, malformed CSV) and FlightError (values failing validation).
    """
    d = Path(dirpath)
    if not d.is_dir():
        raise LogFormatError(d, "not a directory (an ALFA sequence is a directory of CSV files)")
    pre = alfa_prefix(d)
    if pre is None:
        raise LogFormatError(d, f"not an ALFA sequence: no {ALFA_IMU_FILE} (nor <sequence>-{ALFA_IMU_FILE})")
    tables: dict[str, _Table] = {
        "imu": _read_table(d / (pre + ALFA_IMU_FILE), "%time", _ALFA_GYRO + _ALFA_ACCEL)
    }
    optional: dict[str, tuple[str, list[str]]] = {
        "mag": ("mavros-imu-mag.csv", _ALFA_MAG),
        "gnss": ("mavros-global_position-raw-gps_vel.csv", _ALFA_TWIST),
        "reference": ("mavros-imu-data.csv", _ALFA_QUAT),
        "ref_wind": ("mavros-wind_estimation.csv", _ALFA_TWIST),
    }
    absent: dict[str, str] = {}  # (topics exported without a sample: read as absent)
    for name, (fname, cols) in optional.items():
        table = _read_optional(d / (pre + fname), "%time", cols, absent)
        if table is not None:
            tables[name] = table
    air_file = None
    for fname, col in (("mavros-nav_info-airspeed.csv", "field.measured"),
                       ("mavros-vfr_hud.csv", "field.airspeed")):
        table = _read_optional(d / (pre + fname), "%time", [col], absent)
        if table is not None:
            tables["air"] = table
            air_file = pre + fname
            break
    flag = pre + "failure_status-"
    failures = {
        f.stem.removeprefix(flag): table
        for f in sorted(p for p in d.iterdir() if p.name.startswith(flag) and p.suffix == ".csv")
        if (table := _read_optional(f, "%time", [], None)) is not None  # (empty: no failure)
    }
    for name, table in [*tables.items(), *(("failure " + k, v) for k, v in failures.items())]:
        if table.time.dtype.kind != "i":
            raise LogFormatError(table.path, f"column '%time' ({name}): expected integer ns")

    origin = min(_first_ns(t, 1) for t in tables.values())
    meta: dict[str, Any] = {"source": d.name, "format": "alfa", "start_time_ns": origin}
    if absent:
        meta["absent_files"] = "; ".join(f"{k}: {v}" for k, v in sorted(absent.items()))
    for kind, table in failures.items():
        if len(table.time):
            meta[f"failure_time.{kind}"] = (int(table.time.min()) - origin) * 1e-9
    if failures:
        first = min(failures, key=lambda k: meta.get(f"failure_time.{k}", math.inf))
        if f"failure_time.{first}" in meta:
            meta["failure_time"] = meta[f"failure_time.{first}"]
            meta["failure_type"] = first

    rep = RepairLog()

    def sec(name: str) -> tuple[F64, dict[str, F64]]:
        return _seconds(tables[name], 1, origin, name, meta, rep)

    with flight_errors_name(d):
        t, v = sec("imu")
        imu = ImuStream(
            t=t,
            w_b=rep.rows("imu", _stack(v, _ALFA_GYRO) * _FLU_TO_FRD, GYRO_RANGE),
            f_b=rep.rows("imu", _stack(v, _ALFA_ACCEL) * _FLU_TO_FRD, ACCEL_RANGE),
        )
        mag = gnss = air = reference = ref_wind = None
        if "mag" in tables:
            t, v = sec("mag")
            m = rep.rows("mag", _stack(v, _ALFA_MAG) * _FLU_TO_FRD * mag_tesla_per_unit, MAG_RANGE)
            mag = MagStream(t=t, mag_b=m)
        if "gnss" in tables:
            t, v = sec("gnss")
            gnss = GnssStream(t=t, v_n=vec_enu_to_ned(rep.rows("gnss", _stack(v, _ALFA_TWIST), GNSS_VELOCITY_RANGE)))
            # mavros fills z with 0 (no vertical speed in GPS_RAW_INT): flag, do not invent.
            up = gnss.v_n[:, 2]
            meta["gnss.vertical_measured"] = not bool(np.all(up[np.isfinite(up)] == 0.0))
        if "air" in tables:
            t, v = sec("air")
            meta["air.file"] = str(air_file)
            meta["air.tas_is_eas"] = True
            air = AirDataStream(t=t, tas=rep.rows("air", next(iter(v.values())), AIRSPEED_RANGE))
        if "reference" in tables:
            t, v = sec("reference")
            q, n_bad = invalid_quat_rows(_stack(v, _ALFA_QUAT))
            if n_bad:
                meta["reference.invalid_quaternions"] = n_bad
            ok = np.isfinite(q).all(axis=1)
            q[ok] = quat_enu_flu_to_ned_frd(q[ok])
            reference = Reference(t=t, q_nb=q, kind="autopilot")
        if "ref_wind" in tables:
            t, v = sec("ref_wind")
            w_enu = finite_rows(_stack(v, _ALFA_TWIST))
            if wind_points_from:
                w_enu = -w_enu
            meta["ref_wind.negated"] = wind_points_from
            ref_wind = WindStream(t=t, wind_n=vec_enu_to_ned(w_enu))
        return rep.attach(
            Flight(
                imu=imu, mag=mag, gnss=gnss, air=air, reference=reference, ref_wind=ref_wind,
                meta=meta, repairs=rep.counts,
            )
        )


# --- generic CSV directory ----------------------------------------------------------------

_TIME_NS = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
_MAG = (*MAG_UNITS, *MAG_RELATIVE_UNITS)
_ANGLE = {"rad": 1.0, "deg": DEG}
_FRAMES = ("ned_frd", "enu_flu", "enu_rfu")
_KINDS = ("autopilot", "mocap", "truth")
_COMMON = ("file", "time", "time_unit", "frame")
_SECTION_KEYS: dict[str, tuple[str, ...]] = {
    "imu": (*_COMMON, "gyro", "gyro_unit", "accel", "accel_unit", "mount_rpy_deg"),
    "mag": (*_COMMON, "columns", "unit", "mount_rpy_deg"),
    "gnss": (*_COMMON, "velocity", "position", "unit", "speed_accuracy"),
    "air": (*_COMMON, "tas", "unit", "aoa", "sideslip", "angle_unit"),
    "reference": (*_COMMON, "kind", "heading_free", "quaternion", "quaternion_order", "euler",
                  "angle_unit"),
    "ref_wind": (*_COMMON, "columns", "unit", "convention"),
}
_TOP_KEYS = ("format", "version", "flight", *_SECTION_KEYS)
_FLIGHT_KEYS = ("time_origin", "gravity", "mag_n", "declination_deg", "meta")

# WGS-84, for GNSS velocity derived from positions.
_WGS84_A = 6378137.0
_WGS84_E2 = 6.69437999014e-3


class _Manifest:
    """Typed access to a parsed manifest; every error names the key, expected and found."""

    def __init__(self, path: Path, data: dict[str, Any]) -> None:
        self.path = path
        self.data = data

    def fail(self, key: str, expected: str, found: Any) -> LogFormatError:
        return LogFormatError(
            self.path, f"manifest key {key!r}: expected {expected}, found {found!r}"
        )

    def section(self, name: str) -> dict[str, Any] | None:
        sec = self.data.get(name)
        if sec is None:
            return None
        if not isinstance(sec, dict):
            raise self.fail(name, "a table [" + name + "]", sec)
        allowed = _SECTION_KEYS.get(name, _FLIGHT_KEYS)
        for k in sec:
            if k not in allowed:
                raise self.fail(f"{name}.{k}", f"one of {list(allowed)}", "an unknown key")
        return sec

    def get(self, sec: str, key: str, default: Any = None, *, required: bool = False) -> Any:
        table = self.data.get(sec) or {}
        if key not in table:
            if required:
                raise self.fail(f"{sec}.{key}", "a value (required)", "nothing")
            return default
        return table[key]

    def choice(self, sec: str, key: str, table: dict[str, Any] | Sequence[str],
               default: str | None = None) -> str:
        v = self.get(sec, key, default, required=default is None)
        if v not in table:
            raise self.fail(f"{sec}.{key}", f"one of {list(table)}", v)
        return str(v)

    def text(self, sec: str, key: str) -> str:
        v = self.get(sec, key, required=True)
        if not isinstance(v, str) or not v:
            raise self.fail(f"{sec}.{key}", "a column or file name (string)", v)
        return v

    def names(self, sec: str, key: str, n: int) -> list[str]:
        v = self.get(sec, key, required=True)
        if not (isinstance(v, list) and len(v) == n and all(isinstance(c, str) for c in v)):
            raise self.fail(f"{sec}.{key}", f"a list of {n} column names", v)
        return list(v)

    def numbers(self, sec: str, key: str, n: int, what: str) -> F64:
        v = self.get(sec, key, required=True)
        if not (isinstance(v, list) and len(v) == n
                and all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
                and all(math.isfinite(x) for x in v)):
            raise self.fail(f"{sec}.{key}", f"a list of {n} finite numbers ({what})", v)
        return np.array(v, dtype=np.float64)

    def has(self, sec: str, key: str) -> bool:
        return key in (self.data.get(sec) or {})


def read_csv_dir(dirpath: str | os.PathLike[str]) -> Flight:
    """Read a generic CSV directory (or its ``windahrs.toml`` manifest) into a Flight.

    The manifest names, for each stream, its file, time column and unit, value columns,
    units and frame; readings are converted to SI, NED/FRD and seconds here. See
    ``docs/csv-format.md`` for every key. Raises LogFormatError (missing manifest or file,
    bad manifest entry: the message names the key, the expected and the found value;
    missing column; malformed CSV) and FlightError (values failing validation).
    """
    p = Path(dirpath)
    mpath = p if p.is_file() else p / CSV_MANIFEST
    if not mpath.is_file():
        raise LogFormatError(p, f"no manifest {CSV_MANIFEST} (see docs/csv-format.md)")
    try:
        data = tomllib.loads(mpath.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise LogFormatError(mpath, f"not a valid TOML manifest: {exc}") from None
    man = _Manifest(mpath, data)
    for k in data:
        if k not in _TOP_KEYS:
            raise man.fail(k, f"one of {list(_TOP_KEYS)}", "an unknown key")
    if data.get("format") != CSV_FORMAT:
        raise man.fail("format", repr(CSV_FORMAT), data.get("format"))
    if data.get("version") not in _CSV_VERSIONS:
        raise man.fail("version", f"one of {list(_CSV_VERSIONS)}", data.get("version"))
    for name in ("flight", *_SECTION_KEYS):
        man.section(name)  # checks that each table holds known keys only
    if "imu" not in data:
        raise man.fail("imu", "an [imu] table (the IMU stream is required)", None)
    base = mpath.parent

    tables: dict[str, tuple[_Table, int]] = {}
    for name, (cols_of, _) in _STREAMS.items():
        if name not in data:
            continue
        table = _read_table(base / man.text(name, "file"), man.text(name, "time"), cols_of(man))
        tables[name] = (table, _TIME_NS[man.choice(name, "time_unit", _TIME_NS)])

    origin_mode = man.choice("flight", "time_origin", ("first_sample", "none"), "first_sample")
    origin = 0
    if origin_mode == "first_sample":
        origin = min(_first_ns(tab, scale) for tab, scale in tables.values())
    meta: dict[str, Any] = {"source": base.name, "format": "csv", "start_time_ns": origin}
    user_meta = man.get("flight", "meta", {})
    if not isinstance(user_meta, dict):
        raise man.fail("flight.meta", "a table of names and values", user_meta)
    for k, v in user_meta.items():
        if not isinstance(v, str | int | float | bool):
            raise man.fail(f"flight.meta.{k}", "a string, number or boolean", v)
        meta[str(k)] = v
    streams: dict[str, Any] = {}
    with flight_errors_name(mpath):
        site = _site(man)
        rep = RepairLog()
        for name, (table, scale) in tables.items():
            t, vals = _seconds(table, scale, origin, name, meta, rep)
            streams[name] = _STREAMS[name][1](man, t, vals, meta, rep)
        return rep.attach(Flight(**streams, site=site, meta=meta, repairs=rep.counts))


def _site(man: _Manifest) -> Site:
    gravity = man.get("flight", "gravity", G0)
    mag_n = man.get("flight", "mag_n", None)
    if not isinstance(gravity, int | float) or isinstance(gravity, bool):
        raise man.fail("flight.gravity", "a number in m/s^2", gravity)
    if mag_n is not None and not (
        isinstance(mag_n, list) and len(mag_n) == 3
        and all(isinstance(x, int | float) for x in mag_n)
    ):
        raise man.fail("flight.mag_n", "a list of 3 numbers (tesla, NED)", mag_n)
    decl = man.get("flight", "declination_deg", None)
    try:
        declination = None if decl is None else declination_radians(decl, "flight.declination_deg")
    except FlightError:
        raise man.fail("flight.declination_deg", DECLINATION_DEG_EXPECTED, decl) from None
    return Site(
        gravity=float(gravity),
        mag_n=None if mag_n is None else np.array(mag_n, float),
        declination=declination,
    )


def _body_nav(frame: str) -> tuple[Callable[[F64], F64], Callable[[F64], F64]]:
    """Vector conversions (body -> FRD, nav -> NED) for a declared frame."""
    if frame == "ned_frd":
        return (lambda v: v), (lambda v: v)
    if frame == "enu_flu":
        return (lambda v: v * _FLU_TO_FRD), vec_enu_to_ned
    return vec_enu_to_ned, vec_enu_to_ned  # enu_rfu: RFU -> FRD is the same matrix


def _frame(man: _Manifest, sec: str) -> str:
    return man.choice(sec, "frame", _FRAMES, "ned_frd")


def _imu_cols(man: _Manifest) -> list[str]:
    return man.names("imu", "gyro", 3) + man.names("imu", "accel", 3)


def _csv_imu(man: _Manifest, t: F64, v: dict[str, F64], meta: dict[str, Any], rep: RepairLog) -> ImuStream:
    body, _ = _body_nav(_frame(man, "imu"))
    cols = _imu_cols(man)
    kw = GYRO_UNITS[man.choice("imu", "gyro_unit", GYRO_UNITS)]
    ka = ACCEL_UNITS[man.choice("imu", "accel_unit", ACCEL_UNITS)]
    mount = _mount(man, "imu", meta)
    w = mount(body(_stack(v, cols[:3]) * kw))
    f = mount(body(_stack(v, cols[3:]) * ka))
    return ImuStream(t=t, w_b=rep.rows("imu", w, GYRO_RANGE), f_b=rep.rows("imu", f, ACCEL_RANGE))


def _mount(man: _Manifest, sec: str, meta: dict[str, Any]) -> Callable[[F64], F64]:
    """The sensor-to-body rotation of ``[sec] mount_rpy_deg`` (the magnetometer takes the
    IMU's when it has none of its own): ZYX Euler angles of the sensor's axes (FRD after
    the ``frame`` conversion) in the body frame, ``C_bs = Rz(yaw) Ry(pitch) Rx(roll)``,
    applied as ``v_b = C_bs v_s``. Identity when neither table gives one."""
    src = sec if man.has(sec, "mount_rpy_deg") else "imu"
    if not man.has(src, "mount_rpy_deg"):
        return lambda v: v
    rpy = man.numbers(src, "mount_rpy_deg", 3, "roll, pitch, yaw in degrees")
    meta[f"{sec}.mount_rpy_deg"] = ", ".join(f"{a:g}" for a in rpy)
    c_bs = dcm_from_quat(quat_from_euler(rpy * DEG))
    return lambda v: v @ c_bs.T


def _mag_cols(man: _Manifest) -> list[str]:
    return man.names("mag", "columns", 3)


def _csv_mag(man: _Manifest, t: F64, v: dict[str, F64], meta: dict[str, Any], rep: RepairLog) -> MagStream:
    body, _ = _body_nav(_frame(man, "mag"))
    unit = man.choice("mag", "unit", _MAG)
    mount = _mount(man, "mag", meta)
    m = mag_to_tesla(finite_rows(_stack(v, _mag_cols(man))), unit,
                     site_mag_n=_site(man).mag_n, name="mag.unit", meta=meta)
    return MagStream(t=t, mag_b=rep.rows("mag", mount(body(m)), MAG_RANGE))


def _gnss_cols(man: _Manifest) -> list[str]:
    if man.has("gnss", "velocity") == man.has("gnss", "position"):
        raise man.fail("gnss.velocity/gnss.position", "exactly one of the two", "both or neither")
    cols = man.names("gnss", "velocity" if man.has("gnss", "velocity") else "position", 3)
    if man.has("gnss", "speed_accuracy"):  # (the receiver's speed accuracy: GnssStream.v_sigma)
        cols.append(man.text("gnss", "speed_accuracy"))
    return cols


def _csv_gnss(man: _Manifest, t: F64, v: dict[str, F64], meta: dict[str, Any], rep: RepairLog) -> GnssStream:
    cols = _gnss_cols(man)[:3]
    if man.has("gnss", "velocity"):
        _, nav = _body_nav(_frame(man, "gnss"))
        k = SPEED_UNITS[man.choice("gnss", "unit", SPEED_UNITS, "m/s")]
        sigma = None
        if man.has("gnss", "speed_accuracy"):  # (in the velocity's unit; NaN where not given)
            name = man.text("gnss", "speed_accuracy")
            sigma = np.asarray(v[name], dtype=np.float64) * k
            meta["gnss.v_sigma"] = f"column {name!r} (the receiver's speed accuracy)"
        return GnssStream(t=t, v_n=rep.rows("gnss", nav(_stack(v, cols) * k), GNSS_VELOCITY_RANGE), v_sigma=sigma)
    if man.has("gnss", "speed_accuracy"):
        raise man.fail("gnss.speed_accuracy", "velocity columns to go with it (not position)", "position")
    meta["gnss.derived_from"] = "position"
    return GnssStream(t=t, v_n=rep.rows("gnss", _velocity_from_positions(t, _stack(v, cols)), GNSS_VELOCITY_RANGE))


def _velocity_from_positions(t: F64, lla: F64) -> F64:
    """NED velocity (N, 3) m/s from latitude, longitude (deg) and height (m, up).

    Positions go to ECEF (WGS-84) and then to a local NED tangent plane at the first valid
    fix; velocity is their time derivative (:func:`~windahrs.io.edge.velocity_from_positions`:
    central differences, one-sided at the ends). NaN positions give NaN velocities beside them.
    """
    lat, lon, h = lla[:, 0] * DEG, lla[:, 1] * DEG, lla[:, 2]
    n = _WGS84_A / np.sqrt(1.0 - _WGS84_E2 * np.sin(lat) ** 2)
    ecef = np.column_stack([
        (n + h) * np.cos(lat) * np.cos(lon),
        (n + h) * np.cos(lat) * np.sin(lon),
        (n * (1.0 - _WGS84_E2) + h) * np.sin(lat),
    ])
    ok = np.isfinite(ecef).all(axis=1)
    if ok.sum() < 2:
        return np.full_like(ecef, np.nan)
    i0 = int(np.argmax(ok))
    la, lo = lat[i0], lon[i0]
    # Rows of C_ne: north, east, down unit vectors in ECEF at the origin.
    c_ne = np.array([
        [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
        [-np.sin(lo), np.cos(lo), 0.0],
        [-np.cos(la) * np.cos(lo), -np.cos(la) * np.sin(lo), -np.sin(la)],
    ])
    return velocity_from_positions(t, (ecef - ecef[i0]) @ c_ne.T)


def _air_cols(man: _Manifest) -> list[str]:
    cols = [man.text("air", "tas")]
    return cols + [man.text("air", k) for k in ("aoa", "sideslip") if man.has("air", k)]


def _csv_air(man: _Manifest, t: F64, v: dict[str, F64], meta: dict[str, Any], rep: RepairLog) -> AirDataStream:
    cols = _air_cols(man)
    k = SPEED_UNITS[man.choice("air", "unit", SPEED_UNITS, "m/s")]
    tas = rep.rows("air", v[cols[0]] * k, AIRSPEED_RANGE)
    if len(cols) == 1:
        return AirDataStream(t=t, tas=tas)
    ka = _ANGLE[man.choice("air", "angle_unit", _ANGLE, "rad")]
    # One vane alone: the stream stores the other angle as NaN (samples without vanes).
    vanes = {
        name: rep.rows("air", v[man.text("air", name)] * ka, ANGLE_RANGE) if man.has("air", name) else None
        for name in ("aoa", "sideslip")
    }
    return AirDataStream(t=t, tas=tas, **vanes)


def _ref_cols(man: _Manifest) -> list[str]:
    if man.has("reference", "quaternion") == man.has("reference", "euler"):
        raise man.fail("reference.quaternion/reference.euler", "exactly one of the two",
                       "both or neither")
    if man.has("reference", "quaternion"):
        return man.names("reference", "quaternion", 4)
    return man.names("reference", "euler", 3)


def _csv_reference(
    man: _Manifest, t: F64, v: dict[str, F64], meta: dict[str, Any], rep: RepairLog
) -> Reference:
    frame = _frame(man, "reference")
    kind = man.choice("reference", "kind", _KINDS, "autopilot")
    heading_free = man.get("reference", "heading_free", False)
    if not isinstance(heading_free, bool):
        raise man.fail("reference.heading_free", "true or false", heading_free)
    cols = _ref_cols(man)
    a = _stack(v, cols)
    if man.has("reference", "quaternion"):
        order = man.choice("reference", "quaternion_order", ("wxyz", "xyzw"), "wxyz")
        q = a if order == "wxyz" else a[:, [3, 0, 1, 2]]
    else:
        if frame == "enu_rfu":
            raise man.fail("reference.frame", "'ned_frd' or 'enu_flu' with Euler angles "
                           "(ZYX); give enu_rfu attitudes as quaternions", frame)
        k = _ANGLE[man.choice("reference", "angle_unit", _ANGLE, "deg")]
        q = quat_from_euler(a * k)
    q, n_bad = invalid_quat_rows(q)
    if n_bad:
        meta["reference.invalid_quaternions"] = n_bad
    ok = np.isfinite(q).all(axis=1)
    if frame == "enu_flu":
        q[ok] = quat_enu_flu_to_ned_frd(q[ok])
    elif frame == "enu_rfu":
        q[ok] = quat_enu_rfu_to_ned_frd(q[ok])
    return Reference(t=t, q_nb=q, kind=kind, heading_free=heading_free)  # type: ignore[arg-type]


def _wind_cols(man: _Manifest) -> list[str]:
    return man.names("ref_wind", "columns", 3)


def _csv_wind(man: _Manifest, t: F64, v: dict[str, F64], meta: dict[str, Any], rep: RepairLog) -> WindStream:
    _, nav = _body_nav(_frame(man, "ref_wind"))
    k = SPEED_UNITS[man.choice("ref_wind", "unit", SPEED_UNITS, "m/s")]
    sign = -1.0 if man.choice("ref_wind", "convention", ("to", "from"), "to") == "from" else 1.0
    return WindStream(t=t, wind_n=nav(finite_rows(_stack(v, _wind_cols(man))) * k * sign))


#: Per stream: the columns its manifest table names, and the builder of its record.
_STREAMS: dict[str, tuple[Callable[[_Manifest], list[str]], Callable[..., Any]]] = {
    "imu": (_imu_cols, _csv_imu),
    "mag": (_mag_cols, _csv_mag),
    "gnss": (_gnss_cols, _csv_gnss),
    "air": (_air_cols, _csv_air),
    "reference": (_ref_cols, _csv_reference),
    "ref_wind": (_wind_cols, _csv_wind),
}
