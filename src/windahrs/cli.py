"""The ``windahrs`` command: thin wrappers over the library's pure functions.

Each subcommand parses its arguments, calls one library function and prints. Every
failure ends with one line on stderr, ``windahrs COMMAND: error: ...``, naming the
argument, field or path, never a traceback, and with the exit status:

- 2: bad input (an argument, a parameter file, a flight file or log, an output path that
  cannot be written), all checked before the work starts where they can be;
- 1: any other failure (the disk filling up while writing, out of memory, a bug);
- 130: interrupted by Ctrl-C (SIGINT), the shell's convention (128 + 2).

Outputs are checked to be writable before the work starts; on any failure or interrupt the
files and folders the command created are removed (:class:`_Outputs`). A command declares
each output first thing: ``args.outputs.file(args.out, "--out")`` for a file,
``args.outputs.folder(args.out, "--out")`` for a folder (created there), then writes through
the atomic writers of :mod:`windahrs.store`. Paths take ``type=_path`` (``_file_path`` for an
output file), numbers ``_number`` (finite), seeds ``_seed`` and run counts ``_count``; rows of
``tests/test_cli_hardening.py`` check each command's bad input.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import os
import shutil
import signal
import sys
import textwrap
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, NoReturn, TextIO

import numpy as np
from tqdm import tqdm

if TYPE_CHECKING:

    from windahrs.flight import Flight
    from windahrs.metrics import Score
    from windahrs.sim.faults import Fault

__all__ = ["main"]


class UsageError(Exception):
    """Bad command-line input; printed as ``windahrs: error: ...`` with exit status 2."""


class _Parser(argparse.ArgumentParser):
    """argparse with its errors on one line (argparse prints the usage first): the message,
    then where to read more."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see '{self.prog} --help')\n")


#: Largest seed, run count or run index: seeds are stored as 64-bit signed integers (HDF5
#: attributes, JSON readers), and run r of an experiment has seed ``--seed + r``.
MAX_SEED = 2**63 - 1


def _number(text: str) -> float:
    """A finite number (argparse type): nan and inf are refused."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, found {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, found {text!r}")
    return value


def _declination(text: str) -> float:
    """A magnetic declination, degrees east of true north (argparse type): a finite number
    within +-180 (:func:`windahrs.flight.declination_radians`)."""
    from windahrs.flight import FlightError, declination_radians

    value = _number(text)
    try:
        declination_radians(value)
    except FlightError as exc:
        raise argparse.ArgumentTypeError(f"expected {exc.expected}, found {text!r}") from None
    return value


def _integer(text: str, low: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, found {text!r}") from None
    if not low <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"expected an integer from {low} to 2**63 - 1, found {text}")
    return value


def _seed(text: str) -> int:
    """A seed, 0 to 2**63 - 1 (argparse type)."""
    return _integer(text, 0)


def _count(text: str) -> int:
    """A number of runs, 1 to 2**63 - 1 (argparse type)."""
    return _integer(text, 1)


def _path(text: str) -> Path:
    """A path (argparse type): the empty string is refused (``Path("")`` would be ".")."""
    if not text:
        raise argparse.ArgumentTypeError("expected a path, found ''")
    return Path(text)


def _file_path(text: str) -> Path:
    """An output file (argparse type): a path ending in a separator names a directory."""
    if text.endswith(("/", os.sep)):
        raise argparse.ArgumentTypeError(f"expected a file name, found the directory name {text!r}")
    return _path(text)


def _text_path(text: str) -> str:
    """A path kept as typed (argparse type; the empty string refused), for an option that
    is a file or a directory by another option: ``Path`` would drop a trailing "/"."""
    _path(text)
    return text


class _Outputs:
    """The files and folders a command writes: each checked to be writable before the work
    starts, and removed when the command fails or is interrupted (files that did not
    exist before; a folder it created, with what is in it; in a folder that existed, the
    entries that were not there before)."""

    def __init__(self) -> None:
        self._files: list[Path] = []
        self._folders: list[tuple[Path, set[str] | None]] = []

    def file(self, path: Path, option: str) -> Path:
        from windahrs.store import OutputError, check_writable

        try:
            check_writable(path)
        except OutputError as exc:
            raise UsageError(f"{option}: {exc}") from None
        if not path.exists():
            self._files.append(path)
        return path

    def folder(self, path: Path, option: str) -> Path:
        from windahrs.store import OutputError, check_writable

        if path.exists() and not path.is_dir():
            raise UsageError(f"{option}: {path} is a file, expected a directory")
        if path.is_dir():
            before: set[str] | None = set(os.listdir(path))
            top = path
        else:
            missing = [path, *(a for a in path.parents if not a.exists())]
            top = missing[-1]
            if not top.parent.is_dir():
                raise UsageError(f"{option}: {path}: {top.parent} is not a directory")
            before = None
        try:
            check_writable((path if before is not None else top.parent) / ".windahrs-probe")
        except OutputError as exc:
            raise UsageError(f"{option}: {path}: {str(exc).split(': ', 1)[-1]}") from None
        if before is None:
            try:
                path.mkdir(parents=True)
            except OSError as exc:
                raise UsageError(f"{option}: {path}: cannot create the directory ({exc.strerror})") from None
        self._folders.append((top, before))
        return path

    def kept_folder(self, path: Path, option: str) -> Path:
        """A folder checked like :meth:`folder` but kept on failure and interrupt: what was
        completed in it is the point (a sweep's rows, to resume from)."""
        self.folder(path, option)
        self._folders.pop()
        return path

    def new_folder(self, path: Path, option: str) -> Path:
        """A folder the command's writer creates itself, whole or not at all (it must not
        exist yet): its parent checked, the folder removed on failure."""
        from windahrs.store import OutputError, check_writable

        if path.exists():
            raise UsageError(f"{option}: expected a directory that does not exist yet, found {path}")
        try:
            check_writable(path)
        except OutputError as exc:
            raise UsageError(f"{option}: {exc}") from None
        self._folders.append((path, None))
        return path

    def discard(self) -> None:
        """Remove what the command wrote (called on failure and on interrupt)."""
        for f in self._files:
            if f.is_file() or f.is_symlink():
                f.unlink(missing_ok=True)
        for folder, before in self._folders:
            if before is None:
                shutil.rmtree(folder, ignore_errors=True)
                continue
            for name in set(os.listdir(folder)) - before:
                entry = folder / name
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry, ignore_errors=True)
                else:
                    entry.unlink(missing_ok=True)


#: Seconds between progress lines when stderr is not a terminal (CI logs, nohup, a pipe).
LOG_PROGRESS_S = 30.0


class _LineWriter:
    """tqdm's refreshes as lines of their own on stderr: off a terminal, tqdm's "\\r"
    redraws would pile up on one line of a log file."""

    def write(self, text: str) -> None:
        text = text.strip("\r\n")
        if text.strip():
            sys.stderr.write(text.rstrip() + "\n")

    def flush(self) -> None:
        sys.stderr.flush()


def _runs_bar(total: int, desc: str) -> tqdm:
    """Progress of a long multi-run command on stderr: redrawn in place on a terminal; off a
    terminal, one line every :data:`LOG_PROGRESS_S` seconds and one at the end."""
    if sys.stderr.isatty():
        return tqdm(total=total, desc=desc, unit="run", file=sys.stderr)
    return tqdm(total=total, desc=desc, unit="run", file=_LineWriter(), mininterval=LOG_PROGRESS_S,
                maxinterval=LOG_PROGRESS_S, ascii=True)


