"""Throughput and scaling of ``windahrs sweep``: the same sweep of at least 1000 rows on a
local Dask cluster of 1 and of 2 workers (one process each, one thread), and the
efficiency t1 / (2 t2).

    python benchmarks/sweep_scaling.py [--seeds 100] [--duration 10] [--workers 1,2] [--json out.json]

The sweep: a fixed-wing flight of ``--duration`` s (200 Hz IMU) at W20 = 0, 2, 4, 6, 8 m/s
with Dryden turbulence, ``--seeds`` seeds, estimators mekf and ins-wind, ``pcrb = false``
(the per-flight PCRB costs 20-50 estimator runs and would measure the bound, not the sweep):
5 x 2 x 100 = 1000 rows, 500 flights by default. Each cluster is started and every worker
warmed (windahrs imported, the estimators loaded from numba's cache, one short flight run)
before the clock starts; the time is ``run_sweep`` alone, into a fresh dataset directory:
scheduling, simulation, estimation, scoring and the Parquet writes. The machine is shared:
the load average is printed beside the times, and the CPU seconds the workers and this
process (client and scheduler) used, with the share of a core each worker got: on a busy
machine the wall-time efficiency measures the other jobs as much as the sweep.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

SPEC = """
[sweep]
seeds = {seeds}
pcrb = false

[grid]
vehicle = "fixedwing"
wind = [0.0, 2.0, 4.0, 6.0, 8.0]
turbulence = true
duration = {duration}

[[estimator]]
name = "mekf"

[[estimator]]
name = "ins-wind"
"""


def _warm() -> None:
    """Import and load every compiled function a run needs, on a worker."""
    from windahrs.experiments.sweep import RunTask, ScenarioSpec, parse_spec, run_task, windahrs_version

    spec = parse_spec({"sweep": {"seeds": 1, "pcrb": False}, "grid": {"duration": 2.0},
                       "estimator": [{"name": "mekf"}, {"name": "ins-wind"}]})
    sc: ScenarioSpec = spec.scenarios[0]
    run_task(RunTask(sc, 0, tuple((e, "warm") for e in spec.estimators), False, windahrs_version()))


def _cpu() -> float:
    """CPU seconds (user + system) of the calling process."""
    t = os.times()
    return t.user + t.system


def measure(workers: int, spec: Any, out: Path) -> tuple[float, float, float]:
    """Wall time s; CPU s of the workers; CPU s of this process (client and scheduler)."""
    from windahrs.experiments.cluster import open_client
    from windahrs.experiments.sweep import run_sweep

    with open_client(workers=workers) as client:
        client.run(_warm)  # on every worker
        w0, c0 = sum(client.run(_cpu).values()), _cpu()
        t0 = time.perf_counter()
        summary = run_sweep(spec, out, client)
        seconds = time.perf_counter() - t0
        w1, c1 = sum(client.run(_cpu).values()), _cpu()
    assert summary.computed == spec.rows and not summary.failed, summary
    return seconds, w1 - w0, c1 - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--workers", default="1,2", help="cluster sizes to time, comma-separated")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    import tomllib

    from windahrs.experiments.sweep import parse_spec

    spec = parse_spec(tomllib.loads(SPEC.format(seeds=args.seeds, duration=args.duration)))
    flights = len(spec.scenarios) * len(spec.seeds)
    steps = round(args.duration * 200) + 1
    print(f"sweep: {spec.rows} rows = {len(spec.scenarios)} wind levels x {len(spec.estimators)} estimators x "
          f"{len(spec.seeds)} seeds; {flights} flights of {args.duration:g} s ({steps} IMU steps); "
          f"{os.cpu_count()} CPUs")
    times: dict[int, float] = {}
    for n in (int(w) for w in args.workers.split(",")):
        with tempfile.TemporaryDirectory() as tmp:
            load = os.getloadavg()[0]
            t, cpu_w, cpu_c = measure(n, spec, Path(tmp) / "r.parquet")
        times[n] = t
        print(f"{n} worker(s): {t:7.1f} s  {spec.rows / t:7.1f} rows/s  {flights / t:6.2f} flights/s  "
              f"{spec.rows * steps / t / 1e6:6.3f} M filter-steps/s  (load average before: {load:.2f}); "
              f"CPU s: workers {cpu_w:.1f} ({cpu_w / t / n:.0%} of a core each), client+scheduler {cpu_c:.1f}")
    if 1 in times and 2 in times:
        eff = times[1] / (2 * times[2])
        print(f"speed-up 1 -> 2 workers: {times[1] / times[2]:.2f}x, efficiency t1/(2 t2) = {eff:.2f}")
    if args.json is not None:
        args.json.write_text(json.dumps({"rows": spec.rows, "flights": flights, "duration_s": args.duration,
                                         "seconds": {str(k): v for k, v in times.items()}}, indent=1))


if __name__ == "__main__":
    main()
