"""The offline smoothers of the error-state filters on the compiled core ([mekf],
[mekf-air], [ins-wind], [ins-drag], and [auto] when it picks one of them): a two-filter
smoother where the flight allows it, else a Rauch-Tung-Striebel pass.

**Which.** :func:`smooth`'s default ``method="auto"`` runs the two-filter smoother when every
aid source the estimator fuses on the flight has a time-reversed model (gravity, the
magnetometer, GNSS velocity, rest: :func:`reversible`), and the RTS pass otherwise (air data,
which a pitot reads from the nose, and the multirotor drag, which is dissipative).
``Estimate.meta["smoother"]`` says which ran. Why two: the field defaults fuse the
accelerometer and magnetometer as means over the last 3 s and 9 s (VQF's time constants),
errors the RTS pass takes for white noise, so it carries the mean's lag back unchanged
(BROAD, 7 trials, median inclination: forward 0.552 deg, RTS 0.593, two-filter 0.445;
docs/RESULTS.md section 17). A backward pass's means cover the next seconds instead, and the
two lags cancel in the fusion.

**Two-filter** (Fraser and Potter 1969). The filter runs forward, and again on
:func:`reversed_flight` (time reversed: the angular rate and velocities negated). At every
IMU sample the two posteriors are fused as independent estimates by their covariances, on
the error state about the forward one: ``d = x_b [-] x_f``, ``K = P_f (P_f + P_b)^-1``,
``x_s = x_f [+] K d``, ``P_s = P_f - K P_f``. Details, each a physical reason:

- the backward pass starts as the forward did, from its own first samples, when a
  magnetometer gives it a heading; without one nothing would, and it starts from the forward
  pass's last posterior (rates and velocities negated) with the filter's initial spreads;
- with a magnetometer and no site field, each pass takes its heading datum from its own
  first samples and its heading drifts with its own vertical gyro-bias error: the heading
  between the passes, fitted as an offset plus a drift, is turned out of the backward pass;
- where nothing measures the heading (no magnetometer, no GNSS velocity state), the
  smoothed attitude keeps the forward pass's heading (two gyro integrations cannot improve
  on one another's datum) and smooths the tilt;
- a pass is not used over the span one of its own resets says it was lost (from when the
  reset's sensor began to disagree to the reset);
- passes that started on their own and differ by more than :data:`FUSE_LIMIT` (30 deg) are
  not fused (no small error of one another): the forward pass stands there, unless its own
  attitude spread is beyond the limit too;
- before either pass has started the sample keeps the forward run's output and no covariance.

Two records are kept (twice the RTS pass's memory, below); a flight whose two records exceed
:data:`SMOOTH_BUDGET` is smoothed by the RTS pass instead.

**RTS.** Forward: the filter's own event loop (:func:`windahrs.core.kernel.run_events`) with a
smoothing record (``sm``; absent, ``None``, in every other run, so the compiled loop of a
normal run has no smoothing code at all). For every IMU sample k it keeps the posterior at
k (the state after every event before IMU sample k + 1, what ``Estimate`` row k holds): the
nominal state (q, gyro bias, velocity, wind, accelerometer and magnetometer biases) and the
covariance P_post(k); and what the prediction at k used (the sample, the step, the sample
changes of the held-sample noise) with what may break the chain there (below).

Backward (compiled): the prior at k + 1 and the transition are not recorded but recomputed
from the posterior at k by the shipped prediction itself, so the model's maths is written
once and the recomputed prior is the forward's bit for bit:
``P_prior(k+1)`` = :func:`windahrs.core.predict._predict_es` (and
:func:`~windahrs.core.predict.add_held_sample_noise` on a step longer than
``unmeasured_motion_dt``) of P_post(k), ``x_prior(k+1)`` its nominal state, and ``Phi``
the rows of ``Phi P`` that the same prediction leaves in its scratch (``work[W_M]``) when
run on ``P = I`` (Phi is the identity but for the attitude rows and, in the INS, the
velocity rows; with ``P = I`` each entry of ``Phi P`` is one entry of Phi times 1 plus
zeros: exact). Then, with ``[-]`` the error-state difference (attitude: the body-frame
rotation vector ``Log(q_prior^-1 q_s)``, the rest subtraction) and ``[+]`` the filter's
injection (``q Exp(d)``, additions)::

    C_k    = P_post(k) Phi^T P_prior(k+1)^-1          (Cholesky solve, no inverse)
    x_s(k) = x_post(k) [+] C_k (x_s(k+1) [-] x_prior(k+1))
    P_s(k) = P_post(k) + C_k (P_s(k+1) - P_prior(k+1)) C_k^T

An error state with no spread in P_prior (the vertical wind held at zero) gets no
correction (its columns of C are zero).

**Chain breaks.** The smoother's chain is the filter's predictions; where a step is not one,
the backward pass restarts from the forward estimate (``x_s(k) = x_post(k)``,
``P_s(k) = P_post(k)``) and goes on from there: before the initialisation and at the
sample that initialises; a skipped (NaN) IMU sample or a step of zero length; a sample the
IMU screen held (:mod:`windahrs.core.imu_screen`), caught up, dropped or found clipped (it
changes the state or its spread outside the model); and a reset (any row of the ``reset``
log, or the wind restarted from an air sample) among the updates at k + 1, since the
posterior there is then not an update of the prior.

**Memory.** Per IMU sample: the covariance (n x n floats) and 38 floats (the nominal state
and what the prediction used): 592 bytes for [mekf] (6 states), 1 104 for [mekf-air] (9),
2 104 for [ins-wind] (15), 2 896 with a magnetometer bias (18); the smoothed values are
written over them. A flight that needs more than :data:`SMOOTH_BUDGET` (2 GiB, about 85
minutes of 200 Hz [ins-wind]) is refused before anything is allocated.

Innovations, resets, alerts and skipped counts in the smoothed Estimate are the forward
pass's (what the filter saw); the flags and the tilt check are laid on the smoothed attitude.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numba import njit

from windahrs.core.imu_screen import CLIP_SAMPLES
from windahrs.core.layout import (
    _JIT,
    F64,
    INN_IMU,
    INN_RESET,
    L_CNT,
    N_WORK,
    N_X,
    NMAX,
    S_INIT,
    S_WPEND,
    W_M,
    X_BA,
    X_BG,
    X_BM,
    X_DF,
    X_DW,
    X_Q,
    X_TIMU,
    X_V,
    X_W,
)
from windahrs.core.predict import _predict_es, add_held_sample_noise
from windahrs.core.quat import _qexp, _qlog, _qmul, _qnormalize
from windahrs.filters.base import Estimator
from windahrs.rotation import circular_mean, quat_conj, quat_exp, quat_log, quat_mul, twist_angle

if TYPE_CHECKING:
    from collections.abc import Mapping

    from numpy.typing import NDArray

    from windahrs.estimate import Estimate
    from windahrs.filters.base import InitialState, Streamer
    from windahrs.flight import Flight, Site

__all__ = [
    "METHODS", "SMOOTH_BUDGET", "SmoothRecord", "Smoothed", "check_method", "reversed_flight", "reversible", "smooth",
    "smooth_bytes", "smoothed_label", "supports",
]  # fmt: skip

#: The smoothing record a run may take at most, bytes (2 GiB): the covariance and nominal
#: state of every IMU sample (module docstring); a longer flight is refused before any
#: allocation. As :data:`~windahrs.core.layout.COV_BUDGET`, a bound on one run.
SMOOTH_BUDGET = 2 << 30

# nominal state columns of the record
N_Q, N_BG, N_V, N_W, N_BA, N_BM = 0, 4, 7, 10, 13, 16
N_NOM = 19
# what the prediction at k used, and what may break the chain there
A_DT = 0  # the step, s (t - the previous IMU sample's)
A_ROW = 1  # (6,) the sample: w_b, f_b
A_PRE = 7  # 1: finite, initialised before it, no held sample pending (else 0)
A_INIT = 8  # initialised at the posterior
A_NRES = 9  # reset log rows so far
A_NIMU = 10  # IMU screen log rows so far (a held sample)
A_WPEND = 11  # the wind awaits its restart from an air sample
A_CLIP = 12  # the screen found an axis clipped (added spread)
A_DW = 13  # (3,) the sample changes of the held-sample noise: angular rate
A_DF = 16  # (3,) specific force
N_AUX = 19
#: Bytes recorded per IMU sample besides the n x n covariance.
FIXED_BYTES = 8 * (N_NOM + N_AUX)


class SmoothRecord(NamedTuple):
    """The forward pass's smoothing record (the ``sm`` of
    :func:`windahrs.core.kernel.run_events`): nom (N, 19) the posterior nominal state
    (N_* columns), P (N, n, n) the posterior covariance, aux (N, 19) the prediction's
    inputs and the chain's breaks (A_* columns). The backward pass writes the smoothed
    state and covariance over nom and P."""

    nom: F64
    P: F64
    aux: F64


def no_smoothing() -> SmoothRecord:
    """The record of a run that is not smoothed: no rows. run_events takes it rather than
    None so that numba compiles one loop for every caller (with None the smoother's run
    was a second specialisation of the whole filter: 30-50 s more on a cold cache)."""
    return SmoothRecord(np.empty((0, N_NOM)), np.empty((0, 0, 0)), np.empty((0, N_AUX)))


@njit(**_JIT)
def record_pre(sm, k, x, flags, sc, t, row, ok):
    """At IMU sample k (t s, row = [w_b, f_b]; ok: finite), before its step: what the
    prediction will use and whether the step can be one of the chain's (sc: the IMU
    screen's record, core.imu_screen.SCREEN)."""
    aux = sm[2]
    aux[k, A_DT] = t - x[X_TIMU]
    for a in range(6):
        aux[k, A_ROW + a] = row[a]
    aux[k, A_PRE] = 1.0 if (ok and flags[S_INIT] == 1 and sc["held"] == 0) else 0.0