def _cmd_simulate(args: argparse.Namespace) -> int:
    from windahrs.sim.scenario import check_simulation_size, make_scenario, simulate
    from windahrs.store import save_flight

    if args.csv:
        args.out = args.outputs.new_folder(_path(args.out), "--out")
    else:
        try:
            args.out = args.outputs.file(_file_path(args.out), "--out")
        except argparse.ArgumentTypeError as exc:
            raise UsageError(f"--out: {exc}") from None
    scenario = make_scenario(args.vehicle, wind=args.wind, duration=args.duration, altitude=args.altitude)
    check_simulation_size(scenario)
    faults = _faults(args.fault)
    # Shown on a terminal only (tqdm's disable=None); stages, as the work is vectorised.
    with tqdm(total=2, desc=f"simulate {args.vehicle}", unit="stage", disable=None, file=sys.stderr) as bar:
        flight = simulate(scenario, np.random.default_rng(args.seed))
        flight = flight.replace(meta={**flight.meta, "seed": args.seed})
        if faults or args.csv:
            from windahrs.sim.faults import inject_raw

            raw = inject_raw(flight, faults, seed=args.seed)
        bar.update(1)
        bar.set_description(f"write {args.out.name}")
        if args.csv:
            raw.write_csv_dir(args.out)
        else:
            if faults:
                flight = raw.to_flight()
            save_flight(flight, args.out)
        bar.update(1)
    print(f"wrote {args.out}")
    if not args.csv:
        print(flight.summary())
    return 0


def _faults(specs: list[str] | None) -> list[Fault]:
    """The --fault specs as faults (FaultError, a ValueError, naming the field)."""
    from windahrs.sim.faults import parse_fault

    return [parse_fault(s) for s in specs or ()]


def _cmd_faults(args: argparse.Namespace) -> int:
    import json

    from windahrs.experiments.faults import check_cases, counts, default_cases, matrix_markdown, run_fault_matrix
    from windahrs.filters.registry import make_estimator
    from windahrs.store import write_bytes

    specs = _specs(args.filters)
    for spec in specs:  # a bad name or field before any work
        make_estimator(spec)
    if not (np.isfinite(args.wind) and 0 <= args.wind <= 30):
        raise UsageError(f"--wind: expected a W20 between 0 and 30 m/s, found {args.wind}")
    if not (np.isfinite(args.duration) and 0 < args.duration <= 3600):
        raise UsageError(f"--duration: expected between 0 and 3600 s, found {args.duration}")
    cases = default_cases(args.duration / 3)
    if args.faults is not None:
        known = {c.name: c for c in cases}
        wanted = _specs(args.faults, "--faults", "fault case")
        unknown = [w for w in wanted if w not in known]
        if unknown:
            raise UsageError(f"--faults: expected names among {', '.join(known)}, found {', '.join(unknown)}")
        cases = [known[w] for w in wanted]
    try:
        check_cases(cases, args.duration)
    except ValueError as exc:
        raise UsageError(f"--{exc}") from None
    args.outputs.folder(args.out, "--out")  # made here; removed on failure (with what is in it)
    with _runs_bar(len(specs) * (len(cases) + 1), f"faults {args.vehicle}") as bar:

        def step(done: int, total: int, label: str) -> None:
            bar.set_postfix_str(label, refresh=False)
            bar.update(done - bar.n)

        res = run_fault_matrix(args.vehicle, specs, wind=args.wind, duration=args.duration, seed=args.seed,
                               cases=cases, progress=step)
    rows = [r.as_dict() for r in res.rows]
    write_bytes(args.out / "faults.json", (json.dumps(rows, indent=1) + "\n").encode("utf-8"))
    write_bytes(args.out / "faults.md", matrix_markdown([res]).encode("utf-8"))
    for note in res.not_run:
        _note(f"not run: {note}")
    c = counts(res.rows)
    idle = f" ({c.no_effect} more whose fault changed no sample)" if c.no_effect else ""
    print(f"{c.runs} runs{idle}: {c.flagged} flagged within 1 s ({c.flagged_span} within the fault's span), "
          f"{c.recovered} back under twice the pre-fault RMS within 10 s, {c.with_nan} with NaN in the estimate")
    print(f"wrote {args.out / 'faults.md'}")
    print(f"wrote {args.out / 'faults.json'}")
    return 0


#: The reproduction's NEES check runs on this many blocks of --runs flights by default.
NEES_CHECK_BLOCKS = 8

DEFAULT_EXPERIMENT_FILTERS = (
    "ins-wind,mekf-air,mekf,mekf:accel_compensation=airspeed,ekf7,ekf10,usque,"
    "paper,paper:wind=mean,paper-nowind,ekf,ukf"
)


def _cmd_experiment(args: argparse.Namespace) -> int:
    import json

    from windahrs.experiments.montecarlo import run_wind_experiment
    from windahrs.filters.registry import make_estimator
    from windahrs.metrics import WIND_FROM_S
    from windahrs.sim.scenario import check_simulation_size, make_scenario

    specs = _specs(args.filters)
    if args.seed + args.runs - 1 > MAX_SEED:
        raise UsageError(f"--runs: the seeds {args.seed}..{args.seed + args.runs - 1} go past 2**63 - 1")
    for spec in specs:  # fail on a bad name or field before any work
        make_estimator(spec)
    check_simulation_size(make_scenario(args.vehicle, wind=args.wind, duration=args.duration, altitude=args.altitude))
    faults = _faults(args.fault)
    with _runs_bar(args.runs * len(specs), "experiment") as bar:

        def step(done: int, total: int) -> None:
            bar.update(done - bar.n)

        rows = run_wind_experiment(
            args.vehicle, args.wind, args.duration, args.runs, specs, altitude=args.altitude,
            seed0=args.seed, progress=step, faults=faults,
        )
    if args.json:
        print(json.dumps([r.as_dict() for r in rows], indent=1))
        return 0
    print(
        f"{args.vehicle}, W20 = {args.wind} m/s, {args.duration} s, {args.runs} runs (seeds {args.seed}..): "
        "RMSE in deg against truth; from sample 50 | second half"
    )
    width = max(36, *(len(r.filter) + 2 for r in rows))
    axes = f"{'roll':>8}{'pitch':>8}{'yaw':>8} |"
    winds = any(r.wind_rmse_h_ms is not None for r in rows)
    wind_head = f" |{'wind m/s':>9}{'dir deg':>8}{'max':>7}" if winds else ""
    fits = any(r.wind_fit_ms is not None for r in rows)
    fit_head = f" |{'fit m/s':>9}{'max':>7}" if fits else ""
    print(f"{'filter':<{width}}{axes}{axes}{'tilt':>8}{'total':>8}{'s/run':>8}{wind_head}{fit_head}")
    for r in rows:
        a, b = r.rmse_from50_deg, r.rmse_steady_deg
        wind = ""
        if winds:
            wind = " |" + (
                f"{r.wind_rmse_h_ms:9.3f}{r.wind_direction_deg:8.2f}{r.wind_direction_max_deg:7.2f}"
                if r.wind_rmse_h_ms is not None and r.wind_direction_deg is not None
                and r.wind_direction_max_deg is not None
                else f"{'-':>9}{'-':>8}{'-':>7}"
            )
        if fits:
            wind += " |" + (
                f"{r.wind_fit_ms:9.3f}{r.wind_fit_max_ms:7.3f}"
                if r.wind_fit_ms is not None and r.wind_fit_max_ms is not None
                else f"{'-':>9}{'-':>7}"
            )
        print(
            f"{r.filter:<{width}}{a[0]:8.3f}{a[1]:8.3f}{a[2]:8.3f} |{b[0]:8.3f}{b[1]:8.3f}{b[2]:8.3f} |"
            f"{r.rmse_tilt_deg:8.3f}{r.rmse_total_deg:8.3f}{r.seconds:8.2f}{wind}"
        )
    if winds:
        print(f"wind: horizontal RMSE and direction error of the mean wind from {WIND_FROM_S:g} s on, RMS over runs")
    if fits:
        print("fit: horizontal distance of the fitted constant wind (wind=fit) from the flight's mean true wind, "
              "RMS over runs, and the largest")
    for r in rows:
        if r.airspeed_scale is not None and r.airspeed_scale_spread is not None:
            print(f"{r.filter}: airspeed scale (true / measured) at the end {r.airspeed_scale:.4f} mean over runs, "
                  f"runs within +-{r.airspeed_scale_spread:.4f}")
    if faults:
        print("faults: " + ", ".join(f.spec() for f in faults))
    return 0


