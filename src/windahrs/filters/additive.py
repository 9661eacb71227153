"""The compiled event loop of the additive-quaternion filters: [paper], [paper-nowind]
(:mod:`windahrs.filters.paper`), [ekf] (:mod:`windahrs.filters.ekf`) and [ukf]
(:mod:`windahrs.filters.ukf`).

They share everything but their propagation and noise: a state ``x`` starting with the
quaternion ``q_nb`` (4,) (the UKF appends the gyro bias), its covariance ``P`` on those
parameters, initialisation (fixed, or TRIAD from the first accelerometer and
magnetometer samples), the magnetometer reference, sequential 3-row vector updates with
the innovation ``z - h(x)`` (SPEC 2.3), normalisation of ``q`` after every propagation
and update with the covariance projected by the normalisation Jacobian, and the paper's
air-flow row. What they share with [ekf7] is the compiled core's, written once:

* the EKFs' update is the one Kalman update ``core.kalman._fuse``, given H on the
  quaternion's four parameters;
* [ekf]'s prediction is ``core.predict._predict_add`` (SPEC 2.3 without a gyro-bias
  state); the UKF adds its process noise with ``core.predict._noise_add``;
* the normalisation is ``core.predict._normalise_add``.

The paper's own process model (Picard-4, constant Q) and the vector observations are
:mod:`windahrs.models.additive`, the UKF's unscented steps :mod:`windahrs.core.dense`;
this module sequences them. The state's arrays extend the core's (``core.layout``): cfg,
prm and flags start with the core's fields, which the shared functions and the innovation
logs read, and the scratch rows ``work`` are the core's.

One numba function, :func:`run_events`, runs the merged events of a flight (base.replay
compiled, with no Python per sample); :class:`AdditiveStreamer` feeds it one event at a
time without recording, so a streamed flight equals its batch run bit for bit. The
wind the paper's air row needs is evaluated on the Python side (a provider ``t ->
wind_n``) and travels in columns 3..5 of the air event's values row. With
``NUMBA_DISABLE_JIT=1`` the same source runs as plain (slow) Python: the readable path.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, NamedTuple, TypeVar

import numpy as np
from numba import njit
from numpy.typing import NDArray

from windahrs.core import layout as core
from windahrs.core.dense import (
    propagate_cov,
    sigma_points,
    ut_mean_cov,
    ut_update,
    ut_weights,
)
from windahrs.core.events import sample_ok
from windahrs.core.kalman import _fuse, _log, grown_logs, log_layout, read_logs
from windahrs.core.layout import (
    INN_ACCEL,
    INN_AIR,
    INN_MAG,
    K_SKIP,
    W_HQ,
    W_M,
    W_NU,
    W_R,
)
from windahrs.core.predict import _noise_add, _normalise_add, _predict_add
from windahrs.core.quat import _qexp, _qmul, _triad, _xi_into
from windahrs.estimate import Estimate, Innovations
from windahrs.filters.base import (
    EVENT_AIR,
    EVENT_GNSS,
    EVENT_IMU,
    EVENT_MAG,
    Estimator,
    EventStreamer,
    InitialState,
    StateView,
    merge_events,
    stream_counts,
)
from windahrs.filters.checks import checked
from windahrs.filters.params import MAX_MAGNITUDE, read_param_file
from windahrs.flight import Flight, Site
from windahrs.models.additive import (
    Xi,
    att_cov_from_quat_cov,
    quat_cov_from_att_cov,
    transition_picard4,
    vector_obs,
    vector_obs_jacobian,
)

__all__ = [
    "KIND_EKF",
    "KIND_PAPER",
    "KIND_UKF",
    "AdditiveEstimator",
    "AdditiveStreamer",
    "KernelConfig",
    "KernelState",
    "WindProvider",
    "make_state",
    "unfused_counts",
    "wind_at",
    "run_events",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

#: The wind (velocity of the air, NED, m/s) at a time (s): what the paper's filter "knows".
WindProvider = Callable[[float], F64]

_JIT: dict[str, Any] = {"cache": True, "error_model": "numpy"}

#: Propagation and noise: the paper's (Picard-4, constant Q and R), the traditional EKF's
#: (exact transition, noise from the sensor densities), the additive UKF's.
KIND_PAPER, KIND_EKF, KIND_UKF = 0, 1, 2

#: The innovation logs (core.layout.AID_LOGS) these filters write.
LOGGED = (INN_ACCEL, INN_MAG, INN_AIR)

#: Below this air-relative speed (m/s) the air-flow direction is noise, so the row is not
#: fused (counted).
MIN_AIR_SPEED = 0.5

#: Reasons a sample was not fused, in the order of the counters.
UNFUSED = ("mag_before_imu", "air_before_init", "air_no_gnss", "air_slow")

# This family's parameters and configuration are fields of the core's records (core.layout:
# PAPER_PRM_FIELDS, PAPER_CFG_FIELDS), so that the core's functions it shares compile once.
# Its flags extend the core's array (names of its own, after the core's slots).
# s (float64): the remembered samples
S_TIMU, S_TSTATE, S_DT = 0, 1, 2
S_F = 3  # (3,) last specific force
S_MAGREF = 6  # (3,) unit nav-frame field reference
S_MAGNORM = 9
S_V = 10  # (3,) last GNSS velocity
S_TGNSS = 13
N_S = 14
# flags (int64): after the core's (core.layout: the log counters L_CNT, L_FIRST, S_SEQ and
# K_SKIP (4,), NaN samples skipped: imu, mag, gnss, air)
F_READY, F_TIMU, F_F, F_MAGREF, F_V = range(core.N_FLAGS, core.N_FLAGS + 5)
K_UNF = core.N_FLAGS + 5  # (4,) samples not fused, UNFUSED order
N_FLAGS_ADD = core.N_FLAGS + 9

_UP_N = np.array([0.0, 0.0, -1.0])  # conventions.UP_N: a resting accelerometer's reading


class KernelState(NamedTuple):
    """Everything a running filter needs, in arrays: cfg (a core.layout.CFG record), prm (a core.layout.PRM record),
    s (N_S,) remembered samples, flags (N_FLAGS_ADD,) int64, x (n,), P (n, n), wm and wc
    (2n+1,) unscented weights (UKF; (1,) otherwise), and as in core.layout.KernelState:
    work (N_WORK, NMAX) scratch rows, sup (2, NMAX) the columns of H (row 1: all n),
    inn (L, 5) innovation log rows [t, nu (3), nis], acc (L,) accepted."""

    cfg: np.void
    prm: np.void
    s: F64
    flags: I64
    x: F64
    P: F64
    wm: F64
    wc: F64
    work: F64
    sup: I64
    inn: F64
    acc: NDArray[np.bool_]


# --- compiled kernels ---------------------------------------------------------------------


@njit(**_JIT)
def _qnormalize(q):
    """rotation.quat_normalize: unit, ``w >= 0``."""
    n = math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    sign = -1.0 if q[0] < 0.0 else 1.0
    out = np.empty(4)
    for i in range(4):
        out[i] = q[i] * sign / n
    return out


@njit(**_JIT)
def _norm3(v):
    """|v| as numpy.linalg.norm computes it (keeps the paper's and the EKF's last bits)."""
    c = np.ascontiguousarray(v)
    return math.sqrt(np.dot(c, c))


@njit(**_JIT)
def triad(f_b, mag_b, use_mag, mag_n, use_ref):
    """base.triad, compiled (core.quat): q_nb (4,) from f_b (3,) and, when use_mag,
    mag_b (3,) against mag_n (3,)'s declination when use_ref. Called once per run, and
    for the states recorded before initialisation."""
    q0, q1, q2, q3 = _triad(
        f_b[0], f_b[1], f_b[2], use_mag, mag_b[0], mag_b[1], mag_b[2], use_ref, mag_n[0], mag_n[1], mag_n[2]
    )
    return np.array([q0, q1, q2, q3])


@njit(**_JIT)
def _start(cfg, prm, flags, x, P, q_raw):
    """Initial state and covariance at the attitude q_raw (4,)."""
    q = _qnormalize(q_raw)
    n = cfg["n"]
    for i in range(n):
        for j in range(n):
            P[i, j] = 0.0
    if cfg["paper_kind"] == KIND_PAPER and cfg["p0_iso"] == 1:
        for i in range(4):
            P[i, i] = prm["p0_var"]
    else:
        P[:4, :4] = quat_cov_from_att_cov(q, prm["att0_var"] * np.eye(3))
    x[:4] = q
    for i in range(4, n):
        x[i] = prm["b0"][i - 4]
        P[i, i] = prm["bg0_var"]
    flags[F_READY] = 1


@njit(**_JIT)
def _matvec4(M, v):
    out = np.empty(4)
    for i in range(4):
        out[i] = M[i, 0] * v[0] + M[i, 1] * v[1] + M[i, 2] * v[2] + M[i, 3] * v[3]
    return out


@njit(**_JIT)
def _predict(cfg, prm, x, P, wm, wc, work, w_b, dt):
    """Propagate (x, P) in place over dt with the gyro sample w_b (3,), and normalise.

    [paper], [paper-nowind]: the paper's own process model (eq. 6 and 32: the Picard-4
    transition with the raw gyro, no bias state, the constant ``Q = q_var I4`` on the
    quaternion's parameters; SPEC 2.2, 2.3's paper-faithful variant). [ekf]: SPEC 2.3
    without a gyro-bias state, the core's additive prediction (``core.predict._predict_add``,
    [ekf7]'s). [ukf]: the sigma points through ``q * Exp((w - b) dt)``, SPEC 2.3's Q
    (``core.predict._noise_add``)."""
    kind = cfg["paper_kind"]
    if kind == KIND_PAPER:
        # The paper's filter has no bias state: the raw gyro drives eq. 6.
        Phi = transition_picard4(w_b * dt)
        x[:] = _matvec4(Phi, x)
        P[:, :] = propagate_cov(Phi, P, prm["q_var"] * np.eye(4))
        _normalize(cfg, x, P, work)
    elif kind == KIND_EKF:
        _predict_add(cfg, prm, x, P, work, w_b[0], w_b[1], w_b[2], dt)
    else:
        S = sigma_points(x, P, prm["spread"])
        npts = S.shape[0]
        for p in range(npts):
            # q * Exp((w - b) dt) for a constant rate over the step, normalised
            _propagate_point(S, p, w_b, dt)
        # one hemisphere, the centre point's
        c = S[0, :4].copy()
        for p in range(1, npts):
            if S[p, 0] * c[0] + S[p, 1] * c[1] + S[p, 2] * c[2] + S[p, 3] * c[3] < 0.0:
                S[p, :4] = -S[p, :4]
        xm, Pm = ut_mean_cov(S, wm, wc)
        x[:] = xm
        P[:, :] = Pm
        # SPEC 2.3's Q at the mean, then the normalisation: [ekf7]'s order (Q at a non-unit
        # q is Q at q/|q| once projected, J Xi(q) = Xi(q/|q|))
        Xi = work[W_M + 4 : W_M + 8]
        _xi_into(x[0], x[1], x[2], x[3], Xi)
        _noise_add(cfg, prm, P, Xi, dt)
        _normalize(cfg, x, P, work)


# The UKF's sigma points: the kinematics (core.quat) and the vector rows on scalars.


@njit(**_JIT)
def _propagate_point(S, p, w_b, dt):
    """Sigma point p of S (2n+1, 7) in place: ``q <- q * Exp((w_b - b) dt)``, normalised."""
    e = _qexp((w_b[0] - S[p, 4]) * dt, (w_b[1] - S[p, 5]) * dt, (w_b[2] - S[p, 6]) * dt)
    q0, q1, q2, q3 = _qmul(S[p, 0], S[p, 1], S[p, 2], S[p, 3], e[0], e[1], e[2], e[3])
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    S[p, 0], S[p, 1], S[p, 2], S[p, 3] = q0 / n, q1 / n, q2 / n, q3 / n


@njit(**_JIT)
def _observe_point(S, p, v, Y):
    """Row p of Y (2n+1, 3): ``C_bn v = q^* v q`` at sigma point p's quaternion, normalised."""
    n = math.sqrt(S[p, 0] * S[p, 0] + S[p, 1] * S[p, 1] + S[p, 2] * S[p, 2] + S[p, 3] * S[p, 3])
    w, u0, u1, u2 = S[p, 0] / n, -(S[p, 1] / n), -(S[p, 2] / n), -(S[p, 3] / n)
    t0 = 2.0 * (u1 * v[2] - u2 * v[1])
    t1 = 2.0 * (u2 * v[0] - u0 * v[2])
    t2 = 2.0 * (u0 * v[1] - u1 * v[0])
    Y[p, 0] = v[0] + w * t0 + (u1 * t2 - u2 * t1)
    Y[p, 1] = v[1] + w * t1 + (u2 * t0 - u0 * t2)
    Y[p, 2] = v[2] + w * t2 + (u0 * t1 - u1 * t0)


