"""Issue 13's spike acceptance: a single gyro or accelerometer spike of any size changes
``ins-wind``'s RMSE by less than 10 %.

    python benchmarks/spikes.py [--vehicles fixedwing,quadrotor] [--filters ins-wind,mekf]
        [--wind 8] [--duration 60] [--seeds 3] [--times 20,30,40] [--axes 0,1,2]
        [--gyro 0.5,1,2,5,10,20,40,100] [--accel 5,10,20,50,100,300] [--out spikes.json]

For each vehicle (W20 ``--wind`` m/s), seed (0 to seeds - 1) and filter, the clean flight is
run once; then each spike, one IMU sample (the first at or after each time of ``--times``)
with ``magnitude`` added to one body axis of the gyro (rad/s) or of the accelerometer
(m/s^2) (:class:`~windahrs.sim.faults.GyroSpike`, :class:`~windahrs.sim.faults.AccelSpike`),
is run on the same flight. The RMSE is :func:`windahrs.score`'s total attitude error from
sample 50 (the fault matrix's); the change is faulty minus clean, in % of clean.

Every faulty flight is first built as a checked Flight (:func:`~windahrs.sim.faults.inject_raw`
then ``RawFlight.to_flight``): the Flight checks units on the bulk of the data
(:mod:`windahrs.repair`), so one spike of any size passes ("injected": "flight"). Where a
Flight refuses the streams (before that rule, a gyro sample above 50 rad/s was taken for
deg/s), the :class:`~windahrs.flight.ImuStream` is built without its checks
(``object.__new__``, "injected": "bypass"), so that the estimator still sees the sample as a
sensor would send it. The readers' edge repair (which makes a sample beyond the sensor's range
NaN before the estimator) is not exercised here.

How the spike was caught: the IMU screen's log (``Estimate.alerts["imu"]``, outcome 1 beyond
the sensor's range, 2 a spike, 3 motion propagated one sample late, at the spike's sample;
"next held": the spike passed and the sample after it was held; "not held"), the flags
at the spike's sample (``Estimate.flags``), and the flags raised in the 10 s after it that the
clean run did not raise at those samples. ``--out`` writes every case as JSON.
Plain loops, progress on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

#: The largest RMSE change the issue accepts, %.
TARGET_PCT = 10.0
#: New flags are looked for this long after the spike, s.
AFTER_S = 10.0
#: The Flight constructor's gyro unit check, rad/s (windahrs.flight.ImuStream).
FLIGHT_GYRO_LIMIT = 50.0
OUTCOME = {1: "range", 2: "spike", 3: "late"}
SCREEN = (*OUTCOME.values(), "next held", "not held")


def _split(text: str, kind: type, name: str, ap: argparse.ArgumentParser) -> list[Any]:
    try:
        out = [kind(v) for v in text.split(",") if v.strip()]
    except ValueError:
        ap.error(f"{name}: expected comma-separated numbers, found {text!r}")
    if not out:
        ap.error(f"{name}: expected at least one value, found {text!r}")
    return out


def _faulty(flight: Any, fault: Any) -> tuple[Any, str]:
    """The flight with the fault, and how it was built ("flight": a checked Flight;
    "bypass": an ImuStream built without its unit check)."""
    from windahrs.flight import ImuStream
    from windahrs.sim.faults import FaultError, inject_raw

    raw = inject_raw(flight, [fault], seed=0)
    try:
        return raw.to_flight(), "flight"
    except FaultError:
        pass
    imu = object.__new__(ImuStream)
    for k in ("t", "w_b", "f_b"):
        object.__setattr__(imu, k, raw.imu[k])
    return flight.replace(imu=imu, meta={**flight.meta, "faults": fault.spec()}), "bypass"


def _screen(held: np.ndarray | None, t: np.ndarray, k: int) -> str:
    """What the IMU screen did with the spike at sample k: its outcome there ("range",
    "spike", "late"), else "next held" when the sample after it was held (the spike was
    propagated, and the return to normal looked like a spike against it), else "not held"."""
    if held is None or len(held) == 0:
        return "not held"
    rows = np.searchsorted(t, held[:, 0] - 1e-9)
    for row, code in zip(rows, held[:, 3], strict=True):
        if row == k:
            return OUTCOME.get(int(code), f"outcome {int(code)}")
    return "next held" if np.any(rows == k + 1) else "not held"


def _flag_names(bits: int) -> list[str]:
    from windahrs.flags import flag_names

    return flag_names(int(bits))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--vehicles", default="fixedwing,quadrotor")
    ap.add_argument("--filters", default="ins-wind,mekf")
    ap.add_argument("--wind", type=float, default=8.0, help="W20, m/s (default 8)")
    ap.add_argument("--duration", type=float, default=60.0, help="s (default 60)")
    ap.add_argument("--seeds", type=int, default=3, help="flights per vehicle, seeds 0 to N - 1 (default 3)")
    ap.add_argument("--times", default="20,30,40", help="spike times, s (default 20,30,40)")
    ap.add_argument("--axes", default="0,1,2", help="body axes (default 0,1,2)")
    ap.add_argument("--gyro", default="0.5,1,2,5,10,20,40,100", help="gyro spike sizes, rad/s")
    ap.add_argument("--accel", default="5,10,20,50,100,300", help="accelerometer spike sizes, m/s^2")
    ap.add_argument("--out", type=Path, default=None, metavar="FILE.json")
    args = ap.parse_args(argv)
    if args.out is not None and not (args.out.parent.is_dir() and not args.out.is_dir()):
        ap.error(f"--out: expected a file path in an existing directory, found {str(args.out)!r}")
    times = _split(args.times, float, "--times", ap)
    axes = _split(args.axes, int, "--axes", ap)
    sizes = [("gyro", m) for m in _split(args.gyro, float, "--gyro", ap)]
    sizes += [("accel", m) for m in _split(args.accel, float, "--accel", ap)]
    if args.seeds < 1:
        ap.error(f"--seeds: expected an integer >= 1, found {args.seeds}")
    if any(a not in (0, 1, 2) for a in axes):
        ap.error(f"--axes: expected 0, 1 or 2, found {args.axes!r}")
    if any(not 0 < t < args.duration for t in times):
        ap.error(f"--times: expected times within the flight (0, {args.duration:g}) s, found {args.times!r}")

    import windahrs as wa
    from windahrs.flags import FLAGS
    from windahrs.sim.faults import AccelSpike, GyroSpike
    from windahrs.sim.scenario import make_scenario, simulate

    vehicles = [v for v in args.vehicles.split(",") if v.strip()]
    filters = [f for f in args.filters.split(",") if f.strip()]
    try:
        for v in vehicles:
            make_scenario(v, wind=args.wind, duration=args.duration)
        for f in filters:
            wa.estimator(f)
        for m in sizes:
            (GyroSpike if m[0] == "gyro" else AccelSpike)(start=times[0], magnitude=m[1])
    except ValueError as exc:  # (FaultError is a ValueError)
        ap.error(str(exc))
    held_bit = 1 << FLAGS["imu_held"][0]
    late_bit = 1 << FLAGS["imu_late"][0]
    cases: list[dict[str, Any]] = []
    start = time.perf_counter()
    total = len(vehicles) * args.seeds * len(filters) * len(sizes) * len(times) * len(axes)
    for vehicle in vehicles:
        scenario = make_scenario(vehicle, wind=args.wind, duration=args.duration)
        for seed in range(args.seeds):
            flight = simulate(scenario, np.random.default_rng(seed))
            for spec in filters:
                est_obj = wa.estimator(spec)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    clean = est_obj.run(flight)
                sc = wa.score(clean, flight)
                for sensor, mag in sizes:
                    for t_spike in times:
                        for axis in axes:
                            cls = GyroSpike if sensor == "gyro" else AccelSpike
                            fault = cls(start=t_spike, magnitude=mag, axis=axis)
                            faulty, how = _faulty(flight, fault)
                            with warnings.catch_warnings():
                                warnings.simplefilter("ignore")
                                est = est_obj.run(faulty)
                            sf = wa.score(est, flight)
                            k = int(np.searchsorted(flight.imu.t, t_spike))
                            ts = float(flight.imu.t[k])
                            screen = _screen(est.alerts.get("imu"), flight.imu.t, k)
                            fl = int(est.flags[k]) if est.flags is not None else 0
                            if est.flags is not None and clean.flags is not None:
                                w = (est.t > ts) & (est.t <= ts + AFTER_S)
                                new = np.bitwise_or.reduce(est.flags[w] & ~clean.flags[w]) if w.any() else 0
                                new = int(new) & ~(held_bit | late_bit)
                            else:
                                new = 0
                            resets_new = sum(len(v) for v in est.resets.values()) - sum(
                                len(v) for v in clean.resets.values())
                            change = 100.0 * (sf.rmse_total_deg - sc.rmse_total_deg) / sc.rmse_total_deg
                            cases.append({
                                "vehicle": vehicle, "seed": seed, "filter": spec, "sensor": sensor,
                                "magnitude": mag, "t": ts, "axis": axis, "injected": how,
                                "rmse_clean_deg": sc.rmse_total_deg, "rmse_faulty_deg": sf.rmse_total_deg,
                                "change_pct": change,
                                "tilt_change_pct": 100.0 * (sf.rmse_tilt_deg - sc.rmse_tilt_deg) / sc.rmse_tilt_deg,
                                "screen": screen,
                                "flags_at_spike": _flag_names(fl),
                                "new_flags_after": _flag_names(new),
                                "new_resets": resets_new,
                            })
                    done = cases[-len(times) * len(axes):]
                    print(f"{len(cases)}/{total} ({time.perf_counter() - start:.0f} s): {vehicle} seed {seed} {spec} "
                          f"{sensor} {mag:g}: worst change {max(abs(c['change_pct']) for c in done):.1f} %",
                          file=sys.stderr, flush=True)

    print(f"\none spike on one axis at {', '.join(f'{t:g}' for t in times)} s, axes {', '.join(map(str, axes))}, "
          f"seeds 0-{args.seeds - 1}, W20 {args.wind:g} m/s, {args.duration:g} s flights; RMSE = total attitude "
          f"error from sample 50; target |change| < {TARGET_PCT:g} %")
    print("| vehicle | filter | spike | clean RMSE, deg | change %: median / worst | cases within 10 % | "
          "screen: range/spike/late/next held/not held | flagged imu_held at the spike | new flags in 10 s | "
          "new resets |")
    print("|---" * 10 + "|")
    groups: list[dict[str, Any]] = []
    for vehicle in vehicles:
        for spec in filters:
            for sensor, mag in sizes:
                cs = [c for c in cases if c["vehicle"] == vehicle and c["filter"] == spec
                      and c["sensor"] == sensor and c["magnitude"] == mag]
                if not cs:
                    continue
                ch = np.array([c["change_pct"] for c in cs])
                worst = float(ch[np.argmax(np.abs(ch))])
                outcomes = {o: sum(c["screen"] == o for c in cs) for o in SCREEN}
                new_flags: dict[str, int] = {}
                for c in cs:
                    for f in c["new_flags_after"]:
                        new_flags[f] = new_flags.get(f, 0) + 1
                g = {
                    "vehicle": vehicle, "filter": spec, "sensor": sensor, "magnitude": mag, "cases": len(cs),
                    "injected": sorted({c["injected"] for c in cs}),
                    "rmse_clean_deg": [min(c["rmse_clean_deg"] for c in cs), max(c["rmse_clean_deg"] for c in cs)],
                    "change_pct_median": float(np.median(ch)), "change_pct_worst": worst,
                    "within_target": int(np.sum(np.abs(ch) < TARGET_PCT)),
                    "screen": outcomes,
                    "flagged_imu_held": sum("imu_held" in c["flags_at_spike"] for c in cs),
                    "new_flags_after": new_flags,
                    "new_resets": int(sum(c["new_resets"] for c in cs)),
                }
                groups.append(g)
                unit = "rad/s" if sensor == "gyro" else "m/s^2"
                extra = " (bypass)" if "bypass" in g["injected"] else ""
                flags_txt = ", ".join(f"{k} {v}" for k, v in sorted(new_flags.items())) or "-"
                print(f"| {vehicle} | {spec} | {sensor} {mag:g} {unit}{extra} | {g['rmse_clean_deg'][0]:.2f}-"
                      f"{g['rmse_clean_deg'][1]:.2f} | {g['change_pct_median']:+.1f} / {worst:+.1f} | "
                      f"{g['within_target']}/{len(cs)} | " + "/".join(str(outcomes[o]) for o in SCREEN) + " |"
                      f" {g['flagged_imu_held']}/{len(cs)} | {flags_txt} | {g['new_resets']} |")
    print()
    for vehicle in vehicles:
        for spec in filters:
            cs = [c for c in cases if c["vehicle"] == vehicle and c["filter"] == spec]
            bad = [c for c in cs if abs(c["change_pct"]) >= TARGET_PCT]
            line = (f"{vehicle} {spec}: {len(cs) - len(bad)}/{len(cs)} spikes change the RMSE by less than "
                    f"{TARGET_PCT:g} %")
            if bad:
                wc = max(bad, key=lambda c: abs(c["change_pct"]))
                line += (f"; worst {wc['change_pct']:+.1f} % ({wc['sensor']} {wc['magnitude']:g} axis {wc['axis']} "
                         f"at {wc['t']:g} s, seed {wc['seed']}, screen: {wc['screen']}, "
                         f"RMSE {wc['rmse_clean_deg']:.3f} -> {wc['rmse_faulty_deg']:.3f} deg)")
            if bad:
                by = {o: sum(c["screen"] == o for c in bad) for o in SCREEN}
                line += "; beyond it by screen outcome: " + ", ".join(f"{o} {n}" for o, n in by.items() if n)
            print(line)
    if args.out is not None:
        args.out.write_text(json.dumps({"wind": args.wind, "duration": args.duration, "target_pct": TARGET_PCT,
                                        "groups": groups, "cases": cases}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
