"""Simulator figures for the foundation issue: Dryden statistics, zero-noise consistency
and the size of the wind effect. Prints a table; takes about a minute.

    python benchmarks/sim_checks.py
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.signal import welch

from windahrs.rotation import quat_angle, quat_exp, quat_mul, quat_normalize, quat_rotate_inv
from windahrs.sim.atmosphere import WindConfig
from windahrs.sim.fixedwing import FixedWingScenario
from windahrs.sim.quadrotor import QuadrotorScenario
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.sim.sensors import SensorSuite
from windahrs.sim.wind import dryden_gusts, dryden_psd, low_altitude_params


def gravity_angle_deg(f) -> np.ndarray:
    up_b = quat_rotate_inv(f.truth.q_nb, [0.0, 0.0, -1.0])
    c = np.sum(f.imu.f_b * up_b, axis=1) / np.linalg.norm(f.imu.f_b, axis=1)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="seeds per wind-effect case (default 3)")
    args = ap.parse_args()
    t0 = time.perf_counter()

    p = low_altitude_params(8.0, 50.0)
    dt, n = 0.005, 1_000_000
    g = np.concatenate([dryden_gusts(p, 15.0, dt, n, np.random.default_rng(s)) for s in range(4)])
    sig = np.array([p.sigma_u, p.sigma_v, p.sigma_w])
    print("Dryden, W20 = 8 m/s, h = 50 m, V = 15 m/s, 4 x 1e6 samples at 200 Hz")
    print("  std / MIL sigma (u, v, w):", np.round(g.std(axis=0) / sig, 4))
    f, s = welch(g[:n], fs=1 / dt, nperseg=2**15, axis=0)
    band = (f >= 0.05) & (f <= 0.5)
    ratio = (s[band] / dryden_psd(p, 15.0, f[band])).mean(axis=0)
    print("  Welch PSD / analytic, mean over 0.05-0.5 Hz:", np.round(ratio, 4))

    suite = SensorSuite().noiseless()
    for vehicle in ("fixedwing", "quadrotor", "paper"):
        sensors = suite if vehicle != "quadrotor" else SensorSuite(pitot=None, vanes=None).noiseless()
        fl = simulate(
            make_scenario(vehicle, wind=8.0, duration=60.0), np.random.default_rng(1), sensors=sensors
        )
        q = fl.truth.q_nb[0]
        for k in range(1, len(fl.imu.t)):
            q = quat_normalize(quat_mul(q, quat_exp(fl.imu.w_b[k] * (fl.imu.t[k] - fl.imu.t[k - 1]))))
        acc = quat_rotate_inv(fl.truth.q_nb[1:], np.diff(fl.truth.v_n, axis=0) / dt - fl.site.gravity_n)
        print(
            f"zero noise, {vehicle:9s} 60 s: gyro-integrated attitude error "
            f"{float(quat_angle(q, fl.truth.q_nb[-1])):.2e} rad, accelerometer - C_bn(a - g) "
            f"{np.abs(fl.imu.f_b[1:] - acc).max():.2e} m/s^2"
        )

    fw = [
        gravity_angle_deg(
            simulate(
                FixedWingScenario(duration=300.0, altitude=50.0, wind=WindConfig(w20=8.0), plan="level"),
                np.random.default_rng(s),
                sensors=suite,
            )
        ).mean()
        for s in range(args.seeds)
    ]
    print(
        f"fixed wing level, 50 m, W20 = 8: mean angle f vs gravity = {np.mean(fw):.2f} deg"
        f"  (per seed {np.round(fw, 2)})"
    )
    qsuite = SensorSuite(pitot=None, vanes=None).noiseless()
    for w20 in (5.0, 8.0):
        qd = [
            np.sqrt(
                np.mean(
                    gravity_angle_deg(
                        simulate(
                            QuadrotorScenario(duration=300.0, altitude=20.0, wind=WindConfig(w20=w20)),
                            np.random.default_rng(s),
                            sensors=qsuite,
                        )
                    )
                    ** 2
                )
            )
            for s in range(args.seeds)
        ]
        print(
            f"quadrotor hold, 20 m, W20 = {w20:.0f}: gravity-only tilt error RMS = {np.mean(qd):.2f} deg"
            f"  (per seed {np.round(qd, 2)})"
        )
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
