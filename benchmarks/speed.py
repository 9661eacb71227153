"""Speed of every registered estimator, in microseconds per IMU sample, on a simulated
fixed-wing flight (wind 8 m/s, default sensors, seed 0), plus the compiled twins of the
error-state filters (reported under the registry name; their readable references as
"NAME (reference)").

    python benchmarks/speed.py --out speed.json [--duration 60] [--repeat 3]

Each estimator runs once to warm up (JIT compilation or a load from numba's cache; its
time is printed separately), then up to ``--repeat`` timed runs, stopping early once
``--budget`` seconds are spent (at least one timed run); the best is reported. A run is
``time.perf_counter`` around ``Estimator.run`` on the whole flight: event merging, the
filter, recording every state and covariance, and building the Estimate. For the compiled
twins the table also shows the kernel alone with and without recording, i.e. what writing
the (N, n, n) covariance and the states costs. Estimators whose package is missing are
skipped with a note. ``--cold-jit`` compiles from scratch (a fresh numba cache) to show
the true compile time. The JSON output is a list of {"name", "us_per_sample"}.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from collections.abc import Callable
from typing import Any

#: compiled twins: registry name -> (reference module, class), (compiled class)
TWINS = {
    "mekf": ("windahrs.filters.eskf", "Mekf", "MekfFast"),
    "mekf-air": ("windahrs.filters.eskf", "MekfAir", "MekfAirFast"),
    "ins-wind": ("windahrs.filters.eskf", "InsWind", "InsWindFast"),
    "ekf7": ("windahrs.filters.ekf7", "Ekf7", "Ekf7Fast"),
    "ekf10": ("windahrs.filters.ekf7", "Ekf10", "Ekf10Fast"),
}


def timed_runs(run: Callable[[], Any], repeat: int, budget: float) -> tuple[float, list[float]]:
    """Warm-up time and the timed runs (s)."""
    t0 = time.perf_counter()
    run()
    first = time.perf_counter() - t0
    spent, times = first, []
    while len(times) < repeat and (not times or spent < budget):
        t0 = time.perf_counter()
        run()
        times.append(time.perf_counter() - t0)
        spent += times[-1]
    return first, times


def kernel_times(est: Any, flight: Any, repeat: int) -> tuple[float, float]:
    """Best time (s) of the compiled loop alone, with and without recording the states."""
    import numpy as np

    from windahrs.filters import compiled as C
    from windahrs.filters.base import merge_events

    has = frozenset(s for s in ("imu", "mag", "gnss", "air") if getattr(flight, s) is not None) & est.uses
    t_ev, kinds, vals = merge_events(flight, has)
    caps = np.full(6, len(t_ev), dtype=np.int64)
    L = C.layout_of(est.kind, est.params, est.additive)
    N, d = len(flight.imu.t), L.dim
    out = {}
    for rec in (True, False):
        best = np.inf
        for _ in range(repeat + 1):
            st = C.make_state(est.kind, est.additive, est.params, flight.site, None, has, caps)
            q, bg, v, w = (np.empty((N, k)) for k in (4, 3, 3, 3))
            cov = np.empty((N, d, d))
            t0 = time.perf_counter()
            C.run_events(st, t_ev, kinds, vals, q, bg, v, w, cov, rec)
            best = min(best, time.perf_counter() - t0)
        out[rec] = best
    return out[True], out[False]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="JSON file to write")
    ap.add_argument("--duration", type=float, default=60.0, help="flight length in s (default 60)")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per estimator (default 3)")
    ap.add_argument("--budget", type=float, default=60.0, help="seconds per estimator before stopping early")
    ap.add_argument("--cold-jit", action="store_true", help="compile numba code from scratch")
    args = ap.parse_args()
    if args.cold_jit:  # before numba is imported
        os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="windahrs-speed-")

    import importlib

    import numpy as np

    from windahrs.filters.registry import REGISTRY, make_estimator
    from windahrs.sim.scenario import make_scenario, simulate

    flight = simulate(make_scenario("fixedwing", wind=8.0, duration=args.duration), np.random.default_rng(0))
    n = len(flight.imu.t)
    print(f"fixed wing, wind 8 m/s, {args.duration:g} s, {n} IMU samples; best of up to {args.repeat} runs")
    print(f"{'estimator':24s} {'us/sample':>10s} {'runs':>5s} {'warm-up s':>10s}   notes")
    results: list[dict[str, Any]] = []

    def measure(name: str, est: Any, note: str = "") -> None:
        try:
            first, times = timed_runs(lambda: est.run(flight), args.repeat, args.budget)
        except Exception as exc:  # an estimator that cannot run this flight: say so, go on
            print(f"{name:24s} {'-':>10s} {'':>5s} {'':>10s}   skipped: {type(exc).__name__}: {exc}")
            return
        us = min(times) / n * 1e6
        results.append({"name": name, "us_per_sample": round(us, 4)})
        print(f"{name:24s} {us:10.3f} {len(times):5d} {first:10.2f}   {note}", flush=True)

    for name in REGISTRY:
        if name in TWINS:
            module, ref_name, fast_name = TWINS[name]
            try:
                ref_cls = getattr(importlib.import_module(module), ref_name)
                fast_cls = getattr(importlib.import_module("windahrs.filters.compiled"), fast_name)
            except (ImportError, AttributeError) as exc:
                print(f"{name:24s} skipped: {exc}")
                continue
            fast = fast_cls()
            measure(name, fast, "compiled (numba)")
            with_rec, without = kernel_times(fast, flight, args.repeat)
            print(
                f"{'':24s} kernel alone {with_rec / n * 1e6:.3f} us/sample, without recording states and "
                f"covariance {without / n * 1e6:.3f} (recording {(with_rec - without) / n * 1e6:.3f})"
            )
            measure(f"{name} (reference)", ref_cls(), "readable Python reference")
            continue
        try:
            est = make_estimator(name)
        except (ImportError, ValueError) as exc:
            print(f"{name:24s} skipped: {exc}")
            continue
        measure(name, est, REGISTRY[name][2])

    with open(args.out, "w") as fh:
        json.dump(results, fh, indent=1)
        fh.write("\n")
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