def reproduce_nees_runs(runs: int, quick: bool, nees_runs: int | None) -> int:
    """Runs of ``reproduce``'s NEES check: ``--nees-runs`` if given (at least the runs per
    case), else :data:`NEES_CHECK_BLOCKS` x the runs per case, or no extra runs with --quick."""
    if nees_runs is None:
        return runs if quick else NEES_CHECK_BLOCKS * runs
    if nees_runs < runs:
        raise UsageError(f"--nees-runs: expected an integer >= the runs per case ({runs}), found {nees_runs}")
    return nees_runs


def _cmd_reproduce(args: argparse.Namespace) -> int:
    import functools
    import time

    from windahrs.experiments.cluster import default_workers, open_client
    from windahrs.experiments.reproduce import (
        NEES_CHECK_LABEL,
        check_reproduction_size,
        default_cases,
        progress_total,
        run_reproduction,
    )
    from windahrs.filters.registry import names
    from windahrs.report.reproduction import write_reproduction
    from windahrs.sim.scenario import MIN_DURATION_S

    runs = 5 if args.quick and args.runs is None else (args.runs if args.runs is not None else 50)
    if runs < 1:
        raise UsageError(f"--runs: expected an integer >= 1, found {runs}")
    if args.duration < MIN_DURATION_S:
        raise UsageError(f"--duration: expected at least {MIN_DURATION_S:g} s, found {args.duration}")
    nees_runs = reproduce_nees_runs(runs, args.quick, args.nees_runs)
    cases = default_cases(names())
    check_reproduction_size(runs, args.duration, len(cases))
    args.outputs.folder(args.out, "--out")
    checked = sum(c.bound is not None for c in cases)
    _workers_arg(args)
    workers = args.workers if args.workers is not None or args.scheduler is not None else default_workers()
    serial = args.scheduler is None and workers == 1
    if not serial and not _have_dask():
        if args.workers is not None or args.scheduler is not None:
            raise UsageError(f"--{'workers' if args.workers else 'scheduler'}: {DASK_MISSING}")
        _note(f"{DASK_MISSING}; running serially")
        serial = True
    t0 = time.perf_counter()
    with _runs_bar(progress_total(cases, runs, nees_runs), "reproduce") as bar:
        seen: set[str] = set()

        def step(label: str, run: int, of: int) -> None:
            seen.add(label.removesuffix(NEES_CHECK_LABEL))
            bar.set_postfix_str(f"case {len(seen)}/{len(cases)} {label}, run {run}/{of}", refresh=False)
            bar.update(1)

        if serial:
            res = run_reproduction(runs, duration=args.duration, cases=cases, progress=step, nees_runs=nees_runs)
        else:
            with open_client(args.scheduler, None if args.scheduler else workers) as client:
                # the workers first run one short flight per compiled family (reproduce.warm_up):
                # a load from numba's cache, or on a first run minutes of compiling, said here as
                # the compile notice cannot be from the worker processes
                bar.set_postfix_str("workers loading the filters (compiling them on a first run: 1-3 min)")
                bar.refresh()
                res = run_reproduction(
                    runs, duration=args.duration, cases=cases, progress=step, nees_runs=nees_runs,
                    submit=functools.partial(client.submit, pure=False),
                )
    files = write_reproduction(res, args.out)
    extra = f", NEES check of {checked} cases on {nees_runs} runs" if nees_runs > runs else ""
    print(f"{len(cases)} cases x {runs} runs{extra} in {time.perf_counter() - t0:.0f} s")
    for f in files:
        print(f"wrote {f}")
    from windahrs.experiments.reproduce import claims

    for c in claims(res):
        print(f"[{'holds' if c['holds'] else 'does not hold'}] {c['claim']}: {c['numbers']}")
    print(f"open {args.out / 'report.html'} in a browser for the tables and figures")
    return 0


DASK_MISSING = "dask distributed is not installed (pip install 'windahrs[dask]')"


def _have_dask() -> bool:
    import importlib.util

    return importlib.util.find_spec("distributed") is not None and importlib.util.find_spec("pyarrow") is not None


def _need_pyarrow() -> None:
    import importlib.util

    if importlib.util.find_spec("pyarrow") is None:
        raise UsageError("pyarrow is not installed, and sweep results are Parquet (pip install 'windahrs[dask]')")


def _workers_arg(args: argparse.Namespace) -> None:
    if args.workers is not None and args.scheduler is not None:
        raise UsageError(f"--workers: a local cluster's size, not used with --scheduler {args.scheduler}; give one")
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers: expected an integer >= 1, found {args.workers}")


def _cmd_sweep(args: argparse.Namespace) -> int:
    import contextlib

    from windahrs.experiments.cluster import open_client
    from windahrs.experiments.sweep import ResultStore, load_spec, plan_tasks, run_sweep

    _workers_arg(args)
    _need_pyarrow()
    spec = load_spec(args.spec)  # every field checked before any work
    args.outputs.kept_folder(args.out, "--out")  # (its rows are kept on failure: a rerun resumes)
    todo, _ = plan_tasks(spec, ResultStore(args.out).completed_ids())  # --out: a directory or a new name
    serial = (args.workers == 1 and args.scheduler is None) or not todo  # nothing to do: no cluster
    if not serial and not _have_dask():
        raise UsageError(f"{DASK_MISSING}; or run in this process with --workers 1")
    try:
        with _runs_bar(spec.rows, "sweep") as bar:

            def step(done: int, total: int) -> None:
                if bar.n == 0 and bar.initial == 0 and done > 0:  # rows already present: not in the rate
                    bar.initial = bar.n = done
                    bar.refresh()
                else:
                    bar.update(done - bar.n)

            with contextlib.nullcontext(None) if serial else open_client(args.scheduler, args.workers) as client:
                summary = run_sweep(spec, args.out, client, progress=step)
    except KeyboardInterrupt:
        kept = len(ResultStore(args.out).completed_ids())
        print(f"windahrs sweep: interrupted; {kept} of {spec.rows} rows are in {args.out}, rerun to resume",
              file=sys.stderr)
        return 130
    print(
        f"{summary.computed} rows computed, {summary.skipped} already present, of {summary.total} "
        f"({len(spec.scenarios)} scenarios x {len(spec.estimators)} estimators x {len(spec.seeds)} seeds) "
        f"in {summary.seconds:.0f} s; results in {summary.out}"
    )
    if summary.errors:
        _note(f"{summary.errors} rows record an estimator error (column 'error')")
    for f in summary.failed:
        _note(f"run failed: {f}")
    if summary.failed:
        _note(f"{len(summary.failed)} runs failed and are not in {summary.out}; rerun to retry them")
        return 1
    return 0


def _cmd_sweep_report(args: argparse.Namespace) -> int:
    from windahrs.experiments.sweep import read_results
    from windahrs.report.sweep import write_sweep_report

    _need_pyarrow()
    if not args.results.exists():
        raise UsageError(f"results: {args.results} does not exist")
    rows = read_results(args.results).to_pydict()
    args.outputs.folder(args.out, "--out")
    files = write_sweep_report(rows, args.out, title=f"windahrs sweep: {args.results.name}")
    for f in files:
        print(f"wrote {f}")
    return 0


