"""The compiled event loop of the error-state and additive EKFs: initialisation, the
prediction at each IMU sample, the dispatch of every other sample to its aid sources
(windahrs.aid), recording, and the Python side (encoding parameters once into a
:class:`KernelState`, the batch run and the streamer).

Event order: samples are processed in time order; at equal times the IMU sample comes
first (propagation to ``t``), then magnetometer, GNSS and air data. The batch run feeds
:func:`run_events` the whole merged event list; :class:`CompiledStreamer` feeds it one
event at a time (without recording), so a flight streamed equals its batch run bit for bit.
Nothing is allocated inside the loop.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, ClassVar, Literal, NamedTuple

import numpy as np
from numba import njit

from windahrs.aid.air_vector import (
    air_clock,
    fuse_air_vector,
    init_wind,
    reset_wind,
    wind_lost,
)
from windahrs.aid.air_velocity import (
    remember_air,
)
from windahrs.aid.airspeed_scale import (
    airspeed_scale_step,
    asc_state,
)
from windahrs.aid.aoa import (
    fuse_aoa,
)
from windahrs.aid.drag import (
    fuse_drag,
)
from windahrs.aid.gnss_vel import (
    fuse_gnss,
    remember_gnss,
    remember_specific_force,
)
from windahrs.aid.gravity import (
    fuse_gravity,
    gate_start,
)
from windahrs.aid.mag import (
    _set_mag_reference,
    fuse_mag,
)
from windahrs.aid.rest import (
    fuse_rest,
    rest_state,
)
from windahrs.aid.sideslip import (
    fuse_sideslip,
)
from windahrs.aid.tas import (
    fuse_tas,
)
from windahrs.core import pool
from windahrs.core.events import sample_ok
from windahrs.core.imu_screen import screen_imu, screen_state
from windahrs.core.kalman import grown_logs, log_layout, read_airspeed_scale, read_held, read_logs, read_resets
from windahrs.core.layout import (
    _JIT_CORE,
    AIR_AIRSPEED,
    AIR_AUTO,
    AIR_OFF,
    AIR_VECTOR,
    CFG,
    COMP_AIRSPEED,
    COMP_GNSS,
    COMP_NONE,
    F64,
    I64,
    INN_AIR,
    K_SKIP,
    KIND_INS,
    KIND_MEKF,
    KIND_MEKF_AIR,
    L_CNT,
    L_FIRST,
    MAG_3D,
    MAG_HEADING,
    MAG_OFF,
    N_FLAGS,
    N_SENSORS,
    N_WORK,
    N_X,
    NMAX,
    PRM,
    REST_ALIGN,
    REST_OFF,
    REST_ON,
    REST_START,
    S_FBAR,
    S_FLAST,
    S_FMAG,
    S_FV,
    S_HEADLESS,
    S_INIT,
    S_MBAR,
    S_VGNSS,
    S_WIN,
    S_WPEND,
    SENSOR_STREAMS,
    TRIANGLE_N,
    W_IMU,
    W_M,
    W_PEEK,
    X_BA,
    X_BG,
    X_BM,
    X_DF,
    X_DW,
    X_FBAR,
    X_FLAST,
    X_FMAG,
    X_FV,
    X_FWIN,
    X_JLAG,
    X_JMAG,
    X_MBAR,
    X_NRM,
    X_NWIN,
    X_PDT,
    X_PN,
    X_Q,
    X_RM,
    X_TGOK,
    X_TIMU,
    X_TINIT,
    X_TMOK,
    X_TMPASS,
    X_TMREIN,
    X_TOK,
    X_TWIN0,
    X_V,
    X_VAIR,
    X_W,
    X_WLAST,
    KernelState,
    cov_stride_of,
)
from windahrs.core.pool import stream_fence, stream_store3
from windahrs.core.predict import (
    _nominal_es,
    _predict_add,
    _predict_es,
    add_held_sample_noise,
    add_to_mean,
    cov_pending,
    defer_cov,
    flush_cov,
    track_accel_noise,
)
from windahrs.core.quat import (
    _dcm9,
    _qexp,
    _triad,
    _xi_into,
)
from windahrs.core.reset import accepted_at, attitude_cov_about_vertical, set_attitude_cov
from windahrs.core.smooth import no_smoothing, record_post, record_pre
from windahrs.estimate import Estimate, Innovations
from windahrs.filters.base import (
    COV_RECORDS,
    EVENT_AIR,
    EVENT_GNSS,
    EVENT_IMU,
    EVENT_MAG,
    CovRecord,
    Estimator,
    EventStreamer,
    InitialState,
    StateView,
    merge_events,
    stream_counts,
)
from windahrs.filters.checks import checked
from windahrs.filters.params import EskfParams, flight_params
from windahrs.flight import Flight, Site
from windahrs.models.error_state import Layout

#: How long the initialisation waits for a magnetometer the flight has, s: a magnetometer
#: logs at 10 Hz or more (PX4 50-100 Hz, ArduPilot 10-100 Hz), so a second without a sample
#: is one that starts late or not at all. The filter then starts without it (its heading
#: the gyro's from yaw 0, said in the Estimate) and turns to the field's heading at the first
#: sample (:func:`windahrs.aid.mag.fuse_mag`).
MAG_WAIT = 1.0
#: The heading's variance, rad^2, in the rows recorded while the filter waits for the
#: magnetometer that will set it (heading 0 stands for "unknown"): a heading uniform on the
#: circle, pi^2 / 3.
HEADING_UNKNOWN_VAR = math.pi**2 / 3.0


@njit(**_JIT_CORE)
def _try_init(cfg, prm, x, flags, P, work):
    """Initialise once every sample it waits for is in: attitude by TRIAD from the mean
    specific force of the first init_window seconds and the latest field (or the given
    initial state), the covariance (on the quaternion for the additive form), the field
    reference, the low-pass means. x[X_TIMU]: the time of the last IMU sample."""
    if flags[S_INIT] == 1 or flags[S_WIN] == 0:
        return
    if cfg["init_given"] == 0 and x[X_TIMU] - x[X_TWIN0] < prm["init_window"]:
        return
    headless = cfg["wait_mag"] == 1 and flags[S_FMAG] == 0
    if headless and x[X_TIMU] - x[X_TWIN0] < MAG_WAIT:
        return
    if cfg["wait_gnss"] == 1 and flags[S_FV] == 0:
        return
    f0 = _initial_state(cfg, prm, x, flags, P, work)
    if flags[S_FMAG] == 1:
        _set_mag_reference(cfg, prm, x, flags, x[X_FMAG], x[X_FMAG + 1], x[X_FMAG + 2])
    elif cfg["site_mag_known"] == 1:
        _set_mag_reference(cfg, prm, x, flags, 0.0, 0.0, 0.0)
    if prm["accel_lowpass"] > 0:
        for a in range(3):
            x[X_FBAR + a] = x[f0 + a]
        for a in range(9):
            x[X_JLAG + a] = 0.0
        flags[S_FBAR] = 1
        if cfg["start_check"] == 1:  # the start check's running mean (aid.gravity.start_check)
            for a in range(3):
                x[X_RM + a] = x[f0 + a]
            x[X_NRM] = 1.0
        if cfg["gated_start"] == 1:  # a start off the gravity gate (aid.gravity.gate_start)
            gate_start(prm, x, f0)
    flags[S_WPEND] = 1 if (cfg["i_w"] >= 0 and cfg["init_wind_given"] == 0) else 0
    for s in range(N_SENSORS):  # every aid source's reset clock starts now
        x[X_TOK + s] = x[X_TIMU]
    flags[S_HEADLESS] = 1 if headless else 0
    flags[S_INIT] = 1
    x[X_TINIT] = x[X_TIMU]


@njit(**_JIT_CORE)
def _initial_state(cfg, prm, x, flags, P, work):
    """The state and covariance the filter starts from if it initialises now (x and P
    overwritten): the attitude by TRIAD from the specific force (the window's mean, or the
    last sample) and the latest field (heading 0 without one), or the given initial state;
    the biases zero or given; the velocity the last GNSS sample's (zero before one) or
    given; the wind zero or given; the initial spreads. Returns the index in x of the
    specific force used. :func:`_try_init` starts from it, and :func:`record` writes it
    for the samples before the start (flagged not_initialised), so that no output is NaN."""
    f0 = X_FWIN if prm["init_window"] > 0 else X_FLAST  # the window's mean, or the last sample
    if cfg["init_given"] == 1:
        q = (prm["init_q"][0], prm["init_q"][1], prm["init_q"][2], prm["init_q"][3])
    elif flags[S_FLAST] == 0:  # no IMU sample yet (only NaN ones): level
        q = (1.0, 0.0, 0.0, 0.0)
    else:
        # north: the site's field, or (unknown) its declination, 0 when that is unknown too
        if cfg["site_mag_known"] == 1:
            rx, ry, rz = prm["site_mag"][0], prm["site_mag"][1], prm["site_mag"][2]
        else:
            rx, ry, rz = math.cos(prm["site_decl"]), math.sin(prm["site_decl"]), 0.0
        q = _triad(
            x[f0], x[f0 + 1], x[f0 + 2],
            flags[S_FMAG] == 1, x[X_FMAG], x[X_FMAG + 1], x[X_FMAG + 2], True, rx, ry, rz,
        )  # fmt: skip
    x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = q
    iv, ib, iw, iba = cfg["i_v"], cfg["i_bg"], cfg["i_w"], cfg["i_ba"]
    for a in range(3):
        x[X_BG + a] = prm["init_bias"][a] if cfg["init_bias_given"] == 1 else 0.0
        if iv >= 0:
            x[X_V + a] = prm["init_v"][a] if cfg["init_v_given"] == 1 else x[X_FV + a]
        if iw >= 0:
            x[X_W + a] = prm["init_wind"][a] if cfg["init_wind_given"] == 1 else 0.0
        x[X_BA + a] = 0.0
        x[X_BM + a] = 0.0
    for i in range(P.shape[1]):
        for j in range(P.shape[1]):
            P[i, j] = 0.0
    off = cfg["add_form"]  # covariance index = error-state index + 1 after the quaternion
    for a in range(3):
        P[ib + off + a, ib + off + a] = prm["init_bias_var"]
        if iv >= 0:
            P[iv + off + a, iv + off + a] = prm["init_v_var"]
        if iw >= 0:
            P[iw + off + a, iw + off + a] = prm["init_wind_var"] if a < 2 else prm["init_wind_vertical_var"]
        if iba >= 0:
            P[iba + off + a, iba + off + a] = prm["init_accel_bias_var"]
        if cfg["i_bm"] >= 0:
            P[cfg["i_bm"] + off + a, cfg["i_bm"] + off + a] = prm["init_mag_bias_var"]
    set_attitude_cov(cfg, prm, x, P, work)
    return f0


@njit(**_JIT_CORE)
def _window_add(x, flags, t, row):
    """One IMU sample row = [w_b, f_b] at t s into the initialisation window: the running
    mean of the specific force, rotated into the current body frame by the gyro increment
    (bias unknown yet: a window of a second turns it by a bias's worth of degrees at most)."""
    if flags[S_WIN] == 0:
        x[X_FWIN], x[X_FWIN + 1], x[X_FWIN + 2] = row[3], row[4], row[5]
        x[X_NWIN] = 1.0
        x[X_TWIN0] = t
        flags[S_WIN] = 1
        return
    dt = t - x[X_TIMU]
    if dt > 0:
        _rotate_into(_turn(row[0], row[1], row[2], dt), x, np.int64(X_FWIN))
    n = x[X_NWIN] + 1.0
    x[X_NWIN] = n
    add_to_mean(x, np.int64(X_FWIN), n, row[3], row[4], row[5])



@njit(**_JIT_CORE)
def _rotate_lowpass(cfg, prm, x, flags, e, dt):
    """The low-passed vectors into the new body frame,
    v <- C(e)^T v, e = Exp(w dt) the step's turn (w bias-corrected; the prediction's own,
    :func:`windahrs.core.predict._predict_es` returns it); with lowpass_bias, their bias
    sensitivities too, J <- C^T J + dt I (:func:`windahrs.aid.gravity.fuse_gravity`,
    :mod:`windahrs.aid.mag`); and the start check's running mean
    (:func:`windahrs.aid.gravity.start_check`) while it runs."""
    c = _dcm9(e[0], e[1], e[2], e[3])
    if flags[S_FBAR] == 1:
        _rotate_into(c, x, np.int64(X_FBAR))
        if prm["lowpass_bias"] > 0:
            _age_rotated(c, x, np.int64(X_JLAG), dt)
    if x[X_NRM] > 0:
        _rotate_into(c, x, np.int64(X_RM))
    if flags[S_MBAR] == 1:
        _rotate_into(c, x, np.int64(X_MBAR))
        if prm["lowpass_bias"] > 0 and cfg["mag_mode"] == MAG_3D:
            _age_rotated(c, x, np.int64(X_JMAG), dt)


@njit(inline="always", **_JIT_CORE)
def _age_rotated(c, x, ij, dt):
    """A mean's bias sensitivity J = x[ij:ij+9] (row-major) over one step: its columns
    rotated like the mean, and every sample dt older, J <- C^T J + dt I."""
    for j in range(3):
        _rotate_cols(c, x, ij + j)
        x[ij + 4 * j] += dt


@njit(inline="always", **_JIT_CORE)
def _turn(wx, wy, wz, dt):
    """C(Exp(w dt)), row-major: the body's turn over one IMU step at the rate w."""
    e = _qexp(wx * dt, wy * dt, wz * dt)
    return _dcm9(e[0], e[1], e[2], e[3])


@njit(inline="always", **_JIT_CORE)
def corrected_turn(x, row, dt):
    """Exp((w - b_g) dt), the body's turn over one IMU step of dt s at the bias-corrected
    rate of row = [w_b, ...] (what the error-state prediction turns the attitude by)."""
    return _qexp((row[0] - x[X_BG]) * dt, (row[1] - x[X_BG + 1]) * dt, (row[2] - x[X_BG + 2]) * dt)


@njit(inline="always", **_JIT_CORE)
def _rotate_cols(c, x, i0):
    """x[i0], x[i0+3], x[i0+6] (a column of a row-major 3x3) <- C^T of it (c: C row-major)."""
    v0, v1, v2 = x[i0], x[i0 + 3], x[i0 + 6]
    x[i0] = c[0] * v0 + c[3] * v1 + c[6] * v2
    x[i0 + 3] = c[1] * v0 + c[4] * v1 + c[7] * v2
    x[i0 + 6] = c[2] * v0 + c[5] * v1 + c[8] * v2


@njit(**_JIT_CORE)
def _rotate_into(c, x, i0):
    """x[i0:i0+3] <- C^T x[i0:i0+3] (c: C row-major)."""
    v0, v1, v2 = x[i0], x[i0 + 1], x[i0 + 2]
    x[i0] = c[0] * v0 + c[3] * v1 + c[6] * v2
    x[i0 + 1] = c[1] * v0 + c[4] * v1 + c[7] * v2
    x[i0 + 2] = c[2] * v0 + c[5] * v1 + c[8] * v2



@njit(inline="always", **_JIT_CORE)
def imu_clock(cfg, prm, x, flags, P, work, t, row):
    """Every filter's first step at an IMU sample row = [w_b, f_b] at t s: keep the specific
    force, initialise when it can; returns the step dt s since the last IMU sample, or -1
    while not initialised (nothing else to do)."""
    if flags[S_FLAST] == 1:  # the sample-to-sample changes (the held-sample noise of the prediction)
        for a in range(3):
            x[X_DW + a] = row[a] - x[X_WLAST + a]
            x[X_DF + a] = row[3 + a] - x[X_FLAST + a]
    for a in range(3):
        x[X_WLAST + a] = row[a]
        x[X_FLAST + a] = row[3 + a]
    flags[S_FLAST] = 1
    if flags[S_INIT] == 0:
        _window_add(x, flags, t, row)
        x[X_TIMU] = t
        _try_init(cfg, prm, x, flags, P, work)
        return -1.0
    dt = t - x[X_TIMU]
    x[X_TIMU] = t
    return dt


@njit(inline="always", **_JIT_CORE)
def mag_ready(cfg, prm, x, flags, P, work, row):
    """Every filter's first step at a magnetometer sample row[:3] T: before initialisation
    keep the first sample (with an init_window, the latest) for the initial heading; returns
    whether initialised."""
    if flags[S_INIT] == 0:
        if flags[S_FMAG] == 0 or prm["init_window"] > 0:
            x[X_FMAG], x[X_FMAG + 1], x[X_FMAG + 2] = row[0], row[1], row[2]
        flags[S_FMAG] = 1
        _try_init(cfg, prm, x, flags, P, work)
        return False
    return True


@njit(inline="always", **_JIT_CORE)
def cov_deferred(cfg, prm, rs, dt):
    """Whether an IMU step of dt s (> 0) leaves its covariance prediction to the period's
    (cov_period, :func:`~windahrs.core.predict.defer_cov`): in a filter that defers (cfg
    cov_defer: the INS without drag, cov_period > 0), a step no longer than
    unmeasured_motion_dt (a longer one adds its held-sample noise to P at once) while no rest
    update may read P (rest detection off, or its start's rest over: rs["n"] < 0)."""
    return (cfg["cov_defer"] == 1 and dt <= prm["unmeasured_motion_dt"]
            and (cfg["rest"] == REST_OFF or rs["n"] < 0.0))


@njit(inline="always", **_JIT_CORE)
def step_imu(cfg, prm, x, flags, P, work, sup, inn, acc, sc, rs, t, row):
    """An IMU sample (finite): row = [w_b (3) rad/s, f_b (3) m/s^2], at t s:
    screened (:mod:`windahrs.core.imu_screen`), propagation, then the accelerometer's aid
    sources. sc, rs: the records of the IMU screen (core.imu_screen.SCREEN) and of the rest
    detector (aid.rest.REST)."""
    if screen_imu(cfg, prm, x, flags, sc, P, inn, acc, work, t, row):
        row = work[W_IMU]  # the sample propagated in its place
    dt = imu_clock(cfg, prm, x, flags, P, work, t, row)
    if dt < 0:
        return
    fx, fy, fz = row[3], row[4], row[5]
    if dt > 0:
        # (the low-passed means turn with the bias-corrected gyro as the attitude does: the
        # error-state prediction's own turn, Exp((w - b_g) dt), computed once; the
        # prediction does not change b_g)
        if cfg["add_form"] == 1:
            e = corrected_turn(x, row, dt)
            _predict_add(cfg, prm, x, P, work, row[0], row[1], row[2], dt)
        elif cov_deferred(cfg, prm, rs, dt) and (x[X_PN] > 0.0 or 1.5 * dt < prm["cov_period"]):
            # the covariance once per cov_period (predict.defer_cov; a step that closes the
            # period alone, a 100 Hz IMU's, is predicted whole below)
            e, _, wx, wy, wz, gx, gy, gz = _nominal_es(cfg, prm, x, row[0], row[1], row[2], fx, fy, fz, dt)
            defer_cov(x, wx, wy, wz, gx, gy, gz, dt)
            if x[X_PDT] + 0.5 * dt >= prm["cov_period"]:
                flush_cov(cfg, prm, x, P, work)
        else:
            flush_cov(cfg, prm, x, P, work)  # (the steps deferred before this one, if any)
            e = _predict_es(cfg, prm, x, P, work, row[0], row[1], row[2], fx, fy, fz, dt)
        if flags[S_FBAR] == 1 or flags[S_MBAR] == 1:
            _rotate_lowpass(cfg, prm, x, flags, e, dt)
        if dt > prm["unmeasured_motion_dt"]:  # (tested here: a call per sample costs more than the test)
            add_held_sample_noise(cfg, prm, x, P, work, dt)
        if cfg["rest"] != REST_OFF:  # the gyro's bias, when the vehicle is at rest
            fuse_rest(cfg, prm, x, flags, P, work, sup, inn, acc, rs, t, row, dt)
    if cfg["kind"] != KIND_INS:  # the INS takes the accelerometer as an input
        fuse_gravity(cfg, prm, x, flags, P, work, sup, inn, acc, t, row, dt)
        return
    remember_specific_force(x, flags, fx, fy, fz, dt)
    if cfg["accel_noise_online"] >= 1 and dt > 0:  # its noise, the input's density in the next prediction
        track_accel_noise(cfg, prm, x, dt)
    if cfg["drag"] == 1:  # ... and may also read the drag in it
        fuse_drag(cfg, prm, x, flags, P, work, sup, inn, acc, t, row)


@njit(inline="always", **_JIT_CORE)
def step_mag(cfg, prm, x, flags, P, work, sup, inn, acc, t, row):
    """A magnetometer sample (finite): row[:3] tesla, body, at t s."""
    if mag_ready(cfg, prm, x, flags, P, work, row):
        fuse_mag(cfg, prm, x, flags, P, work, sup, inn, acc, t, row)


@njit(inline="always", **_JIT_CORE)
def step_gnss(cfg, prm, x, flags, P, work, sup, inn, acc, t, row):
    """A GNSS velocity sample (finite): row[:3] m/s NED, at t s; before initialisation the
    first sample is kept for the initial velocity."""
    remember_gnss(prm, x, flags, t, row)
    if flags[S_INIT] == 0:
        if flags[S_FV] == 0:
            for a in range(3):
                x[X_FV + a] = row[a]
            flags[S_FV] = 1
        _try_init(cfg, prm, x, flags, P, work)
        return
    fuse_gnss(cfg, prm, x, flags, P, work, sup, inn, acc, t, row)


@njit(inline="always", **_JIT_CORE)
def flying_on_the_air(prm, tas):
    """Whether an airspeed reading of tas m/s is beyond gate_air sigmas (tas_sigma) of zero.
    The true airspeed ``|V_air|``, the angle of attack and the synthetic zero sideslip are
    functions of the air-relative velocity that are singular at zero (a length, and angles of
    a vector without a direction there): their linearisations hold only well away from it,
    and a reading within gate_air sigmas of zero cannot tell where that is. PX4 EKF2 likewise
    fuses an airspeed only above EKF2_ARSP_THR, and only a positive one. (PX4's
    airspeed_validated on PX4 ``sample_log_small.ulg``, on the ground, reads -3.2 to -1.7 m/s.)
    The paper's air-data vector ``V_T^b`` is linear in the air-relative velocity and is fused
    at any airspeed."""
    return tas > 0.0 and tas * tas > prm["gate_air2"] * prm["tas_var"]


@njit(inline="always", **_JIT_CORE)
def step_air(cfg, prm, x, flags, P, work, sup, inn, acc, ac, t, tas, aoa, beta):
    """An air-data sample: tas m/s (finite), aoa and sideslip rad (NaN: no vanes), at t s,
    to its aid sources: the air-data vector with both vanes (air_mode "vector", or "auto"),
    else true airspeed, the angle of attack of a vane without a sideslip vane ("vector" or
    "auto") and (synthetic_sideslip) a zero sideslip. With airspeed_scale, the airspeed is
    first corrected by the scale estimated on line (:mod:`windahrs.aid.airspeed_scale`; ac: its
    record, ASC). An airspeed within gate_air sigmas of zero (or below it) goes only to the
    air-data vector (:func:`flying_on_the_air`)."""
    vanes, ca, sa, cb, sb = remember_air(x, flags, tas, aoa, beta)
    kind = cfg["kind"]
    if flags[S_INIT] == 0 or kind == KIND_MEKF or cfg["air_mode"] == AIR_OFF:
        return
    mode = cfg["air_mode"]
    if mode == AIR_AUTO:
        mode = AIR_VECTOR if vanes else AIR_AIRSPEED
    vector = mode == AIR_VECTOR and vanes
    flying = flying_on_the_air(prm, tas)
    if not (flying or vector):
        return
    extra = 0.0
    if kind == KIND_MEKF_AIR:  # GNSS velocity as an input
        if flags[S_VGNSS] == 0:
            return
        extra = prm["gnss_var"]
    use_v = cfg["i_v"] >= 0
    extra_tas = extra  # the airspeed's added variance (the scale's too, when estimated)
    if cfg["airspeed_scale"] == 1 and flying:
        bv = beta if cfg["air_mode"] != AIR_AIRSPEED else np.nan  # the sideslip vane's, when fused
        syn = cfg["synthetic_sideslip"] == 1
        tc, var_scale = airspeed_scale_step(prm, x, flags, ac, inn, acc, cfg, work, t, tas, bv, syn, use_v)
        f = tc / tas if tas > 0 else 1.0
        x[X_VAIR], x[X_VAIR + 1], x[X_VAIR + 2] = f * x[X_VAIR], f * x[X_VAIR + 1], f * x[X_VAIR + 2]
        tas = tc
        extra_tas = extra + var_scale
    air_clock(prm, x, t)
    if flags[S_WPEND] == 1:
        init_wind(x, flags, use_v, vanes)
    elif wind_lost(cfg, prm, x, flags, t):
        reset_wind(cfg, prm, x, flags, P, work, inn, acc, t, use_v, vanes)
    if vector:
        if fuse_air_vector(cfg, prm, x, flags, P, work, sup, inn, acc, t, tas, ca, sa, cb, sb, use_v, extra_tas):
            accepted_at(x, np.int64(INN_AIR), t)
        return
    if fuse_tas(cfg, prm, x, flags, P, work, sup, inn, acc, t, tas, use_v, extra_tas):
        accepted_at(x, np.int64(INN_AIR), t)
    if cfg["air_mode"] != AIR_AIRSPEED and np.isfinite(aoa):  # one vane: its angle of attack alone
        fuse_aoa(cfg, prm, x, flags, P, work, sup, inn, acc, t, aoa, tas, use_v, extra)
    if cfg["synthetic_sideslip"] == 1:  # at the state after the airspeed update
        fuse_sideslip(cfg, prm, x, flags, P, work, sup, inn, acc, t, tas, use_v, extra)


#: The recorded covariance goes around the caches (non-temporal stores) from this size on: an
#: [ins-wind] row (18 x 18, 2.6 kB a sample) evicted the filter's own working set, while
#: [mekf]'s (6 x 6, 288 B: four and a half cache lines) paid for its partly written lines
#: flushed one by one: recording took 0.23 us a sample that way, about none through the caches
#: (stop 31, docs/RESULTS.md section 37); 9 x 9 ([mekf-air]) measured the same either way.
NT_RECORD_DIM = 12


@njit(inline="always", **_JIT_CORE)
def record(cfg, prm, x, flags, P, work, k, out_q, out_bg, out_v, out_w, out_cov):
    """The current state into row k of the outputs: q (N, 4), bias
    (N, 3), velocity and wind (N, 3) (written only when in the layout), tangent-space
    covariance (additive: T P T^T, T = blkdiag(2 Xi(q)^T, I)) into row k / e of out_cov
    (ceil(N / e), d, d) when k is a multiple of e = cfg["cov_every"]: its leading d x d
    block for d = out_cov.shape[1], the whole (cfg["dim"]), the attitude's (3) or none (0).
    Before the filter starts, the state and covariance it would start from
    (:func:`_initial_state`), with :data:`HEADING_UNKNOWN_VAR` about the vertical while it
    waits for the magnetometer: the rows are finite, and flagged not_initialised."""
    d = out_cov.shape[1]
    iv, iw = cfg["i_v"], cfg["i_w"]
    e = cfg["cov_every"]
    kc = k // e if k % e == 0 else -1
    if flags[S_INIT] == 0:  # the state it would start from now (x and P are free until then)
        _initial_state(cfg, prm, x, flags, P, work)
        if cfg["wait_mag"] == 1 and flags[S_FMAG] == 0:  # waiting for the heading's sensor
            attitude_cov_about_vertical(cfg, x, P, work, prm["init_att_var"], HEADING_UNKNOWN_VAR)
    if kc >= 0 and x[X_PN] > 0.0:  # a prediction pending: recorded with it, P left as it is
        Pp = work[W_PEEK : W_PEEK + P.shape[0]]
        for i in range(P.shape[0]):
            for j in range(P.shape[1]):
                Pp[i, j] = P[i, j]
        cov_pending(cfg, prm, x, Pp, work)
        P = Pp
    # (the covariance first, then the vectors, loaded before they are stored: measurably
    # faster code)
    if kc < 0:
        pass
    elif cfg["add_form"] == 0 and d >= NT_RECORD_DIM:  # (around the caches, core.pool.stream_store3)
        for i in range(d):
            for j in range(d):
                stream_store3(out_cov, kc, i, j, P[i, j])
    elif cfg["add_form"] == 0:  # (a small row: through the caches)
        for i in range(d):
            for j in range(d):
                out_cov[kc, i, j] = P[i, j]
    else:
        _record_tangent_cov(cfg, x, P, work, kc, out_cov)
    q0, q1, q2, q3 = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
    b0, b1, b2 = x[X_BG], x[X_BG + 1], x[X_BG + 2]
    out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = q0, q1, q2, q3
    out_bg[k, 0], out_bg[k, 1], out_bg[k, 2] = b0, b1, b2
    if iv >= 0:
        out_v[k, 0], out_v[k, 1], out_v[k, 2] = x[X_V], x[X_V + 1], x[X_V + 2]
    if iw >= 0:
        out_w[k, 0], out_w[k, 1], out_w[k, 2] = x[X_W], x[X_W + 1], x[X_W + 2]


@njit(**_JIT_CORE)
def _record_tangent_cov(cfg, x, P, work, k, out_cov):
    """The additive filters' tangent-space covariance into out_cov[k]: T P T^T, T = blkdiag(2 Xi(q)^T, I)
    (the attitude's block alone when out_cov is (N, 3, 3), nothing when (N, 0, 0))."""
    if out_cov.shape[1] == 0:
        return
    Xi = work[W_M + 4 : W_M + 8]
    _xi_into(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], Xi)
    n = cfg["n"] if out_cov.shape[1] > 3 else 4
    for r in range(3):
        for j in range(4, n):
            v = (
                2.0 * Xi[0, r] * P[0, j]
                + 2.0 * Xi[1, r] * P[1, j]
                + 2.0 * Xi[2, r] * P[2, j]
                + (2.0 * Xi[3, r] * P[3, j])
            )
            out_cov[k, r, j - 1] = v
            out_cov[k, j - 1, r] = v
        for c in range(3):
            s = 0.0
            for a in range(4):
                for b in range(4):
                    s += Xi[a, r] * P[a, b] * Xi[b, c]
            out_cov[k, r, c] = 4.0 * s
    for i in range(4, n):
        for j in range(4, n):
            out_cov[k, i - 1, j - 1] = P[i, j]