@njit(**_JIT)
def record_post(sm, k, cfg, x, flags, sc, P):
    """The posterior at IMU sample k (after every event before the next IMU sample)."""
    nom, Pr, aux = sm
    aux[k, A_INIT] = float(flags[S_INIT])
    aux[k, A_NRES] = float(flags[L_CNT + INN_RESET])
    aux[k, A_NIMU] = float(flags[L_CNT + INN_IMU])
    aux[k, A_WPEND] = float(flags[S_WPEND])
    clip = 0.0
    for a in range(6):
        if sc["clip"][a] >= CLIP_SAMPLES - 1:
            clip = 1.0
    aux[k, A_CLIP] = clip
    for a in range(3):
        aux[k, A_DW + a] = x[X_DW + a]
        aux[k, A_DF + a] = x[X_DF + a]
    for a in range(4):
        nom[k, N_Q + a] = x[X_Q + a]
    for a in range(3):
        nom[k, N_BG + a] = x[X_BG + a]
        nom[k, N_V + a] = x[X_V + a]
        nom[k, N_W + a] = x[X_W + a]
        nom[k, N_BA + a] = x[X_BA + a]
        nom[k, N_BM + a] = x[X_BM + a]
    n = Pr.shape[1]
    for i in range(n):
        for j in range(n):
            Pr[k, i, j] = P[i, j]


