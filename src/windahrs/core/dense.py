"""Dense unscented machinery in numba: the unscented transform of the additive UKF
([ukf]), the one unscented gain step that [ukf] and [usque] share, and the paper's dense
covariance propagation ``Phi P Phi^T + Q``.
The EKFs' update is the one Kalman update of the compiled core (``core.kalman._fuse``).

States are (n,) float64 arrays, covariances (n, n), measurements (m,) with noise R (m, m);
every function but :func:`unscented_gain` returns new arrays and leaves its arguments
alone. The functions are plain loops (n <= 7, m = 3: no BLAS or LAPACK call per sample),
inverting the innovation covariance by Cholesky (it is symmetric positive definite); the
sigma points come from an LDL^T root (:func:`psd_root`), a function of the covariance
alone: the symmetric-eigen root it replaced depended, for the UKF's isotropic P0, on
which eigenvectors LAPACK picked within a repeated eigenvalue.
With ``NUMBA_DISABLE_JIT=1`` the same source runs as plain Python.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

__all__ = [
    "PIVOT_RTOL",
    "propagate_cov",
    "psd_root",
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
def ut_weights(n, alpha, beta, kappa):
    """Scaled unscented transform on an n-vector: ``lambda = alpha^2 (n + kappa) - n``.

    Returns (mean weights (2n+1,), covariance weights (2n+1,), spread ``n + lambda``)."""
    lam = alpha**2 * (n + kappa) - n
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wm[0] = lam / (n + lam)
    wc = wm.copy()
    wc[0] += 1.0 - alpha**2 + beta
    return wm, wc, n + lam


#: Relative threshold of a zero pivot in :func:`psd_root`, in units of the largest
#: diagonal entry of A (see there).
PIVOT_RTOL = 64.0 * np.finfo(np.float64).eps


@njit(**_JIT)
def psd_root(A):
    """Lower-triangular L (n, n) with ``L L^T = A`` for a symmetric positive
    semi-definite A (n, n) (only its lower triangle is read).

    Computed as ``A = M D M^T`` (LDL^T, unit lower-triangular M, no pivoting, plain loops)
    and returned as ``L = M sqrt(D)``: a function of A alone, unlike the eigenvectors of a
    repeated eigenvalue, and cheap.

    A singular A (the UKF's quaternion block after ``q <- q/|q|``, singular along q, SPEC
    2.3 and 4.2) has zero pivots that rounding turns into tiny numbers of either sign. A
    perturbation of A of size ``delta`` moves pivot j by up to ``delta (1 + |m_j|^2)``,
    ``m_j = M[j, :j]`` its multipliers (Higham, "Accuracy and Stability of Numerical
    Algorithms", 2nd ed., section 10.3, the ``||W||`` of Thm 10.14), and the projection
    leaves ``delta`` of a few eps times the largest entry. So pivot j is taken as zero,
    with its column, when ``d_j <= PIVOT_RTOL max_k A[k, k] (1 + |m_j|^2)``: 64 eps
    (1.4e-14) leaves a margin of ~10 over that rounding, and is far below any real
    variance ratio of the UKF (on the paper's and a fixed-wing flight its smallest variance
    stays above 1e-4 of its largest).
    A clearly negative pivot (A not a covariance) is dropped likewise, as the eigen root's
    ``max(w, 0)`` did."""
    n = A.shape[0]
    big = 0.0
    for k in range(n):
        big = max(big, A[k, k])
    tol = PIVOT_RTOL * big
    M = np.zeros((n, n))
    d = np.zeros(n)
    for j in range(n):
        dj = A[j, j]
        grow = 1.0
        for k in range(j):
            dj -= M[j, k] * M[j, k] * d[k]
            grow += M[j, k] * M[j, k]
        if dj <= tol * grow:
            continue  # zero pivot: column j of M stays 0
        d[j] = dj
        M[j, j] = 1.0
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= M[i, k] * M[j, k] * d[k]
            M[i, j] = s / dj
    L = np.zeros((n, n))
    for j in range(n):
        r = math.sqrt(d[j])
        for i in range(j, n):
            L[i, j] = M[i, j] * r
    return L


@njit(**_JIT)
def sigma_points(x, P, spread):
    """(2n+1, n) points ``x, x + columns of S, x - columns of S``, ``S S^T = spread P``.

    S is :func:`psd_root` of ``spread`` times the symmetrised P: deterministic (a function
    of P alone) and defined for the singular P a normalisation leaves, where plain
    Cholesky fails."""
    n = x.shape[0]
    A = np.empty((n, n))
    for i in range(n):
        for j in range(i + 1):
            A[i, j] = spread * (0.5 * (P[i, j] + P[j, i]))
    L = psd_root(A)
    X = np.empty((2 * n + 1, n))
    for i in range(n):
        X[0, i] = x[i]
    for j in range(n):
        for i in range(n):
            X[1 + j, i] = x[i] + L[i, j]
            X[1 + n + j, i] = x[i] - L[i, j]
    return X


@njit(**_JIT)
def _weighted_mean(X, wm):
    npts, n = X.shape
    x = np.zeros(n)
    for p in range(npts):
        for i in range(n):
            x[i] += wm[p] * X[p, i]
    return x


@njit(**_JIT)
def _weighted_cross(wc, X, x, Y, y):
    """``sum_p wc[p] (X[p] - x) (Y[p] - y)^T`` (n, m)."""
    npts, n = X.shape
    m = Y.shape[1]
    C = np.zeros((n, m))
    for p in range(npts):
        for i in range(n):
            a = wc[p] * (X[p, i] - x[i])
            for j in range(m):
                C[i, j] += a * (Y[p, j] - y[j])
    return C


@njit(**_JIT)
def ut_mean_cov(X, wm, wc):
    """Weighted mean (n,) and covariance (n, n) of the points X (2n+1, n); the covariance
    is exactly symmetric (each entry above the diagonal summed once and mirrored)."""
    x = _weighted_mean(X, wm)
    npts, n = X.shape
    C = np.zeros((n, n))
    for p in range(npts):
        for i in range(n):
            a = wc[p] * (X[p, i] - x[i])
            for j in range(i, n):
                C[i, j] += a * (X[p, j] - x[j])
    for i in range(n):
        for j in range(i):
            C[i, j] = C[j, i]
    return x, C


@njit(**_JIT)
def unscented_gain(P, Pxy, Si, nu, K, dx, n, m):
    """The unscented update's gain step, in place and without allocation, shared by [ukf]
    and [usque]: ``K = Pxy Pyy^-1`` (K (n, m), Si = Pyy^-1 (m, m)), ``dx = K nu`` (n,)
    and ``P <- P - K Pyy K^T = P - (K Pxy^T + Pxy K^T) / 2`` (exactly, as K Pyy = Pxy;
    symmetric by construction). The first n rows and columns of the arrays are used."""
    for i in range(n):
        v = 0.0
        for a in range(m):
            s = 0.0
            for b in range(m):
                s += Pxy[i, b] * Si[b, a]
            K[i, a] = s
            v += s * nu[a]
        dx[i] = v
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for a in range(m):
                s += 0.5 * (K[i, a] * Pxy[j, a] + Pxy[i, a] * K[j, a])
            P[i, j] = P[i, j] - s
            if j != i:
                P[j, i] = P[j, i] - s


@njit(**_JIT)
def ut_update(x, P, X, Y, z, R, wm, wc):
    """Unscented update of (x (n,), P (n, n)) from the sigma points X (2n+1, n), their
    predicted measurements Y (2n+1, m), the measurement z (m,) and its noise R (m, m).

    ``Pyy = sum wc dY dY^T + R``, ``Pxy = sum wc dX dY^T``, ``K = Pxy Pyy^-1``,
    ``x+ = x + K (z - y)``, ``P+ = P - K Pyy K^T = P - K Pxy^T``. Returns (x+, P+,
    nu = z - y, NIS). Plain loops, Pyy inverted by Cholesky: no BLAS or LAPACK call."""
    n, m = x.shape[0], z.shape[0]
    y = _weighted_mean(Y, wm)
    Pyy = _weighted_cross(wc, Y, y, Y, y) + R
    Pxy = _weighted_cross(wc, X, x, Y, y)
    Si = spd_inverse(Pyy)
    nu = z - y
    K, dx = np.zeros((n, m)), np.zeros(n)
    P2 = P.copy()
    unscented_gain(P2, Pxy, Si, nu, K, dx, n, m)
    return x + dx, P2, nu, _quad(nu, Si)


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
