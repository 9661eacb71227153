"""Slow sensor faults: tests that see what no single sample shows, for the per-sample flags
``mag_drift`` and ``air_drift`` (:mod:`windahrs.flags`).

A slowly drifting magnetometer (a motor current that changes with throttle, a ferrous
payload) stays within the norm and dip checks of every sample (VQF's 10 % and 10 deg), and a
blocked pitot whose reading ramps (trapped total pressure against a changing static pressure)
is taken up by the wind states: the estimators' gates do not reject either. Both tests run
after the run, on the flight's samples and the estimate's attitude:

**Magnetometer drift** (:func:`mag_drift`). The field the attitude predicts in the body,
``C_bn m_ref``, is subtracted from each sample: what remains, ``r_b = m_b - C_bn m_ref``, is
constant for a calibrated or a hard-iron-offset magnetometer whatever the vehicle does, and
moves when the field in the body changes. ``m_ref`` (NED) and the constant part of ``r_b`` are
taken over the first :data:`MAG_REF_S` s after the estimate is initialised (VQF's
``magNewTime``, 20 s, the time a field must persist before VQF takes it as its reference);
``r_b`` is low-passed with :data:`MAG_DRIFT_TAU` (3 s) and a sample is drifting when it has
moved from its constant part by more than :data:`MAG_DRIFT_SHARE` (0.2) of the reference
norm. The attitude is the estimate's: a field that disagrees with a wrong attitude is
flagged as well (the test cannot tell which of the two moved).

**Airspeed drift** (:func:`air_drift`). With a constant wind the airspeed changes only as the
vehicle accelerates along its air velocity: ``d|v - W|/dt = u . dv/dt``, with ``u`` the
airflow's direction, here the estimate's body x axis (within the angle of attack and the
sideslip). Over :data:`AIR_DRIFT_WINDOW_S` s the measured airspeed change minus ``u . dv``
(GNSS velocity differences) leaves the change of the wind along the airflow (turbulence) and
a pitot's drift. A sample is drifting when that residual exceeds :data:`AIR_DRIFT_GATE`
standard deviations of the flight's own residual (its robust spread, 1.4826 times the median
absolute deviation: the flight's turbulence and the pitot's noise, whatever the weather).
Needs air data and GNSS velocity.

**GNSS velocity jump** (:func:`gnss_jump`). Between two GNSS samples the velocity changes by
the integral of the acceleration, ``C_nb f_b + g``, which the IMU measures and the estimate's
attitude turns into NED. The GNSS velocity's change minus that integral leaves the two
samples' noise, the accelerometer's bias over the interval and the attitude's error times
the specific force; a multipath or a constellation switch that moves the velocity by metres
per second in one step stands out of it. A sample jumps when that residual, on any axis, is
beyond :data:`GNSS_JUMP_GATE` standard deviations of the flight's own residual (1.4826 MAD)
and at least :data:`GNSS_JUMP_MIN_MS`. This needs no velocity state, so it flags a jump for
the filters that do not fuse GNSS ([mekf]) as well as for those whose gate takes it up.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from windahrs.estimate import Estimate
from windahrs.flight import Flight
from windahrs.rotation import quat_rotate, quat_rotate_inv

__all__ = [
    "AIR_DRIFT_GATE",
    "AIR_DRIFT_MIN_MS",
    "AIR_DRIFT_WINDOW_S",
    "MAG_DRIFT_SHARE",
    "MAG_DRIFT_TAU",
    "MAG_REF_S",
    "air_drift",
    "air_drift_residual",
    "GNSS_JUMP_GATE",
    "GNSS_JUMP_MIN_MS",
    "gnss_jump",
    "gnss_jump_residual",
    "mag_drift",
    "mag_drift_share",
]

F64 = NDArray[np.float64]
B = NDArray[np.bool_]

#: The field in the body moved by more than this share of the reference norm: twice VQF's
#: magNormTh (0.1), as PX4's inclination check (EKF2_MAG_CHK_INC, 20 deg) is twice VQF's
#: magDipTh (10 deg). VQF's tolerance suits a check that only sets one sample aside; a flag
#: against the flight's reference must not fire on the +-10 % an undisturbed field varies by
#: as the vehicle moves through it (BROAD's undisturbed translation trials 10 and 15: 0.12 at
#: most, on which this was chosen; tested on ALFA's carbonZ flight, 0.17, and PX4's
#: sample.ulg, 0.01, with [auto]). 0.2 of a 50 uT field is 10 uT.
MAG_DRIFT_SHARE = 0.2
#: The low-pass of the body-frame field residual, s: VQF's tauAcc, the mean [mekf] takes of
#: the specific force (accel_lowpass, 3 s); VQF's tauMag (9 s) lags a drift by 6 s more.
MAG_DRIFT_TAU = 3.0
#: The reference's span after initialisation, s: VQF's magNewTime, 20 s.
MAG_REF_S = 20.0
#: The airspeed test's window, s: a blocked pitot ramping at 1 m/s per s (a 1.5 m/s climb at
#: 15 m/s, sim.faults.PitotBlockage) is 10 m/s off at its end, while the low-altitude Dryden
#: turbulence's change along the airflow over it stays bounded by its sigma (MIL-F-8785C:
#: 1.3 m/s at 50 m in W20 = 8 m/s, correlated over L_u / V = 13 s).
AIR_DRIFT_WINDOW_S = 10.0
#: Standard deviations of the flight's own residual: the air-data gate (gate_air, 5, and
#: PX4's EKF2_TAS_GATE, 5).
AIR_DRIFT_GATE = 5.0
#: ... and at least this, m/s, so that a flight with almost no turbulence does not flag its
#: airspeed's noise: the difference of two airspeed samples at PX4's airspeed noise
#: (ASPD_TAS_NOISE, 1.4 m/s, its airspeed selector's), at two standard deviations.
AIR_DRIFT_MIN_MS = 2.0 * math.sqrt(2.0) * 1.4
#: Standard deviations of the flight's own GNSS residual: PX4's GNSS velocity gate
#: (EKF2_GPS_V_GATE, 5), as the estimators' gate_gnss.
GNSS_JUMP_GATE = 5.0
#: ... and at least this, m/s: the difference of two GNSS velocity samples at PX4's smallest
#: GNSS velocity noise (EKF2_GPS_V_NOIS, 0.3 m/s), at that gate.
GNSS_JUMP_MIN_MS = GNSS_JUMP_GATE * math.sqrt(2.0) * 0.3


def _at(t: F64, t_est: F64) -> NDArray[np.int64]:
    """The estimate's sample at or just after each of t (the one an event is recorded at)."""
    return np.clip(np.searchsorted(t_est, t, side="left"), 0, len(t_est) - 1)