@njit(**_JIT)
def _linked(aux, k, j):
    """Whether posterior k and posterior j = k + 1 are joined by one prediction and an
    update (module docstring: chain breaks)."""
    return (
        aux[j, A_PRE] == 1.0
        and aux[j, A_DT] > 0.0
        and aux[k, A_INIT] == 1.0
        and aux[j, A_INIT] == 1.0
        and aux[j, A_NRES] == aux[k, A_NRES]
        and aux[j, A_NIMU] == aux[k, A_NIMU]
        and aux[j, A_WPEND] == aux[k, A_WPEND]
        and aux[j, A_CLIP] == 0.0
    )


@njit(**_JIT)
def _load(x, nom, k, aux, j):
    """The nominal state of posterior k into the kernel slots of x, with the sample
    changes of step j (the held-sample noise)."""
    for a in range(4):
        x[X_Q + a] = nom[k, N_Q + a]
    for a in range(3):
        x[X_BG + a] = nom[k, N_BG + a]
        x[X_V + a] = nom[k, N_V + a]
        x[X_W + a] = nom[k, N_W + a]
        x[X_BA + a] = nom[k, N_BA + a]
        x[X_BM + a] = nom[k, N_BM + a]
        x[X_DW + a] = aux[j, A_DW + a]
        x[X_DF + a] = aux[j, A_DF + a]


@njit(**_JIT)
def _cholesky(A, L, n):
    """L L^T = A (n x n, lower L); a zero diagonal entry of A (a state without spread) gets
    L's unit column (its row and column of A are zero). False when A is not positive
    definite on the rest."""
    for c in range(n):
        for r in range(n):
            L[r, c] = 0.0
    for c in range(n):
        if A[c, c] <= 0.0:
            L[c, c] = 1.0
            continue
        s = A[c, c]
        for m in range(c):
            s -= L[c, m] * L[c, m]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        L[c, c] = d
        for r in range(c + 1, n):
            if A[r, r] <= 0.0:
                continue
            v = A[r, c]
            for m in range(c):
                v -= L[r, m] * L[c, m]
            L[r, c] = v / d
    return True


@njit(**_JIT)
def _solve_into(L, B, n):
    """B <- (L L^T)^-1 B in place (n x n right-hand sides)."""
    for col in range(n):
        for r in range(n):
            v = B[r, col]
            for m in range(r):
                v -= L[r, m] * B[m, col]
            B[r, col] = v / L[r, r]
        for r in range(n - 1, -1, -1):
            v = B[r, col]
            for m in range(r + 1, n):
                v -= L[m, r] * B[m, col]
            B[r, col] = v / L[r, r]


