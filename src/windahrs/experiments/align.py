"""Alignment of a reference attitude to an estimator's output: a constant mounting rotation
between the two body frames and a constant time offset between the two clocks.

A motion-capture marker body, or an autopilot board, is never mounted exactly like the IMU
an estimator runs on, and its time stamps may lag. Both show as a constant error that is
not the estimator's fault. The model is

    q_est(t) = A * q_ref(t + time_offset_s) * q_mount

with A the identity, or a rotation about the nav vertical for heading-free references.

* time offset: body rotation rates derived from each attitude series (over a short span,
  on a common uniform grid) do not depend on the nav frame, so A drops out, and the mount
  only rotates one set of rate vectors against the other. The offset is the lag within
  +-``max_offset_s`` where the two agree best up to one constant rotation (the Kabsch
  score: nuclear norm of the cross-covariance over the product of the norms; all lags
  at once by FFT), refined below the grid step by a parabola through the peak and its
  two neighbours. The rate magnitudes alone (|w|) were tried first: on a fixed wing's
  long steady turns their correlation peak is too flat to place within 5 ms;
* mount: with the reference shifted and interpolated (slerp) at the estimate's times,
  ``q_mount`` is the least-squares average of ``q_ref^-1 * q_est`` (the eigenvector of
  the largest eigenvalue of ``sum q q^T``, Markley et al., "Averaging Quaternions",
  JGCD 30(4), 2007). For heading-free references A and the mount are fitted together
  (a few alternating steps, then Gauss-Newton).

Whatever is constant in the estimator's own error (e.g. a tilt bias from an uncompensated
accelerometer bias), and its dynamic lag, is absorbed too: estimate the alignment with the
most accurate estimator available and apply that one alignment to every estimator.

A stream the flight declares to be stamped on the reference's clock (``Flight.meta
["gnss.clock"] = "reference"``, :data:`GNSS_CLOCK_KEY`: the ANSFL reader's GNSS velocity and
reference both come from DJI's log) is moved onto the estimate's clock by the same fitted
offset (:func:`align_gnss_clock`), and its declared timing uncertainty
(``meta["gnss.timing_sigma_s"]``) is lowered to what the fit leaves,
:attr:`Alignment.time_sigma_s`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from windahrs.estimate import Estimate
from windahrs.flight import Flight, GnssStream, Reference
from windahrs.metrics import reference_of
from windahrs.rotation import (
    circular_mean,
    euler_from_quat,
    quat_conj,
    quat_exp,
    quat_log,
    quat_mul,
    quat_normalize,
    twist_angle,
)

__all__ = [
    "ALIGN_MIN_RATE_AGREEMENT",
    "ALIGN_RESIDUAL_DEG",
    "GNSS_CLOCK_KEY",
    "GNSS_ON_REFERENCE_CLOCK",
    "REFERENCE_CLOCK_KEY",
    "REFERENCE_OWN_CLOCK",
    "Alignment",
    "align_gnss_clock",
    "alignment_warning",
    "apply_alignment",
    "describe_alignment",
    "estimate_alignment",
    "quat_average",
    "unaligned_clock_note",
    "unreliable_reason",
]

F64 = NDArray[np.float64]

#: Above this residual (deg) an alignment is reported as unreliable.
ALIGN_RESIDUAL_DEG = 5.0
#: ... and below this agreement of the two series' body rates (the correlation score of the
#: time-offset fit, 1: identical). Under 0.5 the two share less than a quarter of their rate
#: variance (r^2 < 0.25): too little common motion to place the clock offset, or to tell a
#: mount from a constant attitude error (a vehicle at rest: any heading difference fits as
#: the mount's yaw). Measured: 0.96-0.999 on every recording in ../shared/data that
#: moves (16 ANSFL flights, PX4 sample.ulg, ALFA), 0.198 on PX4 sample_log_small.ulg, a
#: vehicle on the ground whose 9.4 deg of heading difference the fit called mount.
ALIGN_MIN_RATE_AGREEMENT = 0.5

#: ``Flight.meta`` key a reader sets to say on which clock the GNSS stream is stamped; the
#: value :data:`GNSS_ON_REFERENCE_CLOCK` means the reference's (both logged by one device),
#: so the clock offset an alignment fits applies to the GNSS too (:func:`align_gnss_clock`).
GNSS_CLOCK_KEY = "gnss.clock"
GNSS_ON_REFERENCE_CLOCK = "reference"

#: ``Flight.meta`` key a reader sets to say on which clock the reference is stamped; the
#: value :data:`REFERENCE_OWN_CLOCK` means a clock of its own, not the IMU's, at an offset
#: the reader does not know (the ANSFL reader: DJI's log against the Xsens DOT's). Scored as
#: logged, the errors then include that offset, so the commands say so when they score
#: without ``--align`` (:func:`unaligned_clock_note`).
REFERENCE_CLOCK_KEY = "reference.clock"
REFERENCE_OWN_CLOCK = "own"


def unaligned_clock_note(flight: Flight) -> str | None:
    """What to tell a user who scores ``flight`` against its reference as logged when the
    flight declares the reference on a clock of its own (:data:`REFERENCE_CLOCK_KEY`);
    None otherwise."""
    if flight.reference is None or flight.meta.get(REFERENCE_CLOCK_KEY) != REFERENCE_OWN_CLOCK:
        return None
    return (
        f"the reference is stamped on a clock of its own, not the IMU's (meta {REFERENCE_CLOCK_KEY}="
        f"{REFERENCE_OWN_CLOCK}), at an unknown offset: scored as logged, the errors include that offset and the "
        "sensor's mount; --align fits and removes both"
    )


@dataclass(frozen=True)
class Alignment:
    """A constant alignment of a reference to an estimate.

    q_mount (4,): ``q_est = q_ref * q_mount`` (up to a heading offset for heading-free
    references). time_offset_s: how late the reference's time stamps are on the
    estimate's clock (the reference sample stamped ``t`` describes the attitude at
    ``t - time_offset_s``). correlation: the peak agreement score of the two series' body
    rates, up to the mount (1: identical). residual_deg: RMS angle of what remains
    between the aligned reference and the estimate, deg. samples: estimate samples used.
    time_sigma_s: the standard deviation of time_offset_s, s, as far as the sampling
    limits it: the offset is resolved within one sample period of the slower of the two
    series, uniformly, so ``period / sqrt(12)`` (the variance of a uniform quantisation,
    Widrow and Kollar, "Quantization Noise", Cambridge 2008, ch. 4; 0.029 s for a 10 Hz
    reference); NaN when not known.
    """

    q_mount: F64
    time_offset_s: float
    correlation: float = math.nan
    residual_deg: float = math.nan
    samples: int = 0
    time_sigma_s: float = math.nan

    @property
    def mount_angle_deg(self) -> float:
        """The mount's rotation angle, deg."""
        return math.degrees(float(np.linalg.norm(quat_log(self.q_mount))))


