"""Recovery from a wrong start: every windahrs estimator started 90 and 180 deg off in roll
and in pitch on simulated flights, and the time it takes to come within 2 deg of the truth.

    python benchmarks/recovery.py [--filters mekf,ekf7,...] [--duration 30] [--seed 3] [--out recovery.json]

Each filter runs from the truth's initial state rotated by the error (body frame), on a
fixed wing and a quadrotor in calm air and in 8 m/s wind. Prints per case the seconds until
the tilt and until the total error first fall below 2 deg (``-`` for never within the
flight), and the resets the filter logged; ``--out`` writes the same as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

import windahrs as wa
from windahrs.filters.base import InitialState, MissingSensorError
from windahrs.metrics import attitude_errors
from windahrs.rotation import quat_mul

ERRORS = (("roll", 0, 90.0), ("roll", 0, 180.0), ("pitch", 1, 90.0), ("pitch", 1, 180.0))
WITHIN_DEG = 2.0


def _first_below(t: np.ndarray, err_rad: np.ndarray) -> float | None:
    ok = np.flatnonzero(np.degrees(err_rad) < WITHIN_DEG)
    return float(t[ok[0]] - t[0]) if len(ok) else None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--filters", default="mekf,ekf7,usque,ins-wind,mekf-air,ekf10")
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    rows = []
    for vehicle in ("fixedwing", "quadrotor"):
        for wind in (0.0, 8.0):
            flight = wa.simulate(vehicle, seed=args.seed, wind=wind, duration=args.duration)
            truth = InitialState.from_truth(flight)
            for spec in args.filters.split(","):
                cells = []
                for axis_name, axis, deg in ERRORS:
                    half = np.radians(deg) / 2
                    dq = np.r_[np.cos(half), np.sin(half) * (np.arange(3) == axis)]
                    ini = InitialState(q_nb=quat_mul(truth.q_nb, dq), v_n=truth.v_n, wind_n=truth.wind_n)
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        try:
                            est = wa.estimator(spec).run(flight, initial=ini)
                        except MissingSensorError:
                            break
                    e = attitude_errors(est, flight)
                    row = {"vehicle": vehicle, "wind": wind, "filter": spec, "error": f"{axis_name} {deg:g}",
                           "tilt_s": _first_below(e.t, e.tilt), "total_s": _first_below(e.t, e.total),
                           "resets": {k: len(v) for k, v in est.resets.items()}}
                    rows.append(row)
                    show = [("-" if row[k] is None else f"{row[k]:.1f}") for k in ("tilt_s", "total_s")]
                    cells.append(f"{axis_name}{deg:g} {show[0]}/{show[1]}")
                if cells:
                    print(f"{vehicle} {wind:g} m/s {spec}: " + ", ".join(cells), flush=True)
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
