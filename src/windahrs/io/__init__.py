"""Readers that turn real recordings into :class:`~windahrs.flight.Flight`.

Units, frames and time stamps are converted here, at the edge: a Flight is SI, NED/FRD,
float seconds from the recording's start. Each source's own attitude (autopilot estimate,
motion capture, simulator truth) becomes a labelled :class:`~windahrs.flight.Reference`,
and a logged wind estimate becomes ``Flight.ref_wind`` (velocity of the air, NED).

Every reader repairs what a real log gets wrong instead of refusing it, with one policy
(:mod:`windahrs.repair`) and a count per stream and kind in ``Flight.repairs``: time stamps
out of order sorted, repeated ones dropped, infinite values and samples beyond the sensor's
range set to NaN. A log cut inside its last message (ULog, DataFlash) or row (CSV) is read up
to the last complete one with a :class:`~windahrs.io.edge.TruncatedLogWarning` saying how
many bytes or rows were dropped.

:func:`read_flight` picks the reader from the path:

==============  ===========================================================================
format          recognised by
==============  ===========================================================================
``ulog``        ``.ulg`` (PX4 ULog), or the ULog magic bytes
``dataflash``   ``.bin`` / ``.log`` (ArduPilot DataFlash, binary or text)
``broad``       ``.hdf5`` / ``.h5`` with an ``imu_gyr`` dataset (BROAD benchmark trial)
``windahrs``    HDF5 whose root attribute ``format`` is ``"windahrs.flight"``
                (:func:`windahrs.store.load_flight`)
``alfa``        a directory holding ``mavros-imu-data_raw.csv`` (ALFA, mavros CSV export)
``csv``         a directory holding ``windahrs.toml`` (or that file): generic CSV,
                ``docs/csv-format.md``
``ansfl``       a directory holding ``GT.csv`` and at least one ``IMU_<k>.csv`` (ANSFL
                quadrotor dataset: DJI flight log and Xsens DOT IMUs)
``asl``         a directory holding ``mav0/imu0/data.csv``, or such a ``mav0`` (the ASL
                layout: EuRoC MAV, TUM-VI; :mod:`windahrs.io.asl`)
==============  ===========================================================================
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from windahrs.flight import Flight
from windahrs.io.ansfl import ANSFL_GT_FILE, is_ansfl_dir, read_ansfl
from windahrs.io.asl import is_asl_dir, read_asl
from windahrs.io.broad import broad_movement_mask, read_broad
from windahrs.io.csv import ALFA_IMU_FILE, CSV_MANIFEST, alfa_prefix, read_alfa, read_csv_dir
from windahrs.io.dataflash import read_dataflash
from windahrs.io.edge import LogFormatError, TruncatedLogWarning
from windahrs.io.ulog import read_ulog

__all__ = [
    "FORMATS",
    "LogFormatError",
    "TruncatedLogWarning",
    "broad_movement_mask",
    "detect_format",
    "read_alfa",
    "read_ansfl",
    "read_asl",
    "read_broad",
    "read_csv_dir",
    "read_dataflash",
    "read_flight",
    "read_ulog",
]

#: The formats :func:`read_flight` knows, by name (the ``fmt`` argument).
FORMATS: tuple[str, ...] = ("ulog", "dataflash", "broad", "windahrs", "alfa", "csv", "ansfl", "asl")

_ULOG_MAGIC = b"ULog\x01\x12\x35"
_DATAFLASH_MAGIC = b"\xa3\x95\x80"
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
_EXTENSIONS = {".ulg": "ulog", ".bin": "dataflash", ".log": "dataflash"}


def read_flight(path: str | os.PathLike[str], *, fmt: str | None = None, **options: Any) -> Flight:
    """Read a recording into a Flight, choosing the reader by ``fmt`` or by the path.

    path: a log file, an HDF5 file or a directory (see the module table). fmt: one of
    :data:`FORMATS` to skip detection. options: keyword options of the chosen reader
    (e.g. ``multi_id`` for ULog, ``instance``/``core`` for DataFlash, ``score`` for BROAD,
    ``wind_points_from`` for ALFA, ``imu``/``gnss`` for ANSFL).

    Raises LogFormatError for a missing path, an unknown or unreadable format (the message
    names the file and what is wrong) and FlightError for values failing validation.
    """
    p = Path(path)
    if fmt is None:
        fmt = detect_format(p)
    elif fmt not in FORMATS:
        raise LogFormatError(p, f"fmt: expected one of {FORMATS}, found {fmt!r}")
    if fmt == "windahrs":
        return _load_windahrs(p, options)
    readers: dict[str, Callable[..., Flight]] = {
        "ulog": read_ulog,
        "dataflash": read_dataflash,
        "broad": read_broad,
        "alfa": read_alfa,
        "csv": read_csv_dir,
        "ansfl": read_ansfl,
        "asl": read_asl,
    }
    reader = readers[fmt]
    try:
        inspect.signature(reader).bind(p, **options)
    except TypeError as exc:
        raise LogFormatError(p, f"option not known to the {fmt} reader: {exc}") from None
    return reader(p, **options)


def detect_format(path: str | os.PathLike[str]) -> str:
    """The :data:`FORMATS` name of ``path``, from its extension, contents or directory files.

    Raises LogFormatError when the path does not exist or matches no known format.
    """
    p = Path(path)
    if p.is_dir():
        if (p / CSV_MANIFEST).is_file():
            return "csv"
        if alfa_prefix(p) is not None:
            return "alfa"
        if is_ansfl_dir(p):
            return "ansfl"
        if is_asl_dir(p):
            return "asl"
        raise LogFormatError(
            p, f"unknown directory format: expected {CSV_MANIFEST} (generic CSV), "
            f"{ALFA_IMU_FILE} or <sequence>-{ALFA_IMU_FILE} (ALFA mavros CSV), {ANSFL_GT_FILE} with "
            "IMU_<k>.csv (ANSFL) or mav0/imu0/data.csv (ASL: EuRoC, TUM-VI)"
        )
    if not p.is_file():
        raise LogFormatError(p, "no such file or directory")
    if p.name == CSV_MANIFEST:
        return "csv"
    ext = p.suffix.lower()
    if ext in _EXTENSIONS:
        return _EXTENSIONS[ext]
    with p.open("rb") as fh:
        head = fh.read(16)
    if ext in (".hdf5", ".h5") or head.startswith(_HDF5_MAGIC):
        return _hdf5_format(p)
    if head.startswith(_ULOG_MAGIC):
        return "ulog"
    if head.startswith(_DATAFLASH_MAGIC):
        return "dataflash"
    if not head:
        raise LogFormatError(p, "empty file")
    raise LogFormatError(
        p, f"unknown format (extension {ext or 'none'!r}; known: .ulg, .bin, .log, .hdf5, "
        f".h5, or a directory with {CSV_MANIFEST}, {ALFA_IMU_FILE}, {ANSFL_GT_FILE} or mav0/imu0/data.csv)"
    )


def _hdf5_format(p: Path) -> str:
    import h5py

    from windahrs.store import FLIGHT_FORMAT

    try:
        with h5py.File(p, "r") as f:
            found = f.attrs.get("format")
            if isinstance(found, bytes):
                found = found.decode()
            if found == FLIGHT_FORMAT:
                return "windahrs"
            if isinstance(f.get("imu_gyr"), h5py.Dataset):
                return "broad"
            keys = sorted(f.keys())[:8]
    except MemoryError:
        raise
    except Exception as exc:  # h5py: OSError, KeyError, RuntimeError, ... on a damaged file
        raise LogFormatError(
            p, f"not a readable HDF5 file (truncated or corrupt?): {type(exc).__name__}: {exc}"
        ) from None
    raise LogFormatError(
        p, f"unknown HDF5 layout: expected root attribute format={FLIGHT_FORMAT!r} or a BROAD "
        f"'imu_gyr' dataset, found format={found!r} and datasets {keys}"
    )


def _load_windahrs(p: Path, options: dict[str, Any]) -> Flight:
    from windahrs.store import StoreError, load_flight

    if options:
        raise LogFormatError(p, f"the windahrs reader takes no options, found {sorted(options)}")
    try:
        return load_flight(p)
    except StoreError as exc:
        problem = str(exc).removeprefix(f"{p}: ")
        raise LogFormatError(p, problem) from None
