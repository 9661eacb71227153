"""Tilt of estimators on simulated flights with the simulator's default sensors (a gyro bias
of about 1 deg/s per axis, drawn per seed): per vehicle, wind and seed the tilt RMSE from
sample 50, and per filter the sum over the cases.

    python benchmarks/sim_tilt.py [--filters mekf,mekf:lowpass_bias=false,vqf]
        [--vehicles quadrotor] [--winds 0,8] [--seeds 0,1,2,3] [--duration 60]

Each flight is simulated once and every filter runs on the same one (the filters are
compared within a case, not across seeds).
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np

import windahrs as wa
from windahrs.metrics import attitude_errors


def _floats(text: str) -> list[float]:
    return [float(v) for v in text.split(",") if v]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--filters", default="mekf,mekf:lowpass_bias=false,vqf")
    ap.add_argument("--vehicles", default="quadrotor")
    ap.add_argument("--winds", default="0,8")
    ap.add_argument("--seeds", default="0,1,2,3")
    ap.add_argument("--duration", type=float, default=60.0)
    args = ap.parse_args(argv)
    specs = [s for s in args.filters.split(",") if s]
    total = np.zeros(len(specs))
    print("vehicle    wind seed  " + "  ".join(f"{s:>24}" for s in specs))
    for vehicle in [v for v in args.vehicles.split(",") if v]:
        for wind in _floats(args.winds):
            for seed in [int(v) for v in _floats(args.seeds)]:
                flight = wa.simulate(vehicle, seed=seed, wind=wind, duration=args.duration)
                row = []
                for spec in specs:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        est = wa.estimator(spec).run(flight)
                    tilt = attitude_errors(est, flight).tilt[50:]
                    row.append(float(np.degrees(np.sqrt(np.mean(tilt**2)))))
                total += row
                print(f"{vehicle:10s} {wind:4.1f} {seed:4d}  " + "  ".join(f"{v:24.3f}" for v in row), flush=True)
    print(f"{'sum':21s}  " + "  ".join(f"{v:24.3f}" for v in total))
    return 0


if __name__ == "__main__":
    sys.exit(main())
