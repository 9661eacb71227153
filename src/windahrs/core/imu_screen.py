"""The IMU screen: a sample the sensor cannot have measured is not propagated.

A single glitched IMU sample (a bus error, an ESD spike, a bit flip) integrates into the
attitude at once: 40 rad/s for one 5 ms step turns it by 11 deg, and a gated filter that
trusts the turned state may then reject the measurements that would fix it. Aiding corrects
the damage only over seconds; not propagating the sample costs one step of the true motion.
Every IMU sample (finite: NaN ones are skipped before) therefore passes this screen before
the prediction. It is held, and the last propagated sample is propagated in its place, when:

1. **beyond range:** a gyro axis above ``gyro_range`` or an accelerometer axis above
   ``accel_range``. The sensor cannot output that (defaults: the ranges of the readers' edge
   repair, :mod:`windahrs.repair`, which sets such samples to NaN in a log: the widest full
   scales of autopilot IMUs plus 10 %; the screen catches them in flights built otherwise).
   A sample *at* its range (a clipped one) is not beyond it and passes.
2. **a spike:** the change of the angular rate or of the specific force since the last
   propagated sample exceeds ``imu_spike_gate`` times the root mean square of the recent
   changes (:data:`TAU_CHANGES` s), or :data:`FLOOR_W` / :data:`FLOOR_F`, whichever is
   larger. The gyro and the accelerometer are screened apart: the other one's sample is
   propagated. The next sample decides what the held one was. A spike is a single sample,
   far from both its neighbours while they agree: when the next sample is back near the
   last propagated one, the held one is dropped. Otherwise it was motion (a step, an
   impact's ringing), propagated one sample late rather than lost: its step's excess
   rotation (and, for the INS, velocity increment) is added to the state then. A held
   angular rate right after another held sample is motion too, whatever the next sample
   says: vibration near 2/5 of the sample rate puts each sample far from both neighbours
   while they are close, the pattern of a lone spike, until the gate has opened, and
   dropping those samples turned the attitude by a sample's rotation per cycle (1.1 deg in
   50 ms at the fault matrix's 80 Hz, 0.5 rad/s on a 200 Hz IMU). The accelerometer's are
   still dropped: a lost velocity increment is GNSS's to take back, the attitude's only the
   slow aiding's.

A dropped sample may still have been motion: what it would have turned the attitude by (at
most as much as the gate lets motion be) and moved the INS velocity by is added to their
spread as a held sample's is
(:func:`windahrs.core.predict.add_unmeasured_motion`), so that a wrong verdict costs a
correction by the aiding, not a lasting error. The recent changes' mean square is taken over
every sample, each change counted at most at the gate (a spike does not open the gate for the
next one; vibration that sets in opens it by a third per sample). Steps longer than
:data:`GAP` s are not screened: the motion between such samples was not measured. Every
held sample is logged (the ``imu`` log: the two changes and the outcome: 1 beyond range,
2 a spike, 3 motion propagated late), which the Estimate carries in ``alerts["imu"]``.
PX4 EKF2 and ArduPilot EKF3 have no such screen on a
single IMU (they compare redundant IMUs, and EKF2 inflates the accelerometer's noise while it
clips); with one IMU, its own recent changes are the reference.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from windahrs.core.kalman import _log
from windahrs.core.layout import (
    _JIT_CORE,
    INN_IMU,
    L_CNT,
    S_FLAST,
    S_INIT,
    W_IMU,
    W_NU,
    X_DF,
    X_DW,
    X_FLAST,
    X_Q,
    X_TIMU,
    X_V,
    X_WLAST,
    record_dtype,
)
from windahrs.core.predict import add_unmeasured_motion, flush_cov
from windahrs.core.quat import _dcm9, _qexp, _qmul, _qnormalize

__all__ = [
    "CLIP_F", "CLIP_SAMPLES", "CLIP_W", "FLOOR_F", "FLOOR_W", "GAP", "PARAMS", "SCREEN", "TAU_CHANGES", "screen_imu",
    "screen_state",
]  # fmt: skip

#: The fields of EskfParams the screen reads.
PARAMS = ("gyro_range", "accel_range", "imu_spike_gate")
#: Time constant of the recent changes' mean square, s: long against a spike, short against
#: the seconds over which vibration builds up with throttle.
TAU_CHANGES = 1.0
#: Smallest gates on a sample-to-sample change, rad/s and m/s^2: a resting or smoothly moving
#: sensor has recent changes near zero, and a change of 1 rad/s (57 deg/s) or 1 g in one
#: sample is then no motion a rigid airframe makes between two samples of a >= 50 Hz IMU
#: (an angular acceleration of >= 50 rad/s^2, a jerk of >= 500 m/s^3), while a smaller
#: glitch turns the attitude by less than 0.3 deg at 200 Hz.
FLOOR_W = 1.0
FLOOR_F = 9.80665
#: An axis repeating a magnitude of at least this exactly for CLIP_SAMPLES samples in a row is
#: clipped, rad/s and m/s^2: the smallest full scales autopilot IMUs are set to (125 deg/s,
#: BMI088; 2 g). Noise moves a live axis by converter steps at nearly every sample; BROAD's
#: quantised gyro repeats a value above 125 deg/s 3 and 4 times in a row, never 5
#: (windahrs.flags uses the same constants).
CLIP_W = 125.0 * math.pi / 180.0
CLIP_F = 2.0 * 9.80665
CLIP_SAMPLES = 5
#: Longer steps are not screened, s (the motion between the samples was not measured).
GAP = 0.1

#: The screen's state (KernelState.screen, a (1,) array of :data:`SCREEN`): float64 fields,
#: then int64 counters, as the flat state and flags they came from. (name, size, meaning)
SCREEN_FIELDS: tuple[tuple[str, int, str], ...] = (
    ("sw2", 1, "mean square of the angular rate's sample-to-sample change, (rad/s)^2"),
    ("sf2", 1, "... of the specific force's, (m/s^2)^2"),
    ("pend", 6, "the held sample's excess over the propagated one: w (rad/s), f (m/s^2)"),
    ("dt_pend", 1, "its step, s"),
)
SCREEN_COUNT_FIELDS: tuple[tuple[str, int, str], ...] = (
    ("held", 1, "the last sample's held parts: 1 its angular rate, 2 its specific force, 3 both"),
    ("run", 1, "samples in a row, up to the last one, that had a part held"),
    ("clip", 6, "samples in a row each axis has repeated one large magnitude"),
)
SCREEN = np.dtype(record_dtype(SCREEN_FIELDS).descr + record_dtype(SCREEN_COUNT_FIELDS, np.int64).descr)


def screen_state() -> NDArray[np.void]:
    """A fresh screen state: nothing held, no change seen yet."""
    return np.zeros(1, SCREEN)


@njit(**_JIT_CORE)
def _catch_up(cfg, x, flags, sc, dt, w, f):
    """The held sample was motion: its step's excess over what was propagated added to the
    nominal state (w: its rotation; f: for the INS, its velocity increment rotated to NED),
    and it becomes the last propagated sample."""
    if w:
        if flags[S_INIT] == 1:
            e = _qexp(sc["pend"][0] * dt, sc["pend"][1] * dt, sc["pend"][2] * dt)
            q = _qmul(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], e[0], e[1], e[2], e[3])
            x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = _qnormalize(q[0], q[1], q[2], q[3])
        for a in range(3):
            x[X_WLAST + a] += sc["pend"][a]
    if f:
        if flags[S_INIT] == 1 and cfg["i_v"] >= 0:
            c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
            fx, fy, fz = sc["pend"][3] * dt, sc["pend"][4] * dt, sc["pend"][5] * dt
            x[X_V] += c[0] * fx + c[1] * fy + c[2] * fz
            x[X_V + 1] += c[3] * fx + c[4] * fy + c[5] * fz
            x[X_V + 2] += c[6] * fx + c[7] * fy + c[8] * fz
        for a in range(3):
            x[X_FLAST + a] += sc["pend"][3 + a]


@njit(**_JIT_CORE)
def _clipped(cfg, prm, x, flags, sc, P, work, row, dt):
    """Axes held at one large magnitude (:data:`CLIP_W`, :data:`CLIP_F`) for
    :data:`CLIP_SAMPLES` samples are clipped: the true value is beyond it by as much as it
    again, unknown, and that step's motion becomes spread, as a held sample's would (PX4 EKF2
    likewise sets the delta-velocity noise of a clipping axis to BADACC_BIAS_PNOISE, 4.9 m/s^2)."""
    clip = False
    for a in range(6):
        v, last = abs(row[a]), abs(x[X_WLAST + a] if a < 3 else x[X_FLAST + a - 3])
        held = v >= (CLIP_W if a < 3 else CLIP_F) and v == last
        sc["clip"][a] = sc["clip"][a] + 1 if held else 0
        d = v if sc["clip"][a] >= CLIP_SAMPLES - 1 else 0.0
        if a < 3:
            x[X_DW + a] = d
        else:
            x[X_DF + a - 3] = d
        clip = clip or d > 0
    if clip:
        flush_cov(cfg, prm, x, P, work)  # (P brought up to date before it is changed)
        add_unmeasured_motion(cfg, x, P, work, dt)


@njit(**_JIT_CORE)
def _change2(row, x, i_row, i_x):
    """|row[i_row:i_row+3] - x[i_x:i_x+3]|^2."""
    s = 0.0
    for a in range(3):
        d = row[i_row + a] - x[i_x + a]
        s += d * d
    return s


@njit(**_JIT_CORE)
def screen_imu(cfg, prm, x, flags, sc, P, inn, acc, work, t, row):
    """Whether the IMU sample ``row`` = [w_b, f_b] (finite) at t s is held: True when the
    sample to propagate in its place, with the last propagated angular rate or specific
    force in place of a held one (module docstring), is in work[W_IMU]; False: propagate
    ``row`` itself. sc: the screen's record (:data:`SCREEN`), read and written in place."""
    if flags[S_FLAST] == 0:
        return False
    k = prm["imu_spike_gate"]
    dt = t - x[X_TIMU]
    gw2 = max(FLOOR_W * FLOOR_W, k * k * sc["sw2"])
    gf2 = max(FLOOR_F * FLOOR_F, k * k * sc["sf2"])
    dw2, df2 = _change2(row, x, 0, X_WLAST), _change2(row, x, 3, X_FLAST)
    if sc["held"] > 0:
        # the held sample: a spike if it was alone (the sample before it was propagated as
        # it came) and this one is back near the last propagated sample; else motion, caught
        # up now
        lone = sc["run"] <= 1
        cw = sc["held"] & 1 != 0 and (dw2 > gw2 or not lone)
        cf = sc["held"] & 2 != 0 and df2 > gf2
        if cw or cf:
            _catch_up(cfg, x, flags, sc, sc["dt_pend"], cw, cf)
            inn[cfg["log_off"][INN_IMU] + flags[L_CNT + INN_IMU] - 1, 4] = 3.0  # its log row: motion
            dw2, df2 = _change2(row, x, 0, X_WLAST), _change2(row, x, 3, X_FLAST)
        dropw, dropf = sc["held"] & 1 != 0 and not cw, sc["held"] & 2 != 0 and not cf
        if (dropw or dropf) and flags[S_INIT] == 1:
            # a dropped sample may still have been motion: that becomes spread (X_DW, X_DF
            # are the kernel's to overwrite at this sample); a rotation as large as the gate
            # lets one be (beyond it no airframe turns in one sample, and a wide-open attitude
            # follows the next disturbed specific force), the velocity's as the sample says
            # (what vibration drops: the GNSS takes it back without touching the attitude)
            pw2 = 0.0
            for a in range(3):
                pw2 += sc["pend"][a] ** 2
            sw = math.sqrt(min(1.0, gw2 / pw2)) if dropw and pw2 > 0 else 0.0
            sf = 1.0 if dropf else 0.0
            for a in range(3):
                x[X_DW + a] = sw * sc["pend"][a]
                x[X_DF + a] = sf * sc["pend"][3 + a]
            flush_cov(cfg, prm, x, P, work)  # (P brought up to date before it is changed)
            add_unmeasured_motion(cfg, x, P, work, sc["dt_pend"])
    gr, ar = prm["gyro_range"], prm["accel_range"]
    beyond_w, beyond_f = False, False
    for a in range(3):
        beyond_w = beyond_w or abs(row[a]) > gr
        beyond_f = beyond_f or abs(row[3 + a]) > ar
    if flags[S_INIT] == 1 and 0 < dt <= GAP:
        _clipped(cfg, prm, x, flags, sc, P, work, row, dt)
    hold_w, hold_f = beyond_w, beyond_f
    if k > 0 and 0 < dt <= GAP:
        hold_w = hold_w or dw2 > gw2
        hold_f = hold_f or df2 > gf2
        # the recent changes' mean square, each change counted at most at the gate
        g = dt / TAU_CHANGES
        sc["sw2"] += g * (min(dw2, gw2) - sc["sw2"])
        sc["sf2"] += g * (min(df2, gf2) - sc["sf2"])
    if not (hold_w or hold_f):
        sc["held"] = 0
        sc["run"] = 0
        return False
    sc["run"] = sc["run"] + 1 if sc["held"] > 0 else 1
    nu = work[W_NU]
    nu[0], nu[1], nu[2] = math.sqrt(dw2), math.sqrt(df2), 0.0
    reason = 1.0 if (beyond_w or beyond_f) else 2.0  # (in the NIS column; 3: set when caught up)
    _log(cfg, flags, inn, acc, nu, np.int64(INN_IMU), t, np.int64(2), reason, np.bool_(False))
    held = work[W_IMU]
    for a in range(3):
        held[a] = x[X_WLAST + a] if hold_w else row[a]
        held[3 + a] = x[X_FLAST + a] if hold_f else row[3 + a]
        # the excess to catch up if the next sample says it was motion (never one beyond range)
        sc["pend"][a] = 0.0 if beyond_w else row[a] - held[a]
        sc["pend"][3 + a] = 0.0 if beyond_f else row[3 + a] - held[3 + a]
    sc["dt_pend"] = dt
    sc["held"] = (1 if hold_w else 0) + (2 if hold_f else 0)
    return True