@njit(**_JIT_CORE)
def run_events(st, t_ev, kinds, vals, out_q, out_bg, out_v, out_w, out_cov, rec, sm):
    """The event loop (filters.base.replay, compiled): feed the merged events (t_ev (E,),
    kinds (E,), vals (E, 6)), skip and count NaN samples, and (rec) record for IMU sample k
    the state after every event with t <= t_imu[k] (before the next IMU sample).

    The streamer calls it with one event at a time and rec=False: the per-kind step
    functions are inlined into this one compiled function, which batch and stream share
    (and numba compiles the filter once). sm: the smoother's record
    (:class:`windahrs.core.smooth.SmoothRecord`, with rec), or one without rows
    (:func:`windahrs.core.smooth.no_smoothing`): a normal run. Every caller passes the same
    types, so numba compiles this loop once for runs, batches, streams and the smoother."""
    k = np.int64(-1)
    smooth = sm.aux.shape[0] > 0
    cfg, prm, x, flags, P, work, sup, inn, acc, screen, rest, asc = st  # once: each extraction costs refcounting
    sc, rs, ac = screen[0], rest[0], asc[0]  # (the aid sources' records: their fields are read and written in place)
    n_ev = t_ev.shape[0]
    for i in range(n_ev):
        kind = kinds[i]
        t = t_ev[i]
        row = vals[i]
        if kind == EVENT_IMU:
            k += 1
            if smooth:
                record_pre(sm, k, x, flags, sc, t, row, sample_ok(kind, row))
        if kind != EVENT_IMU and x[X_PN] > 0.0:  # (an aid source may read or change P)
            flush_cov(cfg, prm, x, P, work)
        if not sample_ok(kind, row):
            flags[K_SKIP + kind] += 1
        elif kind == EVENT_IMU:
            step_imu(cfg, prm, x, flags, P, work, sup, inn, acc, sc, rs, t, row)
        elif kind == EVENT_MAG:
            step_mag(cfg, prm, x, flags, P, work, sup, inn, acc, t, row)
        elif kind == EVENT_GNSS:
            step_gnss(cfg, prm, x, flags, P, work, sup, inn, acc, t, row)
        elif kind == EVENT_AIR:
            step_air(cfg, prm, x, flags, P, work, sup, inn, acc, ac, t, row[0], row[1], row[2])
        # IMU sample k gets the state after the last event before the next IMU sample
        if rec and k >= 0 and (i + 1 == n_ev or kinds[i + 1] == EVENT_IMU):
            record(cfg, prm, x, flags, P, work, k, out_q, out_bg, out_v, out_w, out_cov)
            if smooth:
                record_post(sm, k, cfg, x, flags, sc, P)
    if rec:  # (the covariance was recorded around the caches: visible to every thread now)
        stream_fence()