def _initialised_at(est: Estimate) -> float:
    """The time of the estimate's first initialised sample, s (:attr:`Estimate.first_initialised`;
    inf if it never initialised)."""
    i = est.first_initialised
    return float(est.t[i]) if i < len(est.t) else math.inf


def mag_drift_share(est: Estimate, flight: Flight, tau: float = MAG_DRIFT_TAU) -> tuple[F64, F64]:
    """The magnetometer's times (K,) s and, at each, how far the low-passed body-frame field
    residual has moved from its constant part, as a share of the reference norm (NaN before
    the reference is taken, or where the sample or the attitude is not finite). Empty
    without a magnetometer."""
    m = flight.mag
    if m is None or len(est.t) == 0:
        return np.empty(0), np.empty(0)
    q = est.q_nb[_at(m.t, est.t)]
    ok = np.isfinite(q).all(axis=1) & np.isfinite(m.mag_b).all(axis=1) & (m.t >= _initialised_at(est))
    share = np.full(len(m.t), np.nan)
    if ok.sum() < 2:
        return m.t, share
    t, mb, q = m.t[ok], m.mag_b[ok], q[ok]
    ref_rows = t < t[0] + MAG_REF_S
    if t[-1] - t[0] <= MAG_REF_S:
        return m.t, share
    m_ref = np.median(quat_rotate(q[ref_rows], mb[ref_rows]), axis=0)
    norm = float(np.linalg.norm(m_ref))
    if norm == 0.0:
        return m.t, share
    r = mb - quat_rotate_inv(q, m_ref)
    r0 = np.median(r[ref_rows], axis=0)
    dt = float(np.median(np.diff(t)))
    a = math.exp(-dt / tau)
    low = lfilter([1.0 - a], [1.0, -a], r - r0, axis=0, zi=(a * (r[0] - r0))[None, :])[0]
    s = np.linalg.norm(low, axis=1) / norm
    s[ref_rows] = np.nan
    share[ok] = s
    return m.t, share


def mag_drift(est: Estimate, flight: Flight) -> tuple[F64, B]:
    """The magnetometer's times and which samples drift (module docstring)."""
    t, share = mag_drift_share(est, flight)
    with np.errstate(invalid="ignore"):
        return t, share > MAG_DRIFT_SHARE