@njit(**_JIT)
def _normalize(cfg, x, P, work):
    """``q <- q/|q|`` (w >= 0), ``P <- J P J^T`` (SPEC 2.3) in place: the core's
    additive normalisation (``core.predict._normalise_add``, [ekf7]'s)."""
    _normalise_add(cfg, x, P, work, x[0], x[1], x[2], x[3])


@njit(**_JIT)
def _update_vector(cfg, prm, s, flags, x, P, wm, wc, work, sup, inn, acc, sensor, t, z, r_n, var):
    """Fuse ``z = C_bn r_n + v``, v ~ N(0, var I3), and log it. The EKFs: the one Kalman
    update (``core.kalman._fuse``) with H (3, 4) on the quaternion's parameters (the
    columns ``sup[1, :4]``) and no gate (these filters fuse every sample: the gate at
    infinity accepts every finite innovation), then its normalisation. The UKF: the
    unscented update, the normalisation, the log row (accepted)."""
    if cfg["paper_kind"] == KIND_UKF:
        S = sigma_points(x, P, prm["spread"])
        Y = np.empty((S.shape[0], 3))
        for p in range(S.shape[0]):
            _observe_point(S, p, r_n, Y)
        x2, P2, nu, nis = ut_update(x, P, S, Y, z, var * np.eye(3), wm, wc)
        x[:] = x2
        P[:, :] = P2
        _normalize(cfg, x, P, work)
        _log(cfg, flags, inn, acc, nu, sensor, t, np.int64(3), nis, np.bool_(True))
    else:
        q = x[:4]
        Hq, y = vector_obs_jacobian(q, r_n), vector_obs(q, r_n)
        H, nu, R = work[W_HQ : W_HQ + 3], work[W_NU], work[W_R : W_R + 3]
        for k in range(3):
            nu[k] = z[k] - y[k]
            for c in range(4):
                H[k, c] = Hq[k, c]
            for c in range(3):
                R[k, c] = var if k == c else 0.0
        _fuse(cfg, x, flags, P, work, sup, inn, acc, sensor, t, np.int64(3), np.int64(4), np.inf)
    s[S_TSTATE] = t


