"""No silent divergence: every windahrs estimator on every real recording the readers find
under a folder, and whether it ends more than 10 deg in tilt from the recording's reference
without saying so.

    python benchmarks/silent.py [DIR] [--filters auto,mekf,...] [--out silent.json]

DIR defaults to ``$WINDAHRS_DATA`` or ``../shared/data``. Each recording's reference is
aligned (mount and clock) on ``vqf``'s estimate, as ``compare --align`` does, a GNSS stamped on
the reference's clock (ANSFL's) moved onto the IMU's by the same fit (the reference and the
GNSS as they are when the alignment fails). For each estimator that can run on it: the median tilt error
over the last 5 % of the scored samples, whether it emitted an EstimatorWarning (resets,
tilt alerts, low acceptance), and ``silent`` when it ends beyond 10 deg without one. Prints one
line per recording (``filter=final_deg`` with ``w`` for warned and ``!`` for silent) and the
count of silent cases; exits 1 when there is one.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from windahrs.estimate import EstimatorWarning
from windahrs.experiments.benchdata import aligned_recordings
from windahrs.filters.base import MissingSensorError
from windahrs.filters.registry import make_estimator
from windahrs.metrics import attitude_errors

DEFAULT_FILTERS = "auto,mekf,ekf7,usque,ins-wind,mekf-air,ekf10,paper-nowind,ekf,ukf"
LIMIT_DEG = 10.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    default = Path(os.environ.get("WINDAHRS_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("dir", nargs="?", type=Path, default=default)
    ap.add_argument("--filters", default=DEFAULT_FILTERS)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    if not args.dir.exists():
        print(f"silent.py: no recordings at {args.dir} (set WINDAHRS_DATA)", file=sys.stderr)
        return 2
    rows = []
    for path, flight, scored in aligned_recordings(args.dir):
        cells = []
        for spec in args.filters.split(","):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    est = make_estimator(spec).run(flight)
                except (MissingSensorError, ValueError):
                    continue
            tilt = np.degrees(attitude_errors(est, scored).tilt)
            final = float(np.nanmedian(tilt[-max(1, len(tilt) // 20) :]))
            warned = any(issubclass(w.category, EstimatorWarning) for w in caught)
            silent = final > LIMIT_DEG and not warned
            rows.append({"recording": str(path), "filter": spec, "final_tilt_deg": final, "warned": warned,
                         "silent": silent})
            cells.append(f"{spec}={final:.1f}{'!' if silent else ('w' if warned else '')}")
        print(f"{path.name}: {' '.join(cells)}", flush=True)
    n_silent = sum(r["silent"] for r in rows)
    print(f"{n_silent} silent of {len(rows)} runs (ending > {LIMIT_DEG:g} deg off without a warning)")
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1))
    return 1 if n_silent else 0


if __name__ == "__main__":
    sys.exit(main())
