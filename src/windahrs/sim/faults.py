"""Sensor faults injected into a simulated flight's streams, after the simulation: the truth
is untouched, so an estimator's error during and after a fault is measured against it.

Each fault is a small frozen record with a ``start`` time (s, on the flight's clock) and a
``duration`` (s), plus its own parameters, validated on construction (:class:`FaultError`
names the field, the expected and the found value). ``span`` is the interval during which
it is active, what the fault matrix (:mod:`windahrs.experiments.faults`) scores against.
Faults compose: :func:`inject` applies a list of them in order (value faults first, then
the time-stamp faults, which change the stamps the others select samples by), each
drawing from its own child of one seeded generator, so adding a fault to a list does not
change the draws of the others. Catalogue (``kind`` in the CLI spec, docs/ROBUSTNESS.md):

======================  ===================================================================
IMU                     ``imu-dropout`` (samples removed), ``imu-nan`` (NaN or Inf
                        samples), ``gyro-spike``, ``accel-spike``, ``imu-stuck``,
                        ``gyro-saturation``, ``accel-saturation``, ``vibration``
magnetometer            ``mag-magnet`` (offset field), ``mag-drift`` (slowly varying
                        field), ``mag-absent`` (samples removed)
air data                ``pitot`` (freeze, zero or ramp), ``vane`` (stuck or lost)
GNSS velocity           ``gnss-outage`` (samples removed), ``gnss-jump``
time stamps             ``imu-jitter``, ``duplicate-stamps``, ``out-of-order``
======================  ===================================================================

Duplicated and out-of-order stamps (and Inf values, and spikes beyond the unit check of
:class:`~windahrs.flight.ImuStream`) make streams that the ``Flight`` constructor refuses:
:func:`inject` then raises a :class:`FaultError` that says so, and :func:`inject_raw` gives
the streams as arrays (:class:`RawFlight`), which :meth:`RawFlight.write_csv_dir` writes in
the generic CSV format (``docs/csv-format.md``) for the readers' edge repair.

From the command line: ``windahrs simulate --fault gyro-spike:start=30:magnitude=40``
(:func:`parse_fault` reads that form; :meth:`Fault.spec` writes it).
"""

from __future__ import annotations

import dataclasses
import math
import os
import secrets
import shutil
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from windahrs.conventions import DEG, G0
from windahrs.flight import AirDataStream, Flight, FlightError, GnssStream, ImuStream, MagStream

__all__ = [
    "FAULTS",
    "AccelSaturation",
    "AccelSpike",
    "DuplicateStamps",
    "Fault",
    "FaultError",
    "GnssJump",
    "GnssOutage",
    "GyroSaturation",
    "GyroSpike",
    "ImuDropout",
    "ImuJitter",
    "ImuNaN",
    "ImuStuck",
    "MagAbsent",
    "MagDrift",
    "MagMagnet",
    "OutOfOrder",
    "PitotBlockage",
    "PitotScale",
    "RawFlight",
    "VaneFailure",
    "VibrationBurst",
    "inject",
    "inject_raw",
    "parse_fault",
]

F64 = NDArray[np.float64]

#: MPU-9150 full-scale ranges (InvenSense PS-MPU-9150A, section 6.1): the smallest gyro range
#: (+-250 deg/s) and accelerometer range (+-2 g), the saturation faults' defaults.
MPU9150_GYRO_MIN_RANGE = 250.0 * DEG
MPU9150_ACCEL_MIN_RANGE = 2.0 * G0


class FaultError(ValueError):
    """A fault is malformed or does not fit the flight. ``field``, ``expected`` and
    ``found`` say how (e.g. ``GyroSpike.magnitude: expected a finite value, found inf``)."""

    def __init__(self, field_name: str, expected: str, found: str) -> None:
        self.field = field_name
        self.expected = expected
        self.found = found
        super().__init__(f"{field_name}: expected {expected}, found {found}")


# ---------------------------------------------------------------------------------------------
# the streams as plain arrays