@njit(**_JIT)
def step_imu(cfg, prm, s, flags, x, P, wm, wc, work, sup, inn, acc, t, w_b, f_b):
    """IMU sample: gyro w_b (3,) rad/s, specific force f_b (3,) m/s^2 at t s."""
    first = flags[F_TIMU] == 0
    dt = 0.0 if first else t - s[S_TIMU]
    s[S_TIMU] = t
    flags[F_TIMU] = 1
    s[S_F : S_F + 3] = f_b
    flags[F_F] = 1
    s[S_TSTATE] = t
    if first:
        # The first sample only initialises: its rate belongs to the interval before it.
        if cfg["qstart_given"] == 1:
            _start(cfg, prm, flags, x, P, prm["qstart"])
        elif cfg["has_mag"] == 0:
            _start(cfg, prm, flags, x, P, triad(f_b, f_b, False, f_b, False))
        return
    if flags[F_READY] == 0:
        return  # TRIAD still waits for its magnetometer sample
    s[S_DT] = dt
    _predict(cfg, prm, x, P, wm, wc, work, w_b, dt)
    if cfg["paper_kind"] == KIND_PAPER:
        var = prm["paper_acc_var"]
    else:
        # Per-sample noise sigma_c / sqrt(dt) (Kalibr), divided by |f| = g for the unit vector.
        sw = prm["acc_noise"] / math.sqrt(max(dt, 1e-6)) / prm["g_norm"]
        var = sw * sw + prm["acc_unit2"]
    sensor = np.int64(INN_ACCEL)
    # _UP_N copied: numba types a global array read-only, and a read-only r_n would compile
    # _update_vector a second time (8 s cold) beside the magnetometer's.
    up = _UP_N.copy()
    _update_vector(cfg, prm, s, flags, x, P, wm, wc, work, sup, inn, acc, sensor, t, f_b / _norm3(f_b), up, var)


