"""[ekf7]: the 7-state additive-quaternion EKF ``x = [q; b_g]`` (SPEC 2.3), the paper's
filter made consistent with its abstract: exact transition, process noise derived from the
gyro noise, innovations ``z - h(x)``, Joseph form, normalisation with covariance projection.
[ekf10]: the same plus wind states ``W_n`` fusing air data (SPEC 2.6), the paper's idea
with the wind estimated instead of given.

It shares the sensor handling of the error-state filters (initialisation, accelerometer
gating, magnetometer reference, innovation logging) and differs only in its state
parameterisation: the covariance is 7x7 on ``[q; b]``. Measurement Jacobians on ``q`` are
``2 H_dtheta Xi(q)^T``, which equals SPEC 3.1's additive Jacobian on the tangent space of
the unit sphere (its component along ``q`` meets no covariance after projection; tested).
The Estimate reports the tangent covariance ``T P T^T``, ``T = blkdiag(2 Xi^T, I)``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from windahrs.filters.base import InitialState
from windahrs.filters.eskf import EskfStreamer, Kind, _EskfEstimator
from windahrs.filters.params import EskfParams
from windahrs.flight import Site
from windahrs.models.additive import (
    Xi,
    ekf7_jacobian,
    ekf7_process_noise,
    normalization_jacobian,
    quat_cov_from_att_cov,
    transition_exact,
)
from windahrs.models.error_state import NominalState

__all__ = ["Ekf7", "Ekf7Streamer", "Ekf10"]

F64 = NDArray[np.float64]


class Ekf7Streamer(EskfStreamer):
    """The additive-quaternion EKF fed sample by sample: covariance on ``[q (4), rest]``
    where "rest" are the error-state blocks after the attitude (bias, wind)."""

    additive = True

    def __init__(
        self,
        name: str,
        kind: Kind,
        params: EskfParams,
        site: Site,
        initial: InitialState | None,
        has: frozenset[str],
    ) -> None:
        super().__init__(name, kind, params, site, initial, has)
        self.n = self.layout.dim + 1

    def _try_init(self) -> None:
        was = self.x is None
        super()._try_init()
        if was and self.x is not None:
            P = np.zeros((self.n, self.n))
            P[:4, :4] = quat_cov_from_att_cov(self.x.q_nb, self.P[:3, :3])
            P[4:, 4:] = self.P[3:, 3:]
            self.P = P

    def _normalise(self, x: NominalState) -> None:
        """q <- q/|q| (w >= 0) and P <- J P J^T on the quaternion block."""
        q = x.q_nb
        J = np.eye(self.n)
        J[:4, :4] = normalization_jacobian(q)
        qn = q / np.linalg.norm(q)
        if qn[0] < 0:
            qn = -qn
            J[:4, :4] = -J[:4, :4]
        self.P = J @ self.P @ J.T
        self.P = 0.5 * (self.P + self.P.T)
        self.x = NominalState(q_nb=qn, bg=x.bg, wind_n=x.wind_n)

    def _predict(self, w_b: F64, f_b: F64, dt: float) -> None:
        assert self.x is not None
        dtheta = (w_b - self.x.bg) * dt
        F = np.eye(self.n)
        F[:7, :7] = ekf7_jacobian(self.x.q_nb, dtheta, dt)
        q = transition_exact(dtheta) @ self.x.q_nb
        Q = np.zeros((self.n, self.n))
        Q[:7, :7] = ekf7_process_noise(q, self.p.gyro_noise, self.p.gyro_bias_noise, dt)
        if self.n > 7:  # wind random walk (SPEC 2.6)
            Q[7:, 7:] = np.diag([self.p.wind_noise**2] * 2 + [self.p.wind_noise_vertical**2]) * dt
        self.P = F @ self.P @ F.T + Q
        self._normalise(NominalState(q_nb=q, bg=self.x.bg, wind_n=self.x.wind_n))

    def _fuse(self, sensor: str, t: float, nu: F64, H: F64, R: F64, gate: float) -> bool:
        assert self.x is not None
        H7 = np.zeros((H.shape[0], self.n))
        H7[:, :4] = 2.0 * H[:, :3] @ Xi(self.x.q_nb).T
        H7[:, 4:] = H[:, 3:]
        S = H7 @ self.P @ H7.T + R
        nis = float(nu @ np.linalg.solve(S, nu))
        accepted = bool(np.all(nu**2 <= gate**2 * np.diag(S)))
        self._log(sensor, t, nu, nis, accepted)
        if not accepted:
            return False
        K = np.linalg.solve(S, H7 @ self.P).T
        IKH = np.eye(self.n) - K @ H7
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T
        dx = K @ nu
        rest = self.x.inject(self.layout, np.concatenate([np.zeros(3), dx[4:]]))
        self._normalise(NominalState(q_nb=self.x.q_nb + dx[:4], bg=rest.bg, wind_n=rest.wind_n))
        return True

    def _tangent_cov(self) -> F64:
        assert self.x is not None
        T = np.zeros((self.n - 1, self.n))
        T[:3, :4] = 2.0 * Xi(self.x.q_nb).T
        T[3:, 4:] = np.eye(self.n - 4)
        return T @ self.P @ T.T


class Ekf7(_EskfEstimator):
    """[ekf7] additive quaternion + gyro bias EKF with Q from the gyro noise (SPEC 2.3)."""

    name = "ekf7"
    kind: ClassVar[Kind] = "mekf"
    requires = frozenset({"imu"})
    uses = frozenset({"imu", "mag", "gnss", "air"})

    def streamer(
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> Ekf7Streamer:
        return Ekf7Streamer(self.name, self.kind, self.params, site, initial, has)


class Ekf10(Ekf7):
    """[ekf10] additive quaternion + gyro bias + wind EKF fusing air data (SPEC 2.6)."""

    name = "ekf10"
    kind: ClassVar[Kind] = "mekf-air"
    requires = frozenset({"imu", "air", "gnss"})
    default_params = EskfParams(accel_compensation="airspeed")
