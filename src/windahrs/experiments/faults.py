"""The fault matrix (``windahrs faults``): every fault case of :func:`default_cases` injected
into one seeded simulated flight, every estimator run on the clean and on each faulty flight,
and each run scored against the truth around the fault's active span.

Definitions (docs/ROBUSTNESS.md), with ``e(t)`` the total attitude error (rotation angle
between estimate and truth, deg) and ``[t0, t1]`` the case's span (the union of its faults'
spans):

* ``rms_before_deg``: RMS of e over ``[max(t0 - 10 s, 5 s), t0)`` (the filters are causal, so
  this is the clean run's as well); None when the fault starts before 15 s (no full
  window after the start-up).
* ``rms_during_deg``, ``max_during_deg``: RMS and largest e over ``[t0, max(t1, t0 + 1 s)]``
  (at least a second, so that an instantaneous fault's first effect is inside).
* ``rms_after_deg``: RMS of e from ``t1 + 10 s`` (the recovery allowance) to the flight's end.
* ``recover_s``: the smallest ``tau >= 0`` (on the IMU grid) for which the RMS of e over
  ``[t1 + tau, t1 + tau + 1 s]`` is below twice the reference, the reference being
  rms_before or, for a fault without a pre-fault window, the clean run's RMS over
  ``[t1, t1 + 10 s]``; None when it never is within the flight.
* ``flagged``, ``flag_delay_s``, ``flag_source``: :func:`first_flag` within
  :data:`FLAG_WINDOW_S` of the fault's onset ``t_onset_s`` (issue 13's criterion), the
  first sample the case changed (:meth:`windahrs.sim.faults.RawFlight.first_change`): the
  span's start, but for the stamp faults, whose duplicated or swapped samples fall at
  random in their span, the first of those.
* ``flagged_span``, ``span_flag_delay_s``, ``span_flag_source``: the same within the case's
  span (at least :data:`FLAG_WINDOW_S`): a slow fault (a drifting field, a ramping pitot)
  shows nothing in its first second, and the repaired stamps of ``duplicate-stamps`` and
  ``out-of-order`` fall anywhere in the span.
* ``nan_count``: the estimate's rows with a non-finite attitude, bias, velocity, wind or
  covariance.
* ``no_effect``: the injected flight equals the clean one sample for sample (e.g. a gyro
  clipped at a range the flight's motion never reaches): there is nothing to flag, and the
  summary counts leave the row out (:func:`counts`).
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from windahrs.estimate import Estimate
from windahrs.filters.base import MissingSensorError
from windahrs.filters.registry import make_estimator
from windahrs.flags import FLAGS
from windahrs.flight import Flight
from windahrs.metrics import attitude_errors, score
from windahrs.sim.faults import (
    AccelSaturation,
    AccelSpike,
    DuplicateStamps,
    Fault,
    GnssJump,
    GnssOutage,
    GyroSaturation,
    GyroSpike,
    ImuDropout,
    ImuJitter,
    ImuNaN,
    ImuStuck,
    MagAbsent,
    MagDrift,
    MagMagnet,
    OutOfOrder,
    PitotBlockage,
    VaneFailure,
    VibrationBurst,
    inject_raw,
)
from windahrs.sim.scenario import make_scenario, simulate

__all__ = [
    "DEFAULT_FAULT_FILTERS",
    "FLAG_WINDOW_S",
    "RECOVERY_ALLOWANCE_S",
    "Counts",
    "FaultCase",
    "FaultRow",
    "counts",
    "default_cases",
    "first_flag",
    "matrix_markdown",
    "run_fault_matrix",
    "unchanged",
]

F64 = NDArray[np.float64]

DEFAULT_FAULT_FILTERS = ("ins-wind", "mekf", "mekf-air", "auto")
#: A fault counts as flagged when a flag appears within this long of its start, s (issue 13).
FLAG_WINDOW_S = 1.0
#: The error must be back under twice its pre-fault RMS within this long of the fault's end,
#: s (issue 13); rms_after is measured from then on.
RECOVERY_ALLOWANCE_S = 10.0
#: The pre-fault window, s, and the start-up it leaves out, s.
BEFORE_S = 10.0
SETTLE_S = 5.0
#: The window of the running RMS that recovery is judged on, s.
RECOVERY_WINDOW_S = 1.0
#: The default cases' fault start, s, and flight length, s.
FAULT_AT_S = 30.0
MATRIX_DURATION_S = 90.0
#: The gyro-saturation case's range, rad/s: below the fixed wing's turn rate (0.33 rad/s in
#: yaw at 30-35 s of the default flight), so that the clipping acts on real motion.
GYRO_CLIP_CASE = 0.1


@dataclass(frozen=True)
class FaultCase:
    """One row group of the matrix: a name and the faults injected together. edge: the
    faulty streams go through the generic-CSV reader's edge repair (time-stamp faults that a
    Flight refuses)."""

    name: str
    faults: tuple[Fault, ...]
    edge: bool = False

    @property
    def span(self) -> tuple[float, float]:
        return min(f.span[0] for f in self.faults), max(f.span[1] for f in self.faults)

    @property
    def needs(self) -> frozenset[str]:
        return frozenset(f.needs for f in self.faults) | frozenset(
            "vanes" for f in self.faults if isinstance(f, VaneFailure)
        )


def default_cases(at: float = FAULT_AT_S) -> list[FaultCase]:
    """The catalogue's faults, each alone (a few in the combination that makes them bite),
    starting ``at`` s; the late magnetometer starts at 0 s. Sizes: the issue's (a 40 rad/s
    gyro spike, five of them, +50 uT, a 5 m/s GNSS jump) or each fault's default."""
    a = float(at)
    vib_clip_accel = (
        VibrationBurst(a, 5.0, accel_amplitude=4.0 * 9.80665, gyro_amplitude=0.0), AccelSaturation(a, 5.0)
    )
    return [
        FaultCase("gyro-spike", (GyroSpike(a),)),
        FaultCase("gyro-spike-x5", tuple(GyroSpike(a + 0.4 * k, axis=k % 3) for k in range(5))),
        FaultCase("accel-spike", (AccelSpike(a),)),
        FaultCase("imu-nan-0.5s", (ImuNaN(a, 0.5),)),
        FaultCase("imu-dropout-0.5s", (ImuDropout(a, 0.5),)),
        FaultCase("imu-stuck-1s", (ImuStuck(a, 1.0),)),
        FaultCase("vibration-5s", (VibrationBurst(a, 5.0),)),
        FaultCase("accel-saturation-5s", vib_clip_accel),
        # a range below the flight's own rates, as a flip does to a +-250 deg/s range
        FaultCase("gyro-saturation-5s", (GyroSaturation(a, 5.0, limit=GYRO_CLIP_CASE),)),
        FaultCase("mag-magnet-10s", (MagMagnet(a, 10.0),)),
        FaultCase("mag-drift-30s", (MagDrift(a, 30.0),)),
        FaultCase("mag-absent-15s", (MagAbsent(a, 15.0),)),
        FaultCase("mag-late", (MagAbsent(0.0, a),)),
        FaultCase("pitot-freeze-10s", (PitotBlockage(a, 10.0, mode="freeze"),)),
        FaultCase("pitot-zero-10s", (PitotBlockage(a, 10.0, mode="zero"),)),
        FaultCase("pitot-ramp-10s", (PitotBlockage(a, 10.0, mode="ramp"),)),
        FaultCase("vane-stuck-10s", (VaneFailure(a, 10.0),)),
        FaultCase("gnss-outage-20s", (GnssOutage(a, 20.0),)),
        FaultCase("gnss-jump-10s", (GnssJump(a, 10.0),)),
        FaultCase("imu-jitter-10s", (ImuJitter(a, 10.0),)),
        FaultCase("duplicate-stamps", (DuplicateStamps(a, 10.0, count=5),), edge=True),
        FaultCase("out-of-order", (OutOfOrder(a, 10.0, count=5),), edge=True),
    ]


