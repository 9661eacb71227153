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
import secrets
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import h5py
import numpy as np
from numpy.typing import NDArray

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

F64 = NDArray[np.float64]

__all__ = [
    "FLIGHT_FORMAT",
    "FLIGHT_VERSION",
    "OutputError",
    "StoreError",
    "atomic_h5",
    "atomic_path",
    "check_writable",
    "load_flight",
    "read_errors",
    "read_record",
    "read_repair_times",
    "read_repairs",
    "save_flight",
    "write_bytes",
    "write_record",
    "write_repair_times",
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


class OutputError(OSError):
    """A file cannot be written: its path is empty or a directory, its folder is missing or
    not a folder, the file system refuses it (read-only, no permission) or fills up. The
    message names the user's path (never a temporary file) and the system's reason."""


def check_writable(path: str | os.PathLike[str]) -> Path:
    """Check, before any work, that a file can be written at ``path``: a non-empty name
    that is not a directory, in an existing directory where a file can be created (tried
    with an empty probe file, removed at once: permissions alone miss a read-only file
    system, and root). Returns the path; OutputError naming it otherwise."""
    text = os.fspath(path)
    if not text:
        raise OutputError("expected a file name, found ''")
    target = Path(text)
    if text.endswith(os.sep) or target.is_dir():
        raise OutputError(f"{text}: is a directory, expected a file name")
    if target.exists() and not target.is_file():  # a device or FIFO would be replaced by a file
        raise OutputError(f"{text}: is not a regular file (a device, FIFO or socket), expected a file name")
    parent = target.parent
    if not parent.exists():
        # name the first missing folder, or the file standing where a folder should be
        for anc in reversed(parent.parents):
            if anc.exists() and not anc.is_dir():
                raise OutputError(f"{text}: {anc} is not a directory")
        raise OutputError(f"{text}: directory {parent} does not exist")
    if not parent.is_dir():
        raise OutputError(f"{text}: {parent} is not a directory")
    probe = _new_temp(target, ".probe")
    probe.unlink()
    return target


def _new_temp(target: Path, suffix: str = ".tmp") -> Path:
    """A new empty file beside ``target``, created with mode 0o666 less the user's umask
    (as a plain ``open`` would; ``tempfile.mkstemp`` makes it 0o600). OutputError naming
    ``target`` when the directory refuses it."""
    tmp = target.with_name(f".{target.name}.{secrets.token_hex(6)}{suffix}")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except OSError as exc:
        raise OutputError(f"{target}: cannot write in {target.parent} ({exc.strerror})") from None
    os.close(fd)
    return tmp


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it to ``path``.

    The file gets the user's umask. On any exception (KeyboardInterrupt included) the
    temporary file is removed and the target is left as it was; an OSError on the way
    (a full disk, say) becomes an OutputError naming ``path``, not the temporary file.
    """
    target = check_writable(path)
    tmp = _new_temp(target)
    try:
        yield tmp
        os.replace(tmp, target)
    except OutputError:
        tmp.unlink(missing_ok=True)
        raise
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"{target}: cannot write ({exc.strerror or exc})") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_bytes(path: str | os.PathLike[str], data: bytes | memoryview) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_path`), synced to disk before
    the rename. Returns the path."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    return Path(path)


@contextlib.contextmanager
def atomic_h5(path: str | os.PathLike[str], fmt: str, version: int) -> Iterator[h5py.File]:
    """Open a new HDF5 file for writing atomically, with ``format``/``version`` set.

    The file is built in memory (HDF5's core driver) and written out by
    :func:`write_bytes`: HDF5 writing to a full disk fails in its own cleanup and can
    crash the process (a segfault in h5py 3.x), while a plain write fails cleanly."""
    target = check_writable(path)
    with h5py.File(target.name, "w", driver="core", backing_store=False) as f:
        f.attrs["format"] = fmt
        f.attrs["version"] = version
        yield f
        f.flush()
        image = f.id.get_file_image()
    write_bytes(target, image)


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
        write_repair_times(f, flight.repair_times)
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


def write_repair_times(f: h5py.Group, times: dict[str, dict[str, F64]]) -> None:
    """``times`` (stream -> kind -> times s) as group ``repair_times``: one subgroup per
    stream, one dataset per kind (nothing when empty)."""
    if not times:
        return
    g = f.create_group("repair_times")
    for stream, kinds in times.items():
        sub = g.create_group(stream)
        for kind, t in kinds.items():
            sub.create_dataset(kind, data=np.asarray(t, dtype=np.float64))


def read_repair_times(f: h5py.Group) -> dict[str, dict[str, F64]]:
    """Inverse of :func:`write_repair_times`; empty for files written before it existed."""
    g = f.get("repair_times")
    if not isinstance(g, h5py.Group):
        return {}
    out: dict[str, dict[str, F64]] = {}
    for stream, sub in g.items():
        if not isinstance(sub, h5py.Group):
            raise StoreError(f"/repair_times/{stream}: expected a group, found {type(sub).__name__}")
        out[stream] = {kind: np.asarray(d[()], dtype=np.float64) for kind, d in sub.items()}
    return out


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
        return Flight(**parts, meta=meta, repairs=read_repairs(f), repair_times=read_repair_times(f))


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
