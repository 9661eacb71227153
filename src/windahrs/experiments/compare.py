"""Several estimators on one flight: which of them run, their scores against one reference,
and the one alignment of that reference (``windahrs compare``, ``windahrs report``,
``wa.compare``).

The steps, each a function the CLI only prints around:

* :func:`select_estimators`: build the estimators of the given specs (a bad name or field
  fails here, before any work), or of the defaults; a default that is not installed, or
  that the flight lacks a sensor for (:meth:`Selection.for_flight`), is left out with a
  note, an explicit one is a failure to report;
* :func:`run_estimators`: run them, either stopping at the first error (``compare``) or
  collecting each error as that filter's failure (``report``);
* :func:`align_reference`: the constant mount rotation and clock offset between the
  flight's reference and the FIRST result's estimate, fitted once and applied to every
  filter, so all are scored against the same reference. A simulation's truth needs none;
  a fit that fails either raises :class:`AlignmentError` or, with ``fallback=True``, leaves
  the reference as logged and says why. A flight whose GNSS is stamped on the reference's
  clock (``meta["gnss.clock"] = "reference"``) has its GNSS moved by the same offset
  before the other filters run (:meth:`AlignmentOutcome.run_flight`);
* :func:`compare`: all of it for ``windahrs compare``; its :class:`CompareResult` prints
  (``str``) exactly what the command prints and gives the ``--json`` rows.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from windahrs.estimate import Estimate
from windahrs.experiments.align import (
    GNSS_CLOCK_KEY,
    GNSS_ON_REFERENCE_CLOCK,
    Alignment,
    align_gnss_clock,
    alignment_warning,
    apply_alignment,
    describe_alignment,
    estimate_alignment,
)
from windahrs.filters.base import Estimator, MissingSensorError
from windahrs.flight import Flight
from windahrs.metrics import Score, reference_of, score
from windahrs.rotation import euler_from_quat

__all__ = [
    "DEFAULT_REPORT_FILTERS",
    "AlignmentError",
    "AlignmentOutcome",
    "CompareResult",
    "ReportRun",
    "Selection",
    "align_reference",
    "compare",
    "nothing_to_align",
    "run_estimators",
    "run_for_report",
    "select_estimators",
]

#: What ``windahrs report`` and ``windahrs compare`` run without ``--filters``: ``auto``
#: (the estimator the flight's sensors support) first, then the single estimators it
#: chooses from and the outside baseline.
DEFAULT_REPORT_FILTERS: tuple[str, ...] = ("auto", "mekf", "ins-wind", "vqf")
NOT_INSTALLED = "needs a package that is not installed (pip install 'windahrs[baselines]')"

Progress = Callable[[int, int], None]


# ---------------------------------------------------------------------------------------
# which filters run


@dataclass(frozen=True)
class Selection:
    """The estimators to run, by spec in order; ``failures``: spec -> why an explicitly
    asked-for filter cannot run (listed with the results); ``notes``: one sentence per
    default filter left out; ``explicit``: the specs were given (not the defaults)."""

    estimators: dict[str, Estimator]
    failures: dict[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    explicit: bool = True

    def for_flight(self, flight: Flight) -> Selection:
        """The selection for ``flight``: default filters it lacks a sensor for left out with
        a note; explicit ones kept (running them records the missing sensor as a failure)."""
        if self.explicit:
            return self
        kept: dict[str, Estimator] = {}
        notes = list(self.notes)
        for spec, est in self.estimators.items():
            try:
                est.check(flight)
            except MissingSensorError as exc:
                notes.append(f"Default filter {spec} left out: {exc}.")
                continue
            kept[spec] = est
        return Selection(kept, dict(self.failures), tuple(notes), self.explicit)


def select_estimators(
    specs: Sequence[str] | None, *, defaults: Sequence[str] = DEFAULT_REPORT_FILTERS
) -> Selection:
    """Build the estimators of ``specs`` (registry specs ``NAME[:field=value...]``), or of
    ``defaults`` when ``specs`` is None.

    A registered filter whose package is not installed is a failure when asked for and a
    note when a default. Raises ValueError for an empty list, an unknown name or field
    (before any flight is read).
    """
    from windahrs.filters.registry import REGISTRY, make_estimator, names

    explicit = specs is not None
    chosen = [s.strip() for s in (specs if specs is not None else defaults) if s.strip()]
    if not chosen:
        raise ValueError("filters: expected at least one filter spec, found none")
    available = set(names())
    estimators: dict[str, Estimator] = {}
    failures: dict[str, str] = {}
    notes: list[str] = []
    for spec in chosen:
        name = spec.split(":")[0]
        if name in REGISTRY and name not in available:  # not installed: reported; an unknown name fails below
            if explicit:
                failures[spec] = NOT_INSTALLED
            else:
                notes.append(f"Default filter {spec} left out: it {NOT_INSTALLED}.")
            continue
        estimators[spec] = make_estimator(spec)
    return Selection(estimators, failures, tuple(notes), explicit)


def run_estimators(
    flight: Flight,
    estimators: Mapping[str, Estimator] | Iterable[tuple[str, Estimator]],
    *,
    keep_going: bool = False,
    progress: Progress | None = None,
) -> tuple[list[tuple[str, Estimate]], dict[str, str]]:
    """Run each (spec, estimator) on ``flight``: the (spec, Estimate) of those that ran, in
    order, and spec -> error text of those that did not. ``keep_going=False`` lets the
    first ValueError (a missing sensor, a failed initialisation) propagate instead.
    ``progress(done, total)`` is called after each filter."""
    pairs = list(estimators.items()) if isinstance(estimators, Mapping) else list(estimators)
    results: list[tuple[str, Estimate]] = []
    failures: dict[str, str] = {}
    for i, (spec, est) in enumerate(pairs):
        try:
            results.append((spec, est.run(flight)))
        except ValueError as exc:
            if not keep_going:
                raise
            failures[spec] = str(exc)
        if progress is not None:
            progress(i + 1, len(pairs))
    return results, failures


# ---------------------------------------------------------------------------------------
# the one alignment


class AlignmentError(ValueError):
    """The reference could not be aligned to the estimate (``reason`` says why)."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(f"align: {reason}")