@dataclass(frozen=True)
class FaultRow:
    """One fault x filter result (module docstring for the definitions)."""

    fault: str
    filter: str
    nan_count: int
    flagged: bool
    flag_delay_s: float | None
    recover_s: float | None
    rms_before_deg: float | None
    rms_during_deg: float
    rms_after_deg: float | None
    max_during_deg: float
    vehicle: str = ""
    t_start_s: float = 0.0
    t_end_s: float = 0.0
    t_onset_s: float = 0.0
    flag_source: str | None = None
    rmse_deg: float = math.nan
    rmse_clean_deg: float = math.nan
    resets: int = 0
    flagged_span: bool = False
    span_flag_delay_s: float | None = None
    span_flag_source: str | None = None
    no_effect: bool = False

    def as_dict(self) -> dict[str, Any]:
        """The row for JSON: non-finite numbers as None, times and angles to 1e-4."""
        return {k: _json(v) for k, v in self.__dict__.items()}


def _json(v: Any) -> Any:
    if isinstance(v, float):
        return round(v, 4) if math.isfinite(v) else None
    return v


@dataclass
class MatrixResult:
    """Rows, and the cases or filters that could not run, with the reason."""

    vehicle: str
    wind: float
    duration: float
    seed: int
    rows: list[FaultRow] = field(default_factory=list)
    not_run: list[str] = field(default_factory=list)