@njit(**_JIT)
def backward(cfg, prm, nom, Pr, aux, n_pad):
    """The backward pass (module docstring) over the forward record, in place: nom and Pr
    become the smoothed nominal state and covariance. Returns (N,) bool: whether sample k
    was smoothed from k + 1 (False: the forward estimate, a chain break)."""
    N, n = nom.shape[0], Pr.shape[1]
    ib, iv, iw, iba, ibm = cfg["i_bg"], cfg["i_v"], cfg["i_w"], cfg["i_ba"], cfg["i_bm"]
    na = 6 if iv >= 0 else 3  # the rows of Phi that are not the identity's
    work = np.zeros((N_WORK, max(n_pad, NMAX)))
    xa, xb = np.zeros(N_X), np.zeros(N_X)
    Pa, Pi = np.zeros((n_pad, n_pad)), np.zeros((n_pad, n_pad))
    Phi, B, L = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
    D, E = np.zeros((n, n)), np.zeros((n, n))
    dx, de = np.zeros(n), np.zeros(n)
    linked = np.zeros(N, dtype=np.bool_)
    for k in range(N - 2, -1, -1):
        j = k + 1
        if not _linked(aux, k, j):
            continue
        dt = aux[j, A_DT]
        w0, w1, w2 = aux[j, A_ROW], aux[j, A_ROW + 1], aux[j, A_ROW + 2]
        f0, f1, f2 = aux[j, A_ROW + 3], aux[j, A_ROW + 4], aux[j, A_ROW + 5]
        # the prior at j: the shipped prediction of posterior k
        _load(xa, nom, k, aux, j)
        for r in range(n_pad):
            for c in range(n_pad):
                Pa[r, c] = Pr[k, r, c] if (r < n and c < n) else 0.0
                Pi[r, c] = 1.0 if (r == c and r < n) else 0.0
        _predict_es(cfg, prm, xa, Pa, work, w0, w1, w2, f0, f1, f2, dt)
        if dt > prm["unmeasured_motion_dt"]:
            add_held_sample_noise(cfg, prm, xa, Pa, work, dt)
        # Phi: the rows of Phi P the same prediction leaves in work[W_M] for P = I
        _load(xb, nom, k, aux, j)
        _predict_es(cfg, prm, xb, Pi, work, w0, w1, w2, f0, f1, f2, dt)
        for r in range(n):
            for c in range(n):
                Phi[r, c] = work[W_M + r, c] if r < na else (1.0 if r == c else 0.0)
        # B = Phi P_post(k); C^T = P_prior^-1 B
        for r in range(n):
            for c in range(n):
                v = 0.0
                for m in range(n):
                    v += Phi[r, m] * Pr[k, m, c]
                B[r, c] = v if Pa[r, r] > 0.0 else 0.0
        if not _cholesky(Pa, L, n):
            continue
        _solve_into(L, B, n)  # B = C^T
        # x_s(j) [-] x_prior(j)
        p0, p1, p2, p3 = xa[X_Q], -xa[X_Q + 1], -xa[X_Q + 2], -xa[X_Q + 3]
        dq = _qmul(p0, p1, p2, p3, nom[j, N_Q], nom[j, N_Q + 1], nom[j, N_Q + 2], nom[j, N_Q + 3])
        dx[0], dx[1], dx[2] = _qlog(dq[0], dq[1], dq[2], dq[3])
        for a in range(3):
            dx[ib + a] = nom[j, N_BG + a] - xa[X_BG + a]
            if iv >= 0:
                dx[iv + a] = nom[j, N_V + a] - xa[X_V + a]
            if iw >= 0:
                dx[iw + a] = nom[j, N_W + a] - xa[X_W + a]
            if iba >= 0:
                dx[iba + a] = nom[j, N_BA + a] - xa[X_BA + a]
            if ibm >= 0:
                dx[ibm + a] = nom[j, N_BM + a] - xa[X_BM + a]
        for r in range(n):
            v = 0.0
            for m in range(n):
                v += B[m, r] * dx[m]
            de[r] = v
        # x_s(k) = x_post(k) [+] C dx
        e = _qexp(de[0], de[1], de[2])
        q = _qmul(nom[k, N_Q], nom[k, N_Q + 1], nom[k, N_Q + 2], nom[k, N_Q + 3], e[0], e[1], e[2], e[3])
        nom[k, N_Q], nom[k, N_Q + 1], nom[k, N_Q + 2], nom[k, N_Q + 3] = _qnormalize(q[0], q[1], q[2], q[3])
        for a in range(3):
            nom[k, N_BG + a] += de[ib + a]
            if iv >= 0:
                nom[k, N_V + a] += de[iv + a]
            if iw >= 0:
                nom[k, N_W + a] += de[iw + a]
            if iba >= 0:
                nom[k, N_BA + a] += de[iba + a]
            if ibm >= 0:
                nom[k, N_BM + a] += de[ibm + a]
        # P_s(k) = P_post(k) + C (P_s(j) - P_prior(j)) C^T, C^T = B
        for r in range(n):
            for c in range(n):
                D[r, c] = Pr[j, r, c] - Pa[r, c]
        for r in range(n):  # E = D B
            for c in range(n):
                v = 0.0
                for m in range(n):
                    v += D[r, m] * B[m, c]
                E[r, c] = v
        for r in range(n):  # B^T E, symmetric
            for c in range(r, n):
                v = 0.0
                for m in range(n):
                    v += B[m, r] * E[m, c]
                s = 0.5 * (Pr[k, r, c] + Pr[k, c, r]) + v
                Pr[k, r, c] = s
                Pr[k, c, r] = s
        linked[k] = True
    return linked


