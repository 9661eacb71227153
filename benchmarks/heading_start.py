"""Where a recording's heading error comes from: its first seconds or the rest of the flight.

    python benchmarks/heading_start.py [DIR] [--filters vqf,mekf,auto] [--split 3] [--out heading.json]

DIR defaults to ``$WINDAHRS_DATA`` or ``../shared/data``. Every recording under DIR with a
reference is aligned (mount and clock) on ``vqf``'s estimate, as ``bench-data --align`` does
(:func:`windahrs.experiments.benchdata.aligned_recordings`), and each filter is scored with
bench-data's metric (:func:`windahrs.experiments.benchdata.broad_errors`: a constant heading
offset removed where the reference or the recording has no heading datum). Printed per
recording and filter, RMSE in deg: the total, the heading over the whole recording, over its
first ``--split`` s, and after them; then the medians over the recordings.

Why: on a recording without a magnetometer the heading is scored free of its datum, i.e. one
constant offset removed for the whole flight. A filter whose heading never learns north (vqf,
``mekf``) keeps one datum and is scored on its drift alone; an INS that learns north from GNSS
velocity starts from a heading it does not know and turns to the true one once it knows it, so
no single offset fits both parts and the first seconds weigh on its whole-flight heading. The
split says which part a filter's heading error is. 3 s (the default) is past the moment
``auto`` took the INS's heading on each of the 16 ANSFL flights (0.76-2.2 s, its meta
``auto_handover_s``, docs/RESULTS.md section 44); it is a reporting split, no estimator reads it.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

from windahrs.experiments.benchdata import aligned_recordings, broad_errors
from windahrs.filters.registry import make_estimator

sys.path.insert(0, str(Path(__file__).resolve().parent))
from auto_check import quiet_run  # (a benchmark beside this one)


def _rms_deg(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.degrees(np.sqrt(np.mean(x**2)))) if len(x) else None


def split_scores(spec: str, flight, scored, split: float) -> dict[str, float | None] | None:
    """One filter on one recording: total, heading, heading before and after ``split`` s from
    the first scored sample (deg), or None when the filter cannot run on it."""
    est = quiet_run(spec, flight)
    if est is None:
        return None
    b = broad_errors(est, scored)
    early = b.t - b.t[0] < split
    return {"total": _rms_deg(b.total), "heading": _rms_deg(b.heading), "heading_first": _rms_deg(b.heading[early]),
            "heading_after": _rms_deg(b.heading[~early])}


def _cell(v: float | None) -> str:
    return f"{v:8.2f}" if v is not None else f"{'-':>8s}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    default = Path(os.environ.get("WINDAHRS_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("dir", nargs="?", type=Path, default=default)
    ap.add_argument("--filters", default="vqf,mekf,auto", help="comma-separated specs (default vqf,mekf,auto)")
    ap.add_argument("--split", type=float, default=3.0, help="the first seconds scored apart (default 3)")
    ap.add_argument("--out", type=Path, default=None, help="write the rows as JSON")
    args = ap.parse_args(argv)
    if not args.split > 0:
        ap.error(f"--split: expected seconds > 0, found {args.split}")
    if not args.dir.exists():
        print(f"heading_start.py: no recordings at {args.dir} (set WINDAHRS_DATA)", file=sys.stderr)
        return 2
    specs = [s for s in args.filters.split(",") if s]
    for s in specs:
        make_estimator(s)  # (an unknown name fails here, before any recording is read)
    rows = []
    head = f"{'recording':28s} {'filter':9s} {'total':>8s} {'heading':>8s} {'first':>8s} {'after':>8s}"
    print(f"RMSE in deg; first: the first {args.split:g} s, after: the rest\n{head}")
    for path, flight, scored in aligned_recordings(args.dir):
        name = str(path.relative_to(args.dir))
        for spec in specs:
            r = split_scores(spec, flight, scored, args.split)
            if r is None:
                continue
            rows.append({"recording": name, "filter": spec, **r})
            print(f"{name[-28:]:28s} {spec:9s} " + " ".join(_cell(r[k]) for k in ("total", "heading",
                                                                                    "heading_first", "heading_after")),
                  flush=True)
    print(f"\nmedian over recordings\n{'':28s} {'filter':9s} {'total':>8s} {'heading':>8s} {'first':>8s} {'after':>8s}")
    for spec in specs:
        mine = [r for r in rows if r["filter"] == spec]
        med = {k: float(np.median([r[k] for r in mine if r[k] is not None])) if any(r[k] is not None for r in mine)
               else None for k in ("total", "heading", "heading_first", "heading_after")}
        print(f"{f'({len(mine)} recordings)':28s} {spec:9s} " + " ".join(_cell(med[k]) for k in med))
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1))
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
