"""The multirotor drag aid source: wind and tilt of a simulated quadrotor, with and without
drag fusion.

    python benchmarks/drag.py [--runs 10] [--duration 120] [--wind 8] [--filters A,B,...] [--out drag.json]

Simulates ``--runs`` seeded quadrotor flights holding position in W20 = ``--wind`` m/s
MIL-F-8785C wind with Dryden turbulence (the default sensors: IMU, magnetometer, GNSS
velocity; no pitot), runs each filter spec on each, and prints per filter the RMS over the
runs of: the horizontal wind RMSE after 30 s (``metrics.wind_errors``), the direction error
of the mean wind, the tilt and total attitude RMSE (``metrics.score``, from sample 50).

The default filters are [ins-wind] (no drag: its wind states are not observable without air
data), [ins-drag] with PX4's default coefficients (EKF2_MCOEF 0.15 1/s and a bluff-body
term of 100 kg/m^2, not the simulated airframe's) and [ins-drag] with the coefficients of
the simulated airframe (rotor drag mu = 0.3 1/s, :class:`windahrs.sim.quadrotor.QuadrotorScenario`,
no bluff-body term), as a user who tuned them by PX4's procedure would set them.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

DEFAULT_FILTERS = "ins-wind,ins-drag,ins-drag:drag_mcoef=0.3:drag_bcoef_x=0:drag_bcoef_y=0"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--wind", type=float, default=8.0, help="W20, m/s")
    ap.add_argument("--filters", default=DEFAULT_FILTERS)
    ap.add_argument("--out", help="write the rows as JSON")
    a = ap.parse_args(argv)
    from windahrs.filters.registry import make_estimator
    from windahrs.metrics import score, wind_errors
    from windahrs.sim.scenario import make_scenario, simulate

    specs = [s for s in a.filters.split(",") if s]
    ests = [make_estimator(s) for s in specs]
    sc = make_scenario("quadrotor", wind=a.wind, duration=a.duration)
    acc: dict[str, dict[str, list[float]]] = {s: {"wind": [], "dir": [], "tilt": [], "total": []} for s in specs}
    t0 = time.perf_counter()
    for r in range(a.runs):
        fl = simulate(sc, np.random.default_rng(r))
        for spec, est in zip(specs, ests, strict=True):
            e = est.run(fl)
            s = score(e, fl)
            acc[spec]["tilt"].append(s.rmse_tilt_deg)
            acc[spec]["total"].append(s.rmse_total_deg)
            w = wind_errors(e, fl)
            acc[spec]["wind"].append(w.rmse_h)
            acc[spec]["dir"].append(w.direction_deg)
        print(f"run {r + 1}/{a.runs} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)

    def rms(v: list[float]) -> float:
        return float(np.sqrt(np.mean(np.square(v))))

    rows = [
        {
            "filter": spec,
            "runs": a.runs,
            "wind_rmse_h_ms": rms(v["wind"]),
            "wind_direction_deg_rms": rms(v["dir"]),
            "wind_direction_deg_max": float(np.max(np.abs(v["dir"]))),
            "tilt_rmse_deg": rms(v["tilt"]),
            "total_rmse_deg": rms(v["total"]),
        }
        for spec, v in acc.items()
    ]
    print(f"quadrotor, W20 = {a.wind:g} m/s, {a.duration:g} s, {a.runs} seeds; wind after 30 s, RMS over runs")
    print(f"{'filter':<58}{'wind m/s':>9}{'dir deg':>9}{'max dir':>9}{'tilt deg':>9}{'total':>8}")
    for row in rows:
        print(
            f"{row['filter']:<58}{row['wind_rmse_h_ms']:>9.3f}{row['wind_direction_deg_rms']:>9.2f}"
            f"{row['wind_direction_deg_max']:>9.2f}{row['tilt_rmse_deg']:>9.3f}{row['total_rmse_deg']:>8.3f}"
        )
    if a.out:
        with open(a.out, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
