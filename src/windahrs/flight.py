"""``Flight``: one record for simulated and real data.

A Flight holds multi-rate sensor streams, each with its own strictly increasing time
vector (float seconds), the site (gravity, magnetic field), and optionally the truth
(simulation) or a labelled reference attitude (mocap, the autopilot's own estimate).
Every source, simulator or log reader, produces one; every estimator consumes one.

Validation happens once, at construction. Errors are :class:`FlightError` and name the
field, what was expected and what was found. Constructors repair nothing (time stamps must
be strictly increasing); repairing a glitch of the input, counted in ``Flight.repairs``,
is the edge's job (the readers, :meth:`Flight.from_arrays`; :mod:`windahrs.repair`).

NaN policy: a sensor sample (a row) with a NaN in any component is a *missing* sample;
estimators skip it and count it. Time stamps, truth and the site must be finite. Infinite
values are never accepted.

Units: SI (rad/s, m/s^2, tesla, m/s, rad). The plausibility checks below catch the usual
slips (deg/s for rad/s, g for m/s^2, microtesla or gauss for tesla) and say how to fix them.
They look at the bulk of the data (a median, or the share of samples beyond the sensor's
range), never at one sample: a single spike is a glitch, not a unit.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from windahrs.conventions import (
    ACCEL_UNITS,
    G0,
    GYRO_UNITS,
    MAG_NOMINAL_FIELD,
    MAG_RELATIVE_UNITS,
    MAG_UNITS,
    P_FLU_FRD,
)
from windahrs.repair import (
    ACCEL_RANGE,
    AIRSPEED_RANGE,
    ANGLE_RANGE,
    GNSS_VELOCITY_RANGE,
    GYRO_RANGE,
    MAG_RANGE,
    REPAIR_KINDS,
    SPIKE_SHARE,
    RepairLog,
    beyond_range,
    finite_rows,
    is_bulk,
    repairs_text,
)

__all__ = [
    "AirDataStream",
    "Flight",
    "FlightError",
    "GnssStream",
    "ImuStream",
    "MagStream",
    "Reference",
    "Site",
    "Truth",
    "WindStream",
    "declination_radians",
    "mag_to_tesla",
    "with_declination",
]

F64 = NDArray[np.float64]
ReferenceKind = Literal["truth", "mocap", "autopilot"]
REFERENCE_KINDS: tuple[str, ...] = ("truth", "mocap", "autopilot")


class FlightError(ValueError):
    """A Flight field is malformed. ``field``, ``expected`` and ``found`` say how."""

    def __init__(self, field_name: str, expected: str, found: str) -> None:
        self.field = field_name
        self.expected = expected
        self.found = found
        super().__init__(f"{field_name}: expected {expected}, found {found}")


def _set(obj: object, name: str, value: object) -> None:
    object.__setattr__(obj, name, value)


def _as_array(name: str, value: ArrayLike, ndim: int, width: int | None, *, allow_inf: bool = False) -> F64:
    try:
        a = np.ascontiguousarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise FlightError(name, "a numeric array", f"{type(value).__name__} ({exc})") from None
    shape = "(N,)" if ndim == 1 else f"(N, {width})"
    if a.ndim != ndim or (width is not None and a.shape[-1] != width):
        raise FlightError(name, f"shape {shape}", str(a.shape))
    if not allow_inf and np.isinf(a).any():
        i = int(np.argwhere(np.isinf(a))[0][0])
        raise FlightError(name, "finite values or NaN for a missing sample", f"inf at row {i}")
    return a


def _check_time(name: str, t: ArrayLike) -> F64:
    a = _as_array(name, t, 1, None)
    if a.size == 0:
        raise FlightError(name, "at least one sample", "an empty time vector")
    if np.isnan(a).any():
        raise FlightError(name, "finite time stamps", f"NaN at index {int(np.argmax(np.isnan(a)))}")
    d = np.diff(a)
    if (d <= 0).any():
        i = int(np.argmax(d <= 0))
        raise FlightError(
            name, "strictly increasing time", f"t[{i}] = {float(a[i])!r} then t[{i + 1}] = {float(a[i + 1])!r}"
        )
    return a


def _check_range(name: str, a: F64 | None, limit: float, unit: str) -> None:
    """FlightError naming the first row of ``a`` with a component beyond the sensor range."""
    if a is None:
        return
    over, _ = beyond_range(a, limit)
    if over.any():
        i = int(np.argmax(over))
        raise FlightError(
            name, f"|component| within {limit:.4g} {unit} (the sensor's range, windahrs.repair)",
            f"{float(np.nanmax(np.abs(a[i]))):.4g} at row {i} (strict=False sets such a sample to NaN)",
        )


def _check_len(name: str, a: F64, n: int, tname: str) -> None:
    if a.shape[0] != n:
        raise FlightError(name, f"{n} rows (one per {tname} sample)", f"{a.shape[0]} rows")


def _check_finite(name: str, a: F64) -> None:
    if not np.isfinite(a).all():
        i = int(np.argwhere(~np.isfinite(a))[0][0])
        raise FlightError(name, "finite values", f"NaN at row {i}")


def _check_bulk(name: str, a: F64, limit: float, expected: str, hint: str = "") -> None:
    """A unit check on the bulk of the data: FlightError when the rows of ``a`` with a
    component beyond ``limit`` are its bulk (:func:`~windahrs.repair.is_bulk`: more than
    SPIKE_SHARE of the finite rows and more than one; fewer are spikes, left to the edge's
    repair)."""
    over, share = beyond_range(a, limit)
    if is_bulk(over, share):
        peak = float(np.nanmax(np.abs(a[over])))
        raise FlightError(
            name,
            f"{expected} (|component| within {limit:.4g} {expected} on {100 * (1 - SPIKE_SHARE):g} % of the samples)",
            f"{100 * share:.3g} % beyond, max {peak:.4g}{hint}",
        )


def _median_norm(a: F64) -> float:
    rows = a[np.isfinite(a).all(axis=1)]
    return float(np.median(np.linalg.norm(rows, axis=1))) if len(rows) else float("nan")


def _check_quat(name: str, q: F64) -> F64:
    n = np.linalg.norm(q, axis=1)
    bad = np.abs(n - 1.0) > 1e-3
    if bad.any():
        i = int(np.argmax(bad))
        raise FlightError(name, "unit quaternions [w, x, y, z]", f"norm {n[i]:.6g} at row {i}")
    # Renormalise stored-precision quaternions; w >= 0 by convention.
    return q * (np.where(q[:, :1] < 0, -1.0, 1.0) / n[:, None])


@dataclass(frozen=True)
class ImuStream:
    """Gyroscope and accelerometer, sampled together.

    t: (N,) s. w_b: (N, 3) body rate in rad/s (FRD), the mean over ``(t[k-1], t[k]]``.
    f_b: (N, 3) specific force in m/s^2 (a level, resting FRD sensor reads [0, 0, -g]).
    """

    t: F64
    w_b: F64
    f_b: F64

    def __post_init__(self) -> None:
        t = _check_time("imu.t", self.t)
        w = _as_array("imu.w_b", self.w_b, 2, 3)
        f = _as_array("imu.f_b", self.f_b, 2, 3)
        _check_len("imu.w_b", w, len(t), "imu.t")
        _check_len("imu.f_b", f, len(t), "imu.t")
        _check_bulk("imu.w_b", w, GYRO_RANGE, "rad/s", ": deg/s? multiply by pi/180")
        fn = _median_norm(f)
        if np.isfinite(fn) and not 2.0 < fn < 300.0:
            hint = ": in g? multiply by 9.80665" if 0.2 < fn <= 2.0 else ""
            raise FlightError("imu.f_b", "m/s^2 (median |f| between 2 and 300)", f"{fn:.4g}{hint}")
        _set(self, "t", t)
        _set(self, "w_b", w)
        _set(self, "f_b", f)

    @functools.cached_property
    def period(self) -> float:
        """The median step of ``t``, s (NaN for fewer than two samples), computed once: the
        checks after every run read it (50 us a minute of a 200 Hz stream)."""
        return float(np.median(np.diff(self.t))) if len(self.t) > 1 else math.nan


@dataclass(frozen=True)
class MagStream:
    """Magnetometer. t: (N,) s. mag_b: (N, 3) magnetic field in tesla, body axes."""

    t: F64
    mag_b: F64

    def __post_init__(self) -> None:
        t = _check_time("mag.t", self.t)
        m = _as_array("mag.mag_b", self.mag_b, 2, 3)
        _check_len("mag.mag_b", m, len(t), "mag.t")
        mn = _median_norm(m)
        if np.isfinite(mn) and not 1e-7 < mn < 1e-2:
            hint = ""
            if 5.0 < mn < 500.0:
                hint = ": in microtesla? multiply by 1e-6"
            elif 0.05 < mn < 5.0:
                hint = ": in gauss? multiply by 1e-4"
            raise FlightError(
                "mag.mag_b", "tesla (median |m| between 1e-7 and 1e-2)", f"{mn:.4g}{hint}"
            )
        _set(self, "t", t)
        _set(self, "mag_b", m)


@dataclass(frozen=True)
class GnssStream:
    """GNSS velocity. t: (N,) s (time of validity). v_n: (N, 3) m/s, NED. v_sigma: (N,)
    m/s or None, the receiver's own 1-sigma speed accuracy per sample (u-blox ``sAcc``,
    PX4's ``s_variance_m_s``; NaN where it gave none), which the INS takes as the velocity's
    noise where it exceeds ``gnss_sigma`` (:mod:`windahrs.aid.gnss_vel`)."""

    t: F64
    v_n: F64
    v_sigma: F64 | None = None

    def __post_init__(self) -> None:
        t = _check_time("gnss.t", self.t)
        v = _as_array("gnss.v_n", self.v_n, 2, 3)
        _check_len("gnss.v_n", v, len(t), "gnss.t")
        _check_bulk("gnss.v_n", v, GNSS_VELOCITY_RANGE, "m/s")
        _set(self, "t", t)
        _set(self, "v_n", v)
        if self.v_sigma is not None:
            s = _as_array("gnss.v_sigma", self.v_sigma, 1, None)
            _check_len("gnss.v_sigma", s, len(t), "gnss.t")
            bad = np.isfinite(s) & ~((s >= 0.0) & (s <= GNSS_VELOCITY_RANGE))
            if bad.any():
                i = int(np.argmax(bad))
                raise FlightError(
                    "gnss.v_sigma", f"a speed accuracy in m/s, 0 to {GNSS_VELOCITY_RANGE:g} (NaN: none given)",
                    f"{float(s[i]):.4g} at row {i}",
                )
            _set(self, "v_sigma", s)


@dataclass(frozen=True)
class AirDataStream:
    """Air data. t: (N,) s. tas: (N,) true airspeed, m/s.

    aoa, sideslip: (N,) angle of attack and sideslip in rad (FRD, SPEC 3.4.1:
    ``alpha = atan2(w, u)``, ``beta = asin(v / |V|)``), or None when no vanes exist.
    One vane alone (an angle-of-attack vane without a sideslip vane, or the reverse) is
    accepted: the missing angle is stored as NaN. A NaN angle does not make the sample
    missing (the airspeed stays a measurement); estimators fuse the air-data vector only
    when both angles are finite, otherwise the airspeed, an angle of attack alone
    (:mod:`windahrs.aid.aoa`) and a synthetic zero sideslip.
    """

    t: F64
    tas: F64
    aoa: F64 | None = None
    sideslip: F64 | None = None

    def __post_init__(self) -> None:
        t = _check_time("air.t", self.t)
        tas = _as_array("air.tas", self.tas, 1, None)
        _check_len("air.tas", tas, len(t), "air.t")
        _check_bulk("air.tas", tas, AIRSPEED_RANGE, "m/s")
        _set(self, "t", t)
        _set(self, "tas", tas)
        for name in ("aoa", "sideslip"):
            v = getattr(self, name)
            if v is None:
                continue
            a = _as_array(f"air.{name}", v, 1, None)
            _check_len(f"air.{name}", a, len(t), "air.t")
            _check_bulk(f"air.{name}", a, ANGLE_RANGE, "rad", ": degrees?")
            _set(self, name, a)
        if (self.aoa is None) != (self.sideslip is None):  # one vane: the other angle NaN
            _set(self, "aoa" if self.aoa is None else "sideslip", np.full(len(t), np.nan))

    @property
    def has_vanes(self) -> bool:
        """Both vane angles exist on at least one sample (what the air-vector fusion needs)."""
        if self.aoa is None or self.sideslip is None:
            return False
        return bool((np.isfinite(self.aoa) & np.isfinite(self.sideslip)).any())

    @property
    def vane_names(self) -> tuple[str, ...]:
        """The vane angles the stream carries (some finite value): "aoa", "sideslip"."""
        return tuple(
            n for n in ("aoa", "sideslip")
            if getattr(self, n) is not None and np.isfinite(getattr(self, n)).any()
        )


@dataclass(frozen=True)
class WindStream:
    """A wind velocity series (e.g. a log's own wind estimate). wind_n: (N, 3) m/s NED,
    the velocity of the air (where it blows TO)."""

    t: F64
    wind_n: F64

    def __post_init__(self) -> None:
        t = _check_time("ref_wind.t", self.t)
        w = _as_array("ref_wind.wind_n", self.wind_n, 2, 3)
        _check_len("ref_wind.wind_n", w, len(t), "ref_wind.t")
        _set(self, "t", t)
        _set(self, "wind_n", w)


@dataclass(frozen=True)
class Truth:
    """Simulation truth on its own time grid (the IMU grid for simulated flights).

    q_nb: (N, 4) attitude. Optional: v_n (N, 3) m/s, wind_n (N, 3) m/s (velocity of the
    air), gyro_bias_b (N, 3) rad/s, accel_bias_b (N, 3) m/s^2, p_n (N, 3) m NED position.
    """

    t: F64
    q_nb: F64
    v_n: F64 | None = None
    wind_n: F64 | None = None
    gyro_bias_b: F64 | None = None
    accel_bias_b: F64 | None = None
    p_n: F64 | None = None

    def __post_init__(self) -> None:
        t = _check_time("truth.t", self.t)
        q = _as_array("truth.q_nb", self.q_nb, 2, 4)
        _check_len("truth.q_nb", q, len(t), "truth.t")
        _check_finite("truth.q_nb", q)
        _set(self, "t", t)
        _set(self, "q_nb", _check_quat("truth.q_nb", q))
        for name in ("v_n", "wind_n", "gyro_bias_b", "accel_bias_b", "p_n"):
            v = getattr(self, name)
            if v is None:
                continue
            a = _as_array(f"truth.{name}", v, 2, 3)
            _check_len(f"truth.{name}", a, len(t), "truth.t")
            _check_finite(f"truth.{name}", a)
            _set(self, name, a)


@dataclass(frozen=True)
class Reference:
    """A reference attitude from a real recording, labelled by what it is.

    kind: "mocap" (optical motion capture), "autopilot" (the flight stack's own
    estimate) or "truth". q_nb: (N, 4); rows with NaN are gaps and are not scored.
    heading_free: the reference's heading datum is arbitrary (mocap), so scores remove a
    constant heading offset. mask: optional (N,) bool, samples to score.
    """

    t: F64
    q_nb: F64
    kind: ReferenceKind = "autopilot"
    heading_free: bool = False
    mask: NDArray[np.bool_] | None = None

    def __post_init__(self) -> None:
        if self.kind not in REFERENCE_KINDS:
            raise FlightError("reference.kind", f"one of {REFERENCE_KINDS}", repr(self.kind))
        t = _check_time("reference.t", self.t)
        q = _as_array("reference.q_nb", self.q_nb, 2, 4)
        _check_len("reference.q_nb", q, len(t), "reference.t")
        ok = np.isfinite(q).all(axis=1)
        qn = q.copy()
        qn[ok] = _check_quat("reference.q_nb", q[ok])
        qn[~ok] = np.nan
        _set(self, "t", t)
        _set(self, "q_nb", qn)
        if self.mask is not None:
            m = np.asarray(self.mask)
            if m.shape != t.shape or m.dtype != np.bool_:
                raise FlightError(
                    "reference.mask", f"bool array of shape {t.shape}", f"{m.dtype} {m.shape}"
                )
            _set(self, "mask", m)


#: How far (rad) a declination given with ``mag_n`` may be from the field's own: 0.1 deg,
#: a rounding of a declination quoted to a tenth of a degree (as NOAA's calculator does).
DECLINATION_TOL = float(np.radians(0.1))


@dataclass(frozen=True)
class Site:
    """Where the flight happened.

    gravity: m/s^2 (magnitude; the vector is [0, 0, gravity] in NED).
    mag_n: (3,) Earth's magnetic field in NED, tesla, or None when unknown (estimators
    then take the field's magnitude and dip from the data).
    declination: the field's declination, rad, east of true north (``atan2(mag_n[1],
    mag_n[0])``), or None when unknown (estimators then take magnetic north for north:
    their heading is magnetic). With ``mag_n`` it is derived from it, and a declination
    given with ``mag_n`` must agree with it within :data:`DECLINATION_TOL`. Without
    ``mag_n`` it is what a reader knows of the site, e.g. the autopilot's own declination
    parameter (PX4 ``EKF2_MAG_DECL``, ArduPilot ``COMPASS_DEC``): estimators turn the
    field they learn by it, so that their heading is true, as the autopilot's is.
    """

    gravity: float = G0
    mag_n: F64 | None = None
    declination: float | None = None

    def __post_init__(self) -> None:
        g = float(self.gravity)
        if not np.isfinite(g) or not 9.7 < g < 9.9:
            raise FlightError("site.gravity", "m/s^2 between 9.7 and 9.9", repr(self.gravity))
        _set(self, "gravity", g)
        if self.mag_n is not None:
            m = np.asarray(self.mag_n, dtype=np.float64)
            if m.shape != (3,) or not np.isfinite(m).all():
                raise FlightError("site.mag_n", "finite (3,) vector in tesla", f"{m.shape} {m}")
            n = float(np.linalg.norm(m))
            if not 1e-6 < n < 1e-3:
                raise FlightError("site.mag_n", "tesla (|m| between 1e-6 and 1e-3)", f"{n:.4g}")
            _set(self, "mag_n", m)
        d = self.declination
        if d is not None:
            if isinstance(d, bool) or not isinstance(d, int | float | np.floating | np.integer):
                raise FlightError("site.declination", "a number of radians or None", repr(d))
            d = float(d)
            if not (np.isfinite(d) and abs(d) <= np.pi):
                raise FlightError("site.declination", "radians in [-pi, pi] (east positive)", repr(d))
        if self.mag_n is not None:
            derived = float(np.arctan2(self.mag_n[1], self.mag_n[0]))
            if d is not None and abs(np.angle(np.exp(1j * (d - derived)))) > DECLINATION_TOL:
                raise FlightError(
                    "site.declination",
                    f"the declination of site.mag_n ({np.degrees(derived):.3f} deg) or None",
                    f"{np.degrees(d):.3f} deg",
                )
            d = derived
        _set(self, "declination", d)

    @property
    def gravity_n(self) -> F64:
        return np.array([0.0, 0.0, self.gravity])


@dataclass(frozen=True)
class Flight:
    """Sensor streams, site and optional truth or reference of one flight.

    imu is required; mag, gnss, air are optional streams. truth (simulation) and
    reference (real data) are what estimates are scored against. meta: free-form
    str -> str/float/int description (source file, vehicle, scenario, seed). repairs: what
    the edge repaired in the input (:mod:`windahrs.repair`), stream name -> kind
    (:data:`~windahrs.repair.REPAIR_KINDS`) -> count, e.g. ``{"imu": {"duplicates": 2}}``;
    empty when nothing was repaired (and for a Flight built from its constructors).
    repair_times: where, stream name -> kind -> (K,) times s (sorted) of the rows repaired
    (:mod:`windahrs.repair`: a sorted row's new place, the kept row of a dropped repeat, a
    row set to NaN), what the flags ``stamps_repaired`` and ``values_repaired`` mark; may
    be empty while ``repairs`` is not (a Flight saved before it existed, rows without a time).
    """

    imu: ImuStream
    mag: MagStream | None = None
    gnss: GnssStream | None = None
    air: AirDataStream | None = None
    truth: Truth | None = None
    reference: Reference | None = None
    ref_wind: WindStream | None = None
    site: Site = field(default_factory=Site)
    meta: dict[str, Any] = field(default_factory=dict)
    repairs: dict[str, dict[str, int]] = field(default_factory=dict)
    repair_times: dict[str, dict[str, F64]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        types = {
            "imu": ImuStream,
            "mag": MagStream,
            "gnss": GnssStream,
            "air": AirDataStream,
            "truth": Truth,
            "reference": Reference,
            "ref_wind": WindStream,
            "site": Site,
        }
        for name, typ in types.items():
            v = getattr(self, name)
            if v is None and name != "imu" and name != "site":
                continue
            if not isinstance(v, typ):
                raise FlightError(name, typ.__name__, type(v).__name__)
        for k, v in self.meta.items():
            if not isinstance(k, str) or not isinstance(v, str | int | float | bool):
                raise FlightError(f"meta[{k!r}]", "str, int, float or bool", type(v).__name__)
        _set(self, "repairs", _check_repairs(self.repairs))
        _set(self, "repair_times", _check_repair_times(self.repair_times))

    @classmethod
    def from_arrays(
        cls,
        t: ArrayLike | None = None,
        gyro: ArrayLike | None = None,
        accel: ArrayLike | None = None,
        mag: ArrayLike | None = None,
        *,
        rate: float | None = None,
        gyro_units: Literal["rad/s", "deg/s"] = "rad/s",
        accel_units: Literal["m/s^2", "g"] = "m/s^2",
        mag_units: Literal["T", "mT", "uT", "nT", "G", "gauss", "mG", "normalised", "arbitrary"] = "T",
        frame: Literal["FRD", "FLU"] = "FRD",
        reference: ArrayLike | None = None,
        reference_kind: ReferenceKind = "mocap",
        site: Site | None = None,
        meta: dict[str, Any] | None = None,
        strict: bool = False,
    ) -> Flight:
        """A Flight from raw IMU arrays, as they come from a logger or ``vqf``'s
        ``VQF(Ts).updateBatch(gyr, acc, mag)``.

        t: (N,) s, increasing (see Repair below); or give ``rate`` (Hz) instead for samples
        ``k / rate``. gyro: (N, 3) body rate; accel: (N, 3) specific force (a resting
        sensor reads +g upward); mag: (N, 3) magnetic field on the same time grid, or
        None. Rows with NaN are missing samples. Units (keyword-only): ``gyro_units``
        "rad/s" | "deg/s", ``accel_units`` "m/s^2" | "g" (9.80665 m/s^2), ``mag_units``
        "T" | "mT" | "uT" | "nT" | "G" | "gauss" | "mG", or "normalised" (alias "arbitrary")
        for a field in unknown units, scaled by :func:`mag_to_tesla` (heading only).
        frame: body axes of the arrays, "FRD" (forward, right, down; windahrs) or "FLU"
        (forward, left, up; ROS, most vqf examples),
        converted with :data:`~windahrs.conventions.P_FLU_FRD`. reference: (N, 4) a
        reference attitude [w, x, y, z] on the same grid (body to NED for "FRD", FLU body
        to ENU for "FLU", as ROS logs it), labelled ``reference_kind``. site: gravity and
        Earth's field (default: standard gravity, field unknown).

        Repair (the default, ``strict=False``), as the readers do (:mod:`windahrs.repair`),
        counted in ``Flight.repairs`` (time repairs under "imu": the magnetometer and the
        reference share its grid): rows with a non-finite time are dropped, rows out of
        order sorted, repeated stamps keep their first row; rows with inf become NaN; a
        sample beyond the sensor's range (:data:`~windahrs.repair.GYRO_RANGE`,
        :data:`~windahrs.repair.ACCEL_RANGE`, :data:`~windahrs.repair.MAG_RANGE`, after the
        unit conversion) becomes NaN. ``strict=True`` repairs nothing and refuses each of
        these instead.

        Raises :class:`FlightError` (a ValueError) naming the argument and what was found:
        wrong shapes or lengths, only NaN, an unknown unit or frame, units wrong on the bulk
        of the data; with ``strict=True`` also time not increasing, inf values and samples
        beyond the sensor's range.
        """
        if (t is None) == (rate is None):
            found = "both" if t is not None else "neither"
            raise FlightError("t, rate", "time stamps t (s) or a sample rate rate (Hz), one of them", found)
        log = RepairLog()
        g = _raw_rows("gyro", gyro, strict=strict)
        n = len(g)
        a = _raw_rows("accel", accel, n, strict=strict)
        m = _raw_rows("mag", mag, n, strict=strict) if mag is not None else None
        q = None
        if reference is not None:
            q = _as_array("reference", reference, 2, 4, allow_inf=not strict)
            if len(q) != n:
                raise FlightError("reference", f"{n} rows (one per gyro row)", f"{len(q)} rows")
        if rate is not None:
            r = float(rate)
            if not (np.isfinite(r) and r > 0):
                raise FlightError("rate", "a sample rate > 0 Hz", repr(rate))
            t_s = np.arange(n, dtype=np.float64) / r
        else:
            t_s = _as_array("t", t, 1, None, allow_inf=not strict)  # type: ignore[arg-type]
            if len(t_s) != n:
                raise FlightError("t", f"{n} time stamps (one per gyro row)", f"{len(t_s)}")
            if not strict:
                rows = [x for x in (g, a, m, q) if x is not None]
                t_s, rows = log.series("imu", t_s, *rows)
                g, a = rows[0], rows[1]
                m = rows[2] if m is not None else None
                q = rows[-1] if q is not None else None
            t_s = _check_time("t", t_s)
        g = g * _unit("gyro_units", gyro_units, GYRO_UNITS)
        a = a * _unit("accel_units", accel_units, ACCEL_UNITS)
        extra_meta: dict[str, Any] = {}
        if m is not None:
            site_field = None if site is None else site.mag_n
            m = mag_to_tesla(m, mag_units, site_mag_n=site_field, name="mag_units", meta=extra_meta)
        if frame not in ("FRD", "FLU"):
            raise FlightError("frame", "'FRD' or 'FLU'", repr(frame))
        if not strict:
            g, a = log.rows("imu", g, GYRO_RANGE), log.rows("imu", a, ACCEL_RANGE)
            m = None if m is None else log.rows("mag", m, MAG_RANGE)
            q = None if q is None else finite_rows(q)
        ref = None
        if q is not None:
            if frame == "FLU":
                from windahrs.rotation import quat_enu_flu_to_ned_frd

                ok = np.isfinite(q).all(axis=1)
                q = q.copy()
                q[ok] = quat_enu_flu_to_ned_frd(q[ok])
            ref = Reference(t=t_s, q_nb=q, kind=reference_kind)
        if frame == "FLU":
            g, a = g @ P_FLU_FRD.T, a @ P_FLU_FRD.T
            m = None if m is None else m @ P_FLU_FRD.T
        try:
            imu = ImuStream(t=t_s, w_b=g, f_b=a)
            mag_stream = None if m is None else MagStream(t=t_s, mag_b=m)
        except FlightError as exc:  # a unit slip: say which argument and which keyword fixes it
            name = _RAW_NAMES.get(exc.field, exc.field)
            found = exc.found
            for hint, switch in _UNIT_HINTS.items():
                found = found.replace(hint, switch)
            raise FlightError(name, exc.expected, found) from None
        if strict:  # after the unit checks, whose hints say more than a range
            for name, x, limit, unit in (
                ("gyro", g, GYRO_RANGE, "rad/s"), ("accel", a, ACCEL_RANGE, "m/s^2"), ("mag", m, MAG_RANGE, "T")
            ):
                _check_range(name, x, limit, unit)
        return log.attach(
            cls(
                imu=imu,
                mag=mag_stream,
                reference=ref,
                site=site if site is not None else Site(),
                meta={"source": "arrays", **extra_meta, **(meta or {})},
                repairs=log.counts,
            )
        )

    @property
    def duration(self) -> float:
        """Span of the IMU stream, s."""
        return float(self.imu.t[-1] - self.imu.t[0])

    def streams(self) -> dict[str, F64]:
        """Time vectors of the sensor streams present, by name."""
        out = {"imu": self.imu.t}
        for name in ("mag", "gnss", "air"):
            s = getattr(self, name)
            if s is not None:
                out[name] = s.t
        return out

    def replace(self, **changes: Any) -> Flight:
        """A copy with some fields replaced (validated again)."""
        return dataclasses.replace(self, **changes)

    def summary(self) -> str:
        """Human-readable description: streams, rates, duration, truth/reference."""
        lines = [f"duration   {self.duration:.2f} s"]
        for name, t in self.streams().items():
            stream = getattr(self, name)
            lines.append(f"{name:<10} {_rate_text(t)}{_missing_text(stream)}")
        if self.air is not None:
            vanes = self.air.vane_names
            text = "yes" if self.air.has_vanes else ("only " + vanes[0] if vanes else "no")
            lines.append(f"{'':<10} vanes (aoa, sideslip): {text}")
        lines.append(f"truth      {'yes' if self.truth is not None else 'no'}")
        if self.reference is not None:
            ref = self.reference
            free = ", heading-free (scored after removing a constant heading offset)" if ref.heading_free else ""
            lines.append(f"reference  {ref.kind}, {_rate_text(ref.t)}{free}")
        if self.site.mag_n is not None:
            m = self.site.mag_n * 1e6
            field_text = f"[{m[0]:.2f}, {m[1]:.2f}, {m[2]:.2f}] uT"
            lines.append(f"site       g = {self.site.gravity:.5f} m/s^2, mag_n = {field_text}")
        elif self.site.declination is not None:
            lines.append(f"site       g = {self.site.gravity:.5f} m/s^2, mag_n unknown, "
                         f"declination {np.degrees(self.site.declination):+.2f} deg")
        else:
            lines.append(f"site       g = {self.site.gravity:.5f} m/s^2, mag_n unknown")
        for stream, counts in self.repairs.items():
            lines.append(f"repairs    {repairs_text({stream: counts})}")
        for k, v in sorted(self.meta.items()):
            lines.append(f"meta       {k} = {v}")
        return "\n".join(lines)


#: What a declination given in degrees must be: a direction east of true north, so within
#: half a turn either way (the CSV manifest's ``declination_deg`` takes the same range).
DECLINATION_DEG_EXPECTED = "degrees east of true north, a finite number from -180 to 180"


def declination_radians(degrees: object, name: str = "declination") -> float:
    """A declination given in degrees east of true north (a finite number within +-180),
    in radians; a :class:`FlightError` naming ``name`` (e.g. the option it came from)
    otherwise."""
    if isinstance(degrees, bool) or not isinstance(degrees, int | float | np.floating | np.integer):
        raise FlightError(name, DECLINATION_DEG_EXPECTED, repr(degrees))
    d = float(degrees)
    if not (math.isfinite(d) and abs(d) <= 180.0):
        raise FlightError(name, DECLINATION_DEG_EXPECTED, repr(degrees))
    return math.radians(d)


def with_declination(flight: Flight, degrees: float, *, source: str = "declination") -> Flight:
    """The flight with its site's declination set to ``degrees`` (east of true north),
    replacing what its log said (an autopilot parameter, a manifest's ``declination_deg``),
    and ``meta["site.declination_param"] = source`` (what ``info`` shows); the value it
    replaced, if any, is kept as ``meta["site.declination_replaced"]``.

    When the site's Earth field is known (``mag_n``) the declination is the field's own: a
    value that agrees with it within :data:`DECLINATION_TOL` leaves the flight as it is, one
    that does not is refused (:class:`Site`'s check), a :class:`FlightError` naming
    ``source`` and both values. A value that is not finite or beyond +-180 is refused too
    (:func:`declination_radians`)."""
    d = declination_radians(degrees, source)
    site = flight.site
    try:
        new_site = dataclasses.replace(site, declination=d)
    except FlightError as exc:
        if exc.field != "site.declination" or site.declination is None:
            raise
        raise FlightError(
            source,
            f"the declination of the flight's known field site.mag_n ({np.degrees(site.declination):+.3f} deg, "
            f"within {np.degrees(DECLINATION_TOL):.1f} deg)",
            f"{float(degrees):+.3f} deg",
        ) from None
    if site.mag_n is not None:  # the field's own declination stands, checked against the value
        return flight
    meta = dict(flight.meta)
    if site.declination is not None:
        was = meta.get("site.declination_param", "the flight")
        meta["site.declination_replaced"] = f"{was}: {np.degrees(site.declination):+.3f} deg"
    meta["site.declination_param"] = source
    return flight.replace(site=new_site, meta=meta)


#: The parts of a Flight whose input the edge may repair (keys of ``Flight.repairs``).
REPAIRABLE: tuple[str, ...] = ("imu", "mag", "gnss", "air", "truth", "reference", "ref_wind")


def _repair_entries(field: str, value: object, what: str) -> Iterator[tuple[str, str, object]]:
    """Each (stream, kind, entry) of ``Flight.repairs`` or ``Flight.repair_times`` (``field``),
    whose shape, streams (:data:`REPAIRABLE`) and kinds (``REPAIR_KINDS``) it checks on the
    way; ``what``: the entries' name in the errors ("count", "times")."""
    if not isinstance(value, dict):
        raise FlightError(field, f"a dict stream -> {{kind: {what}}}", type(value).__name__)
    for stream, kinds in value.items():
        if stream not in REPAIRABLE:
            raise FlightError(field, f"streams among {REPAIRABLE}", repr(stream))
        if not isinstance(kinds, dict):
            raise FlightError(f"{field}[{stream!r}]", f"a dict kind -> {what}", type(kinds).__name__)
        for kind, entry in kinds.items():
            if kind not in REPAIR_KINDS:
                raise FlightError(f"{field}[{stream!r}]", f"kinds among {REPAIR_KINDS}", repr(kind))
            yield stream, kind, entry


def _check_repairs(repairs: object) -> dict[str, dict[str, int]]:
    """``Flight.repairs`` validated, as plain ints, zero counts and empty streams left out."""
    out: dict[str, dict[str, int]] = {}
    for stream, kind, n in _repair_entries("repairs", repairs, "count"):
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
            raise FlightError(f"repairs[{stream!r}][{kind!r}]", "a count (int >= 0)", repr(n))
        if n:
            out.setdefault(stream, {})[kind] = int(n)
    return {stream: {k: c[k] for k in REPAIR_KINDS if k in c} for stream, c in out.items()}


_RAW_NAMES = {"imu.w_b": "gyro", "imu.f_b": "accel", "mag.mag_b": "mag"}
_UNIT_HINTS = {
    "deg/s? multiply by pi/180": "deg/s? pass gyro_units='deg/s'",
    "in g? multiply by 9.80665": "in g? pass accel_units='g'",
    "in microtesla? multiply by 1e-6": "in microtesla? pass mag_units='uT'",
    "in gauss? multiply by 1e-4": "in gauss? pass mag_units='gauss'",
}


def _raw_rows(name: str, value: ArrayLike | None, n: int | None = None, *, strict: bool = True) -> F64:
    """(N, 3) float rows of a raw sensor array, at least one of them finite (inf refused
    when ``strict``)."""
    if value is None:
        raise FlightError(name, "an (N, 3) array", "none")
    a = _as_array(name, value, 2, 3, allow_inf=not strict)
    if n is not None and len(a) != n:
        raise FlightError(name, f"{n} rows (one per gyro row)", f"{len(a)} rows")
    if len(a) == 0:
        raise FlightError(name, "at least one sample", "an empty array")
    if not np.isfinite(a).all(axis=1).any():
        raise FlightError(name, "at least one finite sample", f"only NaN in {len(a)} rows")
    return a


def mag_to_tesla(
    mag: ArrayLike,
    unit: str,
    *,
    site_mag_n: ArrayLike | None = None,
    name: str = "mag.unit",
    meta: dict[str, Any] | None = None,
) -> F64:
    """Magnetometer readings (N, 3) in ``unit`` to tesla, a new array.

    unit: a key of :data:`~windahrs.conventions.MAG_UNITS` (a fixed factor), or one of
    :data:`~windahrs.conventions.MAG_RELATIVE_UNITS` ("normalised", "arbitrary": the unit
    is unknown): the readings are then scaled by one factor so that the median norm of
    the finite rows is ``|site_mag_n|`` when the site's field is known, else
    :data:`~windahrs.conventions.MAG_NOMINAL_FIELD` (50 uT, a placeholder), and ``meta``
    (when given) receives ``mag.unit`` = "normalised" and ``mag.raw_median_norm`` (the
    median norm in the input's units). The magnitude is then no information: estimators
    compare the field only with its own first samples (site unknown) or the site's field.
    Raises :class:`FlightError` naming ``name`` for an unknown unit.
    """
    m = np.array(mag, dtype=np.float64)
    if unit in MAG_UNITS:
        return m * MAG_UNITS[unit]
    if unit not in MAG_RELATIVE_UNITS:
        units = [*MAG_UNITS, *MAG_RELATIVE_UNITS]
        raise FlightError(name, f"one of {', '.join(map(repr, units))}", repr(unit))
    raw = _median_norm(m) if m.ndim == 2 and m.shape[-1] == 3 else float("nan")
    if not (np.isfinite(raw) and raw > 0):
        raise FlightError(name, f"{unit!r} readings with a finite, non-zero median norm", repr(raw))
    target = MAG_NOMINAL_FIELD
    if site_mag_n is not None:
        target = float(np.linalg.norm(np.asarray(site_mag_n, dtype=np.float64)))
    if meta is not None:
        meta["mag.unit"] = "normalised"
        meta["mag.raw_median_norm"] = raw
    return m * (target / raw)


def _unit(name: str, unit: str, table: dict[str, float]) -> float:
    if unit not in table:
        raise FlightError(name, f"one of {', '.join(map(repr, table))}", repr(unit))
    return table[unit]


def _rate_text(t: F64) -> str:
    if len(t) < 2:
        return f"{len(t)} sample"
    rate = 1.0 / float(np.median(np.diff(t)))
    gaps = int(np.sum(np.diff(t) > 1.5 / rate))
    gap_text = f", {gaps} gaps" if gaps else ""
    return f"{len(t)} samples at {rate:.4g} Hz{gap_text}"


def _missing_text(stream: object) -> str:
    arrays = [v for v in vars(stream).values() if isinstance(v, np.ndarray) and v.ndim >= 1]
    rows = arrays[0].shape[0]
    missing = np.zeros(rows, dtype=bool)
    for a in arrays[1:]:
        missing |= ~np.isfinite(a.reshape(rows, -1)).all(axis=1)
    n = int(missing.sum())
    return f", {n} missing" if n else ""


def _check_repair_times(times: object) -> dict[str, dict[str, F64]]:
    """``Flight.repair_times`` validated: streams and kinds as ``repairs``', each (K,) finite
    times s, returned sorted as float64; empty arrays and streams left out."""
    out: dict[str, dict[str, F64]] = {}
    for stream, kind, v in _repair_entries("repair_times", times, "times"):
        where = f"repair_times[{stream!r}][{kind!r}]"
        try:
            a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise FlightError(where, "an array of times (s)", type(v).__name__) from None
        if a.ndim != 1:
            raise FlightError(where, "a 1-D array of times (s)", f"shape {a.shape}")
        if not np.isfinite(a).all():
            raise FlightError(where, "finite times (s)", "a non-finite value")
        if len(a):
            out.setdefault(stream, {})[kind] = np.sort(a)
    return out
