"""Edge policy of the readers: what is an error, what is repaired and counted, and the
readers' error :class:`LogFormatError`.

Every reader in :mod:`windahrs.io` raises :class:`LogFormatError` for a file it cannot
turn into a :class:`~windahrs.flight.Flight` (unknown format, truncated or corrupt file,
missing topic, bad manifest entry); malformed *values* that reach the Flight raise
:class:`~windahrs.flight.FlightError` with the file prefixed to the field. Both name
the file.

The repair of the samples themselves (time stamps out of order, repeated or not finite,
infinite values, samples beyond the sensor's range) is :mod:`windahrs.repair`, shared with
``Flight.from_arrays``: each reader fills a :class:`~windahrs.repair.RepairLog` and gives its
counts to ``Flight.repairs``. The helpers below hold the rest of the policy every reader
applies at the edge, so that nothing is dropped silently:

* reference quaternions whose norm is not 1 (an estimator not yet initialised logs
  zeros) become NaN rows, i.e. gaps that are not scored, and are counted;
* what a third-party parser prints about corrupt bytes is captured and counted
  (``meta["<format>.parser_messages"]``), not shown;
* an autopilot log's site takes the autopilot's own declination parameter
  (:func:`autopilot_site`), so that estimated headings are true, as the log's reference is;
* a truncated file (its last message or row incomplete) is read up to its last complete
  one, with a :class:`TruncatedLogWarning` saying how much was dropped, and the count in
  ``meta["<format>.truncated_bytes"]`` (CSV: ``meta["<stream>.dropped_truncated_row"]``).
"""

from __future__ import annotations

import io
import os
import sys
import tempfile
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from windahrs.flight import FlightError, Site
from windahrs.repair import GNSS_VELOCITY_RANGE

__all__ = [
    "LogFormatError",
    "ParserOutput",
    "TruncatedLogWarning",
    "captured_output",
    "flight_errors_name",
    "guard",
    "invalid_quat_rows",
    "param_float",
    "speed_accuracy",
    "velocity_from_positions",
    "warn_truncated",
]

F64 = NDArray[np.float64]
T = TypeVar("T")

#: Quaternions whose norm is off by more than this are not attitudes (e.g. all zeros).
QUAT_NORM_TOL = 1e-3


