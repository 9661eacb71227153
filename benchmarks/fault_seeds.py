"""The fault matrix over several seeds: which fault x filter cells miss issue 13's criteria on
flights other than the one ``windahrs faults`` runs by default.

    python benchmarks/fault_seeds.py [--seeds 0-5] [--vehicles fixedwing,quadrotor]
        [--filters ins-wind,mekf,mekf-air,auto] [--wind 8] [--out seeds.json]

One seed draws one flight (turbulence, sensor noise and biases, the trajectory's details) and
the faults' own draws; ``windahrs faults --seed N`` is one of these runs. Each seed's line
gives the matrix's counts (``windahrs.experiments.faults.counts``: runs whose fault changed
the flight, flagged within 1 s of the fault's onset, back under twice the pre-fault RMS
within 10 s, with NaN); then, per vehicle, fault and filter, the seeds on which the cell was
not flagged within 1 s or did not recover within 10 s (with its recovery time, ``-`` for
never). ``--out`` writes every row (``FaultRow.as_dict`` plus the seed) as JSON. A filter a
vehicle cannot run (``mekf-air`` on the quadrotor, no air data) is left out, as the matrix
does. About 10 s per seed and vehicle on this machine's cores.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

from windahrs.experiments.faults import (
    DEFAULT_FAULT_FILTERS,
    RECOVERY_ALLOWANCE_S,
    FaultRow,
    counts,
    run_fault_matrix,
)


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        lo, _, hi = part.partition("-")
        try:
            a, b = int(lo), int(hi or lo)
        except ValueError:
            raise SystemExit(f"fault_seeds.py: --seeds: expected e.g. 0-5 or 0,3,7, found {text!r}") from None
        if a < 0 or b < a:
            raise SystemExit(f"fault_seeds.py: --seeds: expected 0 <= first <= last, found {part!r}")
        out.extend(range(a, b + 1))
    if not out:
        raise SystemExit("fault_seeds.py: --seeds: expected at least one seed, found none")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0-5", help="seeds, e.g. 0-5 or 0,3,7 (default 0-5)")
    ap.add_argument("--vehicles", default="fixedwing,quadrotor")
    ap.add_argument("--filters", default=",".join(DEFAULT_FAULT_FILTERS))
    ap.add_argument("--wind", type=float, default=8.0, help="W20, m/s (default 8)")
    ap.add_argument("--out", type=Path, metavar="FILE.json")
    a = ap.parse_args(argv)
    seeds = _seeds(a.seeds)
    vehicles = [v.strip() for v in a.vehicles.split(",") if v.strip()]
    filters = [f.strip() for f in a.filters.split(",") if f.strip()]
    rows: list[dict[str, object]] = []
    live: list[FaultRow] = []
    missed_flag: dict[tuple[str, str, str], list[str]] = defaultdict(list)
    missed_rec: dict[tuple[str, str, str], list[str]] = defaultdict(list)
    for seed in seeds:
        for vehicle in vehicles:
            try:
                res = run_fault_matrix(vehicle, filters, wind=a.wind, seed=seed)
            except ValueError as exc:
                raise SystemExit(f"fault_seeds.py: {exc}") from None
            c = counts(res.rows)
            print(f"{vehicle} seed {seed}: {c.runs} runs, {c.flagged} flagged within 1 s, {c.recovered} recovered "
                  f"within {RECOVERY_ALLOWANCE_S:g} s, {c.with_nan} with NaN", file=sys.stderr, flush=True)
            for r in res.rows:
                rows.append({**r.as_dict(), "seed": seed})
                if r.no_effect:
                    continue
                live.append(r)
                key = (vehicle, r.fault, r.filter)
                if not r.flagged:
                    missed_flag[key].append(str(seed))
                if r.recover_s is None or r.recover_s > RECOVERY_ALLOWANCE_S:
                    missed_rec[key].append(f"{seed} ({'-' if r.recover_s is None else f'{r.recover_s:.1f} s'})")
    c = counts(live)
    print(f"\n{c.runs} runs over seeds {a.seeds}: {c.flagged} flagged within 1 s, {c.recovered} recovered within "
          f"{RECOVERY_ALLOWANCE_S:g} s, {c.with_nan} with NaN")
    for title, missed in (("not flagged within 1 s of the onset", missed_flag),
                          (f"not back under twice the pre-fault RMS within {RECOVERY_ALLOWANCE_S:g} s", missed_rec)):
        print(f"\n{title} (vehicle, fault, filter: seeds):")
        for (vehicle, fault, spec), which in sorted(missed.items()):
            print(f"  {vehicle:9s} {fault:20s} {spec:10s} {', '.join(which)}")
        if not missed:
            print("  none")
    if a.out is not None:
        a.out.write_text(json.dumps(rows, indent=1) + "\n")
        print(f"\nwrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