def _json_float(x: float) -> float | None:
    """x, or None where JSON has no number (NaN, inf)."""
    return float(x) if math.isfinite(x) else None


def _json_score(row: dict[str, object]) -> dict[str, object]:
    """A score's dict with None for its NaN figures (a list's entries one by one)."""
    out: dict[str, object] = {}
    for k, v in row.items():
        if isinstance(v, float):
            out[k] = _json_float(v)
        elif isinstance(v, list):
            out[k] = [_json_float(x) if isinstance(x, float) else x for x in v]
        else:
            out[k] = v
    return out


def nothing_to_align(flight: Flight) -> str:
    """Why a flight without a reference gets no alignment."""
    if flight.truth is not None:
        return "simulation truth is in the estimators' frame and on their clock by construction; nothing to align"
    return "the flight has no reference attitude; nothing to align"


@dataclass(frozen=True)
class AlignmentOutcome:
    """What became of an alignment request. ``alignment`` and ``aligned_on`` (the spec
    it was fitted on) when it was made; else ``skipped`` (nothing to align) or ``failed``
    (the fit's error, the reference is used as logged). ``warning``: the fit is
    unreliable (:func:`~windahrs.experiments.align.alignment_warning`). ``gnss_shift_s``
    and ``gnss_timing_sigma_s``: when the flight's GNSS is on the reference's clock, the
    shift its stamps get (s, ``-time_offset_s``) and the timing uncertainty then declared
    (s) (:func:`~windahrs.experiments.align.align_gnss_clock`); None otherwise."""

    alignment: Alignment | None = None
    aligned_on: str | None = None
    skipped: str | None = None
    failed: str | None = None
    warning: str | None = None
    gnss_shift_s: float | None = None
    gnss_timing_sigma_s: float | None = None

    @property
    def text(self) -> str | None:
        """The line ``--align`` prints, or None without an alignment."""
        if self.alignment is None:
            return None
        line = describe_alignment(self.alignment, self.aligned_on)
        if self.gnss_shift_s is not None:
            line += (f"; GNSS on the reference's clock: stamps moved by {self.gnss_shift_s * 1e3:+.1f} ms, "
                     f"timing uncertainty {self.gnss_timing_sigma_s or 0.0:.3f} s")
        return line

    def fields(self) -> dict[str, object]:
        """The alignment as the JSON fields of ``compare --json`` and ``bench-data --json``
        ({} without one): ``aligned_on`` (the spec it was fitted on), ``mount_deg`` (the
        mount's rotation angle), ``mount_rpy_deg`` (its ZYX roll, pitch, yaw), ``mount_q``
        ([w, x, y, z], ``q_est = q_ref * q_mount``), ``time_offset_s`` (how late the
        reference stamps are), ``rate_agreement`` (peak agreement of the body rates, 1:
        identical), ``residual_deg`` (RMS of what the alignment leaves), ``samples``,
        ``warning`` (why the fit is unreliable, or None), ``gnss_time_shift_s`` (how far the
        GNSS stamps were moved, s, or None when the GNSS is not on the reference's clock) and
        ``gnss_timing_sigma_s`` (the timing uncertainty the moved GNSS then declares, s, or
        None)."""
        al = self.alignment
        if al is None:
            return {}
        rpy = np.degrees(euler_from_quat(np.asarray(al.q_mount, dtype=np.float64)))
        return {
            "aligned_on": self.aligned_on,
            "mount_deg": al.mount_angle_deg,
            "mount_rpy_deg": [float(v) for v in rpy],
            "mount_q": [float(v) for v in al.q_mount],
            "time_offset_s": al.time_offset_s,
            "rate_agreement": _json_float(al.correlation),
            "residual_deg": _json_float(al.residual_deg),
            "samples": al.samples,
            "warning": self.warning,
            "gnss_time_shift_s": self.gnss_shift_s,
            "gnss_timing_sigma_s": self.gnss_timing_sigma_s,
        }

    def apply(self, flight: Flight) -> Flight:
        """``flight`` with its reference aligned (unchanged without an alignment)."""
        return flight if self.alignment is None else apply_alignment(flight, self.alignment)

    def run_flight(self, flight: Flight) -> Flight:
        """The flight the filters after the first run on: its GNSS moved onto the IMU's
        clock when it is declared on the reference's
        (:func:`~windahrs.experiments.align.align_gnss_clock`); ``flight`` itself otherwise,
        and without an alignment."""
        return flight if self.alignment is None else align_gnss_clock(flight, self.alignment)