@njit(**_JIT)
def step_mag(cfg, prm, s, flags, x, P, wm, wc, work, sup, inn, acc, t, mag_b):
    """Magnetometer sample mag_b (3,) T at t s."""
    if flags[F_F] == 0:
        flags[K_UNF + 0] += 1  # mag_before_imu
        return
    norm = _norm3(mag_b)
    f_b = s[S_F : S_F + 3]
    if flags[F_MAGREF] == 0:
        # Unknown site field: the horizontal field points at the site's declination (north
        # when unknown), the dip is measured here against the accelerometer's down direction.
        down = -f_b / _norm3(f_b)
        c = np.dot(np.ascontiguousarray(mag_b), down) / norm
        c = min(max(c, -1.0), 1.0)
        h = math.sqrt(1.0 - c * c)  # turned by the site's declination (0: magnetic north)
        s[S_MAGREF] = h * math.cos(prm["site_decl"])
        s[S_MAGREF + 1] = h * math.sin(prm["site_decl"])
        s[S_MAGREF + 2] = c
        s[S_MAGNORM] = norm
        flags[F_MAGREF] = 1
    if flags[F_READY] == 0:
        ref = np.empty(3)
        for a in range(3):
            ref[a] = prm["site_field"][a]
        if _norm3(ref) == 0.0:  # the field unknown: north from its declination (0: magnetic)
            ref[0], ref[1], ref[2] = math.cos(prm["site_decl"]), math.sin(prm["site_decl"]), 0.0
        q0 = triad(f_b, mag_b, True, ref, True)
        _start(cfg, prm, flags, x, P, q0)
        return  # this sample made the initial attitude; fusing it again would reuse it
    if cfg["paper_kind"] == KIND_PAPER:
        var = prm["paper_mag_var"]
    else:
        r = prm["mag_noise"] / s[S_MAGNORM]
        var = r * r + prm["mag_unit2"]
    r_n = s[S_MAGREF : S_MAGREF + 3].copy()
    sensor = np.int64(INN_MAG)
    _update_vector(cfg, prm, s, flags, x, P, wm, wc, work, sup, inn, acc, sensor, t, mag_b / norm, r_n, var)


