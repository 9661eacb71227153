"""Benchmark on recorded data with BROAD's error metrics: every estimator on every trial,
total, inclination and heading RMSE per trial, and the median over trials per estimator.

Error metrics (Laidig et al., "BROAD: A Benchmark for Robust Inertial Orientation
Estimation", Data 6(7):72, 2021; reference code github.com/dlaidig/broad,
``example_code/broad_utils.py``: ``calculateErrorQuatEarth``, ``calculateTotalError``,
``calculateHeadingError``, ``calculateInclinationError``): the error quaternion is taken
in the navigation frame,

    e = q_est * q_ref^-1                      (both q_nb, body to nav)

and split into a rotation about the nav vertical (heading) and one about a horizontal
axis (inclination):

    total       = 2 acos |e_w|
    heading     = 2 atan(|e_z| / |e_w|)
    inclination = 2 acos sqrt(e_w^2 + e_z^2)

The inclination is the angle between the estimated and the reference vertical axes (equal
to :attr:`windahrs.metrics.AttitudeErrors.tilt`); the heading is the twist of ``e`` about
the vertical, the same whether the twist is taken before or after the swing. In NED the
vertical is the z axis, as in BROAD's ENU, so the formulas carry over unchanged.

Heading-free references (BROAD's motion capture: its heading datum is arbitrary) are first
rotated about the vertical by the constant offset ``psi`` that best aligns them: the
circular mean of the signed twist ``2 atan2(e_z, e_w)``. Rotating the reference by
``Rz(psi)`` turns ``e`` into ``e * Rz(-psi)``, which subtracts ``psi`` from every signed
twist exactly and leaves the inclination unchanged, so no Euler angles (and no gimbal
lock) are involved. BROAD's own script scores without an offset because its estimators
are referenced to the same magnetic north as its motion capture; ours are not (the site's
field is unknown), hence the offset, as in the VQF paper's evaluation.

Samples are scored where the reference is finite and inside its mask (BROAD: the
``movement`` phases), as :func:`windahrs.metrics.reference_of` defines.

Any recording the readers know is scored the same way, against its truth (simulation) or
reference (mocap, an autopilot's estimate): :func:`discover_flights` walks a folder for them,
:func:`bench_data` reads and runs them one at a time, listing what it cannot read as skipped
and a filter that cannot run on a flight as that row's failure, and with ``align`` fits one
mount rotation and clock offset per flight on the first filter
(:func:`windahrs.experiments.compare.align_reference`, as ``compare --align``).
"""

from __future__ import annotations

import math
import os
import re
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from windahrs.estimate import Estimate
from windahrs.experiments.align import unreliable_reason
from windahrs.experiments.compare import AlignmentOutcome, align_reference, nothing_to_align, run_estimators
from windahrs.filters.registry import make_estimator
from windahrs.flight import Flight
from windahrs.metrics import _interp_ref, reference_of
from windahrs.rotation import quat_conj, quat_exp, quat_mul

__all__ = [
    "FLIGHT_SUFFIXES",
    "METRICS",
    "BenchResult",
    "BroadErrors",
    "Discovery",
    "Skipped",
    "TrialScore",
    "aligned_recordings",
    "bench_data",
    "broad_errors",
    "discover_flights",
    "discover_trials",
    "split_error",
    "trial_names",
]

F64 = NDArray[np.float64]

#: The three RMSE figures per trial and filter, in the order of the tables.
METRICS: tuple[str, ...] = ("total_deg", "inclination_deg", "heading_deg")
_TRIAL_SUFFIXES = (".hdf5", ".h5")


def split_error(e_n: F64) -> tuple[F64, F64, F64]:
    """Split nav-frame error quaternions ``e = q_est * q_ref^-1`` (..., 4) into (total,
    heading, inclination) angles in rad, each (...,), all >= 0 (BROAD's definitions)."""
    e = np.asarray(e_n, dtype=np.float64)
    w = np.abs(e[..., 0])
    z = np.abs(e[..., 3])
    total = 2.0 * np.arccos(np.clip(w, 0.0, 1.0))
    heading = 2.0 * np.arctan2(z, w)
    inclination = 2.0 * np.arccos(np.clip(np.hypot(w, z), 0.0, 1.0))
    return total, heading, inclination


@dataclass(frozen=True)
class BroadErrors:
    """Errors on the reference's valid samples. t (M,) s; total, heading, inclination
    (M,) rad; index (M,) the estimate's rows used; heading_offset rad: the constant
    rotation about the vertical removed from the reference (0 when not removed)."""

    t: F64
    total: F64
    heading: F64
    inclination: F64
    index: NDArray[np.int64]
    heading_offset: float


