"""Fixed wing in coordinated flight with a quasi-steady gust response (SPEC 5.2).

The autopilot holds a nominal attitude (straight legs, coordinated turns, climbs) and
the trim airflow in the body; gusts perturb the air-relative velocity, and the airframe's
dimensional stability derivatives turn that into a specific-force perturbation
``df_b = D dv_r_b`` which moves the inertial velocity.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from windahrs.conventions import DEG, G0
from windahrs.rotation import air_direction, dcm_from_quat, quat_from_euler
from windahrs.sim.atmosphere import WindConfig, wind_n
from windahrs.sim.gust_response import fly_attitude_held
from windahrs.sim.sensors import TruthTrajectory

__all__ = ["Airframe", "FixedWingScenario", "Leg", "fixedwing_truth"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Airframe:
    """A small fixed-wing UAV. mass kg, wing_area m^2, CL_alpha 1/rad, CD (-),
    CY_beta 1/rad, air_density kg/m^3. Defaults: a 2.5 kg, 0.5 m^2 electric glider-like
    airframe (SPEC 5.2 example)."""

    mass: float = 2.5
    wing_area: float = 0.5
    CL_alpha: float = 4.5
    CD: float = 0.05
    CY_beta: float = -0.5
    air_density: float = 1.225

    def __post_init__(self) -> None:
        for name in ("mass", "wing_area", "CL_alpha", "air_density"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"Airframe.{name}: expected a finite value > 0, found {v!r}")
        if not (np.isfinite(self.CD) and self.CD >= 0):
            raise ValueError(f"Airframe.CD: expected a finite value >= 0, found {self.CD!r}")
        if not (np.isfinite(self.CY_beta) and self.CY_beta <= 0):
            raise ValueError(
                f"Airframe.CY_beta: expected a finite value <= 0, found {self.CY_beta!r}"
            )

    def lift_coefficient(self, airspeed: float, g: float = G0) -> float:
        """Trim lift coefficient in level flight, ``C_L = 2 m g / (rho V^2 S)``."""
        return 2 * self.mass * g / (self.air_density * airspeed**2 * self.wing_area)

    def trim_alpha(self, airspeed: float, g: float = G0) -> float:
        """Trim angle of attack, rad (zero lift at alpha = 0)."""
        return self.lift_coefficient(airspeed, g) / self.CL_alpha

    def derivatives(self, airspeed: float, g: float = G0) -> F64:
        """Dimensional derivatives ``D`` (3, 3) 1/s: ``df_b = D dv_r_b`` (SPEC 5.2)."""
        k = self.air_density * airspeed * self.wing_area / self.mass
        cl = self.lift_coefficient(airspeed, g)
        return np.array(
            [
                [-k * self.CD, 0.0, 0.5 * k * cl],
                [0.0, 0.5 * k * self.CY_beta, 0.0],
                [-k * cl, 0.0, -0.5 * k * (self.CL_alpha + self.CD)],
            ]
        )


@dataclass(frozen=True)
class Leg:
    """One segment of a flight plan: duration s, bank rad (coordinated turn; positive
    right), climb angle rad (flight-path angle)."""

    duration: float
    bank: float = 0.0
    climb: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"Leg.duration: expected > 0 s, found {self.duration!r}")
        if not abs(self.bank) < 60 * DEG:
            raise ValueError(f"Leg.bank: expected |bank| < 60 deg, found {self.bank / DEG:.4g} deg")
        if not abs(self.climb) < 20 * DEG:
            raise ValueError(
                f"Leg.climb: expected |climb| < 20 deg, found {self.climb / DEG:.4g} deg"
            )


#: A repeating pattern: straight, right turn, straight, climb, left turn, descent.
PATTERN: tuple[Leg, ...] = (
    Leg(20.0),
    Leg(15.0, bank=30 * DEG),
    Leg(15.0),
    Leg(10.0, climb=3 * DEG),
    Leg(15.0, bank=-30 * DEG),
    Leg(10.0, climb=-3 * DEG),
)
LEVEL: tuple[Leg, ...] = (Leg(60.0),)


@dataclass(frozen=True)
class FixedWingScenario:
    """A fixed-wing flight. duration s; altitude m above ground; airspeed m/s;
    plan "pattern" (turns and climbs, repeated) or "level" (straight and level), or an
    explicit tuple of legs (repeated to fill the duration); heading0 rad; transition s
    (time to roll into a bank or change climb angle)."""

    duration: float = 120.0
    altitude: float = 50.0
    airspeed: float = 15.0
    wind: WindConfig = field(default_factory=WindConfig)
    airframe: Airframe = field(default_factory=Airframe)
    plan: Literal["pattern", "level"] | tuple[Leg, ...] = "pattern"
    heading0: float = 0.0
    transition: float = 2.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"duration: expected > 0 s, found {self.duration!r}")
        if not (np.isfinite(self.altitude) and 2.0 <= self.altitude <= 3000.0):
            raise ValueError(f"altitude: expected 2 to 3000 m, found {self.altitude!r}")
        if not (np.isfinite(self.airspeed) and 5.0 <= self.airspeed <= 80.0):
            raise ValueError(f"airspeed: expected 5 to 80 m/s, found {self.airspeed!r}")
        if isinstance(self.plan, str) and self.plan not in ("pattern", "level"):
            raise ValueError(
                f"plan: expected 'pattern', 'level' or a tuple of Leg, found {self.plan!r}"
            )

    def legs(self) -> tuple[Leg, ...]:
        if self.plan == "pattern":
            return PATTERN
        if self.plan == "level":
            return LEVEL
        return tuple(self.plan)


def _smooth_schedule(t: F64, legs: tuple[Leg, ...], attr: str, transition: float) -> F64:
    """Piecewise-constant leg values joined by smooth (C1) steps of length ``transition``."""
    out = np.zeros_like(t)
    start, prev, i = t[0], 0.0, 0
    while start <= t[-1]:
        leg = legs[i % len(legs)]
        value = getattr(leg, attr)
        s = np.clip((t - start) / transition, 0.0, 1.0)
        out += (value - prev) * (3 * s**2 - 2 * s**3)
        prev, start, i = value, start + leg.duration, i + 1
    return out


def _pitch_for_climb(alpha: float, roll: F64, climb: F64) -> F64:
    """Pitch giving flight-path angle ``climb`` with body airflow at ``alpha`` (beta 0)
    and bank ``roll``: solves ``-cos(a) sin(th) + cos(roll) sin(a) cos(th) = -sin(climb)``."""
    A = -np.cos(alpha)
    B = np.cos(roll) * np.sin(alpha)
    R = np.hypot(A, B)
    delta = np.arctan2(B, A)
    base = np.arcsin(np.clip(-np.sin(climb) / R, -1, 1))
    c1 = base - delta
    c2 = np.pi - base - delta
    wrap = lambda x: (x + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
    c1, c2 = wrap(c1), wrap(c2)
    guess = climb + alpha * np.cos(roll)
    return np.where(np.abs(c1 - guess) < np.abs(c2 - guess), c1, c2)


def fixedwing_truth(
    sc: FixedWingScenario, t: F64, rng: np.random.Generator, gravity: float = G0
) -> TruthTrajectory:
    """Truth of a fixed-wing flight on the time grid ``t`` (N,) s."""
    legs = sc.legs()
    V = sc.airspeed
    alpha0 = sc.airframe.trim_alpha(V, gravity)
    roll = _smooth_schedule(t, legs, "bank", sc.transition)
    climb = _smooth_schedule(t, legs, "climb", sc.transition)
    yaw_rate = gravity * np.tan(roll) / V
    yaw = sc.heading0 + np.concatenate(
        [[0.0], np.cumsum(0.5 * (yaw_rate[1:] + yaw_rate[:-1]) * np.diff(t))]
    )
    pitch = _pitch_for_climb(alpha0, roll, climb)
    q_nb = quat_from_euler(np.stack([roll, pitch, yaw], axis=1))

    v_air_b = V * air_direction(alpha0, 0.0)
    C_nb = dcm_from_quat(q_nb)
    v_air_n = C_nb @ v_air_b
    mean = sc.wind.mean_n(np.array([sc.altitude]))[0]
    # Shear acts on the nominal altitude profile (climbs), not on gust-induced heights.
    v_nom = v_air_n + mean
    alt = sc.altitude - np.concatenate(
        [[0.0], np.cumsum(0.5 * (v_nom[1:, 2] + v_nom[:-1, 2]) * np.diff(t))]
    )
    track = np.arctan2(v_air_n[:, 1], v_air_n[:, 0])
    mean_n, wd = wind_n(sc.wind, t, alt, sc.altitude, V, track, rng)
    D = sc.airframe.derivatives(V, gravity)
    response = -(C_nb @ D @ np.swapaxes(C_nb, 1, 2))
    return fly_attitude_held(
        t, q_nb, v_air_b, mean_n[0], wd, response, p0_n=np.array([0.0, 0.0, -sc.altitude])
    )
