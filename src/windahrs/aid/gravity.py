"""Aid source: the accelerometer as a measurement of gravity (SPEC 3.2), for the filters
that do not take it as an input ([mekf], [mekf-air], [ekf7], [ekf10]).

Preprocessing: compensation of the vehicle's acceleration by GNSS velocity differences
(``C_bn a_gnss``) or by ``(w - b_g) x V_air`` from pitot and vanes (SPEC 3.2.2); optionally
a first-order low-pass of the compensated specific force in an almost inertial frame (the
running mean is rotated into each new body frame by the gyro increment, VQF's tau_acc), the
mean then being the measurement. With lowpass_bias the mean's measurement model also
carries the gyro bias: its samples were turned into the current body frame with the
bias-corrected gyro, so a bias error db turned each by db integrated over its age, and the
mean reads ``y + [y]x (dtheta + J db)`` with ``J`` (3x3, ``tau I`` at rest) rotated and
aged with the mean by the kernel (``x[X_JLAG]``). Gate: ``| |f| - g | < accel_norm_gate g`` (a rejected
sample logs NaN), then each innovation component within ``gate_accel`` sigmas.
With accel_fuse_rate (error-state filters) the mean is fused at that rate rather than at
every IMU sample, each fusion with R / k for the k samples it stands for, while the gain is
small (:func:`windahrs.core.kalman.samples_to_fuse`); its log then has a row per fusion, the NIS per sample.
Innovation key: ``"accel"`` (3 rows). Parameters: accel_sigma, accel_noise_online,
accel_noise_mean_start, accel_norm_gate, accel_compensation, accel_lowpass,
lowpass_bias, accel_fuse_rate, gate_accel, reset_timeout, start_check, gated_start.

Start check (:func:`start_check`): accel_lowpass seconds after the start, the plain mean of
every sample since then is held against the state's gravity by the lost-gravity test, and a
start that failed it is levelled at once.

Start off the gate (gated_start, :func:`gate_start`): after a start whose sample the
gravity gate rejects, each sample is fused rather than the mean for GATED_START_SAMPLES_S,
the update leaves the gyro bias as it is for GATED_START_BIAS_TAUS accel_lowpass
(:func:`windahrs.core.kalman._keep_bias`), and the start check restarts the mean from the
plain one.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from windahrs.core.kalman import (
    _bias_rows,
    _fuse,
    _log,
    _vector_rows,
    att_var_along,
    lag_age,
    lag_bias_rows,
    per_sample_nis,
    samples_to_fuse,
)
from windahrs.core.layout import (
    _JIT_CORE,
    ADD_COV,
    ADD_NONE,
    COMP_AIRSPEED,
    COMP_GNSS,
    INN_ACCEL,
    INN_LEVEL,
    S_AGNSS,
    S_FBAR,
    S_VAIR,
    W_NU,
    X_AGNSS,
    X_AVAR,
    X_BA,
    X_BG,
    X_FBAR,
    X_FGAIN,
    X_JLAG,
    X_KEEPBG,
    X_NFUSE,
    X_NRM,
    X_OFFSTART,
    X_Q,
    X_RM,
    X_TGFUSE,
    X_TINIT,
    X_TOK,
    X_VAIR,
)
from windahrs.core.predict import add_to_mean, steady_gain, track_accel_noise
from windahrs.core.quat import (
    _dcm9,
)
from windahrs.core.reset import (
    accepted_at,
    level_to,
    log_reset,
    reset_gyro_bias,
    retake_heading,
    set_attitude_cov,
    timed_out,
)

#: cos of the tilt disagreement beyond which the filter has lost gravity (45 deg: no sustained
#: flight manoeuvre but aerobatics holds a horizontal acceleration of 1 g, so the (low-passed)
#: specific force of a filter that knows its tilt stays within it; the gate rejects such a
#: measurement for good, and an accepted one cannot turn a filter that is upside down, where
#: the gravity innovation has no gradient).
LOST_COS = math.cos(math.radians(45.0))
#: ... and within it, the disagreement beyond which a mean force of gravity's length is no
#: acceleration (the filter has lost gravity too): an acceleration across gravity that turns
#: the specific force by d lengthens it to g / cos d, so a force within ACCEL_TURN_NORM (10 %)
#: of g is turned by at most acos(1 / 1.1) = 24.6 deg (a coordinated turn's 30 deg bank reads
#: 1.155 g). Without it a filter 25-45 deg off whose gate rejects every sample (the additive
#: [ekf7], [usque] after a 90 deg start on the quadrotor in wind: 44 deg for good) never resets.
ACCEL_TURN_NORM = 0.1
ACCEL_TURN_COS = 1.0 / (1.0 + ACCEL_TURN_NORM)

#: ... and the low-passed means' gyro-bias columns (the Kalman filters that model them: not
#: [usque], whose unscented update has no such columns).
LAG_PARAMS = ("lowpass_bias",)
#: ... and the mean fused at a lower rate (the error-state filters: core.kalman.samples_to_fuse).
FUSE_RATE_PARAMS = ("accel_fuse_rate",)
#: ... and a start off the gravity gate (the error-state filters: the update that keeps the gyro bias,
#: core.kalman._keep_bias).
GATED_START_PARAMS = ("gated_start",)

#: A start whose sample the gravity gate rejects (gated_start): for this long, s, the gravity
#: aid fuses each sample, not the mean, so that the state takes the plain mean of the samples
#: (VQF's start of its low-pass) rather than the start's one sample, which the mean holds with
#: weight exp(-t / accel_lowpass): a rotor's vibration of several m/s^2 averages out over about
#: a hundred samples, and a multirotor's attitude loop (about 1 Hz) over a second (the
#: init_window rationale, EskfParams). At most accel_lowpass, where the start check ends it
#: and restarts the mean from the plain one (start_check).
GATED_START_SAMPLES_S = 1.0
#: ... and for this many accel_lowpass from the start the gravity update leaves the gyro bias
#: as it is (core.kalman._keep_bias): the state's start is off by the start sample's error,
#: and the mean's drift away from that sample is no drift of the state. VQF clips its bias
#: correction for that reason ("this also effectively limits the harm done by the first
#: inclination correction step", biasClip 2 deg/s).
GATED_START_BIAS_TAUS = 2.0
#: The parameters of this aid source (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = (
    "accel_sigma",
    "accel_noise_online",
    "accel_noise_mean_start",
    "accel_norm_gate",
    "accel_compensation",
    "accel_lowpass",
    "gate_accel",
    "reset_timeout",
    "start_check",
)


@njit(inline="always", **_JIT_CORE)
def knows_gravity(cos_d, fn, g):
    """Whether a state still knows gravity, given the cosine cos_d between its down direction
    and the measured one (-f / |f|, f the sample or its mean) and the length fn m/s^2 of the
    sample itself (not of a mean: a turn's force, turning in the gyro-compensated frame,
    averages out of a mean and leaves it near g): within 45 deg (LOST_COS), and, beyond
    ACCEL_TURN_COS, only with a length that an acceleration explains."""
    return cos_d > LOST_COS and (cos_d > ACCEL_TURN_COS or abs(fn - g) > ACCEL_TURN_NORM * g)


@njit(**_JIT_CORE)
def _level_reset(cfg, prm, x, flags, P, work, inn, acc, t, fx, fy, fz):
    """The filter has lost gravity: level the attitude to the specific force f (body), reopen
    its spread, reset the gyro bias, log the reset (of the accelerometer) and take the heading
    again from the next magnetometer sample."""
    angle = level_to(x, -fx, -fy, -fz)
    set_attitude_cov(cfg, prm, x, P, work)
    reset_gyro_bias(cfg, prm, x, P)
    log_reset(cfg, flags, inn, acc, work, x, np.int64(INN_ACCEL), t, angle)
    retake_heading(cfg, prm, x, flags, t)


@njit(**_JIT_CORE)
def start_check(cfg, prm, x, flags, P, work, inn, acc, t, c, g, fx, fy, fz):
    """The start check (start_check): the mean x[X_FBAR] starts at the start's specific force
    (one sample, or init_window's mean) and forgets it over accel_lowpass, so a start sample
    that vibration or a manoeuvre turned by tens of degrees stays in the measurement for
    seconds, the state follows it, and the gyro bias takes up the difference as the mean
    drifts to the truth (docs/RESULTS.md, section 23). Beside it, the plain mean of every
    (compensated) sample f since the start, x[X_RM] (x[X_NRM] samples), turns with the body
    as the mean does. Once it spans accel_lowpass, VQF's start of its low-pass filters, it is
    held against the state's gravity by the test of the lost-gravity reset (knows_gravity:
    45 deg, or 25 deg at gravity's length; the plain mean's own length, since its direction
    and its length average the same samples: an acceleration that averaged out of the one
    averaged out of the other); failing it, the filter is levelled to it (gyro
    bias reset, the mean restarted from it) at once rather than after reset_timeout. Then
    the check ends. Returns whether it reset (the sample is then not fused). c: C_nb
    row-major of the state."""
    n = x[X_NRM] + 1.0
    add_to_mean(x, np.int64(X_RM), n, fx, fy, fz)
    x[X_NRM] = n
    if t - x[X_TINIT] < prm["accel_lowpass"]:
        return False
    x[X_NRM] = 0.0  # checked once
    rx, ry, rz = x[X_RM], x[X_RM + 1], x[X_RM + 2]
    if cfg["gated_start"] == 1 and x[X_OFFSTART] > 0:
        # after a start sample the gate rejects, the mean goes on from the plain one (VQF's
        # low-pass state at accel_lowpass), not from its exp(-1) share of that sample
        x[X_FBAR], x[X_FBAR + 1], x[X_FBAR + 2] = rx, ry, rz
    rn = math.sqrt(rx * rx + ry * ry + rz * rz)
    if rn <= 0.0 or knows_gravity(-(c[6] * rx + c[7] * ry + c[8] * rz) / rn, rn, g):
        return False
    x[X_TOK + INN_ACCEL] = t + prm["accel_lowpass"]  # logged as out for -accel_lowpass s: the start check
    _level_reset(cfg, prm, x, flags, P, work, inn, acc, t, rx, ry, rz)
    # the mean goes on from the plain one; its bias sensitivity J stays the exponential
    # mean's, of the same samples (a sensitivity of zero would tell the filter that a gyro
    # bias never turned them: measured on the simulated quadrotor started 90 deg off, 2.9
    # deg of tilt 2 s after the reset against 1.5)
    x[X_FBAR], x[X_FBAR + 1], x[X_FBAR + 2] = rx, ry, rz
    return True


@njit(inline="always", **_JIT_CORE)
def gate_start(prm, x, f0):
    """At the start (gated_start): whether its specific force x[f0:f0+3] (one sample, or
    init_window's mean) is one the gravity gate would reject, its length off gravity by more
    than accel_norm_gate, so no reading of gravity to start from (ANSFL path_6's first
    sample, 0.46 g under rotor vibration, is 37 deg from its first second's mean): x[X_OFFSTART]
    1 or 0, and x[X_KEEPBG] how long the gravity update then leaves the gyro bias as it is
    (GATED_START_BIAS_TAUS accel_lowpass, or 0; core.kalman._fuse reads it)."""
    fn = math.sqrt(x[f0] ** 2 + x[f0 + 1] ** 2 + x[f0 + 2] ** 2)
    off = abs(fn - prm["gravity"]) > prm["accel_norm_gate"] * prm["gravity"]
    x[X_OFFSTART] = 1.0 if off else 0.0
    x[X_KEEPBG] = GATED_START_BIAS_TAUS * prm["accel_lowpass"] if off else 0.0


@njit(inline="always", **_JIT_CORE)
def blend_mean(prm, x, a, fx, fy, fz):
    """The low-passed specific force x[X_FBAR] (already carried into this body frame by
    kernel._rotate_lowpass) after the sample f with gain a; returns the new mean. With
    lowpass_bias its bias sensitivity J ages with it: the new sample carries no
    rotation error yet."""
    x[X_FBAR] = x[X_FBAR] + a * (fx - x[X_FBAR])
    x[X_FBAR + 1] = x[X_FBAR + 1] + a * (fy - x[X_FBAR + 1])
    x[X_FBAR + 2] = x[X_FBAR + 2] + a * (fz - x[X_FBAR + 2])
    if prm["lowpass_bias"] > 0:
        lag_age(x, np.int64(X_JLAG), a)
    return x[X_FBAR], x[X_FBAR + 1], x[X_FBAR + 2]


@njit(inline="always", **_JIT_CORE)
def accel_variance(cfg, prm, x):
    """The gravity measurement's variance per axis: accel_sigma^2, plus the accelerometer's
    noise measured on line (core.predict.track_accel_noise) with accel_noise_online."""
    return prm["accel_var"] + x[X_AVAR] if cfg["accel_noise_online"] >= 1 else prm["accel_var"]


@njit(inline="always", **_JIT_CORE)
def fuse_gravity(cfg, prm, x, flags, P, work, sup, inn, acc, t, row, dt):
    """The accelerometer of IMU sample ``row`` = [w_b, f_b] at t s, after the prediction
    over dt s: the specific force (compensated, optionally low-passed) as a measurement of
    gravity, ``h = C_bn (-g_n) (+ compensation) (+ b_a)``, ``H_att = [h_g]x``, R = accel_sigma^2 I,
    gated on ``| |f| - g | > accel_norm_gate g`` and on the innovation (gate_accel)."""
    fx, fy, fz = row[3], row[4], row[5]
    if cfg["accel_noise_online"] >= 1 and dt > 0:  # the accelerometer's noise on line
        track_accel_noise(cfg, prm, x, dt)
    # the accelerometer as a gravity measurement (or its low-passed mean), gated on |f|
    nu = work[W_NU]
    g = prm["gravity"]
    c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    k0, k1, k2 = 0.0, 0.0, 0.0  # compensation acceleration, body
    comp = cfg["accel_compensation"]
    has_k = False
    if comp == COMP_AIRSPEED and flags[S_VAIR] == 1:  # (w - bg) x V_air
        ux, uy, uz = row[0] - x[X_BG], row[1] - x[X_BG + 1], row[2] - x[X_BG + 2]
        vx, vy, vz = x[X_VAIR], x[X_VAIR + 1], x[X_VAIR + 2]
        k0, k1, k2 = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        has_k = True
    elif comp == COMP_GNSS and flags[S_AGNSS] == 1:  # C_bn a_gnss
        ax, ay, az = x[X_AGNSS], x[X_AGNSS + 1], x[X_AGNSS + 2]
        k0 = c[0] * ax + c[3] * ay + c[6] * az
        k1 = c[1] * ax + c[4] * ay + c[7] * az
        k2 = c[2] * ax + c[5] * ay + c[8] * az
        has_k = True
    # the sample's own length (compensated): a mean's is no measure of acceleration, since a
    # turn's force, turning in the gyro-compensated frame, averages out of it (knows_gravity)
    f_now = math.sqrt((fx - k0) ** 2 + (fy - k1) ** 2 + (fz - k2) ** 2)
    lag = flags[S_FBAR] == 1  # the measurement is the mean (else the sample)
    if flags[S_FBAR] == 1:  # the mean of the compensated specific force, no compensation after
        a = steady_gain(x, np.int64(X_FGAIN), dt, prm["accel_lowpass"])
        if has_k:
            fx, fy, fz = fx - k0, fy - k1, fz - k2
        # a start off the gate fuses its first samples themselves (GATED_START_SAMPLES_S)
        raw = (cfg["gated_start"] == 1 and x[X_OFFSTART] > 0 and x[X_NRM] > 0
               and t - x[X_TINIT] < GATED_START_SAMPLES_S)
        if x[X_NRM] > 0 and start_check(cfg, prm, x, flags, P, work, inn, acc, t, c, g, fx, fy, fz):
            return
        sx, sy, sz = fx, fy, fz
        fx, fy, fz = blend_mean(prm, x, a, fx, fy, fz)
        if raw:
            fx, fy, fz = sx, sy, sz
            lag = False
        has_k = False
    sensor = np.int64(INN_ACCEL)
    if abs(math.sqrt(fx * fx + fy * fy + fz * fz) - g) > prm["accel_norm_gate"] * g:
        nu[0], nu[1], nu[2] = np.nan, np.nan, np.nan
        _log(cfg, flags, inn, acc, nu, sensor, t, np.int64(3), np.nan, np.bool_(False))
        return
    y0, y1, y2 = c[6] * -g, c[7] * -g, c[8] * -g  # C_bn (-g_n)
    gx, gy, gz = (fx - k0, fy - k1, fz - k2) if has_k else (fx, fy, fz)
    # the state still knows gravity while the measured down direction is within 45 deg of
    # its C_bn e_3 = -y / g, accepted or not (a sustained acceleration is gated out, and
    # the filter rightly coasts on the gyro through it), unless the sample has gravity's
    # length while the measured down is beyond ACCEL_TURN_COS of the state's: no acceleration
    # turns the force that far without lengthening it
    fn = math.sqrt(gx * gx + gy * gy + gz * gz)
    if knows_gravity((gx * y0 + gy * y1 + gz * y2) / (g * fn), f_now, g):
        accepted_at(x, sensor, t)
    elif timed_out(prm, x, sensor, t):  # gravity far off the state for too long: level to it
        _level_reset(cfg, prm, x, flags, P, work, inn, acc, t, gx, gy, gz)
        return
    var = accel_variance(cfg, prm, x)
    kf = 1.0
    if lag and cfg["add_form"] == ADD_NONE and prm["accel_fuse_dt"] > 0:  # at accel_fuse_rate
        tilt_var = P[0, 0] + P[1, 1] + P[2, 2] - att_var_along(P, c[6], c[7], c[8])  # (less the part about down)
        kf = samples_to_fuse(x, np.int64(X_NFUSE), np.int64(X_TGFUSE), t, prm["accel_fuse_dt"], 0.5 * dt,
                             tilt_var, var / (g * g))
        if kf == 0.0:  # (this sample is in the next fusion)
            return
    var /= kf
    h0, h1, h2 = y0, y1, y2
    if has_k:
        h0, h1, h2 = y0 + k0, y1 + k1, y2 + k2
    _vector_rows(work, sup[0], y0, y1, y2, var)
    nsup = 3
    ib = cfg["i_bg"]
    if lag and prm["lowpass_bias"] > 0 and ib >= 0 and cfg["add_form"] != ADD_COV:
        # the mean's samples were rotated into this body frame by the bias-corrected gyro:
        # a bias error db turned each by its integral over the sample's age, so the mean
        # reads y + [y]x (dtheta + J db), J = d mean / d b_g kept by the kernel (tau I at
        # rest, and rotated with the body): H_b = [y]x J
        nsup = lag_bias_rows(work, sup[0], x, np.int64(X_JLAG), ib, np.int64(3), nsup)
    iba = cfg["i_ba"]
    if iba >= 0:  # (no accelerometer fusion in the INS; kept for the general model)
        h0, h1, h2 = h0 + x[X_BA], h1 + x[X_BA + 1], h2 + x[X_BA + 2]
        nsup = _bias_rows(work, sup[0], iba, nsup)
    nu[0], nu[1], nu[2] = fx - h0, fy - h1, fz - h2
    m, ns = np.int64(3), np.int64(nsup)
    # (gated as one sample: with R / k the innovation's variance is about 1 / k of a sample's,
    # while the mean's innovation is a sample's, so the gate opens by k)
    _fuse(cfg, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, prm["gate_accel2"] * kf)
    per_sample_nis(cfg, flags, inn, sensor, kf)


@njit(**_JIT_CORE)
def fuse_level(cfg, prm, x, flags, P, work, sup, inn, acc, t, fx, fy, fz, var):
    """The INS at rest (:mod:`windahrs.aid.rest`): the mean specific force f (body) of a
    vehicle that does not accelerate as a measurement of gravity and the accelerometer's
    bias, ``h = C_bn (-g_n) + b_a``, ``H_att = [h_g]x``, ``H_ba = I``, R = var I, gated at
    gate_accel. Innovation key: ``"level"``. The INS takes the accelerometer as its input and
    otherwise sees its tilt only through GNSS velocity; a strapdown INS levels on its
    accelerometers while it stands still (stationary, or "fine", alignment)."""
    g = prm["gravity"]
    c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    y0, y1, y2 = c[6] * -g, c[7] * -g, c[8] * -g  # C_bn (-g_n)
    _vector_rows(work, sup[0], y0, y1, y2, var)
    nsup = _bias_rows(work, sup[0], cfg["i_ba"], np.int64(3))
    nu = work[W_NU]
    nu[0], nu[1], nu[2] = fx - y0 - x[X_BA], fy - y1 - x[X_BA + 1], fz - y2 - x[X_BA + 2]
    _fuse(cfg, x, flags, P, work, sup, inn, acc, np.int64(INN_LEVEL), t, np.int64(3), np.int64(nsup),
          prm["gate_accel2"])