def _cmd_bench_data(args: argparse.Namespace) -> int:
    import json

    from windahrs.experiments.align import unaligned_clock_note
    from windahrs.experiments.benchdata import bench_data, discover_flights, trial_names
    from windahrs.filters.registry import make_estimator
    from windahrs.flight import with_declination
    from windahrs.metrics import heading_start_note

    specs = _specs(args.filters)
    if args.out is not None:
        args.outputs.file(args.out, "--out")
    for spec in specs:  # fail on a bad name or field before walking the folder
        make_estimator(spec)
    specs = _smoothed(specs, args.smooth)
    found = discover_flights(args.dir)
    if not found.flights:
        why = "; ".join(f"{s.path}: {s.reason}" for s in found.skipped)
        raise UsageError(f"{args.dir}: no readable recording ({why})")
    with _runs_bar(len(found.flights) * len(specs), "bench-data") as bar:

        def step(done: int, total: int) -> None:
            bar.update(done - bar.n)

        own_clock: dict[str, str] = {}  # recording name: the note
        heading_start: dict[str, str] = {}  # ... and the heading-free scoring's

        def on_read(path: Path, flight: Flight) -> None:
            _say_read(path, flight, name_file=True)
            note = None if args.align else unaligned_clock_note(flight)
            if note is not None:
                own_clock[str(path)] = note
            note = heading_start_note(flight)
            if note is not None:
                heading_start[str(path)] = note

        def prepare(flight: Flight) -> Flight:  # --declination, on every recording
            return flight if args.declination is None else with_declination(
                flight, args.declination, source="--declination")

        res = bench_data(
            found.flights, specs, align=args.align, skipped=found.skipped, progress=step, on_read=on_read,
            prepare=prepare,
        )
    label = dict(zip(map(str, found.flights), trial_names(list(found.flights)), strict=True))  # (as the table)
    for notes in (own_clock, heading_start):  # once for the folder, not once per recording
        if notes:
            paths = list(notes)
            shown = ", ".join(label.get(p, Path(p).name) for p in paths[:5]) + (", ..." if len(paths) > 5 else "")
            _note(f"note: {len(paths)} recording{'s' if len(paths) > 1 else ''} ({shown}): {notes[paths[0]]}")
    if not res.trial_names:
        why = "; ".join(f"{s.path}: {s.reason}" for s in res.skipped)
        raise UsageError(f"{args.dir}: no readable recording with a reference ({why})")
    text = json.dumps(res.as_json(), indent=1)
    table = res.table()
    if args.out is not None:
        from windahrs.store import write_bytes

        write_bytes(args.out, (text if args.out.suffix == ".json" else table).encode("utf-8"))
    print(text if args.json else table)
    return 0


def _cmd_filters(args: argparse.Namespace) -> int:
    from windahrs.filters.registry import REGISTRY, make_estimator, names

    if args.name is None:
        available = set(names())
        for name, (_, _, text) in REGISTRY.items():
            mark = "" if name in available else "  (not installed)"
            print(f"{name:<14}{text}{mark}")
        return 0
    est = make_estimator(args.name)  # (an unknown or uninstalled name: its error, naming the known ones)
    base = args.name.split(":")[0]
    print(f"{args.name}: {REGISTRY[base][2]}")
    params = getattr(est, "params", None)
    fields = getattr(type(est), "param_names", None)
    if params is None:  # auto: passed on to the estimator it chooses
        print("parameters (passed on to the estimator it chooses: windahrs filters mekf, windahrs filters "
              "ins-wind):")
        print(textwrap.fill(", ".join(sorted(fields()) if fields is not None else []), width=100,
                            initial_indent="  ", subsequent_indent="  "))
        return 0
    used = sorted(fields()) if fields is not None else [f.name for f in dataclasses.fields(params)]
    print(f"parameters ({len(used)}; set them as {base}:NAME=VALUE, or in a --params TOML file):")
    for name in used:
        print(f"  {name:<28}{getattr(params, name)!r}")
    return 0


def _cmd_info(args: argparse.Namespace) -> int:
    from windahrs.io import detect_format

    flight = _read(args.file, say_repairs=False, declination=args.declination)  # the summary lists them
    print(f"file       {args.file}")
    print(f"format     {detect_format(args.file)}")
    print(flight.summary())
    if flight.gnss is not None and flight.air is not None:  # the wind triangle (paper:wind=fit's wind)
        from windahrs.windfit import WindFitError, fit_flight_wind

        try:
            print(f"wind fit   {fit_flight_wind(flight).text().removeprefix('wind fit: ')}")
        except WindFitError as exc:
            print(f"wind fit   none: {str(exc).removeprefix('wind fit: ')}")
    return 0


def _read(path: Path, *, say_repairs: bool = True, declination: float | None = None) -> Flight:
    """A flight file or a log/dataset the readers know (a warning on stderr when its IMU
    rate is too low for the default noise, and one saying what the edge repaired: once per
    flight, not once per estimator), with its site's declination set to ``declination``
    (degrees, ``--declination``) when given."""
    from windahrs.flight import with_declination
    from windahrs.io import read_flight

    if path.exists() and not (path.is_file() or path.is_dir()):  # reading a FIFO would wait forever
        raise UsageError(f"{path}: not a regular file or directory (a device, FIFO or socket)")
    flight = read_flight(path)
    if declination is not None:
        flight = with_declination(flight, declination, source="--declination")
    _say_read(path, flight, say_repairs=say_repairs)
    return flight


def _say_read(path: Path, flight: Flight, *, say_repairs: bool = True, name_file: bool = False) -> None:
    """The warnings of reading one flight (:func:`_read`'s; bench-data's per recording, with
    ``name_file``: the IMU-rate warning then names the file, as the repairs' does)."""
    from windahrs.filters.params import imu_rate_warning
    from windahrs.repair import RepairWarning, repairs_text

    warning = imu_rate_warning(flight.imu.t)
    if warning:
        _note(f"warning: {path}: {warning}" if name_file else f"warning: {warning}")
    repaired = repairs_text(flight.repairs)
    if repaired and say_repairs:
        warnings.warn(f"{path}: input repaired at the edge: {repaired}", RepairWarning, stacklevel=3)


def _score_line(sc: Score) -> str:
    r = sc.rmse_from50_deg
    s = sc.rmse_steady_deg
    none = "no reference sample scored"  # a span the reference does not cover (NaN)
    first = (
        f"roll {r[0]:.3f} pitch {r[1]:.3f} yaw {r[2]:.3f} deg, total {sc.rmse_total_deg:.3f} deg, "
        f"tilt {sc.rmse_tilt_deg:.3f} deg"
        if math.isfinite(sc.rmse_total_deg) else none
    )
    second = f"roll {s[0]:.3f} pitch {s[1]:.3f} yaw {s[2]:.3f} deg" if all(map(math.isfinite, s)) else none
    return f"RMSE vs {sc.reference} from sample 50: {first}; second half: {second}"


