"""``auto`` against the single estimators it chooses from, on every real recording under a
folder and on the simulated vehicles: is it ever worse than the best of them by more than 10 %?

    python benchmarks/auto_check.py [DIR] [--duration 120] [--seeds 3] [--out auto.json]

DIR defaults to ``$WINDAHRS_DATA`` or ``../shared/data``. The candidates are the estimators
``auto`` can run (``windahrs.filters.auto``): ``mekf``, ``mekf-air`` and ``ins-wind``; each is
scored where it runs. Score: the tilt RMSE (deg) against the recording's reference, aligned
(mount and clock) once on ``vqf``'s estimate as ``compare --align`` does (a GNSS stamped on the
reference's clock, ANSFL's, moved onto the IMU's by the same fit), from sample 50; on
simulated flights the tilt RMSE against the truth, RMS over ``--seeds`` seeds, for the fixed
wing and the quadrotor in calm air and 8 m/s wind. Tilt, because several references here have
no heading datum. Prints one line per case with ``auto``'s score, the best candidate's and
their ratio (``!`` beyond 1.10) and the count of such cases; exits 1 when there is one.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import warnings
from pathlib import Path

import numpy as np

import windahrs as wa
from windahrs.estimate import Estimate
from windahrs.experiments.benchdata import aligned_recordings
from windahrs.filters.base import MissingSensorError
from windahrs.filters.registry import make_estimator
from windahrs.flight import Flight
from windahrs.metrics import attitude_errors

CANDIDATES = ("mekf", "mekf-air", "ins-wind")
LIMIT = 1.10
SKIP = 50  # samples: the start, scored by the recovery benchmark instead


def quiet_run(spec: str, flight: Flight) -> Estimate | None:
    """``spec``'s estimate of ``flight``, its warnings silenced; None when it cannot run there."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return make_estimator(spec).run(flight)
        except (MissingSensorError, ValueError):
            return None


def _tilt_deg(spec: str, flight: Flight, scored: Flight) -> float | None:
    est = quiet_run(spec, flight)
    if est is None:
        return None
    tilt = attitude_errors(est, scored).tilt[SKIP:]
    tilt = tilt[np.isfinite(tilt)]
    return float(np.degrees(np.sqrt(np.mean(tilt**2)))) if len(tilt) else None


def _row(case: str, scores: dict[str, list[float]]) -> dict[str, object]:
    rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in scores.items() if v}
    best = min((v, k) for k, v in rms.items() if k != "auto")
    ratio = rms["auto"] / best[0] if best[0] > 0 else float("inf")
    return {"case": case, "auto_deg": rms["auto"], "best": best[1], "best_deg": best[0], "ratio": ratio,
            "worse": ratio > LIMIT, "scores_deg": rms}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    default = Path(os.environ.get("WINDAHRS_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("dir", nargs="?", type=Path, default=default)
    ap.add_argument("--duration", type=float, default=120.0, help="simulated flight length, s (default 120)")
    ap.add_argument("--seeds", type=int, default=3, help="simulated seeds per case (default 3)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    rows = []
    cases: list[tuple[str, list[tuple[Flight, Flight]]]] = []
    if args.dir.exists():
        for path, flight, scored in aligned_recordings(args.dir):
            cases.append((str(path.relative_to(args.dir)), [(flight, scored)]))
    else:
        print(f"auto_check.py: no recordings at {args.dir} (set WINDAHRS_DATA); simulated cases only",
              file=sys.stderr)
    for vehicle in ("fixedwing", "quadrotor"):
        for wind in (0.0, 8.0):
            sims = [wa.simulate(vehicle, seed=s, wind=wind, duration=args.duration) for s in range(args.seeds)]
            cases.append((f"sim {vehicle} {wind:g} m/s", [(f, f) for f in sims]))
    for case, flights in cases:
        scores: dict[str, list[float]] = {}
        for spec in ("auto", *CANDIDATES):
            vals = [_tilt_deg(spec, f, s) for f, s in flights]
            if all(v is not None for v in vals):
                scores[spec] = [float(v) for v in vals if v is not None]
        if "auto" not in scores or len(scores) < 2:
            continue
        row = _row(case, scores)
        rows.append(row)
        print(f"{case}: auto {row['auto_deg']:.3f}, best {row['best']} {row['best_deg']:.3f}, "
              f"ratio {row['ratio']:.3f}{' !' if row['worse'] else ''}", flush=True)
    n = sum(bool(r["worse"]) for r in rows)
    print(f"{n} of {len(rows)} cases with auto more than {100 * (LIMIT - 1):.0f} % worse than the best candidate")
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1))
    return 1 if n else 0


if __name__ == "__main__":
    sys.exit(main())