def align_reference(flight: Flight, fitted_on: tuple[str, Estimate], *, fallback: bool = False) -> AlignmentOutcome:
    """Fit the flight's reference to the estimate ``fitted_on = (spec, Estimate)`` (put the
    most accurate filter first: the fit also absorbs its constant errors).

    Without a reference (a simulation's truth, or nothing): no alignment, ``skipped`` says
    why. A failed fit raises :class:`AlignmentError`, or with ``fallback`` returns it as
    ``failed``.
    """
    if flight.reference is None:
        return AlignmentOutcome(skipped=nothing_to_align(flight))
    spec, est = fitted_on
    try:
        al = estimate_alignment(est, flight)
    except ValueError as exc:
        if not fallback:
            raise AlignmentError(str(exc)) from None
        return AlignmentOutcome(failed=str(exc))
    shift = sigma = None
    if flight.gnss is not None and flight.meta.get(GNSS_CLOCK_KEY) == GNSS_ON_REFERENCE_CLOCK:
        moved = align_gnss_clock(flight, al).meta
        shift = float(moved["gnss.time_shift_s"])
        sigma = float(moved.get("gnss.timing_sigma_s", 0.0))
    return AlignmentOutcome(
        alignment=al, aligned_on=spec, warning=alignment_warning(al), gnss_shift_s=shift, gnss_timing_sigma_s=sigma
    )


# ---------------------------------------------------------------------------------------
# compare


