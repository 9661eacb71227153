"""Dense Kalman machinery in numba: one Joseph-form EKF update and one set of
unscented-transform functions, shared by the additive-quaternion filters (paper,
paper-nowind, ekf, ukf).

States are (n,) float64 arrays, covariances (n, n), measurements (m,) with noise R (m, m);
every function returns new arrays and leaves its arguments alone. The EKF update is
written in plain loops (n <= 7, m = 3: no BLAS call per sample), inverting the innovation
covariance by Cholesky (it is symmetric positive definite). The unscented functions keep
the array expressions of the reference they replace: with a covariance whose eigenvalues
coincide (the UKF's isotropic P0) the symmetric-eigen sigma points depend on the last bit
of P, so their arithmetic is kept operation for operation.
With ``NUMBA_DISABLE_JIT=1`` the same source runs as plain Python.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

__all__ = [
    "kalman_update",
    "propagate_cov",
    "sigma_points",
    "spd_inverse",
    "ut_mean_cov",
    "ut_update",
    "ut_weights",
]

_JIT: dict[str, Any] = {"cache": True, "error_model": "numpy"}


@njit(**_JIT)
def spd_inverse(S):
    """Inverse (m, m) of a symmetric positive definite S (m, m), by Cholesky."""
    m = S.shape[0]
    L = np.zeros((m, m))
    for j in range(m):
        d = S[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, m):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    # Li = L^-1 (lower triangular), then S^-1 = Li^T Li
    Li = np.zeros((m, m))
    for j in range(m):
        Li[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, m):
            s = 0.0
            for k in range(j, i):
                s -= L[i, k] * Li[k, j]
            Li[i, j] = s / L[i, i]
    out = np.empty((m, m))
    for i in range(m):
        for j in range(i, m):
            s = 0.0
            for k in range(j, m):
                s += Li[k, i] * Li[k, j]
            out[i, j] = s
            out[j, i] = s
    return out


@njit(**_JIT)
def _quad(nu, Si):
    m = nu.shape[0]
    s = 0.0
    for i in range(m):
        for j in range(m):
            s += nu[i] * Si[i, j] * nu[j]
    return s


@njit(**_JIT)
def kalman_update(x, P, H, nu, R):
    """EKF update with the innovation nu (m,) = z - h(x), Jacobian H (m, n), noise R (m, m).

    Joseph form ``P+ = (I - K H) P (I - K H)^T + K R K^T``, ``K = P H^T S^-1``,
    ``S = H P H^T + R``, evaluated expanded as ``P + K G^T + G K^T`` with ``U = P H^T``,
    ``G = K S / 2 - U`` (the same matrix, exactly symmetric in floating point, no n x n
    temporaries). Returns (x+ (n,), P+ (n, n), NIS ``nu^T S^-1 nu``)."""
    n, m = x.shape[0], nu.shape[0]
    U = np.empty((n, m))  # P H^T
    for i in range(n):
        for a in range(m):
            s = 0.0
            for k in range(n):
                s += P[i, k] * H[a, k]
            U[i, a] = s
    S = np.empty((m, m))
    for a in range(m):
        for b in range(m):
            s = 0.0
            for k in range(n):
                s += H[a, k] * U[k, b]
            S[a, b] = s + R[a, b]
    Si = spd_inverse(S)
    K = np.empty((n, m))
    G = np.empty((n, m))
    x2 = x.copy()
    for i in range(n):
        for a in range(m):
            s = 0.0
            for b in range(m):
                s += U[i, b] * Si[b, a]
            K[i, a] = s
        for a in range(m):
            s = 0.0
            for b in range(m):
                s += K[i, b] * S[b, a]
            G[i, a] = 0.5 * s - U[i, a]
            x2[i] += K[i, a] * nu[a]
    P2 = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for a in range(m):
                s += K[i, a] * G[j, a] + G[i, a] * K[j, a]
            P2[i, j] = P[i, j] + s
            P2[j, i] = P[j, i] + s
    return x2, P2, _quad(nu, Si)


@njit(**_JIT)
def ut_weights(n, alpha, beta, kappa):
    """Scaled unscented transform on an n-vector: ``lambda = alpha^2 (n + kappa) - n``.

    Returns (mean weights (2n+1,), covariance weights (2n+1,), spread ``n + lambda``)."""
    lam = alpha**2 * (n + kappa) - n
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wm[0] = lam / (n + lam)
    wc = wm.copy()
    wc[0] += 1.0 - alpha**2 + beta
    return wm, wc, n + lam


@njit(**_JIT)
def sigma_points(x, P, spread):
    """(2n+1, n) points ``x, x + columns of S, x - columns of S``, ``S S^T = spread P``.

    S is the symmetric-eigen square root ``V sqrt(max(w, 0))`` of the symmetrised P: a
    covariance projected by a normalisation is singular, where Cholesky fails."""
    n = x.shape[0]
    w, V = np.linalg.eigh(spread * (0.5 * (P + P.T)))
    X = np.empty((2 * n + 1, n))
    X[0] = x
    for j in range(n):
        r = math.sqrt(max(w[j], 0.0))
        for i in range(n):
            X[1 + j, i] = x[i] + V[i, j] * r
            X[1 + n + j, i] = x[i] - V[i, j] * r
    return X


@njit(**_JIT)
def ut_mean_cov(X, wm, wc):
    """Weighted mean (n,) and covariance (n, n) of the points X (2n+1, n)."""
    x = wm @ X
    D = X - x
    return x, (D.T * wc) @ D


@njit(**_JIT)
def ut_update(x, P, X, Y, z, R, wm, wc):
    """Unscented update of (x (n,), P (n, n)) from the sigma points X (2n+1, n), their
    predicted measurements Y (2n+1, m), the measurement z (m,) and its noise R (m, m).

    ``Pyy = sum wc dY dY^T + R``, ``Pxy = sum wc dX dY^T``, ``K = Pxy Pyy^-1``,
    ``x+ = x + K (z - y)``, ``P+ = P - K Pyy K^T``. Returns (x+, P+, nu = z - y, NIS)."""
    y = wm @ Y
    dY = Y - y
    dX = X - x
    Pyy = (dY.T * wc) @ dY + R
    Pxy = (dX.T * wc) @ dY
    K = np.linalg.solve(Pyy, np.ascontiguousarray(Pxy.T)).T.copy()
    nu = z - y
    x2 = x + K @ nu
    P2 = P - K @ Pyy @ K.T
    # the NIS is only logged: no second LAPACK solve
    return x2, P2, nu, _quad(nu, spd_inverse(Pyy))


@njit(**_JIT)
def propagate_cov(F, P, Q):
    """``F P F^T + Q`` (n, n) for a transition F (n, n), covariance P and noise Q (n, n)."""
    n = P.shape[0]
    FP = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += F[i, k] * P[k, j]
            FP[i, j] = s
    out = Q.copy()
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += FP[i, k] * F[j, k]
            out[i, j] += s
    return out
