"""Scoring an Estimate against truth or a reference: attitude errors, RMSE windows,
convergence, NEES/NIS with chi-square bands (SPEC 6.3).

Errors are estimate minus reference. Per-axis errors are differences of ZYX Euler angles
(wrapped to +-180 deg); the total error is the rotation angle between the two attitudes;
the tilt (inclination) error is the angle between their "down" axes, which does not
depend on heading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from windahrs.estimate import Estimate
from windahrs.flight import Flight
from windahrs.rotation import (
    circular_mean,
    euler_from_quat,
    quat_conj,
    quat_exp,
    quat_log,
    quat_mul,
    quat_rotate_inv,
)

__all__ = [
    "AttitudeErrors",
    "Score",
    "attitude_errors",
    "WindErrors",
    "chi2_band",
    "convergence_index",
    "heading_start_note",
    "nees_attitude",
    "reference_of",
    "rmse",
    "score",
    "wind_errors",
]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class AttitudeErrors:
    """Errors on the reference's valid samples. t (M,) s; euler (M, 3) rad (roll, pitch,
    yaw); total (M,) rad; tilt (M,) rad; index (M,) the estimate's rows used."""

    t: F64
    euler: F64
    total: F64
    tilt: F64
    index: NDArray[np.int64]


def reference_of(flight: Flight) -> tuple[F64, F64, str, bool]:
    """(t, q_nb, label, heading_free) of what an estimate is scored against: the
    simulation truth, else the recording's reference (mocap or the autopilot's). A recording
    without a magnetometer scores heading free of its datum, as one whose reference declares
    it (mocap; ANSFL, for the same reason): nothing on board shares the reference's north
    (an estimator without GNSS starts its heading anywhere), so a constant heading offset is
    removed and the drift scored."""
    if flight.truth is not None:
        return flight.truth.t, flight.truth.q_nb, "truth", False
    if flight.reference is not None:
        r = flight.reference
        q = r.q_nb.copy()
        if r.mask is not None:
            q[~r.mask] = np.nan
        return r.t, q, r.kind, r.heading_free or flight.mag is None
    raise ValueError("flight: expected truth or a reference attitude to score against, found neither")


def heading_start_note(flight: Flight) -> str | None:
    """What to tell a user whose recording is scored heading-free because it has no
    magnetometer (:func:`reference_of`) while it has GNSS velocity, from which an INS
    ([ins-wind], [auto]) learns north in motion; None otherwise. One offset removed for the
    whole recording fits a heading that keeps one datum (vqf, [mekf]) but not one that turns
    to north part-way, so such an INS is also scored on the seconds before it knows north
    (docs/RESULTS.md section 44: on ANSFL 41 deg over the first 3 s, 1.6 after them)."""
    if flight.truth is not None or flight.reference is None or flight.mag is not None or flight.gnss is None:
        return None
    return ("no magnetometer: heading scored free of its datum (one constant offset removed from each estimate); an "
            "estimator that learns north from GNSS velocity (ins-wind, auto) is scored on its start too, before it "
            "knows north (python benchmarks/heading_start.py splits the two)")


def _interp_ref(t_ref: F64, q_ref: F64, t: F64) -> tuple[F64, NDArray[np.bool_]]:
    """Reference attitude at times t (nearest sample within half a reference period;
    gaps (NaN) and times outside the reference are invalid)."""
    if len(t_ref) == 1:
        return np.repeat(q_ref, len(t), axis=0), np.isclose(t, t_ref[0])
    i = np.clip(np.searchsorted(t_ref, t), 1, len(t_ref) - 1)
    left = np.where(t - t_ref[i - 1] <= t_ref[i] - t, i - 1, i)
    dt_ref = float(np.median(np.diff(t_ref)))
    ok = (np.abs(t_ref[left] - t) <= 0.51 * dt_ref + 1e-9) & np.isfinite(q_ref[left]).all(axis=1)
    return q_ref[left], ok


def heading_offset(q_est: F64, q_ref: F64) -> float:
    """The constant rotation about the nav vertical that best aligns the reference to the
    estimate (circular mean of the yaw differences), rad."""
    return circular_mean(euler_from_quat(q_est)[:, 2] - euler_from_quat(q_ref)[:, 2])


def attitude_errors(est: Estimate, flight: Flight, *, remove_heading: bool | None = None) -> AttitudeErrors:
    """Errors of ``est`` against the flight's truth or reference. ``remove_heading``:
    remove a constant heading offset first (default: when the reference is heading-free)."""
    t_ref, q_ref_all, _, free = reference_of(flight)
    q_ref, ok = _interp_ref(t_ref, q_ref_all, est.t)
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        raise ValueError("reference: no sample overlaps the estimate in time")
    qe, qr = est.q_nb[idx], q_ref[idx]
    if remove_heading if remove_heading is not None else free:
        psi = heading_offset(qe, qr)
        qr = quat_mul(quat_exp(np.array([0.0, 0.0, psi])), qr)
    e = euler_from_quat(qe) - euler_from_quat(qr)
    e = (e + np.pi) % (2 * np.pi) - np.pi
    total = np.linalg.norm(quat_log(quat_mul(quat_conj(qr), qe)), axis=1)
    down = np.array([0.0, 0.0, 1.0])
    c = np.sum(quat_rotate_inv(qe, down) * quat_rotate_inv(qr, down), axis=1)
    tilt = np.arccos(np.clip(c, -1.0, 1.0))
    return AttitudeErrors(t=est.t[idx], euler=e, total=total, tilt=tilt, index=idx)