class LogFormatError(ValueError):
    """A log cannot be read as a Flight. The message names the file and what is wrong.

    ``path`` is the offending file (or directory), ``problem`` the reason.
    """

    def __init__(self, path: str | os.PathLike[str], problem: str) -> None:
        self.path = os.fspath(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class TruncatedLogWarning(UserWarning):
    """A log ends inside a message or row (a recording cut by a power loss or a copy): it
    was read up to its last complete one. The message names the file and what was dropped."""


def warn_truncated(path: str | os.PathLike[str], what: str) -> None:
    """Emit a :class:`TruncatedLogWarning` for ``path``: ``what`` says what was dropped."""
    warnings.warn(f"{os.fspath(path)}: truncated: {what}", TruncatedLogWarning, stacklevel=3)


def invalid_quat_rows(q: NDArray[Any]) -> tuple[F64, int]:
    """Quaternions (N, 4) with non-unit or non-finite rows set to NaN; and their count.

    A flight stack logs zeros (or garbage) before its estimator is initialised; those rows
    are gaps of the reference, not attitudes. Finite rows of norm 1 within
    ``QUAT_NORM_TOL`` are kept as they are.
    """
    out = np.array(q, dtype=np.float64)
    norm = np.linalg.norm(out, axis=1)
    bad = ~np.isfinite(out).all(axis=1) | ~(np.abs(norm - 1.0) <= QUAT_NORM_TOL)
    out[bad] = np.nan
    return out, int(np.count_nonzero(bad & np.isfinite(q).all(axis=1)))


@contextmanager
def flight_errors_name(path: str | os.PathLike[str]) -> Iterator[None]:
    """Re-raise a FlightError raised inside the block with the file prefixed to the field."""
    try:
        yield
    except FlightError as exc:
        raise FlightError(f"{os.fspath(path)}:{exc.field}", exc.expected, exc.found) from None


def guard(path: str | os.PathLike[str], what: str, fn: Callable[[], T]) -> T:
    """Call ``fn``; any exception of a third-party parser becomes a LogFormatError.

    A parser (pyulog, pymavlink, h5py) fails on corrupt input with whatever it meets
    first (struct.error, IndexError, KeyError, ...); the caller should see which file and
    that it is unreadable, not the parser's internals.
    """
    try:
        return fn()
    except (LogFormatError, FlightError):
        raise
    except MemoryError:
        raise
    except Exception as exc:
        raise LogFormatError(path, f"{what}: {type(exc).__name__}: {exc}") from None


def velocity_from_positions(t: NDArray[Any], p: NDArray[Any]) -> F64:
    """Velocity (N, 3) from positions (N, 3) at times t (N,) s, in the positions' frame and
    unit per second: central differences inside, one-sided at the two ends
    (``numpy.gradient`` with the sample times). A NaN position makes the velocities beside
    it NaN; fewer than 2 samples give NaN. Differencing amplifies position noise and
    quantisation: a step q between samples dt apart shows as about q / (2 dt).
    """
    p = np.asarray(p, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if len(t) < 2:
        return np.full_like(p, np.nan)
    return np.asarray(np.gradient(p, t, axis=0), dtype=np.float64)


def speed_accuracy(s: NDArray[Any], meta: dict[str, Any], source: str) -> F64 | None:
    """A log's receiver speed accuracy s (N,) m/s as :class:`~windahrs.flight.GnssStream`'s
    ``v_sigma``: NaN where it is 0 (what receivers log without a fix: not given) or beyond
    the velocity's range; None when no value is left, else ``meta["gnss.v_sigma"]`` names
    ``source``."""
    out = np.array(s, dtype=np.float64)
    out[~((out > 0.0) & (out <= GNSS_VELOCITY_RANGE))] = np.nan
    if not np.isfinite(out).any():
        return None
    meta["gnss.v_sigma"] = f"{source} (the receiver's speed accuracy)"
    return out


def param_float(value: Any) -> float:
    """A logged parameter as a float: single-precision values keep their short decimal form.

    Autopilots store parameters as float32; widening 0.2f to double prints
    0.20000000298023224, which is not what the user set.
    """
    v = float(value)
    if isinstance(value, int | np.integer):
        return v
    return float(str(np.float32(v))) if np.isfinite(v) else v


def autopilot_site(params: dict[str, Any], names: tuple[tuple[str, float], ...], meta: dict[str, Any]) -> Site:
    """The site of an autopilot's log, from the first of its declination parameters
    ``names`` ((name, radians per unit), in order of preference) that is logged, finite and
    non-zero (0 is the stacks' default, "not set"; a site on the agonic line loses
    nothing by it). The autopilot's attitude, the reference of its log, is heading from
    true north by that declination (its own or the World Magnetic Model's lookup, which
    the stacks save in it), so the estimators turn the field they learn by it too.
    Records ``meta["site.declination_param"]``. Gravity is standard; the field unknown."""
    for name, scale in names:
        value = params.get(name)
        if value is None:
            continue
        try:
            d = float(value) * scale
        except (TypeError, ValueError):
            continue
        if np.isfinite(d) and d != 0.0 and abs(d) <= np.pi:
            meta["site.declination_param"] = name
            return Site(declination=d)
    return Site()


class ParserOutput:
    """What a parser printed inside :func:`captured_output`; ``lines`` is filled on exit."""

    def __init__(self) -> None:
        self.lines: list[str] = []


@contextmanager
def captured_output() -> Iterator[ParserOutput]:
    """Capture what third-party parsers print, so readers can count it instead.

    pyulog and pymavlink report corrupt bytes with ``print`` (Python level) and, in
    pymavlink's compiled indexer, ``fprintf(stderr)`` (C level, once per bad byte: millions
    of lines for a corrupt log). Both go to a buffer here; the reader records the count in
    ``Flight.meta``. File descriptor 2 is redirected only for the duration of the block.
    """
    out = ParserOutput()
    sink = io.StringIO()
    with tempfile.TemporaryFile() as tmp:
        saved: int | None = None
        try:
            sys.stderr.flush()
            saved = os.dup(2)
            os.dup2(tmp.fileno(), 2)
        except (OSError, ValueError):  # no real fd 2 (embedded interpreters): Python level only
            saved = None
        try:
            with redirect_stdout(sink), redirect_stderr(sink):
                yield out
        finally:
            if saved is not None:
                os.dup2(saved, 2)
                os.close(saved)
            tmp.seek(0)
            text = sink.getvalue() + tmp.read().decode("utf-8", "replace")
            out.lines = [line for line in text.splitlines() if line.strip()]
