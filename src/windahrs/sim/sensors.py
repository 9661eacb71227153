"""Sensor models (SPEC 5.4): every sample derived from one truth trajectory.

Continuous noise densities are converted to per-sample standard deviations with
``sigma_d = sigma_c / sqrt(dt)`` (Kalibr convention). Biases follow random walks with
the given densities. Every draw comes from the ``rng`` passed in.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from windahrs.conventions import DEG
from windahrs.flight import AirDataStream, Flight, GnssStream, ImuStream, MagStream, Site, Truth
from windahrs.rotation import quat_rotate_inv

__all__ = [
    "AccelModel",
    "GnssModel",
    "GyroModel",
    "MagModel",
    "PitotModel",
    "SensorSuite",
    "TruthTrajectory",
    "VaneModel",
    "measure",
]

F64 = NDArray[np.float64]


def _check(cls_name: str, name: str, value: float, *, positive: bool = False) -> None:
    ok = np.isfinite(value) and (value > 0 if positive else value >= 0)
    if not ok:
        need = "> 0" if positive else ">= 0"
        raise ValueError(f"{cls_name}.{name}: expected a finite value {need}, found {value!r}")


class _Validated:
    """Frozen records whose float fields must be finite and >= 0 (rates > 0)."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            v = getattr(self, f.name)
            if isinstance(v, float | int) and not isinstance(v, bool):
                _check(type(self).__name__, f.name, float(v), positive=f.name == "rate")


@dataclass(frozen=True)
class GyroModel(_Validated):
    """MPU-9150-class gyroscope. noise_density rad/s/sqrt(Hz); bias_rw rad/s^2/sqrt(Hz);
    bias_init_sigma rad/s (residual after start-up calibration)."""

    noise_density: float = 0.005 * DEG
    bias_rw: float = 1e-5
    bias_init_sigma: float = 0.4 * DEG


@dataclass(frozen=True)
class AccelModel(_Validated):
    """Accelerometer. noise_density m/s^2/sqrt(Hz) (400 ug/sqrt(Hz)); bias_rw
    m/s^3/sqrt(Hz); bias_init_sigma m/s^2 (5 mg after calibration)."""

    noise_density: float = 400e-6 * 9.80665
    bias_rw: float = 0.0
    bias_init_sigma: float = 5e-3 * 9.80665


@dataclass(frozen=True)
class MagModel(_Validated):
    """Magnetometer (AK8975-class). rate Hz; noise tesla per axis per sample; hard_iron
    tesla, the standard deviation of a constant per-axis offset drawn once."""

    rate: float = 50.0
    noise: float = 0.5e-6
    hard_iron: float = 0.5e-6


@dataclass(frozen=True)
class GnssModel(_Validated):
    """GNSS velocity. rate Hz; noise m/s per axis; latency s (the sample stamped t
    reports the velocity at t - latency)."""

    rate: float = 10.0
    noise: float = 0.1
    latency: float = 0.0


@dataclass(frozen=True)
class PitotModel(_Validated):
    """Pitot tube. rate Hz; noise m/s; scale_error: the reading is (1 + scale_error) TAS."""

    rate: float = 50.0
    noise: float = 0.3
    scale_error: float = 0.0


@dataclass(frozen=True)
class VaneModel(_Validated):
    """Angle-of-attack and sideslip vanes, sampled with the pitot. noise rad."""

    noise: float = 0.5 * DEG


@dataclass(frozen=True)
class SensorSuite:
    """Which sensors fly and how good they are. ``None`` leaves a sensor out.

    imu_rate: Hz. Other rates are rounded to a divisor of the IMU rate (samples fall on
    IMU instants); the realised rate is what the Flight reports.
    """

    imu_rate: float = 200.0
    gyro: GyroModel = GyroModel()
    accel: AccelModel = AccelModel()
    mag: MagModel | None = MagModel()
    gnss: GnssModel | None = GnssModel()
    pitot: PitotModel | None = PitotModel()
    vanes: VaneModel | None = VaneModel()

    def __post_init__(self) -> None:
        _check("SensorSuite", "imu_rate", float(self.imu_rate), positive=True)
        if self.vanes is not None and self.pitot is None:
            raise ValueError(
                "SensorSuite.vanes: expected a pitot to go with the vanes, found pitot=None"
            )

    def noiseless(self) -> SensorSuite:
        """The same suite with every noise, bias and latency set to zero."""

        def zero(m: object) -> object:
            if m is None:
                return None
            keep = {"rate"}
            return dataclasses.replace(
                m,  # type: ignore[type-var]
                **{f.name: 0.0 for f in dataclasses.fields(m) if f.name not in keep},  # type: ignore[arg-type]
            )

        return dataclasses.replace(
            self,
            gyro=zero(self.gyro),  # type: ignore[arg-type]
            accel=zero(self.accel),  # type: ignore[arg-type]
            mag=zero(self.mag),  # type: ignore[arg-type]
            gnss=zero(self.gnss),  # type: ignore[arg-type]
            pitot=zero(self.pitot),  # type: ignore[arg-type]
            vanes=zero(self.vanes),  # type: ignore[arg-type]
        )