# --- Python side: encoding, estimators, streamer -------------------------------------------


_KINDS = {"mekf": KIND_MEKF, "mekf-air": KIND_MEKF_AIR, "ins-wind": KIND_INS}
_COMP = {"none": COMP_NONE, "gnss": COMP_GNSS, "airspeed": COMP_AIRSPEED}
_MAG = {"3d": MAG_3D, "heading": MAG_HEADING, "off": MAG_OFF}
_REST = {"auto": REST_OFF, "on": REST_ON, "off": REST_OFF, "start": REST_START, "align": REST_ALIGN}
_AIR = {"auto": AIR_AUTO, "vector": AIR_VECTOR, "airspeed": AIR_AIRSPEED, "off": AIR_OFF}
_STREAMS = ("imu", "mag", "gnss", "air")
#: The covariance is zero-padded to a multiple of PAD rows and columns (whole SIMD lanes).
PAD = 4


Kind = Literal["mekf", "mekf-air", "ins-wind"]


def effective_mag_mode(params: EskfParams, site: Site) -> Literal["3d", "heading", "off"]:
    """How the magnetometer is fused: ``params.mag_mode``, except "3d" becomes "heading"
    with ``mag_3d_needs_site`` when the site's field is unknown (its dip would come from
    one sample)."""
    if params.mag_mode == "3d" and params.mag_3d_needs_site and site.mag_n is None:
        return "heading"
    return params.mag_mode