@dataclass
class RawFlight:
    """A flight's sensor streams as plain arrays, which faults edit, and the untouched rest
    (truth, site, meta) of the flight they came from.

    imu: ``{"t", "w_b", "f_b"}``; mag: ``{"t", "mag_b"}``; gnss: ``{"t", "v_n"}``; air:
    ``{"t", "tas", "aoa", "sideslip"}`` (the vane arrays may be absent); a stream the flight
    lacks is None. Arrays are in the Flight's units (SI) and may hold what a Flight refuses
    (repeated or unordered stamps, Inf)."""

    flight: Flight
    imu: dict[str, F64]
    mag: dict[str, F64] | None
    gnss: dict[str, F64] | None
    air: dict[str, F64] | None
    applied: list[str] = field(default_factory=list)

    @classmethod
    def of(cls, flight: Flight) -> RawFlight:
        """Copies of ``flight``'s streams."""

        def arrays(stream: object | None, names: tuple[str, ...]) -> dict[str, F64] | None:
            if stream is None:
                return None
            out = {}
            for n in names:
                v = getattr(stream, n, None)
                if v is not None:
                    out[n] = np.array(v, dtype=np.float64)
            return out

        imu = arrays(flight.imu, ("t", "w_b", "f_b"))
        assert imu is not None
        return cls(
            flight=flight,
            imu=imu,
            mag=arrays(flight.mag, ("t", "mag_b")),
            gnss=arrays(flight.gnss, ("t", "v_n", "v_sigma")),
            air=arrays(flight.air, ("t", "tas", "aoa", "sideslip")),
        )

    def stream(self, name: str) -> dict[str, F64] | None:
        out: dict[str, F64] | None = getattr(self, name)
        return out

    def first_change(self) -> float | None:
        """The time of the first sample, in any stream, that differs from the original
        flight's (a value, a stamp, a sample added or removed; NaN equal to NaN): when the
        faults began to act, which a fault placed at random in its span (a duplicated
        stamp) does after the span's start. None when they changed nothing."""
        first: float | None = None
        orig = RawFlight.of(self.flight)
        for name in ("imu", "mag", "gnss", "air"):
            new, old = self.stream(name), orig.stream(name)
            if new is None or old is None:
                continue
            n = min(len(new["t"]), len(old["t"]))
            differ = np.zeros(n, dtype=bool)
            for key in set(new) | set(old):
                a, b = new.get(key), old.get(key)
                if a is None or b is None:
                    continue
                a2, b2 = a[:n].reshape(n, -1), b[:n].reshape(n, -1)
                differ |= ~((a2 == b2) | (np.isnan(a2) & np.isnan(b2))).all(axis=1)
            idx = np.flatnonzero(differ)
            if len(idx):
                t = float(min(new["t"][idx[0]], old["t"][idx[0]]))
            elif len(new["t"]) != len(old["t"]):
                t = float((new["t"] if len(new["t"]) > n else old["t"])[n])
            else:
                continue
            first = t if first is None else min(first, t)
        return first

    def to_flight(self) -> Flight:
        """The streams as a Flight with the original truth, site and meta (meta["faults"]
        lists the faults applied). Raises :class:`FaultError` when the Flight constructor
        refuses the streams (repeated or unordered stamps, Inf, a spike beyond the unit
        check): such streams need the readers' edge repair (:meth:`write_csv_dir`)."""
        f = self.flight
        try:
            imu = ImuStream(t=self.imu["t"], w_b=self.imu["w_b"], f_b=self.imu["f_b"])
            mag = None if self.mag is None else MagStream(t=self.mag["t"], mag_b=self.mag["mag_b"])
            gnss = None if self.gnss is None else GnssStream(
                t=self.gnss["t"], v_n=self.gnss["v_n"], v_sigma=self.gnss.get("v_sigma")
            )
            air = None
            if self.air is not None:
                air = AirDataStream(
                    t=self.air["t"], tas=self.air["tas"], aoa=self.air.get("aoa"), sideslip=self.air.get("sideslip")
                )
        except FlightError as exc:
            raise FaultError(
                "faults",
                "streams a Flight accepts",
                f"{exc} (after {'; '.join(self.applied)}): use inject_raw() and write_csv_dir() to read them "
                "through the readers' edge repair",
            ) from None
        meta = dict(f.meta)
        if self.applied:
            meta["faults"] = "; ".join(self.applied)
        return f.replace(imu=imu, mag=mag, gnss=gnss, air=air, meta=meta)

    def write_csv_dir(self, path: str | os.PathLike[str]) -> Path:
        """Write the streams as a generic-CSV directory (``docs/csv-format.md``: ``imu.csv``,
        ``mag.csv`` (uT), ``gnss.csv``, ``air.csv``, the truth's attitude as the reference
        ``att.csv``, ``windahrs.toml``), as they are, repeated or unordered stamps included;
        NaN as empty cells. The directory must not exist; it appears complete or not at all."""
        target = Path(path)
        if target.exists():
            raise FaultError("path", "a directory that does not exist yet", f"{target} exists")
        parent = target.parent if str(target.parent) else Path(".")
        if not parent.is_dir():
            raise FaultError("path", "a path in an existing directory", f"{parent} does not exist")
        # a plain mkdir, which honours the user's umask (tempfile.mkdtemp makes it 0o700)
        tmp = parent / f".{target.name}.{secrets.token_hex(6)}.tmp"
        tmp.mkdir()
        try:
            self._write_csv(tmp)
            os.replace(tmp, target)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return target

    def _write_csv(self, d: Path) -> None:
        f = self.flight
        man = ['format = "windahrs.csv"', "version = 1", "", "[flight]", 'time_origin = "none"']
        if f.site.mag_n is not None:
            man.append(f"mag_n = [{', '.join(repr(float(v)) for v in f.site.mag_n)}]")
        elif f.site.declination is not None:
            man.append(f"declination_deg = {math.degrees(f.site.declination)!r}")
        man.append(f"gravity = {f.site.gravity!r}")
        imu = self.imu
        _csv(d / "imu.csv", ["t", "wx", "wy", "wz", "fx", "fy", "fz"], [imu["t"], imu["w_b"], imu["f_b"]])
        clock = ['time = "t"', 'time_unit = "s"']
        man += ["", "[imu]", 'file = "imu.csv"', *clock, 'gyro = ["wx", "wy", "wz"]', 'gyro_unit = "rad/s"',
                'accel = ["fx", "fy", "fz"]', 'accel_unit = "m/s^2"']
        if self.mag is not None:
            _csv(d / "mag.csv", ["t", "mx", "my", "mz"], [self.mag["t"], self.mag["mag_b"] * 1e6])
            man += ["", "[mag]", 'file = "mag.csv"', *clock, 'columns = ["mx", "my", "mz"]', 'unit = "uT"']
        if self.gnss is not None:
            _csv(d / "gnss.csv", ["t", "vn", "ve", "vd"], [self.gnss["t"], self.gnss["v_n"]])
            man += ["", "[gnss]", 'file = "gnss.csv"', *clock, 'velocity = ["vn", "ve", "vd"]', 'unit = "m/s"']
        if self.air is not None:
            cols, header = [self.air["t"], self.air["tas"]], ["t", "tas"]
            for name in ("aoa", "sideslip"):
                if name in self.air:
                    cols.append(self.air[name])
                    header.append(name)
            _csv(d / "air.csv", header, cols)
            man += ["", "[air]", 'file = "air.csv"', *clock, 'tas = "tas"']
            man += [f'{name} = "{name}"' for name in header[2:]] + ['unit = "m/s"', 'angle_unit = "rad"']
        if f.truth is not None:
            _csv(d / "att.csv", ["t", "qw", "qx", "qy", "qz"], [f.truth.t, f.truth.q_nb])
            man += ["", "[reference]", 'file = "att.csv"', *clock, 'kind = "truth"',
                    'quaternion = ["qw", "qx", "qy", "qz"]']
        (d / "windahrs.toml").write_text("\n".join(man) + "\n")


