"""Plumbing shared by the library adapters: parameter checks, the declination, the
zero-order hold of the magnetometer, the lazy sample period and the batch driver.

Every adapter keeps the library's attitude in the library's own navigation frame and
converts at the edge: :meth:`LibraryStreamer.state` returns ``q_nb`` (NED nav, FRD body,
heading from true north). Libraries that reference heading to magnetic north are rotated
by the site's declination about the down axis (:attr:`Site.declination`: ``D =
atan2(mag_n[1], mag_n[0])`` of its field, or the declination a reader knows).
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import os
from abc import abstractmethod
from pathlib import Path
from types import ModuleType
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray

from windahrs.estimate import Estimate
from windahrs.filters.base import (
    Estimator,
    InitialState,
    MissingSensorError,
    StateView,
    Streamer,
    merge_events,
    replay,
    triad,
)
from windahrs.filters.params import read_param_file
from windahrs.flight import Flight, Site
from windahrs.rotation import quat_from_euler, quat_identity

__all__ = [
    "MAG_MODES",
    "UT_PER_TESLA",
    "LibraryEstimator",
    "LibraryStreamer",
    "MagMode",
    "check_flag",
    "check_mag_mode",
    "check_number",
    "check_rate",
    "declination",
    "flight_period",
    "held_mag",
    "import_library",
    "left_matrix",
    "q_about_down",
    "unit_w_positive",
]

F64 = NDArray[np.float64]

#: What an adapter does with a magnetometer: "auto" fuses it when the flight has one,
#: "required" raises MissingSensorError without one, "off" runs 6-axis regardless.
MagMode = Literal["auto", "required", "off"]
MAG_MODES: tuple[str, ...] = ("auto", "required", "off")

#: Magnetometer samples reach the libraries in microtesla (all of them normalise the
#: field, so the unit only keeps single-precision libraries away from tiny numbers).
UT_PER_TESLA = 1e6


def check_number(
    cls_name: str, name: str, value: object, *, low: float = 0.0, strict: bool = True
) -> None:
    """ValueError naming ``cls_name.name`` unless ``value`` is a finite number above
    ``low`` (``>= low`` when ``strict`` is False)."""
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    if ok:
        v = float(value)  # type: ignore[arg-type]
        ok = math.isfinite(v) and (v > low if strict else v >= low)
    if not ok:
        need = f"> {low:g}" if strict else f">= {low:g}"
        raise ValueError(f"{cls_name}.{name}: expected a finite number {need}, found {value!r}")


def check_rate(cls_name: str, value: float | None) -> None:
    """``rate`` is None (taken from the data) or a finite rate > 0 Hz."""
    if value is not None:
        check_number(cls_name, "rate", value)


def check_mag_mode(cls_name: str, value: object) -> None:
    if value not in MAG_MODES:
        raise ValueError(f"{cls_name}.use_mag: expected one of {MAG_MODES}, found {value!r}")


def check_flag(cls_name: str, name: str, value: object) -> None:
    if not isinstance(value, bool):
        raise ValueError(f"{cls_name}.{name}: expected True or False, found {value!r}")


def import_library(module: str) -> ModuleType:
    """Import an optional dependency, saying how to install it when it is missing."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            f"the {module!r} package is needed for this baseline: "
            "pip install 'windahrs[baselines]'"
        ) from exc


def declination(site: Site) -> float:
    """Magnetic declination D (rad, east positive) of the site (:attr:`Site.declination`:
    its field's, or the one a reader knows); 0 when unknown."""
    return 0.0 if site.declination is None else site.declination


def q_about_down(angle: float) -> F64:
    """Quaternion of a rotation by ``angle`` (rad) about the NED down axis."""
    return quat_from_euler([0.0, 0.0, angle])


def flight_period(flight: Flight) -> float:
    """Median IMU sample period of a flight, s (the nominal period handed to the
    libraries that need one)."""
    t = flight.imu.t
    if len(t) < 2:
        raise ValueError("imu.t: expected at least two samples to know the sample period")
    return float(np.median(np.diff(t)))


def left_matrix(p: F64) -> F64:
    """4x4 matrix ``L`` with ``L @ q == quat_mul(p, q)`` (one matrix product per sample is
    much cheaper than the broadcasting :func:`~windahrs.rotation.quat_mul` on one row)."""
    w, x, y, z = (float(v) for v in p)
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


def unit_w_positive(q: F64) -> F64:
    """``q / |q|`` with ``w >= 0``, for one quaternion (4,)."""
    n = math.sqrt(float(q @ q))
    return q / (-n if q[0] < 0.0 else n)


