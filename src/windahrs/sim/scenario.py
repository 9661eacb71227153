"""``simulate``: a scenario and a sensor suite in, a Flight with truth out."""

from __future__ import annotations

import os
from typing import Literal

import numpy as np

from windahrs.conventions import MAG_DALIAN_N
from windahrs.flight import Flight, Site
from windahrs.sim.atmosphere import WindConfig
from windahrs.sim.fixedwing import FixedWingScenario, fixedwing_truth
from windahrs.sim.paper import PaperScenario, paper_truth
from windahrs.sim.quadrotor import QuadrotorScenario, quadrotor_truth
from windahrs.sim.sensors import SensorSuite, measure

__all__ = [
    "MAX_W20", "MIN_DURATION_S", "SIM_BYTES_PER_SAMPLE", "VEHICLES", "Scenario", "check_memory",
    "check_simulation_size", "default_site", "make_scenario", "physical_memory", "simulate",
]

Scenario = FixedWingScenario | QuadrotorScenario | PaperScenario
VEHICLES: tuple[str, ...] = ("fixedwing", "quadrotor", "paper")


def default_site() -> Site:
    """The paper's site: Dalian, IGRF-13 field, standard gravity."""
    return Site(mag_n=MAG_DALIAN_N.copy())


#: Shortest simulated flight, s: the slowest default stream (GNSS velocity, 10 Hz) then
#: has 10 samples, and every stream at least two.
MIN_DURATION_S = 1.0

#: Strongest W20 a scenario takes, m/s: MIL-F-8785C's "severe" 45 kt, the largest W20 for
#: which it gives low-altitude turbulence intensities (light / moderate / severe: 15 / 30 /
#: 45 kt); beyond it the Dryden model has no basis.
MAX_W20 = 45.0 * 0.514444

#: Peak memory of :func:`simulate` per IMU sample, bytes: measured 0.42 to 0.67 kB
#: (tracemalloc, 40 s flights of each vehicle at 200 Hz), rounded up.
SIM_BYTES_PER_SAMPLE = 1024


def physical_memory() -> int | None:
    """The machine's physical memory in bytes, or None where the OS does not say."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):  # pragma: no cover - not POSIX
        return None


def check_memory(name: str, need: float, what: str) -> None:
    """ValueError naming ``name`` (the argument that asked for it) when ``need`` bytes
    exceed the machine's physical memory: checked before allocating, so that an absurd
    request is refused at once instead of swapping or dying in the allocator."""
    have = physical_memory()
    if have is not None and need > have:
        raise ValueError(
            f"{name}: {what} needs about {_size(need)} of memory; this machine has {_size(have)}"
        )


def _size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} PiB"  # pragma: no cover


def check_simulation_size(scenario: Scenario, sensors: SensorSuite | None = None) -> None:
    """Refuse (ValueError naming ``duration``) a simulation whose arrays would not fit in
    memory, before allocating them."""
    sensors = sensors or default_sensors(scenario)
    n = scenario.duration * sensors.imu_rate + 1
    what = f"simulating {scenario.duration:g} s at {sensors.imu_rate:g} Hz"
    check_memory("duration", float(n) * SIM_BYTES_PER_SAMPLE, what)


def make_scenario(
    vehicle: Literal["fixedwing", "quadrotor", "paper"] | str,
    *,
    wind: float = 0.0,
    duration: float | None = None,
    altitude: float | None = None,
) -> Scenario:
    """The default scenario of a vehicle with the given W20 (m/s), duration (s) and
    altitude (m); ``None`` keeps the vehicle's default. For "paper", ``wind`` is the
    paper's wind speed (mean wind and W20)."""
    if vehicle not in VEHICLES:
        raise ValueError(f"vehicle: expected one of {', '.join(VEHICLES)}, found {vehicle!r}")
    if duration is not None and not (np.isfinite(duration) and duration > 0):
        raise ValueError(f"duration: expected > 0 s, found {duration!r}")
    if duration is not None and duration < MIN_DURATION_S:
        raise ValueError(f"duration: expected at least {MIN_DURATION_S:g} s, found {duration!r}")
    if not (np.isfinite(wind) and wind >= 0):
        raise ValueError(f"wind: expected W20 >= 0 m/s, found {wind!r}")
    if wind > MAX_W20:
        raise ValueError(
            f"wind: expected W20 at most {MAX_W20:.4g} m/s (MIL-F-8785C's severe 45 kt, the strongest "
            f"low-altitude turbulence it defines), found {wind!r}"
        )
    kw: dict[str, float] = {}
    if duration is not None:
        kw["duration"] = float(duration)
    if altitude is not None:
        kw["altitude"] = float(altitude)
    if vehicle == "paper":
        return PaperScenario(wind_speed=float(wind), **kw)  # type: ignore[arg-type]
    cfg = WindConfig(w20=float(wind))
    if vehicle == "fixedwing":
        return FixedWingScenario(wind=cfg, **kw)  # type: ignore[arg-type]
    return QuadrotorScenario(wind=cfg, **kw)  # type: ignore[arg-type]


def simulate(
    scenario: Scenario,
    rng: np.random.Generator,
    sensors: SensorSuite | None = None,
    site: Site | None = None,
) -> Flight:
    """Simulate ``scenario`` and sample ``sensors`` (default suite: MPU-9150 IMU at
    200 Hz, magnetometer 50 Hz, GNSS velocity 10 Hz, pitot and vanes 50 Hz; the paper's
    site). Every draw comes from ``rng``. The quadrotor carries no vanes and no pitot by
    default (``sensors`` decides)."""
    sensors = sensors or default_sensors(scenario)
    site = site or default_site()
    check_simulation_size(scenario, sensors)
    dt = 1.0 / sensors.imu_rate
    n = round(scenario.duration / dt) + 1
    t = np.arange(n, dtype=np.float64) * dt
    if isinstance(scenario, FixedWingScenario):
        traj = fixedwing_truth(scenario, t, rng, site.gravity)
        vehicle = "fixedwing"
        w20 = scenario.wind.w20
    elif isinstance(scenario, QuadrotorScenario):
        traj = quadrotor_truth(scenario, t, rng, site.gravity)
        vehicle = "quadrotor"
        w20 = scenario.wind.w20
    elif isinstance(scenario, PaperScenario):
        traj = paper_truth(scenario, t, rng)
        vehicle = "paper"
        w20 = scenario.wind_speed
    else:
        raise TypeError(f"scenario: expected one of {Scenario}, found {type(scenario).__name__}")
    meta: dict[str, str | int | float | bool] = {
        "source": "windahrs.simulate",
        "vehicle": vehicle,
        "w20": float(w20),
        "altitude": float(scenario.altitude),
        "scenario": repr(scenario),
    }
    return measure(traj, sensors, site, rng, meta=meta)


def default_sensors(scenario: Scenario) -> SensorSuite:
    """The default sensor suite of a scenario's vehicle."""
    if isinstance(scenario, QuadrotorScenario):
        return SensorSuite(pitot=None, vanes=None)
    return SensorSuite()
