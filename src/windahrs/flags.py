"""Per-sample flags: what an estimator rejected, detected, fell back to, reset, or went
without, at each IMU sample of its Estimate.

An Estimate already carries each decision where it was made (the innovations with their
gates' verdicts, the resets, the IMU screen's held samples, the tilt alerts); the flight says
when each sensor was there. :func:`estimate_flags` lays both onto the Estimate's time base as
one bit per reason (:data:`FLAGS`), so that a user or a report can ask, sample by sample,
"what was the estimator doing here, and why": ``Estimate.flags`` (N,) uint32, and
:func:`flag_spans` turns them into time spans with their reasons (the shaded spans of
``windahrs report``).

A sensor is **absent** at a sample when its stream has no finite sample within
:func:`absent_after` of it (five of its own periods, and at least :data:`ABSENT_MIN_S`;
before its first sample and after its last one too). A gated sensor is **rejected** from
a rejected sample until its next logged one. A **disturbance** is a sample the aid source
kept out before its gate: the magnetometer's field failing its norm or dip check (logged
with a NaN innovation), the accelerometer's specific force failing its norm check. The
**fallback** of an estimator that fuses GNSS velocity is its running without it: on air
data when it has them (dead reckoning on the airspeed with the wind held, as PX4 EKF2 does
when GNSS is lost), else on the IMU alone.

The flight's own samples add what no estimator decides: a sensor **stuck** (repeating its
sample exactly for :data:`STUCK_S`), an IMU axis **clipped** (holding one large magnitude), a
magnetic field whose norm is off the reference's by more than :data:`MAG_NORM_SHARE`
(**disturbed**, whatever the estimator's own checks are set to). The edge's repairs
(``Flight.repair_times``, :mod:`windahrs.repair`) mark the IMU sample nearest each repaired
row of any stream: **stamps repaired** (a repeated stamp dropped, a row out of order
sorted), **values repaired** (a row set to NaN: infinite, or beyond the sensor's range).
The slow faults no sample shows (:mod:`windahrs.drift`) are tested on the whole flight
with the estimate's attitude: a magnetometer **drifting** from the field the attitude
predicts in the body, an airspeed **drifting** from what the GNSS velocity along the nose
says (a blocked pitot's ramp).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from windahrs.core.imu_screen import CLIP_F, CLIP_SAMPLES, CLIP_W
from windahrs.core.layout import SENSOR_STREAMS, SENSORS
from windahrs.drift import air_drift, gnss_jump, mag_drift
from windahrs.estimate import Estimate
from windahrs.flight import Flight

__all__ = ["ABSENT_MIN_S", "FLAGS", "Span", "absent_after", "absent_mask", "estimate_flags", "flag_spans", "flag_names"]

F64 = NDArray[np.float64]

#: Flag name -> (bit, what it means in words: the reason a report shows).
FLAGS: dict[str, tuple[int, str]] = {
    "imu_held": (0, "IMU sample not propagated (a spike, or beyond the sensor's range)"),
    "imu_late": (1, "IMU sample propagated one sample late (an impact's ringing, a step)"),
    "accel_rejected": (2, "accelerometer rejected by its gate"),
    "mag_rejected": (3, "magnetometer rejected by its gate"),
    "gnss_rejected": (4, "GNSS velocity rejected by its gate"),
    "air_rejected": (5, "air data (or drag) rejected by its gate"),
    "accel_disturbed": (6, "specific force far from gravity (vehicle accelerating, vibration)"),
    "mag_disturbed": (7, "magnetic field disturbed (norm or dip check)"),
    "reset": (8, "state reset to a sensor its gate had kept out"),
    "tilt_lost": (9, "tilt disagrees with the mean specific force (lost gravity?)"),
    "imu_absent": (10, "no IMU samples (gap)"),
    "mag_absent": (11, "no magnetometer samples"),
    "gnss_absent": (12, "no GNSS velocity samples"),
    "air_absent": (13, "no air data samples"),
    "fallback": (14, "fusing no GNSS velocity: dead reckoning on air data or on the IMU"),
    "not_initialised": (15, "not initialised yet (waiting for its first samples)"),
    "imu_stuck": (16, "gyro or accelerometer repeats its sample exactly (a hung sensor or bus)"),
    "mag_stuck": (17, "magnetometer repeats its sample exactly"),
    "air_stuck": (18, "airspeed or a vane repeats its value exactly (blocked pitot, stuck vane)"),
    "imu_clipped": (19, "an IMU axis held at one value (saturated, or the axis stuck)"),
    "imu_jitter": (20, "IMU sample step more than a quarter period off the median (stamps taken on receipt?)"),
    "stamps_repaired": (21, "a time stamp repaired at the edge: a repeated stamp dropped or a row out of order sorted"),
    "values_repaired": (22, "a sample set to NaN at the edge (infinite, or beyond the sensor's range)"),
    "mag_drift": (23, "magnetic field in the body drifting from what the attitude predicts (slow disturbance)"),
    "air_drift": (24, "airspeed changing unlike the GNSS velocity along the nose (a blocked or drifting pitot)"),
    "bias_large": (25, "gyro-bias estimate beyond 2 deg/s for 3 s (an attitude error absorbed into the bias?)"),
    "gnss_jump": (26, "GNSS velocity changing unlike the IMU's acceleration (a jump, or a wrong attitude)"),
}
#: A sensor repeating its sample exactly for at least this long, s (and STUCK_SAMPLES samples),
#: is stuck: the noise of MEMS inertial and magnetic sensors and of pitot and vane transducers
#: spans several steps of their converters, so a live sensor does not repeat itself for long.
STUCK_S = 0.2
STUCK_SAMPLES = 5
#: An IMU axis holding one magnitude of at least CLIP_MIN_W rad/s or CLIP_MIN_F m/s^2 for
#: CLIP_SAMPLES samples in a row is clipped (core.imu_screen's constants): noise moves a live
#: axis by converter steps at every sample, and only a clipped (or stuck) one holds a large
#: value exactly. An axis holding any one value for STUCK_S (and STUCK_SAMPLES samples) while
#: the rest of the sensor moves is clipped too, at a range set below the motion, or stuck:
#: the reason of STUCK_S, for one axis. On every recording of ../shared/data (BROAD at 286 Hz,
#: PX4, ALFA, ANSFL) the longest such run of one axis is 10 samples, 0.032 s (a BROAD gyro
#: axis at rest).
CLIP_MIN_W = CLIP_W
CLIP_MIN_F = CLIP_F
#: An IMU step further than this share of the median period from it (and not a gap) is
#: jitter: an IMU sampled on its own clock and stamped by its driver keeps its period to
#: microseconds, a logger that stamps samples on receipt does not (ALFA's mavros telemetry:
#: 37 % of its steps are 20 % off). The filters integrate over the stamped steps, so a stamp a
#: quarter period off moves a turning vehicle's attitude by a quarter of a sample's rotation.
JITTER_SHARE = 0.25
#: The magnetometer's field is disturbed when its norm is off the reference's by more than
#: this share (the site's field, else the flight's median norm): VQF's magNormTh, 0.1.
MAG_NORM_SHARE = 0.1

#: The innovation logs per flag (the aid sources of windahrs.aid, by their log keys).
_REJECTED = {
    "accel_rejected": ("accel",),
    "mag_rejected": ("mag",),
    "gnss_rejected": ("gnss",),
    "air_rejected": ("air", "tas", "sideslip", "aoa", "drag"),
}
#: A stream absent for at least this long, s, is flagged whatever its rate (PX4 EKF2's
#: GNSS_MAX_INTERVAL, 0.5 s, the longest it waits for a GNSS sample before calling it late).
ABSENT_MIN_S = 0.5
#: ... and after this many of its own median periods.
ABSENT_PERIODS = 5.0


def flag_names(bits: int | np.integer) -> list[str]:
    """The names of the flags set in ``bits``."""
    return [name for name, (b, _) in FLAGS.items() if int(bits) >> b & 1]


def absent_after(t: F64, *, period: float | None = None) -> float:
    """How long a stream with sample times ``t`` may go without a sample before it is absent, s;
    period: the median of ``diff(t)`` when the caller has it (not computed again)."""
    if period is None:
        dt = np.diff(t)
        period = float(np.median(dt)) if len(dt) else 0.0
    return max(ABSENT_PERIODS * period, ABSENT_MIN_S)


def absent_mask(t_stream: F64, ok: NDArray[np.bool_], t: F64, lim: float | None = None) -> NDArray[np.bool_]:
    """At each of t: no finite sample of the stream in the last absence time (``lim``, default
    :func:`absent_after`; a gap, after the last sample, or before a first sample that came late)."""
    ts = t_stream if ok.all() else t_stream[ok]
    if len(ts) == 0:
        return np.ones(len(t), dtype=bool)
    lim = absent_after(t_stream) if lim is None else lim
    if len(t) and ts[0] - t[0] <= lim and t[-1] - ts[-1] <= lim and (len(ts) < 2 or np.diff(ts).max() <= lim):
        return np.zeros(len(t), dtype=bool)  # (no gap anywhere: the common case, quickly)
    i = np.searchsorted(ts, t, side="right")
    prev = np.where(i > 0, ts[np.maximum(i - 1, 0)], -np.inf)
    # (a stream whose first sample comes within the time of the flight's start is not absent before it)
    return ~((t - prev <= lim) | ((i == 0) & (ts[0] - t[0] <= lim)))


def _holding(t_events: F64, bad: NDArray[np.bool_], t: F64, hold: float) -> NDArray[np.bool_]:
    """At each of t: the last event at or before it was bad and at most ``hold`` s ago."""
    if len(t_events) == 0:
        return np.zeros(len(t), dtype=bool)
    i = np.searchsorted(t_events, t, side="right") - 1
    ok = i >= 0
    j = np.maximum(i, 0)
    return ok & bad[j] & (t - t_events[j] <= hold)


def _points(t_events: F64, t: F64) -> NDArray[np.bool_]:
    """The samples of t nearest to each event (IMU samples: the one the event is recorded at)."""
    out = np.zeros(len(t), dtype=bool)
    if len(t_events) and len(t):
        out[np.clip(np.searchsorted(t, t_events, side="left"), 0, len(t) - 1)] = True
    return out


def _points_within(t_events: F64, t: F64, lim: float) -> NDArray[np.bool_]:
    """:func:`_points` of the events within ``lim`` s of the samples' span (an event far
    outside it, on a stream that runs longer than the IMU, marks nothing)."""
    if len(t) == 0:
        return np.zeros(0, dtype=bool)
    return _points(t_events[(t_events >= t[0] - lim) & (t_events <= t[-1] + lim)], t)


#: The flag of each span alert the checks of windahrs.filters.checks leave in Estimate.alerts.
_ALERT_FLAGS = {"tilt": "tilt_lost", "bias": "bias_large"}

#: The repair kinds per flag (windahrs.repair.REPAIR_KINDS; "unsortable" rows have no time).
_REPAIRED = {"stamps_repaired": ("reordered", "duplicates"), "values_repaired": ("infinite", "out_of_range")}


def _stream_rows(flight: Flight, name: str) -> tuple[F64, NDArray[np.bool_]] | None:
    """A stream's sample times and which samples are finite (None: the flight has no such stream)."""
    s = getattr(flight, name)
    if s is None:
        return None
    if name == "imu":
        return s.t, np.isfinite(s.w_b).all(axis=1) & np.isfinite(s.f_b).all(axis=1)
    if name == "mag":
        return s.t, np.isfinite(s.mag_b).all(axis=1)
    if name == "gnss":
        return s.t, np.isfinite(s.v_n).all(axis=1)
    return s.t, np.isfinite(s.tas)