def _cmd_estimate(args: argparse.Namespace) -> int:
    from windahrs.core.kernel import CompiledEstimator
    from windahrs.estimate import save_estimate
    from windahrs.filters.auto import Auto, describe_choice
    from windahrs.filters.registry import make_estimator
    from windahrs.metrics import reference_of, score
    from windahrs.windfit import describe_wind_fit

    if args.out is not None:
        if args.out.exists() and args.file.exists() and args.out.resolve() == args.file.resolve():
            raise UsageError(f"--out: {args.out} is the input FILE; give another name")
        args.outputs.file(args.out, "--out")
    est = make_estimator(args.filter, args.params)
    if args.smooth:
        from windahrs.core.smooth import Smoothed

        try:
            est = est if isinstance(est, Smoothed) else Smoothed(est)
        except ValueError as exc:
            raise UsageError(f"--smooth: {exc}") from None
    if args.cov_every is not None and not isinstance(est, CompiledEstimator | Auto):
        raise UsageError(
            f"--cov-every: {args.filter} records every sample's covariance (only the compiled core's filters "
            "take a stride: auto, mekf, mekf-air, ins-wind, ins-drag, ekf7, ekf10)"
        )
    flight = _read(args.file, declination=args.declination)
    result = est.run(flight) if args.cov_every is None else est.run(flight, cov_every=args.cov_every)  # type: ignore[call-arg]
    chose = describe_choice(result)
    if chose is not None:
        print(chose)
    fitted = describe_wind_fit(result)
    if fitted is not None:
        print(fitted)
    if args.out is not None:
        save_estimate(result, args.out)
        print(f"wrote {args.out}")
    skipped = {k: v for k, v in result.skipped.items() if v}
    if skipped:
        print(f"skipped NaN samples: {skipped}")
    if result.airspeed_scale is not None:
        from windahrs.experiments.compare import airspeed_scale_line

        print(airspeed_scale_line(args.filter, result))
    try:
        reference_of(flight)
    except ValueError:
        print("no truth or reference in the flight: nothing to score")
        return 0
    try:
        scored = score(result, flight)
    except ValueError as exc:  # a reference beside the estimate in time: the estimate stands (and was written)
        print(f"nothing to score: {exc}")
        return 0
    _clock_note(flight, "compare --align")
    print(f"{result.filter if args.smooth else args.filter}: {_score_line(scored)}")
    return 0


def _bar(total: int, desc: str) -> tqdm:
    """A filter-by-filter bar, shown on a terminal only (tqdm's disable=None)."""
    return tqdm(total=total, desc=desc, disable=None, file=sys.stderr)


def _specs(text: str, option: str = "--filters", what: str = "filter") -> list[str]:
    specs = [s.strip() for s in text.split(",") if s.strip()]
    if not specs:
        raise UsageError(f"{option}: expected a comma-separated list of {what} names, found none")
    return specs


def _smoothed(specs: list[str], smooth: bool) -> list[str]:
    """With --smooth, each spec the smoother takes in its smoothed form (``NAME-smooth``,
    ``SPEC:smooth=true``); the others as they are, with a note on stderr."""
    if not smooth:
        return specs
    from windahrs.core.smooth import Smoothed, smoothed_label, supports
    from windahrs.filters.registry import make_estimator

    out = []
    for spec in specs:
        est = make_estimator(spec)
        why = None if isinstance(est, Smoothed) else supports(est)
        if why is not None:
            _note(f"--smooth: {spec} runs unsmoothed ({why})")
        out.append(spec if why is not None or isinstance(est, Smoothed) else smoothed_label(spec))
    return out


def _cmd_compare(args: argparse.Namespace) -> int:
    import json

    from windahrs.experiments.compare import AlignmentError, compare, select_estimators
    from windahrs.filters.auto import describe_choice
    from windahrs.filters.registry import make_estimator
    from windahrs.metrics import heading_start_note
    from windahrs.windfit import describe_wind_fit

    if args.filters is not None:
        # fail on a bad name before any work
        estimators = [make_estimator(n) for n in _smoothed(_specs(args.filters), args.smooth)]
        flight = _read(args.file, declination=args.declination)
    else:  # the defaults, less those the flight lacks a sensor for or that are not installed
        flight = _read(args.file, declination=args.declination)
        selection = select_estimators(None).for_flight(flight)
        for note in selection.notes:
            _note(note)
        estimators = [make_estimator(n) for n in _smoothed(list(selection.estimators), args.smooth)]
    with _bar(len(estimators), "compare") as bar:
        try:
            res = compare(flight, estimators, align=args.align, progress=lambda done, _: bar.update(done - bar.n))
        except AlignmentError as exc:
            raise UsageError(f"--align: {exc.reason}") from None
    for _, est in res.estimates:
        chose = describe_choice(est)
        if chose is not None:
            _note(chose)
        fitted = describe_wind_fit(est)
        if fitted is not None:
            _note(fitted)
    if not args.align:
        _clock_note(flight)
    if (text := heading_start_note(flight)) is not None:
        _note(f"note: {text}")
    al = res.alignment
    if al.skipped:
        _note(f"--align: {al.skipped}")
    if al.text is not None and args.json:  # the alignment is a result: on stderr beside JSON
        print(al.text, file=sys.stderr)
    if al.warning:
        _note(f"warning: {al.warning}")
    print(json.dumps(res.as_json(), indent=1) if args.json else str(res))
    return 0


def _note(text: str) -> None:
    print(f"windahrs: {text}", file=sys.stderr)


def _clock_note(flight: Flight, fix: str = "--align") -> None:
    """A note on stderr when the flight is scored against a reference on a clock of its own
    without an alignment (:func:`windahrs.experiments.align.unaligned_clock_note`)."""
    from windahrs.experiments.align import unaligned_clock_note

    text = unaligned_clock_note(flight)
    if text is not None:
        _note(f"note: {text.replace('--align', fix)}")


def _cmd_report(args: argparse.Namespace) -> int:
    from windahrs.experiments.compare import run_for_report, select_estimators
    from windahrs.report.html import write_html
    from windahrs.report.log_report import build_log_report

    explicit = args.filters is not None
    specs = _specs(args.filters) if explicit else None
    args.outputs.file(args.out, "--out")
    selection = select_estimators(specs)  # fail on a bad name or field before any work
    flight = _read(args.file, declination=args.declination)
    with _bar(len(selection.estimators), "report") as bar:
        run = run_for_report(
            flight, selection, align=args.align, progress=lambda done, _: bar.update(done - bar.n),
            on_failure=lambda spec, why: _note(f"filter {spec} not run: {why}"),
        )
    if not run.results:
        raise UsageError(f"--filters: no filter could run on {args.file}: {run.why_none_ran()}")
    if not args.align:
        _clock_note(flight)
    al = run.alignment
    if al.skipped:
        _note(f"--align: {al.skipped}")
    elif al.failed:
        _note(f"--align: no alignment: {al.failed}")
    if al.text is not None:
        print(al.text)
    if al.warning:
        _note(f"warning: {al.warning}")
    page = build_log_report(
        flight, run.results, alignment=al.alignment, aligned_on=al.aligned_on, failures=run.failures,
        notes=run.notes, title=f"windahrs report: {args.file.name}",
    )
    write_html(args.out, page)
    print(f"wrote {args.out}")
    return 0


_ALIGN_FIT = (
    "before scoring, estimate a constant mounting rotation and time offset between the reference and the FIRST "
    "filter's estimate (put the most accurate first) and remove that one alignment for every filter, so all are "
    "scored against the same reference (fitting each filter its own would also hide its constant errors); "
)
_ALIGN_REST = (
    "Needs a logged reference (mocap or autopilot); a residual over 5 deg, or body rates that agree by under 0.5 "
    "(too little common motion), is flagged as an unreliable alignment. "
    "A GNSS the flight declares on the reference's clock (meta gnss.clock=reference, as ANSFL's) is moved by the "
    "same offset, its timing uncertainty lowered to the fit's, for every filter after the first"
)
ALIGN_HELP = (
    _ALIGN_FIT
    + "prints the mount angle and time offset (beside --json: on stderr, and the alignment's fields in each JSON "
    "row). "
    + _ALIGN_REST
)
#: report has no --json: the alignment is printed and shown in the page.
REPORT_ALIGN_HELP = (
    _ALIGN_FIT + "prints the mount angle and time offset, and the page shows them with the scores against the "
    "reference as logged beside the aligned ones. " + _ALIGN_REST
)
BENCH_ALIGN_HELP = (
    "per recording, before scoring, estimate a constant mounting rotation and time offset between the reference "
    "and the FIRST filter's estimate (put the most accurate first) and remove that one alignment for every "
    "filter, as compare --align does; printed above each recording's table (in --json: 'alignment' by "
    "recording). A recording whose first filter does not run, or whose fit fails, is scored against the reference "
    "as logged, and says so; a residual over 5 deg, or body rates that agree by under 0.5 (too little common "
    "motion), is flagged as an unreliable alignment. A GNSS the recording "
    "declares on the reference's clock (meta gnss.clock=reference, as ANSFL's) is moved by the same offset, its "
    "timing uncertainty lowered to the fit's, for every filter after the first"
)

