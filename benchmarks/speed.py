"""Speed of every registered estimator, in microseconds per IMU sample, on a simulated
fixed-wing flight (wind 8 m/s, default sensors, seed 0), plus the compiled twins of the
error-state filters (reported under the registry name; their readable references as
"NAME (reference)").

    python benchmarks/speed.py --out speed.json [--duration 60] [--repeat 20] [--budget 10]

Each estimator runs once to warm up (JIT compilation or a load from numba's cache; its
time is printed separately), then up to ``--repeat`` timed runs, stopping early once
``--budget`` seconds are spent (at least one timed run); the best is reported. A run is
``time.perf_counter`` around ``Estimator.run`` on the whole flight: event merging, the
filter, recording every state and covariance, and building the Estimate. For the compiled
twins the table also shows the kernel alone with and without recording, i.e. what writing
the (N, n, n) covariance and the states costs. Estimators whose package is missing are
skipped with a note. ``--cold-jit`` compiles from scratch (a fresh numba cache) to show
the true compile time. The JSON output is a list of {"name", "us_per_sample"}.

Machines differ: the figures in ../shared/ANCHORS.md (vqf's ``updateBatch`` 0.29 us/sample,
imufusion 1.07, ahrs's EKF 117) were taken on another 2-core machine. So the run also times
vqf's C++ core alone (``updateBatch`` on this flight's gyro, accelerometer and magnetometer,
contiguous float64, no adapter), reports it as "vqf core (calibration)" and prints the
targets of the issue (ins-wind and mekf at most 1.0 us/sample, usque at most 10) both as
measured here and scaled by ``0.29 / vqf core here`` to the anchors' machine.
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

#: vqf's updateBatch on the anchors' machine (../shared/ANCHORS.md), us/sample
ANCHOR_VQF_CORE_US = 0.29
#: the issue's speed targets, us/sample on the anchors' machine
TARGETS = {"ins-wind": 1.0, "mekf": 1.0, "usque": 10.0}

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


def vqf_core_factor(flight: Any, repeat: int, results: list[dict[str, Any]]) -> float | None:
    """Time vqf's updateBatch alone on the flight's IMU and magnetometer (held to the IMU
    grid), append it to ``results`` and return this machine's slowdown against the anchors'
    (None without vqf)."""
    try:
        from vqf import VQF
    except ImportError:
        print("vqf core (calibration): skipped, vqf is not installed (pip install 'windahrs[baselines]')")
        return None
    import numpy as np

    from windahrs.baselines._common import held_mag

    imu = flight.imu
    gyr = np.ascontiguousarray(imu.w_b, dtype=np.float64)
    acc = np.ascontiguousarray(imu.f_b, dtype=np.float64)
    # the magnetometer held on the IMU grid, in microtesla, as the vqf adapter feeds it
    m = np.ascontiguousarray(held_mag(flight, imu.t)[0]) if flight.mag is not None else None
    dt = float(np.median(np.diff(imu.t)))

    def run() -> None:
        v = VQF(dt)
        if m is None:
            v.updateBatch(gyr, acc)
        else:
            v.updateBatch(gyr, acc, m)

    _, times = timed_runs(run, max(repeat, 5), 30.0)
    us = min(times) / len(imu.t) * 1e6
    results.append({"name": "vqf core (calibration)", "us_per_sample": round(us, 4)})
    factor = us / ANCHOR_VQF_CORE_US
    print(f"{'vqf core (calibration)':24s} {us:10.3f} {len(times):5d} {'':>10s}   "
          f"vqf's updateBatch alone: this machine is {factor:.2f}x the anchors' {ANCHOR_VQF_CORE_US}")
    return factor


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="JSON file to write")
    ap.add_argument("--duration", type=float, default=60.0, help="flight length in s (default 60)")
    ap.add_argument("--repeat", type=int, default=20, help="timed runs per estimator (default 20: a shared "
                    "machine's timings vary by up to 2x from run to run; the best is reported)")
    ap.add_argument("--budget", type=float, default=10.0, help="seconds per estimator before stopping early "
                    "(default 10)")
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

    factor = vqf_core_factor(flight, args.repeat, results)
    if factor is not None:
        by_name = {r["name"]: r["us_per_sample"] for r in results}
        print(f"\ntargets (us/sample; 'scaled' = measured x {1 / factor:.3f}, this machine's vqf core "
              f"against the anchors' {ANCHOR_VQF_CORE_US}):")
        for name, bound in TARGETS.items():
            if name in by_name:
                us = by_name[name]
                verdict = "meets" if us / factor <= bound else "MISSES"
                print(f"  {name:10s} measured {us:7.3f}  scaled {us / factor:7.3f}  target {bound:5.1f}  {verdict}")

    with open(args.out, "w") as fh:
        json.dump(results, fh, indent=1)
        fh.write("\n")
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