# ---------------------------------------------------------------------------------------------
# flags


def _times_in(t: F64, lo: float, hi: float) -> F64:
    return t[(t >= lo) & (t <= hi)]


def first_flag(
    est: Estimate, clean: Estimate | None, t0: float, *, window: float = FLAG_WINDOW_S, flight: Flight | None = None
) -> tuple[float | None, str | None]:
    """The first flag the estimate raised within ``[t0, t0 + window]`` s that the clean run
    (the same filter on the same flight without the fault) did not raise: (time s, what), or
    (None, None). The one place that reads flags; what the Estimate exposes today:

    * a reset (``Estimate.resets``), any sensor;
    * an alert of the checks (``Estimate.alerts``) starting in the window;
    * an innovation rejected by its gate (``Innovations.accepted`` False) at a stamp where
      the clean run accepted it (the gates also reject in clean flight: a sustained
      acceleration on the accelerometer);
    * NaN samples skipped (``Estimate.skipped``, a count per stream: more than the clean
      run's), timed at the flight's first non-finite sample in the window;
    * the per-sample flags (``Estimate.flags``, :data:`windahrs.flags.FLAGS`), raised
      where the clean run's are not.
    """
    hi = t0 + window
    found: list[tuple[float, str]] = []
    for sensor, rows in est.resets.items():
        ts = _times_in(np.asarray(rows)[:, 0], t0, hi) if len(rows) else np.empty(0)
        if len(ts):
            found.append((float(ts[0]), f"reset:{sensor}"))
    for name, rows in est.alerts.items():
        ts = _times_in(np.asarray(rows)[:, 0], t0, hi) if len(rows) else np.empty(0)
        if len(ts):
            found.append((float(ts[0]), f"alert:{name}"))
    for sensor, inn in est.innovations.items():
        sel = (inn.t >= t0) & (inn.t <= hi) & ~inn.accepted
        ts = inn.t[sel]
        if clean is not None and sensor in clean.innovations and len(ts):
            ci = clean.innovations[sensor]
            ts = ts[~np.isin(ts, ci.t[~ci.accepted])]
        if len(ts):
            found.append((float(ts[0]), f"rejected:{sensor}"))
    if flight is not None and sum(est.skipped.values()) > (sum(clean.skipped.values()) if clean else 0):
        for name, t in flight.streams().items():
            s = getattr(flight, name)
            arrays = [v for k, v in vars(s).items() if k != "t" and isinstance(v, np.ndarray)]
            if name == "air":  # a NaN vane angle does not make the sample missing
                arrays = [s.tas]
            bad = np.zeros(len(t), dtype=bool)
            for a in arrays:
                bad |= ~np.isfinite(a.reshape(len(t), -1)).all(axis=1)
            ts = _times_in(t[bad], t0, hi)
            if len(ts) and est.skipped.get(name, 0) > (clean.skipped.get(name, 0) if clean else 0):
                found.append((float(ts[0]), f"skipped:{name}"))
    if est.flags is not None:
        for name, (bit, _) in FLAGS.items():
            on = (est.flags >> np.uint32(bit)) & np.uint32(1) == 1
            new = on
            if clean is not None and clean.flags is not None:
                c = (clean.flags >> np.uint32(bit)) & np.uint32(1) == 1
                new = on & ~np.isin(est.t, clean.t[c])
            ts = _times_in(est.t[new], t0, hi)
            if len(ts):
                found.append((float(ts[0]), f"flag:{name}"))
    if not found:
        return None, None
    t_first, what = min(found)
    return t_first, what