#: ``{tol}``: :data:`windahrs.flight.DECLINATION_TOL` in degrees, filled in by :func:`_declination_option`.
DECLINATION_HELP = (
    "the site's magnetic declination, degrees east of true north (-180 to 180), replacing what the log says "
    "(PX4 EKF2_MAG_DECL or ATT_MAG_DECL, ArduPilot COMPASS_DEC, a CSV manifest's declination_deg): estimators that "
    "learn the Earth's field from the data turn it by this, so their heading is from true north (without any, "
    "magnetic north). A flight whose field is known (site.mag_n: a simulation, a manifest's mag_n) keeps that "
    "field's declination, and a value more than {tol} deg from it is refused"
)
INFO_DECLINATION_HELP = DECLINATION_HELP + "; shown in the site line, meta site.declination_param = --declination"
BENCH_DECLINATION_HELP = (
    DECLINATION_HELP + "; applies to every recording in the folder (one whose known field disagrees is skipped, "
    "with the reason)"
)

SMOOTH_HELP_ONE = (
    "offline: run the filter's smoother over the whole flight (mekf, mekf-air, ins-wind, ins-drag, auto; "
    "same as the spec NAME-smooth): attitude, bias, velocity, wind and covariance from the whole log, by two "
    "filters forward and backward in time (Rauch-Tung-Striebel when the filter fuses air data or drag); fails for "
    "another filter"
)
SMOOTH_HELP_MANY = (
    "offline: run each filter the smoother takes (mekf, mekf-air, ins-wind, ins-drag, auto) as its smoother "
    "(NAME-smooth: two filters forward and backward in time, or Rauch-Tung-Striebel with air data or drag); the "
    "others run as they are, with a note on stderr"
)


def _declination_option(parser: argparse.ArgumentParser, help_text: str) -> None:
    """``--declination DEG`` on a command that reads a recorded flight (``help_text``:
    :data:`DECLINATION_HELP` or a variant, its tolerance filled in)."""
    from windahrs.flight import DECLINATION_TOL

    parser.add_argument("--declination", type=_declination, default=None, metavar="DEG",
                        help=help_text.format(tol=f"{math.degrees(DECLINATION_TOL):g}"))


