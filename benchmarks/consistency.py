"""How much a 50-run NEES check can say: the reproduction's consistency test repeated over
many blocks of 50 seeds.

    python benchmarks/consistency.py [--filter ins-wind] [--winds 5,8] [--runs 400] [--out nees.json]

``windahrs reproduce`` scores a physically tuned filter's consistency by the fraction of
second-half steps at which the 50-run average NEES (attitude and gyro bias, 6 dof) lies in
the two-sided 95 % chi-square band. For [ins-wind] that fraction depends strongly on the
seeds: its remaining errors come from slowly observable constants (gyro bias, accelerometer
bias, magnetometer hard iron), so each run's errors are strongly correlated over the flight
and a block of 50 runs tends to be in or out of the band as a whole. This benchmark runs ``--runs`` flights
per wind speed with the reproduction's own code (:func:`run_reproduction` with
``nees_runs``, the same scenario, seeds (:func:`flight_seed`), parameters and NEES check, as
``windahrs reproduce --nees-runs``), for any physically tuned filter, then reports

* over all runs: the time-averaged second-half NEES and the fraction of steps in the band
  of that many runs (a consistent filter: about 6 and 95 %);
* per block of 50 consecutive seeds (block 0 is the reproduction's 50 runs): the mean NEES
  and the fraction of steps in the 50-run band, the figure the reproduction reports;
* the correlation, over the runs, of a run's NEES at the start of the second half and 0.5,
  2.5 and 10 s later (0 if the errors were white), and the spread over the runs of each
  run's own second-half NEES mean (5.8 to 6.2 over 2000 steps if they were white);
* with more than 50 runs, the fraction of random sets of 50 of the runs (drawn without
  replacement from the same runs, so it understates the spread a little) that pass the
  >= 90 % test: how often a 50-run check passes this filter.

``--out`` writes {"filter", "wind", "runs", "nees_mean", "in_band", "band", "blocks":
[{"seeds", "nees_mean", "in_band"}], "nees_corr_at_lag_s", "per_run_mean_p01_p99" and,
with more than 50 runs, "random_blocks_passing"} per wind speed as a JSON list. About 4 s per 100 runs.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

BLOCK = 50
#: Random sets of BLOCK runs drawn from all the runs: how often one block passes by chance.
SUBSETS = 2000
#: Lags, s after the start of the second half, of the NEES correlation printed.
LAGS_S = (0.5, 2.5, 10.0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--filter", default="ins-wind", help="a physically tuned filter of the reproduction "
                    "(ins-wind, mekf, ekf7, usque; default ins-wind), optionally with overrides, e.g. "
                    "ins-wind:init_mag_bias=0 (the hard iron as noise, no bias states)")
    ap.add_argument("--winds", default="5,8", metavar="W,W", help="wind speeds, m/s (default 5,8)")
    ap.add_argument("--runs", type=int, default=400, help=f"runs per wind speed, a multiple of {BLOCK} "
                    "(default 400)")
    ap.add_argument("--duration", type=float, default=20.0, help="seconds per run (default 20, as reproduce)")
    ap.add_argument("--out", default=None, metavar="FILE.json", help="write the results as JSON")
    args = ap.parse_args(argv)
    if args.runs < BLOCK or args.runs % BLOCK:
        ap.error(f"--runs: expected a multiple of {BLOCK}, found {args.runs}")
    try:
        winds = [float(w) for w in args.winds.split(",") if w.strip()]
    except ValueError:
        ap.error(f"--winds: expected comma-separated numbers, found {args.winds!r}")

    import numpy as np
    from scipy.stats import chi2

    from windahrs.experiments.reproduce import (
        NEES_DIM,
        NEES_PASS,
        PHYSICAL,
        Case,
        case_key,
        flight_seed,
        nees_summary,
        run_reproduction,
    )

    bound = PHYSICAL.get(args.filter.split(":")[0])
    if bound is None:
        known = ", ".join(k for k, v in PHYSICAL.items() if v is not None)
        ap.error(f"--filter: expected a physically tuned filter with a NEES ({known}, with or without "
                 f"overrides NAME:field=value), found {args.filter!r}")
    out: list[dict[str, Any]] = []
    for w in winds:
        case = Case(w, args.filter, "estimated", "", bound)
        t0 = time.perf_counter()
        res = run_reproduction(BLOCK, duration=args.duration, cases=[case], nees_runs=args.runs, bound_fn=None)
        nees = res.nees[case_key(case)]
        total = nees_summary(nees)
        lo, hi = total["band"]
        row: dict[str, Any] = {
            "filter": args.filter, "wind": w, "runs": args.runs, "nees_mean": round(total["nees_mean"], 3),
            "in_band": round(total["in_band"], 3), "band": [round(lo, 3), round(hi, 3)], "blocks": [],
        }
        print(f"{args.filter}, {w:g} m/s, {args.runs} runs ({time.perf_counter() - t0:.0f} s): second-half NEES "
              f"{row['nees_mean']:.2f}, {100 * row['in_band']:.0f} % of steps in the {args.runs}-run band "
              f"[{lo:.2f}, {hi:.2f}]")
        for b in range(args.runs // BLOCK):
            blk = nees_summary(nees[b * BLOCK:(b + 1) * BLOCK])
            seeds = f"{flight_seed(w, b * BLOCK)}..{flight_seed(w, (b + 1) * BLOCK - 1)}"
            row["blocks"].append({"seeds": seeds, "nees_mean": round(blk["nees_mean"], 3),
                                  "in_band": round(blk["in_band"], 3)})
            tag = "  (the reproduction's runs)" if b == 0 else ""
            print(f"  block {b} seeds {seeds}: NEES {blk['nees_mean']:.2f}, {100 * blk['in_band']:5.1f} % of steps in "
                  f"the 50-run band [{blk['band'][0]:.2f}, {blk['band'][1]:.2f}]{tag}")
        passing = sum(blk["in_band"] >= NEES_PASS for blk in row["blocks"])
        print(f"  blocks with >= {100 * NEES_PASS:.0f} % of steps in the band: {passing} of {len(row['blocks'])}")
        steady = nees[:, nees.shape[1] // 2:]
        rate = (nees.shape[1] - 1) / args.duration
        corr = {}
        for lag_s in LAGS_S:
            lag = min(round(lag_s * rate), steady.shape[1] - 1)
            corr[f"{lag / rate:g}"] = round(float(np.corrcoef(steady[:, 0], steady[:, lag])[0, 1]), 3)
        row["nees_corr_at_lag_s"] = corr
        per_run = steady.mean(axis=1)
        row["per_run_mean_p01_p99"] = [round(float(v), 2) for v in np.percentile(per_run, [1, 99])]
        print("  correlation over the runs of a run's NEES at the start of the second half and "
              + ", ".join(f"{k} s" for k in corr) + " later: " + ", ".join(f"{v:.2f}" for v in corr.values())
              + " (0 if the errors were white)")
        k = steady.shape[1]
        white = chi2.ppf([0.01, 0.99], NEES_DIM * k) / k
        print(f"  a run's own second-half NEES mean, 1st to 99th percentile over the runs: "
              f"{row['per_run_mean_p01_p99'][0]:.1f} to {row['per_run_mean_p01_p99'][1]:.1f} (white errors: "
              f"{white[0]:.2f} to {white[1]:.2f})")
        if args.runs > BLOCK:
            rng = np.random.default_rng(0)
            draws = [nees_summary(nees[rng.choice(args.runs, BLOCK, replace=False)])["in_band"] >= NEES_PASS
                     for _ in range(SUBSETS)]
            row["random_blocks_passing"] = round(float(np.mean(draws)), 3)
            print(f"  random sets of {BLOCK} of the {args.runs} runs ({SUBSETS} draws, without replacement) with "
                  f">= {100 * NEES_PASS:.0f} % of steps in the band: {100 * row['random_blocks_passing']:.1f} %")
        out.append(row)
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(out, fh, indent=1)
            fh.write("\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
