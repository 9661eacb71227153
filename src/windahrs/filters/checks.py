"""Checks of an estimate against its own flight, for every windahrs estimator: no filter
may lose the attitude silently.

:func:`tilt_alerts` asks whether the estimated attitude still knows where down is. Rotated
into the navigation frame by the estimate, the specific force must average to ``-g_n`` plus
the vehicle's acceleration, which itself averages out over a long enough time (a vehicle's
velocity is bounded) or is measured (GNSS velocity differences). The mean over
``TILT_TAU_S`` of ``C_nb f_b - a_n`` is therefore ``-g_n`` for a right attitude; a tilt
error theta moves it by ``2 g sin(theta / 2)``, read back as an angle. A disagreement beyond
``TILT_LIMIT_DEG`` held for ``TILT_HOLD_S`` is an alert: the estimator has lost gravity
(upside-down start, a lock-out by its gate, divergence), whatever it believes of itself.
Within ``TILT_TAU_S`` of a GNSS outage in a flight that has GNSS the check is off: the
acceleration is not measured then, and a turn held through the outage would read as a tilt.

:func:`checked` adds the alerts and the flight's repairs to an Estimate and emits each of
``Estimate.warnings()`` as an :class:`~windahrs.estimate.EstimatorWarning`, but the repairs:
they are the flight's, the same for every estimator, and said once where the flight is read.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
from numba import njit
from numpy.typing import NDArray

from windahrs.core.quat import _dcm9
from windahrs.estimate import Deferred, Estimate, EstimatorWarning
from windahrs.flags import absent_mask, estimate_flags
from windahrs.flight import Flight

__all__ = [
    "BIAS_LIMIT_DEG_S", "TILT_HOLD_S", "TILT_LIMIT_DEG", "TILT_TAU_S", "bias_alerts", "checked", "tilt_alerts",
    "with_repairs",
]

F64 = NDArray[np.float64]

#: Time constant of the mean, s: long against a multirotor's or a handheld sensor's
#: back-and-forth accelerations and a third of a fixed wing's 30 s turn, short against a
#: flight (without GNSS, a turn held longer than this reads as a tilt: GNSS removes it).
TILT_TAU_S = 10.0
#: An alert when the mean specific force is further than this from the vertical, deg (the
#: error a user would call lost; issue 12's "more than 10 deg in tilt from the reference").
TILT_LIMIT_DEG = 10.0
#: The specific force is rotated into the nav frame at this rate, as block means (a 10 s mean
#: needs no more; it keeps the check at a tenth of a 200 Hz filter's cost).
CHECK_RATE_HZ = 20.0
#: ... for at least this long, s.
TILT_HOLD_S = 3.0
#: A gyro-bias estimate beyond this on any axis, deg/s, is an alert: VQF's biasClip (2 deg/s,
#: the largest bias it lets its estimate reach), above the residual zero-rate offset of a
#: calibrated MEMS gyro (autopilots calibrate theirs at boot; e.g. BMI088 +-1 deg/s, ICM-42688
#: +-0.5 deg/s before it). A filter whose bias runs beyond it has most likely absorbed an
#: attitude error (a start far off, an unmodelled acceleration) into the bias, which the
#: tilt check above may read only in part: on ANSFL path_20 [mekf] ends 12.7 deg off in tilt
#: with its bias at 3.6 deg/s while the mean specific force disagrees by 8.9 deg at most.
#: Held for TILT_HOLD_S, as the tilt check: a start's transient may pass it for a moment (the
#: simulated paper scenario, 0.4 s at 2.1 deg/s with a true bias of 1 deg/s).
BIAS_LIMIT_DEG_S = 2.0


def _fill(a: F64) -> F64:
    """Rows with NaN take the last finite row (the first finite row before any); ``a``
    itself when every row is finite (not copied: the callers do not write to it)."""
    if np.isfinite(a.sum()):  # (every row finite: one reduction, the common case)
        return a
    ok = np.isfinite(a).all(axis=1)
    if ok.all():
        return a
    if not ok.any():
        return np.zeros_like(a)
    idx = np.where(ok, np.arange(len(a)), 0)
    np.maximum.accumulate(idx, out=idx)
    idx[: np.argmax(ok)] = np.argmax(ok)
    return a[idx]


def tilt_alerts(
    est: Estimate,
    flight: Flight,
    *,
    tau: float = TILT_TAU_S,
    limit_deg: float = TILT_LIMIT_DEG,
    hold_s: float = TILT_HOLD_S,
) -> F64:
    """The spans where the estimate's tilt disagrees with the mean specific force (see the
    module): (K, 3) rows [t_start s, t_end s, largest disagreement deg]. The mean is a running
    mean for the first tau seconds, which are not checked, and starts again at each of the
    estimate's resets (``est.resets``). est.t must be the flight's IMU times."""
    t, imu = est.t, flight.imu
    if len(t) != len(imu.t) or len(t) < 2:
        return np.empty((0, 3))
    # every sample's specific force, rotated at CHECK_RATE_HZ (the mean's tau is seconds): the
    # block means of the samples, rotated with the block's middle attitude
    dt = imu.period  # (t is the flight's IMU times: the stream's median step, computed once)
    step = max(1, int(1.0 / (CHECK_RATE_HZ * dt)))
    if len(t) < step:  # not one block (a flight shorter than 1 / CHECK_RATE_HZ): nothing to check
        return np.empty((0, 3))
    f_n = _block_rotate(_fill(imu.f_b), _fill(est.q_nb), step)  # a_n - g_n for a right attitude
    n = len(t) // step * step
    t = t[step // 2 : n : step]
    dt *= step
    g = flight.gnss
    unmeasured = np.zeros(len(t), dtype=bool)  # the acceleration not measured in the mean's time
    if g is not None and len(g.t) >= 3:
        ok = np.asarray(np.isfinite(g.v_n).all(axis=1))
        out = absent_mask(g.t, ok, t)
        if out.any():  # a GNSS outage: a turn held through it reads as a tilt; not checked then
            last = np.maximum.accumulate(np.where(out, t, -np.inf))
            unmeasured = t - last < tau
        if ok.sum() >= 3:
            a_n = np.gradient(g.v_n[ok], g.t[ok], axis=0)
            for k in range(3):  # the measured acceleration, removed
                f_n[:, k] -= np.interp(t, g.t[ok], a_n[:, k])
    # the mean restarts at each of the filter's resets: the forces before one were rotated
    # by the attitude the reset discarded, and would hold a right attitude after it off for
    # tau and more (an upside-down start levelled at 3 s read as 35-60 deg off until 20 s)
    cuts = [np.searchsorted(t, r) for rows in est.resets.values() for r in np.asarray(rows)[:, 0]]
    bounds = np.unique(np.clip(np.r_[0, cuts, len(t)], 0, len(t)).astype(np.int64))
    angle, fresh = _mean_angles(t, f_n, bounds, tau, dt, flight.site.gravity)
    over = (angle > limit_deg) & ~fresh & ~unmeasured
    return _spans(t, over, angle, hold_s)


@njit(cache=True, error_model="numpy")
def _block_rotate(f_b: F64, q: F64, step: int) -> F64:
    """The means of f_b (N, 3) over blocks of ``step`` samples (the last partial block left
    out), each rotated into the nav frame by q (N, 4, q_nb) at the block's middle sample."""
    m = f_b.shape[0] // step
    out = np.empty((m, 3))
    for b in range(m):
        s0 = s1 = s2 = 0.0
        for k in range(b * step, (b + 1) * step):
            s0 += f_b[k, 0]
            s1 += f_b[k, 1]
            s2 += f_b[k, 2]
        s0, s1, s2 = s0 / step, s1 / step, s2 / step
        j = b * step + step // 2
        c = _dcm9(q[j, 0], q[j, 1], q[j, 2], q[j, 3])
        out[b, 0] = c[0] * s0 + c[1] * s1 + c[2] * s2
        out[b, 1] = c[3] * s0 + c[4] * s1 + c[5] * s2
        out[b, 2] = c[6] * s0 + c[7] * s1 + c[8] * s2
    return out


