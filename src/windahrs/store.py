"""Save and load windahrs records in HDF5, atomically.

The layout is documented in ``docs/file-format.md``. Each record type is a group of
datasets (arrays) and attributes (scalars, strings); the root carries ``format`` and
``version``. Writes go to a temporary file beside the target and are renamed into place
only when complete, so an error or Ctrl-C never leaves a half-written file.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import h5py
import numpy as np

from windahrs.flight import (
    AirDataStream,
    Flight,
    FlightError,
    GnssStream,
    ImuStream,
    MagStream,
    Reference,
    Site,
    Truth,
    WindStream,
)

__all__ = [
    "FLIGHT_FORMAT",
    "FLIGHT_VERSION",
    "StoreError",
    "atomic_h5",
    "atomic_path",
    "load_flight",
    "read_errors",
    "read_record",
    "read_repairs",
    "save_flight",
    "write_record",
    "write_repairs",
]

FLIGHT_FORMAT = "windahrs.flight"
FLIGHT_VERSION = 1

_FLIGHT_PARTS: dict[str, type] = {
    "imu": ImuStream,
    "mag": MagStream,
    "gnss": GnssStream,
    "air": AirDataStream,
    "truth": Truth,
    "reference": Reference,
    "ref_wind": WindStream,
    "site": Site,
}

T = TypeVar("T")


class StoreError(OSError):
    """A windahrs HDF5 file cannot be read: missing, truncated, corrupt or of another
    format or version. The message names the file and what is wrong."""


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it to ``path``.

    On any exception (KeyboardInterrupt included) the temporary file is removed and the
    target is left as it was.
    """
    target = Path(path)
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"{target}: directory {parent} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, target)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_h5(path: str | os.PathLike[str], fmt: str, version: int) -> Iterator[h5py.File]:
    """Open a new HDF5 file for writing atomically, with ``format``/``version`` set."""
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = fmt
            f.attrs["version"] = version
            yield f
            f.flush()


def write_record(group: h5py.Group, record: object) -> None:
    """Write a dataclass: arrays as datasets, scalars and strings as attributes."""
    for fld in dataclasses.fields(record):  # type: ignore[arg-type]
        value = getattr(record, fld.name)
        if value is None:
            continue
        if isinstance(value, np.ndarray):
            group.create_dataset(
                fld.name, data=value, compression="gzip", compression_opts=1, shuffle=True
            )
        elif isinstance(value, dict):
            sub = group.create_group(fld.name)
            for k, v in value.items():
                sub.attrs[k] = v
        else:
            group.attrs[fld.name] = value


def read_record(group: h5py.Group, cls: Callable[..., T], where: str) -> T:
    """Inverse of :func:`write_record`; validation errors name ``where``."""
    kwargs: dict[str, Any] = {}
    for name, ds in group.items():
        if isinstance(ds, h5py.Dataset):
            kwargs[name] = ds[()]
        elif isinstance(ds, h5py.Group):
            kwargs[name] = {k: _plain(v) for k, v in ds.attrs.items()}
        else:  # h5py gives None for an object whose header is damaged
            raise StoreError(f"{where}/{name}: unreadable object (corrupt file?)")
    for k, v in group.attrs.items():
        kwargs[k] = _plain(v)
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise StoreError(f"{where}: unexpected contents ({exc})") from None


def _plain(v: Any) -> Any:
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.generic):
        return v.item()
    return v


def save_flight(flight: Flight, path: str | os.PathLike[str]) -> Path:
    """Write ``flight`` to ``path`` (HDF5, schema ``windahrs.flight`` v1), atomically."""
    with atomic_h5(path, FLIGHT_FORMAT, FLIGHT_VERSION) as f:
        for name in _FLIGHT_PARTS:
            part = getattr(flight, name)
            if part is not None:
                write_record(f.create_group(name), part)
        meta = f.create_group("meta")
        for k, v in flight.meta.items():
            meta.attrs[k] = v
        write_repairs(f, flight.repairs)
    return Path(path)


def write_repairs(f: h5py.Group, repairs: dict[str, dict[str, int]]) -> None:
    """``repairs`` (stream -> kind -> count) as group ``repairs`` with one subgroup per
    stream, the counts as its attributes."""
    g = f.create_group("repairs")
    for stream, counts in repairs.items():
        sub = g.create_group(stream)
        for kind, n in counts.items():
            sub.attrs[kind] = int(n)


def read_repairs(f: h5py.Group) -> dict[str, dict[str, int]]:
    """Inverse of :func:`write_repairs`; empty for files written before it existed."""
    g = f.get("repairs")
    if not isinstance(g, h5py.Group):
        return {}
    return {stream: {k: int(_plain(v)) for k, v in sub.attrs.items()} for stream, sub in g.items()}


@contextlib.contextmanager
def open_h5(
    path: str | os.PathLike[str], fmt: str, versions: tuple[int, ...]
) -> Iterator[h5py.File]:
    """Open a windahrs HDF5 file for reading, checking its format and version."""
    p = Path(path)
    if not p.is_file():
        raise StoreError(f"{p}: no such file")
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        raise StoreError(f"{p}: not a readable HDF5 file (truncated or corrupt?): {exc}") from None
    with f:
        found = _plain(f.attrs.get("format", "<none>"))
        if found != fmt:
            raise StoreError(f"{p}: expected format {fmt!r}, found {found!r}")
        version = _plain(f.attrs.get("version", -1))
        if version not in versions:
            raise StoreError(f"{p}: {fmt} version {version} is not supported (known: {versions})")
        yield f


def load_flight(path: str | os.PathLike[str]) -> Flight:
    """Read a Flight written by :func:`save_flight`.

    Raises StoreError for a missing, truncated, corrupt or foreign file, and FlightError
    (naming the field) when the contents fail validation.
    """
    with read_errors(path, "unreadable contents"), open_h5(path, FLIGHT_FORMAT, (FLIGHT_VERSION,)) as f:
        if "imu" not in f:
            raise StoreError(f"{path}: no 'imu' group: a Flight needs an IMU stream")
        parts = {}
        for name, cls in _FLIGHT_PARTS.items():
            if name not in f:
                continue
            group = f[name]
            if not isinstance(group, h5py.Group):
                raise StoreError(f"{path}:/{name}: expected a group, found {type(group).__name__}")
            parts[name] = read_record(group, cls, f"{path}:/{name}")
        meta = {k: _plain(v) for k, v in f["meta"].attrs.items()} if "meta" in f else {}
        return Flight(**parts, meta=meta, repairs=read_repairs(f))


@contextlib.contextmanager
def read_errors(path: str | os.PathLike[str], what: str) -> Iterator[None]:
    """Errors while reading a windahrs file, made the documented ones: StoreError and
    MemoryError pass, FlightError gets the file's name before its field, and anything
    else becomes ``StoreError("{path}: {what} (...)")``. h5py meets a damaged file with
    whatever it hits first (KeyError, OSError, RuntimeError, ValueError,
    UnicodeDecodeError, ...): one error naming the file."""
    try:
        yield
    except (StoreError, MemoryError):
        raise
    except FlightError as exc:
        raise FlightError(f"{path}:{exc.field}", exc.expected, exc.found) from None
    except Exception as exc:
        raise StoreError(f"{path}: {what} ({type(exc).__name__}: {exc})") from None
