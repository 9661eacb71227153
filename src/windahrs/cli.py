"""The ``windahrs`` command: thin wrappers over the library's pure functions.

Each subcommand parses its arguments, calls one library function and prints. Errors in
the user's input end the command with exit status 2 and a one-line message naming the
argument or field; nothing is written on failure.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

__all__ = ["main"]


class UsageError(Exception):
    """Bad command-line input; printed as ``windahrs: error: ...`` with exit status 2."""


def _cmd_simulate(args: argparse.Namespace) -> int:
    from windahrs.sim.scenario import make_scenario, simulate
    from windahrs.store import save_flight

    if args.seed < 0:
        raise UsageError(f"--seed: expected an integer >= 0, found {args.seed}")
    scenario = make_scenario(
        args.vehicle, wind=args.wind, duration=args.duration, altitude=args.altitude
    )
    # Shown on a terminal only (tqdm's disable=None); stages, as the work is vectorised.
    with tqdm(
        total=2, desc=f"simulate {args.vehicle}", unit="stage", disable=None, file=sys.stderr
    ) as bar:
        flight = simulate(scenario, np.random.default_rng(args.seed))
        flight = flight.replace(meta={**flight.meta, "seed": args.seed})
        bar.update(1)
        bar.set_description(f"write {args.out.name}")
        save_flight(flight, args.out)
        bar.update(1)
    print(f"wrote {args.out}")
    print(flight.summary())
    return 0


def _cmd_info(args: argparse.Namespace) -> int:
    from windahrs.store import load_flight

    flight = load_flight(args.file)
    print(f"file       {args.file}")
    print(flight.summary())
    return 0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="windahrs",
        description="UAV attitude estimation in wind: simulate flights, inspect flight files.",
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser(
        "simulate",
        help="simulate a flight with wind and sensors, write it as HDF5",
        description=(
            "Simulate a flight through mean wind (MIL-F-8785C shear), Dryden turbulence and the "
            "vehicle's response to it; sample an MPU-9150-class IMU at 200 Hz, a magnetometer "
            "(50 Hz), GNSS velocity (10 Hz) and, on fixed wings, pitot and vanes (50 Hz), all "
            "from one truth that is stored with the flight."
        ),
    )
    s.add_argument(
        "--vehicle",
        choices=("fixedwing", "quadrotor", "paper"),
        default="fixedwing",
        help="fixedwing: turns and climbs at 15 m/s; quadrotor: position hold; "
        "paper: the paper's scenario (SPEC 7.3). Default fixedwing.",
    )
    s.add_argument(
        "--wind",
        type=float,
        default=0.0,
        metavar="W20",
        help="mean wind at 20 ft in m/s, which also sets the turbulence intensity "
        "(for --vehicle paper: the paper's wind speed). Default 0.",
    )
    s.add_argument(
        "--altitude",
        type=float,
        default=None,
        metavar="H",
        help="height above ground in m (default: 50 fixed wing, 20 quadrotor and paper)",
    )
    s.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="seconds (default: 120; 10 for paper)",
    )
    s.add_argument("--seed", type=int, default=0, metavar="N", help="random seed (default 0)")
    s.add_argument("--out", type=Path, required=True, metavar="FILE.h5", help="output file")
    s.set_defaults(func=_cmd_simulate)

    i = sub.add_parser(
        "info",
        help="describe a flight file: streams, rates, duration, truth",
        description="Print the streams of a windahrs flight file with their rates, "
        "missing samples and gaps, the duration, and whether truth or a reference is present.",
    )
    i.add_argument("file", type=Path, metavar="FILE.h5")
    i.set_defaults(func=_cmd_info)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    from windahrs.flight import FlightError
    from windahrs.store import StoreError

    parser = _parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except (UsageError, FlightError, StoreError, ValueError, FileNotFoundError) as exc:
        print(f"windahrs {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"windahrs {args.command}: interrupted; nothing was written", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