# --- Python side --------------------------------------------------------------------------


def supports(est: Estimator) -> str | None:
    """None when the smoother can smooth ``est``, else why not (a sentence naming it)."""
    from windahrs.core.kernel import CompiledEstimator
    from windahrs.filters.auto import Auto

    if isinstance(est, Smoothed):
        return f"estimator {est.label!r} is already smoothed"
    if isinstance(est, Auto):
        return None
    if isinstance(est, CompiledEstimator) and not est.additive:
        return None
    if isinstance(est, CompiledEstimator):
        why = "a quaternion-additive EKF (the smoother works on the error state)"
    elif est.name == "usque":
        why = "an unscented filter (no transition matrix to smooth with)"
    elif est.name in ("paper", "paper-nowind", "ekf", "ukf"):
        why = "one of the paper's additive filters (its own event loop)"
    else:
        why = "not a windahrs filter on the compiled error-state core"
    return (f"smoothing: estimator {est.label!r} cannot be smoothed: {why}; the smoother takes "
            "mekf, mekf-air, ins-wind, ins-drag and auto")  # fmt: skip


def smooth_bytes(n_samples: int, dim: int) -> int:
    """Bytes the smoothing record of a flight of n_samples IMU samples takes for a
    dim-state filter."""
    return int(n_samples) * (8 * dim * dim + FIXED_BYTES)


def smoothed_label(label: str) -> str:
    """How a smoothed run of ``label`` is named: ``NAME-smooth``, or ``SPEC:smooth=true``."""
    return f"{label}:smooth=true" if ":" in label else f"{label}-smooth"


def smooth(
    est: Estimator,
    flight: Flight,
    *,
    initial: InitialState | None = None,
    label: str | None = None,
    method: str = "auto",
) -> Estimate:
    """The smoothed Estimate of ``flight`` by ``est`` (the module docstring): attitude, gyro
    bias, velocity, wind and covariance at every IMU sample from the whole flight, the
    forward pass's innovations and resets. ``Estimate.filter`` is ``label`` (default
    :func:`smoothed_label` of the estimator's). ``method``: ``"two-filter"``, ``"rts"``, or
    ``"auto"`` (the default: two-filter where :func:`reversible` allows it, else RTS); the
    Estimate's ``meta["smoother"]`` says which ran. ValueError naming the estimator when it
    cannot be smoothed (or not by the method asked), or when the record would exceed
    :data:`SMOOTH_BUDGET`."""
    from windahrs.filters.auto import Auto

    check_method(method)
    why = supports(est)
    if why is not None:
        raise ValueError(why)
    name = label if label is not None else smoothed_label(est.label)
    if isinstance(est, Auto):
        out: Estimate = est.run(flight, initial=initial, smooth=True)
        return dataclasses.replace(out, filter=name)
    not_reversible = reversible(est, flight)
    if method == "two-filter" and not_reversible is not None:
        raise ValueError(f"smoothing {est.label!r} by two filters: {not_reversible}")
    if method == "rts" or not_reversible is not None:
        return _smooth_compiled(est, flight, initial, name)
    return _smooth_two_filter(est, flight, initial, name)


#: The largest attitude difference, rad, between the two passes that the two-filter
#: smoother fuses when each pass started on its own (30 deg: where the error state's
#: small-angle model, sin x ~ x, is off by 5 %); beyond it the forward pass's estimate stands.
FUSE_LIMIT = math.radians(30.0)
#: The smoothing methods :func:`smooth` takes.
METHODS = ("auto", "two-filter", "rts")


def check_method(method: object, field: str = "smoothing: method") -> None:
    """ValueError naming ``field`` unless ``method`` is one of :data:`METHODS` (the one check
    of :func:`smooth`, :class:`Smoothed` and a spec's ``smoother=``)."""
    if method not in METHODS:
        raise ValueError(f"{field}: expected one of {', '.join(METHODS)}, found {method!r}")


