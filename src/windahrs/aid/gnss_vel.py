"""Aid source: GNSS velocity (NED), ``h = v_n``, ``H = I`` on the velocity states,
R = gnss_sigma^2 I, gated at gate_gnss sigmas ([ins-wind]). A receiver that reports its speed
accuracy s (:class:`~windahrs.flight.GnssStream` ``v_sigma``: u-blox ``sAcc``, PX4's
``s_variance_m_s``) is taken at its word where it is worse: R = max(gnss_sigma, s)^2 on the
horizontal axes and max(gnss_sigma, 1.5 s)^2 on the vertical, as PX4 EKF2 does
(``max(sacc, EKF2_GPS_V_NOISE)``, the vertical 1.5 times: its "typical ratio of vacc/hacc").
Every filter remembers the last GNSS velocity and its difference (the accelerometer
compensation of :mod:`windahrs.aid.gravity` and the velocity input of [mekf-air]). Innovation
key: ``"gnss"`` (3 rows).

Reset: GNSS velocity kept out by its gate for ``reset_timeout`` means the INS has lost its
velocity (and with it, usually, its attitude: one 40 rad/s gyro spike tilts it by 10 deg and
the gate then rejects every sample that would fix it, issue 13). The velocity is reset to the
sample, as PX4 EKF2 (``resetVelocityToGnss`` on its GNSS fusion timeout) and ArduPilot EKF3
(``ResetVelocity`` on ``velTimeout``) do. Those filters reset the velocity alone; here the
states the lost velocity has left unguarded are reset too, because with the gate closed the
aids left (air data, the magnetometer) have been steering them unopposed, and a velocity
reset alone is rejected again 5 s later (measured on the ALFA flight: a reset every 5 s):

* the attitude's spread returns to init_att (so that the next samples can correct a tilt the
  rejected ones could not), and a tilt more than 45 deg from the GNSS-compensated specific
  force is levelled to it (the gravity aid's rule: beyond what a linear update can undo);
* the gyro and accelerometer biases, learnt while the state was lost, restart from zero with
  their initial spreads (the gravity reset's rule; PX4 reopens the gyro bias after its
  emergency yaw reset); the magnetometer bias too when the field was fused since GNSS last
  agreed with the state (or ever, GNSS never having agreed), when it may have learnt the
  lost attitude; else it is the airframe's, learnt under an attitude GNSS vouched for, and
  kept (restarted, the heading taken from the field under an unknown hard iron stayed 2.5 deg
  off for 20 s after the fault matrix's 5 s gyro saturation on the fixed wing, seed 3: the
  error back under twice its pre-fault RMS 26.4 s after the fault, 4.1 s now);
* the wind, fitted to a wrong velocity, restarts from the next air sample as at
  initialisation (PX4 EKF2 likewise resets the wind from the airspeed when it restarts
  airspeed fusion);
* the heading turns to the next magnetometer sample that passes its disturbance checks
  (as at a start without it, :mod:`windahrs.aid.mag`): the heading the lost state drifted to
  is no better than its tilt. This and the magnetometer's own heading reset share one budget,
  :data:`~windahrs.aid.mag.INS_HEADING_RESETS` (2) per run: with the heading reset and no
  budget, a compass mounted 90 deg off made the INS on the simulated fixed wing take its
  wrong heading after each of 4 GNSS resets (total error over the last 20 s of 90: 91 and
  101 deg, seeds 0 and 1); with the budget 9.1 and 6.3 deg, worse than without the INS's
  heading reset, 1.3 and 1.4. Neither turns a heading GNSS has seen in manoeuvres
  (:func:`watch_heading`): 1.4 and 1.7 deg (``python benchmarks/wrong_compass.py``;
  docs/RESULTS.md sections 35 and 36). PX4 EKF2 instead declares the magnetometer faulty after its
  GNSS-triggered emergency yaw reset (``mag_fault``), which turns the yaw with its GNSS yaw
  estimator, which windahrs does not have; declaring it faulty here (until issue 13) left a
  heading the fault had turned uncorrected for the rest of the flight (one 10 s, 5 m/s GNSS
  jump on the simulated fixed wing in 8 m/s wind: total RMSE 2.06 deg, 0.68 deg now; ALFA
  unchanged, its magnetometer's site field unknown).

Logged in the ``reset`` log (size: the velocity jump, m/s) and warned about.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from windahrs.aid.mag import spend_heading_reset
from windahrs.core.kalman import (
    _fuse,
)
from windahrs.core.layout import (
    _JIT_CORE,
    INN_GNSS,
    KIND_INS,
    S_AGNSS,
    S_AINS,
    S_FBAR,
    S_HEADLESS,
    S_INIT,
    S_VGNSS,
    S_WPEND,
    W_H,
    W_NU,
    W_R,
    X_AGNSS,
    X_AINS,
    X_BA,
    X_BM,
    X_FBAR,
    X_HLAST,
    X_HOBS,
    X_HSEEN,
    X_LGAIN,
    X_TGNSS,
    X_TGOK,
    X_TMOK,
    X_V,
    X_VGNSS,
)
from windahrs.core.predict import _lowpass_gain, steady_gain
from windahrs.core.reset import (
    accepted_at,
    level_to,
    log_reset,
    reopen,
    reset_gyro_bias,
    restart,
    restart_after_absence,
    set_attitude_cov,
    timed_out,
)

#: The parameters of this aid source (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = ("gnss_sigma", "gnss_timing_sigma", "gate_gnss", "reset_timeout")

#: The vertical velocity's accuracy over the horizontal one that a receiver reports (PX4 EKF2:
#: "use 1.5 as a typical ratio of vacc/hacc", its vertical variance 1.5^2 times the horizontal).
VERTICAL_SACC_RATIO = 1.5


#: Time constant, s, of the means that level the attitude at a GNSS reset: the specific force
#: in an almost inertial frame (rotated into each new body frame by the gyro) and the GNSS
#: acceleration in NED. Over a few seconds rotor vibration and manoeuvres average out of
#: both alike, while one sample of a multirotor's accelerometer is off by several m/s^2
#: (VQF's tau_acc, 3 s, the same low-pass of the specific force; also [mekf]'s accel_lowpass).
LEVEL_TAU = 3.0

#: The mean horizontal GNSS acceleration, m/s^2, below which GNSS velocity does not show the
#: heading (:func:`watch_heading`): PX4 EKF2's EKF2_MAG_ACCLIM (0.5), with its hysteresis, twice
#: that to start seeing it (``checkYawAngleObservability``). A heading error psi makes the INS's
#: velocity drift by a sin(psi) per second only under a horizontal acceleration a.
HEADING_ACC_LIMIT = 0.5


@njit(inline="always", **_JIT_CORE)
def remember_gnss(prm, x, flags, t, row):
    """Every filter keeps the last GNSS velocity (row[:3] m/s NED at t s) and its
    difference quotient, the acceleration used to compensate the accelerometer (and its
    mean over LEVEL_TAU, the INS reset's levelling). The first sample after an outage longer
    than reset_timeout restarts the reset's clock: the sensor was absent, not kept out by its
    gate (PX4 EKF2 likewise times its GNSS fusion out only while it has samples to fuse)."""
    if flags[S_VGNSS] == 1 and flags[S_INIT] == 1:
        restart_after_absence(prm, x, np.int64(INN_GNSS), t, x[X_TGNSS])
    if flags[S_VGNSS] == 1 and t > x[X_TGNSS]:
        dt = t - x[X_TGNSS]
        for a in range(3):
            x[X_AGNSS + a] = (row[a] - x[X_VGNSS + a]) / dt
        flags[S_AGNSS] = 1
        k = 1.0 if flags[S_AINS] == 0 else _lowpass_gain(dt, LEVEL_TAU)
        for a in range(3):
            x[X_AINS + a] += k * (x[X_AGNSS + a] - x[X_AINS + a])
        flags[S_AINS] = 1
    for a in range(3):
        x[X_VGNSS + a] = row[a]
    x[X_TGNSS] = t
    flags[S_VGNSS] = 1


@njit(inline="always", **_JIT_CORE)
def fuse_gnss(cfg, prm, x, flags, P, work, sup, inn, acc, t, row):
    """A GNSS velocity sample (finite) of an initialised filter: row[:3] m/s NED at t s,
    row[3] the receiver's speed accuracy (m/s; NaN: not given), fused where velocity is a
    state ([ins-wind])."""
    if cfg["kind"] == KIND_INS:
        iv = cfg["i_v"]
        H, R = work[W_H : W_H + 3], work[W_R : W_R + 3]
        tau = prm["gnss_timing_sigma"] if flags[S_AGNSS] == 1 else 0.0
        s = row[3]  # (the receiver's word where worse than gnss_sigma: PX4's max(sacc, EKF2_GPS_V_NOISE))
        for k in range(3):
            H[k, 0], H[k, 1], H[k, 2] = 0.0, 0.0, 0.0
            for a in range(3):
                H[k, iv + a] = 1.0 if k == a else 0.0
                R[k, a] = 0.0
            var = prm["gnss_var"]
            if s == s:  # (finite: the readers give NaN or a value within range)
                sk = s if k < 2 else VERTICAL_SACC_RATIO * s
                var = max(var, sk * sk)
            R[k, k] = var + (tau * x[X_AGNSS + k]) ** 2  # noise, and timing: late by tau, off by a tau
            sup[0, k] = iv + k
            work[W_NU, k] = row[k] - x[X_V + k]
        sensor, m, ns = np.int64(INN_GNSS), np.int64(3), np.int64(3)
        if timed_out(prm, x, sensor, t):
            reset_to_gnss(cfg, prm, x, flags, P, work, inn, acc, t, row)
        elif _fuse(cfg, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, prm["gate_gnss2"]):
            accepted_at(x, sensor, t)
            x[X_TGOK] = t
            watch_heading(x, t, True)
        else:
            watch_heading(x, t, False)


@njit(inline="always", **_JIT_CORE)
def watch_heading(x, t, accepted):
    """Whether GNSS has seen the INS's heading: the seconds (x[X_HSEEN]) of GNSS samples the gate
    accepted while the mean horizontal GNSS acceleration (x[X_AINS], over LEVEL_TAU) was beyond
    HEADING_ACC_LIMIT (x[X_HOBS], with PX4's hysteresis), i.e. while a wrong heading would have
    shown as a velocity error growing at a sin(psi) per second; a sample rejected then starts
    the count again (as does a turn of the heading, aid.mag, and a GNSS reset). A heading GNSS
    has seen for reset_timeout is not turned to a field that disagrees with it
    (:func:`windahrs.aid.mag.heading_reset`): PX4 EKF2 likewise stops fusing a magnetometer whose
    heading is inconsistent with GNSS while the yaw is observable (``mag_heading_consistent``)."""
    a2 = x[X_AINS] ** 2 + x[X_AINS + 1] ** 2
    lim = HEADING_ACC_LIMIT if x[X_HOBS] == 1.0 else 2.0 * HEADING_ACC_LIMIT
    obs = a2 > lim * lim
    x[X_HOBS] = 1.0 if obs else 0.0
    if obs:
        if accepted:
            dt = t - x[X_HLAST]
            if 0.0 < dt <= LEVEL_TAU:  # (a gap longer than the mean's time: not counted)
                x[X_HSEEN] += dt
        else:
            x[X_HSEEN] = 0.0
    x[X_HLAST] = t


@njit(inline="always", **_JIT_CORE)
def remember_specific_force(x, flags, fx, fy, fz, dt):
    """The INS's mean specific force over LEVEL_TAU in the current body frame, in the slot of
    the gravity aid source's mean (x[X_FBAR]: the INS fuses no gravity): blended with f
    (m/s^2) after the kernel has rotated it into the new body frame by the gyro increment
    (kernel._rotate_lowpass, as for every filter whose mean is set)."""
    if flags[S_FBAR] == 0:
        x[X_FBAR], x[X_FBAR + 1], x[X_FBAR + 2] = fx, fy, fz
        flags[S_FBAR] = 1
        return
    k = steady_gain(x, np.int64(X_LGAIN), dt, LEVEL_TAU)
    x[X_FBAR] = x[X_FBAR] + k * (fx - x[X_FBAR])
    x[X_FBAR + 1] = x[X_FBAR + 1] + k * (fy - x[X_FBAR + 1])
    x[X_FBAR + 2] = x[X_FBAR + 2] + k * (fz - x[X_FBAR + 2])


@njit(**_JIT_CORE)
def _level(prm, x):
    """Level the attitude so that the mean specific force matches the mean GNSS
    acceleration, ``f_b = C_bn (a_n - g_n)`` (both over LEVEL_TAU)."""
    g = prm["gravity"]
    level_to(x, -x[X_FBAR], -x[X_FBAR + 1], -x[X_FBAR + 2], -x[X_AINS], -x[X_AINS + 1], g - x[X_AINS + 2])


@njit(**_JIT_CORE)
def reset_to_gnss(cfg, prm, x, flags, P, work, inn, acc, t, row):
    """GNSS velocity kept out by its gate for reset_timeout (module docstring): velocity to
    the sample row[:3] m/s NED at t s (spread gnss_sigma), the attitude's spread reopened (a
    tilt beyond 45 deg levelled), the biases restarted (the hard iron only when it may have
    learnt the lost attitude), the wind restarted from the next air sample, the heading
    turned to the next magnetometer sample; logged."""
    iv = cfg["i_v"]
    reopen(cfg, P, iv, prm["gnss_var"], prm["gnss_var"])
    dv2 = 0.0
    for a in range(3):
        dv2 += (row[a] - x[X_V + a]) ** 2
        x[X_V + a] = row[a]
    if flags[S_FBAR] == 1 and flags[S_AINS] == 1:
        _level(prm, x)
    set_attitude_cov(cfg, prm, x, P, work)
    reset_gyro_bias(cfg, prm, x, P)
    if cfg["i_ba"] >= 0:
        restart(cfg, x, P, X_BA, cfg["i_ba"], prm["init_accel_bias_var"])
    if cfg["i_bm"] >= 0 and x[X_TMOK] > x[X_TGOK]:
        # a hard iron learnt under the lost attitude (the field fused since GNSS last agreed
        # with the state, or ever, GNSS never having agreed) would turn the next heading. One
        # learnt before, under an attitude GNSS vouched for, is the airframe's and kept
        # (restarted, the heading then taken from the field under an unknown hard iron stayed
        # 2.5 deg off for 20 s after the fault matrix's gyro saturation, seed 3)
        restart(cfg, x, P, X_BM, cfg["i_bm"], prm["init_mag_bias_var"])
    x[X_HSEEN] = 0.0  # (the heading GNSS had seen is lost with the state)
    if spend_heading_reset(flags):  # the heading from the next field sample (aid.mag.fuse_mag)
        flags[S_HEADLESS] = 1
    if cfg["i_w"] >= 0:
        reopen(cfg, P, cfg["i_w"], prm["init_wind_var"], prm["init_wind_vertical_var"])
        flags[S_WPEND] = 1  # the wind from the next air sample, as at initialisation
    log_reset(cfg, flags, inn, acc, work, x, np.int64(INN_GNSS), t, math.sqrt(dv2))