@njit(**_JIT)
def step_gnss(s, flags, t, v_n):
    """GNSS velocity v_n (3,) m/s NED at t s: remembered for the air-flow row."""
    s[S_V : S_V + 3] = v_n
    s[S_TGNSS] = t
    flags[F_V] = 1


@njit(**_JIT)
def step_air(cfg, prm, s, flags, x, P, wm, wc, work, sup, inn, acc, t, aoa, beta, wind_n):
    """Air data at t s: the air-flow direction from the vanes (aoa, beta rad) against
    ``u = (V_n - W_n)/|V_n - W_n|``, V_n the latest GNSS velocity, wind_n (3,) the
    provider's wind (SPEC 3.4.3)."""
    if cfg["use_air"] == 0:
        return
    if not (math.isfinite(aoa) and math.isfinite(beta)):
        flags[K_SKIP + 3] += 1
        return
    if flags[F_READY] == 0:
        flags[K_UNF + 1] += 1  # air_before_init
        return
    if flags[F_V] == 0 or t - s[S_TGNSS] > prm["gnss_age"]:
        flags[K_UNF + 2] += 1  # air_no_gnss
        return
    u = s[S_V : S_V + 3] - wind_n
    speed = _norm3(u)
    if speed < MIN_AIR_SPEED:
        flags[K_UNF + 3] += 1  # air_slow
        return
    z = np.empty(3)  # rotation.air_direction
    z[0] = math.cos(aoa) * math.cos(beta)
    z[1] = math.sin(beta)
    z[2] = math.sin(aoa) * math.cos(beta)
    sensor = np.int64(INN_AIR)
    _update_vector(cfg, prm, s, flags, x, P, wm, wc, work, sup, inn, acc, sensor, t, z, u / speed, prm["air_var"])


@njit(**_JIT)
def record(cfg, s, flags, x, P, k, out_q, out_bg, out_cov):
    """Write the current estimate into row k: q_nb (4,) into out_q, the gyro bias (UKF)
    into out_bg, the reported covariance into out_cov (paper: 4x4 on q; ekf: 3x3 attitude
    error; ukf: 6x6 attitude error and bias, ``T P T^T``, ``T = blkdiag(2 Xi^T, I)``)."""
    if flags[F_READY] == 1:
        out_q[k] = x[:4]
    elif flags[F_F] == 1:
        f_b = s[S_F : S_F + 3]
        out_q[k] = triad(f_b, f_b, False, f_b, False)
    else:
        out_q[k] = 0.0
        out_q[k, 0] = 1.0
    kind = cfg["paper_kind"]
    if kind == KIND_PAPER:
        out_cov[k] = P
        return
    q = x[:4].copy()
    out_cov[k, :3, :3] = att_cov_from_quat_cov(q, P[:4, :4])
    if kind == KIND_UKF:
        X = Xi(q)
        for i in range(3):
            out_bg[k, i] = x[4 + i]
            for j in range(3):
                out_cov[k, 3 + i, 3 + j] = P[4 + i, 4 + j]
                c = 0.0  # (2 Xi^T P_qb)[i, j]
                for a in range(4):
                    c += 2.0 * X[a, i] * P[a, 4 + j]
                out_cov[k, i, 3 + j] = c
                out_cov[k, 3 + j, i] = c


@njit(**_JIT)
def run_events(st, t_ev, kinds, vals, out_q, out_bg, out_cov, rec):
    """base.replay, compiled: feed the merged events (t_ev (E,), kinds (E,), vals (E, 6);
    an air row carries the wind in columns 3..5), skip and count NaN samples, and (rec)
    record for IMU sample k the state after every event with t <= t_imu[k]."""
    cfg, prm, s, flags, x, P, wm, wc, work, sup, inn, acc = st
    k = -1
    n_ev = t_ev.shape[0]
    for i in range(n_ev):
        kind = kinds[i]
        t = t_ev[i]
        row = vals[i]
        if kind == EVENT_IMU:
            k += 1
        if not sample_ok(kind, row):
            flags[K_SKIP + kind] += 1
        elif kind == EVENT_IMU:
            step_imu(cfg, prm, s, flags, x, P, wm, wc, work, sup, inn, acc, t, row[:3].copy(), row[3:6].copy())
        elif kind == EVENT_MAG:
            step_mag(cfg, prm, s, flags, x, P, wm, wc, work, sup, inn, acc, t, row[:3].copy())
        elif kind == EVENT_GNSS:
            step_gnss(s, flags, t, row[:3].copy())
        elif kind == EVENT_AIR:
            step_air(cfg, prm, s, flags, x, P, wm, wc, work, sup, inn, acc, t, row[1], row[2], row[3:6].copy())
        if rec and k >= 0 and (i + 1 == n_ev or kinds[i + 1] == EVENT_IMU):
            record(cfg, s, flags, x, P, k, out_q, out_bg, out_cov)