# ---------------------------------------------------------------------------------------------
# scoring one run


def nan_rows(est: Estimate) -> int:
    """Rows of the estimate with a non-finite attitude, bias, velocity, wind or covariance."""
    bad = np.asarray(~np.isfinite(est.q_nb).all(axis=1))
    for a in (est.gyro_bias_b, est.v_n, est.wind_n):
        if a is not None:
            bad |= ~np.isfinite(a).all(axis=1)
    if est.cov is not None:
        bad[est.cov_rows] |= ~np.isfinite(est.cov.reshape(len(est.cov), -1)).all(axis=1)
    return int(bad.sum())


def _rms(x: F64) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if len(x) else None


def _errors_deg(est: Estimate, truth_flight: Flight) -> tuple[F64, F64]:
    err = attitude_errors(est, truth_flight)
    total = np.full(len(est.t), np.nan)  # a NaN attitude scores as NaN, not as a skipped row
    total[err.index] = np.degrees(err.total)
    return est.t, total


def recovery_time(t: F64, e: F64, t1: float, threshold: float, window: float = RECOVERY_WINDOW_S) -> float | None:
    """The smallest tau >= 0 on the grid ``t`` with RMS(e over [t1 + tau, t1 + tau + window])
    below ``threshold`` (a NaN error counts as above it); None if never within ``t``."""
    e2 = np.where(np.isfinite(e), e**2, np.inf)
    c = np.concatenate([[0.0], np.cumsum(e2)])
    i0 = np.flatnonzero(t >= t1)
    if len(i0) == 0:
        return None
    i0 = i0[t[i0] + window <= t[-1]]
    if len(i0) == 0:
        return None
    i1 = np.searchsorted(t, t[i0] + window, side="right")
    with np.errstate(invalid="ignore"):
        ms = (c[i1] - c[i0]) / (i1 - i0)
    ok = np.flatnonzero(ms < threshold**2)
    return float(t[i0[ok[0]]] - t1) if len(ok) else None


def score_fault(
    est: Estimate,
    clean: Estimate,
    flight: Flight,
    faulty: Flight,
    case: FaultCase,
    vehicle: str = "",
    onset: float | None = None,
) -> FaultRow:
    """One row: ``est`` (run on ``faulty``) against ``flight``'s truth around the case's span,
    with ``clean`` (the same filter on ``flight``) for the flags and the recovery reference;
    ``onset``: the first sample the case changed, s (default the span's start), from which
    the flag's delay is counted."""
    t0, t1 = case.span
    ton = t0 if onset is None else onset
    t, e = _errors_deg(est, flight)
    tc, ec = _errors_deg(clean, flight)
    before = (t >= max(t0 - BEFORE_S, SETTLE_S)) & (t < t0)
    rms_before = _rms(e[before]) if t0 - SETTLE_S >= BEFORE_S else None
    ref = rms_before
    if ref is None:
        ref = _rms(ec[(tc >= t1) & (tc <= t1 + BEFORE_S)])
    during = (t >= t0) & (t <= max(t1, t0 + 1.0))
    if not during.any():  # an IMU dropout: the first sample after it
        during = t == t[np.searchsorted(t, t0).clip(max=len(t) - 1)]
    ed = e[during]
    after = t >= t1 + RECOVERY_ALLOWANCE_S
    flag_t, source = first_flag(est, clean, ton, flight=faulty)
    span_t, span_source = first_flag(est, clean, t0, window=max(t1 - t0, FLAG_WINDOW_S), flight=faulty)
    recover = recovery_time(t, e, t1, 2.0 * ref) if ref is not None else None
    return FaultRow(
        fault=case.name,
        filter=est.filter,
        nan_count=nan_rows(est),
        flagged=flag_t is not None,
        flag_delay_s=None if flag_t is None else flag_t - ton,
        recover_s=recover,
        rms_before_deg=rms_before,
        rms_during_deg=_rms(ed) or math.nan,
        rms_after_deg=_rms(e[after]),
        max_during_deg=float(np.nanmax(ed)) if np.isfinite(ed).any() else math.nan,
        vehicle=vehicle,
        t_start_s=t0,
        t_end_s=t1,
        t_onset_s=ton,
        flag_source=source,
        rmse_deg=score(est, flight).rmse_total_deg,
        rmse_clean_deg=score(clean, flight).rmse_total_deg,
        resets=int(sum(len(r) for r in est.resets.values())),
        flagged_span=span_t is not None,
        span_flag_delay_s=None if span_t is None else span_t - t0,
        span_flag_source=span_source,
    )