def reversible(est: Any, flight: Flight) -> str | None:
    """None when every aid source ``est`` fuses on ``flight`` has a time-reversed model
    (gravity, magnetometer, GNSS velocity, rest), else why not: air data (a pitot reads the
    flow from the nose; reversed, the vehicle would fly tail first) and multirotor drag
    (dissipative: reversed, the drag would push)."""
    from windahrs.core.kernel import layout_for

    L = layout_for(est.kind, est.params, additive=est.additive)
    air = L.has("wind") or est.params.accel_compensation == "airspeed"
    if air and "air" in est.uses and flight.air is not None:
        return "the flight's air data has no time-reversed model (a pitot reads the flow from the nose)"
    if est.params.drag:
        return "the multirotor drag has no time-reversed model (it is dissipative)"
    return None


def reversed_flight(flight: Flight) -> Flight:
    """``flight`` run backwards in time, as the two-filter smoother's second pass sees it:
    time t -> t_0 + t_end - t, every stream's rows reversed; the angular rate negated and
    moved one row (w_b[k] is the mean over (t[k-1], t[k]], so the reversed row j, ending at
    the original t[k], takes the original interval that starts there, -w_b[k+1]); the GNSS
    velocity negated; the specific force and the magnetic field unchanged. No air data,
    truth, reference or repairs (the smoother's backward pass uses none of them)."""
    from windahrs.flight import GnssStream, ImuStream, MagStream

    t0, t1 = float(flight.imu.t[0]), float(flight.imu.t[-1])
    w = -flight.imu.w_b[::-1]
    imu = ImuStream(t0 + t1 - flight.imu.t[::-1], np.vstack([w[:1], w[:-1]]), flight.imu.f_b[::-1].copy())
    mag = gnss = None
    if flight.mag is not None:
        mag = MagStream(t0 + t1 - flight.mag.t[::-1], flight.mag.mag_b[::-1].copy())
    if flight.gnss is not None:
        g = flight.gnss
        gnss = GnssStream(t0 + t1 - g.t[::-1], -g.v_n[::-1], None if g.v_sigma is None else g.v_sigma[::-1].copy())
    return dataclasses.replace(
        flight, imu=imu, mag=mag, gnss=gnss, air=None, truth=None, reference=None, ref_wind=None,
        repairs={}, repair_times={},
    )  # fmt: skip


def _continued(run: Any, fw: SmoothRecord) -> InitialState | None:
    """Where the backward pass starts: the forward pass's last posterior, turned to run
    backwards (rates and velocities negated), with the filter's initial spreads, so that both
    passes linearise about the same attitude and heading datum; None (the filter's own start)
    when the forward pass never started."""
    from windahrs.filters.base import InitialState

    last = np.flatnonzero(fw.aux[:, A_INIT] == 1.0)
    if len(last) == 0:
        return None
    x = fw.nom[last[-1]]
    has_v, has_w = run.v.shape[0] > 0, run.w.shape[0] > 0
    return InitialState(
        q_nb=x[N_Q : N_Q + 4].copy(),
        gyro_bias_b=-x[N_BG : N_BG + 3],
        v_n=-x[N_V : N_V + 3] if has_v else None,
        wind_n=-x[N_W : N_W + 3] if has_w else None,
    )


def _lost(t: F64, resets: dict[str, F64]) -> NDArray[np.bool_]:
    """(N,) whether IMU time t (s, in the pass's own time, any order) lies in the span a
    reset of the pass says it was lost: from when the sensor began to disagree to the reset
    (a negative time out: the start check's, the span of the plain mean it found off; NaN: a
    heading taken from a sample, no span)."""
    lost = np.zeros(len(t), dtype=np.bool_)
    for rows in resets.values():
        for t_reset, _, out in rows:
            lost |= (t >= t_reset - abs(out)) & (t < t_reset)
    return lost