def rmse(x: F64, axis: int = 0) -> F64:
    """Root mean square along ``axis`` (NaN-aware); NaN over no sample at all (e.g. a
    reference that ends before the second half), without numpy's "Mean of empty slice"."""
    a = np.asarray(x) ** 2
    if a.shape[axis] == 0:
        return np.full(np.delete(a.shape, axis), np.nan)
    return np.sqrt(np.nanmean(a, axis=axis))


def convergence_index(total: F64, threshold: float) -> int:
    """First sample after which the error stays below ``threshold`` (len if never)."""
    above = np.flatnonzero(total >= threshold)
    return 0 if len(above) == 0 else int(above[-1]) + 1


@dataclass(frozen=True)
class Score:
    """RMSE in degrees: from sample 50 on, and over the second half (steady state); NaN
    over a span without a scored reference sample."""

    filter: str
    reference: str
    rmse_from50_deg: tuple[float, float, float]
    rmse_steady_deg: tuple[float, float, float]
    rmse_tilt_deg: float
    rmse_total_deg: float

    def as_dict(self) -> dict[str, object]:
        return {
            "filter": self.filter,
            "reference": self.reference,
            "rmse_from50_deg": list(self.rmse_from50_deg),
            "rmse_steady_deg": list(self.rmse_steady_deg),
            "rmse_tilt_deg": self.rmse_tilt_deg,
            "rmse_total_deg": self.rmse_total_deg,
        }


def score(est: Estimate, flight: Flight, *, remove_heading: bool | None = None) -> Score:
    """RMSE per axis from sample 50 and over the second half; tilt and total from 50."""
    err = attitude_errors(est, flight, remove_heading=remove_heading)
    d = np.degrees
    from50 = err.index >= 50
    steady = err.index >= len(est.t) // 2
    return Score(
        filter=est.filter,
        reference=reference_of(flight)[2],
        rmse_from50_deg=tuple(float(v) for v in d(rmse(err.euler[from50]))),  # type: ignore[arg-type]
        rmse_steady_deg=tuple(float(v) for v in d(rmse(err.euler[steady]))),  # type: ignore[arg-type]
        rmse_tilt_deg=float(d(rmse(err.tilt[from50]))),
        rmse_total_deg=float(d(rmse(err.total[from50]))),
    )


def nees_attitude(est: Estimate, flight: Flight, *, with_bias: bool = True) -> F64:
    """NEES (M,) of the attitude error (and gyro bias error when estimated and
    ``with_bias``) against the truth, with the estimate's tangent-space covariance, at the
    samples it was recorded at (``est.cov_rows``: every sample but in long records)."""
    tr = flight.truth
    if tr is None or est.cov is None:
        raise ValueError("NEES needs simulation truth and an estimate with covariance")
    if not np.array_equal(tr.t, est.t):
        raise ValueError("NEES: truth and estimate must share the IMU time grid")
    k = est.cov_rows
    e = quat_log(quat_mul(quat_conj(est.q_nb[k]), tr.q_nb[k]))
    labels = [lab for lab in est.state_labels if lab.startswith("att_")]
    if with_bias and est.gyro_bias_b is not None and tr.gyro_bias_b is not None:
        e = np.hstack([e, tr.gyro_bias_b[k] - est.gyro_bias_b[k]])
        labels += [lab for lab in est.state_labels if lab.startswith("bg_")]
    idx = [est.state_labels.index(lab) for lab in labels]
    P = est.cov[:, idx][:, :, idx]
    return np.einsum("ni,ni->n", e, np.linalg.solve(P, e[:, :, None])[:, :, 0])


def chi2_band(dim: int, runs: int, level: float = 0.95) -> tuple[float, float]:
    """Two-sided band of the N-run average of a chi-square(dim) statistic (SPEC 6.3)."""
    lo = chi2.ppf((1 - level) / 2, dim * runs) / runs
    hi = chi2.ppf(1 - (1 - level) / 2, dim * runs) / runs
    return float(lo), float(hi)


#: Wind errors are scored from this time on, s: wind states start unknown (ins-wind: 5 m/s
#: per axis) and converge over tens of seconds.
WIND_FROM_S = 30.0


@dataclass(frozen=True)
class WindErrors:
    """Horizontal wind errors from ``t_from`` s on: rmse_h m/s, the RMS of the horizontal
    error vector; direction_deg, the angle from the mean true horizontal wind to the mean
    estimated one (signed, clockwise seen from above); speed_bias m/s, the mean estimated
    speed minus the mean true speed."""

    rmse_h: float
    direction_deg: float
    speed_bias: float
    t_from: float


def wind_errors(est: Estimate, flight: Flight, *, t_from: float = WIND_FROM_S) -> WindErrors:
    """Horizontal wind of ``est`` against the flight's true wind (simulation truth)."""
    tr = flight.truth
    if est.wind_n is None or tr is None or tr.wind_n is None:
        raise ValueError("wind errors need an estimate with wind states and a flight with the true wind")
    k = np.flatnonzero(est.t >= t_from)
    if len(k) == 0:
        raise ValueError(f"t_from: expected a time within the flight (ends at {est.t[-1]:.1f} s), found {t_from!r}")
    i = np.clip(np.searchsorted(tr.t, est.t[k]), 0, len(tr.t) - 1)
    w_est, w_true = est.wind_n[k, :2], tr.wind_n[i, :2]
    me, mt = w_est.mean(axis=0), w_true.mean(axis=0)
    d = np.arctan2(me[1], me[0]) - np.arctan2(mt[1], mt[0])
    return WindErrors(
        rmse_h=float(np.sqrt(np.mean(np.sum((w_est - w_true) ** 2, axis=1)))),
        direction_deg=float(np.degrees((d + np.pi) % (2 * np.pi) - np.pi)),
        speed_bias=float(np.linalg.norm(me) - np.linalg.norm(mt)),
        t_from=t_from,
    )