# --- Python side: configuration, streamer, estimator base ---------------------------------


@dataclass(frozen=True)
class KernelConfig:
    """What distinguishes the four filters, encoded once per run. kind: KIND_*; n: state
    size (4, or 7 with the gyro bias); q_start: fixed initial attitude (4,) or None
    (TRIAD); use_air: fuse the air-flow row; p0_iso: the paper's ``P0 = p0_var I4``;
    the rest as in the filters' parameter records (variances and densities in SI)."""

    kind: int
    n: int = 4
    q_start: F64 | None = None
    use_air: bool = False
    p0_iso: bool = False
    p0_var: float = 0.0
    att0_var: float = 0.0
    bg0_var: float = 0.0
    b0: F64 | None = None
    process_var: float = 0.0
    acc_var: float = 0.0
    mag_var: float = 0.0
    air_var: float = 0.0
    gnss_max_age: float = 0.0
    gyro_noise: float = 0.0
    accel_noise: float = 0.0
    accel_sigma_unit: float = 0.0
    mag_noise: float = 0.0
    mag_sigma_unit: float = 0.0
    gyro_bias_rw: float = 0.0
    ut: tuple[float, float, float] = (1.0, 0.0, 1.0)  # alpha, beta, kappa


def make_state(c: KernelConfig, site: Site, has: frozenset[str], caps: dict[int, int]) -> KernelState:
    """A fresh KernelState for the filter c at the site; has: the streams that will be fed;
    caps: innovation log rows by sensor (core.layout's INN_ACCEL, INN_MAG, INN_AIR; at
    most one per event of its stream)."""
    cfg = np.zeros(1, core.CFG)[0]
    # the core's fields: the covariance, the form of H, no error-state blocks to inject into
    cfg["n"] = c.n
    cfg["add_form"] = core.ADD_COV
    cfg["i_v"] = cfg["i_w"] = cfg["i_ba"] = cfg["i_bm"] = -1
    cfg["i_bg"] = 3 if c.n == 7 else -1  # the UKF's gyro bias: covariance rows 4..6
    rows = np.zeros(core.N_SENSORS, dtype=np.int64)
    for sensor, cap in caps.items():
        rows[sensor] = cap
    total = log_layout(cfg, rows)
    cfg["paper_kind"] = c.kind
    cfg["has_mag"] = int("mag" in has)
    cfg["qstart_given"] = int(c.q_start is not None)
    cfg["use_air"] = int(c.use_air)
    cfg["p0_iso"] = int(c.p0_iso)
    prm = np.zeros(1, core.PRM)[0]
    prm["p0_var"] = c.p0_var
    prm["att0_var"] = c.att0_var
    prm["bg0_var"] = c.bg0_var
    prm["q_var"] = c.process_var
    prm["paper_acc_var"] = c.acc_var
    prm["paper_mag_var"] = c.mag_var
    prm["air_var"] = c.air_var
    prm["gnss_age"] = c.gnss_max_age
    prm["gyro_noise2"] = c.gyro_noise**2
    prm["gyro_bias_noise2"] = c.gyro_bias_rw**2
    prm["acc_noise"] = c.accel_noise
    prm["acc_unit2"] = c.accel_sigma_unit**2
    prm["mag_noise"] = c.mag_noise
    prm["mag_unit2"] = c.mag_sigma_unit**2
    prm["g_norm"] = site.gravity
    if c.q_start is not None:
        q = np.asarray(c.q_start, dtype=np.float64)
        if q.shape != (4,):
            raise ValueError(f"initial.q_nb: expected shape (4,), found {q.shape}")
        prm["qstart"] = q
    if c.b0 is not None:
        b = np.asarray(c.b0, dtype=np.float64)
        if b.shape != (3,):
            raise ValueError(f"initial.gyro_bias_b: expected shape (3,), found {b.shape}")
        prm["b0"] = b
    s = np.zeros(N_S)
    s[S_TGNSS] = -np.inf
    s[S_TSTATE] = -np.inf  # no sample yet
    flags = np.zeros(N_FLAGS_ADD, dtype=np.int64)
    flags[core.L_FIRST : core.L_FIRST + core.N_SENSORS] = -1
    prm["site_decl"] = 0.0 if site.declination is None else site.declination
    if site.mag_n is not None:
        prm["site_field"] = site.mag_n
        norm = float(np.linalg.norm(site.mag_n))
        s[S_MAGNORM] = norm
        s[S_MAGREF : S_MAGREF + 3] = site.mag_n / norm
        flags[F_MAGREF] = 1
    if c.kind == KIND_UKF:
        wm, wc, spread = ut_weights(c.n, *c.ut)
        prm["spread"] = spread
    else:
        wm, wc = np.ones(1), np.ones(1)
    x = np.zeros(c.n)
    x[0] = 1.0
    sup = np.zeros((2, core.NMAX), dtype=np.int64)
    sup[1, :4] = np.arange(4)  # the vector rows' H: on the quaternion's columns
    return KernelState(
        cfg=cfg,
        prm=prm,
        s=s,
        flags=flags,
        x=x,
        P=np.eye(c.n),
        wm=wm,
        wc=wc,
        work=np.zeros((core.N_WORK, max(c.n, core.NMAX))),
        sup=sup,
        inn=np.empty((total, 5)),
        acc=np.zeros(total, dtype=np.bool_),
    )