@njit(cache=True, error_model="numpy")
def _mean_angles(
    t: F64, f_n: F64, bounds: NDArray[np.int64], tau: float, dt: float, g: float
) -> tuple[F64, NDArray[np.bool_]]:
    """The tilt check's angle (deg) between the mean of f_n (M, 3) at times t and -g_n, and
    whether each row is within tau of its span's start (not checked). The mean starts again
    at each of ``bounds`` (row indices: 0, the resets, M): the running mean until it spans
    tau (VQF's start), then a first-order low-pass from it. |mean + g_n| = 2 g sin(theta / 2)
    for a tilt error theta; it also catches an attitude that follows every sample's specific
    force (its mean then stays vertical, but longer than g: the accelerations rectified)."""
    m = t.shape[0]
    angle = np.empty(m)
    fresh = np.zeros(m, dtype=np.bool_)
    a = math.exp(-dt / tau)
    for s in range(bounds.shape[0] - 1):
        i0, i1 = bounds[s], bounds[s + 1]
        m0 = m1 = m2 = 0.0
        for i in range(i0, i1):
            n = i - i0 + 1
            if t[i] < t[i0] + tau:  # the running mean (not checked)
                fresh[i] = True
                m0 += (f_n[i, 0] - m0) / n
                m1 += (f_n[i, 1] - m1) / n
                m2 += (f_n[i, 2] - m2) / n
            else:
                m0 = a * m0 + (1.0 - a) * f_n[i, 0]
                m1 = a * m1 + (1.0 - a) * f_n[i, 1]
                m2 = a * m2 + (1.0 - a) * f_n[i, 2]
            off = math.sqrt(m0 * m0 + m1 * m1 + (m2 + g) ** 2) / (2.0 * g)
            angle[i] = math.degrees(2.0 * math.asin(min(max(off, 0.0), 1.0)))
    return angle, fresh


