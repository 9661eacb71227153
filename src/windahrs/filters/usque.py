"""[usque] Unscented quaternion estimator (SPEC 4.1; Crassidis & Markley, JGCA 26(4), 2003),
written for Hamilton quaternions and a body-frame error, in numba nopython kernels.

The state is the attitude ``q_nb`` with the gyro bias; the filter's uncertainty lives in
the 6-dim tangent vector ``[dp, db]``, ``dp`` the generalised Rodrigues parameters (GRP,
a = 1, f = 4) of the body-frame error ``q_true = q_hat * dq(dp)``. With f = 2(a + 1),
``dp = 4 tan(|dtheta|/4) e = dtheta + O(|dtheta|^3)``.

Everything the error-state [mekf] decides is decided the same way here, and taken from
:mod:`windahrs.core` rather than written again: parameters
(:class:`~windahrs.filters.params.EskfParams`), the :class:`~windahrs.core.layout.KernelState`
(encoded by ``make_state`` for an [att, bg] layout), initialisation (InitialState or TRIAD,
waiting for a magnetometer sample), the magnetometer reference, the scalar quaternion
helpers, the innovation logs, the recording of states and covariance and the streamer
(:class:`~windahrs.core.kernel.CompiledStreamer` with the step loop swapped). The process
noise is the Farrenkopf closed form of SPEC 2.4; the measurement models are those of
:mod:`windahrs.aid.gravity` and :mod:`windahrs.aid.mag` (the accelerometer as gravity only,
the magnetometer in 3-D or as heading), with [mekf]'s gates (``| |f| - g |`` and the per-component innovation
test). Only the way the mean and covariance travel through the models differs: unscented
transforms with 2n + 1 = 13 sigma points, lambda = 1, the same weights for mean and
covariance.

This module is the only implementation; run with ``NUMBA_DISABLE_JIT=1`` it is the readable
reference (tests/test_usque.py holds the two equal). The sigma points and their predictions
live in scratch rows of the kernel's ``work`` array (the U_* row offsets below), so nothing
is allocated per sample (except in the eigen-square-root fallback, which runs only when
rounding has made P indefinite).

The covariance is that of ``[dp, dbg]``; it is reported as the covariance of the
body-frame rotation-vector error (labels ``att_*``) without conversion, since
``dp = dtheta`` to first order (relative difference ``|dtheta|^2/48``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np
from numba import njit
from numpy.typing import NDArray

from windahrs.aid.gravity import accel_variance, blend_mean, knows_gravity
from windahrs.aid.mag import heading_reset, mag_reference, measured_heading
from windahrs.core import predict as process
from windahrs.core.dense import unscented_gain
from windahrs.core.events import sample_ok
from windahrs.core.kalman import _gate, _log
from windahrs.core.kernel import (
    _STREAMS,
    CompiledStreamer,
    Kind,
    _grow,
    _innovations,
    _resets,
    _rotate_lowpass,
    corrected_turn,
    effective_mag_mode,
    imu_clock,
    init_index,
    layout_for,
    mag_ready,
    make_state,
    record,
)
from windahrs.core.layout import (
    _JIT,
    INN_ACCEL,
    INN_MAG,
    K_SKIP,
    L_CNT,
    MAG_3D,
    MAG_OFF,
    N_SENSORS,
    S_FBAR,
    SENSOR_STREAMS,
    SENSORS,
    X_BG,
    X_Q,
    KernelState,
)
from windahrs.core.predict import _lowpass_gain, track_accel_noise
from windahrs.core.quat import (
    _dcm9,
    _euler,
    _qexp,
    _qmul,
    _qnormalize,
    _wrap_pi,
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
from windahrs.estimate import Estimate
from windahrs.filters.base import EVENT_IMU, EVENT_MAG, Estimator, InitialState, merge_events, stream_counts
from windahrs.filters.checks import checked
from windahrs.filters.params import EskfParams
from windahrs.flight import Flight, Site
from windahrs.rotation import quat_normalize

__all__ = ["GRP_A", "GRP_F", "USQUE_LAMBDA", "Usque", "UsqueStreamer", "run_usque", "sqrt_cov"]

F64 = NDArray[np.float64]

#: Generalised Rodrigues parameters: a and f = 2 (a + 1), so that dp ~ dtheta.
GRP_A = 1.0
GRP_F = 2.0 * (GRP_A + 1.0)
#: Sigma-point spread of the 6-dim state (Crassidis & Markley use lambda = 1).
USQUE_LAMBDA = 1.0

_N = 6  # [dp, dbg]
_NP = 2 * _N + 1  # sigma points
_SPREAD = _N + USQUE_LAMBDA
_W0 = USQUE_LAMBDA / (_N + USQUE_LAMBDA)  # weight of the centre ...
_WI = 0.5 / (_N + USQUE_LAMBDA)  # ... and of each +- point
_F2 = GRP_F * GRP_F

# Scratch rows of KernelState.work (N_WORK = 66 rows of NMAX = 19 columns).
U_S = 0  # (13, 6) sigma offsets [dp, db]
U_Q = 13  # (13, 4) sigma-point quaternions
U_Y = 26  # (13, 6) propagated errors X, or (13, m) predicted measurements Y
U_L = 39  # (6, 6) square root of (n + lambda) P
U_PYY = 45  # (3, 3) innovation covariance
U_SI = 48  # (3, 3) its inverse
U_PXY = 51  # (6, 3) cross covariance
U_K = 57  # (6, 3) gain
U_MEAN = 63  # mean of X or Y
U_NU = 64  # innovation
U_DX = 65  # correction [dp, db]

_KERNEL_KIND: Kind = "mekf"  # the [att, bg] layout and initialisation of make_state / _try_init


# --- generalised Rodrigues parameters ----------------------------------------------------------


@njit(**_JIT)
def _dq_from_grp(p0, p1, p2):
    """Error quaternion of the GRP ``dp`` (SPEC 4.1: dq0 = (-a s + f sqrt(f^2 + (1 - a^2) s))
    / (f^2 + s), s = |dp|^2; a = 1 drops the root). ``|dp| <= 4`` covers every rotation up to
    180 deg; larger ``dp`` give the same rotations again with ``dq0 < 0``."""
    s = p0 * p0 + p1 * p1 + p2 * p2
    q0 = (_F2 - s) / (_F2 + s)
    c = GRP_A + q0
    return q0, c * p0 / GRP_F, c * p1 / GRP_F, c * p2 / GRP_F


@njit(**_JIT)
def _grp_from_dq(q0, q1, q2, q3):
    """GRP of a unit error quaternion; ``dq`` and ``-dq`` give the same result (the one with
    ``dq0 >= 0``: the shorter rotation, ``|dp| <= 4``), so the map is defined everywhere."""
    sign = -1.0 if q0 < 0.0 else 1.0
    d = GRP_A + sign * q0
    return GRP_F * sign * q1 / d, GRP_F * sign * q2 / d, GRP_F * sign * q3 / d


# --- sigma points -------------------------------------------------------------------------


@njit(**_JIT)
def sqrt_cov(P, spread, L):
    """A square root L[:6, :6] with ``L L^T = spread P``: the lower Cholesky factor of
    ``spread`` times the symmetrised P; if rounding has left that indefinite, the eigen square
    root with negative eigenvalues clipped to zero."""
    h = spread * 0.5
    for i in range(_N):
        for j in range(_N):
            L[i, j] = h * (P[i, j] + P[j, i])
    ok = True
    for j in range(_N):  # in place: L[i, j] (i >= j) still holds A[i, j] when first read
        s = L[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:  # LAPACK's test (NaN included)
            ok = False
            break
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, _N):
            v = L[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k]
            L[i, j] = v / d
        for i in range(j):
            L[i, j] = 0.0
    if ok:
        return
    A = np.empty((_N, _N))
    for i in range(_N):
        for j in range(_N):
            A[i, j] = h * (P[i, j] + P[j, i])
    w, V = np.linalg.eigh(A)
    for j in range(_N):
        r = math.sqrt(max(w[j], 0.0))
        for i in range(_N):
            L[i, j] = V[i, j] * r


@njit(**_JIT)
def _sigma(x, P, work):
    """Sigma offsets S = 0, +-columns of sqrt((n + lambda) P) and the
    point quaternions q_i = q * dq(S_i^p) (the biases are bg + S_i^b, formed by callers)."""
    S, Q, L = work[U_S : U_S + _NP], work[U_Q : U_Q + _NP], work[U_L : U_L + _N]
    sqrt_cov(P, _SPREAD, L)
    for c in range(_N):
        S[0, c] = 0.0
        for i in range(_N):
            v = L[c, i]  # column i of L
            S[1 + i, c] = v
            S[1 + _N + i, c] = -v
    a0, a1, a2, a3 = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
    for i in range(_NP):
        d = _dq_from_grp(S[i, 0], S[i, 1], S[i, 2])
        Q[i, 0], Q[i, 1], Q[i, 2], Q[i, 3] = _qmul(a0, a1, a2, a3, d[0], d[1], d[2], d[3])


@njit(**_JIT)
def _weighted_cov(D, n, C):
    """C[:n, :n] = sum_i w_i D_i D_i^T over the 13 rows of D (exactly symmetric)."""
    for r in range(n):
        for c in range(r, n):
            s = _W0 * D[0, r] * D[0, c]
            for i in range(1, _NP):
                s += _WI * D[i, r] * D[i, c]
            C[r, c] = s
            C[c, r] = s


@njit(**_JIT)
def _centre(Y, n, mean):
    """mean[:n] = sum_i w_i Y_i; Y[:, :n] -= mean."""
    for c in range(n):
        s = _W0 * Y[0, c]
        for i in range(1, _NP):
            s += _WI * Y[i, c]
        mean[c] = s
        for i in range(_NP):
            Y[i, c] -= s


@njit(**_JIT)
def _add_process_noise(sg2, sb2, dt, P):
    """P[:6, :6] += the discrete process noise of ``[dtheta, dbg]`` over ``dt`` s (SPEC 2.4,
    the Farrenkopf closed form; the [att, bg] blocks of the error-state model). sg2: gyro
    noise density squared (rad/s)^2/Hz, sb2: bias random walk squared (rad/s^2)^2/Hz."""
    qaa = sg2 * dt + sb2 * dt**3 / 3.0
    qab = -sb2 * dt**2 / 2.0
    qbb = sb2 * dt
    for k in range(3):
        P[k, k] += qaa
        P[k, k + 3] += qab
        P[k + 3, k] += qab
        P[k + 3, k + 3] += qbb


@njit(**_JIT)
def _propagate(prm, x, P, work, w0, w1, w2, dt):
    """SPEC 4.1 steps 1-4 over ``dt`` s with the gyro sample ``w`` (rad/s): the points through
    the exact quaternion exponential, their errors about the propagated centre, mean,
    covariance plus process noise, and the new estimate."""
    _sigma(x, P, work)
    S, Q, X = work[U_S : U_S + _NP], work[U_Q : U_Q + _NP], work[U_Y : U_Y + _NP]
    mean = work[U_MEAN]
    for i in range(_NP):
        b0, b1, b2 = x[X_BG] + S[i, 3], x[X_BG + 1] + S[i, 4], x[X_BG + 2] + S[i, 5]
        e = _qexp((w0 - b0) * dt, (w1 - b1) * dt, (w2 - b2) * dt)
        Q[i, 0], Q[i, 1], Q[i, 2], Q[i, 3] = _qmul(Q[i, 0], Q[i, 1], Q[i, 2], Q[i, 3], e[0], e[1], e[2], e[3])
        X[i, 3], X[i, 4], X[i, 5] = b0, b1, b2
    # errors relative to the propagated centre: dp(q_0^* q_i), dp_0 = 0 exactly
    c0, c1, c2, c3 = Q[0, 0], -Q[0, 1], -Q[0, 2], -Q[0, 3]
    X[0, 0], X[0, 1], X[0, 2] = 0.0, 0.0, 0.0
    for i in range(1, _NP):
        d = _qmul(c0, c1, c2, c3, Q[i, 0], Q[i, 1], Q[i, 2], Q[i, 3])
        X[i, 0], X[i, 1], X[i, 2] = _grp_from_dq(d[0], d[1], d[2], d[3])
    _centre(X, _N, mean)
    _weighted_cov(X, _N, P)
    _add_process_noise(prm["gyro_noise2"], prm["gyro_bias_noise2"], dt, P)
    d = _dq_from_grp(mean[0], mean[1], mean[2])
    q = _qmul(Q[0, 0], Q[0, 1], Q[0, 2], Q[0, 3], d[0], d[1], d[2], d[3])
    x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = _qnormalize(q[0], q[1], q[2], q[3])
    x[X_BG], x[X_BG + 1], x[X_BG + 2] = mean[3], mean[4], mean[5]


@njit(**_JIT)
def _predict_vector(work, r0, r1, r2):
    """Y_i = C_bn(q_i) r for the 13 point quaternions: the prediction of
    accelerometer as gravity (r = -g_n, :mod:`windahrs.aid.gravity`) and of the 3-D
    magnetometer (r = m_n, :mod:`windahrs.aid.mag`), expanded."""
    Q, Y = work[U_Q : U_Q + _NP], work[U_Y : U_Y + _NP]
    for i in range(_NP):
        w, v0, v1, v2 = Q[i, 0], Q[i, 1], Q[i, 2], Q[i, 3]
        c0, c1, c2 = v1 * r2 - v2 * r1, v2 * r0 - v0 * r2, v0 * r1 - v1 * r0  # v x r
        a = w * w - (v0 * v0 + v1 * v1 + v2 * v2)
        b = 2.0 * (v0 * r0 + v1 * r1 + v2 * r2)
        Y[i, 0] = (a * r0 + b * v0) - 2.0 * w * c0
        Y[i, 1] = (a * r1 + b * v1) - 2.0 * w * c1
        Y[i, 2] = (a * r2 + b * v2) - 2.0 * w * c2


@njit(**_JIT)
def _predict_heading(work):
    """The points' ZYX yaw (the "yaw" heading model of :mod:`windahrs.aid.mag`), unwrapped about the centre's:
    Y_0 + wrap(Y_i - Y_0)."""
    Q, Y = work[U_Q : U_Q + _NP], work[U_Y : U_Y + _NP]
    for i in range(_NP):
        Y[i, 0] = _euler(Q[i, 0], Q[i, 1], Q[i, 2], Q[i, 3])[2]
    y0 = Y[0, 0]
    for i in range(_NP):
        Y[i, 0] = y0 + _wrap_pi(Y[i, 0] - y0)


@njit(**_JIT)
def _update(cfg, x, flags, P, work, inn, acc, sensor, t, m, var, gate2, angle):
    """SPEC 4.1 step 5 once ``_sigma`` and the predictions
    Y (13, m) are in place: the measurement is in work[U_NU, :m], noise ``var`` I (m = 1
    or 3); ``angle``: differences wrapped to +-pi. Returns whether it was accepted."""
    S, Y = work[U_S : U_S + _NP], work[U_Y : U_Y + _NP]
    Pyy, Si = work[U_PYY : U_PYY + 3], work[U_SI : U_SI + 3]
    Pxy, K = work[U_PXY : U_PXY + _N], work[U_K : U_K + _N]
    y, nu, dx = work[U_MEAN], work[U_NU], work[U_DX]
    _centre(Y, m, y)
    _weighted_cov(Y, m, Pyy)
    for k in range(m):
        Pyy[k, k] += var
        z = nu[k]
        nu[k] = _wrap_pi(z - y[k]) if angle else z - y[k]
    for r in range(_N):
        for k in range(m):
            s = _W0 * S[0, r] * Y[0, k]
            for i in range(1, _NP):
                s += _WI * S[i, r] * Y[i, k]
            Pxy[r, k] = s
    if not _gate(cfg, flags, inn, acc, nu, Pyy, Si, sensor, t, m, gate2):
        return False
    unscented_gain(P, Pxy, Si, nu, K, dx, np.int64(_N), m)  # K, dx = K nu, P -= K Pyy K^T
    d = _dq_from_grp(dx[0], dx[1], dx[2])
    q = _qmul(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], d[0], d[1], d[2], d[3])
    x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = _qnormalize(q[0], q[1], q[2], q[3])
    for a in range(3):
        x[X_BG + a] += dx[3 + a]
    return True


# --- event steps and the loop ---------------------------------------------------------------


@njit(inline="always", **_JIT)
def _step_imu(cfg, prm, x, flags, P, work, inn, acc, t, row):
    """An IMU sample row = [w_b, f_b] (finite): initialise, or propagate and fuse the
    accelerometer as gravity (gated on ``| |f| - g |``): with accel_lowpass, its mean in an
    almost inertial frame, as :func:`windahrs.aid.gravity.fuse_gravity` takes it (the same
    rotation of the mean, the same on-line noise)."""
    dt = imu_clock(cfg, prm, x, flags, P, work, t, row)
    if dt < 0:
        return
    fx, fy, fz = row[3], row[4], row[5]
    if dt > 0:
        if flags[S_FBAR] == 1:
            _rotate_lowpass(cfg, prm, x, flags, corrected_turn(x, row, dt), dt)
        _propagate(prm, x, P, work, row[0], row[1], row[2], dt)
        if cfg["accel_noise_online"] >= 1:
            track_accel_noise(cfg, prm, x, dt)
    var = accel_variance(cfg, prm, x)
    f_now = math.sqrt(fx * fx + fy * fy + fz * fz)  # the sample's own length (knows_gravity)
    if flags[S_FBAR] == 1:
        fx, fy, fz = blend_mean(prm, x, _lowpass_gain(dt, prm["accel_lowpass"]), fx, fy, fz)
    nu = work[U_NU]
    g = prm["gravity"]
    f_norm = math.sqrt(fx * fx + fy * fy + fz * fz)
    if abs(f_norm - g) > prm["accel_norm_gate"] * g:
        nu[0], nu[1], nu[2] = np.nan, np.nan, np.nan
        _log(cfg, flags, inn, acc, nu, np.int64(INN_ACCEL), t, np.int64(3), np.nan, np.bool_(False))
        return
    # lost gravity, as the gravity aid source sees it (windahrs.aid.gravity, core.reset): the
    # measured down direction -f too far from the state's C_bn e_3 for reset_timeout
    c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    sensor = np.int64(INN_ACCEL)
    if knows_gravity(-(fx * c[6] + fy * c[7] + fz * c[8]) / f_norm, f_now, g):
        accepted_at(x, sensor, t)
    elif timed_out(prm, x, sensor, t):
        angle = level_to(x, -fx, -fy, -fz)
        set_attitude_cov(cfg, prm, x, P, work)
        reset_gyro_bias(cfg, prm, x, P)
        log_reset(cfg, flags, inn, acc, work, x, sensor, t, angle)
        retake_heading(cfg, prm, x, flags, t)
        return
    _sigma(x, P, work)
    _predict_vector(work, -0.0, -0.0, -g)  # -g_n
    nu[0], nu[1], nu[2] = fx, fy, fz
    sensor, m = np.int64(INN_ACCEL), np.int64(3)
    _update(cfg, x, flags, P, work, inn, acc, sensor, t, m, var, prm["gate_accel2"], False)


@njit(inline="always", **_JIT)
def _step_mag(cfg, prm, x, flags, P, work, inn, acc, t, row):
    """A magnetometer sample row[:3] (tesla, body; finite): initialise, or fuse it in 3-D or
    as heading."""
    mx, my, mz = row[0], row[1], row[2]
    if not mag_ready(cfg, prm, x, flags, P, work, row):
        return
    mode = cfg["mag_mode"]
    if mode == MAG_OFF:
        return
    rx, ry, rz = mag_reference(cfg, prm, x, flags, mx, my, mz)
    if heading_reset(cfg, prm, x, flags, P, work, inn, acc, t, mx, my, mz, rx, ry):
        return
    nu = work[U_NU]
    sensor = np.int64(INN_MAG)
    if mode == MAG_3D:
        _sigma(x, P, work)
        _predict_vector(work, rx, ry, rz)
        nu[0], nu[1], nu[2] = mx, my, mz
        _update(cfg, x, flags, P, work, inn, acc, sensor, t, np.int64(3), prm["mag_var"], prm["gate_mag2"], False)
        return
    # heading only, tilt-compensated with the current roll/pitch estimate (as [mekf])
    roll, pitch, _ = _euler(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    nu[0] = measured_heading(roll, pitch, mx, my, mz, rx, ry)
    sigma = prm["mag_sigma"] / max(math.hypot(rx, ry), 1e-9)
    _sigma(x, P, work)
    _predict_heading(work)
    _update(cfg, x, flags, P, work, inn, acc, sensor, t, np.int64(1), sigma**2, prm["gate_mag2"], True)


@njit(**_JIT)
def run_usque(st, t_ev, kinds, vals, out_q, out_bg, out_vw, out_cov, rec):
    """core.kernel.run_events for [usque]: feed the merged events (t_ev (E,), kinds (E,),
    vals (E, 6)), skip and count NaN samples, and (rec) record for IMU sample k the state
    after every event with t <= t_imu[k]. out_vw: an empty (0, 3) array (no velocity or
    wind states). Events other than IMU and magnetometer are ignored."""
    k = np.int64(-1)
    cfg, prm, x, flags, P, work, _, inn, acc = st[:9]  # (the core's fields: no aid source's records)
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
            _step_imu(cfg, prm, x, flags, P, work, inn, acc, t, row)
        elif kind == EVENT_MAG:
            _step_mag(cfg, prm, x, flags, P, work, inn, acc, t, row)
        if rec and k >= 0 and (i + 1 == n_ev or kinds[i + 1] == EVENT_IMU):
            record(cfg, prm, x, flags, P, work, k, out_q, out_bg, out_vw, out_vw, out_cov)


# --- Python side ----------------------------------------------------------------------------


def _kernel_params(params: EskfParams) -> EskfParams:
    """The parameters make_state encodes: [usque] carries no magnetometer-bias states
    whatever init_mag_bias says, so the [att, bg] layout."""
    return params.replace(init_mag_bias=0.0) if params.init_mag_bias > 0 else params


def _kernel_initial(initial: InitialState | None) -> InitialState | None:
    """The given attitude normalised (the [mekf] kernels take it as is)."""
    if initial is None:
        return None
    return dataclasses.replace(initial, q_nb=quat_normalize(np.asarray(initial.q_nb, dtype=np.float64)))


class UsqueStreamer(CompiledStreamer):
    """[usque] fed sample by sample through the batch loop :func:`run_usque` (so a flight
    streamed equals its batch estimate bit for bit)."""

    def __init__(
        self, name: str, params: EskfParams, site: Site, initial: InitialState | None, has: frozenset[str]
    ) -> None:
        super().__init__(name, _KERNEL_KIND, False, _kernel_params(params), site, _kernel_initial(initial), has)

    def _step(self, kind: int, t: float) -> None:
        st = self._st
        if (st.flags[L_CNT : L_CNT + N_SENSORS] >= st.cfg["log_cap"]).any():
            self._st = st = _grow(st)  # an event logs at most one row per sensor
        run_usque(st, self._t, self._kind, self._row, self._none[0], self._none[1], self._none[2], self._none[4], False)

    def _gnss(self, t: float, v_n: F64, v_sigma: float) -> None:
        """[usque] fuses no GNSS velocity."""

    def _air(self, t: float, tas: float, aoa: float, sideslip: float) -> None:
        """[usque] fuses no air data."""


#: The fields of EskfParams that [usque] uses: its process model's, the accelerometer as
#: gravity (no compensation; the low-pass and the on-line noise of [mekf]) and the
#: magnetometer (the yaw heading model; no low-pass, no disturbance checks, no hard-iron
#: states).
PARAMS = (
    *process.ATTITUDE_PARAMS,
    "accel_sigma",
    "accel_lowpass",
    "accel_noise_online",
    "accel_noise_mean_start",
    "accel_norm_gate",
    "gate_accel",
    "mag_mode",
    "mag_sigma",
    "mag_3d_needs_site",
    "gate_mag",
    "reset_timeout",
)


class Usque(Estimator):
    """[usque] unscented quaternion estimator: attitude and gyro bias; accelerometer
    (gravity, gated) and magnetometer, with the models, noise and gates of [mekf].

    params: :class:`EskfParams`, of which it uses :data:`PARAMS` (a spec or a parameter
    file that sets another field is refused; accel_compensation must stay "none": this
    filter fuses no GNSS or air data to compensate with).
    """

    name: ClassVar[str] = "usque"
    requires: ClassVar[frozenset[str]] = frozenset({"imu"})
    uses: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})
    #: gravity as [mekf] and [ekf7] take it in the field (the 3 s mean, the accelerometer's
    #: noise on line; stop 19): ANSFL tilt 25.4 -> 5.14 deg (even 4.71, odd 6.38; vqf 5.56),
    #: BROAD total / inclination 3.31 / 2.06 -> 2.02 / 1.26; the simulated quadrotor
    #: unchanged (0.42 -> 0.41 deg, 8 m/s), fixed wings worse (simulated 1.35 -> 3.94, ALFA
    #: 18.6 -> 25.5: the mean keeps their coordinated turns). The reproduction's matched runs
    #: take raw samples.
    default_params: ClassVar[EskfParams] = EskfParams(accel_lowpass=3.0, accel_noise_online=True)

    @classmethod
    def param_names(cls) -> frozenset[str]:
        """The fields of :class:`EskfParams` [usque] uses (the others cannot be set on it)."""
        return frozenset(PARAMS)

    def __init__(self, params: EskfParams | None = None) -> None:
        p = params if params is not None else self.default_params
        if not isinstance(p, EskfParams):
            raise TypeError(f"params: expected EskfParams, found {type(p).__name__}")
        if p.accel_compensation != "none":
            raise ValueError(
                "accel_compensation: expected 'none' ([usque] fuses no GNSS or air data to "
                f"compensate the accelerometer with), found {p.accel_compensation!r}"
            )
        self.params = p

    def run(self, flight: Flight, *, initial: InitialState | None = None) -> Estimate:
        """Estimate the whole flight in one compiled loop."""
        self.check(flight)
        has = frozenset(s for s in _STREAMS if getattr(flight, s) is not None) & self.uses
        t_ev, kinds, vals = merge_events(flight, has)
        counts = stream_counts(flight, has)
        fused = ("accel", "mag", "reset")  # [usque]'s aid sources, and its resets
        caps = np.array(
            [counts[s] if k in fused else 0 for k, s in zip(SENSORS, SENSOR_STREAMS, strict=True)], dtype=np.int64
        )
        kp = _kernel_params(self.params)
        st: KernelState = make_state(_KERNEL_KIND, False, kp, flight.site, _kernel_initial(initial), has, caps)
        L = layout_for(_KERNEL_KIND, kp)
        N = len(flight.imu.t)
        q, bg, cov = np.empty((N, 4)), np.empty((N, 3)), np.empty((N, _N, _N))
        run_usque(st, t_ev, kinds, np.ascontiguousarray(vals), q, bg, np.empty((0, 3)), cov, True)
        skipped = st.flags[K_SKIP : K_SKIP + 4]
        return checked(Estimate(
            filter=self.label,
            t=flight.imu.t.copy(),
            q_nb=q,
            gyro_bias_b=bg,
            v_n=None,
            wind_n=None,
            cov=cov,
            state_labels=L.labels(),
            innovations=_innovations(st, effective_mag_mode(self.params, flight.site)),
            skipped={s: int(c) for s, c in zip(_STREAMS, skipped, strict=True)},
            params=self.params_text(),
            resets=_resets(st),
            init_index=init_index(st.x, flight.imu.t),
        ), flight)

    def streamer(
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> UsqueStreamer:
        return UsqueStreamer(self.name, self.params, site, initial, has)