def layout_for(kind: Kind, params: EskfParams, *, additive: bool = False) -> Layout:
    """The error-state blocks of ``kind`` with ``params``: [ins-wind] adds velocity and
    (accel_bias_noise > 0) accelerometer bias; [mekf-air] and [ins-wind] wind; every kind a
    magnetometer bias when ``init_mag_bias > 0`` with the 3-D magnetometer, except the
    quaternion-additive filters (``additive``: [ekf7], [ekf10]). The kernels assume the
    attitude at 0 and the velocity at 3."""
    blocks = ["att", "bg"]
    if kind == "ins-wind":
        blocks.insert(1, "v")
    if kind in ("mekf-air", "ins-wind"):
        blocks.append("wind")
    if kind == "ins-wind" and params.accel_bias_noise > 0:
        blocks.append("ba")
    if params.init_mag_bias > 0 and params.mag_mode == "3d" and not additive:
        blocks.append("bm")
    L = Layout(tuple(blocks))
    if L.dim + int(additive) >= NMAX:
        raise AssertionError(f"compiled kernels cannot run the layout {L.blocks}")
    return L


def _vec(a: Any, n: int, name: str) -> F64:
    v = np.asarray(a, dtype=np.float64)
    if v.shape != (n,):
        raise ValueError(f"initial.{name}: expected shape ({n},), found {v.shape}")
    return v


