"""The mean wind of a flight from its own GNSS velocity and airspeed: the wind triangle.

A pitot measures the speed of the air past the vehicle, GNSS the vehicle's velocity over
the ground; their difference is the wind: ``|v_gnss - w| = k * airspeed`` at every sample
where both exist (SPEC 3.4.4: the airspeed magnitude does not depend on the attitude, so
the fit needs none). :func:`fit_wind` solves it for a constant wind ``w`` (a horizontal
2-vector with ``w_d = 0`` by default, as PX4 EKF2's and ArduPilot EKF3's wind states; or a
3-vector) and the pitot scale ``k`` (ArduPilot's ARSPD_RATIO error, or the EAS-to-TAS
factor of a log whose airspeed is equivalent airspeed) by robust least squares
(``scipy.optimize.least_squares``, soft-L1 loss: gusts and turns are outliers of a
constant-wind model, not Gaussian noise). GNSS velocity is interpolated to the air-data
times.

The along-track wind and the scale trade against each other on a straight line: only
flight on different courses separates them. The fit refuses (:class:`WindFitError`,
naming what is missing) without GNSS velocity or airspeed, with too few paired samples,
when the air-relative course covers less than :data:`MIN_HEADING_SPAN_DEG`, or when the
pitot scale comes out outside :data:`SCALE_RANGE` (a straight flight's degenerate answer).
:func:`fit_flight_wind` does it for a :class:`~windahrs.flight.Flight`;
``paper:wind=fit`` uses it (:mod:`windahrs.filters.paper`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from windahrs.estimate import Estimate
from windahrs.flight import Flight

__all__ = [
    "MAX_CONDITION", "MIN_HEADING_SPAN_DEG", "MIN_PAIRS", "SCALE_RANGE", "WIND_FIT_SCALE", "WindFit", "WindFitError",
    "describe_wind_fit", "fit_flight_wind", "fit_wind", "heading_span_deg",
]

F64 = NDArray[np.float64]

#: m/s, the soft-L1 loss's scale: residuals below it count quadratically, above it
#: linearly. PX4 EKF2_EAS_NOISE (1.4 m/s), the airspeed noise its wind estimate assumes.
WIND_FIT_SCALE = 1.4

#: deg: the least arc of air-relative course the fit accepts. On one course the along-track
#: wind and the scale are interchangeable (``|v - w|`` changes by ``-u . dw``, the airspeed
#: term by ``tas dk``, and ``u`` is constant); a quarter turn is the least that a loiter,
#: a survey leg and its turn, or any circuit gives, and over it the three functions
#: ``1, cos, sin`` of the course that the fit separates are independent.
MIN_HEADING_SPAN_DEG = 90.0

#: The fewest paired samples the fit accepts: three unknowns (four with a vertical wind)
#: need more equations than that to have a residual at all; ten gives the robust loss
#: something to reject outliers against.
MIN_PAIRS = 10

#: The pitot scales the fit accepts. A pitot reading half or twice the true airspeed is
#: off by a factor 4 in dynamic pressure: a blocked or leaking tube, not a calibration
#: (ArduPilot's ARSPD_RATIO, V^2 = ratio * dp, is adjusted within a few tens of percent; the
#: EAS-to-TAS factor is 1.29 at 5000 m, ISA). Outside them the fit has found the degenerate
#: answer of a straight flight, the wind equal to the ground velocity and k near 0
#: (measured: k 0.02 on the first 5 s of a simulated fixed wing).
SCALE_RANGE = (0.5, 2.0)

#: The largest condition number of the column-scaled Jacobian at the solution: beyond it
#: the parameters are not determined by the data (double precision keeps ~16 digits; 1e8
#: leaves 8 for the answer).
MAX_CONDITION = 1e8


class WindFitError(ValueError):
    """The flight cannot give a wind-triangle fit; the message says what is missing."""


@dataclass(frozen=True)
class WindFit:
    """A wind-triangle fit. wind_n: (3,) m/s NED, the velocity of the air (where it blows
    TO; ``wind_n[2] = 0`` for a horizontal fit). scale: k in ``|v - w| = k * airspeed``
    (the airspeed the filter should use is ``k * airspeed``). rms: m/s, RMS of the
    residuals ``|v - w| - k * airspeed``. sigma_wind_n (3,) m/s and sigma_scale: standard
    errors from the Jacobian at the solution and the residual RMS. pairs: samples used.
    heading_span_deg: arc of air-relative course covered. horizontal: w_d held at 0.
    scale_held: k was given, not fitted (sigma_scale 0)."""

    wind_n: F64
    scale: float
    rms: float
    sigma_wind_n: F64
    sigma_scale: float
    pairs: int
    heading_span_deg: float
    horizontal: bool
    scale_held: bool = False

    def text(self) -> str:
        """One line: the wind, where it comes from, the scale, the residual."""
        held = " (held)" if self.scale_held else ""
        w = self.wind_n
        speed = float(np.hypot(w[0], w[1]))
        frm = math.degrees(math.atan2(-w[1], -w[0])) % 360.0
        vert = "" if self.horizontal else f", down {w[2]:+.2f}"
        return (
            f"wind fit: north {w[0]:+.2f} east {w[1]:+.2f}{vert} m/s (from {frm:.0f} deg at {speed:.2f} m/s), "
            f"pitot scale k {self.scale:.4f}{held}; residual RMS {self.rms:.2f} m/s over {self.pairs} samples, "
            f"course span {self.heading_span_deg:.0f} deg"
        )

    def as_meta(self) -> dict[str, object]:
        """The fit as ``Estimate.meta`` entries (plain floats and lists)."""
        return {
            "wind_fit_n": [float(v) for v in self.wind_n],
            "wind_fit_scale": float(self.scale),
            "wind_fit_rms": float(self.rms),
            "wind_fit_sigma_n": [float(v) for v in self.sigma_wind_n],
            "wind_fit_sigma_scale": float(self.sigma_scale),
            "wind_fit_pairs": int(self.pairs),
            "wind_fit_heading_span_deg": float(self.heading_span_deg),
            "wind_fit_horizontal": bool(self.horizontal),
            "wind_fit_scale_held": bool(self.scale_held),
        }

    @classmethod
    def from_meta(cls, meta: Mapping[str, Any]) -> WindFit | None:
        """The fit :meth:`as_meta` wrote into ``meta``, or None when it holds none."""
        if "wind_fit_n" not in meta:
            return None
        return cls(
            wind_n=np.asarray(meta["wind_fit_n"], dtype=np.float64),
            scale=float(meta["wind_fit_scale"]),
            rms=float(meta["wind_fit_rms"]),
            sigma_wind_n=np.asarray(meta["wind_fit_sigma_n"], dtype=np.float64),
            sigma_scale=float(meta["wind_fit_sigma_scale"]),
            pairs=int(meta["wind_fit_pairs"]),
            heading_span_deg=float(meta["wind_fit_heading_span_deg"]),
            horizontal=bool(meta["wind_fit_horizontal"]),
            scale_held=bool(meta.get("wind_fit_scale_held", False)),
        )


def describe_wind_fit(estimate: Estimate) -> str | None:
    """One line giving the wind an estimator fitted for ``estimate`` (``paper:wind=fit``),
    None when it fitted none."""
    fit = WindFit.from_meta(estimate.meta)
    return None if fit is None else f"{estimate.filter}: {fit.text()}"


def heading_span_deg(course: F64) -> float:
    """The arc (deg, 0..360) covered by the angles ``course`` (rad): 360 less the largest
    gap between neighbours on the circle."""
    if len(course) == 0:
        return 0.0
    a = np.sort(np.mod(course, 2.0 * np.pi))
    gaps = np.diff(np.concatenate([a, [a[0] + 2.0 * np.pi]]))
    return float(np.degrees(2.0 * np.pi - gaps.max()))


def _linear_start(v: F64, a: F64) -> F64:
    """A start for the fit: squared, ``|v - w|^2 = k^2 a^2`` is linear in ``w``, ``c = |w|^2``
    and ``K = k^2`` (``2 v.w - c + K a^2 = |v|^2``); solved by linear least squares with
    ``c`` and ``K`` free. From no wind, a strong wind (simulated W20 = 15 m/s) converged to
    a wrong minimum 24 m/s from the truth."""
    A = np.column_stack([2.0 * v, -np.ones(len(a)), a**2])
    x = np.linalg.lstsq(A, np.sum(v**2, axis=1), rcond=None)[0]
    k = math.sqrt(x[-1]) if x[-1] > 0 else float(np.mean(np.linalg.norm(v, axis=1)) / np.mean(a))
    start: F64 = np.r_[x[: v.shape[1]], k]
    return start if np.isfinite(start).all() else np.r_[np.zeros(v.shape[1]), 1.0]


def _solve(v: F64, a: F64, scale: float | None, loss: str, f_scale: float) -> F64:
    """The robust least-squares solution: (wind..., k) with ``scale`` None, else (wind...)."""
    dims = v.shape[1]
    start = _linear_start(v, a)

    def residual(p: F64) -> F64:
        k = p[dims] if scale is None else scale
        return np.linalg.norm(v - p[:dims], axis=1) - k * a

    def jacobian(p: F64) -> F64:
        d = v - p[:dims]
        u = d / np.maximum(np.linalg.norm(d, axis=1), 1e-9)[:, None]
        return np.column_stack([-u, -a]) if scale is None else -u

    if scale is not None:
        start = start[:dims]
    sol = least_squares(residual, start, jac=jacobian, loss=loss, f_scale=f_scale, x_scale="jac")
    x: F64 = sol.x
    return x


def _air_course_span(v: F64, wind: F64) -> float:
    d = v - wind[: v.shape[1]]
    return heading_span_deg(np.arctan2(d[:, 1], d[:, 0]))


def fit_wind(
    t_gnss: F64,
    v_n: F64,
    t_air: F64,
    tas: F64,
    *,
    horizontal: bool = True,
    scale: float | None = None,
    max_gap: float = 1.0,
    loss: str = "soft_l1",
    f_scale: float = WIND_FIT_SCALE,
) -> WindFit:
    """Fit ``|v_n(t) - w| = k * tas(t)`` over the air-data times.

    t_gnss (M,) s, v_n (M, 3) m/s NED; t_air (K,) s, tas (K,) m/s. GNSS velocity is
    interpolated linearly to each air-data time inside the GNSS record whose nearest GNSS
    samples are at most ``max_gap`` s away (the paper filter's ``gnss_max_age``, 1 s);
    samples with a NaN, or a non-positive airspeed, are left out. horizontal: ``w_d = 0``
    and only v_n's north and east enter (a GNSS without vertical velocity, PX4's and
    ArduPilot's 2-D wind). scale: None fits k; a number holds it (a calibrated pitot: on
    simulated W20 = 8 m/s, 120 s flights with Dryden turbulence, seeds 0..4, k = 1 held put
    the wind 0.12 to 0.31 m/s from the flight's mean true wind, k fitted 0.22 to 0.65 m/s:
    turbulence trades against k). WindFitError when fewer than :data:`MIN_PAIRS` samples pair up,
    when the course covers less than :data:`MIN_HEADING_SPAN_DEG`, or when the solution is
    ill-conditioned.
    """
    t_gnss = np.asarray(t_gnss, dtype=np.float64)
    v_n = np.asarray(v_n, dtype=np.float64).reshape(len(t_gnss), 3)
    t_air = np.asarray(t_air, dtype=np.float64)
    tas = np.asarray(tas, dtype=np.float64)
    if scale is not None and not (isinstance(scale, int | float) and math.isfinite(scale) and scale > 0):
        raise ValueError(f"fit_wind.scale: expected None or a finite number > 0, found {scale!r}")
    if not (max_gap > 0 and math.isfinite(max_gap)):
        raise ValueError(f"fit_wind.max_gap: expected a finite number > 0 s, found {max_gap!r}")
    dims = 2 if horizontal else 3
    good_g = np.isfinite(t_gnss) & np.isfinite(v_n[:, :dims]).all(axis=1)
    tg, vg = t_gnss[good_g], v_n[good_g, :dims]
    if len(tg) < 2:
        raise WindFitError(f"wind fit: expected GNSS velocity (2 or more samples), found {len(tg)}")
    positive = np.isfinite(t_air) & np.isfinite(tas) & (tas > 0)
    keep = positive & (t_air >= tg[0]) & (t_air <= tg[-1])
    idx = np.clip(np.searchsorted(tg, t_air), 1, len(tg) - 1)
    near = np.maximum(np.abs(t_air - tg[idx - 1]), np.abs(tg[idx] - t_air))  # both neighbours close
    keep &= near <= max_gap
    n = int(keep.sum())
    if n < MIN_PAIRS:
        raise WindFitError(
            f"wind fit: expected at least {MIN_PAIRS} airspeed samples with GNSS velocity within {max_gap:g} s, "
            f"found {n} (of {len(t_air)} airspeed samples, {int(positive.sum())} of them > 0 m/s, and "
            f"{len(tg)} GNSS samples)"
        )
    ta, a = t_air[keep], tas[keep]
    v = np.column_stack([np.interp(ta, tg, vg[:, i]) for i in range(dims)])

    free = scale is None

    def k_of(p: F64) -> float:
        return float(p[dims]) if free else float(scale)  # type: ignore[arg-type]

    def residual(p: F64) -> F64:
        return np.linalg.norm(v - p[:dims], axis=1) - k_of(p) * a

    def jacobian(p: F64) -> F64:
        d = v - p[:dims]
        u = d / np.maximum(np.linalg.norm(d, axis=1), 1e-9)[:, None]
        return np.column_stack([-u, -a]) if free else -u

    p = _solve(v, a, scale, loss, f_scale)
    k = k_of(p)
    span = _air_course_span(v, p[:dims])
    if not SCALE_RANGE[0] <= k <= SCALE_RANGE[1]:
        # k held at 1 says whether the flight turned at all
        span1 = _air_course_span(v, _solve(v, a, 1.0, loss, f_scale))
        why = (
            f"with k held at 1 the air-relative course covers {span1:.1f} deg, expected at least "
            f"{MIN_HEADING_SPAN_DEG:g} deg: without turns the flight does not determine the wind"
            if span1 < MIN_HEADING_SPAN_DEG
            else f"the air-relative course covers {span1:.1f} deg with k held at 1: is the pitot broken?"
        )
        raise WindFitError(
            f"wind fit: ill-conditioned: the fitted pitot scale k {k:.3g} is outside {SCALE_RANGE[0]:g} to "
            f"{SCALE_RANGE[1]:g} ({why})"
        )
    if span < MIN_HEADING_SPAN_DEG:
        raise WindFitError(
            f"wind fit: ill-conditioned: the air-relative course covers {span:.1f} deg, expected at least "
            f"{MIN_HEADING_SPAN_DEG:g} deg (on one course the along-track wind and the pitot scale trade "
            "against each other: the flight needs turns)"
        )
    J = jacobian(p)
    cols = np.linalg.norm(J, axis=0)
    if not (cols > 0).all():
        raise WindFitError("wind fit: ill-conditioned: a parameter does not change the residuals")
    cond = float(np.linalg.cond(J / cols))
    if not math.isfinite(cond) or cond > MAX_CONDITION:
        raise WindFitError(
            f"wind fit: ill-conditioned: condition number {cond:.3g} (expected at most {MAX_CONDITION:g}) "
            f"with the course covering {span:.1f} deg"
        )
    r = residual(p)
    rms = float(np.sqrt(np.mean(r**2)))
    cov = np.linalg.inv(J.T @ J) * (rms**2 * n / max(n - len(p), 1))
    sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    wind = np.zeros(3)
    wind[:dims] = p[:dims]
    sw = np.zeros(3)
    sw[:dims] = sig[:dims]
    return WindFit(
        wind_n=wind, scale=k_of(p), rms=rms, sigma_wind_n=sw, sigma_scale=float(sig[dims]) if free else 0.0,
        pairs=n, heading_span_deg=span, horizontal=horizontal, scale_held=not free,
    )


def fit_flight_wind(
    flight: Flight, *, horizontal: bool = True, scale: float | None = None, max_gap: float = 1.0
) -> WindFit:
    """:func:`fit_wind` on a flight's GNSS velocity and airspeed. WindFitError naming the
    stream when the flight has no GNSS velocity or no air data (see :func:`fit_wind`)."""
    missing = [name for name, s in (("GNSS velocity (gnss)", flight.gnss), ("airspeed (air)", flight.air))
               if s is None]
    if missing:
        raise WindFitError(
            f"wind fit: expected a flight with GNSS velocity and airspeed, found no {' and no '.join(missing)}"
        )
    assert flight.gnss is not None and flight.air is not None
    return fit_wind(flight.gnss.t, flight.gnss.v_n, flight.air.t, flight.air.tas,
                    horizontal=horizontal, scale=scale, max_gap=max_gap)