class LibraryStreamer(Streamer):
    """A streamer around one library object, fed one IMU sample at a time.

    The latest magnetometer sample is held (zero-order hold) and handed to the library
    with every IMU sample; until the first one arrives the library's 6-axis update runs.
    The library's quaternion lives in its own navigation frame; ``frame_q`` rotates that
    frame to NED (``q_ned = frame_q * q_lib``) and, when the library's heading is
    magnetic (``magnetic_heading``), the declination rotates magnetic NED to true NED:
    ``q_nb = Rz(D) * frame_q * q_lib``, one fixed 4x4 matrix.

    Sample timing: the gyro sample at ``t[k]`` covers ``(t[k-1], t[k]]``, so updates use
    ``dt = t[k] - t[k-1]``. Libraries that need the nominal sample period before their
    first update (``needs_period``) get it from the parameters or, when streaming without
    one, from the first interval: the first sample is then held until the second arrives.
    """

    #: Rotation from the library's nav frame to NED (None: the library works in NED).
    frame_q: ClassVar[F64 | None] = None
    #: True: the library needs the sample period before its first update.
    needs_period: ClassVar[bool] = False
    #: True: the library estimates a gyro bias (the state then always carries one).
    estimates_bias: ClassVar[bool] = False

    def __init__(
        self,
        filter_name: str,
        site: Site,
        *,
        initial: InitialState | None,
        use_mag: bool,
        period: float | None,
        magnetic_heading: bool = True,
    ) -> None:
        super().__init__(filter_name)
        self._site = site
        self._initial = initial
        self._use_mag = use_mag
        self._period = period
        decl = declination(site) if (use_mag and magnetic_heading) else 0.0
        self._L_frame = np.eye(4) if self.frame_q is None else left_matrix(self.frame_q)
        #: library quaternion -> true-north NED q_nb; its transpose is the inverse.
        self.out_matrix = left_matrix(q_about_down(decl)) @ self._L_frame
        self._mag_held: F64 | None = None  # microtesla, body axes
        self._t_prev: float | None = None
        self._t_state = float("nan")
        self._pending: tuple[float, F64, F64, F64 | None] | None = None
        self._started = False
        # The library quaternion shown before the library has seen a sample: the
        # initial state, else level and north.
        q0 = initial.q_nb if initial is not None else quat_identity()
        self._q_placeholder = unit_w_positive(self.out_matrix.T @ np.asarray(q0, dtype=float))
        self._bias_placeholder = (
            np.array(initial.gyro_bias_b, dtype=np.float64)
            if initial is not None and initial.gyro_bias_b is not None
            else np.zeros(3)
        )

    # --- frames ---------------------------------------------------------------------

    def library_from_ned(self, q_ned: F64) -> F64:
        """An attitude w.r.t. the library's NED frame (magnetic or true north) -> the
        library's own quaternion."""
        return unit_w_positive(self._L_frame.T @ q_ned)

    def triad_library_nav(self, f_b: F64, mag_ut: F64 | None) -> F64:
        """Attitude from one accelerometer and one magnetometer sample, w.r.t. the
        library's NED frame (magnetic north unless a subclass says otherwise)."""
        return triad(f_b, mag_ut, None)

    # --- events ---------------------------------------------------------------------

    def _mag(self, t: float, mag_b: F64) -> None:
        if self._use_mag:
            self._mag_held = np.ascontiguousarray(mag_b * UT_PER_TESLA, dtype=np.float64)

    def _imu(self, t: float, w_b: F64, f_b: F64) -> None:
        w = np.ascontiguousarray(w_b, dtype=np.float64)
        f = np.ascontiguousarray(f_b, dtype=np.float64)
        mag = self._mag_held
        self._t_state = t
        if not self._started and self._pending is None:
            if self.needs_period and self._period is None:
                self._pending = (t, w, f, mag)
                return
            self._start(w, f, mag)
            self._started = True
            self._t_prev = t
            return
        if self._pending is not None:
            t0, w0, f0, m0 = self._pending
            self._pending = None
            self._period = t - t0
            if not self._period > 0.0:
                raise ValueError(
                    f"imu.t: expected a positive first interval to set the sample period of "
                    f"{self.filter_name!r}, found {self._period!r} (give params.rate)"
                )
            self._start(w0, f0, m0)
            self._started = True
            self._t_prev = t0
        assert self._t_prev is not None
        self._update(t - self._t_prev, w, f, mag)
        self._t_prev = t

    @abstractmethod
    def _start(self, w_b: F64, f_b: F64, mag_ut: F64 | None) -> None:
        """Create or initialise the library with the first sample."""

    @abstractmethod
    def _update(self, dt: float, w_b: F64, f_b: F64, mag_ut: F64 | None) -> None:
        """One library update over ``dt`` seconds."""

    @abstractmethod
    def _q_lib(self) -> F64:
        """The library's current quaternion, in its own frame (once started)."""

    def _bias(self) -> F64:
        """Gyro bias estimate, rad/s (started libraries with ``estimates_bias`` only)."""
        raise NotImplementedError

    @property
    def state(self) -> StateView:
        q = self._q_lib() if self._started else self._q_placeholder
        bias: F64 | None = None
        if self.estimates_bias:
            bias = self._bias() if self._started else self._bias_placeholder.copy()
        return StateView(
            t=self._t_state,
            q_nb=unit_w_positive(self.out_matrix @ q),
            gyro_bias_b=bias,
            v_n=None,
            wind_n=None,
            cov=None,
            state_labels=(),
        )