@dataclass(frozen=True)
class TruthTrajectory:
    """Truth on the IMU grid, as produced by a vehicle model.

    t (N,) s; q_nb (N, 4); w_b (N, 3) body rate over (t[k-1], t[k]] (w_b[0] repeats
    w_b[1]); a_n (N, 3) nav acceleration over the same interval, m/s^2; v_n, p_n (N, 3);
    wind_n (N, 3) velocity of the air, m/s, NED.
    """

    t: F64
    q_nb: F64
    w_b: F64
    a_n: F64
    v_n: F64
    p_n: F64
    wind_n: F64

    def air_velocity_b(self) -> F64:
        """Air-relative velocity in body axes, ``C_bn (v_n - wind_n)``, (N, 3) m/s."""
        return quat_rotate_inv(self.q_nb, self.v_n - self.wind_n)

    def specific_force_b(self, gravity: float) -> F64:
        """``f_b = C_bn (a_n - g_n)``, (N, 3) m/s^2."""
        return quat_rotate_inv(self.q_nb, self.a_n - np.array([0.0, 0.0, gravity]))


def _random_walk(n: int, dt: float, init_sigma: float, rw: float, rng: np.random.Generator) -> F64:
    b0 = rng.normal(0.0, 1.0, 3) * init_sigma
    steps = rng.normal(0.0, 1.0, (n, 3)) * (rw * np.sqrt(dt))
    steps[0] = 0.0
    return b0 + np.cumsum(steps, axis=0)


def _decimation(imu_rate: float, rate: float, name: str) -> int:
    step = max(1, round(imu_rate / rate))
    if abs(imu_rate / step - rate) > 0.05 * rate:
        raise ValueError(
            f"{name}.rate: expected a divisor of the IMU rate {imu_rate} Hz, found {rate}"
        )
    return step


def air_data_from_velocity(v_air_b: F64) -> tuple[F64, F64, F64]:
    """True airspeed, angle of attack and sideslip (SPEC 3.4.1, FRD) from (N, 3) m/s."""
    tas = np.linalg.norm(v_air_b, axis=1)
    aoa = np.arctan2(v_air_b[:, 2], v_air_b[:, 0])
    beta = np.arcsin(np.clip(v_air_b[:, 1] / np.maximum(tas, 1e-9), -1.0, 1.0))
    return tas, aoa, beta


def measure(
    traj: TruthTrajectory,
    sensors: SensorSuite,
    site: Site,
    rng: np.random.Generator,
    meta: dict[str, str | int | float | bool] | None = None,
) -> Flight:
    """Sample every sensor of ``sensors`` from ``traj``; returns a Flight with truth."""
    t = traj.t
    n = len(t)
    dt = float(np.median(np.diff(t)))
    g, a = sensors.gyro, sensors.accel
    gyro_bias = _random_walk(n, dt, g.bias_init_sigma, g.bias_rw, rng)
    accel_bias = _random_walk(n, dt, a.bias_init_sigma, a.bias_rw, rng)
    w_m = traj.w_b + gyro_bias + rng.normal(0.0, 1.0, (n, 3)) * (g.noise_density / np.sqrt(dt))
    f_m = (
        traj.specific_force_b(site.gravity)
        + accel_bias
        + rng.normal(0.0, 1.0, (n, 3)) * (a.noise_density / np.sqrt(dt))
    )
    imu = ImuStream(t=t, w_b=w_m, f_b=f_m)

    mag = None
    if sensors.mag is not None:
        if site.mag_n is None:
            raise ValueError(
                "site.mag_n: expected the Earth field to simulate a magnetometer, found None"
            )
        k = slice(None, None, _decimation(sensors.imu_rate, sensors.mag.rate, "mag"))
        hard_iron = rng.normal(0.0, 1.0, 3) * sensors.mag.hard_iron
        m_b = quat_rotate_inv(traj.q_nb[k], site.mag_n)
        m_b = m_b + hard_iron + rng.normal(0.0, 1.0, m_b.shape) * sensors.mag.noise
        mag = MagStream(t=t[k], mag_b=m_b)

    gnss = None
    if sensors.gnss is not None:
        k = slice(None, None, _decimation(sensors.imu_rate, sensors.gnss.rate, "gnss"))
        tg = t[k]
        lag = tg - sensors.gnss.latency
        v = np.stack([np.interp(lag, t, traj.v_n[:, i]) for i in range(3)], axis=1)
        v = v + rng.normal(0.0, 1.0, v.shape) * sensors.gnss.noise
        gnss = GnssStream(t=tg, v_n=v)

    air = None
    if sensors.pitot is not None:
        k = slice(None, None, _decimation(sensors.imu_rate, sensors.pitot.rate, "pitot"))
        tas, aoa, beta = air_data_from_velocity(traj.air_velocity_b()[k])
        p = sensors.pitot
        tas_m = (1.0 + p.scale_error) * tas + rng.normal(0.0, 1.0, tas.shape) * p.noise
        if sensors.vanes is not None:
            vn = sensors.vanes.noise
            air = AirDataStream(
                t=t[k],
                tas=tas_m,
                aoa=aoa + rng.normal(0.0, 1.0, aoa.shape) * vn,
                sideslip=beta + rng.normal(0.0, 1.0, beta.shape) * vn,
            )
        else:
            air = AirDataStream(t=t[k], tas=tas_m)

    truth = Truth(
        t=t,
        q_nb=traj.q_nb,
        v_n=traj.v_n,
        wind_n=traj.wind_n,
        gyro_bias_b=gyro_bias,
        accel_bias_b=accel_bias,
        p_n=traj.p_n,
    )
    return Flight(
        imu=imu, mag=mag, gnss=gnss, air=air, truth=truth, site=site, meta=dict(meta or {})
    )