def _smooth_two_filter(est: Any, flight: Flight, initial: InitialState | None, name: str) -> Estimate:
    """The two-filter smoother (Fraser and Potter 1969): the filter run forward and on
    :func:`reversed_flight`, the two posteriors at each IMU sample fused by their
    covariances (module docstring)."""
    from windahrs.core.kernel import _resets, layout_for

    N = len(flight.imu.t)
    dim = layout_for(est.kind, est.params, additive=est.additive).dim
    if 2 * smooth_bytes(N, dim) > SMOOTH_BUDGET:  # two records; the RTS pass needs one
        return _smooth_compiled(est, flight, initial, name)

    run, fw = forward_record(est, flight, initial)
    # with a magnetometer the backward pass starts as the forward did, from its own first
    # samples; without, nothing would give it a heading, so it starts where the forward ended
    mag = "mag" in est.uses and flight.mag is not None
    run_b, bw = forward_record(est, reversed_flight(flight), None if mag else _continued(run, fw))
    L = run.layout
    t = flight.imu.t
    # a pass is not used where a reset of its own says it was lost: over the time its sensor
    # had disagreed before the reset (for the backward pass, after it in the flight's time)
    lost_f = _lost(t, _resets(run.st))
    lost_b = _lost((t[0] + t[-1]) - t, _resets(run_b.st))
    ok_b = (bw.aux[::-1, A_INIT] == 1.0) & ~lost_b
    ok_f = (fw.aux[:, A_INIT] == 1.0) & ~(lost_f & ok_b)
    nom_b, P_b = bw.nom[::-1], bw.P[::-1]
    # the backward pass's nominal state and covariance in the forward's terms: rates and
    # velocities change sign, and a heading datum of its own is turned onto the forward's
    q_b = nom_b[:, N_Q : N_Q + 4]
    both = ok_f & ok_b
    if mag and flight.site.mag_n is None and both.sum() > 1:
        # each pass took its heading datum from its own first magnetometer samples, and its
        # heading drifts with its own vertical gyro bias error: the heading between them,
        # fitted as an offset plus a drift, is turned out of the backward pass
        psi = twist_angle(quat_mul(q_b[both], quat_conj(fw.nom[both, N_Q : N_Q + 4])))
        off = circular_mean(psi)
        tm = float(np.mean(t[both]))
        drift, off2 = np.polyfit(t[both] - tm, np.angle(np.exp(1j * (psi - off))), 1)
        turn = off + off2 + drift * (t - tm)
        q_b = quat_mul(quat_exp(np.outer(-turn, [0.0, 0.0, 1.0])), q_b)
    T = np.zeros((dim, dim))
    x_b = np.zeros((N, dim))
    cols = {"bg": N_BG, "v": N_V, "wind": N_W, "ba": N_BA, "bm": N_BM}
    for block in L.blocks:
        sl = L.sl(block)
        if block == "att":
            T[sl, sl] = np.eye(3)
            continue
        A = -np.eye(3) if block in ("bg", "v", "wind") else np.eye(3)
        T[sl, sl] = A
        x_b[:, sl] = nom_b[:, cols[block] : cols[block] + 3] @ A.T
    P_b = T @ P_b @ T.T
    # fused where both passes have started; the one that has elsewhere
    nom, P = fw.nom, fw.P
    d = np.zeros((N, dim))
    d[:, :3] = quat_log(quat_mul(quat_conj(nom[:, N_Q : N_Q + 4]), q_b))
    for block in L.blocks[1:]:
        sl = L.sl(block)
        d[:, sl] = x_b[:, sl] - nom[:, cols[block] : cols[block] + 3]
    # passes that started apart (with a magnetometer) and differ beyond FUSE_LIMIT are no
    # small error of one another: the forward pass stands, unless its own attitude spread is
    # beyond the limit too
    apart = both & (np.linalg.norm(d[:, :3], axis=1) > FUSE_LIMIT) & mag
    unsure_f = np.trace(P[:, :3, :3], axis1=1, axis2=2) > FUSE_LIMIT**2
    both &= ~apart
    ok_b &= ~(apart & ~unsure_f)
    ok_f &= ~(apart & unsure_f)
    S = P[both] + P_b[both]
    dead = np.diagonal(S, axis1=1, axis2=2) <= 0.0  # a state held in both (the vertical wind)
    S[:, np.arange(dim), np.arange(dim)] += dead
    K = np.linalg.solve(S, P[both]).transpose(0, 2, 1)  # P_f S^-1 (both symmetric)
    dx = np.einsum("kij,kj->ki", K, d[both])
    Ps = P[both] - K @ P[both]
    P[both] = 0.5 * (Ps + Ps.transpose(0, 2, 1))
    q = nom[:, N_Q : N_Q + 4]
    q[both] = quat_mul(q[both], quat_exp(dx[:, :3]))
    only_b = ok_b & ~ok_f
    q[only_b] = q_b[only_b]
    P[only_b] = P_b[only_b]
    for block in L.blocks[1:]:
        sl = L.sl(block)
        x = nom[:, cols[block] : cols[block] + 3]
        x[both] += dx[:, sl]
        x[only_b] = x_b[only_b, sl]
    gnss_v = L.has("v") and "gnss" in est.uses and flight.gnss is not None
    if not (mag or gnss_v):
        # nothing measures the heading: the passes' headings are two gyro integrations from
        # datums of their own, so the smoothed attitude keeps the forward pass's heading
        psi = twist_angle(quat_mul(q[both], quat_conj(run.q[both])))  # smoothed against forward
        q[both] = quat_mul(quat_exp(np.outer(-psi, [0.0, 0.0, 1.0])), q[both])
    ok = ok_f | ok_b
    q[ok] /= np.linalg.norm(q[ok], axis=1)[:, None]
    return _smoothed_estimate(est, run, nom, P, ok, name, "two-filter")