class LibraryEstimator(Estimator):
    """An Estimator wrapping a library. Subclasses set ``name``, ``params`` and
    :meth:`_make_streamer`. ``run`` hands the flight's median sample period to the
    streamer (libraries with a fixed-rate model need one)."""

    uses: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})
    #: The frozen dataclass of the parameters.
    params_type: ClassVar[type]
    params: Any

    @classmethod
    def load_params(cls, path: str | os.PathLike[str]) -> Any:
        """Parameters from a TOML file: a ``[windahrs]`` table of the parameter record's
        field names (e.g. ``gain_marg = 0.1``); anything else is refused (ValueError)."""
        p = Path(path)
        data = read_param_file(p)
        record = cls.params_type.__name__
        fields = {f.name for f in dataclasses.fields(cls.params_type)}
        changes: dict[str, Any] = {}
        for table, entries in data.items():
            if table != "windahrs" or not isinstance(entries, dict):
                raise ValueError(f"{p}: expected a [windahrs] table of {record} fields, found [{table}]")
            for key, value in entries.items():
                if key not in fields:
                    raise ValueError(
                        f"{p}: unknown parameter {key!r} of {record}; known: {', '.join(sorted(fields))}"
                    )
                changes[key] = value
        try:
            return cls.params_type(**changes)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{p}: {exc}") from None

    def check(self, flight: Flight) -> None:
        super().check(flight)
        if self.params.use_mag == "required" and flight.mag is None:
            raise MissingSensorError(self.name, "mag", " (params.use_mag='required')")

    def _use_mag(self, has: frozenset[str]) -> bool:
        mode = self.params.use_mag
        if mode == "required" and "mag" not in has:
            raise MissingSensorError(self.name, "mag", " (params.use_mag='required')")
        return mode != "off" and "mag" in has

    def streamer(
        self,
        site: Site,
        *,
        initial: InitialState | None = None,
        has: frozenset[str] = frozenset(),
        period: float | None = None,
    ) -> Streamer:
        """A fresh streaming instance.

        site: the flight's site (declination, field). initial: attitude (and gyro bias)
        to start from, or None. has: the streams that will be fed ("mag" enables the
        9-axis update). period: nominal IMU sample period, s; None takes ``params.rate``
        or, failing that, the first interval of the stream.
        """
        rate = getattr(self.params, "rate", None)
        if period is None and rate is not None:
            period = 1.0 / float(rate)
        return self._make_streamer(site, initial, self._use_mag(has), period)

    @abstractmethod
    def _make_streamer(
        self, site: Site, initial: InitialState | None, use_mag: bool, period: float | None
    ) -> LibraryStreamer: ...

    def _has(self, flight: Flight) -> frozenset[str]:
        has = {"imu"}
        if flight.mag is not None and self.params.use_mag != "off":
            has.add("mag")
        return frozenset(has)

    def _period(self, flight: Flight) -> float:
        rate = getattr(self.params, "rate", None)
        return 1.0 / float(rate) if rate is not None else flight_period(flight)

    def run(self, flight: Flight, *, initial: InitialState | None = None) -> Estimate:
        """Estimate the whole flight by replaying it through :meth:`streamer`."""
        self.check(flight)
        has = self._has(flight)
        t_ev, kinds, vals = merge_events(flight, has)
        s = self.streamer(flight.site, initial=initial, has=has, period=self._period(flight))
        return replay(self, s, flight, t_ev, kinds, vals)


def held_mag(flight: Flight, t_imu: F64) -> tuple[F64, NDArray[np.bool_]]:
    """The magnetometer sample (microtesla) held at each IMU time, as the streamers see it.

    At equal times the IMU sample is processed before the magnetometer sample, so the
    held sample is the last finite one strictly before ``t_imu``. Returns (N, 3) values
    (zero rows where none has arrived yet) and the (N,) mask of rows that have one.
    """
    out = np.zeros((len(t_imu), 3))
    if flight.mag is None:
        return out, np.zeros(len(t_imu), dtype=bool)
    ok = np.isfinite(flight.mag.mag_b).all(axis=1)
    tm = flight.mag.t[ok]
    mm = flight.mag.mag_b[ok] * UT_PER_TESLA
    k = np.searchsorted(tm, t_imu, side="left") - 1
    have = k >= 0
    out[have] = mm[k[have]]
    return out, have