def air_drift_residual(est: Estimate, flight: Flight, window: float = AIR_DRIFT_WINDOW_S) -> tuple[F64, F64]:
    """The air data's times (K,) s and, at each, the airspeed's change over the last ``window``
    s minus the GNSS velocity's change along the estimate's body x axis, m/s (NaN where it
    cannot be formed). Empty without air data or GNSS velocity."""
    air, g = flight.air, flight.gnss
    if air is None or g is None or len(est.t) == 0:
        return np.empty(0), np.empty(0)
    out = np.full(len(air.t), np.nan)
    gok = np.isfinite(g.v_n).all(axis=1)
    if gok.sum() < 2:
        return air.t, out
    tg, v = g.t[gok], g.v_n[gok]
    x_n = quat_rotate(est.q_nb[_at(tg[:-1], est.t)], np.array([1.0, 0.0, 0.0]))
    along = np.r_[0.0, np.cumsum(np.einsum("ij,ij->i", x_n, np.diff(v, axis=0)))]
    along[1:][~np.isfinite(along[1:])] = np.nan
    aok = np.isfinite(air.tas) & (air.t >= _initialised_at(est))
    ta, tas = air.t[aok], air.tas[aok]
    inside = (ta >= tg[0]) & (ta <= tg[-1])
    ta, tas = ta[inside], tas[inside]
    if len(ta) < 2:
        return air.t, out
    p = np.interp(ta, tg, along)
    j = np.searchsorted(ta, ta - window, side="left")
    full = ta - ta[j] >= 0.9 * window  # (a window that spans the time asked, not a gap's remnant)
    r = np.where(full, (tas - tas[j]) - (p - p[j]), np.nan)
    idx = np.flatnonzero(aok)[inside]
    out[idx] = r
    return air.t, out


def air_drift(est: Estimate, flight: Flight) -> tuple[F64, B]:
    """The air data's times and which samples drift (module docstring)."""
    t, r = air_drift_residual(est, flight)
    on = np.zeros(len(t), dtype=bool)
    fin = np.isfinite(r)
    if fin.sum() < 10:
        return t, on
    med = float(np.median(r[fin]))
    spread = 1.4826 * float(np.median(np.abs(r[fin] - med)))
    lim = max(AIR_DRIFT_GATE * spread, AIR_DRIFT_MIN_MS)
    on[fin] = np.abs(r[fin] - med) > lim
    return t, on


def gnss_jump_residual(est: Estimate, flight: Flight) -> tuple[F64, F64]:
    """The GNSS times (K,) s and, at each, (K, 3) m/s NED: the GNSS velocity's change since
    the previous finite sample minus the IMU's acceleration integrated over the interval
    (the estimate's attitude, :func:`~windahrs.rotation.quat_rotate` of the specific force,
    plus gravity; NaN where it cannot be formed: the first sample, before the estimate is
    initialised, across an IMU gap). Empty without GNSS velocity."""
    from windahrs.conventions import GRAVITY_N

    g, imu = flight.gnss, flight.imu
    if g is None or len(est.t) < 2:
        return np.empty(0), np.empty((0, 3))
    out = np.full((len(g.t), 3), np.nan)
    q = est.q_nb
    ok = np.isfinite(q).all(axis=1) & np.isfinite(imu.f_b).all(axis=1) & (imu.t >= _initialised_at(est))
    if ok.sum() < 2:
        return g.t, out
    a = np.where(ok[:, None], quat_rotate(np.where(ok[:, None], q, [1.0, 0.0, 0.0, 0.0]), imu.f_b) + GRAVITY_N, 0.0)
    dt = np.diff(imu.t)
    # the velocity the IMU integrates, at its samples (each step's acceleration, its end's
    # sample: w_b[k] and f_b[k] are the means over (t[k-1], t[k]])
    vel = np.r_[[np.zeros(3)], np.cumsum(a[1:] * dt[:, None], axis=0)]
    bad = np.r_[0, np.cumsum((~ok[1:]) | (dt > 0.5))]  # steps without a usable sample, so far
    gok = np.flatnonzero(np.isfinite(g.v_n).all(axis=1) & (g.t >= _initialised_at(est))
                         & (g.t >= imu.t[0]) & (g.t <= imu.t[-1]))  # fmt: skip
    if len(gok) < 2:
        return g.t, out
    i0, i1 = gok[:-1], gok[1:]
    vi = np.column_stack([np.interp(g.t[gok], imu.t, vel[:, c]) for c in range(3)])
    k = np.searchsorted(imu.t, g.t[gok], side="left").clip(max=len(imu.t) - 1)
    clean = bad[k[1:]] == bad[k[:-1]]  # no unusable IMU step between the two GNSS samples
    r = (g.v_n[i1] - g.v_n[i0]) - (vi[1:] - vi[:-1])
    out[i1[clean]] = r[clean]
    return g.t, out


def gnss_jump(est: Estimate, flight: Flight) -> tuple[F64, B]:
    """The GNSS times and which samples jump (module docstring)."""
    t, r = gnss_jump_residual(est, flight)
    on = np.zeros(len(t), dtype=bool)
    fin = np.isfinite(r).all(axis=1)
    if fin.sum() < 10:
        return t, on
    med = np.median(r[fin], axis=0)
    spread = 1.4826 * np.median(np.abs(r[fin] - med), axis=0)
    lim = np.maximum(GNSS_JUMP_GATE * spread, GNSS_JUMP_MIN_MS)
    on[fin] = (np.abs(r[fin] - med) > lim).any(axis=1)
    return t, on