def _smooth_compiled(est: Any, flight: Flight, initial: InitialState | None, name: str) -> Estimate:
    run, sm = forward_record(est, flight, initial)
    st = run.st
    backward(st.cfg, st.prm, sm.nom, sm.P, sm.aux, st.P.shape[0])
    return _smoothed_estimate(est, run, sm.nom, sm.P, sm.aux[:, A_INIT] == 1.0, name, "rts")


def _smoothed_estimate(est: Any, run: Any, nom: F64, P: F64, ok: NDArray[np.bool_], name: str, method: str) -> Estimate:
    """The Estimate of a smoothed run: the smoothed nominal state (record columns N_*) and
    covariance at the samples ``ok``, the forward pass's outputs elsewhere with no
    covariance; labelled ``name``, ``meta["smoother"]`` = method."""
    run.q[ok] = nom[ok, N_Q : N_Q + 4]
    run.bg[ok] = nom[ok, N_BG : N_BG + 3]
    if run.v.shape[0]:
        run.v[ok] = nom[ok, N_V : N_V + 3]
    if run.w.shape[0]:
        run.w[ok] = nom[ok, N_W : N_W + 3]
    P[~ok] = np.nan
    run.st.cfg["cov_every"] = 1
    out: Estimate = est.finish(run._replace(cov=P))
    return dataclasses.replace(out, filter=name, meta={**out.meta, "smoother": method})


def forward_record(est: Any, flight: Flight, initial: InitialState | None = None) -> tuple[Any, SmoothRecord]:
    """The forward pass of a compiled error-state estimator over ``flight`` with the
    smoothing record: its :class:`~windahrs.core.kernel.PreparedRun` (the filter's outputs,
    no covariance) and the :class:`SmoothRecord`. ValueError beyond :data:`SMOOTH_BUDGET`,
    before the record is allocated."""
    from windahrs.core.kernel import run_events

    run = est.prepare(flight, initial, cov="none", cov_every=1)  # (the outputs: 13 floats a sample)
    st, N, dim = run.st, len(flight.imu.t), run.layout.dim
    # every IMU step's covariance predicted at its sample (not once per predict.COV_PERIOD_S):
    # the backward pass recomputes each step's prior from the posterior before it
    st.cfg["cov_defer"] = 0
    if st.cfg["add_form"] != 0 or st.cfg["n"] != dim:
        raise ValueError(f"smoothing {est.label!r}: not an error-state filter")
    need = smooth_bytes(N, dim)
    if need > SMOOTH_BUDGET:
        raise ValueError(
            f"smoothing {est.label!r}: {N} IMU samples need {need / 2**30:.2f} GiB of record "
            f"({need // N} bytes per sample: the {dim}x{dim} covariance and the nominal state), beyond "
            f"SMOOTH_BUDGET = {SMOOTH_BUDGET / 2**30:g} GiB (windahrs.core.smooth); smooth a shorter span "
            "of the flight"
        )
    sm = SmoothRecord(np.zeros((N, N_NOM)), np.zeros((N, dim, dim)), np.zeros((N, N_AUX)))
    run_events(st, run.t_ev, run.kinds, run.vals, run.q, run.bg, run.v, run.w, run.cov, True, sm)
    return run, sm


class Smoothed(Estimator):
    """An estimator spec's smoothed form (``NAME-smooth`` or ``NAME:smooth=true``, see
    :func:`windahrs.filters.registry.make_estimator`): ``run`` is :func:`smooth` of the
    inner estimator with ``method`` (``smoother=`` in a spec); offline only (no streamer)."""

    def __init__(self, inner: Estimator, label: str | None = None, method: str = "auto") -> None:
        why = supports(inner)
        if why is not None:
            raise ValueError(why)
        check_method(method)
        self.inner = inner
        self.method = method
        self.name = smoothed_label(inner.name)  # type: ignore[misc]
        self.label = label if label is not None else smoothed_label(inner.label)
        self.requires = inner.requires  # type: ignore[misc]
        self.uses = inner.uses  # type: ignore[misc]

    def with_overrides(self, overrides: Mapping[str, Any]) -> Smoothed:
        """The smoothed form of the inner estimator with ``overrides`` on its parameters."""
        from windahrs.filters.registry import with_overrides

        return Smoothed(with_overrides(self.inner, self.inner.name, dict(overrides)), method=self.method)

    def check(self, flight: Flight) -> None:
        self.inner.check(flight)

    def params_text(self) -> str:
        return self.inner.params_text()

    def run(self, flight: Flight, *, initial: InitialState | None = None) -> Estimate:
        return smooth(self.inner, flight, initial=initial, label=self.label, method=self.method)

    def streamer(
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> Streamer:
        raise ValueError(f"{self.label}: a smoother runs offline on a whole flight; it has no streamer")
