"""The one Kalman update of every EKF (error-state, additive [ekf7]/[ekf10], and the
paper's [paper], [paper-nowind], [ekf]), with its gate and its innovation log.

:func:`_fuse` computes the NIS, gates each component at ``gate`` sigmas (the innovation
test ratio ``nu_k^2 / (gate^2 S_kk)`` of PX4's EKF2), logs the innovation, updates the
covariance, then injects the correction into the nominal state. The covariance update:

* the error-state filters' with the Kalman gain itself (:func:`_whitened`):
  ``P - U^T S^-1 U = P - V^T V`` on the whitened rows ``V = L^-1 U`` (``U = H P``,
  ``S = L L^T``), three products per entry of P, exactly symmetric in floating point;
* the Joseph form, evaluated expanded as ``P + K G^T + G K^T`` with ``G = K S / 2 - U^T``
  (algebraically ``(I - K H) P (I - K H)^T + K R K^T``, exactly symmetric too, six products
  per entry), for a gain changed after it was computed (the gravity aid's tilt-only and
  kept-bias gains) and for the quaternion-additive filters ([ekf7], [ekf10], the paper's),
  whose covariance is singular along q (SPEC 2.3: Joseph form there).

The two agree to rounding (the quaternions within 3.1e-14 rad over 60 s simulated flights,
docs/RESULTS.md section 37). An update with m rows (1, 2 or 3) whose Jacobian touches c
columns costs O(n c m + n^2 m). Every aid source
(windahrs.aid) fills ``nu``, ``H`` on its support columns and ``R`` in the scratch rows and
calls it; so does the paper's filters' vector update (windahrs.filters.additive), with H
on the quaternion's four parameters.

The innovation log is one block of rows per sensor (``core.layout.AID_LOGS``); the Python
side lays it out (:func:`log_layout`), grows it for a streamer (:func:`grown_logs`) and
reads it back as Estimate innovations (:func:`read_logs`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from windahrs.core.layout import (
    _JIT_CORE,
    ADD_ATT,
    ADD_COV,
    ADD_NONE,
    EVENT_LOGS,
    F64,
    I64,
    INN_ACCEL,
    INN_ASPD,
    INN_IMU,
    INN_RESET,
    L_CNT,
    L_FIRST,
    N_SENSORS,
    S_FBAR,
    S_MBAR,
    S_SEQ,
    SENSOR_ROWS,
    SENSORS,
    TRIANGLE_N,
    W_DX,
    W_G,
    W_H,
    W_HQ,
    W_K,
    W_NU,
    W_R,
    W_S,
    W_SI,
    W_U,
    X_BA,
    X_BG,
    X_BM,
    X_FBAR,
    X_JLAG,
    X_JMAG,
    X_KEEPBG,
    X_MBAR,
    X_Q,
    X_TINIT,
    X_V,
    X_W,
)
from windahrs.core.predict import (
    _normalise_add,
)
from windahrs.core.quat import (
    _dcm9,
    _qexp,
    _qmul,
    _qnormalize,
)
from windahrs.estimate import Innovations


@njit(inline="always", **_JIT_CORE)
def _log(cfg, flags, inn, acc, nu, sensor, t, m, nis, accepted):
    """Streamer._log: t, nu[:m] (NaN-padded to 3), nis, accepted."""
    c = flags[L_CNT + sensor]
    if c >= cfg["log_cap"][sensor]:
        raise IndexError("innovation log full")
    if c == 0:
        flags[L_FIRST + sensor] = flags[S_SEQ]
        flags[S_SEQ] += 1
    row = cfg["log_off"][sensor] + c
    inn[row, 0] = t
    for i in range(3):
        inn[row, 1 + i] = nu[i] if i < m else np.nan
    inn[row, 4] = nis
    acc[row] = accepted
    flags[L_CNT + sensor] = c + 1



def log_layout(cfg: np.void, caps: I64) -> int:
    """Lay the logs out in cfg: caps (N_SENSORS,) rows for each sensor, one block after
    the other. Returns the rows in all."""
    cfg["log_cap"] = caps
    cfg["log_off"] = np.concatenate([[0], np.cumsum(caps)[:-1]])
    return int(caps.sum())


def grown_logs(cfg: np.void, flags: I64, inn: F64, acc: NDArray[np.bool_]) -> tuple[np.void, F64, NDArray[np.bool_]]:
    """(cfg, inn, acc) with twice the rows for every full sensor log, the rows logged so
    far copied (new arrays; the arguments are left alone)."""
    cnt = flags[L_CNT : L_CNT + N_SENSORS]
    caps = cfg["log_cap"].copy()
    caps[cnt >= caps] *= 2
    cfg2 = cfg.copy()
    total = log_layout(cfg2, caps)
    inn2, acc2 = np.empty((total, 5)), np.zeros(total, dtype=np.bool_)
    for s in range(N_SENSORS):
        o, c, o2 = int(cfg["log_off"][s]), int(cnt[s]), int(cfg2["log_off"][s])
        inn2[o2 : o2 + c] = inn[o : o + c]
        acc2[o2 : o2 + c] = acc[o : o + c]
    return cfg2, inn2, acc2


def read_logs(
    cfg: np.void, flags: I64, inn: F64, acc: NDArray[np.bool_], *, heading: bool = False
) -> dict[str, Innovations]:
    """The logs as Estimate innovations, keyed in the order sensors first logged (the reset
    log is not one: ``Estimate.resets``); heading: the magnetometer was fused as a heading
    (1 row)."""
    cnt, first = flags[L_CNT : L_CNT + N_SENSORS], flags[L_FIRST : L_FIRST + N_SENSORS]
    out: dict[str, Innovations] = {}
    for s in sorted((s for s in range(N_SENSORS) if cnt[s] > 0 and s not in EVENT_LOGS), key=lambda s: int(first[s])):
        o, c = int(cfg["log_off"][s]), int(cnt[s])
        name = SENSORS[s]
        rows = 1 if name == "mag" and heading else SENSOR_ROWS[s]
        out[name] = Innovations(
            t=inn[o : o + c, 0].copy(),
            nu=inn[o : o + c, 1 : 1 + rows].copy(),
            nis=inn[o : o + c, 4].copy(),
            accepted=acc[o : o + c].copy(),
        )
    return out


def read_resets(cfg: np.void, flags: I64, inn: F64) -> dict[str, F64]:
    """The reset log (windahrs.core.reset) as ``Estimate.resets``: per sensor key, (K, 3)
    rows [t s, size, how long the sensor had disagreed s]."""
    o, c = int(cfg["log_off"][INN_RESET]), int(flags[L_CNT + INN_RESET])
    rows = inn[o : o + c]
    out: dict[str, F64] = {}
    for s in np.unique(rows[:, 1]).astype(int):
        mine = rows[rows[:, 1] == s]
        out[SENSORS[s]] = np.column_stack([mine[:, 0], mine[:, 2], mine[:, 3]])
    return out


def read_held(cfg: np.void, flags: I64, inn: F64) -> dict[str, F64]:
    """The IMU screen's log (windahrs.core.imu_screen) as ``Estimate.alerts["imu"]``: (K, 4)
    rows [t s, change of the angular rate rad/s, of the specific force m/s^2, outcome: 1
    beyond range, 2 a spike (not propagated), 3 motion (propagated one sample late)]; no key
    when no sample was held."""
    o, c = int(cfg["log_off"][INN_IMU]), int(flags[L_CNT + INN_IMU])
    rows = inn[o : o + c]
    return {"imu": np.column_stack([rows[:, :3], rows[:, 4]])} if c else {}


def read_airspeed_scale(cfg: np.void, flags: I64, inn: F64, acc: NDArray[np.bool_]) -> F64 | None:
    """The airspeed scale estimator's log (windahrs.aid.airspeed_scale) as
    ``Estimate.airspeed_scale``: (K, 5) rows [t s, scale, its standard deviation, airspeed
    innovation m/s, accepted]; None when it did not run."""
    o, c = int(cfg["log_off"][INN_ASPD]), int(flags[L_CNT + INN_ASPD])
    if c == 0:
        return None
    return np.column_stack([inn[o : o + c, :4], acc[o : o + c].astype(np.float64)])


@njit(**_JIT_CORE)
def _inverse_small(S, Si, m):
    """Si = S^-1 for m = 1, 2 or 3 (cofactors; S is a well-conditioned innovation covariance)."""
    if m == 1:
        Si[0, 0] = 1.0 / S[0, 0]
        return
    if m == 2:
        r = 1.0 / (S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0])
        Si[0, 0], Si[0, 1], Si[1, 0], Si[1, 1] = S[1, 1] * r, -S[0, 1] * r, -S[1, 0] * r, S[0, 0] * r
        return
    a, b, c = S[0, 0], S[0, 1], S[0, 2]
    d, e, f = S[1, 0], S[1, 1], S[1, 2]
    g, h, i = S[2, 0], S[2, 1], S[2, 2]
    A, B, C = e * i - f * h, f * g - d * i, d * h - e * g
    r = 1.0 / (a * A + b * B + c * C)
    Si[0, 0], Si[0, 1], Si[0, 2] = A * r, (c * h - b * i) * r, (b * f - c * e) * r
    Si[1, 0], Si[1, 1], Si[1, 2] = B * r, (a * i - c * g) * r, (c * d - a * f) * r
    Si[2, 0], Si[2, 1], Si[2, 2] = C * r, (b * g - a * h) * r, (a * e - b * d) * r


@njit(inline="always", **_JIT_CORE)
def within_gate(nu, S, m, gate2):
    """Whether each component of the innovation nu[:m] is within gate sigmas of its own
    variance S[k, k] (``nu_k^2 <= gate^2 S_kk``; False for a NaN)."""
    for k in range(m):
        if not (nu[k] * nu[k] <= gate2 * S[k, k]):
            return False
    return True


@njit(inline="always", **_JIT_CORE)
def _gate(cfg, flags, inn, acc, nu, S, Si, sensor, t, m, gate2):
    """Si = S^-1, the NIS ``nu^T S^-1 nu`` and the gate (each component within gate sigmas,
    ``nu_k^2 <= gate^2 S_kk``: PX4 EKF2's test ratio), logged; returns whether accepted.
    Shared by the EKF update below and the unscented update of [usque]."""
    _inverse_small(S, Si, m)
    nis = 0.0
    for k in range(m):
        v = 0.0
        for l in range(m):
            v += Si[k, l] * nu[l]
        nis += nu[k] * v
    accepted = within_gate(nu, S, m, gate2)
    _log(cfg, flags, inn, acc, nu, sensor, t, m, nis, accepted)
    return accepted


@njit(**_JIT_CORE)
def _fuse(cfg, x, flags, P, work, sups, inn, acc, sensor, t, m, nsup, gate2):
    """The Kalman update of the error-state and additive EKFs: NIS, gate, log, covariance
    update (:func:`_whitened` for the error state's own gain, else the Joseph form), injection.

    The measurement: nu = work[W_NU, :m], R = work[W_R:W_R+m, :m] and H, by the form
    cfg["add_form"]: the error state and [ekf7], [ekf10] (ADD_NONE, ADD_ATT) give H =
    work[W_H:W_H+m] on the error-state columns sups[0, :nsup] (the attitude columns 0..2
    always written), mapped here to the quaternion's four columns for the additive form;
    the paper's filters (ADD_COV) give it on the covariance's own columns, H =
    work[W_HQ:W_HQ+m] on sups[1, :nsup]. m is 1, 2 or 3. The additive forms add the
    correction to the quaternion's parameters and normalise (``_normalise_add``).
    Returns whether the update was accepted.

    Every entry of U = H P sums the support's columns in their order: in a register for up to
    TRIANGLE_N states, for more (3 rows) along P's whole rows, which the compiler vectorises.
    The covariance update of up to TRIANGLE_N states is evaluated on one triangle and
    mirrored (Joseph: each entry adds K_ik G_jk + G_ik K_jk, its mirror's sum with the terms
    swapped; whitened: each subtracts the sum of V_ki V_kj, its mirror's the same products:
    what updating both gave, for half the work), of more on whole rows, which the compiler
    vectorises; either way P stays exactly symmetric. Loops run over the n states, not P's
    zero padding."""
    n = cfg["n"]
    H, sup = work[W_H : W_H + 3], sups[0]
    Hm, cols, nc = H, sup, nsup
    if cfg["add_form"] == ADD_ATT:
        Hq = work[W_HQ : W_HQ + 3]
        cols = sups[1]
        q0, q1, q2, q3 = x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3]
        for k in range(m):  # 2 H_att Xi(q)^T
            h0, h1, h2 = 2.0 * H[k, 0], 2.0 * H[k, 1], 2.0 * H[k, 2]
            Hq[k, 0] = -h0 * q1 - h1 * q2 - h2 * q3
            Hq[k, 1] = h0 * q0 - h1 * q3 + h2 * q2
            Hq[k, 2] = h0 * q3 + h1 * q0 - h2 * q1
            Hq[k, 3] = -h0 * q2 + h1 * q1 + h2 * q0
        for c in range(4):
            cols[c] = c
        nc = 4
        for ci in range(nsup):
            c = sup[ci]
            if c >= 3:
                cols[nc] = c + 1
                nc += 1
                for k in range(m):
                    Hq[k, c + 1] = H[k, c]
        Hm = Hq
    elif cfg["add_form"] == ADD_COV:
        Hm, cols = work[W_HQ : W_HQ + 3], sups[1]
    U, Kt, Gt = work[W_U : W_U + 3], work[W_K : W_K + 3], work[W_G : W_G + 3]
    R, S, Si = work[W_R : W_R + 3], work[W_S : W_S + 3], work[W_SI : W_SI + 3]
    nu, dx = work[W_NU], work[W_DX]
    # U = H P (P is exactly symmetric, so U^T = P H^T exactly); either way each entry sums the
    # support's columns in their order from 0: the same numbers
    wide = m == 3 and n > TRIANGLE_N
    if wide:  # along P's rows on the support (whole rows: vectorised; [ins-wind] 9 % faster)
        for j in range(n):
            U[0, j] = U[1, j] = U[2, j] = 0.0
        for ci in range(nc):
            c = cols[ci]
            h0, h1, h2 = Hm[0, c], Hm[1, c], Hm[2, c]
            for j in range(n):
                U[0, j] += h0 * P[c, j]
            for j in range(n):
                U[1, j] += h1 * P[c, j]
            for j in range(n):
                U[2, j] += h2 * P[c, j]
    else:  # each entry summed in a register (a small covariance: [mekf]'s faster so)
        for j in range(n):
            if m == 3:
                u0 = u1 = u2 = 0.0
                for ci in range(nc):
                    c = cols[ci]
                    p = P[c, j]
                    u0 += Hm[0, c] * p
                    u1 += Hm[1, c] * p
                    u2 += Hm[2, c] * p
                U[0, j], U[1, j], U[2, j] = u0, u1, u2
            elif m == 2:
                u0 = u1 = 0.0
                for ci in range(nc):
                    c = cols[ci]
                    p = P[c, j]
                    u0 += Hm[0, c] * p
                    u1 += Hm[1, c] * p
                U[0, j], U[1, j] = u0, u1
            else:
                u0 = 0.0
                for ci in range(nc):
                    c = cols[ci]
                    u0 += Hm[0, c] * P[c, j]
                U[0, j] = u0
    for k in range(m):
        for l in range(m):
            s = 0.0
            for ci in range(nc):
                c = cols[ci]
                s += Hm[k, c] * U[l, c]
            S[k, l] = s + R[k, l]
    if not _gate(cfg, flags, inn, acc, nu, S, Si, sensor, t, m, gate2):
        return False
    tilt_only = cfg["tilt_only"] == 1 and sensor == INN_ACCEL
    keep_bias = cfg["gated_start"] == 1 and sensor == INN_ACCEL and t - x[X_TINIT] < x[X_KEEPBG]
    if cfg["add_form"] == ADD_NONE and not (tilt_only or keep_bias) and _whitened(P, U, Kt, nu, dx, S, m, n):
        pass  # the Kalman gain's own update, on the whitened rows
    # Any other gain (K^T = S^-1 H P, then changed): the Joseph form expanded,
    # P - K U^T - U K^T + K S K^T = P + K G^T + G K^T with G = K S / 2 - U^T.
    elif m == 3:
        i00, i01, i02, i10, i11, i12 = Si[0, 0], Si[0, 1], Si[0, 2], Si[1, 0], Si[1, 1], Si[1, 2]
        i20, i21, i22 = Si[2, 0], Si[2, 1], Si[2, 2]
        s00, s01, s02, s10, s11, s12 = S[0, 0], S[0, 1], S[0, 2], S[1, 0], S[1, 1], S[1, 2]
        s20, s21, s22 = S[2, 0], S[2, 1], S[2, 2]
        n0, n1, n2 = nu[0], nu[1], nu[2]
        for j in range(n):
            u0, u1, u2 = U[0, j], U[1, j], U[2, j]
            k0 = i00 * u0 + i01 * u1 + i02 * u2
            k1 = i10 * u0 + i11 * u1 + i12 * u2
            k2 = i20 * u0 + i21 * u1 + i22 * u2
            Kt[0, j], Kt[1, j], Kt[2, j] = k0, k1, k2
            dx[j] = k0 * n0 + k1 * n1 + k2 * n2  # K nu
            Gt[0, j] = 0.5 * (s00 * k0 + s10 * k1 + s20 * k2) - u0
            Gt[1, j] = 0.5 * (s01 * k0 + s11 * k1 + s21 * k2) - u1
            Gt[2, j] = 0.5 * (s02 * k0 + s12 * k1 + s22 * k2) - u2
        if tilt_only:
            _tilt_only(x, Kt, Gt, dx, S, U, nu)
        if keep_bias:  # a start off the gravity gate: the gyro bias kept (aid.gravity.gate_start)
            _keep_bias(cfg, Kt, Gt, dx, U)
        for i in range(n):
            a0, b0, a1, b1, a2, b2 = Kt[0, i], Gt[0, i], Kt[1, i], Gt[1, i], Kt[2, i], Gt[2, i]
            if n <= TRIANGLE_N:
                for j in range(i, n):
                    P[i, j] = P[j, i] = _joseph3(P, Kt, Gt, i, j, a0, b0, a1, b1, a2, b2)
            else:
                for j in range(n):
                    P[i, j] = _joseph3(P, Kt, Gt, i, j, a0, b0, a1, b1, a2, b2)
    elif m == 2:
        i00, i01, i10, i11 = Si[0, 0], Si[0, 1], Si[1, 0], Si[1, 1]
        s00, s01, s10, s11 = S[0, 0], S[0, 1], S[1, 0], S[1, 1]
        n0, n1 = nu[0], nu[1]
        for j in range(n):
            u0, u1 = U[0, j], U[1, j]
            k0 = i00 * u0 + i01 * u1
            k1 = i10 * u0 + i11 * u1
            Kt[0, j], Kt[1, j] = k0, k1
            dx[j] = k0 * n0 + k1 * n1
            Gt[0, j] = 0.5 * (s00 * k0 + s10 * k1) - u0
            Gt[1, j] = 0.5 * (s01 * k0 + s11 * k1) - u1
        for i in range(n):
            a0, b0, a1, b1 = Kt[0, i], Gt[0, i], Kt[1, i], Gt[1, i]
            if n <= TRIANGLE_N:
                for j in range(i, n):
                    P[i, j] = P[j, i] = _joseph2(P, Kt, Gt, i, j, a0, b0, a1, b1)
            else:
                for j in range(n):
                    P[i, j] = _joseph2(P, Kt, Gt, i, j, a0, b0, a1, b1)
    else:
        i00, s00, n0 = Si[0, 0], S[0, 0], nu[0]
        for j in range(n):
            k0 = i00 * U[0, j]
            Kt[0, j] = k0
            dx[j] = k0 * n0
            Gt[0, j] = 0.5 * (s00 * k0) - U[0, j]
        for i in range(n):
            a0, b0 = Kt[0, i], Gt[0, i]
            if n <= TRIANGLE_N:
                for j in range(i, n):
                    P[i, j] = P[j, i] = P[i, j] + (a0 * Gt[0, j] + b0 * Kt[0, j])
            else:
                for j in range(n):
                    P[i, j] = P[i, j] + (a0 * Gt[0, j] + b0 * Kt[0, j])
    ib, iv, iw, iba = cfg["i_bg"], cfg["i_v"], cfg["i_w"], cfg["i_ba"]
    if cfg["add_form"] != ADD_NONE:
        if ib >= 0:
            if flags[S_FBAR] == 1:
                _rebias_mean(x, X_FBAR, X_JLAG, dx[ib + 1], dx[ib + 2], dx[ib + 3])
            if flags[S_MBAR] == 1:
                _rebias_mean(x, X_MBAR, X_JMAG, dx[ib + 1], dx[ib + 2], dx[ib + 3])
            for a in range(3):
                x[X_BG + a] += dx[ib + 1 + a]
        if iw >= 0:
            for a in range(3):
                x[X_W + a] += dx[iw + 1 + a]
        _normalise_add(
            cfg, x, P, work, x[X_Q] + dx[0], x[X_Q + 1] + dx[1], x[X_Q + 2] + dx[2], x[X_Q + 3] + dx[3]
        )
    else:
        e = _qexp(dx[0], dx[1], dx[2])
        q = _qmul(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3], e[0], e[1], e[2], e[3])
        x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = _qnormalize(q[0], q[1], q[2], q[3])
        if flags[S_FBAR] == 1:
            _rebias_mean(x, X_FBAR, X_JLAG, dx[ib], dx[ib + 1], dx[ib + 2])
        if flags[S_MBAR] == 1:
            _rebias_mean(x, X_MBAR, X_JMAG, dx[ib], dx[ib + 1], dx[ib + 2])
        for a in range(3):
            x[X_BG + a] += dx[ib + a]
            if iv >= 0:
                x[X_V + a] += dx[iv + a]
            if iw >= 0:
                x[X_W + a] += dx[iw + a]
            if iba >= 0:
                x[X_BA + a] += dx[iba + a]
            if cfg["i_bm"] >= 0:
                x[X_BM + a] += dx[cfg["i_bm"] + a]
    return True


@njit(inline="always", **_JIT_CORE)
def _whitened(P, U, V, nu, dx, S, m, n):
    """The update with the Kalman gain itself, ``P - U^T S^-1 U = P - V^T V`` with the
    whitened rows ``V = L^-1 U`` (S = L L^T, Cholesky; V in the gain's scratch rows) and the
    correction ``dx = K nu = V^T L^-1 nu``: three products per entry of P where the Joseph
    form's expansion takes six, and exactly symmetric as it is (entry (i, j) sums
    V_ki V_kj, entry (j, i) the same products in the same order). Algebraically the Joseph
    form's value for this gain. Returns False, P untouched, when a pivot of S is not
    positive (a covariance gone wrong: the caller's Joseph form then)."""
    d0 = S[0, 0]
    if not d0 > 0.0:
        return False
    l00 = math.sqrt(d0)
    r0 = 1.0 / l00
    z0 = nu[0] * r0
    if m == 1:
        for j in range(n):
            v0 = U[0, j] * r0
            V[0, j] = v0
            dx[j] = v0 * z0
        for i in range(n):
            a0 = V[0, i]
            if n <= TRIANGLE_N:
                for j in range(i, n):
                    P[i, j] = P[j, i] = P[i, j] - a0 * V[0, j]
            else:
                for j in range(n):
                    P[i, j] = P[i, j] - a0 * V[0, j]
        return True
    l10 = S[1, 0] * r0
    d1 = S[1, 1] - l10 * l10
    if not d1 > 0.0:
        return False
    r1 = 1.0 / math.sqrt(d1)
    z1 = (nu[1] - l10 * z0) * r1
    if m == 2:
        for j in range(n):
            v0 = U[0, j] * r0
            v1 = (U[1, j] - l10 * v0) * r1
            V[0, j], V[1, j] = v0, v1
            dx[j] = v0 * z0 + v1 * z1
        for i in range(n):
            a0, a1 = V[0, i], V[1, i]
            if n <= TRIANGLE_N:
                for j in range(i, n):
                    P[i, j] = P[j, i] = P[i, j] - (a0 * V[0, j] + a1 * V[1, j])
            else:
                for j in range(n):
                    P[i, j] = P[i, j] - (a0 * V[0, j] + a1 * V[1, j])
        return True
    l20 = S[2, 0] * r0
    l21 = (S[2, 1] - l20 * l10) * r1
    d2 = S[2, 2] - l20 * l20 - l21 * l21
    if not d2 > 0.0:
        return False
    r2 = 1.0 / math.sqrt(d2)
    z2 = (nu[2] - l20 * z0 - l21 * z1) * r2
    for j in range(n):
        v0 = U[0, j] * r0
        v1 = (U[1, j] - l10 * v0) * r1
        v2 = (U[2, j] - l20 * v0 - l21 * v1) * r2
        V[0, j], V[1, j], V[2, j] = v0, v1, v2
        dx[j] = v0 * z0 + v1 * z1 + v2 * z2
    for i in range(n):
        a0, a1, a2 = V[0, i], V[1, i], V[2, i]
        if n <= TRIANGLE_N:
            for j in range(i, n):
                P[i, j] = P[j, i] = P[i, j] - ((a0 * V[0, j] + a1 * V[1, j]) + a2 * V[2, j])
        else:
            for j in range(n):
                P[i, j] = P[i, j] - ((a0 * V[0, j] + a1 * V[1, j]) + a2 * V[2, j])
    return True


@njit(inline="always", **_JIT_CORE)
def _joseph3(P, Kt, Gt, i, j, a0, b0, a1, b1, a2, b2):
    """Entry (i, j) of P + K G^T + G K^T for 3 rows (a_k = K_ik, b_k = G_ik): it adds
    K_ik G_jk + G_ik K_jk, its mirror's sum with the terms swapped, so both are equal."""
    return ((P[i, j] + (a0 * Gt[0, j] + b0 * Kt[0, j])) + (a1 * Gt[1, j] + b1 * Kt[1, j])) + (
        a2 * Gt[2, j] + b2 * Kt[2, j]
    )


@njit(inline="always", **_JIT_CORE)
def _joseph2(P, Kt, Gt, i, j, a0, b0, a1, b1):
    """:func:`_joseph3` for 2 rows."""
    return (P[i, j] + (a0 * Gt[0, j] + b0 * Kt[0, j])) + (a1 * Gt[1, j] + b1 * Kt[1, j])


@njit(inline="always", **_JIT_CORE)
def _rebias_mean(x, im, ij, d0, d1, d2):
    """A low-passed vector x[im:im+3] (the gravity or magnetometer aid's mean) after a gyro-bias
    correction d: its samples were carried into the body frame by the rate less the old bias,
    which turned each by d times its age, so the mean moves by -mean x (J d), J =
    x[ij:ij+9] = d mean / d b_g (row-major), as if carried by the new bias all along. Without
    lowpass_bias J stays zero: no change."""
    v0 = x[ij] * d0 + x[ij + 1] * d1 + x[ij + 2] * d2
    v1 = x[ij + 3] * d0 + x[ij + 4] * d1 + x[ij + 5] * d2
    v2 = x[ij + 6] * d0 + x[ij + 7] * d1 + x[ij + 8] * d2
    m0, m1, m2 = x[im], x[im + 1], x[im + 2]
    x[im] = m0 - (m1 * v2 - m2 * v1)
    x[im + 1] = m1 - (m2 * v0 - m0 * v2)
    x[im + 2] = m2 - (m0 * v1 - m1 * v0)


@njit(inline="always", **_JIT_CORE)
def lag_age(x, ij, a):
    """A low-passed vector's bias sensitivity J = x[ij:ij+9] after it took a fresh sample
    with gain a: the new sample carries no rotation error yet, so J shrinks by 1 - a."""
    for i in range(9):
        x[ij + i] *= 1.0 - a


#: A low-passed mean is fused below its rate (accel_fuse_rate, mag_fuse_rate) only while its
#: gain is small: the prior variance of what it measures at most this fraction of a sample's
#: noise variance. There k samples fused as one with R / k update the state as the k did (the
#: information adds; the state hardly moves between them); at a start or after a reset, whose
#: gains are large, every sample is fused.
DECIMATE_PRIOR_SHARE = 0.1


@njit(inline="always", **_JIT_CORE)
def samples_to_fuse(x, i_n, i_t, t, fuse_dt, half_step, prior_var, noise_var):
    """How many samples of a low-passed mean the measurement at t s stands for (the samples
    since its last fusion, this one included; 1 when every sample is fused), or 0 when it is
    not fused now. A mean changes over its time constant (seconds), so fusing it at every
    sample repeats it: it is fused once per fuse_dt s (0: every sample), with R / k for the k
    samples it stands for (the information per second kept), while prior_var <=
    DECIMATE_PRIOR_SHARE noise_var. x[i_n]: samples since the last fusion, x[i_t]: its time;
    half_step: half the stream's sample interval, s (a fusion falls due within it)."""
    n = x[i_n] + 1.0
    if fuse_dt > 0.0 and t - x[i_t] < fuse_dt - half_step and prior_var <= DECIMATE_PRIOR_SHARE * noise_var:
        x[i_n] = n
        return 0.0
    x[i_n] = 0.0
    x[i_t] = t
    return n


@njit(inline="always", **_JIT_CORE)
def att_var_along(P, u0, u1, u2):
    """u^T P_att u: the error state's attitude variance about the body axis u (unit), rad^2."""
    return (u0 * (P[0, 0] * u0 + P[0, 1] * u1 + P[0, 2] * u2) + u1 * (P[1, 0] * u0 + P[1, 1] * u1 + P[1, 2] * u2)
            + u2 * (P[2, 0] * u0 + P[2, 1] * u1 + P[2, 2] * u2))


@njit(inline="always", **_JIT_CORE)
def per_sample_nis(cfg, flags, inn, sensor, kf):
    """The NIS just logged for ``sensor`` (by a fusion that stood for kf samples, with R /
    kf: about kf times a sample's) divided by kf: the log keeps a sample's NIS."""
    if kf > 1.0:
        inn[cfg["log_off"][sensor] + flags[L_CNT + sensor] - 1, 4] /= kf


@njit(inline="always", **_JIT_CORE)
def lag_bias_rows(work, sup, x, ij, ib, m, nsup):
    """The gyro-bias columns of a measurement made of a low-passed vector whose rotation
    error is J db (J = x[ij:ij+9], row-major): it enters as an attitude error does, so
    H_b = H_att J on the bias columns ib..ib+2 of its m rows, appended to the support sup
    (row) after nsup columns. Returns the new support size."""
    H = work[W_H : W_H + 3]
    for k in range(m):
        r0, r1, r2 = H[k, 0], H[k, 1], H[k, 2]
        for a in range(3):
            H[k, ib + a] = r0 * x[ij + a] + r1 * x[ij + 3 + a] + r2 * x[ij + 6 + a]
    for a in range(3):
        sup[nsup + a] = ib + a
    return nsup + 3


@njit(inline="always", **_JIT_CORE)
def _tilt_only(x, Kt, Gt, dx, S, U, nu):
    """The gravity update's gain without its part about the vertical (3 rows, error state,
    attitude columns 0..2): gravity says nothing of the heading, and without a heading aid
    the covariance's correlations through which the EKF would turn it are built of
    unmodelled accelerations and grow without bound (VQF corrects the inclination only,
    likewise). K_att <- (I - u u^T) K_att with u = C_bn e_3, the vertical in body axes; dx
    and G = K S / 2 - U^T follow the gain (the Joseph form holds for any gain)."""
    c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    u0, u1, u2 = c[6], c[7], c[8]
    for k in range(3):
        s = Kt[k, 0] * u0 + Kt[k, 1] * u1 + Kt[k, 2] * u2
        Kt[k, 0] -= s * u0
        Kt[k, 1] -= s * u1
        Kt[k, 2] -= s * u2
    for j in range(3):
        k0, k1, k2 = Kt[0, j], Kt[1, j], Kt[2, j]
        dx[j] = k0 * nu[0] + k1 * nu[1] + k2 * nu[2]
        for r in range(3):
            Gt[r, j] = 0.5 * (S[0, r] * k0 + S[1, r] * k1 + S[2, r] * k2) - U[r, j]


@njit(inline="always", **_JIT_CORE)
def _keep_bias(cfg, Kt, Gt, dx, U):
    """A 3-row update that leaves the gyro bias as it is (error state, columns
    cfg["i_bg"]..+2): its gain rows set to zero, the bias then a considered state (the
    Schmidt-Kalman filter's update: the attitude's gain and covariance still account for the
    bias's spread and correlations, and the bias's own covariance is unchanged). The Joseph
    form holds for any gain, so G = K S / 2 - U^T follows it: G_b = -U_b."""
    ib = cfg["i_bg"]
    for j in range(ib, ib + 3):
        Kt[0, j], Kt[1, j], Kt[2, j] = 0.0, 0.0, 0.0
        Gt[0, j], Gt[1, j], Gt[2, j] = -U[0, j], -U[1, j], -U[2, j]
        dx[j] = 0.0


@njit(**_JIT_CORE)
def _vector_rows(work, sup, y0, y1, y2, var):
    """A 3-row measurement with H_att = [y]x and R = var I (accelerometer, magnetometer);
    sup: the support row."""
    H, R = work[W_H : W_H + 3], work[W_R : W_R + 3]
    H[0, 0], H[0, 1], H[0, 2] = 0.0, -y2, y1
    H[1, 0], H[1, 1], H[1, 2] = y2, 0.0, -y0
    H[2, 0], H[2, 1], H[2, 2] = -y1, y0, 0.0
    for k in range(3):
        sup[k] = k
        for l in range(3):
            R[k, l] = var if k == l else 0.0


@njit(inline="always", **_JIT_CORE)
def _bias_rows(work, sup, ib, nsup):
    """A 3-row measurement plus a sensor bias state (h += b, H_b = I): the identity on the
    bias columns ib..ib+2 of every row, appended to the support sup (row) after nsup
    columns. Returns the new support size."""
    for k in range(3):
        for a in range(3):
            work[W_H + k, ib + a] = 1.0 if k == a else 0.0
        sup[nsup + k] = ib + k
    return nsup + 3


# --- event steps --------------------------------------------------------------------------
