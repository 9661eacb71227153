"""The process models of the compiled core: the error-state prediction (attitude, gyro bias,
velocity, wind, accelerometer and magnetometer biases; SPEC 2.4, 2.5) and the additive
quaternion prediction of [ekf7] and [ekf10] (SPEC 2.3), with the normalisation that
projects the covariance (which the paper's filters, windahrs.filters.additive, use too).

The transition matrix is the identity except a few 3x3 blocks in the attitude (and
velocity) rows, so each prediction rewrites only those rows and columns of P (O(n) work
instead of the O(n^3) of a dense ``Phi P Phi^T``); the 3x3 blocks live in local scalars.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from windahrs.core.layout import (
    _JIT_CORE,
    _JIT_FMA,
    W_DX,
    W_M,
    W_T,
    W_X,
    X_AVAR,
    X_BA,
    X_BG,
    X_DF,
    X_DW,
    X_NAVAR,
    X_NGAIN,
    X_PDT,
    X_PF,
    X_PN,
    X_PW,
    X_Q,
    X_V,
)
from windahrs.core.quat import (
    _dcm9,
    _qexp_half,
    _qmul,
    _qnormalize,
    _sinc,
    _xi_into,
)

#: The parameters of the process models (fields of :class:`windahrs.filters.params.EskfParams`):
#: attitude and gyro bias (every filter), the held-sample noise of long IMU steps (the EKFs on
#: this core), the rate-proportional gyro noise (error-state only), the INS (velocity from the
#: accelerometer, its bias), the wind states.
ATTITUDE_PARAMS = ("gyro_noise", "gyro_bias_noise", "init_att", "init_yaw", "init_bias", "init_window")
HELD_SAMPLE_PARAMS = ("unmeasured_motion_dt",)
GYRO_SCALE_PARAMS = ("gyro_scale_noise",)
#: ... and the gyro bias's walk about the nav vertical at a density of its own (error-state only).
BIAS_WALK_PARAMS = ("gyro_bias_noise_vertical",)
#: ... and the INS's covariance predicted once per period over the IMU steps in it.
COV_PERIOD_PARAMS = ("cov_period",)
INS_PARAMS = ("accel_noise", "accel_noise_measured", "accel_bias_noise", "init_accel_bias", "init_v")

#: The time constant of the accelerometer noise measured on line when no low-pass gives it, s
#: (the INS; VQF's tau_acc, 3 s: long against one rotor's or gait's cycle, short against a
#: change of throttle or terrain).
NOISE_TAU = 3.0
WIND_PARAMS = ("wind_noise", "wind_noise_vertical", "wind_vertical", "init_wind")


@njit(**_JIT_CORE)
def _lowpass_gain(dt, tau):
    """Weight of a new sample in a first-order low-pass after dt."""
    return 1.0 - math.exp(-dt / tau) if dt > 0 else 0.0


@njit(inline="always", **_JIT_CORE)
def steady_gain(x, i, dt, tau):
    """:func:`_lowpass_gain` (dt, tau) of a low-pass whose tau is fixed for the run, remembered
    with its step in x[i:i+2] (dt, gain): at a steady sample rate the exponential once. A
    fresh state (zeros) holds the gain of dt = 0, which is 0."""
    if dt != x[i]:
        x[i], x[i + 1] = dt, _lowpass_gain(dt, tau)
    return x[i + 1]


@njit(inline="always", **_JIT_CORE)
def add_to_mean(x, i0, n, v0, v1, v2):
    """x[i0:i0+3], the plain mean of n - 1 samples, after the n-th, v."""
    x[i0] += (v0 - x[i0]) / n
    x[i0 + 1] += (v1 - x[i0 + 1]) / n
    x[i0 + 2] += (v2 - x[i0 + 2]) / n


@njit(inline="always", **_JIT_CORE)
def track_accel_noise(cfg, prm, x, dt):
    """The accelerometer's noise on line, from the differences of consecutive samples
    (x[X_DF], kept by the kernel): (f_k - f_k-1) / sqrt(2) has the variance of the
    sample-to-sample noise (vibration, aliased rotor harmonics), while the smooth motion of
    the vehicle barely enters it at IMU rates; low-passed over accel_lowpass (else
    NOISE_TAU) into x[X_AVAR], per axis (m/s^2)^2 per sample. cfg["accel_noise_online"] 2: VQF's filter
    start, the mean of the samples so far until the low-pass's own gain takes over, so that
    the first seconds are weighed by the noise measured, not by a variance growing from zero.
    Read by the gravity aid source (its R) and the INS's prediction (its input's density)."""
    d0, d1, d2 = x[X_DF], x[X_DF + 1], x[X_DF + 2]
    gain = steady_gain(x, np.int64(X_NGAIN), dt, prm["accel_lowpass"] if prm["accel_lowpass"] > 0 else NOISE_TAU)
    if cfg["accel_noise_online"] == 2:
        x[X_NAVAR] += 1.0
        gain = max(gain, 1.0 / x[X_NAVAR])
    x[X_AVAR] += gain * ((d0 * d0 + d1 * d1 + d2 * d2) / 6.0 - x[X_AVAR])


@njit(inline="always", **_JIT_CORE)
def ins_accel_density2(cfg, prm, x, dt):
    """The INS's accelerometer noise density squared, (m/s^2)^2/Hz: accel_noise's, or the
    noise measured on line (x[X_AVAR], a per-sample variance: density^2 = var * step, at the
    sample step dt s) when that is larger (accel_noise_measured)."""
    sa2 = prm["accel_noise2"]
    if cfg["accel_noise_online"] >= 1:
        sa2 = max(sa2, x[X_AVAR] * dt)
    return sa2


@njit(**_JIT_FMA)
def _predict_es(cfg, prm, x, P, work, wmx, wmy, wmz, fmx, fmy, fmz, dt):
    """The error-state prediction (SPEC 2.4, 2.5) over one IMU step: the nominal state
    (:func:`_nominal_es`), then the covariance (:func:`_cov_es`). Returns the step's turn
    Exp((w_m - b_g) dt) (the kernel turns its low-passed means with it)."""
    e, sh, wx, wy, wz, fx, fy, fz = _nominal_es(cfg, prm, x, wmx, wmy, wmz, fmx, fmy, fmz, dt)
    _cov_es(cfg, prm, x, P, work, wx, wy, wz, fx, fy, fz, dt, e[0], sh, dt)
    return e


@njit(inline="always", **_JIT_FMA)
def _nominal_es(cfg, prm, x, wmx, wmy, wmz, fmx, fmy, fmz, dt):
    """The nominal state over one IMU step of dt s at the measured rate w_m and specific force
    f_m: the attitude turned by Exp((w_m - b_g) dt), and (the INS) the velocity moved by
    (C_nb (f_m - b_a) + g) dt with the turned attitude. Returns the turn, the sine of its half
    angle, and the bias-corrected rate and specific force (what :func:`_cov_es` takes)."""
    wx, wy, wz = wmx - x[X_BG], wmy - x[X_BG + 1], wmz - x[X_BG + 2]
    e, sh = _qexp_half(wx * dt, wy * dt, wz * dt)
    q = _qmul(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], e[0], e[1], e[2], e[3])
    x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = _qnormalize(q[0], q[1], q[2], q[3])
    fx, fy, fz = fmx, fmy, fmz
    if cfg["i_v"] >= 0:
        C = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
        if cfg["i_ba"] >= 0:
            fx, fy, fz = fmx - x[X_BA], fmy - x[X_BA + 1], fmz - x[X_BA + 2]
        x[X_V] += (C[0] * fx + C[1] * fy + C[2] * fz + 0.0) * dt
        x[X_V + 1] += (C[3] * fx + C[4] * fy + C[5] * fz + 0.0) * dt
        x[X_V + 2] += (C[6] * fx + C[7] * fy + C[8] * fz + prm["gravity"]) * dt
    return e, sh, wx, wy, wz, fx, fy, fz


@njit(**_JIT_FMA)
def _cov_es(cfg, prm, x, P, work, wx, wy, wz, fx, fy, fz, dt, e0, sh, dts):
    """The error-state covariance over a step of dt s at the bias-corrected rate w and
    specific force f, with the attitude the step ends at (x's), ``Phi P Phi^T + Q``, using
    Phi's block structure: only the attitude (and velocity) rows and columns of P change
    before Q is added (layout: att 0..2, v 3..5). The 3x3 blocks of Phi live in local
    scalars. e0, sh: the cosine and sine of half the turn's angle |w| dt. dts: the IMU's
    sample step, s (dt, or its mean over the steps of a period): the accelerometer noise
    measured per sample becomes a density at it (:func:`ins_accel_density2`)."""
    n, ib, iv, iw, iba = cfg["n"], cfg["i_bg"], cfg["i_v"], cfg["i_w"], cfg["i_ba"]
    M, X = work[W_M : W_M + 8], work[W_X : W_X + 8]
    w = cfg["rows"]  # the columns of M's rows (below)
    # the attitude transition: phi11 = I + c11 W + c12 W^2, phi12 = -dt I + c21 W + c22 W^2,
    # W = [w]x; W^2 = w w^T - |w|^2 I entry by entry as W @ W evaluates it.
    a = math.sqrt(wx * wx + wy * wy + wz * wz)
    if a * dt < 1e-6:  # the series (the closed form loses precision)
        c11, c12 = -dt, 0.5 * dt**2
        c21, c22 = 0.5 * dt**2, -(dt**3) / 6.0
    else:  # sin(a dt) and 1 - cos(a dt) from the turn's half angle (sh, e0 its cosine)
        s, omc = 2.0 * sh * e0, 2.0 * sh * sh
        c11, c12 = -s / a, omc / a**2
        c21, c22 = omc / a**2, -(a * dt - s) / a**3
    xy, xz, yz = wy * wx, wz * wx, wz * wy
    s00, s11, s22 = -(wz * wz) - wy * wy, -(wz * wz) - wx * wx, -(wy * wy) - wx * wx
    p00, p01, p02 = 1.0 + c12 * s00, c11 * -wz + c12 * xy, c11 * wy + c12 * xz
    p10, p11, p12 = c11 * wz + c12 * xy, 1.0 + c12 * s11, c11 * -wx + c12 * yz
    p20, p21, p22 = c11 * -wy + c12 * xz, c11 * wx + c12 * yz, 1.0 + c12 * s22
    r00, r01, r02 = -dt + c22 * s00, c21 * -wz + c22 * xy, c21 * wy + c22 * xz
    r10, r11, r12 = c21 * wz + c22 * xy, -dt + c22 * s11, c21 * -wx + c22 * yz
    r20, r21, r22 = c21 * -wy + c22 * xz, c21 * wx + c22 * yz, -dt + c22 * s22
    # M[0:3] = attitude rows of Phi P = phi11 P[att] + phi12 P[bg]. One output row per loop
    # keeps LLVM's runtime alias checks few enough to vectorise. Each runs over w columns
    # (cfg["rows"], core.kernel.make_state), P's padded width for a large covariance: its
    # padding columns are zero, so are M's there, never read.
    for j in range(w):
        M[0, j] = (
            p00 * P[0, j]
            + p01 * P[1, j]
            + p02 * P[2, j]
            + r00 * P[ib, j]
            + r01 * P[ib + 1, j]
            + (r02 * P[ib + 2, j])
        )
    for j in range(w):
        M[1, j] = (
            p10 * P[0, j]
            + p11 * P[1, j]
            + p12 * P[2, j]
            + r10 * P[ib, j]
            + r11 * P[ib + 1, j]
            + (r12 * P[ib + 2, j])
        )
    for j in range(w):
        M[2, j] = (
            p20 * P[0, j]
            + p21 * P[1, j]
            + p22 * P[2, j]
            + r20 * P[ib, j]
            + r21 * P[ib + 1, j]
            + (r22 * P[ib + 2, j])
        )
    na = 3
    f00 = f01 = f02 = f10 = f11 = f12 = f20 = f21 = f22 = 0.0
    d00 = d01 = d02 = d10 = d11 = d12 = d20 = d21 = d22 = 0.0
    if iv >= 0:
        na = 6
        C = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
        # Phi[v, att] = CF phi11, Phi[v, bg] = CF phi12 with CF = -C [f]x dt; Phi[v, ba] = -C dt
        f00, f01, f02 = (
            (-C[1] * fz + C[2] * fy) * dt,
            (-C[2] * fx + C[0] * fz) * dt,
            (-C[0] * fy + C[1] * fx) * dt,
        )
        f10, f11, f12 = (
            (-C[4] * fz + C[5] * fy) * dt,
            (-C[5] * fx + C[3] * fz) * dt,
            (-C[3] * fy + C[4] * fx) * dt,
        )
        f20, f21, f22 = (
            (-C[7] * fz + C[8] * fy) * dt,
            (-C[8] * fx + C[6] * fz) * dt,
            (-C[6] * fy + C[7] * fx) * dt,
        )
        d00, d01, d02, d10, d11, d12 = -C[0] * dt, -C[1] * dt, -C[2] * dt, -C[3] * dt, -C[4] * dt, -C[5] * dt
        d20, d21, d22 = -C[6] * dt, -C[7] * dt, -C[8] * dt
        # M[3:6] = velocity rows of Phi P = P[v] + CF M[0:3] (+ Cdt P[ba])
        if iba >= 0:
            for j in range(w):
                M[3, j] = (
                    P[iv, j]
                    + (f00 * M[0, j] + f01 * M[1, j] + f02 * M[2, j])
                    + (d00 * P[iba, j] + d01 * P[iba + 1, j] + d02 * P[iba + 2, j])
                )
            for j in range(w):
                M[4, j] = (
                    P[iv + 1, j]
                    + (f10 * M[0, j] + f11 * M[1, j] + f12 * M[2, j])
                    + (d10 * P[iba, j] + d11 * P[iba + 1, j] + d12 * P[iba + 2, j])
                )
            for j in range(w):
                M[5, j] = (
                    P[iv + 2, j]
                    + (f20 * M[0, j] + f21 * M[1, j] + f22 * M[2, j])
                    + (d20 * P[iba, j] + d21 * P[iba + 1, j] + d22 * P[iba + 2, j])
                )
        else:
            for j in range(w):
                m0, m1, m2 = M[0, j], M[1, j], M[2, j]
                M[3, j] = P[iv, j] + (f00 * m0 + f01 * m1 + f02 * m2)
                M[4, j] = P[iv + 1, j] + (f10 * m0 + f11 * m1 + f12 * m2)
                M[5, j] = P[iv + 2, j] + (f20 * m0 + f21 * m1 + f22 * m2)
    # X = Phi P Phi^T on the attitude/velocity rows and columns (0..na-1)
    for r in range(na):
        t0, t1, t2, g0, g1, g2 = M[r, 0], M[r, 1], M[r, 2], M[r, ib], M[r, ib + 1], M[r, ib + 2]
        x0 = t0 * p00 + t1 * p01 + t2 * p02 + g0 * r00 + g1 * r01 + g2 * r02
        x1 = t0 * p10 + t1 * p11 + t2 * p12 + g0 * r10 + g1 * r11 + g2 * r12
        x2 = t0 * p20 + t1 * p21 + t2 * p22 + g0 * r20 + g1 * r21 + g2 * r22
        X[r, 0], X[r, 1], X[r, 2] = x0, x1, x2
        if iv >= 0:
            X[r, 3] = M[r, 3] + (f00 * x0 + f01 * x1 + f02 * x2)
            X[r, 4] = M[r, 4] + (f10 * x0 + f11 * x1 + f12 * x2)
            X[r, 5] = M[r, 5] + (f20 * x0 + f21 * x1 + f22 * x2)
            if iba >= 0:
                g0, g1, g2 = M[r, iba], M[r, iba + 1], M[r, iba + 2]
                X[r, 3] += d00 * g0 + d01 * g1 + d02 * g2
                X[r, 4] += d10 * g0 + d11 * g1 + d12 * g2
                X[r, 5] += d20 * g0 + d21 * g1 + d22 * g2
    # write back, exactly symmetric; the rest of P is unchanged (Phi is the identity there)
    for j in range(na, n):
        m0, m1, m2 = M[0, j], M[1, j], M[2, j]
        P[0, j], P[1, j], P[2, j] = m0, m1, m2
        P[j, 0], P[j, 1], P[j, 2] = m0, m1, m2
        if na == 6:
            m0, m1, m2 = M[3, j], M[4, j], M[5, j]
            P[3, j], P[4, j], P[5, j] = m0, m1, m2
            P[j, 3], P[j, 4], P[j, 5] = m0, m1, m2
    for r in range(na):
        for c in range(r, na):
            v = 0.5 * (X[r, c] + X[c, r])
            P[r, c] = v
            P[c, r] = v
    # process noise
    sg2, sb2 = prm["gyro_noise2"], prm["gyro_bias_noise2"]
    if prm["gyro_scale_noise2"] > 0:  # rate-proportional gyro noise
        sg2 = sg2 + prm["gyro_scale_noise2"] * (wx * wx + wy * wy + wz * wz)
    qaa = sg2 * dt + sb2 * dt**3 / 3.0
    qab = -sb2 * dt**2 / 2.0
    qbb = sb2 * dt
    sa2 = ins_accel_density2(cfg, prm, x, dts) if iv >= 0 else prm["accel_noise2"]
    if prm["gyro_bias_noise_dv2"] != 0.0:  # the bias's walk about the vertical: its own density
        _bias_walk_vertical(x, P, ib, prm["gyro_bias_noise_dv2"], dt)
    for k in range(3):
        P[k, k] += qaa
        P[k, ib + k] += qab
        P[ib + k, k] += qab
        P[ib + k, ib + k] += qbb
        if iv >= 0:
            P[iv + k, iv + k] += sa2 * dt
        if iba >= 0:
            P[iba + k, iba + k] += prm["accel_bias_noise2"] * dt
        if cfg["i_bm"] >= 0:
            P[cfg["i_bm"] + k, cfg["i_bm"] + k] += prm["mag_bias_noise2"] * dt
    if iw >= 0:
        P[iw, iw] += prm["wind_noise2"] * dt
        P[iw + 1, iw + 1] += prm["wind_noise2"] * dt
        P[iw + 2, iw + 2] += prm["wind_noise_vertical2"] * dt


#: The INS's covariance is predicted once per ``cov_period`` s over the IMU steps in it, its
#: nominal state at every step (:class:`windahrs.filters.params.EskfParams`, PX4 EKF2's
#: ``EKF2_PREDICT_US``). A step closes the period when the steps deferred sum to within half a
#: step of it; the covariance is brought up to date at once before anything reads or changes
#: it (:func:`flush_cov`).


@njit(inline="always", **_JIT_CORE)
def defer_cov(x, wx, wy, wz, fx, fy, fz, dt):
    """One IMU step of dt s at the bias-corrected rate w and specific force f added to the
    covariance's pending step (x[X_PN] steps, x[X_PDT] s, the sums of w dt and f dt)."""
    x[X_PN] += 1.0
    x[X_PDT] += dt
    x[X_PW] += wx * dt
    x[X_PW + 1] += wy * dt
    x[X_PW + 2] += wz * dt
    x[X_PF] += fx * dt
    x[X_PF + 1] += fy * dt
    x[X_PF + 2] += fz * dt


@njit(inline="always", **_JIT_CORE)
def cov_pending(cfg, prm, x, P, work):
    """P predicted over the pending steps as one step of their summed length at their mean rate
    and specific force (:func:`defer_cov`), with the attitude they end at; x unchanged."""
    T = x[X_PDT]
    e, sh = _qexp_half(x[X_PW], x[X_PW + 1], x[X_PW + 2])
    _cov_es(cfg, prm, x, P, work, x[X_PW] / T, x[X_PW + 1] / T, x[X_PW + 2] / T,
            x[X_PF] / T, x[X_PF + 1] / T, x[X_PF + 2] / T, T, e[0], sh, T / x[X_PN])


@njit(inline="always", **_JIT_CORE)
def flush_cov(cfg, prm, x, P, work):
    """The pending steps' covariance prediction done (:func:`cov_pending`) and the pending
    step emptied; nothing when none is pending."""
    if x[X_PN] == 0.0:
        return
    cov_pending(cfg, prm, x, P, work)
    for i in range(X_PF + 3 - X_PN):
        x[X_PN + i] = 0.0


@njit(inline="always", **_JIT_CORE)
def _bias_walk_vertical(x, P, ib, ds2, dt):
    """The gyro bias's random walk about the nav vertical at a density whose square differs
    from the isotropic one's by ds2: ds2 u u^T added to the walk's density, u the nav down
    in the body (C_bn e_3), with its attitude terms (-dt^2 / 2, dt^3 / 3) as the isotropic
    walk's."""
    w, qx, qy, qz = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
    u = (2.0 * (qx * qz - w * qy), 2.0 * (qy * qz + w * qx), w * w - qx * qx - qy * qy + qz * qz)  # C_nb's last row
    a3, a2, a1 = ds2 * dt**3 / 3.0, ds2 * dt**2 / 2.0, ds2 * dt
    for r in range(3):
        ur = u[r]
        for k in range(3):
            uu = ur * u[k]  # (u[r] u[k] and u[k] u[r]: the same number, so P stays symmetric)
            P[r, k] += a3 * uu
            P[r, ib + k] -= a2 * uu
            P[ib + r, k] -= a2 * uu
            P[ib + r, ib + k] += a1 * uu


@njit(**_JIT_CORE)
def _normalise_add(cfg, x, P, work, q0, q1, q2, q3):
    """The additive filters' normalisation: q <- q/|q| (w >= 0), P <- J P J^T with
    J = blkdiag(+-(I - u u^T)/|q|, I), u = q/|q| (the sign of the flip to w >= 0 in J:
    the quaternion's covariance with the other states changes sign), the quaternion block
    symmetrised. (q0..q3): the quaternion before; P (n, n), n = cfg["n"], the quaternion
    in its first four rows; in place."""
    M, X = work[W_M : W_M + 8], work[W_X : W_X + 8]
    n = cfg["n"]
    nq = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    u = work[W_DX]  # (free here: any correction was applied before)
    u[0], u[1], u[2], u[3] = q0 / nq, q1 / nq, q2 / nq, q3 / nq
    sign = -1.0 if u[0] < 0.0 else 1.0
    # J = +-(I - u u^T)/|q| in X[4:8, 0:4]
    for r in range(4):
        for c in range(4):
            eye = 1.0 if r == c else 0.0
            X[4 + r, c] = sign * ((eye - u[r] * u[c]) / nq)
    # M[0:4] = J P[0:4, :]
    for r in range(4):
        j0, j1, j2, j3 = X[4 + r, 0], X[4 + r, 1], X[4 + r, 2], X[4 + r, 3]
        for j in range(P.shape[1]):
            M[r, j] = j0 * P[0, j] + j1 * P[1, j] + j2 * P[2, j] + j3 * P[3, j]
    for r in range(4):
        for c in range(4):
            X[r, c] = (
                M[r, 0] * X[4 + c, 0]
                + M[r, 1] * X[4 + c, 1]
                + M[r, 2] * X[4 + c, 2]
                + (M[r, 3] * X[4 + c, 3])
            )
    for r in range(4):
        for j in range(4, n):
            P[r, j] = M[r, j]
            P[j, r] = M[r, j]
        for c in range(r, 4):
            v = 0.5 * (X[r, c] + X[c, r])
            P[r, c] = v
            P[c, r] = v
    x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = sign * u[0], sign * u[1], sign * u[2], sign * u[3]


@njit(inline="always", **_JIT_FMA)
def _noise_add(cfg, prm, P, Xi, dt):
    """SPEC 2.3's discrete process noise of the additive state ``[q; b_g (; W)]`` added to
    P (n, n), n = cfg["n"]: ``(sg2 dt/4 + sb2 dt^3/12) Xi Xi^T`` on the quaternion,
    ``-sb2 dt^2/4 Xi`` with the gyro bias, ``sb2 dt I`` on it, the wind's random walk;
    Xi (4, 3) = Xi(q_k). A state without gyro bias (cfg["i_bg"] < 0, [ekf]) has the
    quaternion block alone (sb2 = 0). Shared by :func:`_predict_add` and the additive UKF."""
    sg2, sb2 = prm["gyro_noise2"], prm["gyro_bias_noise2"]
    ib = cfg["i_bg"] + 1 if cfg["i_bg"] >= 0 else -1
    iw = cfg["i_w"] + 1 if cfg["i_w"] >= 0 else -1
    cqq = sg2 * dt / 4.0 + sb2 * dt**3 / 12.0
    cqb = -sb2 * dt**2 / 4.0
    for r in range(4):
        for c in range(4):
            P[r, c] += cqq * (Xi[r, 0] * Xi[c, 0] + Xi[r, 1] * Xi[c, 1] + Xi[r, 2] * Xi[c, 2])
        if ib > 0:
            for k in range(3):
                P[r, ib + k] += cqb * Xi[r, k]
                P[ib + k, r] += cqb * Xi[r, k]
    if ib > 0:
        for k in range(3):
            P[ib + k, ib + k] += sb2 * dt
    if iw >= 0:
        P[iw, iw] += prm["wind_noise2"] * dt
        P[iw + 1, iw + 1] += prm["wind_noise2"] * dt
        P[iw + 2, iw + 2] += prm["wind_noise_vertical2"] * dt


@njit(**_JIT_FMA)
def _predict_add(cfg, prm, x, P, work, wmx, wmy, wmz, dt):
    """The additive prediction (SPEC 2.3) of [ekf7], [ekf10] and [ekf]: the exact transition
    ``q_k = Phi(dtheta) q``, ``dtheta = (w_m - b) dt``, F = [[Phi, -(dt/2) Xi(q_k) J_r], [0, I]],
    Q of :func:`_noise_add`, then the normalisation. Without a gyro-bias state
    (cfg["i_bg"] < 0: [ekf], the 4-state EKF) dtheta = w_m dt and F = Phi."""
    M, X, Xi = work[W_M : W_M + 4], work[W_X : W_X + 8], work[W_M + 4 : W_M + 8]
    Jr, K = work[W_T : W_T + 3, 0:3], work[W_T + 3 : W_T + 6, 0:3]
    Fqb = work[W_T + 6 : W_T + 10, 0:3]  # 4x3 (borrows a row of the next matrix)
    n = cfg["n"]
    ib = cfg["i_bg"] + 1 if cfg["i_bg"] >= 0 else -1
    dx, dy, dz = wmx * dt, wmy * dt, wmz * dt
    if ib > 0:
        dx, dy, dz = (wmx - x[X_BG]) * dt, (wmy - x[X_BG + 1]) * dt, (wmz - x[X_BG + 2]) * dt
    a = math.sqrt(dx * dx + dy * dy + dz * dz)
    s = 0.5 * _sinc(a / (2.0 * math.pi))
    ch = math.cos(0.5 * a)
    # Phi4 = cos(a/2) I + s Omega(d), in X[4:8, 0:4]
    X[4, 0], X[4, 1], X[4, 2], X[4, 3] = ch, -s * dx, -s * dy, -s * dz
    X[5, 0], X[5, 1], X[5, 2], X[5, 3] = s * dx, ch, s * dz, -s * dy
    X[6, 0], X[6, 1], X[6, 2], X[6, 3] = s * dy, -s * dz, ch, s * dx
    X[7, 0], X[7, 1], X[7, 2], X[7, 3] = s * dz, s * dy, -s * dx, ch
    p0, p1, p2, p3 = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
    qk = (
        X[4, 0] * p0 + X[4, 1] * p1 + X[4, 2] * p2 + X[4, 3] * p3,
        X[5, 0] * p0 + X[5, 1] * p1 + X[5, 2] * p2 + X[5, 3] * p3,
        X[6, 0] * p0 + X[6, 1] * p1 + X[6, 2] * p2 + X[6, 3] * p3,
        X[7, 0] * p0 + X[7, 1] * p1 + X[7, 2] * p2 + X[7, 3] * p3,
    )
    _xi_into(qk[0], qk[1], qk[2], qk[3], Xi)
    if ib > 0:
        # right Jacobian of the increment (rotation.right_jacobian)
        if a < 1e-5:
            c1 = 0.5 - a**2 / 24.0
            c2 = 1.0 / 6.0 - a**2 / 120.0
        else:
            c1 = (1.0 - math.cos(a)) / a**2
            c2 = (a - math.sin(a)) / a**3
        K[0, 0], K[0, 1], K[0, 2] = 0.0, -dz, dy
        K[1, 0], K[1, 1], K[1, 2] = dz, 0.0, -dx
        K[2, 0], K[2, 1], K[2, 2] = -dy, dx, 0.0
        for r in range(3):
            for c in range(3):
                k2 = K[r, 0] * K[0, c] + K[r, 1] * K[1, c] + K[r, 2] * K[2, c]
                Jr[r, c] = (1.0 if r == c else 0.0) - c1 * K[r, c] + c2 * k2
        h = -0.5 * dt
        for r in range(4):
            for c in range(3):
                Fqb[r, c] = h * Xi[r, 0] * Jr[0, c] + h * Xi[r, 1] * Jr[1, c] + h * Xi[r, 2] * Jr[2, c]
        # M = quaternion rows of F P
        for r in range(4):
            f0, f1, f2, f3 = X[4 + r, 0], X[4 + r, 1], X[4 + r, 2], X[4 + r, 3]
            g0, g1, g2 = Fqb[r, 0], Fqb[r, 1], Fqb[r, 2]
            for j in range(P.shape[1]):
                M[r, j] = (
                    f0 * P[0, j] + f1 * P[1, j] + f2 * P[2, j] + f3 * P[3, j]
                    + g0 * P[ib, j] + g1 * P[ib + 1, j] + g2 * P[ib + 2, j]
                )  # fmt: skip
    else:
        for r in range(4):
            f0, f1, f2, f3 = X[4 + r, 0], X[4 + r, 1], X[4 + r, 2], X[4 + r, 3]
            for j in range(P.shape[1]):
                M[r, j] = f0 * P[0, j] + f1 * P[1, j] + f2 * P[2, j] + f3 * P[3, j]
    for r in range(4):
        for c in range(4):
            v = 0.0
            for k in range(4):
                v += M[r, k] * X[4 + c, k]
            if ib > 0:
                for k in range(3):
                    v += M[r, ib + k] * Fqb[c, k]
            X[r, c] = v
    for r in range(4):
        for j in range(4, n):
            P[r, j] = M[r, j]
            P[j, r] = M[r, j]
        for c in range(4):
            P[r, c] = X[r, c]
    _noise_add(cfg, prm, P, Xi, dt)
    _normalise_add(cfg, x, P, work, qk[0], qk[1], qk[2], qk[3])


@njit(inline="always", **_JIT_CORE)
def held_sample_variance(change, dt):
    """Variance of the integral over a step of dt s of a signal sampled at the step's end and
    held, when the sample differs from the previous one by ``change``: the change happened at
    an unmeasured instant within the step, uniformly distributed, so the held sample is wrong
    by ``change`` over a fraction u ~ U(0, 1) of the step: ``E[(change u dt)^2] =
    (change dt)^2 / 3``."""
    return (change * dt) ** 2 / 3.0


@njit(**_JIT_CORE)
def add_held_sample_noise(cfg, prm, x, P, work, dt):
    """After the prediction over a step of dt s longer than unmeasured_motion_dt: the noise
    of holding a point sample over motion it did not measure (:func:`held_sample_variance`),
    per body axis ``(dw dt)^2 / 3`` on the attitude and ``(df dt)^2 / 3`` on the INS velocity
    (rotated to NED), with dw, df the changes of the gyro and accelerometer samples since the
    previous ones (x[X_DW], x[X_DF]). Additive form: ``1/4 Xi(q) diag(d) Xi(q)^T`` on the
    quaternion (tangent to q, so adding it after the normalisation changes nothing else)."""
    if dt > prm["unmeasured_motion_dt"]:
        add_unmeasured_motion(cfg, x, P, work, dt)


@njit(**_JIT_CORE)
def add_unmeasured_motion(cfg, x, P, work, dt):
    """The noise of motion over a step of dt s that the filter did not propagate, per body
    axis ``(dw dt)^2 / 3`` on the attitude and ``(df dt)^2 / 3`` on the INS velocity, with
    dw, df (x[X_DW], x[X_DF]) the rate and specific force it may have missed
    (:func:`add_held_sample_noise`; the IMU screen's dropped spikes)."""
    d0 = held_sample_variance(x[X_DW], dt)
    d1 = held_sample_variance(x[X_DW + 1], dt)
    d2 = held_sample_variance(x[X_DW + 2], dt)
    if cfg["add_form"] == 1:
        Xi = work[W_M + 4 : W_M + 8]
        _xi_into(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], Xi)
        for r in range(4):
            for c in range(4):
                P[r, c] += 0.25 * (d0 * (Xi[r, 0] * Xi[c, 0]) + d1 * (Xi[r, 1] * Xi[c, 1]) + d2 * (Xi[r, 2] * Xi[c, 2]))
        return
    P[0, 0] += d0
    P[1, 1] += d1
    P[2, 2] += d2
    iv = cfg["i_v"]
    if iv >= 0:
        C = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
        d0 = held_sample_variance(x[X_DF], dt)
        d1 = held_sample_variance(x[X_DF + 1], dt)
        d2 = held_sample_variance(x[X_DF + 2], dt)
        for r in range(3):
            for c in range(r, 3):  # C diag(d) C^T, mirrored (P stays exactly symmetric)
                v = C[3 * r] * d0 * C[3 * c] + C[3 * r + 1] * d1 * C[3 * c + 1] + C[3 * r + 2] * d2 * C[3 * c + 2]
                P[iv + r, iv + c] += v
                if c != r:
                    P[iv + c, iv + r] += v
