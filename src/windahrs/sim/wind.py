"""Wind: MIL-F-8785C Dryden turbulence, wind shear and discrete gusts (SPEC 5.1).

Conventions
-----------
Spectra and shaping filters follow SPEC 5.1 exactly: the filters are driven by continuous
white noise of *unit intensity* (``E[n(t) n(s)] = delta(t - s)``), so

* ``H_u(s) = sigma_u sqrt(2 T_u) / (1 + T_u s)``,
* ``H_v(s) = sigma_v sqrt(T_v) (1 + sqrt(3) T_v s) / (1 + T_v s)^2`` (``H_w`` likewise),

with ``T = L / V``. The MIL documents' ``sqrt(2 L / (pi V))`` carries a ``pi`` that belongs
to a different noise normalisation, and MIL-HDBK-1797's ``2 L`` / ``2 sqrt(3)`` forms use
halved lengths; neither is mixed in here (the sqrt(pi) and factor-2 traps of SPEC 5.1).

Gust components returned by :func:`dryden_gusts` are wind (air-mass) velocity
perturbations in the *turbulence frame*: ``u`` along the mean air-relative flight path
(positive in the direction of flight), ``v`` lateral (positive to the right), ``w`` vertical
(positive down). The caller rotates them into NED; for level flight with air-relative
course ``chi`` the rotation is ``[cos chi, -sin chi, 0; sin chi, cos chi, 0; 0, 0, 1]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import cache, lru_cache
from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import cholesky, eigh, expm, solve_continuous_lyapunov
from scipy.signal import lfilter

__all__ = [
    "FT",
    "DrydenParams",
    "dryden_gusts",
    "dryden_psd",
    "low_altitude_params",
    "random_walk_density",
    "one_minus_cosine_gust",
    "shear_mean_wind",
]

F64 = NDArray[np.float64]

#: One international foot in metres.
FT: float = 0.3048

#: Lowest airspeed used as the frozen-turbulence advection speed, m/s.
_MIN_AIRSPEED = 1.0

#: Ratio step (minus 1) of the airspeed grid on which time-varying airspeeds are discretised.
_V_REL_TOL = 0.01

#: Segments with at least this many steps are propagated with ``lfilter``; shorter ones
#: with a scalar loop, because ``lfilter``'s per-call overhead dominates for a few steps.
_LFILTER_MIN_STEPS = 64

_SQRT3 = math.sqrt(3.0)

# The v/w filter in time-normalised form (p = T s): states z1 = z2/(1+p), z2 = n'/(1+p),
# output sigma*(sqrt(3) z2 + (1 - sqrt(3)) z1), since (1 + sqrt3 p) = sqrt3 (1+p) + 1 - sqrt3.
# Driving z2 with n/sqrt(T) (not n) makes the stationary state covariance independent of T,
# so a change of airspeed neither jumps the output nor disturbs the variance.
_A0 = np.array([[-1.0, 1.0], [0.0, -1.0]])
_B0 = np.array([[0.0], [1.0]])
_C0 = np.array([1.0 - _SQRT3, _SQRT3])


def _fail(name: str, expected: str, found: object) -> ValueError:
    return ValueError(f"{name}: expected {expected}, found {found!r}")


def _finite_float(name: str, value: object) -> float:
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise _fail(name, "a finite real number", value) from None
    if not math.isfinite(x):
        raise _fail(name, "a finite real number", value)
    return x


@dataclass(frozen=True)
class DrydenParams:
    """Dryden turbulence scale lengths (m) and intensities (m/s), MIL-F-8785C.

    Attributes
    ----------
    L_u, L_v, L_w : float
        Scale lengths of the longitudinal, lateral and vertical components, m, > 0.
    sigma_u, sigma_v, sigma_w : float
        Standard deviations of the three components, m/s, >= 0.
    """

    L_u: float
    L_v: float
    L_w: float
    sigma_u: float
    sigma_v: float
    sigma_w: float

    def __post_init__(self) -> None:
        for f in fields(self):
            name = f"DrydenParams.{f.name}"
            value = getattr(self, f.name)
            x = _finite_float(name, value)
            if f.name.startswith("L_") and not x > 0.0:
                raise _fail(name, "a finite length > 0 m", value)
            if f.name.startswith("sigma_") and not x >= 0.0:
                raise _fail(name, "a finite standard deviation >= 0 m/s", value)


def low_altitude_params(w20: float, altitude: float) -> DrydenParams:
    """MIL-F-8785C low-altitude Dryden parameters (SPEC 5.1).

    With ``h`` the altitude in feet: ``L_w = h``, ``L_u = L_v = h / (0.177 + 0.000823 h)^1.2``,
    ``sigma_w = 0.1 W20``, ``sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)^0.4``.

    The formulas are only valid for 10 ft <= h <= 1000 ft (below 10 ft the scale lengths go
    to 0 and the spectra degenerate), so ``h`` is clamped to [10 ft, 1000 ft] (3.048 m to
    304.8 m): any altitude below 10 ft, including 0 or a small negative value, gets the 10 ft
    parameters, any altitude above 1000 ft the 1000 ft parameters. Above 1000 ft this is an
    approximation, not MIL-F-8785C's medium/high-altitude model.

    Parameters
    ----------
    w20 : float
        Mean wind speed at 20 ft (6.096 m) above ground, m/s, >= 0 (light / moderate /
        severe: 15 / 30 / 45 kt).
    altitude : float
        Height above ground, m.

    Returns
    -------
    DrydenParams
        Scale lengths in m, intensities in m/s.
    """
    w = _finite_float("w20", w20)
    if w < 0.0:
        raise _fail("w20", "a wind speed >= 0 m/s", w20)
    h_m = _finite_float("altitude", altitude)
    h = min(max(h_m / FT, 10.0), 1000.0)
    k = 0.177 + 0.000823 * h
    l_uv = h / k**1.2 * FT
    sigma_w = 0.1 * w
    sigma_uv = sigma_w / k**0.4
    return DrydenParams(
        L_u=l_uv, L_v=l_uv, L_w=h * FT, sigma_u=sigma_uv, sigma_v=sigma_uv, sigma_w=sigma_w
    )


@overload
def shear_mean_wind(w20: float, altitude: float, z0: float = ...) -> float: ...
@overload
def shear_mean_wind(w20: float, altitude: ArrayLike, z0: float = ...) -> F64: ...
def shear_mean_wind(w20: float, altitude: ArrayLike, z0: float = 0.15 * FT) -> float | F64:
    """Mean wind speed of the MIL-F-8785C logarithmic shear profile (SPEC 5.1).

    ``U(h) = W20 ln(h / z0) / ln(20 ft / z0)``. Altitudes below ``z0`` are floored at ``z0``
    (so ``U = 0`` there) to avoid the logarithm of a value <= 0: the log profile has no
    meaning inside the roughness layer.

    Parameters
    ----------
    w20 : float
        Mean wind speed at 20 ft (6.096 m), m/s, >= 0.
    altitude : float or array_like, shape (m,)
        Height above ground, m.
    z0 : float
        Surface roughness length, m, 0 < z0 < 20 ft; default 0.15 ft (MIL-F-8785C
        Category C, terminal flight phases); 2 ft for other phases.

    Returns
    -------
    float or ndarray, shape like ``altitude``
        Mean wind speed, m/s.
    """
    w = _finite_float("w20", w20)
    if w < 0.0:
        raise _fail("w20", "a wind speed >= 0 m/s", w20)
    zr = _finite_float("z0", z0)
    if not 0.0 < zr < 20.0 * FT:
        raise _fail("z0", f"a roughness length in (0, {20.0 * FT}) m", z0)
    h = np.asarray(altitude, dtype=np.float64)
    if not np.all(np.isfinite(h)):
        raise _fail("altitude", "finite heights in m", altitude)
    u = w * np.log(np.maximum(h, zr) / zr) / math.log(20.0 * FT / zr)
    if h.ndim == 0:
        return float(u)
    return u


# --------------------------------------------------------------------------- Dryden


@cache
def _stationary_cov2() -> F64:
    """Stationary covariance (2, 2) of the normalised v/w state; independent of T."""
    p = solve_continuous_lyapunov(_A0, -_B0 @ _B0.T)
    p = 0.5 * (p + p.T)
    p.setflags(write=False)
    return p


@cache
def _stationary_sqrt2() -> F64:
    """Lower Cholesky factor (2, 2) of :func:`_stationary_cov2`."""
    g = _sqrt_psd(np.array(_stationary_cov2()))
    g.setflags(write=False)
    return g


def _sqrt_psd(q: F64) -> F64:
    """Lower factor ``G`` (2, 2) with ``G G^T = q``, robust to round-off near singularity."""
    try:
        return np.asarray(cholesky(q, lower=True), dtype=np.float64)
    except np.linalg.LinAlgError:
        # For dt << T the discrete covariance has condition ~ (T/dt)^2; if round-off makes it
        # numerically indefinite, clip the negligible negative eigenvalue instead of failing.
        lam, vec = eigh(q)
        return np.asarray(vec * np.sqrt(np.clip(lam, 0.0, None)), dtype=np.float64)


@lru_cache(maxsize=4096)
def _disc_first(tau: float, dt: float) -> tuple[float, float]:
    """AR(1) ``x+ = phi x + g eta`` of the unit-variance u state: (phi, g)."""
    return math.exp(-dt / tau), math.sqrt(-math.expm1(-2.0 * dt / tau))


@lru_cache(maxsize=4096)
def _disc_second(tau: float, dt: float) -> tuple[F64, F64]:
    """Exact discretisation of the v/w state: ``x+ = A_d x + G eta``, eta ~ N(0, I2).

    Returns ``A_d`` (2, 2) and ``G`` (2, 2) with ``G G^T = Q_d`` (Van Loan).
    """
    h = dt / tau
    a = _A0 / tau
    qc = (_B0 @ _B0.T) / tau
    if h <= 1.0:
        m = np.zeros((4, 4))
        m[:2, :2] = -a * dt
        m[:2, 2:] = qc * dt
        m[2:, 2:] = a.T * dt
        f = expm(m)
        ad = np.ascontiguousarray(f[2:, 2:].T)
        qd = ad @ f[:2, 2:]
    else:
        # Van Loan's block exp(+dt/T) terms overflow for dt >> T; when the correlation has
        # largely decayed the stationary identity Q_d = P - A_d P A_d^T is exact and free of
        # cancellation (A_d P A_d^T < P / e).
        ad = np.asarray(expm(a * dt), dtype=np.float64)
        p = _stationary_cov2()
        qd = p - ad @ p @ ad.T
    qd = 0.5 * (qd + qd.T)
    g = _sqrt_psd(qd)
    ad.setflags(write=False)
    g.setflags(write=False)
    return ad, g


def _tables(lengths: tuple[float, float, float], refs: F64, dt: float) -> F64:
    """Discretisations for the airspeeds ``refs`` (K,), one row each, shape (K, 18).

    Columns: phi_u, g_u, A_d(v) row-major (4), G(v) (4), A_d(w) (4), G(w) (4).
    """
    tab = np.empty((refs.size, 18))
    for r, ref in enumerate(refs.tolist()):
        phi, gu = _disc_first(lengths[0] / ref, dt)
        ad_v, g_v = _disc_second(lengths[1] / ref, dt)
        ad_w, g_w = _disc_second(lengths[2] / ref, dt)
        tab[r, :2] = phi, gu
        tab[r, 2:6] = ad_v.ravel()
        tab[r, 6:10] = g_v.ravel()
        tab[r, 10:14] = ad_w.ravel()
        tab[r, 14:18] = g_w.ravel()
    return tab


def _noise(c: F64, z: F64) -> F64:
    """Process noise (5, m) from coefficients ``c`` (18,) or (18, m) and normals ``z`` (5, m).

    Element-wise rather than ``@``: a threaded BLAS call per short run costs more than it
    saves.
    """
    w = np.empty_like(z)
    w[0] = c[1] * z[0]
    for row, off in ((1, 6), (3, 14)):
        w[row] = c[off] * z[row] + c[off + 1] * z[row + 1]
        w[row + 1] = c[off + 2] * z[row] + c[off + 3] * z[row + 1]
    return w


def _run_lfilter(c: F64, x0: F64, w: F64) -> F64:
    """States ``x_1..x_m`` (5, m) for constant coefficients ``c`` (18,) from ``x_0`` (5,)."""
    out = np.empty_like(w)
    e = w.copy()
    e[0, 0] += c[0] * x0[0]
    out[0] = lfilter([1.0], [1.0, -c[0]], e[0])
    for row, off in ((1, 2), (3, 10)):
        a, b, cc, d = c[off : off + 4].tolist()
        e[row, 0] += a * x0[row] + b * x0[row + 1]
        e[row + 1, 0] += cc * x0[row] + d * x0[row + 1]
        # (I - A_d q)^-1 = adj(I - A_d q) / det(I - A_d q), q = z^-1: two-input IIR filters.
        den = [1.0, -(a + d), a * d - b * cc]
        e1, e2 = e[row], e[row + 1]
        out[row] = lfilter([1.0, -d], den, e1) + lfilter([0.0, b], den, e2)
        out[row + 1] = lfilter([0.0, cc], den, e1) + lfilter([1.0, -a], den, e2)
    return out


def _run_scalar(c: F64, x0: F64, w: F64) -> F64:
    """As :func:`_run_lfilter` with per-step coefficients ``c`` (18, m); plain-float loop."""
    u, v1, v2, w1, w2 = x0.tolist()
    cols = [c[0], c[2], c[3], c[4], c[5], c[10], c[11], c[12], c[13], *w]
    out: list[tuple[float, float, float, float, float]] = []
    for p, va, vb, vc, vd, wa, wb, wc, wd, eu, ev1, ev2, ew1, ew2 in zip(
        *(col.tolist() for col in cols), strict=True
    ):
        u = p * u + eu
        v1, v2 = va * v1 + vb * v2 + ev1, vc * v1 + vd * v2 + ev2
        w1, w2 = wa * w1 + wb * w2 + ew1, wc * w1 + wd * w2 + ew2
        out.append((u, v1, v2, w1, w2))
    return np.array(out, dtype=np.float64).T.reshape(w.shape)


def _check_n_dt(dt: float, n: int) -> float:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise _fail("n", "an integer >= 1", n)
    step = _finite_float("dt", dt)
    if not step > 0.0:
        raise _fail("dt", "a time step > 0 s", dt)
    return step


def _airspeed_array(airspeed: float | ArrayLike, n: int) -> F64:
    v = np.asarray(airspeed, dtype=np.float64)
    if v.ndim == 0:
        v = np.full(n, float(v))
    if v.shape != (n,):
        raise _fail("airspeed", f"a float or an array of shape ({n},)", v.shape)
    if not np.all(np.isfinite(v)) or np.any(v < 0.0):
        raise _fail("airspeed", "finite speeds >= 0 m/s", airspeed)
    return np.maximum(v, _MIN_AIRSPEED)


def dryden_gusts(
    params: DrydenParams,
    airspeed: float | ArrayLike,
    dt: float,
    n: int,
    rng: np.random.Generator,
) -> F64:
    """Sample Dryden turbulence: exact discretisation of the SPEC 5.1 shaping filters.

    Each filter's state is advanced with the exact transition ``A_d = expm(A dt)`` and the
    exact process-noise covariance ``Q_d = int_0^dt e^{A s} B B^T e^{A^T s} ds`` (Van Loan),
    so the samples are the continuous Dryden process sampled at ``dt`` with no
    discretisation bias for any ``V dt / L`` (unlike the Euler recursion found online). The
    u channel reduces to the AR(1)
    ``u_{k+1} = e^{-dt/T} u_k + sigma_u sqrt(1 - e^{-2 dt/T}) eta_k``. The first sample is
    drawn from the stationary distribution, so the output is stationary from ``k = 0``.

    Frozen turbulence (Taylor) converts the spatial spectra to time with ``T = L / V``.
    ``airspeed`` is floored at 1 m/s because the frozen-field assumption fails as
    ``V -> 0``; for hover pass the mean wind speed (the field is advected past the vehicle
    at that speed).

    Time-varying airspeed: entry ``k`` is held over step ``k -> k + 1``. Each entry is
    rounded to the geometric grid ``airspeed[0] * 1.01**i`` (a relative error of at most
    0.5 % in ``T``), and one discretisation is computed (and cached) per grid value, so a
    new one is needed only when ``V`` moves by about 1 %; a constant airspeed, scalar or
    array, is used exactly. Runs of steps sharing a discretisation are filtered with
    ``lfilter``; only short runs fall back to a Python loop. The state realisation has a
    stationary covariance independent of ``V``, so the variances stay ``sigma^2`` and the
    output is continuous while ``V`` varies.

    Parameters
    ----------
    params : DrydenParams
        Scale lengths (m) and intensities (m/s).
    airspeed : float or array_like, shape (n,)
        Airspeed ``V`` (advection speed) in m/s, >= 0.
    dt : float
        Sample interval, s, > 0.
    n : int
        Number of samples, >= 1.
    rng : numpy.random.Generator
        Source of every random draw (one ``standard_normal((5, n))`` call).

    Returns
    -------
    ndarray, shape (n, 3)
        Gust velocity ``[u, v, w]`` in m/s at ``t = k dt``, k = 0..n-1: ``u`` along the mean
        air-relative flight path (positive forward), ``v`` lateral (positive right), ``w``
        vertical (positive down). The caller rotates them into NED.
    """
    step = _check_n_dt(dt, n)
    v = _airspeed_array(airspeed, n)
    lengths = (float(params.L_u), float(params.L_v), float(params.L_w))

    # One block of draws in a fixed layout: column 0 initial states, column k+1 the noise
    # of step k; the result then does not depend on how the steps are grouped below.
    z = rng.standard_normal((5, n))
    x = np.empty((5, n))
    p_sqrt = _stationary_sqrt2()
    x[0, 0] = z[0, 0]
    x[1:3, 0] = p_sqrt @ z[1:3, 0]
    x[3:5, 0] = p_sqrt @ z[3:5, 0]

    if n > 1:
        v0 = float(v[0])
        cell = np.rint(np.log(v[: n - 1] / v0) / math.log1p(_V_REL_TOL)).astype(np.int64)
        uniq, inv = np.unique(cell, return_inverse=True)
        refs = v0 * (1.0 + _V_REL_TOL) ** uniq.astype(np.float64)
        refs[uniq == 0] = v0
        tab = _tables(lengths, refs, step)

        starts = np.flatnonzero(np.r_[True, cell[1:] != cell[:-1]])
        stops = np.r_[starts[1:], n - 1]
        done = 0  # steps 0..done-1 are propagated
        for r in np.flatnonzero(stops - starts >= _LFILTER_MIN_STEPS).tolist():
            i, j = int(starts[r]), int(stops[r])
            if i > done:
                c = tab[inv[done:i]].T
                w = _noise(c, z[:, done + 1 : i + 1])
                x[:, done + 1 : i + 1] = _run_scalar(c, x[:, done], w)
            c = tab[inv[i]]
            x[:, i + 1 : j + 1] = _run_lfilter(c, x[:, i], _noise(c, z[:, i + 1 : j + 1]))
            done = j
        if done < n - 1:
            c = tab[inv[done:]].T
            x[:, done + 1 :] = _run_scalar(c, x[:, done], _noise(c, z[:, done + 1 :]))

    out = np.empty((n, 3))
    out[:, 0] = params.sigma_u * x[0]
    out[:, 1] = params.sigma_v * (_C0[0] * x[1] + _C0[1] * x[2])
    out[:, 2] = params.sigma_w * (_C0[0] * x[3] + _C0[1] * x[4])
    return out


def dryden_psd(params: DrydenParams, airspeed: float, freq_hz: ArrayLike) -> F64:
    """Analytic one-sided PSD of the Dryden gust components, (m/s)^2/Hz.

    ``S(f) = 2 |H(j 2 pi f)|^2`` for the unit-intensity shaping filters of SPEC 5.1 (unit
    two-sided white-noise intensity, one-sided in Hz, hence the 2), so that
    ``int_0^inf S df = sigma^2``. In terms of the spatial spectra ``Phi(Omega)`` of SPEC
    5.1, ``S(f) = 2 pi Phi(2 pi f / V) / V``. Explicitly, with ``x = 2 pi f T``:
    ``S_u = 4 sigma_u^2 T_u / (1 + x^2)``,
    ``S_v = 2 sigma_v^2 T_v (1 + 3 x^2) / (1 + x^2)^2`` (``S_w`` likewise).

    Parameters
    ----------
    params : DrydenParams
        Scale lengths (m) and intensities (m/s).
    airspeed : float
        Airspeed, m/s, >= 0; floored at 1 m/s as in :func:`dryden_gusts`.
    freq_hz : array_like, shape (m,)
        Frequencies, Hz, >= 0.

    Returns
    -------
    ndarray, shape (m, 3)
        One-sided PSD of ``[u, v, w]``, (m/s)^2/Hz.
    """
    v_air = _finite_float("airspeed", airspeed)
    if v_air < 0.0:
        raise _fail("airspeed", "a speed >= 0 m/s", airspeed)
    v_air = max(v_air, _MIN_AIRSPEED)
    f = np.atleast_1d(np.asarray(freq_hz, dtype=np.float64))
    if f.ndim != 1 or not np.all(np.isfinite(f)) or np.any(f < 0.0):
        raise _fail("freq_hz", "a 1-D array of finite frequencies >= 0 Hz", freq_hz)
    omega = 2.0 * np.pi * f
    out = np.empty((f.size, 3))
    tu = params.L_u / v_air
    out[:, 0] = 4.0 * params.sigma_u**2 * tu / (1.0 + (omega * tu) ** 2)
    for col, length, sigma in ((1, params.L_v, params.sigma_v), (2, params.L_w, params.sigma_w)):
        t = length / v_air
        x2 = (omega * t) ** 2
        out[:, col] = 2.0 * sigma**2 * t * (1.0 + 3.0 * x2) / (1.0 + x2) ** 2
    return out


def random_walk_density(params: DrydenParams, airspeed: float) -> tuple[float, float]:
    """Random-walk densities (horizontal, vertical), m/s^2/sqrt(Hz), that match Dryden
    turbulence over short times: the wind states of a filter that models the wind as a
    random walk (``EskfParams.wind_noise``, ``wind_noise_vertical``).

    With ``T = L / V``, a component's increments over a short dt have variance
    ``2 (R(0) - R(dt))``: ``2 sigma^2 dt / T`` for the first-order longitudinal filter
    (``R(tau) = sigma^2 e^(-tau/T)``) and ``3 sigma^2 dt / T`` for the second-order lateral
    and vertical ones (``R(tau) = sigma^2 (1 - tau / 2T) e^(-tau/T)``), i.e. densities
    ``sigma_u sqrt(2 V / L_u)`` and ``sigma_{v,w} sqrt(3 V / L_{v,w})`` (the high-frequency
    asymptotes of :func:`dryden_psd`). Horizontal: the larger of the u and v values;
    vertical: the w value. Airspeed is floored at 1 m/s as in :func:`dryden_gusts`.
    """
    v_air = _finite_float("airspeed", airspeed)
    if v_air < 0.0:
        raise _fail("airspeed", "a speed >= 0 m/s", airspeed)
    v_air = max(v_air, _MIN_AIRSPEED)
    u = params.sigma_u * np.sqrt(2.0 * v_air / params.L_u)
    v = params.sigma_v * np.sqrt(3.0 * v_air / params.L_v)
    return float(max(u, v)), float(params.sigma_w * np.sqrt(3.0 * v_air / params.L_w))


# --------------------------------------------------------------------------- discrete gust


def one_minus_cosine_gust(
    t: ArrayLike, t_start: float, duration: float, amplitude: float | ArrayLike
) -> F64:
    """Discrete "1 - cosine" gust.

    ``g(t) = 0.5 A (1 - cos(2 pi (t - t_start) / duration))`` for
    ``t_start <= t <= t_start + duration``, 0 elsewhere; peak ``A`` at mid-duration.

    Parameters
    ----------
    t : array_like, shape (m,)
        Times, s.
    t_start : float
        Gust onset, s.
    duration : float
        Gust length, s, > 0.
    amplitude : float or array_like, shape (3,)
        Peak gust velocity, m/s: a scalar, or a NED 3-vector.

    Returns
    -------
    ndarray, shape (m,) for a scalar amplitude, (m, 3) for a 3-vector
        Gust velocity, m/s.
    """
    t0 = _finite_float("t_start", t_start)
    d = _finite_float("duration", duration)
    if not d > 0.0:
        raise _fail("duration", "a gust length > 0 s", duration)
    a = np.asarray(amplitude, dtype=np.float64)
    if a.shape not in ((), (3,)) or not np.all(np.isfinite(a)):
        raise _fail("amplitude", "a finite scalar or 3-vector in m/s", amplitude)
    tt = np.atleast_1d(np.asarray(t, dtype=np.float64))
    if tt.ndim != 1:
        raise _fail("t", "a 1-D array of times in s", tt.shape)
    s = tt - t0
    inside = (s >= 0.0) & (s <= d)
    shape = np.where(inside, 0.5 * (1.0 - np.cos(2.0 * np.pi * s / d)), 0.0)
    if a.ndim == 0:
        return np.asarray(shape * float(a), dtype=np.float64)
    return np.asarray(shape[:, None] * a[None, :], dtype=np.float64)