# ---------------------------------------------------------------------------------------------
# the matrix


def _faulty_flight(flight: Flight, case: FaultCase, seed: int) -> tuple[Flight, float | None]:
    """The case injected into ``flight``, and its onset (None: it changed no sample)."""
    raw = inject_raw(flight, case.faults, seed=seed)
    onset = raw.first_change()
    if not case.edge:
        return raw.to_flight(), onset
    from windahrs.io import read_flight

    with tempfile.TemporaryDirectory(prefix="windahrs-faults-") as d:
        repaired = read_flight(raw.write_csv_dir(Path(d) / "flight"))
    # the reader rebuilt the streams; the truth is the simulation's, as for the other cases
    return repaired.replace(truth=flight.truth, reference=None, site=flight.site), onset


def _available(flight: Flight, case: FaultCase) -> str | None:
    for need in sorted(case.needs):
        if need == "vanes":
            if flight.air is None or not flight.air.has_vanes:
                return "the flight has no vanes"
        elif getattr(flight, need) is None:
            return f"the flight has no {need} stream"
    return None


def check_cases(cases: Sequence[FaultCase], duration: float) -> None:
    """ValueError naming ``duration`` when a case ends after the flight."""
    for c in cases:
        if c.span[1] > duration:
            raise ValueError(
                f"duration: expected at least the end of case {c.name} ({c.span[1]:g} s), found {duration:g}"
            )


def run_fault_matrix(
    vehicle: str,
    specs: Sequence[str],
    *,
    wind: float = 8.0,
    duration: float = MATRIX_DURATION_S,
    seed: int = 0,
    cases: Sequence[FaultCase] | None = None,
    progress: Callable[[int, int, str], None] | None = None,
) -> MatrixResult:
    """Simulate one ``vehicle`` flight (W20 ``wind`` m/s, ``duration`` s, ``seed``), inject
    each case (default :func:`default_cases`; fault draws seeded with ``seed``), run every
    estimator spec on it and on the clean flight, and score (:func:`score_fault`). A case the
    flight lacks a sensor for, or a filter that cannot run on the vehicle, is listed in
    ``not_run``. ValueError for a bad spec (before any simulation) or a case that does not fit
    the flight. ``progress(done, total, label)`` after each run."""
    if not specs:
        raise ValueError("filters: expected at least one estimator, found none")
    estimators = [(s, make_estimator(s)) for s in specs]
    cases = list(default_cases() if cases is None else cases)
    if not cases:
        raise ValueError("cases: expected at least one fault case, found none")
    check_cases(cases, duration)
    scenario = make_scenario(vehicle, wind=wind, duration=duration)
    res = MatrixResult(vehicle=vehicle, wind=wind, duration=duration, seed=seed)
    flight = simulate(scenario, np.random.default_rng(seed))
    total, done = len(estimators) * (len(cases) + 1), 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # what the estimators warn about is in their Estimates
        clean: dict[str, Estimate] = {}
        for spec, est in estimators:
            try:
                clean[spec] = est.run(flight)
            except MissingSensorError as exc:
                res.not_run.append(f"{spec}: {exc}")
            done += 1
            if progress is not None:
                progress(done, total, f"{spec} clean")
        for case in cases:
            why = _available(flight, case)
            if why is not None:
                res.not_run.append(f"{case.name}: {why}")
                done += len(estimators)
                if progress is not None:
                    progress(done, total, f"{case.name} not applicable")
                continue
            faulty, onset = _faulty_flight(flight, case, seed)
            same = unchanged(flight, faulty)
            for spec, est in estimators:
                if spec in clean:
                    out = est.run(faulty)
                    row = score_fault(out, clean[spec], flight, faulty, case, vehicle, onset)
                    res.rows.append(_relabel(row, spec, same))
                done += 1
                if progress is not None:
                    progress(done, total, f"{case.name} {spec}")
    return res