def _runs(same: NDArray[np.bool_], t: F64, min_n: int, min_s: float) -> NDArray[np.bool_]:
    """Mark the samples of runs where ``same[k]`` (sample k repeats sample k-1) holds for at
    least min_n samples and min_s s (the run's first sample included)."""
    out = np.zeros(len(t), dtype=bool)
    edges = np.flatnonzero(np.diff(np.r_[0, same.astype(np.int8), 0]))
    for i0, i1 in zip(edges[::2], edges[1::2], strict=True):
        a = max(i0 - 1, 0)  # the sample the run repeats
        if i1 - a >= min_n and t[i1 - 1] - t[a] >= min_s:
            out[a:i1] = True
    return out


def _repeats(v: F64) -> NDArray[np.bool_]:
    """Sample k equals sample k-1 in every column (False for the first)."""
    v = v.reshape(len(v), -1)
    same = np.zeros(len(v), dtype=bool)
    first = v[1:, 0] == v[:-1, 0]
    if first.any():  # (a live sensor rarely repeats even one column: checked first, quickly)
        same[1:] = first & np.all(v[1:] == v[:-1], axis=1) & np.isfinite(v[1:]).all(axis=1)
    return same


def stream_flags(flight: Flight) -> dict[str, tuple[F64, NDArray[np.bool_]]]:
    """What the flight's own samples say: per flag name (stuck sensors, clipped IMU axes),
    the stream's times and the samples flagged."""
    out: dict[str, tuple[F64, NDArray[np.bool_]]] = {}
    imu = flight.imu
    stuck = np.zeros(len(imu.t), dtype=bool)
    clipped = np.zeros(len(imu.t), dtype=bool)
    for v, lo in ((imu.w_b, CLIP_MIN_W), (imu.f_b, CLIP_MIN_F)):
        whole = _repeats(v)
        stuck |= _runs(whole, imu.t, STUCK_SAMPLES, STUCK_S)
        big = np.abs(v) >= lo
        for a in range(3):
            col = v[:, a]
            held = np.zeros(len(col), dtype=bool)
            held[1:] = (col[1:] == col[:-1]) & np.isfinite(col[1:])
            if held.any():  # one axis holding any value
                clipped |= _runs(held & ~whole, imu.t, STUCK_SAMPLES, STUCK_S)
            if big[:, a].any():  # one large magnitude, either sign
                same = np.zeros(len(col), dtype=bool)
                same[1:] = (np.abs(col[1:]) == np.abs(col[:-1])) & big[1:, a]
                clipped |= _runs(same, imu.t, CLIP_SAMPLES, 0.0)
    out["imu_stuck"], out["imu_clipped"] = (imu.t, stuck), (imu.t, clipped)
    jitter = np.zeros(len(imu.t), dtype=bool)
    if len(imu.t) > 2:
        dt = np.diff(imu.t)
        period = float(np.median(dt))
        jitter[1:] = (np.abs(dt - period) > JITTER_SHARE * period) & (dt < absent_after(imu.t))
    out["imu_jitter"] = (imu.t, jitter)
    if flight.mag is not None:
        m = flight.mag
        out["mag_stuck"] = (m.t, _runs(_repeats(m.mag_b), m.t, STUCK_SAMPLES, STUCK_S))
        norm = np.linalg.norm(m.mag_b, axis=1)
        ref = float(np.linalg.norm(flight.site.mag_n)) if flight.site.mag_n is not None else float(np.nanmedian(norm))
        with np.errstate(invalid="ignore"):
            out["mag_disturbed"] = (m.t, np.abs(norm - ref) > MAG_NORM_SHARE * ref)
    if flight.air is not None:
        air = flight.air
        s = _runs(_repeats(air.tas), air.t, STUCK_SAMPLES, STUCK_S)
        for vane in (air.aoa, air.sideslip):
            if vane is not None:
                s |= _runs(_repeats(vane), air.t, STUCK_SAMPLES, STUCK_S)
        out["air_stuck"] = (air.t, s)
    return out