def _csv(path: Path, header: list[str], columns: list[F64]) -> None:
    data = np.column_stack(columns)
    with path.open("w") as fh:
        fh.write(",".join(header) + "\n")
        for row in data:
            fh.write(",".join("" if math.isnan(v) else repr(float(v)) for v in row) + "\n")


# ---------------------------------------------------------------------------------------------
# the faults


def _num(v: float) -> str:
    """The shortest text that reads back as exactly ``v``."""
    short = format(v, "g")
    return short if float(short) == v else repr(v)


def _float(owner: str, name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise FaultError(f"{owner}.{name}", "a number", f"{type(value).__name__} {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise FaultError(f"{owner}.{name}", "a finite value", repr(value))
    return v


@dataclass(frozen=True)
class Fault:
    """Base of every fault: active from ``start`` s for ``duration`` s (``span``).

    Subclasses set ``kind`` (the CLI name), ``needs`` (the stream it acts on) and implement
    ``_apply``; their parameters are validated in ``_check``."""

    start: float
    duration: float

    kind: ClassVar[str] = ""
    needs: ClassVar[str] = "imu"
    #: 0: values and removals; 1: time stamps (applied after every value fault).
    stage: ClassVar[int] = 0
    #: A duration of 0 s is allowed (one sample: the spikes).
    instant: ClassVar[bool] = False

    def __post_init__(self) -> None:
        name = type(self).__name__
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.type in ("float", float):
                object.__setattr__(self, f.name, _float(name, f.name, v))
        if self.start < 0:
            raise FaultError(f"{name}.start", "a time >= 0 s", repr(self.start))
        if self.duration < 0 or (self.duration == 0 and not self.instant):
            need = ">= 0 s" if self.instant else "> 0 s"
            raise FaultError(f"{name}.duration", f"a duration {need}", repr(self.duration))
        self._check()

    def _check(self) -> None:
        """Validate the fault's own parameters (FaultError naming the field)."""

    def _bad(self, name: str, expected: str) -> FaultError:
        return FaultError(f"{type(self).__name__}.{name}", expected, repr(getattr(self, name)))

    def _choice(self, name: str, choices: tuple[str, ...]) -> None:
        if getattr(self, name) not in choices:
            raise self._bad(name, f"one of {', '.join(map(repr, choices))}")

    def _vector(self, name: str) -> None:
        v = getattr(self, name)
        try:
            a = np.array(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise self._bad(name, "a vector of 3 numbers") from None
        if a.shape != (3,) or not np.isfinite(a).all():
            raise self._bad(name, "a vector of 3 finite numbers")
        object.__setattr__(self, name, tuple(float(x) for x in a))

    @property
    def span(self) -> tuple[float, float]:
        """(t_start, t_end) s: when the fault is active (the scoring window)."""
        return (self.start, self.start + self.duration)

    def spec(self) -> str:
        """The fault as a CLI spec, ``kind:field=value:...`` (:func:`parse_fault`'s input)."""
        parts = [self.kind]
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            text = ",".join(map(_num, v)) if isinstance(v, tuple) else (_num(v) if isinstance(v, float) else str(v))
            parts.append(f"{f.name}={text}")
        return ":".join(parts)

    def apply(self, raw: RawFlight, rng: np.random.Generator) -> None:
        """Apply the fault to ``raw``'s arrays (in place; :func:`inject` works on a copy)."""
        s = raw.stream(self.needs)
        if s is None:
            raise FaultError(type(self).__name__, f"a flight with a {self.needs} stream", "none")
        t0, t_end = float(raw.flight.imu.t[0]), float(raw.flight.imu.t[-1])
        if not t0 <= self.start <= t_end:
            raise FaultError(
                f"{type(self).__name__}.start", f"a time within the flight ({t0:g} to {t_end:g} s)", repr(self.start)
            )
        self._apply(raw, s, rng)
        raw.applied.append(self.spec())

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        raise NotImplementedError

    def mask(self, t: F64) -> NDArray[np.bool_]:
        """The samples of stamps ``t`` the fault acts on: those in [start, start + duration);
        for a zero duration, the first sample at or after start."""
        if self.duration == 0:
            m = np.zeros(len(t), dtype=bool)
            i = int(np.searchsorted(t, self.start))
            if i < len(t):
                m[i] = True
            return m
        return (t >= self.start) & (t < self.start + self.duration)


def _remove(s: dict[str, F64], keep: NDArray[np.bool_]) -> None:
    for k in s:
        s[k] = s[k][keep]


def _sensors(sensor: str) -> tuple[str, ...]:
    return {"gyro": ("w_b",), "accel": ("f_b",), "both": ("w_b", "f_b")}[sensor]


_SENSORS = ("gyro", "accel", "both")


@dataclass(frozen=True)
class ImuDropout(Fault):
    """The IMU delivers nothing for the span: its samples are removed (a gap)."""

    kind: ClassVar[str] = "imu-dropout"

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        _remove(s, ~self.mask(s["t"]))


@dataclass(frozen=True)
class ImuNaN(Fault):
    """IMU samples become NaN (a missing sample) or Inf (``value="inf"``, which a Flight
    refuses: edge repair). sensor: "gyro", "accel" or "both"; fraction: the share of the
    span's samples hit, chosen at random (1: all)."""

    sensor: str = "both"
    value: str = "nan"
    fraction: float = 1.0
    kind: ClassVar[str] = "imu-nan"

    def _check(self) -> None:
        self._choice("sensor", _SENSORS)
        self._choice("value", ("nan", "inf"))
        if not 0 < self.fraction <= 1:
            raise self._bad("fraction", "a share in (0, 1]")

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        idx = np.flatnonzero(self.mask(s["t"]))
        if self.fraction < 1:
            idx = np.sort(rng.choice(idx, size=max(1, round(self.fraction * len(idx))), replace=False))
        for k in _sensors(self.sensor):
            s[k][idx] = np.nan if self.value == "nan" else np.inf


@dataclass(frozen=True)
class _Spike(Fault):
    duration: float = 0.0
    magnitude: float = 0.0
    axis: int = 0
    key: ClassVar[str] = ""
    instant: ClassVar[bool] = True

    def _check(self) -> None:
        if self.axis not in (0, 1, 2) or isinstance(self.axis, bool):
            raise self._bad("axis", "0, 1 or 2 (body x, y, z)")
        if self.magnitude == 0:
            raise self._bad("magnitude", "a non-zero spike")

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        s[self.key][self.mask(s["t"]), self.axis] += self.magnitude


@dataclass(frozen=True)
class GyroSpike(_Spike):
    """``magnitude`` rad/s added to the gyro's ``axis`` on the samples of the span (duration
    0: one sample), as an electrical glitch does. Above 50 rad/s a Flight refuses the
    stream as deg/s (edge repair)."""

    magnitude: float = 40.0
    kind: ClassVar[str] = "gyro-spike"
    key: ClassVar[str] = "w_b"


@dataclass(frozen=True)
class AccelSpike(_Spike):
    """``magnitude`` m/s^2 added to the accelerometer's ``axis`` on the samples of the span
    (duration 0: one sample)."""

    magnitude: float = 150.0
    axis: int = 2
    kind: ClassVar[str] = "accel-spike"
    key: ClassVar[str] = "f_b"


@dataclass(frozen=True)
class ImuStuck(Fault):
    """The IMU repeats its last sample before the span for the whole span (a hung bus that
    the driver does not notice). sensor: "gyro", "accel" or "both"."""

    sensor: str = "both"
    kind: ClassVar[str] = "imu-stuck"

    def _check(self) -> None:
        self._choice("sensor", _SENSORS)

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        _hold(s, self.mask(s["t"]), _sensors(self.sensor))


def _hold(s: dict[str, F64], m: NDArray[np.bool_], keys: Sequence[str]) -> None:
    """Rows in ``m`` take the last value before the first of them (the first row's own if none)."""
    idx = np.flatnonzero(m)
    if len(idx) == 0:
        return
    src = max(int(idx[0]) - 1, 0)
    for k in keys:
        s[k][idx] = s[k][src]


@dataclass(frozen=True)
class _Clipping(Fault):
    """Each axis of an IMU column (``_column``: "w_b" or "f_b") clipped to +-``limit``
    (in ``_unit``), the field each subclass declares with its default."""

    _column: ClassVar[str] = ""
    _unit: ClassVar[str] = ""

    def _check(self) -> None:
        if self.limit <= 0:  # type: ignore[attr-defined]
            raise self._bad("limit", f"a range > 0 {self._unit}")

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        m = self.mask(s["t"])
        lim = self.limit  # type: ignore[attr-defined]
        s[self._column][m] = np.clip(s[self._column][m], -lim, lim)


@dataclass(frozen=True)
class GyroSaturation(_Clipping):
    """Each gyro axis clipped to +-``limit`` rad/s (default the MPU-9150's smallest range,
    250 deg/s): motion beyond the configured range reads as the range."""

    limit: float = MPU9150_GYRO_MIN_RANGE
    kind: ClassVar[str] = "gyro-saturation"
    _column: ClassVar[str] = "w_b"
    _unit: ClassVar[str] = "rad/s"


@dataclass(frozen=True)
class AccelSaturation(_Clipping):
    """Each accelerometer axis clipped to +-``limit`` m/s^2 (default the MPU-9150's smallest
    range, 2 g). With vibration (:class:`VibrationBurst`) the clipping rectifies: the mean
    specific force is biased, the classic vibration failure of multirotors."""

    limit: float = MPU9150_ACCEL_MIN_RANGE
    kind: ClassVar[str] = "accel-saturation"
    _column: ClassVar[str] = "f_b"
    _unit: ClassVar[str] = "m/s^2"


@dataclass(frozen=True)
class VibrationBurst(Fault):
    """A sinusoidal vibration of ``frequency`` Hz on every axis (random phase per axis),
    ``accel_amplitude`` m/s^2 and ``gyro_amplitude`` rad/s peak, sampled at the IMU's stamps
    (a frequency above half the IMU rate aliases, as in a sensor without an anti-alias
    filter). Defaults: 3 g and 0.5 rad/s at 80 Hz, a loose or unbalanced propeller: 3 g peak is
    21 m/s^2 RMS, near the 30 m/s^2 beyond which ArduPilot's "Measuring Vibration" page says
    its VIBE levels may give problems (above 60 m/s^2 nearly always)."""

    accel_amplitude: float = 3.0 * G0
    gyro_amplitude: float = 0.5
    frequency: float = 80.0
    kind: ClassVar[str] = "vibration"

    def _check(self) -> None:
        for name in ("accel_amplitude", "gyro_amplitude"):
            if getattr(self, name) < 0:
                raise self._bad(name, "an amplitude >= 0")
        if self.frequency <= 0:
            raise self._bad("frequency", "a frequency > 0 Hz")

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        m = self.mask(s["t"])
        t = s["t"][m]
        for key, amp in (("f_b", self.accel_amplitude), ("w_b", self.gyro_amplitude)):
            phase = rng.uniform(0.0, 2.0 * np.pi, 3)
            s[key][m] += amp * np.sin(2.0 * np.pi * self.frequency * t[:, None] + phase)


@dataclass(frozen=True)
class MagMagnet(Fault):
    """A magnet or current near the compass: ``offset_b`` tesla (body axes) added to the
    field for the span (default +50 uT on body x, about the Earth's whole field)."""

    offset_b: tuple[float, float, float] = (50e-6, 0.0, 0.0)
    kind: ClassVar[str] = "mag-magnet"
    needs: ClassVar[str] = "mag"

    def _check(self) -> None:
        self._vector("offset_b")

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        s["mag_b"][self.mask(s["t"])] += np.asarray(self.offset_b)


@dataclass(frozen=True)
class MagDrift(Fault):
    """A slowly varying disturbance (a motor current that changes with throttle, a ferrous
    payload swinging): ``amplitude * (1 - cos(2 pi (t - start) / period)) / 2`` tesla along
    body ``direction`` for the span, rising smoothly from zero (default 20 uT, period 30 s)."""

    amplitude: float = 20e-6
    period: float = 30.0
    direction: tuple[float, float, float] = (0.0, 1.0, 0.0)
    kind: ClassVar[str] = "mag-drift"
    needs: ClassVar[str] = "mag"

    def _check(self) -> None:
        if self.period <= 0:
            raise self._bad("period", "a period > 0 s")
        self._vector("direction")
        if np.linalg.norm(self.direction) == 0:
            raise self._bad("direction", "a non-zero vector")

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        m = self.mask(s["t"])
        u = np.asarray(self.direction) / np.linalg.norm(self.direction)
        size = self.amplitude * 0.5 * (1.0 - np.cos(2.0 * np.pi * (s["t"][m] - self.start) / self.period))
        s["mag_b"][m] += size[:, None] * u


@dataclass(frozen=True)
class MagAbsent(Fault):
    """No magnetometer for the span: its samples are removed (a span from 0 s: a
    magnetometer that starts late)."""

    kind: ClassVar[str] = "mag-absent"
    needs: ClassVar[str] = "mag"

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        _remove(s, ~self.mask(s["t"]))


@dataclass(frozen=True)
class PitotBlockage(Fault):
    """A blocked or iced pitot. mode "freeze": the airspeed holds its last value before the
    span (ram port and drain blocked, level flight); "zero": it drops to 0 (ram port blocked,
    drain open: the pressure leaks away); "ramp": it changes by ``rate`` m/s per s from its
    last value (both blocked, the trapped pressure read against a changing static pressure:
    about 1 m/s per s at 15 m/s in a 1.5 m/s climb, ``dV = rho g dh / (rho V)``)."""

    mode: str = "freeze"
    rate: float = 1.0
    kind: ClassVar[str] = "pitot"
    needs: ClassVar[str] = "air"

    def _check(self) -> None:
        self._choice("mode", ("freeze", "zero", "ramp"))

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        m = self.mask(s["t"])
        if self.mode == "zero":
            s["tas"][m] = 0.0
            return
        _hold(s, m, ("tas",))
        if self.mode == "ramp":
            s["tas"][m] = np.maximum(s["tas"][m] + self.rate * (s["t"][m] - self.start), 0.0)


@dataclass(frozen=True)
class PitotScale(Fault):
    """A pitot whose airspeed is off by a constant factor: the reading is ``scale`` times
    the true airspeed (a port in the propeller's or the fuselage's flow, a bent tube, a
    transducer calibrated for another installation; PX4 estimates the inverse as ASPD_SCALE,
    ArduPilot calibrates ARSPD_RATIO). scale: > 0 (0.75: the pitot reads 25 % low)."""

    scale: float = 0.75
    kind: ClassVar[str] = "pitot-scale"
    needs: ClassVar[str] = "air"

    def _check(self) -> None:
        if not (0.0 < self.scale <= 10.0):
            raise self._bad("scale", "a factor in (0, 10]")

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        m = self.mask(s["t"])
        s["tas"][m] = self.scale * s["tas"][m]


@dataclass(frozen=True)
class VaneFailure(Fault):
    """A vane fails. vane: "aoa", "sideslip" or "both"; mode "stuck": it holds its last angle
    before the span, "nan": it reads nothing (NaN angle; the airspeed stays)."""

    vane: str = "both"
    mode: str = "stuck"
    kind: ClassVar[str] = "vane"
    needs: ClassVar[str] = "air"

    def _check(self) -> None:
        self._choice("vane", ("aoa", "sideslip", "both"))
        self._choice("mode", ("stuck", "nan"))

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        keys = ("aoa", "sideslip") if self.vane == "both" else (self.vane,)
        if any(k not in s or not np.isfinite(s[k]).any() for k in keys):
            raise FaultError("VaneFailure.vane", "a flight with that vane", f"no {self.vane} vane")
        m = self.mask(s["t"])
        if self.mode == "nan":
            for k in keys:
                s[k][m] = np.nan
        else:
            _hold(s, m, keys)


@dataclass(frozen=True)
class GnssOutage(Fault):
    """No GNSS velocity for the span: its samples are removed."""

    kind: ClassVar[str] = "gnss-outage"
    needs: ClassVar[str] = "gnss"

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        _remove(s, ~self.mask(s["t"]))


@dataclass(frozen=True)
class GnssJump(Fault):
    """GNSS velocity off by ``jump_n`` m/s (NED) for the span (a multipath or a
    constellation switch; default 5 m/s north)."""

    jump_n: tuple[float, float, float] = (5.0, 0.0, 0.0)
    kind: ClassVar[str] = "gnss-jump"
    needs: ClassVar[str] = "gnss"

    def _check(self) -> None:
        self._vector("jump_n")

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        s["v_n"][self.mask(s["t"])] += np.asarray(self.jump_n)


@dataclass(frozen=True)
class ImuJitter(Fault):
    """The IMU's stamps (not its data) off by Gaussian noise of ``sigma`` s for the span (a
    logger stamping on receipt; default 0.5 ms, a tenth of a 200 Hz period). A sigma
    comparable with the period puts stamps out of order: edge repair."""

    sigma: float = 0.5e-3
    kind: ClassVar[str] = "imu-jitter"
    stage: ClassVar[int] = 1

    def _check(self) -> None:
        if self.sigma <= 0:
            raise self._bad("sigma", "a standard deviation > 0 s")

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        m = self.mask(s["t"])
        s["t"][m] += rng.normal(0.0, self.sigma, int(m.sum()))


def _count_check(fault: Fault) -> None:
    c = fault.count  # type: ignore[attr-defined]
    if isinstance(c, bool) or not isinstance(c, int) or c < 1:
        raise fault._bad("count", "an integer >= 1")
    fault._choice("stream", ("imu", "mag", "gnss", "air"))


def _pick(fault: Fault, m: NDArray[np.bool_], count: int, rng: np.random.Generator, room: int) -> NDArray[np.int64]:
    idx = np.flatnonzero(m)
    idx = idx[idx + room < len(m)] if room else idx
    if len(idx) < count:
        raise FaultError(f"{type(fault).__name__}.count", f"at most {len(idx)} (the samples in the span)", str(count))
    return np.sort(rng.choice(idx, size=count, replace=False))


@dataclass(frozen=True)
class DuplicateStamps(Fault):
    """``count`` samples of ``stream`` in the span written twice (the same stamp and values
    in two rows, as a logger that retries a write). A Flight refuses it: edge repair."""

    count: int = 1
    stream: str = "imu"
    kind: ClassVar[str] = "duplicate-stamps"
    stage: ClassVar[int] = 1

    def _check(self) -> None:
        _count_check(self)

    @property
    def needs(self) -> str:  # type: ignore[override]
        return self.stream

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        idx = _pick(self, self.mask(s["t"]), self.count, rng, 0)
        order = np.sort(np.concatenate([np.arange(len(s["t"])), idx]))
        for k in s:
            s[k] = s[k][order]


@dataclass(frozen=True)
class OutOfOrder(Fault):
    """``count`` pairs of neighbouring samples of ``stream`` in the span swapped (stamps and
    values travel together: rows written out of order). A Flight refuses it: edge repair."""

    count: int = 1
    stream: str = "imu"
    kind: ClassVar[str] = "out-of-order"
    stage: ClassVar[int] = 1

    def _check(self) -> None:
        _count_check(self)

    @property
    def needs(self) -> str:  # type: ignore[override]
        return self.stream

    def _apply(self, raw: RawFlight, s: dict[str, F64], rng: np.random.Generator) -> None:
        m = self.mask(s["t"])
        idx = np.flatnonzero(m)[::2]  # pairs that do not overlap
        idx = idx[idx + 1 < len(m)]
        if len(idx) < self.count:
            raise FaultError("OutOfOrder.count", f"at most {len(idx)} (pairs in the span)", str(self.count))
        idx = np.sort(rng.choice(idx, size=self.count, replace=False))
        order = np.arange(len(m))
        order[idx], order[idx + 1] = idx + 1, idx
        for k in s:
            s[k] = s[k][order]


#: kind -> fault class, every fault of the catalogue.
FAULTS: dict[str, type[Fault]] = {
    c.kind: c
    for c in (
        ImuDropout, ImuNaN, GyroSpike, AccelSpike, ImuStuck, GyroSaturation, AccelSaturation, VibrationBurst,
        MagMagnet, MagDrift, MagAbsent, PitotBlockage, PitotScale, VaneFailure, GnssOutage, GnssJump,
        ImuJitter, DuplicateStamps, OutOfOrder,
    )
}


# ---------------------------------------------------------------------------------------------
# applying them


def _rng(seed: int | None, rng: np.random.Generator | None) -> np.random.Generator:
    if (seed is None) == (rng is None):
        found = "both" if seed is not None else "neither"
        raise FaultError("seed, rng", "one of an integer seed or a numpy Generator", found)
    if seed is not None:
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise FaultError("seed", "an integer >= 0", repr(seed))
        return np.random.default_rng(seed)
    assert rng is not None
    return rng


def inject_raw(
    flight: Flight, faults: Sequence[Fault], *, seed: int | None = None, rng: np.random.Generator | None = None
) -> RawFlight:
    """``flight``'s streams with ``faults`` applied, as arrays (:class:`RawFlight`); the
    flight is not changed. Value faults are applied first, in order, then the time-stamp
    faults; fault i draws from the i-th child of the generator (``seed`` or ``rng``, one
    of them), so a fault's draws do not depend on the others."""
    gen = _rng(seed, rng)
    for i, f in enumerate(faults):
        if not isinstance(f, Fault):
            raise FaultError(f"faults[{i}]", "a Fault (windahrs.sim.faults)", type(f).__name__)
    children = gen.spawn(len(faults))
    raw = RawFlight.of(flight)
    for i in sorted(range(len(faults)), key=lambda k: faults[k].stage):
        faults[i].apply(raw, children[i])
    return raw


def inject(
    flight: Flight, faults: Sequence[Fault], *, seed: int | None = None, rng: np.random.Generator | None = None
) -> Flight:
    """``flight`` with ``faults`` applied to its sensor streams (truth, site untouched;
    ``meta["faults"]`` lists them as specs). See :func:`inject_raw`; raises
    :class:`FaultError` when the result is not a valid Flight (duplicated or unordered
    stamps, Inf: use :func:`inject_raw` and :meth:`RawFlight.write_csv_dir`)."""
    return inject_raw(flight, faults, seed=seed, rng=rng).to_flight()


def _parse_value(kind: str, name: str, text: str, typ: Any) -> Any:
    where = f"{FAULTS[kind].__name__}.{name}"
    try:
        if typ in ("float", float):
            return float(text)
        if typ in ("int", int):
            return int(text)
        if "tuple" in str(typ):
            return tuple(float(x) for x in text.split(","))
    except ValueError:
        raise FaultError(where, f"a {'vector of numbers' if 'tuple' in str(typ) else str(typ)}", repr(text)) from None
    return text


def parse_fault(spec: str) -> Fault:
    """A fault from ``kind:field=value:...``, e.g. ``gyro-spike:start=30:magnitude=40`` or
    ``mag-magnet:start=20:duration=10:offset_b=0,50e-6,0`` (vectors comma-separated).
    FaultError names an unknown kind or field, or a bad value."""
    kind, *assignments = spec.strip().split(":")
    if kind not in FAULTS:
        raise FaultError("fault", f"one of {', '.join(FAULTS)}", repr(kind))
    cls = FAULTS[kind]
    types = {f.name: f.type for f in dataclasses.fields(cls)}
    kw: dict[str, Any] = {}
    for a in assignments:
        key, sep, val = a.partition("=")
        key = key.strip()
        if not sep or not key:
            raise FaultError(f"fault {spec!r}", "kind:field=value:...", repr(a))
        if key not in types:
            raise FaultError(f"{cls.__name__}.{key}", f"one of the fields {', '.join(types)}", "an unknown field")
        kw[key] = _parse_value(kind, key, val.strip(), types[key])
    missing = [n for n, f in ((f.name, f) for f in dataclasses.fields(cls))
               if f.default is dataclasses.MISSING and n not in kw]
    if missing:
        raise FaultError(f"{cls.__name__}.{missing[0]}", "a value (kind:field=value)", "none")
    return cls(**kw)