def make_state(
    kind: Kind,
    additive: bool,
    params: EskfParams,
    site: Site,
    initial: InitialState | None,
    has: frozenset[str],
    caps: I64,
    *,
    layout: Layout | None = None,
) -> KernelState:
    """A fresh KernelState, parameters and modes encoded once. kind: "mekf", "mekf-air"
    or "ins-wind"; additive: the quaternion-additive form (ekf7/ekf10); has: the streams
    that will be fed; caps (N_SENSORS,): innovation log rows per sensor (SENSORS order);
    layout: the error-state blocks instead of :func:`layout_for`'s (e.g. the PCRB's,
    :mod:`windahrs.core.linearize`), with the kernels' assumptions: the attitude at 0,
    the velocity (when present) at 3, the covariance narrower than NMAX."""
    p, ini = params, initial
    if layout is None:
        L = layout_for(kind, p, additive=additive)
    else:
        L = layout
        if (L.has("v") and L.sl("v").start != 3) or L.dim + int(additive) >= NMAX:
            raise ValueError(f"layout: expected the velocity (if any) at 3 and dim < {NMAX - int(additive)}, "
                             f"found {L.blocks}")  # fmt: skip
    dim = L.dim
    n = dim + 1 if additive else dim
    cfg = np.zeros(1, CFG)[0]
    cfg["kind"] = _KINDS[kind]
    cfg["add_form"] = int(additive)
    cfg["accel_compensation"] = _COMP[p.accel_compensation]
    cfg["mag_mode"] = _MAG[effective_mag_mode(p, site)]
    cfg["heading_vertical"] = int(p.heading_model == "vertical")
    cfg["air_mode"] = _AIR[p.air_mode]
    cfg["synthetic_sideslip"] = int(p.synthetic_sideslip)
    cfg["drag"] = int(p.drag and kind == "ins-wind")
    cfg["airspeed_scale"] = int(p.airspeed_scale and kind != "mekf")
    # without a heading aid (the 6-D mode of the error-state filters that fuse gravity) the
    # gravity update corrects the tilt only (core.kalman._tilt_only), and rest detection
    # ("auto") measures the gyro bias, the vertical one included (aid.rest)
    cfg["tilt_only"] = int(kind != "ins-wind" and not additive
                      and ("mag" not in has or effective_mag_mode(p, site) == "off"))
    cfg["rest"] = _REST[p.rest_detection]
    # the filters that fuse the mean specific force as gravity check its start (not the INS)
    cfg["start_check"] = int(p.start_check and kind != "ins-wind" and p.accel_lowpass > 0 and p.reset_timeout > 0)
    # ... and a start off its gate (the error-state filters: the update keeps the gyro bias in core.kalman._fuse)
    cfg["gated_start"] = int(p.gated_start and cfg["start_check"] == 1 and not additive)
    if p.rest_detection == "auto":
        cfg["rest"] = REST_ON if cfg["tilt_only"] == 1 else REST_OFF
        if kind == "ins-wind" and ini is None:  # the INS's stationary alignment (aid.rest), unless its start is given
            cfg["rest"] = REST_ALIGN
    online = p.accel_noise_online and p.accel_lowpass > 0
    cfg["accel_noise_online"] = (2 if p.accel_noise_mean_start else 1) if online else 0
    if kind == "ins-wind":  # the INS takes the accelerometer as its input: its noise from the flight
        cfg["accel_noise_online"] = 2 if p.accel_noise_measured else 0
    cfg["wait_mag"] = int("mag" in has and p.mag_mode != "off" and ini is None)
    cfg["wait_gnss"] = int(kind == "ins-wind" and (ini is None or ini.v_n is None))
    cfg["init_given"] = int(ini is not None)
    cfg["init_bias_given"] = int(ini is not None and ini.gyro_bias_b is not None)
    cfg["init_v_given"] = int(ini is not None and ini.v_n is not None)
    cfg["init_wind_given"] = int(ini is not None and ini.wind_n is not None)
    cfg["site_mag_known"] = int(site.mag_n is not None)
    cfg["i_v"] = L.sl("v").start if L.has("v") else -1
    cfg["i_bg"] = L.sl("bg").start
    cfg["i_w"] = L.sl("wind").start if L.has("wind") else -1
    cfg["i_ba"] = L.sl("ba").start if L.has("ba") else -1
    cfg["i_bm"] = L.sl("bm").start if L.has("bm") else -1
    cfg["dim"] = dim
    cfg["cov_every"] = 1
    cfg["n"] = n
    total = log_layout(cfg, np.asarray(caps, dtype=np.int64))
    n_pad = -(-n // PAD) * PAD  # the covariance's rows and columns, padded
    # the prediction's rows of Phi P over whole SIMD vectors, the padded width, for more than
    # TRIANGLE_N states ([ins-wind]'s 18 in 20 columns: its run 1.236-1.319 -> 1.155-1.234 us
    # per sample), else over the n states ([mekf]'s 6: over 8 its compiled loop was 2-4 % slower)
    cfg["rows"] = n_pad if n > TRIANGLE_N else n
    # the INS's covariance predicted once per cov_period, as PX4 EKF2 does (not with the drag
    # aid, whose update reads P at every IMU sample)
    cfg["cov_defer"] = int(kind == "ins-wind" and not additive and cfg["drag"] == 0 and p.cov_period > 0)

    def sig(given: float | None, default: float) -> float:
        return default if given is None else given

    prm = np.zeros(1, PRM)[0]
    prm["gyro_noise2"] = p.gyro_noise**2
    prm["gyro_bias_noise2"] = p.gyro_bias_noise**2
    vb = p.gyro_bias_noise_vertical
    # (about the vertical at most gyro_bias_noise: a slower walk where only a heading aid observes it)
    prm["gyro_bias_noise_dv2"] = min(vb, p.gyro_bias_noise) ** 2 - p.gyro_bias_noise**2 if vb > 0 else 0.0
    prm["accel_noise2"] = p.accel_noise**2
    prm["accel_bias_noise2"] = p.accel_bias_noise**2
    prm["wind_noise2"] = p.wind_noise**2
    prm["wind_noise_vertical2"] = p.wind_noise_vertical**2 if p.wind_vertical else 0.0
    prm["accel_var"] = p.accel_sigma**2
    prm["accel_norm_gate"] = p.accel_norm_gate
    prm["mag_sigma"] = p.mag_sigma
    prm["mag_var"] = p.mag_sigma**2
    prm["gnss_var"] = p.gnss_sigma**2
    prm["tas_var"] = p.tas_sigma**2
    prm["vane_var"] = p.vane_sigma**2
    prm["sideslip_var"] = p.sideslip_sigma**2
    prm["gate_accel2"] = p.gate_accel**2
    prm["gate_mag2"] = p.gate_mag**2
    prm["mag_reentry_gate2"] = (p.mag_reentry_gate * p.gate_mag) ** 2
    prm["gate_gnss2"] = p.gate_gnss**2
    prm["gate_air2"] = p.gate_air**2
    # initial spreads: the given initial state's, else the parameters'
    prm["init_att_var"] = sig(ini.sigma_att if ini else None, p.init_att) ** 2
    prm["init_yaw_var"] = p.init_yaw**2 if ini is None or ini.sigma_att is None else 0.0
    if kind == "ins-wind" and p.init_yaw == 0 and ini is None and cfg["wait_mag"] == 0:
        # an INS with nothing to give it a heading at the start (no magnetometer fused, and
        # no initial state): its heading is unknown, and only the GNSS accelerations turn it
        prm["init_yaw_var"] = math.pi**2
    prm["init_bias_var"] = sig(ini.sigma_bias if ini else None, p.init_bias) ** 2
    prm["init_v_var"] = sig(ini.sigma_v if ini else None, p.init_v if ini is None else p.gnss_sigma) ** 2
    prm["init_wind_var"] = sig(ini.sigma_wind if ini else None, p.init_wind) ** 2
    prm["init_wind_vertical_var"] = prm["init_wind_var"] if p.wind_vertical else 0.0
    prm["init_accel_bias_var"] = p.init_accel_bias**2
    prm["init_mag_bias_var"] = p.init_mag_bias**2
    prm["mag_bias_noise2"] = p.mag_bias_noise**2
    prm["accel_lowpass"] = p.accel_lowpass
    prm["accel_fuse_dt"] = 1.0 / p.accel_fuse_rate if p.accel_fuse_rate > 0 else 0.0
    prm["mag_fuse_dt"] = 1.0 / p.mag_fuse_rate if p.mag_fuse_rate > 0 else 0.0
    prm["mag_lowpass"] = p.mag_lowpass
    prm["gyro_scale_noise2"] = p.gyro_scale_noise**2
    prm["mag_norm_gate"] = p.mag_norm_gate
    prm["mag_dip_gate"] = p.mag_dip_gate
    prm["drag_mcoef"] = p.drag_mcoef
    prm["drag_kx"] = 0.0 if p.drag_bcoef_x == 0 else p.air_density / (2.0 * p.drag_bcoef_x)
    prm["drag_ky"] = 0.0 if p.drag_bcoef_y == 0 else p.air_density / (2.0 * p.drag_bcoef_y)
    prm["drag_var"] = p.drag_sigma**2
    prm["gate_drag2"] = p.gate_drag**2
    prm["init_window"] = p.init_window
    prm["reset_timeout"] = p.reset_timeout
    prm["unmeasured_motion_dt"] = p.unmeasured_motion_dt
    prm["cov_period"] = p.cov_period
    prm["gnss_timing_sigma"] = p.gnss_timing_sigma
    prm["gyro_range"] = p.gyro_range
    prm["accel_range"] = p.accel_range
    prm["imu_spike_gate"] = p.imu_spike_gate
    prm["asc_init_var"] = p.airspeed_scale_sigma**2
    prm["asc_kn2"] = p.airspeed_scale_noise**2
    prm["asc_wn2"] = p.airspeed_scale_wind_noise**2
    prm["asc_tas_var"] = p.airspeed_scale_tas_sigma**2
    prm["asc_beta_var"] = p.airspeed_scale_beta_sigma**2
    prm["rest_w2"] = p.rest_gyro_threshold**2
    prm["rest_f2"] = p.rest_accel_threshold**2
    prm["rest_tau"] = p.rest_tau
    prm["rest_min_t"] = p.rest_min_time
    prm["rest_var"] = p.rest_bias_sigma**2
    prm["rest_clip"] = p.rest_bias_clip
    prm["lowpass_bias"] = 1.0 if p.lowpass_bias else 0.0
    prm["gravity"] = site.gravity_n[2]
    if site.mag_n is not None:
        prm["site_mag"] = site.mag_n
    prm["site_decl"] = 0.0 if site.declination is None else site.declination
    if ini is not None:
        prm["init_q"] = _vec(ini.q_nb, 4, "q_nb")
        if ini.gyro_bias_b is not None:
            prm["init_bias"] = _vec(ini.gyro_bias_b, 3, "gyro_bias_b")
        if ini.v_n is not None:
            prm["init_v"] = _vec(ini.v_n, 3, "v_n")
        if ini.wind_n is not None:
            prm["init_wind"] = _vec(ini.wind_n, 3, "wind_n")
    flags = np.zeros(N_FLAGS, dtype=np.int64)
    flags[L_FIRST : L_FIRST + N_SENSORS] = -1
    x = np.zeros(N_X)
    x[X_TOK : X_TOK + N_SENSORS] = np.nan  # no reset clock before initialisation
    x[X_TMOK] = x[X_TGOK] = -np.inf  # no field nor GNSS velocity fused yet
    x[X_TMREIN] = -np.inf  # no magnetometer re-entry gate
    x[X_TMPASS] = np.nan  # (no field fused yet)
    x[X_TINIT] = np.nan  # not initialised
    return KernelState(
        cfg=cfg,
        prm=prm,
        x=x,
        flags=flags,
        P=np.zeros((n_pad, n_pad)),
        work=np.zeros((N_WORK, max(n_pad, NMAX))),  # (scratch rows span P's columns)
        sup=np.zeros((2, NMAX), dtype=np.int64),
        inn=np.empty((total, 5)),
        acc=np.zeros(total, dtype=np.bool_),
        screen=screen_state(),
        rest=rest_state(),
        asc=asc_state(),
    )


def init_index(x: F64, t_imu: F64) -> int:
    """The first IMU sample (index into t_imu) at which the filter with state x had started:
    the one at its start time x[X_TINIT], ``len(t_imu)`` if it never did."""
    t0 = x[X_TINIT]
    return int(np.searchsorted(t_imu, t0)) if np.isfinite(t0) else len(t_imu)


def _innovations(st: KernelState, mag_mode: str) -> dict[str, Innovations]:
    """The logs as Estimate innovations, keyed in the order sensors first logged."""
    return read_logs(st.cfg, st.flags, st.inn, st.acc, heading=mag_mode == "heading")


def _resets(st: KernelState) -> dict[str, F64]:
    """The reset log as ``Estimate.resets`` (:func:`windahrs.core.kalman.read_resets`)."""
    return read_resets(st.cfg, st.flags, st.inn)


def _grow(st: KernelState) -> KernelState:
    """The same state with twice the log capacity for every full sensor log."""
    cfg, inn, acc = grown_logs(st.cfg, st.flags, st.inn, st.acc)
    return st._replace(cfg=cfg, inn=inn, acc=acc)


class CompiledStreamer(EventStreamer):
    """A compiled filter fed sample by sample through the same step functions as the
    batch run (so a flight streamed equals its batch estimate)."""

    def __init__(
        self,
        name: str,
        kind: Kind,
        additive: bool,
        params: EskfParams,
        site: Site,
        initial: InitialState | None,
        has: frozenset[str],
    ) -> None:
        super().__init__(name)
        self.kind = kind
        self.params = params
        self.layout = layout_for(kind, params, additive=additive)
        self._st = make_state(kind, additive, params, site, initial, has, np.full(N_SENSORS, 256, dtype=np.int64))
        self._mag_fusion = effective_mag_mode(params, site)
        # one event at a time through the batch loop, without recording
        self._none = (
            np.empty((0, 4)),
            np.empty((0, 3)),
            np.empty((0, 3)),
            np.empty((0, 3)),
            np.empty((0, 0, 0)),
        )
        self._no_sm = no_smoothing()

    def _step(self, kind: int, t: float) -> None:
        if (self._st.flags[L_CNT : L_CNT + N_SENSORS] >= self._st.cfg["log_cap"]).any():
            self._st = _grow(self._st)  # an event logs at most one row per sensor
        run_events(self._st, self._t, self._kind, self._row, *self._none, False, self._no_sm)

    def innovations(self) -> dict[str, Innovations]:
        return _innovations(self._st, self._mag_fusion)

    @property
    def state(self) -> StateView:
        d = self.layout.dim
        q, bg, v, w = np.empty((1, 4)), np.empty((1, 3)), np.empty((1, 3)), np.empty((1, 3))
        cov = np.empty((1, d, d))
        st = self._st
        record(st.cfg, st.prm, st.x, st.flags, st.P, st.work, 0, q, bg, v, w, cov)
        return StateView(
            t=self._t_last,
            q_nb=q[0],
            gyro_bias_b=bg[0],
            v_n=v[0] if self.layout.has("v") else None,
            wind_n=w[0] if self.layout.has("wind") else None,
            cov=cov[0],
            state_labels=self.layout.labels(),
        )


class PreparedRun(NamedTuple):
    """One flight made ready for :func:`run_events`: the flight, its parameters (the
    estimator's with what the flight declares), the error-state layout, a fresh
    KernelState, the merged events (t_ev (E,), kinds (E,), vals (E, 6)) and the outputs it
    records into: q (N, 4), bg (N, 3), v and w (N, 3), or (0, 3) when not in the layout,
    cov (ceil(N / e), d, d) at every e-th sample (e = st.cfg["cov_every"]), d the layout's
    dimension, 3 (the attitude's block) or 0 (none)."""

    flight: Flight
    params: EskfParams
    layout: Layout
    st: KernelState
    t_ev: F64
    kinds: I64
    vals: F64
    q: F64
    bg: F64
    v: F64
    w: F64
    cov: F64


class CompiledEstimator(Estimator):
    """An estimator on the compiled core: a process model (``kind``; ``additive`` for the
    quaternion-additive form) and the aid sources its parameters switch on. ``run`` is one
    compiled loop over the flight; ``streamer`` feeds the same loop sample by sample."""

    kind: ClassVar[Kind]
    additive: ClassVar[bool] = False
    default_params: ClassVar[EskfParams] = EskfParams()
    #: The parameter sets of its process model and aid sources (``PARAMS`` of windahrs.aid
    #: and windahrs.core.predict): the fields a user may set on it.
    parts: ClassVar[tuple[tuple[str, ...], ...]] = ()

    def __init__(self, params: EskfParams | None = None) -> None:
        self.params = params if params is not None else self.default_params

    @classmethod
    def param_names(cls) -> frozenset[str]:
        """The fields of :class:`EskfParams` this estimator uses."""
        return frozenset(name for part in cls.parts for name in part)

    def run(
        self, flight: Flight, *, initial: InitialState | None = None, cov_every: int | str | None = None
    ) -> Estimate:
        """Estimate the whole flight in one compiled loop (with the parameters the flight
        itself declares, :func:`~windahrs.filters.params.flight_params`); the covariance at
        every cov_every-th IMU sample (default: at :data:`~windahrs.core.layout.COV_RECORD_HZ`,
        20 Hz, within :data:`~windahrs.core.layout.COV_BUDGET`,
        :func:`~windahrs.core.layout.cov_stride`; 1: every sample; "budget": every
        sample within the budget, for a caller that reads the covariance sample by sample,
        as [auto]'s handover)."""
        run = self.prepare(flight, initial, cov_every=cov_every)
        run_events(run.st, run.t_ev, run.kinds, run.vals, run.q, run.bg, run.v, run.w, run.cov, True, no_smoothing())
        return self.finish(run)

    def run_batch(
        self,
        flights: Sequence[Flight],
        *,
        initial: Sequence[InitialState | None] | None = None,
        threads: int | None = None,
        cov: CovRecord = "full",
        cov_every: int | str | None = None,
    ) -> list[Estimate]:
        """Estimate several flights in one compiled call, the runs advancing in parallel
        (:func:`windahrs.core.batch.run_batch`): the same Estimates as ``[self.run(f,
        initial=i, cov_every=cov_every) for f, i in zip(flights, initial)]``. initial: one
        InitialState (or None) per flight; threads: how many runs at once (default: numba's
        thread count, ``NUMBA_NUM_THREADS``); cov: the covariance recorded, "full",
        "attitude" or "none" (:data:`~windahrs.filters.base.CovRecord`); cov_every: as
        :meth:`run`'s, per flight."""
        from windahrs.core.batch import run_batch

        return run_batch(self, flights, initial=initial, threads=threads, cov=cov, cov_every=cov_every)

    def prepare(
        self,
        flight: Flight,
        initial: InitialState | None = None,
        cov: CovRecord = "full",
        cov_every: int | str | None = None,
        *,
        reuse: bool = True,
    ) -> PreparedRun:
        """What :func:`run_events` needs to run ``flight``: a fresh state, the merged events
        and the outputs (uninitialised), in a :class:`PreparedRun`; cov: the covariance to
        record (:data:`~windahrs.filters.base.CovRecord`), at every cov_every-th IMU sample
        (as :meth:`run`'s, from the recorded block's size); reuse: the outputs and the
        innovation logs in memory reused from dropped Estimates (:mod:`windahrs.core.pool`:
        no page faults on their first touch), False for fresh arrays (a caller that
        replaces them unwritten, as the batch does)."""
        if cov not in COV_RECORDS:
            raise ValueError(f"cov: expected one of {', '.join(map(repr, COV_RECORDS))}, found {cov!r}")
        self.check(flight)
        params = flight_params(self.params, flight.meta, self.param_names())
        has = frozenset(s for s in _STREAMS if getattr(flight, s) is not None) & self.uses
        t_ev, kinds, vals = merge_events(flight, has)
        counts = stream_counts(flight, has)
        caps = np.array([counts[stream] for stream in SENSOR_STREAMS], dtype=np.int64)
        st = make_state(self.kind, self.additive, params, flight.site, initial, has, caps)
        new = pool.empty if reuse else np.empty
        if reuse:
            st = st._replace(inn=new(st.inn.shape))
        L = layout_for(self.kind, params, additive=self.additive)
        N, d = len(flight.imu.t), {"full": L.dim, "attitude": 3, "none": 0}[cov]
        q, bg = new((N, 4)), new((N, 3))
        v = new((N, 3)) if L.has("v") else np.empty((0, 3))
        w = new((N, 3)) if L.has("wind") else np.empty((0, 3))
        every = cov_stride_of(flight.imu.t, d, cov_every)
        st.cfg["cov_every"] = every
        P = new((-(-N // every), d, d))
        return PreparedRun(flight, params, L, st, t_ev, kinds, np.ascontiguousarray(vals), q, bg, v, w, P)

    def finish(self, run: PreparedRun) -> Estimate:
        """The Estimate of a run that :func:`run_events` has been through (checked:
        :func:`~windahrs.filters.checks.checked`)."""
        st, L, flight = run.st, run.layout, run.flight
        N, d, every = len(flight.imu.t), run.cov.shape[1], int(st.cfg["cov_every"])
        skipped = st.flags[K_SKIP : K_SKIP + 4]
        return checked(Estimate(
            filter=self.label,
            t=flight.imu.t.copy(),
            q_nb=run.q,
            gyro_bias_b=run.bg,
            v_n=run.v if L.has("v") else None,
            wind_n=run.w if L.has("wind") else None,
            cov=run.cov if d else None,
            cov_index=None if every == 1 or not d else np.arange(0, N, every),
            state_labels=L.labels()[:d],
            innovations=_innovations(st, effective_mag_mode(run.params, flight.site)),
            skipped={s: int(c) for s, c in zip(_STREAMS, skipped, strict=True)},
            params=repr(run.params),
            resets=_resets(st),
            alerts=read_held(st.cfg, st.flags, st.inn),
            airspeed_scale=read_airspeed_scale(st.cfg, st.flags, st.inn, st.acc),
            init_index=init_index(st.x, flight.imu.t),
        ), flight)

    def streamer(
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> CompiledStreamer:
        return CompiledStreamer(self.name, self.kind, self.additive, self.params, site, initial, has)
