"""[ekf]: the traditional accelerometer + magnetometer EKF the paper compares with (its
ref. [6]), tuned from the sensor noise instead of the paper's constants.

4 states (the quaternion), exact transition, Joseph-form updates with the innovation
``z - h(x)``, normalisation with covariance projection (SPEC 2.3); it runs on the compiled
loop of :mod:`windahrs.filters.additive`, its prediction, update and normalisation those of
[ekf7] (``core.predict._predict_add`` without a gyro-bias state, ``core.kalman._fuse``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import ClassVar

from windahrs.conventions import DEG, G0
from windahrs.estimate import STATE_LABELS
from windahrs.filters.additive import (
    KIND_EKF,
    AdditiveEstimator,
    KernelConfig,
    check_number,
    params_from_toml,
)
from windahrs.filters.base import InitialState

__all__ = ["TraditionalEKF", "TraditionalEKFParams"]


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
            check_number(self, name, positive=True)
        for name in ("accel_sigma_unit", "mag_sigma_unit"):
            check_number(self, name, positive=False)


def noise_config(p: TraditionalEKFParams, initial: InitialState | None, kind: int, n: int) -> KernelConfig:
    """The kernel encoding of the sensor-noise filters (ekf, and the ukf's shared part)."""
    sigma_att0 = p.sigma_att0 if initial is None or initial.sigma_att is None else initial.sigma_att
    return KernelConfig(
        kind=kind,
        n=n,
        q_start=None if initial is None else initial.q_nb,
        att0_var=sigma_att0**2,
        gyro_noise=p.gyro_noise,
        accel_noise=p.accel_noise,
        accel_sigma_unit=p.accel_sigma_unit,
        mag_noise=p.mag_noise,
        mag_sigma_unit=p.mag_sigma_unit,
    )


class TraditionalEKF(AdditiveEstimator):
    """The traditional accelerometer + magnetometer EKF the paper compares with (ref. [6]).

    4 states (the quaternion, no gyro bias), exact transition, process noise from the
    gyro noise density (SPEC 2.3 ``Q_d,qq`` with ``sigma_b = 0``), normalised vectors with
    R from the sensor noise (``sigma/|m|`` plus the allowances of
    :class:`TraditionalEKFParams`), TRIAD initialisation. An uncompensated gyro bias is
    integrated into the attitude: this filter trusts its gyro as the datasheet says.
    Covariance reported as the body-frame attitude error (att_x..att_z), rad^2.
    Innovations logged as "accel" and "mag".
    """

    name: ClassVar[str] = "ekf"
    requires: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})
    uses: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})
    labels: ClassVar[tuple[str, ...]] = STATE_LABELS["att"]

    def __init__(self, params: TraditionalEKFParams | None = None) -> None:
        self.params = TraditionalEKFParams() if params is None else params

    @classmethod
    def load_params(cls, path: str | os.PathLike[str]) -> TraditionalEKFParams:
        """TraditionalEKFParams from a TOML file with a ``[windahrs]`` table of its field names."""
        return params_from_toml(TraditionalEKFParams, path)

    def config(self, initial: InitialState | None) -> KernelConfig:
        return noise_config(self.params, initial, KIND_EKF, 4)
