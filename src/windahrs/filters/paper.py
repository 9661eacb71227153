"""The additive-quaternion family: the paper's EKF and the baselines it compares with.

* :class:`PaperEKF` ("paper"): the paper's 4-state EKF, faithful to its printed constants
  (eqs 6, 30-33) with every error of SPEC 8 corrected, fusing the normalised
  accelerometer, magnetometer and air-flow direction (SPEC 3.2.1, 3.1, 3.4.3).
* :class:`PaperEKFNoWind` ("paper-nowind"): the same filter without the air-data rows, the
  paper's "without considering wind".
* :class:`TraditionalEKF` ("ekf"): the accelerometer + magnetometer EKF of the paper's
  ref. [6], tuned from the sensor noise instead of the paper's constants.
* :class:`AdditiveUKF` ("ukf"): the additive-quaternion UKF of the paper's ref. [7]
  (SPEC 4.2), with a gyro-bias state.

All four hold the quaternion parameters themselves in the state; the math lives in
:mod:`windahrs.models.additive`. Shared rules (SPEC 2.3): innovation ``z - h(x)`` (never
the printed ``z - H x``), Joseph-form covariance update, normalisation of ``q`` after every
propagation and update with the covariance projected by the normalisation Jacobian.
Accelerometer, magnetometer and air-data rows are fused as separate sequential 3-row
updates when each sample arrives (the sensors run at different rates).
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
from abc import abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal, TypeVar

import numpy as np
from numpy.typing import NDArray

from windahrs.conventions import DEG, G0, UP_N
from windahrs.estimate import STATE_LABELS, Estimate
from windahrs.filters.base import (
    Estimator,
    InitialState,
    MissingSensorError,
    StateView,
    Streamer,
    merge_events,
    replay,
    triad,
)
from windahrs.flight import Flight, Site
from windahrs.models.additive import (
    Xi,
    att_cov_from_quat_cov,
    ekf7_process_noise,
    normalization_jacobian,
    quat_cov_from_att_cov,
    transition_exact,
    transition_picard4,
    vector_obs,
    vector_obs_jacobian,
)
from windahrs.rotation import (
    air_direction,
    quat_exp,
    quat_identity,
    quat_mul,
    quat_normalize,
    quat_rotate_inv,
)

__all__ = [
    "AdditiveUKF",
    "AdditiveUKFParams",
    "PaperEKF",
    "PaperEKFNoWind",
    "PaperNoWindParams",
    "PaperParams",
    "TraditionalEKF",
    "TraditionalEKFParams",
    "WindProvider",
]

F64 = NDArray[np.float64]

#: The wind (velocity of the air, NED, m/s) at a time (s): what the paper's filter "knows".
WindProvider = Callable[[float], F64]

_P = TypeVar("_P")

InitMode = Literal["paper", "triad"]
WindMode = Literal["oracle", "mean"]

#: Below this air-relative speed (m/s) the air-flow direction is noise, so the row is not
#: fused (counted in the Estimate's meta).
_MIN_AIR_SPEED = 0.5

_QUAT_LABELS = STATE_LABELS["quat"]
_ATT_LABELS = STATE_LABELS["att"]
_ATT_BG_LABELS = STATE_LABELS["att"] + STATE_LABELS["bg"]


# --- parameters ------------------------------------------------------------------------


def _bad(obj: object, name: str, expected: str) -> ValueError:
    found = getattr(obj, name)
    return ValueError(f"{type(obj).__name__}.{name}: expected {expected}, found {found!r}")


def _check_number(obj: object, name: str, *, positive: bool) -> None:
    v = getattr(obj, name)
    ok = isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v)
    if not ok or (v <= 0 if positive else v < 0):
        raise _bad(obj, name, "a finite number " + ("> 0" if positive else ">= 0"))


def _check_choice(obj: object, name: str, choices: tuple[str, ...]) -> None:
    if getattr(obj, name) not in choices:
        raise _bad(obj, name, "one of " + ", ".join(repr(c) for c in choices))


@dataclass(frozen=True)
class PaperNoWindParams:
    """Constants of the paper's filter (SPEC 7.1), per IMU step at 200 Hz.

    init: "paper" starts from ``q0 = [1, 0, 0, 0]`` (eq. 30); "triad" from the first
    accelerometer and magnetometer samples (what the paper's text says instead, T29).
    p0_var: initial variance of each quaternion parameter (eq. 31), 1.
    process_var: variance added to each quaternion parameter per IMU step (eq. 32), 1.
    acc_var, mag_var: variance of each component of the normalised accelerometer and
    magnetometer vectors (eq. 33), 1.
    """

    init: InitMode = "paper"
    p0_var: float = 0.2846
    process_var: float = 0.02
    acc_var: float = 10.0
    mag_var: float = 20.0

    def __post_init__(self) -> None:
        _check_choice(self, "init", ("paper", "triad"))
        for name in ("p0_var", "process_var", "acc_var", "mag_var"):
            _check_number(self, name, positive=True)


@dataclass(frozen=True)
class PaperParams(PaperNoWindParams):
    """The paper's constants (see :class:`PaperNoWindParams`) plus its air-data row.

    air_var: variance of each component of the air-flow direction; the paper gives none
    (its R is 6x6 for 9 rows, T31), 20 like the magnetometer's is this library's choice.
    wind: how the filter "knows" the wind, which the paper assumes known without saying
    how: "oracle" is the instantaneous TRUE wind of a simulation (an oracle no real
    vehicle has; it reproduces the paper's claim, SPEC 7.4), "mean" a constant wind:
    ``mean_wind_n`` or, when None, the time mean of the flight's truth (or reference)
    wind. mean_wind_n: (north, east, down) m/s or None. gnss_max_age: s, a GNSS velocity
    older than this is not used for the air-flow row.
    """

    air_var: float = 20.0
    wind: WindMode = "oracle"
    mean_wind_n: tuple[float, float, float] | None = None
    gnss_max_age: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_number(self, "air_var", positive=True)
        _check_number(self, "gnss_max_age", positive=True)
        _check_choice(self, "wind", ("oracle", "mean"))
        m = self.mean_wind_n
        if m is not None:
            ok = isinstance(m, tuple | list) and len(m) == 3
            if not ok or not np.isfinite(np.asarray(m, dtype=np.float64)).all():
                raise _bad(self, "mean_wind_n", "None or 3 finite numbers (north, east, down) m/s")
            object.__setattr__(self, "mean_wind_n", tuple(float(v) for v in m))


@dataclass(frozen=True)
class TraditionalEKFParams:
    """Physical noise of an MPU-9150-class IMU and magnetometer (SPEC 5.4).

    gyro_noise: gyro white-noise density, rad/s/sqrt(Hz). accel_noise: accelerometer
    white-noise density, m/s^2/sqrt(Hz). accel_sigma_unit: extra standard deviation of
    the normalised accelerometer (1, per axis), an allowance for the unmodelled vehicle
    acceleration. mag_noise: magnetometer noise per axis per sample, tesla.
    mag_sigma_unit: extra standard deviation of the normalised magnetometer (1), an
    allowance for residual hard iron. sigma_att0: initial attitude standard deviation per
    axis, rad (after TRIAD).
    """

    gyro_noise: float = 0.005 * DEG
    accel_noise: float = 400e-6 * G0
    accel_sigma_unit: float = 0.05
    mag_noise: float = 0.5e-6
    mag_sigma_unit: float = 0.01
    sigma_att0: float = 10.0 * DEG

    def __post_init__(self) -> None:
        for name in ("gyro_noise", "accel_noise", "mag_noise", "sigma_att0"):
            _check_number(self, name, positive=True)
        for name in ("accel_sigma_unit", "mag_sigma_unit"):
            _check_number(self, name, positive=False)


@dataclass(frozen=True)
class AdditiveUKFParams(TraditionalEKFParams):
    """Noise as :class:`TraditionalEKFParams`, plus the bias state and the sigma points.

    gyro_bias_rw: gyro-bias random-walk density, rad/s^2/sqrt(Hz). sigma_bias0: initial
    bias standard deviation per axis, rad/s. alpha, beta, kappa: scaled unscented
    transform on the 7-vector ``[q; b]``, ``lambda = alpha^2 (7 + kappa) - 7``; the
    defaults give SPEC 4.1's ``lambda = 1`` with equal mean and covariance weights.
    """

    gyro_bias_rw: float = 1e-5
    sigma_bias0: float = 0.5 * DEG
    alpha: float = 1.0
    beta: float = 0.0
    kappa: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_number(self, "gyro_bias_rw", positive=True)
        _check_number(self, "sigma_bias0", positive=True)
        _check_number(self, "beta", positive=False)
        _check_number(self, "alpha", positive=True)
        if self.alpha > 1.0:
            raise _bad(self, "alpha", "a number in (0, 1]")
        k = self.kappa
        if isinstance(k, bool) or not isinstance(k, int | float) or not np.isfinite(k) or k <= -7:
            raise _bad(self, "kappa", "a finite number > -7 (7 + kappa > 0)")


def _params_from_toml(params_type: type[_P], path: str | os.PathLike[str]) -> _P:
    """Parameters from a TOML file holding one ``[windahrs]`` table of our field names
    (the PX4 / ArduPilot tables of the error-state filters have no meaning here)."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text())
    except FileNotFoundError:
        raise ValueError(f"{p}: no such parameter file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{p}: not valid TOML ({exc})") from None
    other = sorted(set(data) - {"windahrs"})
    if other:
        raise ValueError(f"{p}: expected only a [windahrs] table, found [{other[0]}]")
    table: dict[str, Any] = dict(data.get("windahrs", {}))
    known = {f.name for f in dataclasses.fields(params_type)}  # type: ignore[arg-type]
    unknown = sorted(set(table) - known)
    if unknown:
        raise ValueError(
            f"{p}: [windahrs].{unknown[0]}: expected one of {', '.join(sorted(known))}, found an unknown key"
        )
    if isinstance(table.get("mean_wind_n"), list):
        table["mean_wind_n"] = tuple(table["mean_wind_n"])
    return params_type(**table)


# --- shared machinery ------------------------------------------------------------------


class _AdditiveStreamer(Streamer):
    """Shared part of the additive-quaternion filters.

    State ``x`` (n,) starts with the quaternion ``q_nb`` (4,), covariance ``P`` (n, n) on
    the parameters. Subclasses provide the propagation, the noise and the report; this
    class does the initialisation (fixed, or TRIAD from the first accelerometer and
    magnetometer samples), the magnetometer reference, and the EKF vector update.
    """

    def __init__(
        self,
        filter_name: str,
        site: Site,
        *,
        has: frozenset[str],
        n: int,
        q_start: F64 | None,
    ) -> None:
        super().__init__(filter_name)
        self._site = site
        self._has = has
        self._n = n
        self._q_start = q_start
        self._x = np.zeros(n)
        self._x[0] = 1.0
        self._P = np.eye(n)
        self._ready = False
        self._t_imu: float | None = None
        self._t_state = -np.inf
        self._dt = 0.0
        self._f_b: F64 | None = None
        self._mag_ref: F64 | None = None
        self._mag_norm = 0.0
        if site.mag_n is not None:
            self._mag_norm = float(np.linalg.norm(site.mag_n))
            self._mag_ref = site.mag_n / self._mag_norm
        #: Samples that could not be fused (no reference yet, no GNSS, ...), by reason.
        self.unfused: dict[str, int] = {}

    # subclass hooks ---------------------------------------------------------------------

    @abstractmethod
    def _initial_x_P(self, q: F64) -> tuple[F64, F64]: ...

    @abstractmethod
    def _predict(self, w_b: F64, dt: float) -> None: ...

    @abstractmethod
    def _acc_cov(self) -> F64: ...

    @abstractmethod
    def _mag_cov(self) -> F64: ...

    @abstractmethod
    def _report(self) -> tuple[F64 | None, F64, tuple[str, ...]]:
        """(gyro bias or None, covariance, labels) for the StateView."""

    # common -----------------------------------------------------------------------------

    def _count(self, reason: str) -> None:
        self.unfused[reason] = self.unfused.get(reason, 0) + 1

    def _start(self, q: F64) -> None:
        self._x, self._P = self._initial_x_P(quat_normalize(q))
        self._ready = True

    def _normalize(self) -> None:
        """``q <- q/|q|`` (w >= 0) and ``P <- J P J^T`` with the normalisation Jacobian."""
        q = self._x[:4]
        J = np.eye(self._n)
        J[:4, :4] = normalization_jacobian(q)
        # The sign flip to w >= 0 leaves P unchanged (it is J -> -J on both sides).
        self._x[:4] = q * (np.copysign(1.0, q[0]) / np.sqrt(q @ q))
        P = J @ self._P @ J.T
        self._P = 0.5 * (P + P.T)

    def _imu(self, t: float, w_b: F64, f_b: F64) -> None:
        first = self._t_imu is None
        dt = 0.0 if self._t_imu is None else t - self._t_imu
        self._t_imu = t
        self._f_b = f_b
        self._t_state = t
        if first:
            # The first sample only initialises: its rate belongs to the interval before it.
            if self._q_start is not None:
                self._start(self._q_start)
            elif "mag" not in self._has:
                self._start(triad(f_b, None, None))
            return
        if not self._ready:
            return  # TRIAD still waits for its magnetometer sample
        self._dt = dt
        self._predict(w_b, dt)
        self._normalize()
        # A resting accelerometer reads "up" (-g in NED is [0, 0, -1] after normalising).
        z = f_b / np.linalg.norm(f_b)
        self._update_vector("acc", t, z, UP_N, self._acc_cov())

    def _mag(self, t: float, mag_b: F64) -> None:
        if self._f_b is None:
            self._count("mag_before_imu")
            return
        norm = float(np.linalg.norm(mag_b))
        if self._mag_ref is None:
            # Unknown site field: the horizontal field is north, the dip is measured here
            # against the accelerometer's down direction.
            down_b = -self._f_b / np.linalg.norm(self._f_b)
            s = float(np.clip(mag_b @ down_b / norm, -1.0, 1.0))
            self._mag_ref = np.array([np.sqrt(1.0 - s * s), 0.0, s])
            self._mag_norm = norm
        if not self._ready:
            self._start(triad(self._f_b, mag_b, self._site.mag_n))
            return  # this sample made the initial attitude; fusing it again would reuse it
        self._update_vector("mag", t, mag_b / norm, self._mag_ref, self._mag_cov())

    def _update_vector(self, sensor: str, t: float, z: F64, r_n: F64, R: F64) -> None:
        """EKF update with ``z = C_bn r_n + v``, innovation ``z - h(x)``, Joseph form."""
        q = self._x[:4]
        H = np.zeros((3, self._n))
        H[:, :4] = vector_obs_jacobian(q, r_n)
        nu = z - vector_obs(q, r_n)
        P = self._P
        PHt = P @ H.T
        S_inv = np.linalg.inv(H @ PHt + R)
        K = PHt @ S_inv
        self._x = self._x + K @ nu
        A = np.eye(self._n) - K @ H
        self._P = A @ P @ A.T + K @ R @ K.T
        self._normalize()
        self._log(sensor, t, nu, float(nu @ S_inv @ nu), True)
        self._t_state = t

    @property
    def state(self) -> StateView:
        if self._ready:
            q = self._x[:4].copy()
        elif self._f_b is not None:
            q = triad(self._f_b, None, None)
        else:
            q = quat_identity()
        bias, cov, labels = self._report()
        return StateView(
            t=float(self._t_state),
            q_nb=q,
            gyro_bias_b=bias,
            v_n=None,
            wind_n=None,
            cov=cov,
            state_labels=labels,
        )


class _PaperStreamer(_AdditiveStreamer):
    """The paper's 4-state filter: Picard-4 transition, constant per-step Q, constant R."""

    def __init__(
        self,
        filter_name: str,
        site: Site,
        params: PaperNoWindParams,
        *,
        has: frozenset[str],
        initial: InitialState | None,
        wind: WindProvider | None,
    ) -> None:
        q_start: F64 | None = None
        if initial is not None:
            q_start = np.asarray(initial.q_nb, dtype=np.float64)
        elif params.init == "paper":
            q_start = quat_identity()
        super().__init__(filter_name, site, has=has, n=4, q_start=q_start)
        self._p = params
        self._sigma_att0 = None if initial is None else initial.sigma_att
        self._wind = wind
        self._v_n: F64 | None = None
        self._t_gnss = -np.inf

    def _initial_x_P(self, q: F64) -> tuple[F64, F64]:
        if self._sigma_att0 is not None:
            return q.copy(), quat_cov_from_att_cov(q, self._sigma_att0**2 * np.eye(3))
        return q.copy(), self._p.p0_var * np.eye(4)

    def _predict(self, w_b: F64, dt: float) -> None:
        # The paper's filter has no bias state: the raw gyro drives eq. 6.
        Phi = transition_picard4(w_b * dt)
        self._x = Phi @ self._x
        self._P = Phi @ self._P @ Phi.T + self._p.process_var * np.eye(4)

    def _acc_cov(self) -> F64:
        return self._p.acc_var * np.eye(3)

    def _mag_cov(self) -> F64:
        return self._p.mag_var * np.eye(3)

    def _report(self) -> tuple[F64 | None, F64, tuple[str, ...]]:
        return None, self._P.copy(), _QUAT_LABELS

    def _gnss(self, t: float, v_n: F64) -> None:
        self._v_n = v_n.copy()
        self._t_gnss = t

    def _air(self, t: float, tas: float, aoa: float, sideslip: float) -> None:
        p = self._p
        if not isinstance(p, PaperParams) or self._wind is None:
            return
        if not (np.isfinite(aoa) and np.isfinite(sideslip)):
            self.skipped["air"] += 1
            return
        if not self._ready:
            self._count("air_before_init")
            return
        if self._v_n is None or t - self._t_gnss > p.gnss_max_age:
            self._count("air_no_gnss")
            return
        u = self._v_n - self._wind(t)
        speed = float(np.linalg.norm(u))
        if speed < _MIN_AIR_SPEED:
            self._count("air_slow")
            return
        R = p.air_var * np.eye(3)
        self._update_vector("air", t, air_direction(aoa, sideslip), u / speed, R)


class _TraditionalStreamer(_AdditiveStreamer):
    """4-state EKF with the exact transition and noise from the sensor densities."""

    def __init__(
        self,
        filter_name: str,
        site: Site,
        params: TraditionalEKFParams,
        *,
        has: frozenset[str],
        initial: InitialState | None,
        n: int = 4,
    ) -> None:
        q_start = None if initial is None else np.asarray(initial.q_nb, dtype=np.float64)
        super().__init__(filter_name, site, has=has, n=n, q_start=q_start)
        self._p = params
        self._sigma_att0 = params.sigma_att0
        if initial is not None and initial.sigma_att is not None:
            self._sigma_att0 = initial.sigma_att

    def _initial_x_P(self, q: F64) -> tuple[F64, F64]:
        return q.copy(), quat_cov_from_att_cov(q, self._sigma_att0**2 * np.eye(3))

    def _predict(self, w_b: F64, dt: float) -> None:
        Phi = transition_exact(w_b * dt)
        q = Phi @ self._x
        X = Xi(q)
        self._x = q
        # SPEC 2.3 Q_d,qq with sigma_b = 0: the gyro white noise, rank 3.
        Q = (self._p.gyro_noise**2 * dt / 4.0) * (X @ X.T)
        self._P = Phi @ self._P @ Phi.T + Q

    def _acc_cov(self) -> F64:
        p = self._p
        # Per-sample noise sigma_c / sqrt(dt) (Kalibr), divided by |f| = g for the unit vector.
        sigma_white = p.accel_noise / np.sqrt(max(self._dt, 1e-6)) / self._site.gravity
        return (sigma_white**2 + p.accel_sigma_unit**2) * np.eye(3)

    def _mag_cov(self) -> F64:
        p = self._p
        return ((p.mag_noise / self._mag_norm) ** 2 + p.mag_sigma_unit**2) * np.eye(3)

    def _report(self) -> tuple[F64 | None, F64, tuple[str, ...]]:
        q = self._x[:4]
        return None, att_cov_from_quat_cov(q, self._P[:4, :4]), _ATT_LABELS


class _UKFStreamer(_TraditionalStreamer):
    """Additive-quaternion UKF on ``[q; b_g]`` (SPEC 4.2)."""

    def __init__(
        self,
        filter_name: str,
        site: Site,
        params: AdditiveUKFParams,
        *,
        has: frozenset[str],
        initial: InitialState | None,
    ) -> None:
        super().__init__(filter_name, site, params, has=has, initial=initial, n=7)
        self._u = params
        self._b0 = np.zeros(3)
        self._sigma_b0 = params.sigma_bias0
        if initial is not None:
            if initial.gyro_bias_b is not None:
                self._b0 = np.asarray(initial.gyro_bias_b, dtype=np.float64).copy()
            if initial.sigma_bias is not None:
                self._sigma_b0 = initial.sigma_bias
        n = 7
        lam = params.alpha**2 * (n + params.kappa) - n
        self._spread = n + lam
        self._wm = np.full(2 * n + 1, 0.5 / (n + lam))
        self._wm[0] = lam / (n + lam)
        self._wc = self._wm.copy()
        self._wc[0] += 1.0 - params.alpha**2 + params.beta

    def _initial_x_P(self, q: F64) -> tuple[F64, F64]:
        P = np.zeros((7, 7))
        P[:4, :4] = quat_cov_from_att_cov(q, self._sigma_att0**2 * np.eye(3))
        P[4:, 4:] = self._sigma_b0**2 * np.eye(3)
        return np.concatenate([q, self._b0]), P

    def _sigma_points(self) -> F64:
        """(15, 7) points ``x, x +- columns of sqrt((n + lambda) P)``."""
        P = 0.5 * (self._P + self._P.T)
        # P is singular along q (projected), so a PSD square root instead of Cholesky.
        w, V = np.linalg.eigh(self._spread * P)
        S = V * np.sqrt(np.clip(w, 0.0, None))
        return np.vstack([self._x, self._x + S.T, self._x - S.T])

    def _predict(self, w_b: F64, dt: float) -> None:
        X = self._sigma_points()
        dtheta = (w_b - X[:, 4:]) * dt
        # q * Exp(dtheta) is transition_exact(dtheta) @ q, for all points at once.
        q = quat_mul(X[:, :4], quat_exp(dtheta))
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        q[q @ q[0] < 0.0] *= -1.0  # one hemisphere, the centre point's
        X = np.hstack([q, X[:, 4:]])
        x = self._wm @ X
        D = X - x
        P = (D.T * self._wc) @ D
        J = np.eye(7)
        J[:4, :4] = normalization_jacobian(x[:4])
        x[:4] = x[:4] / np.linalg.norm(x[:4])
        p = self._u
        self._x = x
        self._P = J @ P @ J.T + ekf7_process_noise(x[:4], p.gyro_noise, p.gyro_bias_rw, dt)

    def _update_vector(self, sensor: str, t: float, z: F64, r_n: F64, R: F64) -> None:
        X = self._sigma_points()
        q = X[:, :4] / np.linalg.norm(X[:, :4], axis=1, keepdims=True)
        Y = quat_rotate_inv(q, r_n)
        y = self._wm @ Y
        dY = Y - y
        dX = X - self._x
        Pyy = (dY.T * self._wc) @ dY + R
        Pxy = (dX.T * self._wc) @ dY
        K = np.linalg.solve(Pyy, Pxy.T).T
        nu = z - y
        self._x = self._x + K @ nu
        self._P = self._P - K @ Pyy @ K.T
        self._normalize()
        self._log(sensor, t, nu, float(nu @ np.linalg.solve(Pyy, nu)), True)
        self._t_state = t

    def _report(self) -> tuple[F64 | None, F64, tuple[str, ...]]:
        q = self._x[:4]
        T = np.zeros((6, 7))
        T[:3, :4] = 2.0 * Xi(q).T  # dtheta ~ 2 Xi^T dq (SPEC 2.3)
        T[3:, 4:] = np.eye(3)
        return self._x[4:].copy(), T @ self._P @ T.T, _ATT_BG_LABELS


# --- estimators ------------------------------------------------------------------------


class PaperEKFNoWind(Estimator):
    """The paper's EKF "without considering wind": accelerometer and magnetometer only.

    4 states (the quaternion; no gyro bias, T7), Picard-4 transition with the raw gyro
    (eq. 6), the paper's q0, P0, Q, R (eqs 30-33, :class:`PaperNoWindParams`), normalised
    vectors (T11, T12), innovation ``z - h(x)`` (T26), Joseph form, normalisation with
    covariance projection. The covariance is reported on the quaternion parameters (4x4,
    labels q_w..q_z): this filter is 4x4 by definition, and its P (tens of degrees) is not
    consistent with its errors (SPEC 6.3), so score it by RMSE only.
    """

    name: ClassVar[str] = "paper-nowind"
    requires: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})
    uses: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})

    def __init__(self, params: PaperNoWindParams | None = None) -> None:
        self.params = PaperNoWindParams() if params is None else params

    @classmethod
    def load_params(cls, path: str | os.PathLike[str]) -> PaperNoWindParams:
        """PaperNoWindParams from a TOML file with a ``[windahrs]`` table of its field names."""
        return _params_from_toml(PaperNoWindParams, path)

    def streamer(
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> Streamer:
        """A streaming instance; ``has`` empty means every stream the filter uses."""
        return _PaperStreamer(self.name, site, self.params, has=has or self.uses, initial=initial, wind=None)


class PaperEKF(Estimator):
    """The paper's EKF "considering wind" (SPEC 7.3 (ii)): :class:`PaperEKFNoWind` plus the
    air-flow direction row (SPEC 3.4.3).

    Air data: ``z = d(alpha_m, beta_m) = [cos a cos b, sin b, sin a cos b]`` from the
    vanes, ``h = C_bn u``, ``u = (V_n - W_n)/|V_n - W_n|`` with ``V_n`` the latest GNSS
    velocity and ``W_n`` the wind the filter is given (``params.wind``):

    * "oracle": the instantaneous TRUE wind of the simulation at the air-data time. No
      real vehicle knows it; it is what the paper implicitly assumes and what reproduces
      its claim (SPEC 7.4). Needs a Flight with truth.
    * "mean": a constant wind, ``params.mean_wind_n`` or the flight's time-mean truth (or
      reference) wind; gusts then corrupt the row (SPEC 3.4.3).

    R of the air row is ``air_var`` (20) per component: the paper does not give it (T31).
    Needs vanes (angle of attack and sideslip) and GNSS velocity. Air samples without a
    recent GNSS velocity or below 0.5 m/s air-relative speed are not fused; their counts
    are in ``Estimate.meta`` (keys ``unfused_*``).
    """

    name: ClassVar[str] = "paper"
    requires: ClassVar[frozenset[str]] = frozenset({"imu", "mag", "gnss", "air"})
    uses: ClassVar[frozenset[str]] = frozenset({"imu", "mag", "gnss", "air"})

    def __init__(self, params: PaperParams | None = None) -> None:
        self.params = PaperParams() if params is None else params

    @classmethod
    def load_params(cls, path: str | os.PathLike[str]) -> PaperParams:
        """PaperParams from a TOML file with a ``[windahrs]`` table of its field names."""
        return _params_from_toml(PaperParams, path)

    def check(self, flight: Flight) -> None:
        if flight.air is None or not flight.air.has_vanes:
            found = "no air data" if flight.air is None else "air data without vanes (pitot only)"
            raise MissingSensorError(
                self.name,
                "air",
                f": the air-flow direction needs vanes (angle of attack and sideslip), found {found}",
            )
        super().check(flight)

    def wind_provider(self, flight: Flight) -> WindProvider:
        """The wind ``t -> wind_n`` (3,) m/s NED that ``params.wind`` gives for ``flight``.

        ValueError when the flight cannot provide it ("oracle" without truth, "mean"
        without ``mean_wind_n``, truth wind or reference wind).
        """
        p = self.params
        tr = flight.truth
        if p.wind == "oracle":
            if tr is None or tr.wind_n is None:
                raise ValueError(
                    "PaperParams.wind: expected a flight with simulation truth for the 'oracle' "
                    "wind (the oracle needs flight.truth.wind_n), found none; use wind='mean' "
                    "with mean_wind_n for real data"
                )
            t_tr, w_tr = tr.t, tr.wind_n

            def oracle(t: float) -> F64:
                return np.array([np.interp(t, t_tr, w_tr[:, i]) for i in range(3)])

            return oracle
        if p.mean_wind_n is not None:
            mean = np.array(p.mean_wind_n)
        elif tr is not None and tr.wind_n is not None:
            mean = tr.wind_n.mean(axis=0)
        elif flight.ref_wind is not None and np.isfinite(flight.ref_wind.wind_n).all(1).any():
            mean = np.nanmean(flight.ref_wind.wind_n, axis=0)
        else:
            raise ValueError(
                "PaperParams.mean_wind_n: expected a mean wind (or a flight with truth or "
                "reference wind to average), found None and neither in the flight"
            )

        def constant(t: float) -> F64:
            return mean.copy()

        return constant

    def streamer(
        self,
        site: Site,
        *,
        initial: InitialState | None = None,
        has: frozenset[str] = frozenset(),
        wind: WindProvider | None = None,
    ) -> Streamer:
        """A streaming instance. ``has`` empty means every stream the filter uses.
        ``wind``: the wind provider (see :meth:`wind_provider`); it may be omitted only for
        ``wind="mean"`` with ``mean_wind_n`` set, or when no air data will be fed."""
        has = has or self.uses
        p = self.params
        if wind is None and p.wind == "mean" and p.mean_wind_n is not None:
            mean = np.array(p.mean_wind_n)

            def constant(t: float) -> F64:
                return mean.copy()

            wind = constant
        if wind is None and "air" in has:
            raise ValueError(
                "wind: expected a wind provider (t -> wind_n) for the air-flow row, found None; "
                "build one with PaperEKF.wind_provider(flight)"
            )
        return _PaperStreamer(self.name, site, p, has=has, initial=initial, wind=wind)

    def run(self, flight: Flight, *, initial: InitialState | None = None) -> Estimate:
        """Estimate the whole flight (replays it through :meth:`streamer`)."""
        self.check(flight)
        wind = self.wind_provider(flight)
        has = self.uses & frozenset(flight.streams())
        t_ev, kinds, vals = merge_events(flight, has)
        s = self.streamer(flight.site, initial=initial, has=has, wind=wind)
        est = replay(self, s, flight, t_ev, kinds, vals)
        meta = dict(est.meta)
        meta["wind"] = self.params.wind
        if isinstance(s, _PaperStreamer):
            for reason, count in sorted(s.unfused.items()):
                meta[f"unfused_{reason}"] = count
        return dataclasses.replace(est, meta=meta)


class TraditionalEKF(Estimator):
    """The traditional accelerometer + magnetometer EKF the paper compares with (ref. [6]).

    4 states (the quaternion, no gyro bias), exact transition, process noise from the
    gyro noise density (SPEC 2.3 ``Q_d,qq`` with ``sigma_b = 0``), normalised vectors with
    R from the sensor noise (``sigma/|m|`` plus the allowances of
    :class:`TraditionalEKFParams`), TRIAD initialisation. An uncompensated gyro bias is
    integrated into the attitude: this filter trusts its gyro as the datasheet says.
    Covariance reported as the body-frame attitude error (att_x..att_z), rad^2.
    """

    name: ClassVar[str] = "ekf"
    requires: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})
    uses: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})

    def __init__(self, params: TraditionalEKFParams | None = None) -> None:
        self.params = TraditionalEKFParams() if params is None else params

    @classmethod
    def load_params(cls, path: str | os.PathLike[str]) -> TraditionalEKFParams:
        """TraditionalEKFParams from a TOML file with a ``[windahrs]`` table of its field names."""
        return _params_from_toml(TraditionalEKFParams, path)

    def streamer(
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> Streamer:
        """A streaming instance; ``has`` empty means every stream the filter uses."""
        return _TraditionalStreamer(self.name, site, self.params, has=has or self.uses, initial=initial)


class AdditiveUKF(Estimator):
    """The additive-quaternion UKF the paper compares with (ref. [7], SPEC 4.2).

    State ``[q; b_g]`` (7); sigma points on the 7-vector (scaled unscented transform),
    each propagated quaternion normalised and flipped to the centre point's hemisphere,
    weighted mean renormalised (covariance projected as in the EKF); process noise of
    SPEC 2.3; accelerometer and magnetometer as normalised vectors as in
    :class:`TraditionalEKF`; TRIAD initialisation. Reports the gyro bias and the
    covariance in the tangent space (att_x.., bg_x..): ``P_dtheta = 4 Xi^T P_qq Xi``.
    """

    name: ClassVar[str] = "ukf"
    requires: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})
    uses: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})

    def __init__(self, params: AdditiveUKFParams | None = None) -> None:
        self.params = AdditiveUKFParams() if params is None else params

    @classmethod
    def load_params(cls, path: str | os.PathLike[str]) -> AdditiveUKFParams:
        """AdditiveUKFParams from a TOML file with a ``[windahrs]`` table of its field names."""
        return _params_from_toml(AdditiveUKFParams, path)

    def streamer(
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> Streamer:
        """A streaming instance; ``has`` empty means every stream the filter uses."""
        return _UKFStreamer(self.name, site, self.params, has=has or self.uses, initial=initial)
