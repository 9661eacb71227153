"""Recovery from a wrong start: every windahrs estimator started 90 and 180 deg off in roll
and in pitch (or in heading, ``--errors``) on simulated flights, and the time it takes to
come within 2 deg of the truth.

    python benchmarks/recovery.py [--filters mekf,ekf7,...] [--errors roll90,roll180,pitch90,pitch180]
        [--seeds 3] [--duration 30] [--attitude-only] [--rms-after 10] [--out recovery.json]

Each filter runs from the truth's initial state rotated by the error (roll and pitch: about
the body axes; yaw: about the nav vertical), with the true velocity and wind, or the attitude
alone with ``--attitude-only``, on a fixed wing and a quadrotor in calm air and in 8 m/s
wind, for each of ``--seeds``. Prints per case the seconds until the tilt and until the total
error first fall below 2 deg (``-`` for never within the flight), then the seconds after
which the total error stays below 2 deg (``settle``) and its RMS from ``--rms-after`` s on,
and the resets the filter logged; ``--out`` writes the same as JSON. A filter a flight cannot
run (a missing sensor) is left out of that flight's lines.
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

#: The errors --errors names: the axis's index and whether the turn is about the nav frame's
#: axis (heading: about the vertical) rather than the body's.
AXES = {"roll": (0, False), "pitch": (1, False), "yaw": (2, True)}
WITHIN_DEG = 2.0


def _first_below(t: np.ndarray, err_rad: np.ndarray) -> float | None:
    ok = np.flatnonzero(np.degrees(err_rad) < WITHIN_DEG)
    return float(t[ok[0]] - t[0]) if len(ok) else None


def _settle(t: np.ndarray, err_rad: np.ndarray) -> float | None:
    """Seconds after which the error stays below WITHIN_DEG (None: not by the flight's end)."""
    bad = np.flatnonzero(np.degrees(err_rad) >= WITHIN_DEG)
    if len(bad) == 0:
        return 0.0
    return None if bad[-1] == len(t) - 1 else float(t[bad[-1] + 1] - t[0])


def _errors(text: str) -> list[tuple[str, int, bool, float]]:
    out = []
    for item in (s.strip() for s in text.split(",") if s.strip()):
        name = item.rstrip("0123456789.")
        if name not in AXES or name == item:
            raise SystemExit(f"recovery.py: --errors: expected e.g. roll90 or yaw180 (roll, pitch, yaw), "
                             f"found {item!r}")
        axis, nav = AXES[name]
        out.append((item, axis, nav, float(item[len(name):])))
    return out


def _seconds(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--filters", default="mekf,ekf7,usque,ins-wind,mekf-air,ekf10")
    ap.add_argument("--errors", default="roll90,roll180,pitch90,pitch180",
                    help="starts, e.g. roll90,pitch180,yaw45 (default roll and pitch, 90 and 180)")
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--seeds", default="3", help="comma-separated simulation seeds (default 3)")
    ap.add_argument("--attitude-only", action="store_true",
                    help="give the filter the wrong attitude alone, not the true velocity and wind")
    ap.add_argument("--rms-after", type=float, default=10.0, help="RMS of the total error from this time, s")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    errors = _errors(args.errors)
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    rows = []
    for vehicle in ("fixedwing", "quadrotor"):
        for wind in (0.0, 8.0):
            for seed in seeds:
                flight = wa.simulate(vehicle, seed=seed, wind=wind, duration=args.duration)
                truth = InitialState.from_truth(flight)
                for spec in args.filters.split(","):
                    cells = []
                    for name, axis, nav, deg in errors:
                        half = np.radians(deg) / 2
                        dq = np.r_[np.cos(half), np.sin(half) * (np.arange(3) == axis)]
                        q = quat_mul(dq, truth.q_nb) if nav else quat_mul(truth.q_nb, dq)
                        ini = (InitialState(q_nb=q) if args.attitude_only
                               else InitialState(q_nb=q, v_n=truth.v_n, wind_n=truth.wind_n))
                        with warnings.catch_warnings():
                            warnings.simplefilter("ignore")
                            try:
                                est = wa.estimator(spec).run(flight, initial=ini)
                            except MissingSensorError:
                                break
                        e = attitude_errors(est, flight)
                        late = e.t - e.t[0] >= args.rms_after
                        rms = float(np.degrees(np.sqrt(np.mean(e.total[late] ** 2)))) if late.any() else None
                        row = {"vehicle": vehicle, "wind": wind, "seed": seed, "filter": spec, "error": name,
                               "attitude_only": args.attitude_only,
                               "tilt_s": _first_below(e.t, e.tilt), "total_s": _first_below(e.t, e.total),
                               "settle_s": _settle(e.t, e.total), "rms_after_deg": rms,
                               "resets": {k: len(v) for k, v in est.resets.items()}}
                        rows.append(row)
                        shown = "-" if rms is None else f"{rms:.2f}"
                        cells.append(f"{name} {_seconds(row['tilt_s'])}/{_seconds(row['total_s'])} "
                                     f"(settle {_seconds(row['settle_s'])}, rms {shown})")
                    if cells:
                        print(f"{vehicle} {wind:g} m/s seed {seed} {spec}: " + ", ".join(cells), flush=True)
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
