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
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from windahrs.estimate import Estimate
from windahrs.filters.registry import make_estimator
from windahrs.flight import Flight
from windahrs.metrics import _interp_ref, reference_of
from windahrs.rotation import quat_conj, quat_exp, quat_mul

__all__ = [
    "METRICS",
    "BenchResult",
    "BroadErrors",
    "TrialScore",
    "bench_data",
    "broad_errors",
    "discover_trials",
    "split_error",
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
    scored samples, and the run time of the estimator in s."""

    trial: str
    filter: str
    total_deg: float
    inclination_deg: float
    heading_deg: float
    samples: int
    seconds: float

    def as_dict(self) -> dict[str, Any]:
        """The JSON row: trial, filter and the three RMSE figures."""
        return {
            "trial": self.trial,
            "filter": self.filter,
            "total_deg": self.total_deg,
            "inclination_deg": self.inclination_deg,
            "heading_deg": self.heading_deg,
        }


@dataclass(frozen=True)
class BenchResult:
    """Scores of every filter on every trial, in the order given (trials outer); trial_names
    (file stems) and filters (specs) in that order."""

    scores: tuple[TrialScore, ...]
    trial_names: tuple[str, ...]
    filters: tuple[str, ...]

    def median(self) -> dict[str, dict[str, float]]:
        """Per filter, the median over trials of each RMSE figure (deg)."""
        out: dict[str, dict[str, float]] = {}
        for f in self.filters:
            rows = [s for s in self.scores if s.filter == f]
            out[f] = {m: float(np.median([getattr(s, m) for s in rows])) for m in METRICS}
        return out

    def as_json(self) -> dict[str, Any]:
        """A JSON-ready dict: ``{"trials": [{"trial", "filter", "total_deg",
        "inclination_deg", "heading_deg"}, ...], "median": {FILTER: {"total_deg",
        "inclination_deg", "heading_deg"}}}`` (serialise with ``json.dumps``)."""
        return {"trials": [s.as_dict() for s in self.scores], "median": self.median()}

    def table(self) -> str:
        """Text tables: one per trial (RMSE in deg, scored samples, run time), then the
        median over trials."""
        width = max([len("filter"), *(len(f) for f in self.filters)]) + 2
        head = f"{'filter':<{width}}{'total':>9}{'incl':>9}{'heading':>9}"
        lines: list[str] = []
        for trial in self.trial_names:
            rows = [s for s in self.scores if s.trial == trial]
            lines += [f"{trial}: RMSE in deg", f"{head}{'samples':>9}{'s':>8}"]
            for s in rows:
                lines.append(
                    f"{s.filter:<{width}}{s.total_deg:9.3f}{s.inclination_deg:9.3f}{s.heading_deg:9.3f}"
                    f"{s.samples:9d}{s.seconds:8.2f}"
                )
            lines.append("")
        lines += [f"median over {len(self.trial_names)} trials: RMSE in deg", head]
        for f, m in self.median().items():
            lines.append(f"{f:<{width}}{m['total_deg']:9.3f}{m['inclination_deg']:9.3f}{m['heading_deg']:9.3f}")
        return "\n".join(lines)


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


def _rms_deg(x: F64) -> float:
    return math.degrees(float(np.sqrt(np.mean(np.square(x)))))


def bench_data(
    paths: Sequence[str | os.PathLike[str]],
    specs: Sequence[str],
    *,
    progress: Callable[[int, int], None] | None = None,
) -> BenchResult:
    """Run every estimator spec (``NAME`` or ``NAME:field=value:...``, see
    :func:`~windahrs.filters.registry.make_estimator`) over every recording in ``paths``
    (read with :func:`windahrs.io.read_flight`) and score each with :func:`broad_errors`.

    Every spec is built and every file read and checked against every estimator's
    required sensors before any estimator runs, so a bad spec, file or missing sensor
    fails at once (ValueError, LogFormatError, MissingSensorError). ``progress(done,
    total)`` is called after each run. The trial's name is the file stem (the directory
    name for a directory recording).
    """
    from windahrs.io import read_flight

    if not paths:
        raise ValueError("paths: expected at least one recording, found none")
    if not specs:
        raise ValueError("specs: expected at least one estimator spec, found none")
    if len(set(specs)) != len(specs):
        raise ValueError(f"specs: expected distinct specs, found duplicates in {list(specs)}")
    estimators = [make_estimator(s) for s in specs]
    flights: list[tuple[str, Flight]] = []
    for p in paths:
        path = Path(p)
        flight = read_flight(path)
        reference_of(flight)  # raises when there is nothing to score against
        for est in estimators:
            est.check(flight)
        flights.append((path.stem, flight))
    names = [n for n, _ in flights]
    if len(set(names)) != len(names):
        raise ValueError(f"paths: expected distinct trial names (file stems), found {names}")
    scores: list[TrialScore] = []
    done, total = 0, len(flights) * len(estimators)
    for name, flight in flights:
        for spec, est in zip(specs, estimators, strict=True):
            t0 = time.perf_counter()
            result = est.run(flight)
            seconds = time.perf_counter() - t0
            err = broad_errors(result, flight)
            scores.append(
                TrialScore(
                    trial=name,
                    filter=spec,
                    total_deg=_rms_deg(err.total),
                    inclination_deg=_rms_deg(err.inclination),
                    heading_deg=_rms_deg(err.heading),
                    samples=len(err.index),
                    seconds=seconds,
                )
            )
            done += 1
            if progress is not None:
                progress(done, total)
    return BenchResult(scores=tuple(scores), trial_names=tuple(names), filters=tuple(specs))
