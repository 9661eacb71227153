"""Regenerate the golden attitudes that tests/test_golden.py compares against.

The committed file was written by this script on commit addd942 (the last main before the
estimator core was restructured), so the test checks that every windahrs estimator still
gives that commit's answers. Rerun it only when a change of answers is intended, and say
which and by how much in the commit message.

    python tests/golden/make_golden.py
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np

from windahrs.experiments.reproduce import Case, _estimator, flight_seed
from windahrs.filters.registry import make_estimator
from windahrs.sim.atmosphere import WindConfig
from windahrs.sim.fixedwing import FixedWingScenario
from windahrs.sim.paper import PaperScenario
from windahrs.sim.quadrotor import QuadrotorScenario
from windahrs.sim.scenario import simulate

HERE = Path(__file__).resolve().parent
#: Our estimators (the outside baselines are not ours to keep equal).
FILTERS = (
    "paper", "paper:wind=mean", "paper-nowind", "ekf", "ukf",
    "ekf7", "ekf10", "mekf", "mekf-air", "ins-wind", "usque",
)
#: Physically tuned filters as the reproduction builds them (matched to the sensors).
MATCHED = ("ekf7", "mekf", "usque", "ins-wind", "mekf-air")
EVERY = 5  # keep every 5th IMU sample
DURATION = 20.0


def flights():
    """(name, flight) of the cases: the reproduction's first seed at each wind speed, a
    fixed wing and a quadrotor in 8 m/s wind."""
    for w in (0.0, 5.0, 8.0):
        yield f"paper_{w:g}", w, simulate(
            PaperScenario(duration=DURATION, wind_speed=w), np.random.default_rng(flight_seed(w, 0))
        )
    wind = WindConfig(w20=8.0)
    yield "fixedwing_8", None, simulate(FixedWingScenario(duration=DURATION, wind=wind), np.random.default_rng(7))
    yield "quadrotor_8", None, simulate(QuadrotorScenario(duration=DURATION, wind=wind), np.random.default_rng(8))


def main() -> None:
    out: dict[str, np.ndarray] = {}
    for fname, w, fl in flights():
        for spec in FILTERS:
            est = make_estimator(spec)
            try:
                est.check(fl)
            except ValueError:
                continue
            out[f"{fname}|{spec}"] = est.run(fl).q_nb[::EVERY]
            if w is not None and spec in MATCHED:
                out[f"{fname}|{spec}|matched"] = _estimator(Case(w, spec, "none")).run(fl).q_nb[::EVERY]
            print(fname, spec, flush=True)
    git = ["git", "rev-parse", "--short", "HEAD"]
    rev = subprocess.run(git, capture_output=True, text=True, cwd=HERE).stdout.strip()
    np.savez_compressed(HERE / "attitudes.npz", commit=np.array(rev), **out)


if __name__ == "__main__":
    main()