def broad_errors(est: Estimate, flight: Flight, *, remove_heading: bool | None = None) -> BroadErrors:
    """BROAD's total / heading / inclination errors of ``est`` against the flight's truth
    or reference. ``remove_heading``: remove a constant heading offset first (default:
    when the reference is heading-free). Raises ValueError when no sample can be scored."""
    t_ref, q_ref_all, _, free = reference_of(flight)
    q_ref, ok = _interp_ref(t_ref, q_ref_all, est.t)
    ok &= np.isfinite(est.q_nb).all(axis=1)
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        if not np.isfinite(q_ref_all).all(axis=1).any():
            raise ValueError("reference: no valid sample (every one masked or NaN, e.g. a BROAD trial whose "
                             "movement mask selects none)")
        raise ValueError("reference: no valid sample overlaps the estimate in time")
    e = quat_mul(est.q_nb[idx], quat_conj(q_ref[idx]))
    e = e / np.linalg.norm(e, axis=1, keepdims=True)
    e = e * np.where(e[:, :1] < 0, -1.0, 1.0)
    psi = 0.0
    if remove_heading if remove_heading is not None else free:
        twist = 2.0 * np.arctan2(e[:, 3], e[:, 0])
        psi = float(np.arctan2(np.mean(np.sin(twist)), np.mean(np.cos(twist))))
        e = quat_mul(e, quat_exp(np.array([0.0, 0.0, -psi])))
    total, heading, inclination = split_error(e)
    return BroadErrors(
        t=est.t[idx], total=total, heading=heading, inclination=inclination, index=idx, heading_offset=psi
    )


@dataclass(frozen=True)
class TrialScore:
    """One filter on one trial: RMSE in degrees over the scored samples, the number of
    scored samples, and the run time of the estimator in s. ``error``: why the filter did
    not run or could not be scored on this trial (the figures are then NaN)."""

    trial: str
    filter: str
    total_deg: float
    inclination_deg: float
    heading_deg: float
    samples: int
    seconds: float
    error: str | None = None
    #: the estimator an ``auto`` spec ran (``Estimate.meta["auto"]``), None for the others
    ran: str | None = None

    @property
    def ok(self) -> bool:
        """The filter ran and was scored."""
        return self.error is None

    def as_dict(self) -> dict[str, Any]:
        """The JSON row: trial, filter, the three RMSE figures, ``samples`` (scored) and
        ``seconds`` (run time), as the text table shows them, and ``ran`` for an ``auto``
        spec (the estimator it chose); or trial, filter and ``error`` for a filter that failed
        on the trial."""
        if self.error is not None:
            return {"trial": self.trial, "filter": self.filter, "error": self.error}
        row: dict[str, Any] = {
            "trial": self.trial,
            "filter": self.filter,
            "total_deg": self.total_deg,
            "inclination_deg": self.inclination_deg,
            "heading_deg": self.heading_deg,
            "samples": self.samples,
            "seconds": _json_float(self.seconds),
        }
        if self.ran is not None:
            row["ran"] = self.ran
        return row


def _auto_ran(est: Estimate) -> str | None:
    """The estimator an ``auto`` Estimate ran (its ``meta["auto"]``), None for the others."""
    ran = est.meta.get("auto")
    return None if ran is None else str(ran)


@dataclass(frozen=True)
class Skipped:
    """A file or directory that was not benchmarked: ``path`` and the ``reason``."""

    path: str
    reason: str

    def as_dict(self) -> dict[str, str]:
        return {"path": self.path, "reason": self.reason}