def _parser() -> argparse.ArgumentParser:
    from windahrs.experiments.compare import DEFAULT_REPORT_FILTERS

    p = _Parser(
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
        type=_number,
        default=0.0,
        metavar="W20",
        help="mean wind at 20 ft in m/s, which also sets the turbulence intensity "
        "(for --vehicle paper: the paper's wind speed). Default 0.",
    )
    s.add_argument(
        "--altitude",
        type=_number,
        default=None,
        metavar="H",
        help="height above ground in m (default: 50 fixed wing, 20 quadrotor and paper)",
    )
    s.add_argument(
        "--duration",
        type=_number,
        default=None,
        metavar="S",
        help="seconds (default: 120; 10 for paper)",
    )
    s.add_argument("--seed", type=_seed, default=0, metavar="N", help="random seed (default 0)")
    s.add_argument("--fault", action="append", default=None, metavar="KIND:field=value:...",
                   help="inject a sensor fault after the simulation (repeatable; the truth is untouched), e.g. "
                   "gyro-spike:start=30:magnitude=40 or gnss-outage:start=20:duration=10; kinds and fields in "
                   "docs/ROBUSTNESS.md. Faults whose stamps a Flight refuses (duplicate-stamps, out-of-order) are "
                   "refused in an HDF5 flight file: write them with --csv")
    s.add_argument("--csv", action="store_true",
                   help="write --out as a generic-CSV directory (docs/csv-format.md, the truth as the reference) "
                   "instead of HDF5, keeping what a Flight refuses (duplicated or out-of-order stamps, Inf) for the "
                   "readers' edge repair")
    # a file, or with --csv a directory: the text is kept (a trailing "/" names a directory)
    s.add_argument("--out", type=_text_path, required=True, metavar="FILE.h5", help="output file")
    s.set_defaults(func=_cmd_simulate)

    ft = sub.add_parser(
        "faults",
        help="the fault matrix: sensor faults x estimators on a simulated flight, flags and recovery",
        description="Simulate one seeded flight, inject each fault of the catalogue in turn (gyro and "
        "accelerometer spikes, NaN samples, dropouts, stuck values, vibration, saturation, a magnet, a drifting "
        "or absent or late magnetometer, pitot and vane failures, GNSS outage and jumps, jittered, duplicated and "
        "out-of-order stamps) and run every estimator on the clean and the faulty flights. Writes DIR/faults.md "
        "and DIR/faults.json: per fault and filter the NaN rows, whether and how soon a flag was raised, the "
        "attitude error before, during and after the fault and the time to recover (docs/ROBUSTNESS.md).",
    )
    ft.add_argument("--filters", default="ins-wind,mekf,mekf-air,auto", metavar="A,B,...",
                    help="estimator specs (default ins-wind,mekf,mekf-air,auto; one that needs a sensor the vehicle "
                    "lacks is listed as not run)")
    ft.add_argument("--vehicle", choices=("fixedwing", "quadrotor"), default="fixedwing",
                    help="fixedwing (pitot and vanes) or quadrotor (no air data). Default fixedwing")
    ft.add_argument("--wind", type=_number, default=8.0, metavar="W20", help="W20 in m/s (default 8)")
    ft.add_argument("--duration", type=_number, default=90.0, metavar="S",
                    help="flight length in s (default 90); the faults start at a third of it")
    ft.add_argument("--seed", type=_seed, default=0, metavar="N", help="seed of the flight and the faults (default 0)")
    ft.add_argument("--faults", default=None, metavar="NAME,...",
                    help="only these cases of the matrix (default all; names as in faults.md, e.g. gyro-spike)")
    ft.add_argument("--out", type=_path, required=True, metavar="DIR", help="output directory (made if missing)")
    ft.set_defaults(func=_cmd_faults)

    i = sub.add_parser(
        "info",
        help="describe a flight file or log: streams, rates, duration, truth or reference",
        description="Read a windahrs flight file or any log or dataset the readers know (.ulg, .bin/.log, "
        "BROAD .hdf5, an ALFA, generic-CSV or ANSFL directory) and print its format, its streams with their "
        "rates, missing samples and gaps, the duration, whether truth or a reference is present (and which "
        "kind), the site, what the reader repaired (samples out of order, repeated stamps, infinite values and "
        "samples beyond the sensor's range: a count per stream and kind) and the reader's notes (meta).",
    )
    i.add_argument("file", type=_path, metavar="FILE", help="a windahrs flight file, a log or a dataset directory")
    _declination_option(i, INFO_DECLINATION_HELP)
    i.set_defaults(func=_cmd_info)

    e = sub.add_parser(
        "estimate",
        help="run one estimator on a flight or log; print its RMSE when there is truth or a reference",
        description="Run one estimator (see 'windahrs filters') over a flight file or log and write "
        "its Estimate (attitude, bias, wind, covariance, innovations) as HDF5.",
    )
    e.add_argument("file", type=_path, metavar="FILE", help="a windahrs flight file or a log")
    e.add_argument("--filter", default="auto", metavar="NAME",
                   help="estimator spec, e.g. ins-wind, mekf:mag_mode=heading or paper:wind=mean:mean_wind_n=3/-2/0 "
                   "(a vector's components separated by /) (default: auto, which runs ins-wind "
                   "when the flight has GNSS velocity, else mekf, and prints which)")
    e.add_argument(
        "--params",
        type=_path,
        default=None,
        metavar="FILE.toml",
        help="parameters: [windahrs] fields, or [px4] / [ardupilot] parameter names",
    )
    e.add_argument("--out", type=_file_path, default=None, metavar="EST.h5", help="write the Estimate here")
    e.add_argument(
        "--cov-every", type=_count, default=None, metavar="K",
        help="record the covariance at every K-th IMU sample (1: every sample; default: at 20 Hz within 128 MiB; "
        "the compiled core's filters, docs/core.md 'The covariance record')",
    )
    e.add_argument("--smooth", action="store_true", help=SMOOTH_HELP_ONE)
    _declination_option(e, DECLINATION_HELP)
    e.set_defaults(func=_cmd_estimate)

    c = sub.add_parser(
        "compare",
        help="run several estimators on one flight and print their RMSE side by side",
        description="RMSE per axis from sample 50 and over the second half, tilt and total, per estimator, "
        "against the flight's truth (simulation) or reference (mocap, autopilot).",
    )
    c.add_argument("file", type=_path, metavar="FILE")
    c.add_argument(
        "--filters", default=None, metavar="A,B,...",
        help=f"comma-separated estimator specs (default: {','.join(DEFAULT_REPORT_FILTERS)}, leaving out those the "
        "flight lacks a sensor for or that are not installed)",
    )
    c.add_argument("--json", action="store_true", help="print a JSON list instead of a table")
    c.add_argument("--smooth", action="store_true", help=SMOOTH_HELP_MANY)
    c.add_argument("--align", action="store_true", help=ALIGN_HELP)
    _declination_option(c, DECLINATION_HELP)
    c.set_defaults(func=_cmd_compare)

    rp = sub.add_parser(
        "report",
        help="one HTML page: estimators against the reference, errors, innovations and NIS, wind, sensors",
        description="Run estimators on a flight or log and write a self-contained HTML report: attitude of each "
        "estimator against the flight's truth or reference with the errors and the RMSE table of 'compare', "
        "innovations and NIS per sensor, the wind estimate against the log's own wind, and a sensor summary "
        "(rates, gaps, NaN samples, saturation). A filter that cannot run (e.g. a missing sensor) is listed in "
        "the report and on stderr; the command fails only when no filter runs.",
    )
    rp.add_argument("file", type=_path, metavar="FILE", help="a windahrs flight file or a log")
    rp.add_argument(
        "--filters", default=None, metavar="A,B,...",
        help=f"estimator specs (default: {','.join(DEFAULT_REPORT_FILTERS)}, leaving out those the flight lacks a "
        "sensor for or that are not installed)",
    )
    rp.add_argument("--align", action="store_true", help=REPORT_ALIGN_HELP)
    _declination_option(rp, DECLINATION_HELP)
    rp.add_argument("--out", type=_file_path, required=True, metavar="REPORT.html", help="the HTML file to write")
    rp.set_defaults(func=_cmd_report)

    x = sub.add_parser(
        "experiment",
        help="Monte Carlo: estimators on N simulated flights in wind, RMSE per axis",
        description="Simulate N seeded flights of one scenario and run every estimator on each; print "
        "RMSE per axis (from sample 50 and over the second half), tilt and total, aggregated over runs. "
        "Filters are registry names, optionally with parameter overrides: NAME:field=value:field=value "
        "(e.g. paper:wind=mean).",
    )
    x.add_argument("--vehicle", choices=("fixedwing", "quadrotor", "paper"), default="fixedwing")
    x.add_argument("--wind", type=_number, default=8.0, metavar="W20", help="W20 in m/s (default 8)")
    x.add_argument("--duration", type=_number, default=120.0, metavar="S", help="seconds (default 120)")
    x.add_argument("--altitude", type=_number, default=None, metavar="H", help="m (vehicle default)")
    x.add_argument("--runs", type=_count, default=5, metavar="N", help="flights (default 5)")
    x.add_argument("--seed", type=_seed, default=0, metavar="N", help="first seed (default 0)")
    x.add_argument("--fault", action="append", default=None, metavar="KIND:field=value:...",
                   help="inject a sensor fault into every simulated flight (repeatable; as simulate's), e.g. "
                   "pitot-scale:start=0:duration=120:scale=0.75 (the pitot reads 25 %% low)")
    x.add_argument("--filters", default=DEFAULT_EXPERIMENT_FILTERS, metavar="A,B,...",
                   help=f"estimator specs (default: {DEFAULT_EXPERIMENT_FILTERS})")
    x.add_argument("--json", action="store_true", help="print JSON instead of a table")
    x.set_defaults(func=_cmd_experiment)

    r = sub.add_parser(
        "reproduce",
        help="rerun the paper's section 4 experiment and score every estimator against the PCRB",
        description="The paper's Fig. 4-6 cases (no wind; 5 and 8 m/s with the wind considered, as the "
        "instantaneous true wind or only its mean, and ignored; EKF vs UKF vs the proposed filter) by the "
        "protocol of SPEC 7.3, then the modern estimators and the outside baselines on the same flights. "
        "Writes DIR/results.json, DIR/results.md, PNG figures and DIR/report.html (self-contained).",
    )
    r.add_argument("--runs", type=_count, default=None, metavar="N", help="Monte Carlo runs per case (default 50)")
    r.add_argument("--quick", action="store_true", help="5 runs per case (unless --runs is given)")
    r.add_argument("--nees-runs", type=_count, default=None, metavar="M",
                   help=f"runs of the physically tuned filters' NEES check, at least the runs per case (default "
                   f"{NEES_CHECK_BLOCKS} x the runs per case, 400 without --runs; with --quick, the runs per case: "
                   "no extra flights); the check is also reported per block of the runs per case")
    r.add_argument("--duration", type=_number, default=20.0, metavar="S", help="seconds per run (default 20)")
    r.add_argument("--out", type=_path, required=True, metavar="DIR", help="output directory")
    r.add_argument("--workers", type=_count, default=None, metavar="N",
                   help="run on a local Dask cluster of N processes (default: one per core); 1 runs serially in this "
                   "process. The results are the same bit for bit")
    r.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                   help="run on this running Dask scheduler's workers instead of a local cluster")
    r.set_defaults(func=_cmd_reproduce)

    sw = sub.add_parser(
        "sweep",
        help="many simulated flights x estimators from a TOML spec, on Dask, into Parquet (resumable)",
        description="Run every scenario x estimator x seed of a TOML sweep spec (docs/sweep.md) on a Dask cluster "
        "and append one row per run and estimator to a Parquet dataset directory: the parameters, RMSE per axis, "
        "tilt and total, convergence time, NEES, the PCRB ratio where a bound applies, run time and a "
        "content-addressed run id. Rerunning resumes: rows already present are skipped. Ctrl-C keeps the rows "
        "finished so far.",
    )
    sw.add_argument("spec", type=_path, metavar="SPEC.toml", help="the sweep specification")
    sw.add_argument("--out", type=_path, required=True, metavar="RESULTS.parquet",
                    help="the Parquet dataset directory (created; part files are added to it)")
    sw.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                    help="submit to this running Dask scheduler instead of starting a local cluster")
    sw.add_argument("--workers", type=_count, default=None, metavar="N",
                    help="local cluster size, one process per worker with one thread (default: one per core); "
                    "1 runs in this process without Dask")
    sw.set_defaults(func=_cmd_sweep)

    sr = sub.add_parser(
        "sweep-report",
        help="tables and figures of a sweep's Parquet results in one HTML page",
        description="Read a sweep's Parquet dataset and write DIR/report.html (self-contained), DIR/summary.md "
        "and PNG figures: per scenario family, a table of estimator x wind speed (mean and spread over seeds of "
        "the RMSE, convergence, NEES, PCRB ratio) and RMSE against wind speed per estimator with the spread over "
        "seeds.",
    )
    sr.add_argument("results", type=_path, metavar="RESULTS.parquet", help="a sweep's dataset directory")
    sr.add_argument("--out", type=_path, required=True, metavar="DIR", help="output directory")
    sr.set_defaults(func=_cmd_sweep_report)

    b = sub.add_parser(
        "bench-data",
        help="every estimator over every recording in a folder: total, inclination (tilt), heading RMSE",
        description="Run estimators over every recording the readers know under DIR, walked recursively (BROAD "
        ".hdf5 trials, windahrs .h5 flights, .ulg, .bin/.log, ALFA, generic-CSV and ANSFL directories; a "
        "directory that is a recording is not descended into) and score each against its truth or reference "
        "with BROAD's metric: total, inclination (tilt) and heading RMSE per recording, a constant heading offset "
        "removed where the reference's heading datum is not the estimators' (mocap; ANSFL, which has no "
        "magnetometer), and the median over recordings. A file that cannot be read is listed as skipped with the "
        "reason; a filter that cannot run on a recording (e.g. ins-wind without GNSS) fails only that row.",
    )
    b.add_argument("dir", type=_path, metavar="DIR", help="a folder of recordings (or one recording)")
    b.add_argument("--filters", default="auto,mekf,ekf7,vqf,vqf-offline,madgwick,mahony,imufusion",
                   metavar="A,B,...", help="estimator specs (a filter that cannot run on a recording fails that "
                   "row only)")
    b.add_argument("--align", action="store_true", help=BENCH_ALIGN_HELP)
    b.add_argument("--smooth", action="store_true", help=SMOOTH_HELP_MANY)
    _declination_option(b, BENCH_DECLINATION_HELP)
    b.add_argument("--json", action="store_true", help="print the JSON result instead of the table")
    b.add_argument("--out", type=_file_path, default=None, metavar="FILE", help="also write .json or a text table")
    b.set_defaults(func=_cmd_bench_data)

    fl = sub.add_parser(
        "filters", help="list the estimators, or one estimator's parameters",
        description="List the registered estimators; with NAME, the parameters that estimator takes and their "
        "defaults (what a spec NAME:FIELD=VALUE or a --params file may set).",
    )
    fl.add_argument("name", nargs="?", default=None, metavar="NAME", help="an estimator (e.g. mekf)")
    fl.set_defaults(func=_cmd_filters)
    return p