@dataclass(frozen=True)
class CompareResult:
    """Scores of several estimators on one flight (what ``windahrs compare`` prints).

    rows: one :class:`~windahrs.metrics.Score` per filter, in order; estimates: the
    (spec, Estimate) they score; alignment: what ``align`` did. ``str(result)`` is the
    command's output (the alignment line when aligned, then :meth:`table`);
    :meth:`as_json` is its ``--json`` output.
    """

    rows: tuple[Score, ...]
    estimates: tuple[tuple[str, Estimate], ...]
    alignment: AlignmentOutcome = AlignmentOutcome()
    #: the reference has no heading datum (mocap), or the recording no magnetometer: each
    #: filter's constant heading offset was removed before scoring
    #: (:func:`windahrs.metrics.reference_of`, :func:`~windahrs.metrics.attitude_errors`)
    heading_free: bool = False

    @property
    def aligned(self) -> bool:
        return self.alignment.alignment is not None

    def table(self) -> str:
        """The RMSE table in degrees: per axis from sample 50 and over the second half,
        tilt and total."""
        rows = self.rows
        free = "; a constant heading offset removed per filter (no heading datum shared with the reference)"
        lines = [f"RMSE in deg against {rows[0].reference}{' (aligned)' if self.aligned else ''}"
                 f"{free if self.heading_free else ''}; from sample 50 | second half"]
        axes = f"{'roll':>8}{'pitch':>8}{'yaw':>8} |"
        width = max(14, *(len(r.filter) + 1 for r in rows))
        lines.append(f"{'filter':<{width}}{axes}{axes}{'tilt':>8}{'total':>8}")
        empty = False
        for r in rows:
            a, b = r.rmse_from50_deg, r.rmse_steady_deg
            cells = [*a, *b, r.rmse_tilt_deg, r.rmse_total_deg]
            empty |= not all(math.isfinite(v) for v in cells)
            c = [f"{v:8.3f}" if math.isfinite(v) else f"{'-':>8}" for v in cells]
            lines.append(f"{r.filter:<{width}}{''.join(c[:3])} |{''.join(c[3:6])} |{''.join(c[6:])}")
        if empty:
            lines.append("(-: no reference sample scored in that span)")
        return "\n".join(lines)

    def as_json(self) -> list[dict[str, object]]:
        """One dict per filter: its score (null where a span has no scored reference
        sample: JSON has no NaN), ``ran`` and ``sensors`` for an ``auto`` spec (the estimator
        it chose and the streams it used) and, when aligned, the alignment's fields."""
        extra = self.alignment.fields()
        out = []
        for r, (_, est) in zip(self.rows, self.estimates, strict=True):
            ran = est.meta.get("auto")
            chosen = {} if ran is None else {"ran": str(ran), "sensors": str(est.meta.get("sensors", ""))}
            out.append({**_json_score(r.as_dict()), **chosen, **extra})
        return out

    def scale_lines(self) -> list[str]:
        """One line per filter that estimated the airspeed scale on line (``airspeed_scale``)."""
        return [airspeed_scale_line(spec, est) for spec, est in self.estimates if est.airspeed_scale is not None]

    def __str__(self) -> str:
        text = self.alignment.text
        body = "\n".join([self.table(), *self.scale_lines()])
        return body if text is None else f"{text}\n{body}"


def airspeed_scale_line(name: str, est: Estimate) -> str:
    """``name: airspeed scale ...``: the last estimate of the pitot's scale (true / measured
    airspeed), its standard deviation and the share of airspeed samples its gate accepted."""
    a = est.airspeed_scale
    if a is None or not len(a):
        return f"{name}: airspeed scale not estimated"
    return (f"{name}: airspeed scale (true / measured) {a[-1, 1]:.4f} +- {a[-1, 2]:.4f} at t = {a[-1, 0]:.1f} s "
            f"({100 * float(np.mean(a[:, 4])):.0f} % of {len(a)} airspeed samples accepted)")