def _spans(t: F64, over: NDArray[np.bool_], value: F64, hold_s: float) -> F64:
    """The runs of ``over`` that last at least ``hold_s``: (K, 3) rows [t_start s, t_end s,
    the largest of ``value`` in the run]."""
    edges = np.flatnonzero(np.diff(np.r_[0, over.astype(np.int8), 0]))
    rows = [(t[i0], t[i1 - 1], float(value[i0:i1].max()))
            for i0, i1 in zip(edges[::2], edges[1::2], strict=True) if t[i1 - 1] - t[i0] >= hold_s]
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def bias_alerts(est: Estimate, *, limit_deg_s: float = BIAS_LIMIT_DEG_S, hold_s: float = TILT_HOLD_S) -> F64:
    """The spans of at least ``hold_s`` where the gyro-bias estimate is beyond ``limit_deg_s``
    on some axis: (K, 3) rows [t_start s, t_end s, largest axis deg/s]; none for an estimate
    without a bias."""
    b = est.gyro_bias_b
    if b is None or len(b) == 0:
        return np.empty((0, 3))
    big = np.abs(b[:, 0])  # the largest axis (column by column: 20 times faster than max(axis=1))
    for k in range(1, b.shape[1]):
        big = np.maximum(big, np.abs(b[:, k]))
    over = big > math.radians(limit_deg_s)  # (NaN rows: not over)
    if not over.any():
        return np.empty((0, 3))
    return _spans(est.t, over, np.degrees(big), hold_s)


def with_repairs(est: Estimate, flight: Flight) -> Estimate:
    """``est`` carrying ``flight.repairs`` (a copy)."""
    if not flight.repairs:
        return est
    return dataclasses.replace(est, repairs={k: dict(v) for k, v in flight.repairs.items()})


def checked(est: Estimate, flight: Flight) -> Estimate:
    """``est`` with its tilt and bias alerts (``alerts["tilt"]``, ``alerts["bias"]``), its per-sample flags
    (:func:`windahrs.flags.estimate_flags`, built when first read: :class:`~windahrs.estimate.Deferred`)
    and the flight's repairs, each of its warnings but
    the repairs emitted as an EstimatorWarning."""
    rows, bias = tilt_alerts(est, flight), bias_alerts(est)
    if len(rows) or len(bias):
        new = {"tilt": rows} if len(rows) else {}
        if len(bias):
            new["bias"] = bias
        est = dataclasses.replace(est, alerts={**est.alerts, **new})
    est = with_repairs(est, flight)
    done = est  # the flags read the Estimate's own records (not its flags): built when first read
    est = dataclasses.replace(est, flags=Deferred(lambda: estimate_flags(done, flight)))  # type: ignore[arg-type]
    for line in est.warnings(repairs=False):
        warnings.warn(line, EstimatorWarning, stacklevel=3)
    return est