def _one_line_warning(command: str) -> Callable[..., None]:
    """Warnings on stderr as ``windahrs COMMAND: warning: message``, one line each."""

    def show(message: Warning | str, category: type[Warning], *_: object, **__: object) -> None:
        print(f"windahrs {command}: warning: {message}", file=sys.stderr)

    return show


#: The options whose values the library checks under their own names (``duration: ...``):
#: its message then names the option as the user typed it (``--duration: ...``).
_LIBRARY_NAMES = ("duration", "wind", "altitude", "seed", "runs", "nees_runs", "vehicle", "filter", "filters")


def _one_line(exc: BaseException, args: argparse.Namespace) -> str:
    """The message of ``exc`` on one line, the library's field named as the CLI option."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    name, sep, rest = text.partition(": ")
    if sep and name in _LIBRARY_NAMES and hasattr(args, name):
        text = f"--{name.replace('_', '-')}: {rest}"
    return text


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status (0 done, 2 bad input, 1 other failure, 130
    interrupted; see the module docstring). Set WINDAHRS_DEBUG=1 for the traceback of an
    unexpected error."""
    from windahrs.estimate import EstimatorWarning
    from windahrs.repair import RepairWarning
    from windahrs.store import OutputError

    parser = _parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    args.outputs = outputs = _Outputs()
    interrupted = False

    def on_sigint(signum: int, frame: FrameType | None) -> None:
        nonlocal interrupted
        interrupted = True
        raise KeyboardInterrupt

    def fail(status: int, text: str) -> int:
        outputs.discard()
        print(f"windahrs {args.command}: {text}", file=sys.stderr)
        return status

    def unraisable(u: sys.UnraisableHookArgs) -> None:
        # A Ctrl-C that lands in a finaliser or weakref callback (numba's and llvmlite's
        # __del__, h5py's dealloc) cannot propagate: Python would print "Exception ignored"
        # with a traceback and go on. Raise it again in the main flow instead.
        if u.exc_type is not None and issubclass(u.exc_type, KeyboardInterrupt):
            if retry is not None:  # 10 ms on, outside this hook and the finaliser
                signal.setitimer(signal.ITIMER_REAL, 0.01)
            return
        if interrupted:  # an object a Ctrl-C cut off half-built, failing in its finaliser: the
            return  # interrupt's own consequence, said by its one line
        print(f"windahrs {args.command}: warning: ignored in {u.object!r}: {u.exc_type.__name__}: "
              f"{' '.join(str(u.exc_value).split())}", file=sys.stderr)

    # Python's own handler raises KeyboardInterrupt too; this one also remembers it, for a
    # Ctrl-C raised where it is swallowed
    previous = signal.signal(signal.SIGINT, on_sigint) if _main_thread() else None
    retry = signal.signal(signal.SIGALRM, on_sigint) if previous is not None and hasattr(signal, "setitimer") else None
    previous_hook, sys.unraisablehook = sys.unraisablehook, unraisable
    try:
        with warnings.catch_warnings(), compile_notice(sys.stderr):
            warnings.simplefilter("always", EstimatorWarning)  # each flight's, not the first only
            warnings.simplefilter("always", RepairWarning)
            warnings.showwarning = _one_line_warning(args.command)
            status = func(args)
        if interrupted:
            raise KeyboardInterrupt
        return status
    except KeyboardInterrupt:
        return fail(130, "interrupted; nothing was written")
    except BrokenPipeError:
        # Output piped into e.g. `head`: stop quietly, as Unix tools do.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OutputError as exc:  # writable when checked, then failed: a full disk, say
        return fail(1, f"error: {_one_line(exc, args)}")
    except (UsageError, ValueError, OSError) as exc:  # FlightError, LogFormatError, StoreError, missing files
        return fail(2, f"error: {_one_line(exc, args)}")
    except MemoryError:
        return fail(1, "error: out of memory")
    except Exception as exc:
        if os.environ.get("WINDAHRS_DEBUG"):
            raise
        return fail(1, f"error: internal error, please report it (set WINDAHRS_DEBUG=1 for the traceback): "
                       f"{type(exc).__name__}: {_one_line(exc, args)}")
    finally:
        sys.unraisablehook = previous_hook
        if retry is not None:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, retry)
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


#: Said once per command at a terminal when numba starts compiling (not on a load from its cache).
COMPILE_NOTICE = (
    "windahrs: compiling the filters for this machine (numba, first run only: up to a minute per "
    "family of filters, then cached) ..."
)


def compile_notice(stream: TextIO) -> contextlib.AbstractContextManager[object]:
    """While active, :data:`COMPILE_NOTICE` is written to ``stream`` the first time numba
    compiles (a fresh install's first run of a filter waits 10-60 s with nothing else to
    show), when ``stream`` is a terminal; through tqdm, above any progress bar."""
    if not (hasattr(stream, "isatty") and stream.isatty()):
        return contextlib.nullcontext()
    from numba.core import event

    class Notice(event.Listener):
        said = False

        def on_start(self, ev: object) -> None:
            if not self.said:
                self.said = True
                tqdm.write(COMPILE_NOTICE, file=stream)

        def on_end(self, ev: object) -> None:
            pass

    return event.install_listener("numba:compile", Notice())


def _main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def entry() -> None:
    """The console script: :func:`main`'s status is the exit status. After a Ctrl-C (130)
    the process ends without Python's finalisation, once its line is out and the outputs
    are discarded: an interrupt that cut numba's compiler off midway can leave objects whose
    finalisers crash (exit status -11 after the interrupted line, once, in a test run that
    compiled on both cores)."""
    status = main()
    if status == 130:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    sys.exit(status)


if __name__ == "__main__":  # pragma: no cover
    entry()
