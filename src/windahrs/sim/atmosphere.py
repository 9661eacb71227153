"""The wind a simulated vehicle flies through: mean wind with shear, Dryden
turbulence and discrete gusts, composed in NED from the primitives of
:mod:`windahrs.sim.wind`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from windahrs.sim.wind import (
    dryden_gusts,
    low_altitude_params,
    one_minus_cosine_gust,
    shear_mean_wind,
)

__all__ = ["Gust", "WindConfig", "wind_n"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Gust:
    """A discrete 1-cosine gust: starts at t_start s, lasts duration s, peak amplitude_n
    (3,) m/s NED (velocity of the air)."""

    t_start: float
    duration: float
    amplitude_n: tuple[float, float, float]

    def __post_init__(self) -> None:
        if not (np.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"Gust.duration: expected > 0 s, found {self.duration!r}")
        if len(self.amplitude_n) != 3 or not np.all(np.isfinite(self.amplitude_n)):
            raise ValueError(f"Gust.amplitude_n: expected 3 finite m/s, found {self.amplitude_n!r}")


@dataclass(frozen=True)
class WindConfig:
    """Wind of a scenario.

    w20: mean wind speed at 20 ft (6.1 m), m/s, which also sets the Dryden intensities
    (MIL-F-8785C; light/moderate/severe = 7.7/15.4/23.1 m/s). direction_from: rad,
    where the wind comes from (meteorological; 0 = from north). shear: apply the
    MIL-F-8785C log profile (otherwise the mean wind is w20 at every height).
    turbulence: add Dryden turbulence. gusts: discrete 1-cosine gusts.
    """

    w20: float = 0.0
    direction_from: float = 0.0
    shear: bool = True
    turbulence: bool = True
    gusts: tuple[Gust, ...] = ()

    def __post_init__(self) -> None:
        if not (np.isfinite(self.w20) and self.w20 >= 0):
            raise ValueError(
                f"WindConfig.w20: expected a finite speed >= 0 m/s, found {self.w20!r}"
            )
        if not np.isfinite(self.direction_from):
            raise ValueError(
                f"WindConfig.direction_from: expected finite rad, found {self.direction_from!r}"
            )

    def blowing_to_n(self) -> F64:
        """Unit horizontal vector (3,) NED along which the mean wind blows."""
        return -np.array([np.cos(self.direction_from), np.sin(self.direction_from), 0.0])

    def mean_n(self, altitude: ArrayLike) -> F64:
        """Mean wind (N, 3) m/s NED at the altitudes (N,) m above ground."""
        h = np.atleast_1d(np.asarray(altitude, dtype=np.float64))
        speed = shear_mean_wind(self.w20, h) if self.shear else np.full(h.shape, self.w20)
        return speed[:, None] * self.blowing_to_n()


def wind_n(
    cfg: WindConfig,
    t: F64,
    altitude: F64,
    nominal_altitude: float,
    airspeed: ArrayLike,
    track: F64,
    rng: np.random.Generator,
) -> tuple[F64, F64]:
    """Mean wind and disturbance (mean-wind deviation + turbulence + gusts), both (N, 3).

    altitude (N,) m drives the shear; nominal_altitude m sets the Dryden scales;
    airspeed (N,) or scalar m/s advects the frozen turbulence field; track (N,) rad is
    the direction of the mean air-relative path, along which the u component lies.
    The disturbance is relative to the mean wind at the nominal altitude.
    """
    n = len(t)
    mean0 = cfg.mean_n(np.array([nominal_altitude]))[0]
    dist = cfg.mean_n(altitude) - mean0
    if cfg.turbulence and cfg.w20 > 0:
        dt = float(np.median(np.diff(t))) if n > 1 else 1.0
        params = low_altitude_params(cfg.w20, nominal_altitude)
        uvw = dryden_gusts(params, airspeed, dt, n, rng)
        c, s = np.cos(track), np.sin(track)
        dist = dist + np.stack(
            [c * uvw[:, 0] - s * uvw[:, 1], s * uvw[:, 0] + c * uvw[:, 1], uvw[:, 2]], 1
        )
    for g in cfg.gusts:
        dist = dist + one_minus_cosine_gust(t, g.t_start, g.duration, np.asarray(g.amplitude_n))
    return np.broadcast_to(mean0, (n, 3)).copy(), dist