def quat_average(q: F64) -> F64:
    """Least-squares average (4,) of unit quaternions (N, 4), insensitive to the sign of
    each: the eigenvector of the largest eigenvalue of ``sum q q^T`` (Markley 2007)."""
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 4 or len(q) == 0:
        raise ValueError(f"q: expected shape (N, 4) with N >= 1, found {q.shape}")
    _, vecs = np.linalg.eigh(q.T @ q)
    return quat_normalize(vecs[:, -1])


def _finite_rows(a: F64) -> NDArray[np.bool_]:
    """Rows of a (N, k) array without NaN, (N,) bool."""
    return np.asarray(np.isfinite(a).all(axis=1), dtype=np.bool_)


def _valid_steps(t: F64, ok: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Pairs (k, k+1) of valid samples not spanning a gap (dt <= 1.5 median dt)."""
    dt = np.diff(t)
    return ok[:-1] & ok[1:] & (dt <= 1.5 * float(np.median(dt)))


def _slerp_at(t_ref: F64, q_ref: F64, ok_ref: NDArray[np.bool_], t: F64) -> tuple[F64, NDArray[np.bool_]]:
    """Attitude at times t by slerp between the bracketing valid samples (not across
    gaps); invalid (NaN) outside the series or next to a gap."""
    j = np.clip(np.searchsorted(t_ref, t, side="right"), 1, len(t_ref) - 1)
    step = _valid_steps(t_ref, ok_ref)
    ok = (t >= t_ref[0]) & (t <= t_ref[-1]) & step[j - 1]
    q0 = np.where(ok[:, None], q_ref[j - 1], 1.0)
    q1 = np.where(ok[:, None], q_ref[j], 1.0)
    u = np.where(ok, (t - t_ref[j - 1]) / (t_ref[j] - t_ref[j - 1]), 0.0)
    d = quat_mul(quat_conj(q0), q1)
    q = quat_mul(q0, quat_exp(u[:, None] * quat_log(d)))
    q[~ok] = np.nan
    return q, ok


def _body_rates(q: F64, m: int, h: float) -> F64:
    """Body rotation rates (N, 3), rad/s, on a uniform grid of step h: the rotation from
    sample i - m to i + m over 2 m h (a moving average over that span; NaN near gaps)."""
    w = np.full((len(q), 3), np.nan)
    if len(q) > 2 * m:
        d = quat_mul(quat_conj(q[: -2 * m]), q[2 * m :])
        w[m:-m] = quat_log(d) / (2 * m * h)
    return w


def _lagged_sums(a: F64, b: F64, n_lag: int) -> F64:
    """``sum_n a[n] b[n + L]`` for L = -n_lag..n_lag (FFT), a and b (N,)."""
    n = len(a)
    n_fft = 1 << int(np.ceil(np.log2(2 * n)))
    r = np.fft.irfft(np.conj(np.fft.rfft(a, n_fft)) * np.fft.rfft(b, n_fft), n_fft)
    return np.concatenate([r[n_fft - n_lag :], r[: n_lag + 1]])


def _rotation_scores(x: F64, y: F64, n_lag: int) -> F64:
    """For each lag L in -n_lag..n_lag, how well x[i] and y[i + L] (rate vectors in two
    body frames, NaN where invalid) agree up to one constant rotation: the largest
    ``sum y^T R x`` over rotations R (Kabsch) over ``sqrt(sum |x|^2 sum |y|^2)`` on the
    pairs where both are valid; 1 for a perfect match, NaN with fewer than 10 pairs."""
    mx = _finite_rows(x).astype(np.float64)
    my = _finite_rows(y).astype(np.float64)
    x0 = np.where(mx[:, None] > 0, x, 0.0)
    y0 = np.where(my[:, None] > 0, y, 0.0)
    cross = np.empty((2 * n_lag + 1, 3, 3))
    for i in range(3):
        for j in range(3):
            cross[:, i, j] = _lagged_sums(x0[:, i], y0[:, j], n_lag)
    sxx = _lagged_sums(np.sum(x0 * x0, axis=1), my, n_lag)
    syy = _lagged_sums(mx, np.sum(y0 * y0, axis=1), n_lag)
    count = _lagged_sums(mx, my, n_lag)
    u, sv, vt = np.linalg.svd(cross)
    sign = np.where(np.linalg.det(u @ vt) >= 0, 1.0, -1.0)
    den = np.sqrt(np.maximum(sxx * syy, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        score = (sv[:, 0] + sv[:, 1] + sign * sv[:, 2]) / den
    score[(count < 9.5) | ~(den > 0)] = np.nan
    return score


def _time_offset(
    t_est: F64, q_est: F64, ok_est: NDArray[np.bool_], t_ref: F64, q_ref: F64, ok_ref: NDArray[np.bool_],
    max_offset_s: float,
) -> tuple[float, float]:
    """(offset s, peak score) maximising the agreement of the body rotation rates."""
    dt_e = float(np.median(np.diff(t_est)))
    dt_r = float(np.median(np.diff(t_ref)))
    h = max(min(dt_e, dt_r), 1e-3)
    # Rates over a span of at least two samples of the slower series (and 40 ms, against
    # the noise that differentiation amplifies); the same span for both, so no relative lag.
    m = max(1, round(max(0.04, 2.0 * max(dt_e, dt_r)) / (2.0 * h)))
    grid = np.arange(min(t_est[0], t_ref[0]), max(t_est[-1], t_ref[-1]) + h, h)
    x = _body_rates(_slerp_at(t_est, q_est, ok_est, grid)[0], m, h)
    y = _body_rates(_slerp_at(t_ref, q_ref, ok_ref, grid)[0], m, h)
    if np.nanmax(np.linalg.norm(x, axis=1), initial=0.0) < 1e-3 or (
        np.nanmax(np.linalg.norm(y, axis=1), initial=0.0) < 1e-3
    ):
        raise ValueError("alignment: the attitude barely rotates; no time offset can be found")
    n_lag = math.ceil(max_offset_s / h)
    lags = np.arange(-n_lag, n_lag + 1)
    c = _rotation_scores(x, y, n_lag)
    if not np.isfinite(c).any():
        raise ValueError("alignment: the estimate and the reference do not overlap in time")
    i = int(np.nanargmax(c))
    if i == 0 or i == len(c) - 1 or not np.isfinite(c[i - 1 : i + 2]).all():
        raise ValueError(
            f"alignment: time offset: expected a peak of agreement within +-{max_offset_s} s, "
            f"found the maximum at the edge ({lags[i] * h:+.3f} s)"
        )
    c0, c1, c2 = c[i - 1], c[i], c[i + 1]
    den = c0 - 2.0 * c1 + c2
    frac = 0.5 * (c0 - c2) / den if den < 0 else 0.0
    return float((lags[i] + frac) * h), float(c1)


def _heading_part(q: F64) -> F64:
    """The rotation about the nav z axis closest to each q, as one averaged quaternion."""
    return quat_exp(np.array([0.0, 0.0, circular_mean(twist_angle(quat_normalize(q)))]))


def _heading_and_mount(qe: F64, qr: F64, mount: F64) -> tuple[F64, F64]:
    """Least squares ``qe = Rz(psi) * qr * mount`` for psi and mount: a few alternating
    steps to start, then Gauss-Newton on (psi, mount tangent) (the mount's yaw and psi
    trade against each other when the attitude stays near level, so alternation alone
    converges slowly)."""
    a = _heading_part(quat_mul(qe, quat_mul(quat_conj(mount), quat_conj(qr))))
    for _ in range(5):
        mount = quat_average(quat_mul(quat_conj(quat_mul(a, qr)), qe))
        a = _heading_part(quat_mul(qe, quat_mul(quat_conj(mount), quat_conj(qr))))
    psi = 2.0 * math.atan2(float(a[3]), float(a[0]))

    def residual(p: F64) -> F64:
        a_p = quat_exp(np.array([0.0, 0.0, psi + p[0]]))
        m_p = quat_mul(mount, quat_exp(p[1:]))
        return quat_log(quat_mul(quat_conj(quat_mul(quat_mul(a_p, qr), m_p)), qe)).ravel()

    eps = 1e-6
    for _ in range(20):
        r0 = residual(np.zeros(4))
        J = np.column_stack(
            [(residual(eps * e) - residual(-eps * e)) / (2 * eps) for e in np.eye(4)]
        )
        step = -np.linalg.lstsq(J, r0, rcond=None)[0]
        psi += float(step[0])
        mount = quat_normalize(quat_mul(mount, quat_exp(step[1:])))
        if float(np.linalg.norm(step)) < 1e-10:
            break
    return quat_exp(np.array([0.0, 0.0, psi])), mount


def estimate_alignment(est: Estimate, flight: Flight, *, max_offset_s: float = 1.0) -> Alignment:
    """Constant mount rotation and time offset between ``est`` and the flight's reference
    (or truth), see the module docstring. Uses the reference's valid samples only (finite,
    inside its mask). max_offset_s: the largest offset searched, s.

    Raises ValueError when the two series do not overlap, barely rotate, or the best time
    offset lies at the edge of the search range.
    """
    if not (math.isfinite(max_offset_s) and max_offset_s > 0):
        raise ValueError(f"max_offset_s: expected > 0 s, found {max_offset_s!r}")
    t_ref, q_ref, _, free = reference_of(flight)
    ok_ref = _finite_rows(q_ref)
    ok_est = _finite_rows(est.q_nb)
    if len(t_ref) < 3 or np.count_nonzero(ok_ref) < 3:
        raise ValueError("alignment: the reference has fewer than 3 valid samples")
    tau, corr = _time_offset(est.t, est.q_nb, ok_est, t_ref, q_ref, ok_ref, max_offset_s)
    period = max(float(np.median(np.diff(est.t))), float(np.median(np.diff(t_ref))))
    q_r, ok = _slerp_at(t_ref - tau, q_ref, ok_ref, est.t)
    ok &= ok_est
    if np.count_nonzero(ok) < 3:
        raise ValueError("alignment: fewer than 3 estimate samples overlap the shifted reference")
    qe, qr = est.q_nb[ok], q_r[ok]
    a = np.array([1.0, 0.0, 0.0, 0.0])
    mount = quat_average(quat_mul(quat_conj(qr), qe))
    if free:
        a, mount = _heading_and_mount(qe, qr, mount)
    resid = quat_log(quat_mul(quat_conj(quat_mul(quat_mul(a, qr), mount)), qe))
    rms = math.degrees(float(np.sqrt(np.mean(np.sum(resid**2, axis=1)))))
    return Alignment(
        q_mount=mount, time_offset_s=tau, correlation=corr, residual_deg=rms, samples=int(np.count_nonzero(ok)),
        time_sigma_s=period / math.sqrt(12.0),
    )


def apply_alignment(flight: Flight, alignment: Alignment) -> Flight:
    """A copy of ``flight`` whose reference is on the estimate's clock and in its body
    frame: times ``t - time_offset_s``, attitudes ``q_ref * q_mount`` (gaps and mask
    kept). Raises ValueError when the flight has no reference (a simulation's truth is in
    the estimator's frame by construction)."""
    ref = flight.reference
    if ref is None:
        raise ValueError("flight: expected a reference attitude to align, found none")
    q_mount = np.asarray(alignment.q_mount, dtype=np.float64)
    if q_mount.shape != (4,) or not np.isfinite(q_mount).all():
        raise ValueError(f"alignment.q_mount: expected a finite (4,) quaternion, found {q_mount!r}")
    if not math.isfinite(alignment.time_offset_s):
        raise ValueError(f"alignment.time_offset_s: expected a finite time, found {alignment.time_offset_s!r}")
    q = quat_mul(ref.q_nb, quat_normalize(q_mount))
    new_ref = Reference(
        t=ref.t - alignment.time_offset_s, q_nb=q, kind=ref.kind, heading_free=ref.heading_free, mask=ref.mask
    )
    meta = {
        **flight.meta,
        "reference.time_offset_s": float(alignment.time_offset_s),
        "reference.mount_deg": alignment.mount_angle_deg,
    }
    return flight.replace(reference=new_ref, meta=meta)


def align_gnss_clock(flight: Flight, alignment: Alignment) -> Flight:
    """``flight`` with its GNSS stream moved onto the estimate's clock when the flight
    declares it stamped on the reference's (``meta[GNSS_CLOCK_KEY] == "reference"``);
    otherwise ``flight`` itself, unchanged (no GNSS, another clock, or no declaration).

    The reference sample stamped ``t`` describes the attitude at ``t - time_offset_s`` on
    the estimate's (the IMU's) clock, so a GNSS sample stamped ``t`` on the same clock is
    moved to ``t - time_offset_s`` (as :func:`apply_alignment` moves the reference). The
    declared timing uncertainty ``meta["gnss.timing_sigma_s"]`` becomes the smaller of its
    value and :attr:`Alignment.time_sigma_s` (what the fit leaves); ``meta
    ["gnss.time_shift_s"]`` records the shift applied, s (``-time_offset_s``), and the
    clock key becomes ``"estimate"``. Raises ValueError for a non-finite offset or a
    time_sigma_s that is negative."""
    if flight.gnss is None or flight.meta.get(GNSS_CLOCK_KEY) != GNSS_ON_REFERENCE_CLOCK:
        return flight
    tau = alignment.time_offset_s
    if not math.isfinite(tau):
        raise ValueError(f"alignment.time_offset_s: expected a finite time, found {tau!r}")
    sigma = alignment.time_sigma_s
    if sigma < 0:
        raise ValueError(f"alignment.time_sigma_s: expected >= 0 s or NaN, found {sigma!r}")
    meta = {**flight.meta, GNSS_CLOCK_KEY: "estimate", "gnss.time_shift_s": -float(tau)}
    declared = float(flight.meta.get("gnss.timing_sigma_s", math.inf) or 0.0)
    if math.isfinite(sigma) and sigma < declared:
        meta["gnss.timing_sigma_s"] = float(sigma)
    gnss = GnssStream(t=flight.gnss.t - tau, v_n=flight.gnss.v_n, v_sigma=flight.gnss.v_sigma)
    return flight.replace(gnss=gnss, meta=meta)


def describe_alignment(alignment: Alignment, aligned_on: str | None = None) -> str:
    """One line: the mount rotation (angle and ZYX Euler angles), the time offset, the
    rate agreement and the residual; ``aligned_on`` names the estimate it was fitted on."""
    rpy = np.degrees(euler_from_quat(np.asarray(alignment.q_mount, dtype=np.float64)))
    tau_ms = alignment.time_offset_s * 1e3
    late = "late" if tau_ms >= 0 else "early"
    on = f" to {aligned_on}" if aligned_on else ""
    return (
        f"reference aligned{on}: mount {alignment.mount_angle_deg:.3f} deg (roll {rpy[0]:+.3f}, pitch "
        f"{rpy[1]:+.3f}, yaw {rpy[2]:+.3f} deg), time offset {tau_ms:+.1f} ms (reference stamps {late}), "
        f"rate agreement {alignment.correlation:.3f}, residual {alignment.residual_deg:.3f} deg "
        f"over {alignment.samples} samples"
    )


def _unreliable(alignment: Alignment) -> tuple[str, str] | None:
    """Why an alignment should not be trusted, in a few words and in full, or None: what
    remains after it is more than ALIGN_RESIDUAL_DEG, so the estimate it was fitted on
    differs from the reference by more than a constant rotation and the fit absorbed part of
    that estimator's error; or the two series' body rates agree by less than
    ALIGN_MIN_RATE_AGREEMENT, so they share too little motion to fit a clock offset or tell a
    mount from a constant error."""
    if alignment.residual_deg > ALIGN_RESIDUAL_DEG or not math.isfinite(alignment.residual_deg):
        return f"residual over {ALIGN_RESIDUAL_DEG:g} deg", (
            f"the residual after alignment ({alignment.residual_deg:.3g} deg) exceeds {ALIGN_RESIDUAL_DEG:g} deg: "
            "the estimate it was fitted on differs from the reference by more than a constant rotation, so the "
            "mount and offset are unreliable; judge the scores against the reference as logged"
        )
    if alignment.correlation < ALIGN_MIN_RATE_AGREEMENT:
        return f"rate agreement under {ALIGN_MIN_RATE_AGREEMENT:g}: too little common motion", (
            f"the body rates of the reference and the estimate agree by only {alignment.correlation:.3g} "
            f"(1: identical; under {ALIGN_MIN_RATE_AGREEMENT:g} they share under a quarter of their motion): too "
            "little common motion to fit the clock offset or to tell a mount from a constant attitude error, so "
            "the mount and offset are unreliable; judge the scores against the reference as logged"
        )
    return None


def unreliable_reason(alignment: Alignment) -> str | None:
    """In a few words, why an alignment should not be trusted (:func:`alignment_warning` says
    it in full), or None."""
    why = _unreliable(alignment)
    return None if why is None else why[0]


def alignment_warning(alignment: Alignment) -> str | None:
    """Why an alignment should not be trusted, in full, or None (:func:`_unreliable`)."""
    why = _unreliable(alignment)
    return None if why is None else why[1]