def _innovations(st: KernelState) -> dict[str, Innovations]:
    """The logs as Estimate innovations, keyed in the order sensors first logged."""
    return read_logs(st.cfg, st.flags, st.inn, st.acc)


def unfused_counts(st: KernelState) -> dict[str, int]:
    """Samples not fused, by reason (UNFUSED), those counted only."""
    c = st.flags[K_UNF : K_UNF + 4]
    return {r: int(v) for r, v in zip(UNFUSED, c, strict=True) if v > 0}


_STREAMS = ("imu", "mag", "gnss", "air")


class AdditiveStreamer(EventStreamer):
    """An additive-quaternion filter fed sample by sample through the same compiled loop
    as the batch run (so a flight streamed equals its batch estimate)."""

    def __init__(
        self,
        filter_name: str,
        config: KernelConfig,
        site: Site,
        has: frozenset[str],
        labels: tuple[str, ...],
        wind: WindProvider | None = None,
    ) -> None:
        super().__init__(filter_name)
        self._c = config
        self._labels = labels
        self._wind = wind
        self._st = make_state(config, site, has, dict.fromkeys(LOGGED, 256))
        d = len(labels)
        self._q, self._bg, self._cov = np.empty((1, 4)), np.empty((1, 3)), np.empty((1, d, d))

    @property
    def unfused(self) -> dict[str, int]:
        """Samples that could not be fused (no reference yet, no GNSS, ...), by reason."""
        return unfused_counts(self._st)

    def _step(self, kind: int, t: float) -> None:
        st = self._st
        cnt = st.flags[core.L_CNT : core.L_CNT + core.N_SENSORS]
        if (cnt >= st.cfg["log_cap"]).any():
            cfg, inn, acc = grown_logs(st.cfg, st.flags, st.inn, st.acc)  # an event logs at most one row
            self._st = st = st._replace(cfg=cfg, inn=inn, acc=acc)
        run_events(st, self._t, self._kind, self._row, self._q, self._bg, self._cov, False)

    def _air(self, t: float, tas: float, aoa: float, sideslip: float) -> None:
        # the air row also carries the wind the filter is given
        self._row[0, 3:6] = np.nan if self._wind is None else self._wind(t)
        skipped = int(self._st.flags[K_SKIP + 3])
        super()._air(t, tas, aoa, sideslip)
        self.skipped["air"] += int(self._st.flags[K_SKIP + 3]) - skipped  # vanes NaN

    def innovations(self) -> dict[str, Innovations]:
        return _innovations(self._st)

    @property
    def state(self) -> StateView:
        st = self._st
        record(st.cfg, st.s, st.flags, st.x, st.P, 0, self._q, self._bg, self._cov)
        return StateView(
            t=float(st.s[S_TSTATE]),
            q_nb=self._q[0].copy(),
            gyro_bias_b=self._bg[0].copy() if self._c.n == 7 else None,
            v_n=None,
            wind_n=None,
            cov=self._cov[0].copy(),
            state_labels=self._labels,
        )


