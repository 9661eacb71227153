"""Truth trajectories for filter tests where the models hold exactly."""

from __future__ import annotations

import numpy as np

from windahrs.flight import Flight
from windahrs.rotation import quat_from_euler
from windahrs.sim.gust_response import rates_from_attitude
from windahrs.sim.scenario import default_site
from windahrs.sim.sensors import SensorSuite, TruthTrajectory, measure


def rotating_in_place(duration: float, rate: float, phase: float = 0.0) -> TruthTrajectory:
    """A body turning about a fixed point (no linear acceleration): gravity-only
    accelerometer models are exact. Roll +-40 deg, pitch +-25 deg, yaw sweeping."""
    t = np.arange(round(duration * rate) + 1) / rate
    rpy = np.column_stack(
        [
            0.7 * np.sin(0.9 * t + phase),
            0.45 * np.sin(0.6 * t + 1.0 + phase),
            1.5 * np.sin(0.25 * t + phase) + 0.3 * t,
        ]
    )
    q = quat_from_euler(rpy)
    z = np.zeros((len(t), 3))
    return TruthTrajectory(t=t, q_nb=q, w_b=rates_from_attitude(t, q), a_n=z, v_n=z, p_n=z, wind_n=z)


def flight_in_place(suite: SensorSuite, seed: int, duration: float = 20.0, phase: float = 0.0) -> Flight:
    traj = rotating_in_place(duration, suite.imu_rate, phase)
    return measure(traj, suite, default_site(), np.random.default_rng(seed))
