"""[ukf]: the additive-quaternion UKF the paper compares with (its ref. [7], SPEC 4.2),
with a gyro-bias state; it runs on the compiled loop of :mod:`windahrs.filters.additive`
with the unscented transform of :mod:`windahrs.core.dense`, [ekf7]'s process noise and
normalisation (``core.predict._noise_add``, ``_normalise_add``).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from windahrs.conventions import DEG
from windahrs.estimate import STATE_LABELS
from windahrs.filters.additive import (
    KIND_UKF,
    AdditiveEstimator,
    KernelConfig,
    bad_param,
    check_number,
    params_from_toml,
)
from windahrs.filters.base import InitialState
from windahrs.filters.ekf import TraditionalEKFParams, noise_config

__all__ = ["AdditiveUKF", "AdditiveUKFParams"]


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
        check_number(self, "gyro_bias_rw", positive=True)
        check_number(self, "sigma_bias0", positive=True)
        check_number(self, "beta", positive=False)
        check_number(self, "alpha", positive=True)
        if self.alpha > 1.0:
            raise bad_param(self, "alpha", "a number in (0, 1]")
        k = self.kappa
        if isinstance(k, bool) or not isinstance(k, int | float) or not np.isfinite(k) or k <= -7:
            raise bad_param(self, "kappa", "a finite number > -7 (7 + kappa > 0)")


class AdditiveUKF(AdditiveEstimator):
    """The additive-quaternion UKF the paper compares with (ref. [7], SPEC 4.2).

    State ``[q; b_g]`` (7); sigma points on the 7-vector (scaled unscented transform,
    from the LDL^T root :func:`~windahrs.core.dense.psd_root` of ``(n + lambda) P``:
    determined by P alone, and defined where the normalisation leaves P singular along q),
    each propagated quaternion normalised and flipped to the centre point's hemisphere,
    process noise of SPEC 2.3 added at the weighted mean, which is then renormalised
    (covariance projected as in the EKF); accelerometer and magnetometer as normalised vectors as in
    :class:`~windahrs.filters.ekf.TraditionalEKF`; TRIAD initialisation. Reports the gyro
    bias and the covariance in the tangent space (att_x.., bg_x..):
    ``P_dtheta = 4 Xi^T P_qq Xi``. Innovations logged as "accel" and "mag".
    """

    name: ClassVar[str] = "ukf"
    requires: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})
    uses: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})
    labels: ClassVar[tuple[str, ...]] = STATE_LABELS["att"] + STATE_LABELS["bg"]

    def __init__(self, params: AdditiveUKFParams | None = None) -> None:
        self.params = AdditiveUKFParams() if params is None else params

    @classmethod
    def load_params(cls, path: str | os.PathLike[str]) -> AdditiveUKFParams:
        """AdditiveUKFParams from a TOML file with a ``[windahrs]`` table of its field names."""
        return params_from_toml(AdditiveUKFParams, path)

    def config(self, initial: InitialState | None) -> KernelConfig:
        p = self.params
        sigma_b0 = p.sigma_bias0
        b0 = np.zeros(3)
        if initial is not None:
            if initial.gyro_bias_b is not None:
                b0 = np.asarray(initial.gyro_bias_b, dtype=np.float64).copy()
            if initial.sigma_bias is not None:
                sigma_b0 = initial.sigma_bias
        return dataclasses.replace(
            noise_config(p, initial, KIND_UKF, 7),
            bg0_var=sigma_b0**2,
            b0=b0,
            gyro_bias_rw=p.gyro_bias_rw,
            ut=(p.alpha, p.beta, p.kappa),
        )