def estimate_flags(est: Estimate, flight: Flight) -> NDArray[np.uint32]:
    """The flags (:data:`FLAGS`) at each of the Estimate's samples, from its own records and
    the flight's streams (module docstring)."""
    t = est.t
    out = np.zeros(len(t), dtype=np.uint32)

    def put(name: str, mask: NDArray[np.bool_]) -> None:
        out[mask] |= np.uint32(1 << FLAGS[name][0])

    held = est.alerts.get("imu")
    if held is not None and len(held):
        put("imu_held", _points(held[held[:, 3] < 3, 0], t))
        put("imu_late", _points(held[held[:, 3] == 3, 0], t))
    absent: dict[str, NDArray[np.bool_]] = {}
    lims: dict[str, float] = {}
    for stream in ("imu", "mag", "gnss", "air"):
        rows = _stream_rows(flight, stream)
        if rows is not None:
            lims[stream] = lim = absent_after(rows[0])
            absent[stream] = absent_mask(rows[0], rows[1], t, lim)
            if stream == "imu":  # the estimate has no rows in a gap: its first row after says it
                absent[stream][1:] |= np.diff(t) > lim
            put(f"{stream}_absent", absent[stream])
    for flag, keys in _REJECTED.items():
        for key in keys:
            inn = est.innovations.get(key)
            if inn is None or len(inn.t) == 0 or inn.accepted.all():
                continue
            # a disturbance check logs NaN: that is a disturbance, not the gate
            nan = ~np.isfinite(inn.nu).all(axis=1) if inn.nu.ndim == 2 else ~np.isfinite(inn.nu)
            hold = lims.get(SENSOR_STREAMS[SENSORS.index(key)]) or absent_after(inn.t)
            put(flag, _holding(inn.t, ~inn.accepted & ~nan, t, hold))
            if key in ("mag", "accel"):
                put(f"{key}_disturbed", _holding(inn.t, ~inn.accepted & nan, t, hold))
    for reset_rows in est.resets.values():
        put("reset", _points(reset_rows[:, 0], t))
    for alert, flag in _ALERT_FLAGS.items():  # the checks' spans (windahrs.filters.checks)
        for t0, t1, _ in est.alerts.get(alert, ()):
            put(flag, (t >= t0) & (t <= t1))
    if "gnss" in est.innovations or (est.v_n is not None and "gnss" in absent):
        put("fallback", absent.get("gnss", np.zeros(len(t), dtype=bool)))
    for name, (ts, on) in stream_flags(flight).items():  # onto the estimate's samples
        if on.any():
            put(name, _holding(ts, on, t, lims.get(name.split("_")[0]) or absent_after(ts)))
    lim_imu = lims.get("imu", ABSENT_MIN_S)
    for name, kinds in _REPAIRED.items():
        for per in flight.repair_times.values():
            for kind in kinds:
                if kind in per:
                    put(name, _points_within(per[kind], t, lim_imu))
    if flight.mag is not None:
        tm, on = mag_drift(est, flight)
        if on.any():
            put("mag_drift", _holding(tm, on, t, lims.get("mag") or absent_after(tm)))
    if flight.air is not None and flight.gnss is not None:
        ta, on = air_drift(est, flight)
        if on.any():
            put("air_drift", _holding(ta, on, t, lims.get("air") or absent_after(ta)))
    if flight.gnss is not None:
        tg, on = gnss_jump(est, flight)
        if on.any():
            put("gnss_jump", _points_within(tg[on], t, lims.get("gnss") or absent_after(tg)))
    if (est.cov is not None or est.init_index is not None) and len(t):
        put("not_initialised", np.arange(len(t)) < est.first_initialised)
    return out


@dataclass(frozen=True)
class Span:
    """A run of samples with one flag set: t0 to t1 s, the flag's name and its reason."""

    t0: float
    t1: float
    flag: str
    reason: str


def flag_spans(t: F64, flags: NDArray[np.uint32], *, names: tuple[str, ...] | None = None) -> list[Span]:
    """The runs of consecutive samples with each flag set (``names``: only these), in time order."""
    spans: list[Span] = []
    for name, (bit, reason) in FLAGS.items():
        if names is not None and name not in names:
            continue
        on = (flags >> np.uint32(bit)) & np.uint32(1)
        edges = np.flatnonzero(np.diff(np.r_[0, on.astype(np.int8), 0]))
        for i0, i1 in zip(edges[::2], edges[1::2], strict=True):
            spans.append(Span(float(t[i0]), float(t[i1 - 1]), name, reason))
    return sorted(spans, key=lambda s: (s.t0, s.flag))
