"""Error-state Kalman filters (SPEC 2.4, 2.5, 3).

Three estimators share one core:

* [mekf]: attitude error and gyro bias; accelerometer as a gravity measurement (gated on
  ``|f|`` and on its innovation, optionally compensated by GNSS velocity differences or by
  ``w x V_air``), magnetometer in 3-D or heading only. Its defaults (:data:`MEKF_FIELD`)
  fuse the means of the specific force and of the field in an almost inertial frame
  (``accel_lowpass``, ``mag_lowpass``), add rate-proportional gyro noise and take only the
  heading, about the vertical, from the magnetometer when the site's field is unknown.
* [mekf-air]: the paper's idea done right: [mekf] plus wind states, fusing the air-data
  vector ``C_bn (V_gnss - W)`` (pitot and vanes) or, with a pitot alone, true airspeed and
  a synthetic zero sideslip; the accelerometer is compensated by ``w x V_air``.
* [ins-wind]: the accelerometer as an input; attitude, velocity, gyro bias, wind (and
  optionally accelerometer bias); fuses GNSS velocity, magnetometer and air data. The
  recommended estimator.

Each may carry magnetometer-bias (hard-iron) states with a 3-D magnetometer
(``init_mag_bias > 0``; the [ins-wind] default).

Each is a process model over the compiled core (:mod:`windahrs.core.kernel`) with the aid
sources of :mod:`windahrs.aid` that its parameters switch on; this module only names them and
gives their defaults.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from windahrs.aid import air_vector, airspeed_scale, aoa, drag, gnss_vel, gravity, mag, rest, sideslip, tas
from windahrs.core import imu_screen
from windahrs.core import predict as process
from windahrs.core.kernel import CompiledEstimator
from windahrs.filters.params import EskfParams

__all__ = ["MEKF_FIELD", "InsDrag", "InsWind", "Mekf", "MekfAir"]

#: The parameters of the air-data aid sources (the vector, airspeed, synthetic sideslip).
_AIR = (air_vector.PARAMS, tas.PARAMS, sideslip.PARAMS, aoa.PARAMS, airspeed_scale.PARAMS)


#: [mekf]'s defaults for a 9-D AHRS in the field (handheld, robots, vehicles; BROAD-type
#: motion): gravity and field as means in an almost inertial frame (3 s, 9 s, VQF's time
#: constants), the accelerometer's noise (vibration) estimated on line,
#: rate-proportional gyro noise, heading-only magnetometer about the vertical
#: when the site's field is unknown, magnetic disturbance checks (10 %, 10 deg), and the
#: means' gyro-bias columns (lowpass_bias); the gravity mean fused at 50 Hz,
#: the field's at 10 Hz (accel_fuse_rate, mag_fuse_rate); the gyro bias walks at PX4 EKF2's
#: density (EKF2_GYR_B_NOISE 1e-3 rad/s^2 per 10 ms step: 1e-4 rad/s^2/sqrt(Hz)) where gravity
#: observes it and at the core's 2e-5 about the vertical, where only the magnetometer
#: does (gyro_bias_noise_vertical: its gains and costs in EskfParams, docs/RESULTS.md section 32).
MEKF_FIELD = EskfParams(
    gyro_bias_noise=1e-4,
    gyro_bias_noise_vertical=2e-5,
    accel_lowpass=3.0,
    accel_fuse_rate=50.0,
    accel_noise_online=True,
    gyro_scale_noise=1e-3,
    mag_3d_needs_site=True,
    heading_model="vertical",
    mag_lowpass=9.0,
    mag_fuse_rate=10.0,
    mag_norm_gate=0.1,
    mag_dip_gate=float(np.radians(10.0)),
    lowpass_bias=True,
)


class Mekf(CompiledEstimator):
    """[mekf] error-state EKF: attitude error and gyro bias; accelerometer (gravity, gated)
    and magnetometer. Defaults: :data:`MEKF_FIELD`."""

    name = "mekf"
    kind = "mekf"
    requires = frozenset({"imu"})
    uses = frozenset({"imu", "mag", "gnss", "air"})
    default_params = MEKF_FIELD
    parts: ClassVar[tuple[tuple[str, ...], ...]] = (
        process.ATTITUDE_PARAMS,
        process.HELD_SAMPLE_PARAMS,
        imu_screen.PARAMS,
        rest.PARAMS,
        process.GYRO_SCALE_PARAMS,
        process.BIAS_WALK_PARAMS,
        gravity.PARAMS,
        gravity.LAG_PARAMS,
        gravity.FUSE_RATE_PARAMS,
        gravity.GATED_START_PARAMS,
        mag.PARAMS,
        mag.BIAS_PARAMS,
        mag.FUSE_RATE_PARAMS,
    )


class MekfAir(CompiledEstimator):
    """[mekf-air] [mekf] plus wind states fusing air data with GNSS velocity as input."""

    name = "mekf-air"
    kind = "mekf-air"
    requires = frozenset({"imu", "air", "gnss"})
    uses = frozenset({"imu", "mag", "gnss", "air"})
    default_params = EskfParams(accel_compensation="airspeed")
    parts = (*Mekf.parts, process.WIND_PARAMS, *_AIR, ("gnss_sigma",))


class InsWind(CompiledEstimator):
    """[ins-wind] error-state INS with wind states: the recommended estimator."""

    name = "ins-wind"
    kind = "ins-wind"
    requires = frozenset({"imu", "gnss"})
    uses = frozenset({"imu", "mag", "gnss", "air"})
    #: hard-iron states, and [mekf]'s magnetic disturbance checks (VQF's 10 %, 10 deg): a field
    #: whose norm or dip is off the reference's is not fused (ALFA, tilt / total against
    #: ArduPilot: 5.25 / 12.68 deg without the checks, 4.44 / 8.91 with them; the simulated
    #: flights unchanged). The field's innovation gate at 3 sigma, PX4 EKF2's EKF2_MAG_GATE and
    #: ArduPilot EKF3's EK3_MAG_I_GATE (300) defaults, where the other sensors keep 5: a
    #: disturbance that turns the field slowly enough to pass the norm and dip checks bends
    #: the heading by less before the gate stops it, while GNSS velocity keeps the heading
    #: (the fault matrix's drifting field, total RMSE fixed wing 4.34 -> 1.46 deg, quadrotor
    #: 6.02 -> 2.26; the simulated flights without faults and the PX4 logs unchanged;
    #: docs/RESULTS.md section 35). A heading the gate would then keep out for good is turned
    #: to the field after reset_timeout (:func:`windahrs.aid.mag.heading_reset`).
    #: The covariance predicted once per 10 ms over the IMU steps in it (cov_period), as PX4 EKF2
    #: predicts at its filter update period (EKF2_PREDICT_US 10 000 us).
    default_params = EskfParams(
        init_mag_bias=1e-6, mag_norm_gate=0.1, mag_dip_gate=float(np.radians(10.0)), gate_mag=3.0, cov_period=0.01
    )
    parts: ClassVar[tuple[tuple[str, ...], ...]] = (
        process.ATTITUDE_PARAMS,
        process.HELD_SAMPLE_PARAMS,
        imu_screen.PARAMS,
        rest.PARAMS,
        process.GYRO_SCALE_PARAMS,
        process.BIAS_WALK_PARAMS,
        process.INS_PARAMS,
        process.COV_PERIOD_PARAMS,
        process.WIND_PARAMS,
        gnss_vel.PARAMS,
        mag.PARAMS,
        mag.BIAS_PARAMS,
        mag.FUSE_RATE_PARAMS,
        *_AIR,
        drag.PARAMS,
    )


class InsDrag(InsWind):
    """[ins-drag] [ins-wind] fusing the multirotor drag in the accelerometer (PX4 EKF2's
    drag fusion, :mod:`windahrs.aid.drag`): a wind estimate and a tilt reference without a
    pitot. Defaults: [ins-wind]'s with PX4's drag coefficients (EKF2_MCOEF 0.15 1/s,
    EKF2_BCOEF_X/Y 100 kg/m^2, EKF2_DRAG_NOISE 2.5 (m/s^2)^2; tune them to the airframe)
    and the vertical wind held at zero (EKF2's wind state is horizontal: the body-x/y drag
    of a tilted multirotor cannot tell vertical from horizontal wind)."""

    name = "ins-drag"
    default_params = InsWind.default_params.replace(drag=True, wind_vertical=False)
    #: (every IMU step's covariance predicted at its sample: the drag update reads P at every one)
    parts = tuple(part for part in InsWind.parts if part is not process.COV_PERIOD_PARAMS)
