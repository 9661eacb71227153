"""A compass mounted wrong: the magnetometer's field turned about body z for the whole
flight (a board rotated in its mount, a misconfigured orientation), on simulated flights.

    python benchmarks/wrong_compass.py [--filters ins-wind,ins-wind:gate_mag=5] [--turn 90]
        [--seeds 0,1] [--duration 90] [--tail 20] [--out wrong_compass.json]

Per vehicle (fixed wing and quadrotor, W20 8 m/s), seed and filter: the resets logged per
sensor, the tilt and total RMSE from sample 50 against the truth, and the total RMSE over the
last ``--tail`` s (does the filter end on the heading GNSS shows, or on the compass's?).
``--out`` writes the same as JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import warnings
from pathlib import Path

import numpy as np

import windahrs as wa
from windahrs.metrics import attitude_errors


def _rms_deg(x: np.ndarray) -> float:
    return float(np.degrees(np.sqrt(np.mean(x**2))))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--filters", default="ins-wind")
    ap.add_argument("--turn", type=float, default=90.0, help="the field's turn about body z, deg (default 90)")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--duration", type=float, default=90.0)
    ap.add_argument("--tail", type=float, default=20.0, help="the last seconds scored apart (default 20)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    c, s = np.cos(np.radians(args.turn)), np.sin(np.radians(args.turn))
    rows = []
    for vehicle in ("fixedwing", "quadrotor"):
        for seed in (int(v) for v in args.seeds.split(",") if v.strip()):
            flight = wa.simulate(vehicle, seed=seed, wind=8.0, duration=args.duration)
            if flight.mag is None:
                print(f"{vehicle} seed {seed}: no magnetometer, skipped", flush=True)
                continue
            m = flight.mag.mag_b
            turned = np.column_stack([c * m[:, 0] - s * m[:, 1], s * m[:, 0] + c * m[:, 1], m[:, 2]])
            faulty = dataclasses.replace(flight, mag=dataclasses.replace(flight.mag, mag_b=turned))
            for spec in (f for f in args.filters.split(",") if f):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    est = wa.estimator(spec).run(faulty)
                e = attitude_errors(est, flight)
                tail = e.t >= e.t[-1] - args.tail
                row = {"vehicle": vehicle, "seed": seed, "filter": spec, "turn_deg": args.turn,
                       "resets": {k: len(v) for k, v in est.resets.items()},
                       "tilt_deg": _rms_deg(e.tilt[50:]), "total_deg": _rms_deg(e.total[50:]),
                       "tail_total_deg": _rms_deg(e.total[tail])}
                rows.append(row)
                print(f"{vehicle} seed {seed} {spec}: resets {row['resets']}, tilt {row['tilt_deg']:.2f}, "
                      f"total {row['total_deg']:.2f}, last {args.tail:g} s total {row['tail_total_deg']:.2f} deg",
                      flush=True)
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