def _relabel(row: FaultRow, spec: str, no_effect: bool = False) -> FaultRow:
    return dataclasses.replace(row, filter=spec, no_effect=no_effect)


def unchanged(flight: Flight, faulty: Flight) -> bool:
    """Whether ``faulty`` has the same samples as ``flight`` in every sensor stream (times
    and values, NaN equal to NaN): the fault changed nothing."""
    for name in ("imu", "mag", "gnss", "air"):
        a, b = getattr(flight, name), getattr(faulty, name)
        if (a is None) != (b is None):
            return False
        if a is None:
            continue
        for f in dataclasses.fields(a):
            x, y = getattr(a, f.name), getattr(b, f.name)
            if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
                if not (isinstance(x, np.ndarray) and isinstance(y, np.ndarray)):
                    return False
                if x.shape != y.shape or not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
                    return False
    return True


@dataclass(frozen=True)
class Counts:
    """The matrix's summary against issue 13's acceptance, over the runs whose fault changed
    the flight (``no_effect`` rows left out)."""

    runs: int
    no_effect: int
    flagged: int
    flagged_span: int
    recovered: int
    with_nan: int


def counts(rows: Sequence[FaultRow]) -> Counts:
    """:class:`Counts` of ``rows``: flagged within 1 s, within the span, back under twice the
    pre-fault RMS within :data:`RECOVERY_ALLOWANCE_S`, with NaN rows."""
    live = [r for r in rows if not r.no_effect]
    return Counts(
        runs=len(live),
        no_effect=len(rows) - len(live),
        flagged=sum(r.flagged for r in live),
        flagged_span=sum(r.flagged_span for r in live),
        recovered=sum(r.recover_s is not None and r.recover_s <= RECOVERY_ALLOWANCE_S for r in live),
        with_nan=sum(r.nan_count > 0 for r in rows),
    )


def _cell(v: float | None, fmt: str = ".2f") -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def matrix_markdown(results: Sequence[MatrixResult]) -> str:
    """The matrices as markdown tables, one per result (vehicle)."""
    lines = ["# Fault matrix", ""]
    lines.append(
        "Total attitude error against the truth, deg. before: RMS over the 10 s before the fault; during: over its "
        "span (at least 1 s); after: from 10 s after its end; recover: s after its end until the 1-s RMS is under "
        "twice the pre-fault RMS (- never); flag: the first flag within 1 s of the start, and its delay (else the "
        "first within the fault's span, 'span:', and its delay; docs/ROBUSTNESS.md)."
    )
    for r in results:
        lines += ["", f"## {r.vehicle}, W20 = {r.wind:g} m/s, {r.duration:g} s, seed {r.seed}", ""]
        lines.append(
            "| fault | filter | NaN | flag (delay s) | before | during | max | after | recover s "
            "| RMSE clean -> faulty |"
        )
        lines.append("|---|---|---|---|---|---|---|---|---|---|")
        for w in r.rows:
            flag = f"{w.flag_source} ({w.flag_delay_s:.2f})" if w.flagged and w.flag_delay_s is not None else "no"
            if not w.flagged and w.flagged_span and w.span_flag_delay_s is not None:
                flag = f"span: {w.span_flag_source} ({w.span_flag_delay_s:.2f})"
            if w.no_effect:
                flag = f"({flag}; the fault changed no sample)"
            lines.append(
                f"| {w.fault} | {w.filter} | {w.nan_count} | {flag} | {_cell(w.rms_before_deg)} | "
                f"{_cell(w.rms_during_deg)} | {_cell(w.max_during_deg)} | {_cell(w.rms_after_deg)} | "
                f"{_cell(w.recover_s, '.1f')} | {_cell(w.rmse_clean_deg)} -> {_cell(w.rmse_deg)} |"
            )
        if r.not_run:
            lines += ["", "Not run: " + "; ".join(r.not_run) + "."]
    return "\n".join(lines) + "\n"

