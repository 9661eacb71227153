"""What every estimator shares: the streaming interface, the batch driver that replays
a Flight through it in time order, initial states, and the errors for missing sensors.

An estimator is built from frozen parameters and turns a Flight into an Estimate with
:meth:`Estimator.run`. The same estimator also runs sample by sample through a
:class:`Streamer` (as it would on a companion computer fed live from an autopilot); a run
fed sample by sample equals the batch run, because ``run`` is that replay (or, for the
compiled filters, the same compiled step functions called from a compiled loop).

Event order: samples are processed in time order; at equal times the IMU sample comes
first (propagation to ``t``), then magnetometer, GNSS and air data. The state recorded
for IMU sample ``k`` is the state after every sample with ``t <= t_imu[k]`` and before the
next IMU sample.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from abc import ABC, abstractmethod
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from numba import njit
from numpy.typing import NDArray

from windahrs.core import pool
from windahrs.core.layout import _JIT
from windahrs.estimate import Estimate, Innovations
from windahrs.flight import Flight, Site
from windahrs.rotation import dcm_from_quat, quat_from_euler

__all__ = [
    "COV_RECORDS",
    "EVENT_AIR",
    "EVENT_GNSS",
    "EVENT_IMU",
    "EVENT_MAG",
    "CovRecord",
    "Estimator",
    "EventStreamer",
    "InitialState",
    "MissingSensorError",
    "StateView",
    "Streamer",
    "loop_family",
    "merge_events",
    "triad",
]

F64 = NDArray[np.float64]

EVENT_IMU, EVENT_MAG, EVENT_GNSS, EVENT_AIR = 0, 1, 2, 3

#: What :meth:`Estimator.run_batch` keeps of the covariance: "full" (as ``run``),
#: "attitude" (the attitude's 3 x 3 block and its labels: enough for the attitude's NEES,
#: and a fraction of the memory and time of an INS's 18 x 18) or "none" (``cov`` None).
CovRecord = Literal["full", "attitude", "none"]
COV_RECORDS: tuple[CovRecord, ...] = ("full", "attitude", "none")
SENSOR_NAMES = {"imu": "the IMU", "mag": "a magnetometer", "gnss": "GNSS velocity", "air": "air data"}


class MissingSensorError(ValueError):
    """The flight lacks a sensor the filter needs."""

    def __init__(self, filter_name: str, sensor: str, detail: str = "", *, what: str | None = None) -> None:
        """what: what the filter needs of the stream, when the stream alone does not say it
        (default: the stream's name, e.g. "air data")."""
        self.filter = filter_name
        self.sensor = sensor
        what = SENSOR_NAMES.get(sensor, sensor) if what is None else what
        super().__init__(
            f"filter {filter_name!r} needs {what} ({sensor!r}), which the flight does not have{detail}"
        )


@dataclass(frozen=True)
class InitialState:
    """A known initial state (e.g. the truth of a simulation). q_nb (4,); the rest (3,)
    or None (estimated from the data / zero). sigma_att rad, sigma_bias rad/s,
    sigma_v m/s, sigma_wind m/s: initial standard deviations per axis (None: the
    filter's own defaults)."""

    q_nb: F64
    gyro_bias_b: F64 | None = None
    v_n: F64 | None = None
    wind_n: F64 | None = None
    sigma_att: float | None = None
    sigma_bias: float | None = None
    sigma_v: float | None = None
    sigma_wind: float | None = None

    @classmethod
    def from_truth(
        cls, flight: Flight, *, sigma_att: float | None = None, **sigmas: float | None
    ) -> InitialState:
        """The truth at the first IMU sample (raises ValueError without truth)."""
        tr = flight.truth
        if tr is None:
            raise ValueError("initial: the flight has no truth to start from")
        k = int(np.searchsorted(tr.t, flight.imu.t[0]))

        def at(a: F64 | None) -> F64 | None:
            return None if a is None else a[k].copy()

        return cls(
            q_nb=tr.q_nb[k].copy(),
            gyro_bias_b=at(tr.gyro_bias_b),
            v_n=at(tr.v_n),
            wind_n=at(tr.wind_n),
            sigma_att=sigma_att,
            **sigmas,
        )


@dataclass(frozen=True)
class StateView:
    """The current estimate of a streamer: t s, q_nb (4,), gyro_bias_b (3,), v_n and
    wind_n (3,) or None, cov (n, n) error-state covariance labelled by state_labels."""

    t: float
    q_nb: F64
    gyro_bias_b: F64 | None
    v_n: F64 | None
    wind_n: F64 | None
    cov: F64 | None
    state_labels: tuple[str, ...]


def triad(f_b: F64, mag_b: F64 | None, mag_n: F64 | None) -> F64:
    """Attitude q_nb from one specific-force sample and (optionally) one magnetometer sample.

    Roll and pitch come from ``f_b`` (assumed to be gravity only: ``f_b = -C_bn g_n``); yaw
    from the horizontal magnetic field compared with ``mag_n`` (its declination), or 0 when
    there is no magnetometer sample.
    """
    # A resting accelerometer reads f_b = -C_bn g_n = C_bn (up), so f/|f| is "up" in the body.
    up_b = np.asarray(f_b, dtype=np.float64)
    up_b = up_b / np.linalg.norm(up_b)
    roll = np.arctan2(-up_b[1], -up_b[2])
    pitch = np.arcsin(np.clip(up_b[0], -1.0, 1.0))
    q_level = quat_from_euler([roll, pitch, 0.0])
    if mag_b is None or not np.isfinite(mag_b).all():
        return q_level
    m_level = dcm_from_quat(q_level) @ np.asarray(mag_b, dtype=np.float64)
    yaw_meas = -np.arctan2(m_level[1], m_level[0])
    decl = 0.0 if mag_n is None else float(np.arctan2(mag_n[1], mag_n[0]))
    return quat_from_euler([roll, pitch, yaw_meas + decl])


class Streamer(ABC):
    """A running estimator fed one timestamped sample at a time, in time order.

    Feed any stream in any interleaving, as long as time does not go backwards. NaN
    samples are skipped and counted in ``skipped``. ``state`` gives the current estimate.
    """

    def __init__(self, filter_name: str) -> None:
        self.filter_name = filter_name
        self.skipped: dict[str, int] = {"imu": 0, "mag": 0, "gnss": 0, "air": 0}
        self._inn: dict[str, list[tuple[float, F64, float, bool]]] = {}
        self._t_last = -np.inf

    def _clock(self, t: float, name: str) -> None:
        if t < self._t_last:
            raise ValueError(
                f"{name}.t: expected time not before the last sample ({self._t_last!r}), found {t!r}"
            )
        self._t_last = t

    def _log(self, sensor: str, t: float, nu: F64, nis: float, accepted: bool) -> None:
        self._inn.setdefault(sensor, []).append((t, np.array(nu, dtype=np.float64, ndmin=1), nis, accepted))

    def innovations(self) -> dict[str, Innovations]:
        """Innovations logged so far, per sensor."""
        out = {}
        for k, rows in self._inn.items():
            out[k] = Innovations(
                t=np.array([r[0] for r in rows]),
                nu=np.stack([r[1] for r in rows]),
                nis=np.array([r[2] for r in rows]),
                accepted=np.array([r[3] for r in rows], dtype=bool),
            )
        return out

    def push(self, kind: int, t: float, values: F64) -> None:
        """Dispatch one sample; ``values`` as in the Flight stream (IMU: [w_b, f_b] (6,);
        mag: (3,); GNSS: v_n (3,), or [v_n, v_sigma] (4,) and more, as :func:`merge_events`
        rows; air: [tas, aoa, sideslip] (3,), NaN angles without vanes)."""
        if kind == EVENT_IMU:
            self.imu(t, values[:3], values[3:6])
        elif kind == EVENT_MAG:
            self.mag(t, values[:3])
        elif kind == EVENT_GNSS:
            self.gnss(t, values[:3], float(values[3]) if len(values) > 3 else np.nan)
        elif kind == EVENT_AIR:
            self.air(t, float(values[0]), float(values[1]), float(values[2]))
        else:
            raise ValueError(f"kind: expected 0 (imu), 1 (mag), 2 (gnss) or 3 (air), found {kind!r}")

    def imu(self, t: float, w_b: F64, f_b: F64) -> None:
        """Gyro (rad/s) and specific force (m/s^2) sample at t (s)."""
        self._clock(t, "imu")
        if not (np.isfinite(w_b).all() and np.isfinite(f_b).all()):
            self.skipped["imu"] += 1
            return
        self._imu(t, np.asarray(w_b, dtype=np.float64), np.asarray(f_b, dtype=np.float64))

    def mag(self, t: float, mag_b: F64) -> None:
        """Magnetometer sample (tesla, body) at t."""
        self._clock(t, "mag")
        if not np.isfinite(mag_b).all():
            self.skipped["mag"] += 1
            return
        self._mag(t, np.asarray(mag_b, dtype=np.float64))

    def gnss(self, t: float, v_n: F64, v_sigma: float = np.nan) -> None:
        """GNSS velocity sample (m/s, NED) at t, with the receiver's speed accuracy v_sigma
        (m/s, 1 sigma; NaN: not given; :class:`~windahrs.flight.GnssStream`)."""
        if not (math.isnan(v_sigma) or 0.0 <= v_sigma < math.inf):
            raise ValueError(f"v_sigma: expected a speed accuracy >= 0 m/s (NaN: not given), found {v_sigma!r}")
        self._clock(t, "gnss")
        if not np.isfinite(v_n).all():
            self.skipped["gnss"] += 1
            return
        self._gnss(t, np.asarray(v_n, dtype=np.float64), float(v_sigma))

    def air(self, t: float, tas: float, aoa: float = np.nan, sideslip: float = np.nan) -> None:
        """Air-data sample: true airspeed m/s, angle of attack and sideslip rad (NaN: no vanes)."""
        self._clock(t, "air")
        if not np.isfinite(tas):
            self.skipped["air"] += 1
            return
        self._air(t, float(tas), float(aoa), float(sideslip))

    @abstractmethod
    def _imu(self, t: float, w_b: F64, f_b: F64) -> None: ...

    def _mag(self, t: float, mag_b: F64) -> None:
        """Default: the filter does not use the magnetometer."""

    def _gnss(self, t: float, v_n: F64, v_sigma: float) -> None:
        """Default: the filter does not use GNSS velocity."""

    def _air(self, t: float, tas: float, aoa: float, sideslip: float) -> None:
        """Default: the filter does not use air data."""

    @property
    @abstractmethod
    def state(self) -> StateView: ...

    def snapshot(self) -> Streamer:
        """A deep copy of this streamer's whole state (filter state, covariance, logged
        innovations, skip counts, clock), independent of it: feeding either leaves the
        other unchanged. :meth:`restore` it to go back; restore-then-continue equals the
        uninterrupted run bit for bit. Raises TypeError when the streamer holds a library
        object that cannot be copied (imufusion's)."""
        try:
            return copy.deepcopy(self)
        except TypeError as exc:
            raise TypeError(
                f"snapshot: the {self.filter_name} streamer holds state that cannot be copied ({exc})"
            ) from None

    def restore(self, snapshot: Streamer) -> None:
        """Return to the state of ``snapshot`` (from :meth:`snapshot` of a streamer of the
        same type); the snapshot is copied, so it can be restored again."""
        if type(snapshot) is not type(self):
            raise ValueError(
                f"snapshot: expected a snapshot of a {type(self).__name__}, found {type(snapshot).__name__}"
            )
        clone = copy.deepcopy(snapshot)  # through the type's own __deepcopy__, when it has one
        self.__dict__.clear()
        self.__dict__.update(clone.__dict__)


class EventStreamer(Streamer):
    """A streamer over a compiled event loop: each sample becomes one event row (as
    :func:`merge_events` lays them out) handed to :meth:`_step`, the batch run's own loop
    called on a single event, so a flight streamed equals its batch run bit for bit."""

    def __init__(self, filter_name: str) -> None:
        super().__init__(filter_name)
        self._t = np.zeros(1)
        self._kind = np.zeros(1, dtype=np.int64)
        self._row = np.full((1, 6), np.nan)

    @abstractmethod
    def _step(self, kind: int, t: float) -> None:
        """Run the compiled loop on the event in ``_row`` of ``kind`` (EVENT_*) at t s."""

    def _event(self, kind: int, t: float) -> None:
        self._t[0] = t
        self._kind[0] = kind
        self._step(kind, t)

    def _imu(self, t: float, w_b: F64, f_b: F64) -> None:
        self._row[0, :3] = w_b
        self._row[0, 3:6] = f_b
        self._event(EVENT_IMU, t)

    def _mag(self, t: float, mag_b: F64) -> None:
        self._row[0, :3] = mag_b
        self._event(EVENT_MAG, t)

    def _gnss(self, t: float, v_n: F64, v_sigma: float) -> None:
        self._row[0, :3] = v_n
        self._row[0, 3:6] = (v_sigma, np.nan, np.nan)  # (as merge_events lays a GNSS row out)
        self._event(EVENT_GNSS, t)

    def _air(self, t: float, tas: float, aoa: float, sideslip: float) -> None:
        self._row[0, :3] = (tas, aoa, sideslip)
        self._event(EVENT_AIR, t)


def merge_events(flight: Flight, use: frozenset[str]) -> tuple[F64, NDArray[np.int64], F64]:
    """All samples of the streams in ``use`` in processing order.

    Returns times (E,), kinds (E,) (EVENT_* codes) and values (E, 6) (IMU: w_b, f_b;
    mag: 3 values then NaN; GNSS: v_n, the receiver's speed accuracy (NaN when not given),
    then NaN; air: tas, aoa, sideslip then NaN), in memory reused
    from dropped events (:mod:`windahrs.core.pool`: a run drops its events when it ends,
    and the next run's take no page faults).
    """
    streams = event_streams(flight, use)
    n = sum(len(streams[k]) for k in (0, 3, 5, 7))  # (the times)
    t, kinds, vals = pool.empty((n,)), pool.empty((n,), np.int64), pool.empty((n, 6))
    merge_into(*streams, t, kinds, vals)
    return t, kinds, vals


def stream_counts(flight: Flight, use: frozenset[str]) -> dict[str, int]:
    """How many events of each stream :func:`merge_events` lays out for ``use``: every sample of
    a stream in it (the streams' lengths: a count of the merged kinds took 30 us a minute of a
    200 Hz flight), 0 for the others; keys "imu", "mag", "gnss", "air"."""
    return {s: len(getattr(flight, s).t) if s in use and getattr(flight, s) is not None else 0
            for s in ("imu", "mag", "gnss", "air")}


def event_streams(flight: Flight, use: frozenset[str]) -> tuple[F64, ...]:
    """The arguments of :func:`merge_into` before its outputs: the flight's streams in
    ``use`` as contiguous float64 arrays, (0,) and (0, 3) for a stream left out; the GNSS as
    (n, 4) columns v_n, v_sigma (NaN when the stream has none); the air data as (n, 3)
    columns tas, aoa, sideslip (NaN for vanes it lacks)."""

    def arr(a: object) -> F64:
        return np.ascontiguousarray(a, dtype=np.float64)

    none1, none3 = np.empty(0), np.empty((0, 3))
    mag, gnss, air = (none1, none3), (none1, none3), (none1, none3)
    if "mag" in use and flight.mag is not None:
        mag = (arr(flight.mag.t), arr(flight.mag.mag_b))
    if "gnss" in use and flight.gnss is not None:
        g = flight.gnss
        sigma = np.full(len(g.t), np.nan) if g.v_sigma is None else g.v_sigma
        gnss = (arr(g.t), arr(np.column_stack([g.v_n, sigma])))
    if "air" in use and flight.air is not None:
        a, nan = flight.air, np.full(len(flight.air.t), np.nan)
        vanes = (nan if a.aoa is None else a.aoa, nan if a.sideslip is None else a.sideslip)
        air = (arr(a.t), np.column_stack([a.tas, *vanes]))
    return (arr(flight.imu.t), arr(flight.imu.w_b), arr(flight.imu.f_b), *mag, *gnss, *air)


@njit(nogil=True, **_JIT)
def merge_into(t_imu, w_b, f_b, t_mag, mag_b, t_gnss, v_n, t_air, air, t, kinds, vals):
    """Merge the streams (:func:`event_streams`) into t (E,), kinds (E,) and vals (E, 6)
    (E: all their samples), by time, and at equal times in the kinds' order (EVENT_IMU
    first): each stream's time is strictly increasing (windahrs.flight), so taking the
    earliest next sample of the four, the lowest kind at a tie, is that order. A row takes
    its stream's columns, NaN after them."""
    times = (t_imu, t_mag, t_gnss, t_air)
    nxt = np.zeros(4, dtype=np.int64)
    for e in range(t.shape[0]):
        k = -1
        for s in range(4):
            if nxt[s] < times[s].shape[0] and (k < 0 or times[s][nxt[s]] < times[k][nxt[k]]):
                k = s
        i = nxt[k]
        nxt[k] = i + 1
        t[e] = times[k][i]
        kinds[e] = k  # (the EVENT_* codes are the order of times)
        row = vals[e]
        if k == EVENT_IMU:
            for c in range(3):
                row[c], row[3 + c] = w_b[i, c], f_b[i, c]
            continue
        src = mag_b if k == EVENT_MAG else v_n if k == EVENT_GNSS else air
        w = src.shape[1]
        for c in range(6):
            row[c] = src[i, c] if c < w else np.nan


class Estimator(ABC):
    """An attitude estimator. Subclasses set ``name``, ``requires`` (streams without
    which it cannot run), ``uses`` (streams it fuses when present) and implement
    :meth:`streamer`."""

    name: ClassVar[str]
    #: How results are labelled: the registry spec when built with overrides.
    label: str
    requires: ClassVar[frozenset[str]] = frozenset({"imu"})
    uses: ClassVar[frozenset[str]] = frozenset({"imu"})

    def __getattr__(self, attr: str) -> str:
        # ``label`` defaults to the registry name unless an instance sets it.
        if attr == "label":
            return self.name
        raise AttributeError(attr)

    def check(self, flight: Flight) -> None:
        """Raise MissingSensorError naming the filter and the first missing sensor."""
        for sensor in ("imu", "mag", "gnss", "air"):
            if sensor in self.requires and getattr(flight, sensor) is None:
                raise MissingSensorError(self.name, sensor)

    def params_text(self) -> str:
        """The parameters as text (stored with the Estimate)."""
        return repr(getattr(self, "params", ""))

    @abstractmethod
    def streamer(
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> Streamer:
        """A fresh streaming instance. ``has``: the streams that will be fed (lets the filter
        wait for a magnetometer sample before initialising heading; without "mag", the 6-D
        mode)."""

    def stream(
        self, site: Site | None = None, *, initial: InitialState | None = None, has: Iterable[str] | None = None
    ) -> Streamer:
        """A fresh streamer to feed sample by sample (``imu``, ``mag``, ``gnss``, ``air``).

        site: gravity and magnetic field (default :class:`~windahrs.flight.Site`: standard
        gravity, field unknown). initial: a known initial state, or None. has: the streams
        you will feed, from "imu", "mag", "gnss", "air" (default: every stream the filter
        uses, as :meth:`run` on a flight that has them all); the filter waits for a first
        magnetometer (and, for the INS, GNSS) sample before initialising when they are
        announced, so leave out what you will not feed; without "mag" the error-state
        filters that fuse gravity run their 6-D mode (tilt-only gravity updates, the gyro
        bias at rest: docs/core.md).
        """
        known = ("imu", "mag", "gnss", "air")
        streams = frozenset(self.uses if has is None else ({has} if isinstance(has, str) else set(has)))
        unknown = sorted(streams - set(known))
        if unknown:
            raise ValueError(f"has: expected stream names from {known}, found {unknown}")
        return self.streamer(site if site is not None else Site(), initial=initial, has=streams & self.uses)

    def run_batch(
        self,
        flights: Sequence[Flight],
        *,
        initial: Sequence[InitialState | None] | None = None,
        threads: int | None = None,
        cov: CovRecord = "full",
    ) -> list[Estimate]:
        """The Estimates of several flights, as ``[self.run(f, initial=i) for f, i in
        zip(flights, initial)]``. initial: one InitialState (or None) per flight (default
        None for all); cov: the covariance kept (:data:`CovRecord`). The estimators on the
        compiled core (``mekf``, ``mekf-air``, ``ins-wind``, ``ins-drag``, ``ekf7``,
        ``ekf10``) run the flights together on ``threads`` threads and record only the
        covariance kept (:mod:`windahrs.core.batch`); the others run them one after the
        other, ignore ``threads`` and drop what is not kept."""
        if cov not in COV_RECORDS:
            raise ValueError(f"cov: expected one of {', '.join(map(repr, COV_RECORDS))}, found {cov!r}")
        flights = list(flights)
        inits = initial_per_flight(initial, len(flights))
        return [kept_cov(self.run(f, initial=i), cov) for f, i in zip(flights, inits, strict=True)]

    def run(self, flight: Flight, *, initial: InitialState | None = None) -> Estimate:
        """Estimate the whole flight (replays it through :meth:`streamer`)."""
        self.check(flight)
        has = (
            frozenset(s for s in ("imu", "mag", "gnss", "air") if getattr(flight, s) is not None) & self.uses
        )
        t_ev, kinds, vals = merge_events(flight, has)
        s = self.streamer(flight.site, initial=initial, has=has)
        return replay(self, s, flight, t_ev, kinds, vals)


def loop_family(est: Estimator) -> type:
    """The class whose compiled loop ``est`` runs: the additive filters share one
    (AdditiveEstimator), the error-state ones another (CompiledEstimator); an estimator
    derived from Estimator directly is its own. Two estimators of one family compile the
    same numba functions, so a cluster warming its workers' cache compiles each family once,
    on one worker (:func:`windahrs.experiments.cluster.warm_families`, which ``reproduce``
    and ``sweep`` call)."""
    mro = type(est).__mro__
    return mro[mro.index(Estimator) - 1]


def kept_cov(est: Estimate, cov: CovRecord) -> Estimate:
    """``est`` with only the covariance ``cov`` says to keep (:data:`CovRecord`): the
    attitude's block is the dimensions labelled ``att_*``."""
    if cov == "full" or est.cov is None:
        return est
    if cov == "none":
        return dataclasses.replace(est, cov=None, cov_index=None, state_labels=())
    idx = [i for i, lab in enumerate(est.state_labels) if lab.startswith("att_")]
    block = np.ascontiguousarray(est.cov[:, idx][:, :, idx])
    return dataclasses.replace(est, cov=block, state_labels=tuple(est.state_labels[i] for i in idx))


def initial_per_flight(initial: Sequence[InitialState | None] | None, n: int) -> list[InitialState | None]:
    """``run_batch``'s ``initial`` as a list of n entries (None: n times None); ValueError
    when it does not hold one entry per flight."""
    inits: list[InitialState | None] = [None] * n if initial is None else list(initial)
    if len(inits) != n:
        raise ValueError(f"initial: expected one entry per flight ({n}), found {len(inits)}")
    return inits


def replay(
    est: Estimator, s: Streamer, flight: Flight, t_ev: F64, kinds: NDArray[np.int64], vals: F64
) -> Estimate:
    """Feed events to a streamer and record its state at every IMU sample."""
    n = len(flight.imu.t)
    q = np.empty((n, 4))
    rows: dict[str, list[F64]] = {"bg": [], "v": [], "wind": [], "cov": []}
    k = -1
    labels: tuple[str, ...] = ()
    first = True

    def record() -> None:
        nonlocal labels, first
        st = s.state
        q[k] = st.q_nb
        if first:
            labels = st.state_labels
            first = False
        for key, v in (("bg", st.gyro_bias_b), ("v", st.v_n), ("wind", st.wind_n), ("cov", st.cov)):
            if v is not None:
                rows[key].append(v)

    for i in range(len(t_ev)):
        if kinds[i] == EVENT_IMU:
            if k >= 0:
                record()
            k += 1
        s.push(int(kinds[i]), float(t_ev[i]), vals[i])
    record()

    def stack(key: str) -> F64 | None:
        return np.asarray(rows[key]) if len(rows[key]) == n else None

    return Estimate(
        filter=est.label,
        t=flight.imu.t.copy(),
        q_nb=q,
        gyro_bias_b=stack("bg"),
        v_n=stack("v"),
        wind_n=stack("wind"),
        cov=stack("cov"),
        state_labels=labels if stack("cov") is not None else (),
        innovations=s.innovations(),
        skipped=dict(s.skipped),
        params=est.params_text(),
        repairs={k: dict(v) for k, v in flight.repairs.items()},
    )
