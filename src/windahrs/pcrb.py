"""Posterior Cramér-Rao bound of attitude along a simulated truth (SPEC 6).

The bound of Tichavský, Muravchik & Nehorai (IEEE TSP 46(5), 1998) for additive Gaussian
noise with Jacobians on the true trajectory is

    J_k = (Phi_{k-1} J_{k-1}^-1 Phi_{k-1}^T + Q_{k-1})^-1 + H_k^T R_k^-1 H_k,    J_0 = P_0^-1

(valid for singular Q), and PCRB_k = J_k^-1. With every Jacobian evaluated on the truth
this is, term by term, the covariance recursion of a Kalman filter that linearises about
the true state: ``P_k^- = Phi P Phi^T + Q`` and ``P_k = (P_k^-^-1 + H^T R^-1 H)^-1``. We
compute it in that covariance form (the update in Joseph form
``(I - K H) P (I - K H)^T + K R K^T`` with the optimal gain, ``S = H P H^T + R`` factored
by Cholesky), which never inverts P or Q, so a singular prior (a bias known exactly) or a
rank-deficient Q is fine. :func:`pcrb_recursion` is that recursion on
explicit per-step matrices; :func:`pcrb` builds the steps of a flight (SPEC 6.2).

Error state: the tangent space of the error-state filters (body-frame attitude error
``q_true = q_hat * Exp(dtheta)``, additive elsewhere; a
:class:`~windahrs.models.error_state.Layout`), never the 4-d quaternion. The prediction
``Phi P Phi^T + Q`` and the measurement Jacobians H and noise R are the shipped filters'
own compiled functions (the error-state prediction and the aid sources, through
:class:`windahrs.core.linearize.Linearization`), evaluated at the truth: the true body
rate ``Log(q[k-1]^* q[k]) / dt`` (what the simulator integrates), the true specific force
``C_bn (a_n - g_n)`` with ``a_n`` the difference quotient of ``truth.v_n`` over each step
(the simulator's definition), and the true attitude, velocity and wind, the biases at 0.
Noise is the sensor's true noise (:class:`PcrbNoise`, usually :meth:`PcrbNoise.from_suite`
of the simulator's SensorSuite), given to those functions as :class:`EskfParams`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from windahrs.core.linearize import Linearization
from windahrs.filters.params import EskfParams
from windahrs.flight import Flight, Truth
from windahrs.models.error_state import Layout
from windahrs.rotation import euler_from_quat, euler_rate_map, quat_rotate_inv
from windahrs.sim.gust_response import rates_from_attitude
from windahrs.sim.sensors import SensorSuite, air_data_from_velocity

__all__ = [
    "PcrbModel",
    "PcrbNoise",
    "PcrbResult",
    "efficiency_ratio",
    "pcrb",
    "pcrb_average",
    "pcrb_layout",
    "pcrb_recursion",
]

F64 = NDArray[np.float64]
PcrbModel = Literal["gravity", "ins"]
MODELS: tuple[str, ...] = ("gravity", "ins")
DEG = math.pi / 180.0


# --- noise --------------------------------------------------------------------------------


@dataclass(frozen=True)
class PcrbNoise:
    """The true sensor noise the bound assumes.

    Densities (continuous, per sqrt(Hz)): gyro rad/s; gyro_bias rad/s^2 (random walk);
    accel m/s^2; accel_bias m/s^3 (random walk); mag_bias tesla/s (random walk). Initial
    bias spreads (standard deviation per axis): gyro_bias_init rad/s, accel_bias_init
    m/s^2, mag_bias_init tesla (the magnetometer's hard iron, a constant offset). Per-sample
    standard deviations per axis: mag tesla, gnss m/s, tas m/s, vane rad (angle of attack
    and sideslip).
    """

    gyro: float
    gyro_bias: float = 0.0
    gyro_bias_init: float = 0.0
    accel: float = 0.0
    accel_bias: float = 0.0
    accel_bias_init: float = 0.0
    mag_bias: float = 0.0
    mag_bias_init: float = 0.0
    mag: float = 0.0
    gnss: float = 0.0
    tas: float = 0.0
    vane: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
                raise ValueError(f"PcrbNoise.{f.name}: expected a finite number >= 0, found {v!r}")

    @classmethod
    def from_suite(cls, suite: SensorSuite) -> PcrbNoise:
        """The noise of a simulator SensorSuite (SPEC 5.4); the magnetometer hard iron is
        an unknown constant bias of known spread. Not carried over, because they are not
        noise of the models the bound uses: the GNSS latency, the pitot scale error.
        Absent sensors give 0."""
        return cls(
            gyro=suite.gyro.noise_density,
            gyro_bias=suite.gyro.bias_rw,
            gyro_bias_init=suite.gyro.bias_init_sigma,
            accel=suite.accel.noise_density,
            accel_bias=suite.accel.bias_rw,
            accel_bias_init=suite.accel.bias_init_sigma,
            mag_bias_init=0.0 if suite.mag is None else suite.mag.hard_iron,
            mag=0.0 if suite.mag is None else suite.mag.noise,
            gnss=0.0 if suite.gnss is None else suite.gnss.noise,
            tas=0.0 if suite.pitot is None else suite.pitot.noise,
            vane=0.0 if suite.vanes is None else suite.vanes.noise,
        )

    @property
    def has_accel_bias(self) -> bool:
        return self.accel_bias > 0 or self.accel_bias_init > 0

    @property
    def has_mag_bias(self) -> bool:
        return self.mag_bias > 0 or self.mag_bias_init > 0


# --- result -------------------------------------------------------------------------------


@dataclass(frozen=True)
class PcrbResult:
    """The bound on the IMU grid.

    t (N,) s; cov (N, n, n) error-state bound in the tangent space (SI units, labelled by
    ``labels``: att_* rad (body frame), v_* m/s, bg_* rad/s, wind_* m/s, ba_* m/s^2);
    cov_euler (N, 3, 3) rad^2, the bound of (roll, pitch, yaw) = ``T P_att T^T`` (SPEC 1.4)
    at the true attitude; model "gravity" or "ins"; sensors: the measurement streams
    used; used: samples fused per stream; runs: truths averaged (1 for one flight);
    max_accel_n m/s^2: the largest true acceleration (NaN without truth velocity), zero
    when the "gravity" model is exact.
    """

    t: F64
    cov: F64
    cov_euler: F64
    labels: tuple[str, ...]
    model: str
    sensors: tuple[str, ...]
    used: dict[str, int]
    runs: int = 1
    max_accel_n: float = math.nan

    def index(self, label: str) -> int:
        try:
            return self.labels.index(label)
        except ValueError:
            raise KeyError(f"label: expected one of {self.labels}, found {label!r}") from None

    def std(self) -> F64:
        """Standard deviation bound of every state (N, n), SI units."""
        return np.sqrt(np.maximum(np.diagonal(self.cov, axis1=1, axis2=2), 0.0))

    def att_std_deg(self) -> F64:
        """Body-frame attitude error bound (N, 3) in degrees, components of ``dtheta``."""
        i = [self.index(f"att_{a}") for a in "xyz"]
        return np.degrees(self.std()[:, i])

    def euler_std_deg(self) -> F64:
        """Roll, pitch, yaw bound (N, 3) in degrees (``T P T^T`` at the true attitude)."""
        return np.degrees(np.sqrt(np.maximum(np.diagonal(self.cov_euler, axis1=1, axis2=2), 0.0)))


# --- the recursion ------------------------------------------------------------------------


def _update(P: F64, H: F64, R: F64) -> F64:
    """Measurement update of the bound: Joseph form with the optimal gain."""
    if H.shape[0] == 0:
        return P
    PHt = P @ H.T
    S = H @ PHt + R
    try:
        c = scipy.linalg.cho_factor(S, lower=True)
    except np.linalg.LinAlgError:
        raise ValueError("R: the innovation covariance H P H^T + R is not positive definite") from None
    K = scipy.linalg.cho_solve(c, PHt.T).T
    IKH = np.eye(P.shape[0]) - K @ H
    P = IKH @ P @ IKH.T + K @ R @ K.T
    return 0.5 * (P + P.T)


def _recursion(
    n_steps: int,
    P0: F64,
    propagate: Callable[[int, F64], F64],
    measurement: Callable[[int], tuple[F64, F64]],
) -> F64:
    """Bound (n_steps, n, n): ``P = update(P0, 0)``, then predict to k and update at k.
    ``propagate(k, P)`` returns ``Phi P Phi^T + Q`` from step k-1 to k; ``measurement(k)``
    returns (H (m, n), R (m, m)), m possibly 0."""
    n = P0.shape[0]
    out = np.empty((n_steps, n, n))
    P = _update(P0, *measurement(0))
    out[0] = P
    for k in range(1, n_steps):
        P = _update(propagate(k, P), *measurement(k))
        out[k] = P
    return out


def _check_square(name: str, a: F64, n: int) -> None:
    if a.shape != (n, n):
        raise ValueError(f"{name}: expected shape ({n}, {n}), found {a.shape}")


def pcrb_recursion(
    Phis: F64 | Sequence[F64],
    Qs: F64 | Sequence[F64],
    Hs: Sequence[F64 | None],
    Rs: Sequence[F64 | None],
    P0: F64,
) -> F64:
    """The PCRB recursion (module docstring) on explicit matrices.

    Phis, Qs: (N-1, n, n), the transition and process noise from step k-1 to k at index
    k-1. Hs, Rs: N entries, the measurement Jacobian (m_k, n) and noise covariance
    (m_k, m_k) at step k (None or m_k = 0: no measurement). P0 (n, n) prior covariance
    (J_0^-1; may be singular). Returns the bound (N, n, n) after the measurement of each
    step. Q and P0 are never inverted.
    """
    P0 = np.asarray(P0, dtype=np.float64)
    n = P0.shape[0] if P0.ndim == 2 else -1
    _check_square("P0", P0, n)
    N = len(Hs)
    if len(Rs) != N:
        raise ValueError(f"Rs: expected {N} entries (one per entry of Hs), found {len(Rs)}")
    Phi_a = np.asarray(Phis, dtype=np.float64).reshape(-1, n, n) if N > 1 else np.zeros((0, n, n))
    Q_a = np.asarray(Qs, dtype=np.float64).reshape(-1, n, n) if N > 1 else np.zeros((0, n, n))
    for name, a in (("Phis", Phi_a), ("Qs", Q_a)):
        if a.shape[0] != N - 1:
            raise ValueError(
                f"{name}: expected {N - 1} matrices (N - 1 for N entries of Hs), found {a.shape[0]}"
            )
    meas: list[tuple[F64, F64]] = []
    for k, (H, R) in enumerate(zip(Hs, Rs, strict=True)):
        if H is None or R is None or np.asarray(H).size == 0:
            meas.append((np.zeros((0, n)), np.zeros((0, 0))))
            continue
        H_a = np.atleast_2d(np.asarray(H, dtype=np.float64))
        R_a = np.atleast_2d(np.asarray(R, dtype=np.float64))
        if H_a.shape[1] != n:
            raise ValueError(f"Hs[{k}]: expected {n} columns, found shape {H_a.shape}")
        _check_square(f"Rs[{k}]", R_a, H_a.shape[0])
        meas.append((H_a, R_a))

    def propagate(k: int, P: F64) -> F64:
        Phi = Phi_a[k - 1]
        P = Phi @ P @ Phi.T + Q_a[k - 1]
        return 0.5 * (P + P.T)

    return _recursion(N, P0, propagate, lambda k: meas[k])


# --- along a flight -----------------------------------------------------------------------


def pcrb_layout(
    model: PcrbModel, *, air: bool = False, accel_bias: bool = False, mag_bias: bool = False
) -> Layout:
    """Error-state layout of the bound: "gravity" [att, bg] (+ ba), "ins" [att, v, bg]
    (+ wind with air data) (+ ba), then (+ bm); the order of the filters in
    :mod:`windahrs.filters.eskf`."""
    if model not in MODELS:
        raise ValueError(f"model: expected one of {MODELS}, found {model!r}")
    blocks = ["att", "bg"] if model == "gravity" else ["att", "v", "bg"]
    if air:
        if model != "ins":
            raise ValueError("air: expected False for the 'gravity' model (air data needs the 'ins' model)")
        blocks.append("wind")
    if accel_bias:
        blocks.append("ba")
    if mag_bias:
        blocks.append("bm")
    return Layout(tuple(blocks))


def _model_params(noise: PcrbNoise, dt: float, wind_noise: float, wind_noise_vertical: float) -> EskfParams:
    """The true noise as the shipped models' parameters: the process noise densities, the
    accelerometer's per-sample sigma ``accel / sqrt(dt)`` (dt the median IMU step), the
    other sensors' sigmas (the field's default for a sensor without noise, a placeholder
    inside the sensor's range: its stream is then not used, :func:`_positive`), the 3-D
    magnetometer, no preprocessing."""

    def sigma(v: float, name: str) -> float:
        return v if v > 0 else float(getattr(EskfParams, name))

    return EskfParams(
        gyro_noise=noise.gyro,
        gyro_bias_noise=noise.gyro_bias,
        accel_noise=noise.accel,
        accel_bias_noise=noise.accel_bias,
        mag_bias_noise=noise.mag_bias,
        wind_noise=wind_noise,
        wind_noise_vertical=wind_noise_vertical,
        wind_vertical=True,
        gyro_scale_noise=0.0,
        accel_sigma=sigma(noise.accel / math.sqrt(dt), "accel_sigma"),
        mag_sigma=sigma(noise.mag, "mag_sigma"),
        gnss_sigma=sigma(noise.gnss, "gnss_sigma"),
        tas_sigma=sigma(noise.tas, "tas_sigma"),
        vane_sigma=sigma(noise.vane, "vane_sigma"),
        mag_mode="3d",
        accel_compensation="none",
    )


def _truth_motion(truth: Truth, gravity_n: F64) -> tuple[F64, F64 | None, F64]:
    """True body rate (N, 3), specific force (N, 3) or None, and acceleration (N, 3)."""
    t = truth.t
    w_b = rates_from_attitude(t, truth.q_nb)
    if truth.v_n is None or len(t) < 2:
        return w_b, None, np.full((len(t), 3), np.nan)
    a_n = np.empty_like(truth.v_n)
    a_n[1:] = np.diff(truth.v_n, axis=0) / np.diff(t)[:, None]
    a_n[0] = a_n[1]
    return w_b, quat_rotate_inv(truth.q_nb, a_n - gravity_n), a_n


def _step_index(t_imu: F64, t_s: F64) -> NDArray[np.int64]:
    """IMU step of each sample: the last IMU time at or before it (-1: before the first)."""
    return np.searchsorted(t_imu, t_s, side="right").astype(np.int64) - 1


def _positive(name: str, value: float, stream: str) -> None:
    if not value > 0:
        raise ValueError(f"noise.{name}: expected > 0 to use the {stream} stream, found {value!r}")


def _choose(flag: bool | None, present: bool, name: str, model: str) -> bool:
    if flag is None:
        return present
    if flag and not present:
        raise ValueError(f"{name}: expected a flight with a {name} stream for model {model!r}, found none")
    return flag


def pcrb(
    flight: Flight,
    sensors: SensorSuite | PcrbNoise,
    *,
    model: PcrbModel,
    P0: F64 | None = None,
    sigma_att: float = 10.0 * DEG,
    sigma_bias: float | None = None,
    sigma_v: float = 1.0,
    sigma_wind: float = 5.0,
    sigma_accel_bias: float | None = None,
    mag: bool | None = None,
    gnss: bool | None = None,
    air: bool = False,
    accel_bias: bool | None = None,
    mag_bias: bool | None = None,
    sigma_mag_bias: float | None = None,
    wind_noise: float = 0.5,
    wind_noise_vertical: float = 0.3,
) -> PcrbResult:
    """The PCRB along ``flight.truth`` on the IMU grid (module docstring, SPEC 6.2).

    sensors: the simulator's SensorSuite or an explicit :class:`PcrbNoise`.

    model "gravity": error state [dtheta, dbg]; the accelerometer measures ``-C_bn g_n``
    at every IMU sample with R = (accel density)^2 / dt per axis (dt the median IMU step,
    as the simulator draws), the magnetometer ``C_bn m_n`` (3-D) with R = mag^2 per axis
    at its own times. Exact only for a truth without linear acceleration (``max_accel_n``
    in the result tells); with acceleration it is the bound of a model the truth does not
    obey, not a bound of the flight (SPEC 6.2: gusts then need their own states).
    GNSS and air data cannot be used (no velocity state).

    model "ins": [dtheta, dv, dbg]; the accelerometer is the input of the velocity (its
    density enters Q), GNSS velocity (R = gnss^2) and magnetometer are measurements. The
    bound depends on the trajectory only through the true rates and specific force, so
    the wind enters only through the motion it causes: a steady wind changes nothing,
    turbulence changes the specific force (in straight flight its accelerations help
    separate accelerometer bias from tilt, lowering the bound until a turn does that
    anyway). It is the physical limit of IMU + GNSS + magnetometer (SPEC 6.2).

    Accelerometer bias: ``accel_bias`` None adds ba states when the noise has a bias
    (random walk or initial spread), True/False forces it. Magnetometer bias (hard iron):
    ``mag_bias`` None adds bm states when the magnetometer is used and the noise has a
    bias, True/False forces it (False treats the hard iron as known: an optimistic bound
    when the simulation has one).

    air (model "ins" only): adds the air-data rows (pitot and vanes: the air-relative
    velocity ``C_bn (v_n - wind_n)`` with R = J diag(tas^2, vane^2, vane^2) J^T at the true
    airspeed, angle of attack and sideslip; pitot only: airspeed, R = tas^2) and wind
    states modelled as a random walk with densities ``wind_noise`` (horizontal) and
    ``wind_noise_vertical`` m/s^2/sqrt(Hz). Caution: Dryden turbulence is not a random
    walk, so this is the bound of the random-walk wind model, not of the simulated
    atmosphere; the honest physical limit of the sensor set is the "ins" bound without
    air data (SPEC 6.2). The synthetic zero sideslip is a modelling assumption, not a
    sensor, and is never used.

    mag, gnss: None uses the stream when the flight has it (GNSS only for "ins"); True
    requires it. Samples with NaN are skipped (as the filters skip them); a sample between
    IMU instants is fused at the last IMU instant before it (as the filters do).

    Prior: ``P0`` (n, n) in the layout's order (:func:`pcrb_layout`), or diagonal from
    sigma_att rad, sigma_bias rad/s (default ``gyro_bias_init``), sigma_v m/s,
    sigma_wind m/s, sigma_accel_bias m/s^2 (default ``accel_bias_init``),
    sigma_mag_bias tesla (default ``mag_bias_init``). Zero spreads are
    allowed (a state known exactly).
    """
    if model not in MODELS:
        raise ValueError(f"model: expected one of {MODELS}, found {model!r}")
    noise = PcrbNoise.from_suite(sensors) if isinstance(sensors, SensorSuite) else sensors
    if not isinstance(noise, PcrbNoise):
        raise TypeError(f"sensors: expected a SensorSuite or PcrbNoise, found {type(sensors).__name__}")
    truth = flight.truth
    if truth is None:
        raise ValueError("flight.truth: expected a simulation truth to evaluate the bound on, found None")
    t = flight.imu.t
    if not np.array_equal(truth.t, t):
        raise ValueError(
            f"flight.truth.t: expected the IMU time grid ({len(t)} samples), found a different grid "
            f"({len(truth.t)} samples)"
        )
    if len(t) < 2:
        raise ValueError(f"flight.imu.t: expected at least 2 samples, found {len(t)}")
    for name, value in (("wind_noise", wind_noise), ("wind_noise_vertical", wind_noise_vertical)):
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name}: expected a finite number >= 0, found {value!r}")

    use_mag = _choose(mag, flight.mag is not None, "mag", model)
    if model == "gravity":
        if gnss:
            raise ValueError("gnss: expected False or None for the 'gravity' model (no velocity state)")
        use_gnss = False
    else:
        use_gnss = _choose(gnss, flight.gnss is not None, "gnss", model)
    use_air = bool(air)
    if use_air:
        if model != "ins":
            raise ValueError("air: expected False for the 'gravity' model (air data needs the 'ins' model)")
        if flight.air is None:
            raise ValueError("air: expected a flight with an air-data stream, found none")
        if truth.wind_n is None:
            raise ValueError("flight.truth.wind_n: expected the true wind to use air data, found None")
    use_ba = noise.has_accel_bias if accel_bias is None else bool(accel_bias)
    use_bm = (noise.has_mag_bias if mag_bias is None else bool(mag_bias)) and use_mag
    if mag_bias and not use_mag:
        raise ValueError("mag_bias: expected False or None without the magnetometer")
    layout = pcrb_layout(model, air=use_air, accel_bias=use_ba, mag_bias=use_bm)

    g_n = flight.site.gravity_n
    w_b, f_b, a_n = _truth_motion(truth, g_n)
    if model == "ins" and (truth.v_n is None or f_b is None):
        raise ValueError("flight.truth.v_n: expected the true velocity for the 'ins' model, found None")
    dt_med = float(np.median(np.diff(t)))

    # Prior.
    if P0 is None:
        s_bg = noise.gyro_bias_init if sigma_bias is None else sigma_bias
        s_ba = noise.accel_bias_init if sigma_accel_bias is None else sigma_accel_bias
        s_bm = noise.mag_bias_init if sigma_mag_bias is None else sigma_mag_bias
        spreads = {"att": sigma_att, "v": sigma_v, "bg": s_bg, "wind": sigma_wind, "ba": s_ba, "bm": s_bm}
        d = np.zeros(layout.dim)
        for b in layout.blocks:
            s = spreads[b]
            if not (math.isfinite(s) and s >= 0):
                raise ValueError(f"initial spread of {b!r}: expected a finite number >= 0, found {s!r}")
            d[layout.sl(b)] = s**2
        P_init = np.diag(d)
    else:
        P_init = np.array(P0, dtype=np.float64)
        if P_init.shape != (layout.dim, layout.dim):
            raise ValueError(
                f"P0: expected shape ({layout.dim}, {layout.dim}) for states {layout.labels()}, "
                f"found {P_init.shape}"
            )
        if not np.isfinite(P_init).all() or not np.allclose(P_init, P_init.T):
            raise ValueError("P0: expected a finite symmetric matrix")

    # The shipped models with the true noise, linearised at the truth (biases 0).
    _positive("gyro", noise.gyro, "gyroscope (the prediction)")
    lin = Linearization(layout, _model_params(noise, dt_med, wind_noise, wind_noise_vertical), flight.site)
    v_true = truth.v_n if layout.has("v") else None
    w_true = truth.wind_n if layout.has("wind") else None

    def at(k: int) -> None:
        """The truth at IMU step k as the nominal state."""
        lin.set_state(
            truth.q_nb[k],
            v_n=None if v_true is None else v_true[k],
            wind_n=None if w_true is None else w_true[k],
        )

    # Measurements, grouped per IMU step.
    rows: list[list[tuple[F64, F64]]] = [[] for _ in range(len(t))]
    used: dict[str, int] = {}

    def attach(stream: str, t_s: F64, ok: ArrayLike, make: Callable[[int, int], tuple[F64, F64]]) -> None:
        idx = _step_index(t, t_s)
        take = np.flatnonzero(np.asarray(ok, dtype=bool) & (idx >= 0))
        for j in take:
            k = int(idx[j])
            at(k)
            rows[k].append(make(k, int(j)))
        used[stream] = len(take)

    sensors_used: list[str] = []
    if model == "gravity":
        _positive("accel", noise.accel, "accelerometer (gravity)")
        ok = np.isfinite(flight.imu.f_b).all(axis=1)
        attach("accel", t, ok, lambda k, j: lin.gravity())
        sensors_used.append("accel")
    if use_mag:
        assert flight.mag is not None
        _positive("mag", noise.mag, "magnetometer")
        if flight.site.mag_n is None:
            raise ValueError(
                "flight.site.mag_n: expected the Earth field to use the magnetometer, found None"
            )
        ok = np.isfinite(flight.mag.mag_b).all(axis=1)
        attach("mag", flight.mag.t, ok, lambda k, j: lin.mag())
        sensors_used.append("mag")
    if use_gnss:
        assert flight.gnss is not None
        _positive("gnss", noise.gnss, "GNSS")
        ok = np.isfinite(flight.gnss.v_n).all(axis=1)
        attach("gnss", flight.gnss.t, ok, lambda k, j: lin.gnss())
        sensors_used.append("gnss")
    if use_air:
        assert flight.air is not None and truth.v_n is not None and truth.wind_n is not None
        air_s = flight.air
        _positive("tas", noise.tas, "air-data")
        v_air_b = quat_rotate_inv(truth.q_nb, truth.v_n - truth.wind_n)
        tas, aoa, beta = air_data_from_velocity(v_air_b)
        if air_s.has_vanes:
            _positive("vane", noise.vane, "air-data (vanes)")

            def air_row(k: int, j: int) -> tuple[F64, F64]:
                return lin.air_vector(float(tas[k]), float(aoa[k]), float(beta[k]))

            assert air_s.aoa is not None and air_s.sideslip is not None
            ok = np.isfinite(air_s.tas) & np.isfinite(air_s.aoa) & np.isfinite(air_s.sideslip)
        else:

            def air_row(k: int, j: int) -> tuple[F64, F64]:
                return lin.tas(float(tas[k]))

            ok = np.isfinite(air_s.tas)
        attach("air", air_s.t, ok, air_row)
        sensors_used.append("air")

    def measurement(k: int) -> tuple[F64, F64]:
        r = rows[k]
        if not r:
            return np.zeros((0, layout.dim)), np.zeros((0, 0))
        if len(r) == 1:
            return r[0]
        return np.vstack([h for h, _ in r]), scipy.linalg.block_diag(*[R for _, R in r])

    f_in = f_b if f_b is not None else np.zeros((len(t), 3))
    dts = np.diff(t)

    def propagate(k: int, P: F64) -> F64:
        # Phi P Phi^T + Q from the truth at k-1; with the biases 0 the rate and specific
        # force are the true ones passed here.
        at(k - 1)
        return lin.predict(P, w_b[k], f_in[k], float(dts[k - 1]))

    cov = _recursion(len(t), P_init, propagate, measurement)
    return PcrbResult(
        t=t.copy(),
        cov=cov,
        cov_euler=_euler_cov(cov[:, layout.sl("att"), layout.sl("att")], truth.q_nb),
        labels=layout.labels(),
        model=model,
        sensors=tuple(sensors_used),
        used=used,
        runs=1,
        max_accel_n=float(np.max(np.linalg.norm(a_n, axis=1))) if np.isfinite(a_n).all() else math.nan,
    )


def _euler_cov(P_att: F64, q_nb: F64) -> F64:
    """``T P T^T`` (N, 3, 3) at the attitudes q_nb (N, 4) (SPEC 1.4)."""
    rpy = euler_from_quat(q_nb)
    T = euler_rate_map(rpy[:, 0], rpy[:, 1])
    return T @ P_att @ np.swapaxes(T, 1, 2)


def _information(cov: F64, what: str) -> F64:
    """Inverse of each (n, n) covariance of a stack, via Cholesky; a clear error when one is
    singular (a state known exactly has infinite information and cannot be averaged)."""
    out = np.empty_like(cov)
    eye = np.eye(cov.shape[1])
    for k in range(cov.shape[0]):
        try:
            out[k] = scipy.linalg.cho_solve(scipy.linalg.cho_factor(cov[k], lower=True), eye)
        except np.linalg.LinAlgError:
            raise ValueError(
                f"{what}: the bound at step {k} is singular (a state known exactly, e.g. a zero "
                "initial spread without process noise); give it a positive spread to average"
            ) from None
    return 0.5 * (out + np.swapaxes(out, 1, 2))


def pcrb_average(
    flights: Sequence[Flight],
    sensors: SensorSuite | PcrbNoise,
    *,
    model: PcrbModel,
    **options: object,
) -> PcrbResult:
    """The bound of a random scenario from Monte Carlo truths (SPEC 6.2: Tichavský's
    expectation over the trajectories).

    Each flight gives its bound P_k^(i) (:func:`pcrb`, same keyword options, e.g.
    ``sigma_att``, ``air``). The information is averaged per time step,
    ``J_k = mean_i (P_k^(i))^-1``, and the result is ``J_k^-1`` (full state; the Euler
    bound likewise from the per-run Euler covariances). By convexity of the inverse this
    is at most the mean of the per-run bounds. The flights must share the IMU grid length
    and the state layout; every per-run bound must be positive definite.
    """
    if len(flights) == 0:
        raise ValueError("flights: expected at least one flight, found none")
    results = [pcrb(fl, sensors, model=model, **options) for fl in flights]  # type: ignore[arg-type]
    first = results[0]
    for i, r in enumerate(results[1:], start=1):
        if r.cov.shape != first.cov.shape or r.labels != first.labels:
            raise ValueError(
                f"flights[{i}]: expected {first.cov.shape[0]} IMU samples and states {first.labels}, "
                f"found {r.cov.shape[0]} and {r.labels}"
            )
    J = np.mean([_information(r.cov, f"flights[{i}]") for i, r in enumerate(results)], axis=0)
    Je = np.mean([_information(r.cov_euler, f"flights[{i}] (Euler)") for i, r in enumerate(results)], axis=0)
    return PcrbResult(
        t=first.t,
        cov=_information(J, "averaged information"),
        cov_euler=_information(Je, "averaged information (Euler)"),
        labels=first.labels,
        model=first.model,
        sensors=first.sensors,
        used={k: sum(r.used.get(k, 0) for r in results) for k in first.used},
        runs=len(results),
        max_accel_n=max(r.max_accel_n for r in results),
    )


# --- efficiency ---------------------------------------------------------------------------


def efficiency_ratio(
    errors_deg: F64,
    pcrb_std_deg: F64,
    window: slice | NDArray[np.bool_] | NDArray[np.int64],
) -> F64:
    """RMSE / sqrt(PCRB) per axis (SPEC 6.2), (3,).

    errors_deg (runs, N, 3): estimate errors (e.g. body-frame ``Log(q_est^* q_true)`` in
    degrees); pcrb_std_deg (N, 3): the bound's standard deviation in the same
    coordinates; window: the time steps to average over (a slice, a boolean mask (N,) or
    indices), normally after convergence. Numerator: RMSE over all runs and the window;
    denominator: square root of the bound's variance averaged over the window. 1 means
    the estimator attains the bound.
    """
    e = np.asarray(errors_deg, dtype=np.float64)
    s = np.asarray(pcrb_std_deg, dtype=np.float64)
    if e.ndim != 3:
        raise ValueError(f"errors_deg: expected shape (runs, N, axes), found {e.shape}")
    if s.shape != e.shape[1:]:
        raise ValueError(f"pcrb_std_deg: expected shape {e.shape[1:]} to match errors_deg, found {s.shape}")
    ew, sw = e[:, window], s[window]
    if sw.shape[0] == 0:
        raise ValueError("window: expected at least one time step, found none")
    if not (np.isfinite(ew).all() and np.isfinite(sw).all()):
        raise ValueError("errors_deg, pcrb_std_deg: expected finite values in the window")
    rmse = np.sqrt(np.mean(ew**2, axis=(0, 1)))
    return rmse / np.sqrt(np.mean(sw**2, axis=0))


def reproduction_bound(flights: Sequence[Flight], model: str) -> F64 | None:
    """Body-axis attitude bound std (N, 3) in deg for ``windahrs reproduce``: the PCRB of
    the default sensor suite of the flights' scenario averaged over the Monte Carlo truths,
    with the filters' initial uncertainty (10 deg attitude, the datasheet's gyro-bias
    spread) and the suite's unknown constant biases (accelerometer, magnetometer hard
    iron) as states. "ins": IMU + GNSS velocity + magnetometer, no air data (the wind-free physical
    limit of the sensor set, SPEC 6.2); "gravity": IMU + magnetometer with the accelerometer
    as a gravity measurement (exact only without linear acceleration, so filters of that
    kind are measured against a bound their model cannot reach in gusts)."""
    from windahrs.sim.sensors import SensorSuite

    if model not in ("ins", "gravity"):
        return None
    suite = SensorSuite()
    options: dict[str, object] = {"sigma_att": float(np.radians(10.0)), "mag": True}
    if model == "ins":
        options.update(gnss=True, air=False)
    res = pcrb_average(flights, suite, model=model, **options)  # type: ignore[arg-type]
    return res.att_std_deg()