@dataclass(frozen=True)
class BenchResult:
    """Scores of every filter on every trial, in the order given (trials outer); trial_names
    and filters (specs) in that order. skipped: recordings that could not be read or scored.
    alignments: with ``align``, what became of each trial's alignment, by trial name (None
    without ``align``)."""

    scores: tuple[TrialScore, ...]
    trial_names: tuple[str, ...]
    filters: tuple[str, ...]
    skipped: tuple[Skipped, ...] = ()
    alignments: Mapping[str, AlignmentOutcome] | None = None

    def scored(self, filter_spec: str) -> list[TrialScore]:
        """The rows of ``filter_spec`` that ran and were scored."""
        return [s for s in self.scores if s.filter == filter_spec and s.ok]

    def median(self) -> dict[str, dict[str, float]]:
        """Per filter, the median over the trials it ran on of each RMSE figure (deg; NaN
        when it ran on none)."""
        out: dict[str, dict[str, float]] = {}
        for f in self.filters:
            rows = self.scored(f)
            out[f] = {m: float(np.median([getattr(s, m) for s in rows])) if rows else math.nan for m in METRICS}
        return out

    def as_json(self) -> dict[str, Any]:
        """A JSON-ready dict: ``{"trials": [{"trial", "filter", "total_deg",
        "inclination_deg", "heading_deg", "samples", "seconds"} or {"trial", "filter",
        "error"}, ...], "median":
        {FILTER: {"total_deg", "inclination_deg", "heading_deg"}}}`` (a median is None for a
        filter that ran on no trial), with ``"skipped": [{"path", "reason"}]`` when a
        recording was skipped and ``"alignment": {TRIAL: {...}}`` with ``align``: the fields
        of :meth:`AlignmentOutcome.fields` (``aligned_on``, ``mount_deg``,
        ``mount_rpy_deg``, ``mount_q``, ``time_offset_s``, ``rate_agreement``,
        ``residual_deg``, ``samples``, ``warning``, ``gnss_time_shift_s``,
        ``gnss_timing_sigma_s``), or ``{"skipped": why}`` /
        ``{"failed": why}``. Serialise with ``json.dumps``."""
        median = {f: {k: _json_float(v) for k, v in m.items()} for f, m in self.median().items()}
        out: dict[str, Any] = {"trials": [s.as_dict() for s in self.scores], "median": median}
        if self.skipped:
            out["skipped"] = [s.as_dict() for s in self.skipped]
        if self.alignments is not None:
            out["alignment"] = {name: _alignment_json(a) for name, a in self.alignments.items()}
        return out

    def table(self) -> str:
        """Text tables: one per trial (RMSE in deg, scored samples, run time; with
        ``align``, the alignment line first), then the median over trials and the skipped
        recordings."""
        width = max([len("filter"), *(len(f) for f in self.filters)]) + 2
        head = f"{'filter':<{width}}{'total':>9}{'incl':>9}{'heading':>9}"
        lines: list[str] = []
        for trial in self.trial_names:
            rows = [s for s in self.scores if s.trial == trial]
            lines.append(f"{trial}: RMSE in deg")
            if self.alignments is not None and trial in self.alignments:
                lines.append(_alignment_line(self.alignments[trial]))
            lines.append(f"{head}{'samples':>9}{'s':>8}")
            for s in rows:
                if not s.ok:
                    lines.append(f"{s.filter:<{width}}  failed: {s.error}")
                    continue
                lines.append(
                    f"{s.filter:<{width}}{s.total_deg:9.3f}{s.inclination_deg:9.3f}{s.heading_deg:9.3f}"
                    f"{s.samples:9d}{s.seconds:8.2f}"
                )
            lines.append("")
        lines += [f"median over {len(self.trial_names)} trials: RMSE in deg", head]
        partial: list[str] = []
        for f, m in self.median().items():
            n = len(self.scored(f))
            if n == 0:
                lines.append(f"{f:<{width}}{'-':>9}{'-':>9}{'-':>9}")
            else:
                lines.append(f"{f:<{width}}{m['total_deg']:9.3f}{m['inclination_deg']:9.3f}{m['heading_deg']:9.3f}")
            if n < len(self.trial_names):
                partial.append(f"{f} on {n}")
        if partial:
            lines.append(f"(over the trials each filter ran on: {', '.join(partial)} of {len(self.trial_names)})")
        if self.skipped:
            lines += ["", f"skipped {len(self.skipped)}:"]
            lines += [f"  {s.path}: {s.reason}" for s in self.skipped]
        return "\n".join(lines)


