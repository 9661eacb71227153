"""Two versions of windahrs side by side: the compiled loop's speed and the answers.

    git worktree add /tmp/old REV
    python benchmarks/kernel_ab.py --old /tmp/old/src [--filters ins-wind,mekf] [--rounds 5] [--repeat 30]

On this shared machine the speed of the moment drifts by up to 2x over minutes, so one run of
each version cannot compare them. Here each round runs the old and then the new source in a
fresh Python process (``PYTHONPATH``); each process times, on the simulated fixed wing (8 m/s,
60 s, seed 0), vqf's core and every filter's compiled loop alone without recording
(``Estimator.prepare``, then ``run_events``), interleaved, best of ``--repeat``. Printed: per
version the best us/sample over all rounds and the median ratio to vqf's core of the rounds.
Then both versions run every filter on a 60 s fixed-wing and quadrotor flight (8 m/s, seed 1)
and the largest angle between their attitudes is printed (the same answers?).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

#: What the child process runs: ``timing FILTERS REPEAT`` prints one JSON line of us/sample
#: (vqf's core under "vqf"); ``answers FILTERS OUT`` writes every filter's q_nb to OUT (.npz).
CHILD = r"""
import json, sys, time, warnings
warnings.simplefilter("ignore")
import numpy as np
import windahrs as wa
from windahrs.sim.scenario import make_scenario, simulate
mode, names = sys.argv[1], [s for s in sys.argv[2].split(",") if s]
if mode == "timing":
    from vqf import VQF
    from windahrs.baselines._common import held_mag
    from windahrs.core.kernel import run_events
    from windahrs.core.smooth import no_smoothing
    flight = simulate(make_scenario("fixedwing", wind=8.0, duration=60.0), np.random.default_rng(0))
    imu, n = flight.imu, len(flight.imu.t)
    gyr, acc = np.ascontiguousarray(imu.w_b), np.ascontiguousarray(imu.f_b)
    mag = np.ascontiguousarray(held_mag(flight, imu.t)[0])
    dt = float(np.median(np.diff(imu.t)))
    ests = {s: wa.estimator(s) for s in names}
    def loop(est):
        r = est.prepare(flight)
        t0 = time.perf_counter()
        run_events(r.st, r.t_ev, r.kinds, r.vals, r.q, r.bg, r.v, r.w, r.cov, False, no_smoothing())
        return time.perf_counter() - t0
    for est in ests.values():
        loop(est)
    best = dict.fromkeys(["vqf", *names], float("inf"))
    for _ in range(int(sys.argv[3])):
        t0 = time.perf_counter()
        VQF(dt).updateBatch(gyr, acc, mag)
        best["vqf"] = min(best["vqf"], time.perf_counter() - t0)
        for s, est in ests.items():
            best[s] = min(best[s], loop(est))
    print(json.dumps({k: v / n * 1e6 for k, v in best.items()}))
else:
    out = {}
    for vehicle in ("fixedwing", "quadrotor"):
        flight = wa.simulate(vehicle, seed=1, wind=8.0, duration=60.0)
        for s in names:
            try:
                out[f"{vehicle}/{s}"] = wa.estimator(s).run(flight).q_nb
            except Exception:  # a filter this vehicle cannot run (a missing sensor)
                pass
    np.savez(sys.argv[3], **out)
"""


def _child(src: str | None, *args: str) -> str:
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = src
    done = subprocess.run([sys.executable, "-c", CHILD, *args], env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"kernel_ab.py: the {'old' if src else 'new'} version failed:\n{done.stderr[-2000:]}")
    return done.stdout


def _largest_angle(a: object, b: object) -> dict[str, float]:
    import numpy as np

    out = {}
    for k in sorted(set(a.files) & set(b.files)):  # type: ignore[attr-defined]
        qa, qb = a[k], b[k]  # type: ignore[index]
        w = np.abs(np.einsum("ij,ij->i", qa, qb))
        # the vector part of qa^-1 qb, exact for small angles (arccos is not, near 1)
        v = qa[:, :1] * qb[:, 1:] - qb[:, :1] * qa[:, 1:] - np.cross(qa[:, 1:], qb[:, 1:])
        out[k] = float(np.nanmax(2.0 * np.arctan2(np.linalg.norm(v, axis=1), w)))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--old", required=True, help="the old version's source folder (a worktree's src)")
    ap.add_argument("--filters", default="ins-wind,mekf")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--answers", default="mekf,mekf-air,ins-wind,ekf7,ekf10,paper,paper-nowind,ekf,ukf,usque,auto",
                    help="the filters whose attitudes are compared (empty: none)")
    args = ap.parse_args(argv)
    if not Path(args.old).is_dir():
        raise SystemExit(f"kernel_ab.py: --old: no such folder {args.old!r}")
    rows: dict[str, list[dict[str, float]]] = {"old": [], "new": []}
    for r in range(args.rounds):
        for tag, src in (("old", args.old), ("new", None)):
            rows[tag].append(json.loads(_child(src, "timing", args.filters, str(args.repeat))))
        print(f"round {r + 1}/{args.rounds}: " + "; ".join(
            f"{tag} " + " ".join(f"{k} {v:.3f}" for k, v in rows[tag][-1].items()) for tag in rows), flush=True)
    names = [s for s in args.filters.split(",") if s]
    for tag, runs in rows.items():
        best = {k: min(run[k] for run in runs) for k in ["vqf", *names]}
        ratio = {s: statistics.median(run[s] / run["vqf"] for run in runs) for s in names}
        print(f"{tag}: best us/sample " + ", ".join(f"{k} {v:.3f}" for k, v in best.items())
              + "; median ratio to vqf's core " + ", ".join(f"{s} {v:.2f}" for s, v in ratio.items()))
    if args.answers:
        import tempfile

        import numpy as np

        with tempfile.TemporaryDirectory() as tmp:
            files = {tag: str(Path(tmp) / f"{tag}.npz") for tag in rows}
            _child(args.old, "answers", args.answers, files["old"])
            _child(None, "answers", args.answers, files["new"])
            angles = _largest_angle(np.load(files["old"]), np.load(files["new"]))
        print("largest angle between the versions' attitudes, rad: "
              + ", ".join(f"{k} {v:.1e}" for k, v in angles.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