class AdditiveEstimator(Estimator):
    """Base of the four additive-quaternion estimators: ``run`` in one compiled loop,
    ``streamer`` over the same loop. Subclasses give :meth:`config` and ``labels``."""

    #: labels of the reported covariance
    labels: ClassVar[tuple[str, ...]]
    params: Any

    def config(self, initial: InitialState | None) -> KernelConfig:
        """The kernel encoding of this filter's parameters (and the initial state)."""
        raise NotImplementedError

    def _wind_for(self, flight: Flight) -> WindProvider | None:
        """The wind provider for a batch run (only the paper's filter has one)."""
        return None

    def streamer(
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> AdditiveStreamer:
        """A streaming instance; ``has`` empty means every stream the filter uses."""
        return AdditiveStreamer(self.name, self.config(initial), site, has or self.uses, self.labels)

    def run(self, flight: Flight, *, initial: InitialState | None = None) -> Estimate:
        """Estimate the whole flight in one compiled loop (equal to streaming it)."""
        self.check(flight)
        wind = self._wind_for(flight)
        has = self.uses & frozenset(s for s in _STREAMS if getattr(flight, s) is not None)
        t_ev, kinds, vals = merge_events(flight, has)
        vals = np.ascontiguousarray(vals)
        if wind is not None:
            air = np.flatnonzero(kinds == EVENT_AIR)
            vals[air, 3:6] = wind_at(wind, t_ev[air])
        c = self.config(initial)
        counts = stream_counts(flight, has)
        caps = {INN_ACCEL: counts["imu"], INN_MAG: counts["mag"], INN_AIR: counts["air"]}
        st = make_state(c, flight.site, has, caps)
        N, d = len(flight.imu.t), len(self.labels)
        q, cov = np.empty((N, 4)), np.empty((N, d, d))
        bg = np.empty((N, 3)) if c.n == 7 else np.empty((0, 3))
        run_events(st, t_ev, kinds, vals, q, bg, cov, True)
        skipped = st.flags[K_SKIP : K_SKIP + 4]
        return checked(Estimate(
            filter=self.label,
            t=flight.imu.t.copy(),
            q_nb=q,
            gyro_bias_b=bg if c.n == 7 else None,
            v_n=None,
            wind_n=None,
            cov=cov,
            state_labels=self.labels,
            innovations=_innovations(st),
            skipped={s: int(v) for s, v in zip(_STREAMS, skipped, strict=True)},
            params=self.params_text(),
            meta=self._meta(st, wind),
        ), flight)

    def _meta(self, st: KernelState, wind: WindProvider | None = None) -> dict[str, Any]:
        """``Estimate.meta`` of a batch run: the final state and the wind provider it used."""
        return {}


def wind_at(wind: WindProvider, t: F64) -> F64:
    """The provider's wind (len(t), 3) at the times t (s); a provider with a vectorised
    ``at(t)`` (the oracle, the constant) is evaluated in one call."""
    at = getattr(wind, "at", None)
    if at is not None:
        return np.asarray(at(t), dtype=np.float64).reshape(len(t), 3)
    return np.array([wind(float(ti)) for ti in t], dtype=np.float64).reshape(len(t), 3)


# --- parameter records: checks and TOML ---------------------------------------------------

_P = TypeVar("_P")


def bad_param(obj: object, name: str, expected: str) -> ValueError:
    """ValueError naming the field of a parameter record, expected and found."""
    found = getattr(obj, name)
    return ValueError(f"{type(obj).__name__}.{name}: expected {expected}, found {found!r}")


def check_number(obj: object, name: str, *, positive: bool) -> None:
    """Raise unless the field is a finite number > 0 (positive) or >= 0."""
    v = getattr(obj, name)
    ok = isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v)
    if not ok or (v <= 0 if positive else v < 0):
        raise bad_param(obj, name, "a finite number " + ("> 0" if positive else ">= 0"))
    if v > MAX_MAGNITUDE:
        raise bad_param(obj, name, f"at most {MAX_MAGNITUDE:g}")


def check_choice(obj: object, name: str, choices: tuple[str, ...]) -> None:
    """Raise unless the field is one of choices."""
    if getattr(obj, name) not in choices:
        raise bad_param(obj, name, "one of " + ", ".join(repr(c) for c in choices))


def params_from_toml(params_type: type[_P], path: str | os.PathLike[str]) -> _P:
    """Parameters from a TOML file holding one ``[windahrs]`` table of our field names
    (the PX4 / ArduPilot tables of the error-state filters have no meaning here)."""
    p = Path(path)
    data = read_param_file(p)
    other = sorted(set(data) - {"windahrs"})
    if other:
        raise ValueError(f"{p}: expected only a [windahrs] table, found [{other[0]}]")
    raw = data.get("windahrs", {})
    if not isinstance(raw, dict):
        raise ValueError(f"{p}: [windahrs] must be a table, found {type(raw).__name__}")
    table: dict[str, Any] = dict(raw)
    known = {f.name for f in dataclasses.fields(params_type)}  # type: ignore[arg-type]
    unknown = sorted(set(table) - known)
    if unknown:
        raise ValueError(
            f"{p}: [windahrs].{unknown[0]}: expected one of {', '.join(sorted(known))}, found an unknown key"
        )
    if isinstance(table.get("mean_wind_n"), list):
        table["mean_wind_n"] = tuple(table["mean_wind_n"])
    try:
        return params_type(**table)
    except ValueError as exc:
        raise ValueError(f"{p}: {exc}") from None