def compare(
    flight: Flight,
    specs: str | Sequence[str | Estimator],
    *,
    align: bool = False,
    progress: Progress | None = None,
) -> CompareResult:
    """Run every estimator on ``flight`` and score each against its truth or reference.

    specs: registry specs (a list, or one comma-separated string) or built estimators
    (labelled by their ``label``). align: first fit one mount rotation and clock offset
    between the reference and the FIRST filter's estimate and score every filter against
    that aligned reference (a simulation's truth is used as is); a GNSS stream declared on
    the reference's clock is moved by that offset before the other filters run
    (:meth:`AlignmentOutcome.run_flight`; the first runs on the flight as logged).
    ``progress(done, total)`` after each filter.

    Raises ValueError for a bad spec, a filter that cannot run on the flight, a flight
    with nothing to score against, and :class:`AlignmentError` for a failed alignment.
    """
    from windahrs.filters.registry import make_estimator

    items = [s.strip() for s in specs.split(",") if s.strip()] if isinstance(specs, str) else list(specs)
    if not items:
        raise ValueError("specs: expected at least one filter spec, found none")
    pairs = [(s, make_estimator(s)) if isinstance(s, str) else (s.label, s) for s in items]
    if not align:
        results, _ = run_estimators(flight, pairs, progress=progress)
        outcome = AlignmentOutcome()
    else:
        step = None if progress is None else (lambda done, _: progress(done, len(pairs)))
        results, _ = run_estimators(flight, pairs[:1], progress=step)
        outcome = align_reference(flight, results[0])
        step = None if progress is None else (lambda done, _: progress(done + 1, len(pairs)))
        rest, _ = run_estimators(outcome.run_flight(flight), pairs[1:], progress=step)
        results += rest
    scored = outcome.apply(flight)
    rows = tuple(score(est, scored) for _, est in results)
    free = reference_of(scored)[3]  # (False against truth; score has raised without either)
    return CompareResult(rows=rows, estimates=tuple(results), alignment=outcome, heading_free=free)


# ---------------------------------------------------------------------------------------
# report


@dataclass(frozen=True)
class ReportRun:
    """What ``windahrs report`` puts on its page: results (spec, Estimate) of the filters
    that ran, failures (spec -> why not), notes (sentences for the page) and the alignment."""

    results: list[tuple[str, Estimate]]
    failures: dict[str, str]
    notes: tuple[str, ...]
    alignment: AlignmentOutcome

    def why_none_ran(self) -> str:
        """Why no filter ran, in one line (for the error when ``results`` is empty)."""
        return "; ".join(f"{k}: {v}" for k, v in self.failures.items()) or "; ".join(self.notes) or "none given"


def run_for_report(
    flight: Flight,
    selection: Selection,
    *,
    align: bool = False,
    progress: Progress | None = None,
    on_failure: Callable[[str, str], None] | None = None,
) -> ReportRun:
    """Run a selection on ``flight`` for the report: defaults the flight lacks a sensor for
    are left out (noted), a filter that fails is recorded and the others go on
    (``on_failure(spec, why)`` is called as it happens); what ``auto`` ran is noted. With
    ``align`` and at least one result, the reference is aligned to the first result (and a
    GNSS on the reference's clock moved for the filters after it,
    :meth:`AlignmentOutcome.run_flight`); a failed fit is noted and the scores are against
    the reference as logged."""
    from windahrs.filters.auto import describe_choice

    sel = selection.for_flight(flight)
    pairs = list(sel.estimators.items())
    results: list[tuple[str, Estimate]] = []
    failed: dict[str, str] = {}
    outcome = AlignmentOutcome()
    for i, (spec, est) in enumerate(pairs):
        # With align, the filters after the first that ran see the GNSS the alignment moved.
        run_on = outcome.run_flight(flight)
        try:
            results.append((spec, est.run(run_on)))
        except ValueError as exc:
            failed[spec] = str(exc)
        if align and len(results) == 1 and spec == results[0][0]:
            outcome = align_reference(flight, results[0], fallback=True)
        if progress is not None:
            progress(i + 1, len(pairs))
    if on_failure is not None:
        for spec, why in failed.items():
            on_failure(spec, why)
    failures = {**sel.failures, **failed}
    notes = list(sel.notes)
    notes += [f"{line}." for line in (describe_choice(est) for _, est in results) if line is not None]
    if align and results:
        if outcome.skipped:
            notes.append(f"--align: {outcome.skipped}.")
        elif outcome.failed:
            notes.append(f"--align: no alignment ({outcome.failed}); scores are against the reference as logged.")
    return ReportRun(results, failures, tuple(notes), outcome)