def _json_float(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _alignment_json(outcome: AlignmentOutcome) -> dict[str, Any]:
    if outcome.alignment is not None:
        return outcome.fields()
    if outcome.skipped is not None:
        return {"skipped": outcome.skipped}
    return {"failed": outcome.failed}


def _alignment_line(outcome: AlignmentOutcome) -> str:
    al = outcome.alignment
    if outcome.text is not None and al is not None:
        why = unreliable_reason(al) if outcome.warning else None
        return outcome.text if why is None else f"{outcome.text} (unreliable: {why})"
    if outcome.skipped is not None:
        return f"not aligned: {outcome.skipped}"
    return f"not aligned ({outcome.failed}): scored against the reference as logged"


def discover_trials(directory: str | os.PathLike[str]) -> list[Path]:
    """BROAD-style trial files (``*.hdf5``, ``*.h5``) directly in ``directory``, sorted by
    name. Raises FileNotFoundError naming the directory when it is missing or holds none."""
    d = Path(directory)
    if not d.is_dir():
        raise FileNotFoundError(f"{d}: no such directory (expected BROAD trials *.hdf5, *.h5)")
    found = sorted(p for p in d.iterdir() if p.is_file() and p.suffix.lower() in _TRIAL_SUFFIXES)
    if not found:
        raise FileNotFoundError(f"{d}: no BROAD trials (*.hdf5, *.h5) in this directory")
    return found


#: File extensions of the readers' formats: such a file that cannot be read is listed as
#: skipped; other files are taken only when their contents are a known format.
FLIGHT_SUFFIXES: tuple[str, ...] = (".ulg", ".bin", ".log", ".hdf5", ".h5")


@dataclass(frozen=True)
class Discovery:
    """What :func:`discover_flights` found: the recordings the readers recognise, in
    walking order, and the files with a log extension that they do not."""

    flights: tuple[Path, ...]
    skipped: tuple[Skipped, ...] = ()


def _natural_key(p: Path) -> list[Any]:
    """Sort key putting path_6 before path_10."""
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", p.name)]


def discover_flights(directory: str | os.PathLike[str]) -> Discovery:
    """Every recording the readers know under ``directory``, recursively
    (:func:`windahrs.io.detect_format`): BROAD ``.hdf5`` trials, windahrs ``.h5`` flights,
    ``.ulg``, ``.bin``/``.log`` DataFlash, and ALFA, generic-CSV and ANSFL directories. A
    directory that is itself a recording is not descended into; names starting with a dot
    are passed over; entries are walked in natural order (``path_6`` before ``path_10``).

    A file with a log extension (:data:`FLIGHT_SUFFIXES`) that is no known format is
    listed in ``skipped`` with the reason; other files are taken only when their first
    bytes are a known format (ULog, DataFlash, HDF5 flight) and passed over otherwise. A
    directory of CSV files that is no recording and holds none is listed in ``skipped``
    with the reason (an export in a layout the readers do not know).
    ``directory`` may itself be one recording. Raises FileNotFoundError when it does not
    exist or holds nothing recognised.
    """
    from windahrs.io import LogFormatError, detect_format

    root = Path(directory)
    if not root.exists():
        raise FileNotFoundError(f"{root}: no such file or directory")
    if root.is_file():
        return Discovery((root,))
    flights: list[Path] = []
    skipped: list[Skipped] = []
    seen: set[Path] = set()

    def walk(d: Path, why: str | None = None) -> None:
        """Take the recordings under d; d itself is no recording (``why``: the reason)."""
        real = d.resolve()
        if real in seen:  # a symbolic link back up the tree
            return
        seen.add(real)
        try:
            entries = sorted(d.iterdir(), key=_natural_key)
        except OSError as exc:
            skipped.append(Skipped(str(d), f"cannot list the directory: {exc.strerror or exc}"))
            return
        before = len(flights) + len(skipped)
        for p in entries:
            if p.name.startswith("."):
                continue
            if p.is_dir():
                try:
                    detect_format(p)
                except LogFormatError as exc:
                    walk(p, exc.problem)
                else:
                    flights.append(p)
                continue
            try:
                detect_format(p)
            except LogFormatError as exc:
                if p.suffix.lower() in FLIGHT_SUFFIXES:
                    skipped.append(Skipped(str(p), exc.problem))
            except OSError as exc:
                if p.suffix.lower() in FLIGHT_SUFFIXES:
                    skipped.append(Skipped(str(p), f"cannot read: {exc.strerror or exc}"))
            else:
                flights.append(p)
        # a directory of CSV files that is no recording and holds none: said, not passed
        # over (an export whose layout the readers do not know would vanish from the table)
        if why is not None and len(flights) + len(skipped) == before and any(
            p.suffix.lower() == ".csv" for p in entries if not p.name.startswith(".")
        ):
            skipped.append(Skipped(str(d), why))

    try:
        detect_format(root)
    except LogFormatError:
        walk(root)
    else:
        return Discovery((root,))
    if not flights and not skipped:
        raise FileNotFoundError(
            f"{root}: no recording the readers know under this directory (BROAD .hdf5, windahrs .h5, .ulg, "
            ".bin/.log, or an ALFA, generic-CSV or ANSFL directory)"
        )
    return Discovery(tuple(flights), tuple(skipped))


def aligned_recordings(
    directory: str | os.PathLike[str], align_on: str = "vqf"
) -> Iterator[tuple[Path, Flight, Flight]]:
    """Each recording under ``directory`` (:func:`discover_flights`) that has a reference or
    truth: its path, the flight to run estimators on, and the flight to score against, as
    ``compare --align`` and ``bench-data --align`` have them: the reference aligned (mount
    and clock) on ``align_on``'s estimate, and a GNSS stream the recording declares on the
    reference's clock moved onto the IMU's by the same fit
    (:meth:`~windahrs.experiments.compare.AlignmentOutcome.run_flight`; ANSFL's); both as
    logged when the fit fails (the benchmarks' real-data loop)."""
    from windahrs.io import read_flight

    for path in discover_flights(directory).flights:
        flight = read_flight(path)
        if flight.reference is None and flight.truth is None:
            continue
        try:
            outcome = align_reference(flight, (align_on, make_estimator(align_on).run(flight)))
        except ValueError:
            yield path, flight, flight
            continue
        yield path, outcome.run_flight(flight), outcome.apply(flight)


def trial_names(paths: Sequence[str | os.PathLike[str]]) -> list[str]:
    """A name per recording: its file stem (directory name), or, when two stems are the
    same (``Horizontal/path_10``, ``Vertical/path_10``), its path below the recordings'
    common folder without the extension."""
    ps = [Path(p) for p in paths]
    stems = [p.name if p.is_dir() else p.stem for p in ps]
    if len(set(stems)) == len(stems):
        return stems
    common = Path(os.path.commonpath([p.absolute() for p in ps]))
    rel = [p.absolute().relative_to(common) for p in ps]
    names = [r.as_posix() if p.is_dir() else r.with_suffix("").as_posix() for p, r in zip(ps, rel, strict=True)]
    if len(set(names)) != len(names):
        raise ValueError(f"paths: expected distinct recordings, found repeats in {[str(p) for p in ps]}")
    return names


def _rms_deg(x: F64) -> float:
    return math.degrees(float(np.sqrt(np.mean(np.square(x)))))


def _failed(trial: str, spec: str, why: str, seconds: float = math.nan) -> TrialScore:
    return TrialScore(trial, spec, math.nan, math.nan, math.nan, 0, seconds, error=why)


@contextmanager
def _naming_warnings(recording: str) -> Iterator[None]:
    """Re-issue the warnings of the block (an estimator's resets, rejections, alerts) with
    the recording's name in front: over a folder of recordings, "mekf: 46 IMU samples not
    propagated" alone does not say which one. Issued when the block ends, also when it
    raises."""
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield
    finally:  # (once the recording has stopped, or they would be caught again)
        for w in caught:
            warnings.warn_explicit(f"{recording}: {w.message}", w.category, w.filename, w.lineno)


def bench_data(
    paths: Sequence[str | os.PathLike[str]],
    specs: Sequence[str],
    *,
    align: bool = False,
    skipped: Sequence[Skipped] = (),
    progress: Callable[[int, int], None] | None = None,
    on_read: Callable[[Path, Flight], None] | None = None,
    prepare: Callable[[Flight], Flight] | None = None,
) -> BenchResult:
    """Run every estimator spec (``NAME`` or ``NAME:field=value:...``, see
    :func:`~windahrs.filters.registry.make_estimator`) over every recording in ``paths``
    (read with :func:`windahrs.io.read_flight`) and score each with :func:`broad_errors`
    against the flight's truth or reference (total, inclination = tilt, heading; a constant
    heading offset removed for heading-free references).

    Every spec is built before any file is read, so a bad spec fails at once (ValueError).
    A recording that cannot be read, or has nothing to score against, is listed in
    ``skipped`` with the reason (``skipped`` given here, e.g. by :func:`discover_flights`,
    is listed first). A filter that cannot run on a flight (a missing sensor, a failed
    initialisation: a ValueError) or cannot be scored fails that trial's row only, with the
    reason. Flights are read and run one at a time. What the estimators warn of (resets,
    rejections, alerts) is warned again with the recording's name in front, ``"path_7:
    mekf: ..."``.

    align: per flight, fit one mount rotation and clock offset between the reference and
    the FIRST spec's estimate (:func:`~windahrs.experiments.compare.align_reference`, as
    ``compare --align``) and score every filter against that aligned reference. A fit that
    fails, or a first filter that did not run, leaves that flight's reference as logged,
    said so in ``alignments``. A simulation's truth is never aligned. A flight declaring its
    GNSS on the reference's clock (``meta["gnss.clock"] = "reference"``) has its GNSS moved
    by the fitted offset, and its timing uncertainty lowered to the fit's, before the other
    filters run (:meth:`~windahrs.experiments.compare.AlignmentOutcome.run_flight`; the
    first runs on the flight as logged).

    ``progress(done, total)`` is called after each filter run (and per filter of a skipped
    recording); ``on_read(path, flight)`` after each recording is read, before its filters
    run (the command line says there what the reader repaired and warns of a low-rate IMU,
    as for one flight). ``prepare(flight)``, when given, is applied to each recording as
    soon as it is read and its result used instead (the command line's ``--declination``,
    :func:`windahrs.flight.with_declination`); a ValueError from it skips that recording
    with the reason, as a read that fails does. Trial names are :func:`trial_names`.
    """
    from windahrs.io import read_flight

    if not paths:
        raise ValueError("paths: expected at least one recording, found none")
    if not specs:
        raise ValueError("specs: expected at least one estimator spec, found none")
    if len(set(specs)) != len(specs):
        raise ValueError(f"specs: expected distinct specs, found duplicates in {list(specs)}")
    estimators = [make_estimator(s) for s in specs]
    names = trial_names(paths)
    skips = list(skipped)
    scores: list[TrialScore] = []
    scored_names: list[str] = []
    alignments: dict[str, AlignmentOutcome] = {}
    done, total = 0, len(paths) * len(estimators)
    for name, p in zip(names, paths, strict=True):
        try:
            flight = read_flight(Path(p))
            if prepare is not None:
                flight = prepare(flight)
            reference_of(flight)  # raises when there is nothing to score against
        except (ValueError, OSError, ImportError) as exc:
            skips.append(Skipped(str(p), _reason(exc, p)))
            done += len(estimators)
            if progress is not None:
                progress(done, total)
            continue
        if on_read is not None:
            on_read(Path(p), flight)
        runs: list[tuple[str, Estimate | str, float]] = []
        outcome = AlignmentOutcome()
        for k, (spec, est) in enumerate(zip(specs, estimators, strict=True)):
            t0 = time.perf_counter()
            # The filters after the first run on the GNSS the alignment moved (if any).
            with _naming_warnings(name):
                results, failures = run_estimators(outcome.run_flight(flight), [(spec, est)], keep_going=True)
            seconds = time.perf_counter() - t0
            runs.append((spec, results[0][1] if results else failures[spec], seconds))
            done += 1
            if progress is not None:
                progress(done, total)
            if align and k == 0:
                outcome = _first_alignment(flight, spec, runs[0][1])
                alignments[name] = outcome
        scored = outcome.apply(flight)
        for spec, result, seconds in runs:
            if not isinstance(result, Estimate):
                scores.append(_failed(name, spec, result))
                continue
            try:
                err = broad_errors(result, scored)
            except ValueError as exc:
                scores.append(_failed(name, spec, f"not scored: {exc}", seconds))
                continue
            scores.append(
                TrialScore(
                    trial=name,
                    filter=spec,
                    total_deg=_rms_deg(err.total),
                    inclination_deg=_rms_deg(err.inclination),
                    heading_deg=_rms_deg(err.heading),
                    samples=len(err.index),
                    seconds=seconds,
                    ran=_auto_ran(result),
                )
            )
        scored_names.append(name)
    return BenchResult(
        scores=tuple(scores),
        trial_names=tuple(scored_names),
        filters=tuple(specs),
        skipped=tuple(skips),
        alignments=alignments if align else None,
    )


def _first_alignment(flight: Flight, spec: str, first: Estimate | str) -> AlignmentOutcome:
    """The alignment on the first filter's result, or why there is none."""
    if isinstance(first, Estimate):
        return align_reference(flight, (spec, first), fallback=True)
    if flight.reference is None:
        return AlignmentOutcome(skipped=nothing_to_align(flight))
    return AlignmentOutcome(failed=f"the first filter, {spec}, did not run")


def _reason(exc: BaseException, path: str | os.PathLike[str]) -> str:
    """Why a recording could not be benchmarked, without the path the caller shows anyway
    (a file inside a recording's directory keeps its own name)."""
    if isinstance(exc, ImportError):
        return f"needs a package that is not installed: {exc}"
    return str(exc).removeprefix(f"{os.fspath(path)}: ")
