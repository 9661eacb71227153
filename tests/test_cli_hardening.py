"""The command line under bad input (issue 13, "A hardened CLI").

Every command, given a bad path, an unwritable or full output, malformed or absurd TOML or
parameter values, an unknown name, an absurd number, or Ctrl-C, exits non-zero with ONE line
on stderr that names the argument, field or path; never a traceback; and leaves no partial
output (files or folders) behind.

One row of :data:`CASES` per bad input. A new command adds its rows there: ``argv`` is split
like a shell line after its placeholders are filled in:

``{flight}``  a small simulated flight file (valid), in a folder of its own
``{t}``       the case's own empty folder (also the working directory), whose tree must be
              the same after the command as before (plus the ``files`` of the row)
``{ro}``      a folder on a read-only file system (a read-only tmpfs as root, else a folder
              without write permission); rows using it skip where neither is possible

``files`` are created under ``{t}`` first: ``(name, text)``; a text of ``"/"`` makes a folder,
``"|"`` a FIFO. Lines of the documented progress of experiment, reproduce and bench-data on
stderr are not counted (:data:`PROGRESS`).
``expect`` must occur in the one line on stderr; ``rc`` is the exit status (2: bad input).

Ctrl-C (SIGINT) and a full file system run the CLI in a subprocess (:func:`test_sigint_leaves_nothing`,
:func:`test_full_file_system`); everything else runs in-process through ``windahrs.cli.main``.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from windahrs.cli import main

REPO = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Case:
    argv: str
    expect: str
    files: tuple[tuple[str, str], ...] = ()
    rc: int = 2


def toml(text: str, name: str = "p.toml") -> tuple[tuple[str, str], ...]:
    return ((name, text),)


A_FILE = (("afile", "not a folder\n"),)
A_DIR = (("adir", "/"),)
OUT = "--out {t}/out.h5"
EST = "estimate {flight} --filter mekf"
P = "--params {t}/p.toml"
HUGE_INT = "1" + "0" * 29  # a 30-digit number
BOOL_NOISE = toml("[windahrs]\ngyro_noise = true\n")
HUGE_NOISE = toml("[windahrs]\ngyro_noise = 1e60\n")
SWEEP = ('[sweep]\nseeds = 1\n[grid]\nvehicle = "fixedwing"\nwind = [0.0]\nduration = 5.0\n'
         '[[estimator]]\nname = "mekf"\n')


CASES: dict[str, Case] = {
    # ---- simulate: numbers --------------------------------------------------------------------------------
    "sim-duration-nan": Case(f"simulate --duration nan {OUT}", "--duration"),
    "sim-duration-inf": Case(f"simulate --duration inf {OUT}", "--duration"),
    "sim-duration-neg": Case(f"simulate --duration -3 {OUT}", "--duration"),
    "sim-duration-zero": Case(f"simulate --duration 0 {OUT}", "--duration"),
    "sim-duration-tiny": Case(f"simulate --duration 1e-9 {OUT}", "--duration"),
    "sim-duration-huge": Case(f"simulate --duration 1e9 {OUT}", "--duration"),
    "sim-duration-huge-paper": Case(f"simulate --vehicle paper --duration 1e9 {OUT}", "--duration"),
    "sim-duration-huge-quad": Case(f"simulate --vehicle quadrotor --duration 1e12 {OUT}", "--duration"),
    "sim-duration-word": Case(f"simulate --duration abc {OUT}", "--duration"),
    "sim-duration-empty": Case(f"simulate --duration '' {OUT}", "--duration"),
    "sim-wind-nan": Case(f"simulate --wind nan {OUT}", "--wind"),
    "sim-wind-inf": Case(f"simulate --wind inf {OUT}", "--wind"),
    "sim-wind-neg": Case(f"simulate --wind -1 {OUT}", "--wind"),
    "sim-wind-huge": Case(f"simulate --wind 1e6 --duration 1 {OUT}", "--wind"),
    "sim-wind-huge-paper": Case(f"simulate --vehicle paper --wind 1e6 --duration 1 {OUT}", "--wind"),
    "sim-wind-huge-quad": Case(f"simulate --vehicle quadrotor --wind 500 --duration 1 {OUT}", "--wind"),
    "sim-wind-1e300": Case(f"simulate --wind 1e300 --duration 1 {OUT}", "--wind"),
    "sim-altitude-nan": Case(f"simulate --altitude nan {OUT}", "--altitude"),
    "sim-altitude-low": Case(f"simulate --altitude 1 {OUT}", "altitude"),
    "sim-altitude-neg": Case(f"simulate --altitude -50 {OUT}", "altitude"),
    "sim-altitude-huge": Case(f"simulate --altitude 1e9 {OUT}", "altitude"),
    "sim-altitude-quad-huge": Case(f"simulate --vehicle quadrotor --altitude 1e9 {OUT}", "altitude"),
    "sim-seed-neg": Case(f"simulate --seed -1 {OUT}", "--seed"),
    "sim-seed-30-digits": Case(f"simulate --seed {HUGE_INT} --duration 1 {OUT}", "--seed"),
    "sim-seed-float": Case(f"simulate --seed 1.5 {OUT}", "--seed"),
    "sim-seed-word": Case(f"simulate --seed x {OUT}", "--seed"),
    "sim-vehicle": Case(f"simulate --vehicle rocket {OUT}", "--vehicle"),
    "sim-unknown-option": Case(f"simulate --bogus 1 {OUT}", "--bogus"),
    "sim-no-out": Case("simulate --duration 1", "--out"),
    # ---- simulate: outputs ----------------------------------------------------------------------------------
    "sim-out-empty": Case("simulate --duration 1 --out ''", "--out"),
    "sim-out-dir": Case("simulate --duration 1 --out {t}/adir", "adir", A_DIR),
    "sim-out-dot": Case("simulate --duration 1 --out .", "--out"),
    "sim-out-parent-file": Case("simulate --duration 1 --out {t}/afile/x.h5", "afile is not a directory", A_FILE),
    "sim-out-no-parent": Case("simulate --duration 1 --out {t}/nodir/x.h5", "nodir does not exist"),
    "sim-out-readonly": Case("simulate --duration 1 --out {ro}/x.h5", "--out"),
    "sim-out-fifo": Case("simulate --duration 1 --out {t}/fifo", "not a regular file", (("fifo", "|"),)),
    "est-out-fifo": Case(f"{EST} --out {{t}}/fifo", "not a regular file", (("fifo", "|"),)),
    "sim-out-trailing-slash": Case("simulate --duration 1 --out {t}/x.h5/", "--out"),
    # ---- simulate: --fault and --csv ----------------------------------------------------------------------------
    "sim-fault-unknown": Case(f"simulate --duration 2 --fault nope {OUT}", "'nope'"),
    "sim-fault-field": Case(f"simulate --duration 2 --fault gyro-spike:nope=1 {OUT}", "GyroSpike.nope"),
    "sim-fault-nan": Case(f"simulate --duration 2 --fault gyro-spike:start=nan {OUT}", "GyroSpike.start"),
    "sim-fault-bool": Case(f"simulate --duration 2 --fault gyro-spike:start=true {OUT}", "GyroSpike.start"),
    "sim-fault-no-value": Case(f"simulate --duration 2 --fault duplicate-stamps {OUT}", "DuplicateStamps.start"),
    "sim-fault-empty": Case(f"simulate --duration 2 --fault '' {OUT}", "fault"),
    "sim-csv-exists": Case("simulate --duration 2 --csv --out {t}/adir", "does not exist yet", A_DIR),
    "sim-csv-parent-file": Case("simulate --duration 2 --csv --out {t}/afile/c", "afile is not a directory", A_FILE),
    "sim-csv-no-parent": Case("simulate --duration 2 --csv --out {t}/nodir/c", "nodir does not exist"),
    "sim-csv-readonly": Case("simulate --duration 2 --csv --out {ro}/c", "--out"),
    "sim-csv-huge": Case("simulate --duration 1e9 --csv --out {t}/c", "--duration"),
    # ---- sweep and sweep-report --------------------------------------------------------------------------------
    "swp-no-spec": Case("sweep --out {t}/r.parquet", "SPEC.toml"),
    "swp-spec-missing": Case("sweep {t}/nope.toml --out {t}/r.parquet", "nope.toml"),
    "swp-spec-dir": Case("sweep {t}/adir --out {t}/r.parquet", "adir", A_DIR),
    "swp-spec-not-toml": Case("sweep {t}/s.toml --out {t}/r.parquet", "s.toml", toml("seeds = [\n", "s.toml")),
    "swp-spec-unknown-key": Case("sweep {t}/s.toml --workers 1 --out {t}/r.parquet", "bogus",
                                 toml(SWEEP.replace("seeds = 1", "seeds = 1\nbogus = 1"), "s.toml")),
    "swp-workers-zero": Case("sweep {t}/s.toml --workers 0 --out {t}/r.parquet", "--workers",
                             toml("seeds = [0]\n", "s.toml")),
    "swp-workers-and-scheduler": Case("sweep {t}/s.toml --workers 2 --scheduler tcp://127.0.0.1:1 --out {t}/r",
                                      "--workers", toml("seeds = [0]\n", "s.toml")),
    "swp-out-parent-file": Case("sweep {t}/s.toml --workers 1 --out {t}/afile/r", "afile",
                                (*A_FILE, ("s.toml", SWEEP))),
    "swp-out-readonly": Case("sweep {t}/s.toml --workers 1 --out {ro}/r", "--out", toml(SWEEP, "s.toml")),
    "swr-results-missing": Case("sweep-report {t}/nope.parquet --out {t}/rep", "nope.parquet"),
    "swr-no-out": Case("sweep-report {t}/adir", "--out", A_DIR),
    # ---- faults ---------------------------------------------------------------------------------------------
    "flt-no-out": Case("faults", "--out"),
    "flt-out-empty": Case("faults --out ''", "--out"),
    "flt-out-file": Case("faults --out {t}/afile", "afile", A_FILE),
    "flt-out-parent-file": Case("faults --out {t}/afile/f", "afile is not a directory", A_FILE),
    "flt-out-readonly": Case("faults --out {ro}/f", "--out"),
    "flt-filters-empty": Case("faults --filters '' --out {t}/f", "--filters"),
    "flt-filters-unknown": Case("faults --filters mekf,nope --out {t}/f", "'nope'"),
    "flt-filters-bool": Case("faults --filters mekf:gyro_noise=true --out {t}/f", "gyro_noise"),
    "flt-wind-nan": Case("faults --wind nan --out {t}/f", "--wind"),
    "flt-wind-huge": Case("faults --wind 1e6 --out {t}/f", "--wind"),
    "flt-duration-zero": Case("faults --duration 0 --out {t}/f", "--duration"),
    "flt-duration-huge": Case("faults --duration 1e9 --out {t}/f", "--duration"),
    "flt-seed-neg": Case("faults --seed -1 --out {t}/f", "--seed"),
    "flt-seed-huge": Case(f"faults --seed {HUGE_INT} --out {{t}}/f", "--seed"),
    "flt-faults-unknown": Case("faults --faults nope --out {t}/f", "nope"),
    "flt-faults-empty": Case("faults --faults '' --out {t}/f", "--faults"),
    "flt-vehicle": Case("faults --vehicle paper --out {t}/f", "--vehicle"),
    # ---- info -----------------------------------------------------------------------------------------------
    "info-missing": Case("info {t}/none.h5", "none.h5"),
    "info-empty-path": Case("info ''", "''"),
    "info-empty-file": Case("info {t}/e.h5", "e.h5", (("e.h5", ""),)),
    "info-garbage-h5": Case("info {t}/g.h5", "g.h5", (("g.h5", "garbage" * 50),)),
    "info-garbage-ulg": Case("info {t}/g.ulg", "g.ulg", (("g.ulg", "garbage" * 50),)),
    "info-garbage-bin": Case("info {t}/g.bin", "g.bin", (("g.bin", "garbage" * 50),)),
    "info-text-file": Case("info {t}/notes.txt", "notes.txt", (("notes.txt", "hello\n"),)),
    "info-unknown-dir": Case("info {t}/adir", "adir", A_DIR),
    "info-bad-manifest": Case("info {t}/csv", "windahrs.toml", (("csv", "/"), ("csv/windahrs.toml", "[[[\n"))),
    "info-fifo": Case("info {t}/fifo", "not a regular file", (("fifo", "|"),)),
    "est-fifo": Case("estimate {t}/fifo.h5 --filter mekf", "not a regular file", (("fifo.h5", "|"),)),
    "info-parent-file": Case("info {t}/afile/x.h5", "afile", A_FILE),
    "info-extra-arg": Case("info {flight} {flight}", "unrecognized"),
    "info-no-arg": Case("info", "FILE"),
    # ---- filters and the top level --------------------------------------------------------------------------
    "filters-extra": Case("filters mekf ekf7", "unrecognized"),
    "filters-unknown": Case("filters nope", "unknown 'nope'; known filters"),
    "filters-bad-spec": Case("filters mekf:nope=1", "nope"),
    "filters-option": Case("filters --bogus", "--bogus"),
    "no-command": Case("", "COMMAND"),
    "unknown-command": Case("fly", "'fly'"),
    # ---- estimate: names and --filter fields ----------------------------------------------------------------
    "est-missing-file": Case("estimate {t}/none.h5 --filter mekf", "none.h5"),
    "est-empty-file-arg": Case("estimate '' --filter mekf", "''"),
    "est-dir-file-arg": Case("estimate {t}/adir --filter mekf", "adir", A_DIR),
    "est-garbage-file": Case("estimate {t}/g.h5 --filter mekf", "g.h5", (("g.h5", "x" * 100),)),
    "est-unknown-filter": Case("estimate {flight} --filter nope", "'nope'"),
    "est-empty-filter": Case("estimate {flight} --filter ''", "--filter"),
    "est-filter-colon": Case("estimate {flight} --filter mekf:", "mekf:"),
    "est-filter-no-value": Case("estimate {flight} --filter mekf:gyro_noise", "gyro_noise"),
    "est-filter-unknown-field": Case("estimate {flight} --filter mekf:nope=1", "'nope'"),
    "est-filter-bool-for-float": Case("estimate {flight} --filter mekf:gyro_noise=true", "gyro_noise"),
    "est-filter-2-for-bool": Case("estimate {flight} --filter ins-wind:wind_vertical=2", "wind_vertical"),
    "est-filter-nan": Case("estimate {flight} --filter mekf:gyro_noise=nan", "gyro_noise"),
    "est-filter-inf": Case("estimate {flight} --filter mekf:gyro_noise=inf", "gyro_noise"),
    "est-filter-neg": Case("estimate {flight} --filter mekf:gyro_noise=-1", "gyro_noise"),
    "est-filter-1e300": Case("estimate {flight} --filter mekf:gyro_noise=1e300", "gyro_noise"),
    "est-filter-word": Case("estimate {flight} --filter mekf:gyro_noise=abc", "gyro_noise"),
    "est-filter-choice": Case("estimate {flight} --filter mekf:mag_mode=xyz", "mag_mode"),
    "est-cov-every-zero": Case("estimate {flight} --filter mekf --cov-every 0", "--cov-every"),
    "est-cov-every-word": Case("estimate {flight} --filter mekf --cov-every all", "--cov-every"),
    "est-cov-every-paper": Case("estimate {flight} --filter paper-nowind --cov-every 2", "--cov-every"),
    "est-filter-choice-number": Case("estimate {flight} --filter mekf:mag_mode=3", "mag_mode"),
    "est-filter-gate-huge": Case("estimate {flight} --filter ins-wind:gate_gnss=1e300", "gate_gnss"),
    "est-filter-paper-wind": Case("estimate {flight} --filter paper:wind=xyz", "wind"),
    "est-filter-paper-bool": Case("estimate {flight} --filter paper:p0_var=true", "p0_var"),
    "est-filter-ekf-flag-2": Case("estimate {flight} --filter ekf:p0_iso=2", "p0_iso"),
    "est-filter-ekf-flag-word": Case("estimate {flight} --filter ekf:use_air=yes", "use_air"),
    "est-filter-vqf-bool": Case("estimate {flight} --filter vqf:tau_acc=true", "tau_acc"),
    "est-filter-vqf-flag-2": Case("estimate {flight} --filter vqf:rest_bias_est=2", "rest_bias_est"),
    "est-filter-auto-field": Case("estimate {flight} --filter auto:nope=1", "nope"),
    "est-filter-auto-bool": Case("estimate {flight} --filter auto:gyro_noise=false", "gyro_noise"),
    "est-filter-takes-none": Case("estimate {flight} --filter madgwick:x=1", "'x'"),
    # ---- estimate: --params TOML ----------------------------------------------------------------------------
    "toml-missing": Case(f"{EST} --params {{t}}/none.toml", "none.toml"),
    "toml-empty-path": Case(f"{EST} --params ''", "--params"),
    "toml-dir": Case(f"{EST} --params {{t}}/adir", "adir", A_DIR),
    "toml-fifo": Case(f"{EST} --params {{t}}/fifo", "not a regular file", (("fifo", "|"),)),
    "toml-parent-file": Case(f"{EST} --params {{t}}/afile/p.toml", "afile", A_FILE),
    "toml-decode": Case(f"{EST} {P}", "p.toml", toml("[windahrs\ngyro_noise = 1\n")),
    "toml-decode-value": Case(f"{EST} {P}", "p.toml", toml("[windahrs]\ngyro_noise = \n")),
    "toml-binary": Case(f"{EST} {P}", "p.toml", toml("\udcff\udcfe garbage")),
    "toml-bool-for-float": Case(f"{EST} {P}", "gyro_noise", toml("[windahrs]\ngyro_noise = true\n")),
    "toml-string-for-float": Case(f"{EST} {P}", "gyro_noise", toml('[windahrs]\ngyro_noise = "0.1"\n')),
    "toml-array-for-float": Case(f"{EST} {P}", "gyro_noise", toml("[windahrs]\ngyro_noise = [1, 2]\n")),
    "toml-table-for-float": Case(f"{EST} {P}", "gyro_noise", toml("[windahrs.gyro_noise]\na = 1\n")),
    "toml-date-for-float": Case(f"{EST} {P}", "gyro_noise", toml("[windahrs]\ngyro_noise = 2024-01-01\n")),
    "toml-nan": Case(f"{EST} {P}", "gyro_noise", toml("[windahrs]\ngyro_noise = nan\n")),
    "toml-inf": Case(f"{EST} {P}", "gyro_noise", toml("[windahrs]\ngyro_noise = inf\n")),
    "toml-neg": Case(f"{EST} {P}", "gyro_noise", toml("[windahrs]\ngyro_noise = -1.0\n")),
    "toml-zero-sigma": Case(f"{EST} {P}", "mag_sigma", toml("[windahrs]\nmag_sigma = 0.0\n")),
    "toml-1e300": Case(f"{EST} {P}", "gyro_noise", toml("[windahrs]\ngyro_noise = 1e300\n")),
    "toml-1e300-sigma": Case(f"{EST} {P}", "accel_sigma", toml("[windahrs]\naccel_sigma = 1e300\n")),
    "toml-1e300-init": Case(f"{EST} {P}", "init_att", toml("[windahrs]\ninit_att = 1e300\n")),
    "toml-1e300-gate": Case(f"{EST} {P}", "gate_mag", toml("[windahrs]\ngate_mag = 1e300\n")),
    "toml-1e300-window": Case(f"{EST} {P}", "init_window", toml("[windahrs]\ninit_window = 1e300\n")),
    "toml-huge-int": Case(f"{EST} {P}", "gyro_noise", toml(f"[windahrs]\ngyro_noise = {HUGE_INT}\n")),
    "toml-2-for-bool": Case(f"{EST} {P}", "mag_3d_needs_site", toml("[windahrs]\nmag_3d_needs_site = 2\n")),
    "toml-1-for-bool": Case(f"{EST} {P}", "accel_noise_online", toml("[windahrs]\naccel_noise_online = 1\n")),
    "toml-string-for-bool": Case(f"{EST} {P}", "mag_3d_needs_site", toml('[windahrs]\nmag_3d_needs_site = "yes"\n')),
    "toml-choice": Case(f"{EST} {P}", "mag_mode", toml('[windahrs]\nmag_mode = "4d"\n')),
    "toml-choice-number": Case(f"{EST} {P}", "mag_mode", toml("[windahrs]\nmag_mode = 3\n")),
    "toml-unknown-key": Case(f"{EST} {P}", "'nope'", toml("[windahrs]\nnope = 1\n")),
    "toml-unused-key": Case(f"{EST} {P}", "wind_noise", toml("[windahrs]\nwind_noise = 1.0\n")),
    "toml-unknown-table": Case(f"{EST} {P}", "[other]", toml("[other]\na = 1\n")),
    "toml-table-not-table": Case(f"{EST} {P}", "[windahrs]", toml("windahrs = 3\n")),
    "toml-px4-bool": Case(f"{EST} {P}", "EKF2_GYR_NOISE", toml("[px4]\nEKF2_GYR_NOISE = true\n")),
    "toml-px4-string": Case(f"{EST} {P}", "EKF2_GYR_NOISE", toml('[px4]\nEKF2_GYR_NOISE = "x"\n')),
    "toml-px4-nan": Case(f"{EST} {P}", "EKF2_GYR_NOISE", toml("[px4]\nEKF2_GYR_NOISE = nan\n")),
    "toml-px4-neg": Case(f"{EST} {P}", "EKF2_MAG_NOISE", toml("[px4]\nEKF2_MAG_NOISE = -0.5\n")),
    "toml-px4-1e300": Case(f"{EST} {P}", "EKF2_GYR_NOISE", toml("[px4]\nEKF2_GYR_NOISE = 1e300\n")),
    "toml-px4-unknown": Case(f"{EST} {P}", "EKF2_NOPE", toml("[px4]\nEKF2_NOPE = 1\n")),
    "toml-ardupilot-bool": Case(f"{EST} {P}", "EK3_MAG_M_NSE", toml("[ardupilot]\nEK3_MAG_M_NSE = false\n")),
    "toml-ardupilot-unknown": Case(f"{EST} {P}", "EK3_NOPE", toml("[ardupilot]\nEK3_NOPE = 1\n")),
    "toml-paper-bool": Case("estimate {flight} --filter paper " + P, "p0_var", toml("[windahrs]\np0_var = true\n")),
    "toml-paper-wind-vector": Case(
        "estimate {flight} --filter paper " + P, "mean_wind_n", toml("[windahrs]\nmean_wind_n = [true, 1, 2]\n")
    ),
    "toml-paper-wind-short": Case(
        "estimate {flight} --filter paper " + P, "mean_wind_n", toml("[windahrs]\nmean_wind_n = [1, 2]\n")
    ),
    "toml-paper-px4": Case("estimate {flight} --filter paper " + P, "[px4]", toml("[px4]\nEKF2_GYR_NOISE = 1\n")),
    "toml-ekf-flag-2": Case("estimate {flight} --filter ekf " + P, "p0_iso", toml("[windahrs]\np0_iso = 2\n")),
    "toml-ekf-unknown": Case("estimate {flight} --filter ekf " + P, "nope", toml("[windahrs]\nnope = 2\n")),
    "toml-vqf-bool": Case("estimate {flight} --filter vqf " + P, "tau_acc", toml("[windahrs]\ntau_acc = true\n")),
    "toml-vqf-flag-2": Case(
        "estimate {flight} --filter vqf " + P, "rest_bias_est", toml("[windahrs]\nrest_bias_est = 2\n")
    ),
    "toml-auto-bool": Case("estimate {flight} --filter auto " + P, "gyro_noise", BOOL_NOISE),
    "toml-usque-huge": Case("estimate {flight} --filter usque " + P, "gyro_noise", HUGE_NOISE),
    # ---- estimate: --out ------------------------------------------------------------------------------------
    "est-out-empty": Case(f"{EST} --out ''", "--out"),
    "est-out-dir": Case(f"{EST} --out {{t}}/adir", "adir", A_DIR),
    "est-out-parent-file": Case(f"{EST} --out {{t}}/afile/e.h5", "afile is not a directory", A_FILE),
    "est-out-no-parent": Case(f"{EST} --out {{t}}/nodir/e.h5", "nodir does not exist"),
    "est-out-readonly": Case(f"{EST} --out {{ro}}/e.h5", "--out"),
    "est-out-is-input": Case("estimate {t}/f.h5 --filter mekf --out {t}/f.h5", "--out", (("f.h5", "x"),)),
    # ---- compare --------------------------------------------------------------------------------------------
    "cmp-missing-file": Case("compare {t}/none.h5", "none.h5"),
    "cmp-missing-file-filters": Case("compare {t}/none.h5 --filters mekf", "none.h5"),
    "cmp-dir": Case("compare {t}/adir", "adir", A_DIR),
    "cmp-empty-path": Case("compare ''", "''"),
    "cmp-garbage": Case("compare {t}/g.ulg", "g.ulg", (("g.ulg", "ULog garbage"),)),
    "cmp-filters-empty": Case("compare {flight} --filters ''", "--filters"),
    "cmp-filters-commas": Case("compare {flight} --filters ,,", "--filters"),
    "cmp-filters-unknown": Case("compare {flight} --filters mekf,nope", "'nope'"),
    "cmp-filters-bool": Case("compare {flight} --filters mekf:gyro_noise=true", "gyro_noise"),
    "cmp-filters-nan": Case("compare {flight} --filters mekf:accel_sigma=nan", "accel_sigma"),
    "cmp-filters-flag-2": Case("compare {flight} --filters mekf:accel_noise_online=2", "accel_noise_online"),
    "cmp-extra": Case("compare {flight} --bogus", "--bogus"),
    # ---- report ---------------------------------------------------------------------------------------------
    "rep-no-out": Case("report {flight}", "--out"),
    "rep-out-empty": Case("report {flight} --filters mekf --out ''", "--out"),
    "rep-out-dir": Case("report {flight} --filters mekf --out {t}/adir", "adir", A_DIR),
    "rep-out-parent-file": Case("report {flight} --filters mekf --out {t}/afile/r.html", "afile", A_FILE),
    "rep-out-no-parent": Case("report {flight} --filters mekf --out {t}/nodir/r.html", "nodir does not exist"),
    "rep-out-readonly": Case("report {flight} --filters mekf --out {ro}/r.html", "--out"),
    "rep-missing-file": Case("report {t}/none.h5 --out {t}/r.html", "none.h5"),
    "rep-filters-empty": Case("report {flight} --filters '' --out {t}/r.html", "--filters"),
    "rep-filters-unknown": Case("report {flight} --filters nope --out {t}/r.html", "'nope'"),
    "rep-filters-bool": Case("report {flight} --filters mekf:gyro_noise=true --out {t}/r.html", "gyro_noise"),
    "rep-filters-flag": Case("report {flight} --filters ins-wind:drag=3 --out {t}/r.html", "drag"),
    "rep-garbage": Case("report {t}/g.bin --out {t}/r.html", "g.bin", (("g.bin", "x" * 64),)),
    # ---- experiment -----------------------------------------------------------------------------------------
    "exp-filters-empty": Case("experiment --runs 1 --duration 2 --filters ''", "--filters"),
    "exp-filters-commas": Case("experiment --runs 1 --duration 2 --filters ' , '", "--filters"),
    "exp-filters-unknown": Case("experiment --runs 1 --duration 2 --filters mekf,nope", "'nope'"),
    "exp-filters-field": Case("experiment --runs 1 --duration 2 --filters mekf:nope=1", "'nope'"),
    "exp-filters-bool": Case("experiment --runs 1 --duration 2 --filters mekf:gyro_noise=true", "gyro_noise"),
    "exp-runs-zero": Case("experiment --runs 0 --duration 2", "--runs"),
    "exp-runs-neg": Case("experiment --runs -1 --duration 2", "--runs"),
    "exp-runs-huge": Case(f"experiment --runs {HUGE_INT} --duration 2", "--runs"),
    "exp-runs-float": Case("experiment --runs 1.5 --duration 2", "--runs"),
    "exp-duration-nan": Case("experiment --runs 1 --duration nan", "--duration"),
    "exp-duration-neg": Case("experiment --runs 1 --duration -2", "--duration"),
    "exp-duration-huge": Case("experiment --runs 1 --duration 1e9", "--duration"),
    "exp-duration-tiny": Case("experiment --runs 1 --duration 1e-6", "--duration"),
    "exp-wind-nan": Case("experiment --runs 1 --duration 2 --wind nan", "--wind"),
    "exp-wind-neg": Case("experiment --runs 1 --duration 2 --wind -3", "--wind"),
    "exp-wind-huge": Case("experiment --runs 1 --duration 2 --wind 1e6", "--wind"),
    "exp-altitude-nan": Case("experiment --runs 1 --duration 2 --altitude nan", "--altitude"),
    "exp-altitude-low": Case("experiment --runs 1 --duration 2 --altitude 0.5", "altitude"),
    "exp-seed-neg": Case("experiment --runs 1 --duration 2 --seed -4", "--seed"),
    "exp-seed-huge": Case(f"experiment --runs 1 --duration 2 --seed {HUGE_INT}", "--seed"),
    "exp-vehicle": Case("experiment --vehicle glider", "--vehicle"),
    # ---- reproduce ------------------------------------------------------------------------------------------
    "rpr-no-out": Case("reproduce --quick", "--out"),
    "rpr-out-empty": Case("reproduce --quick --out ''", "--out"),
    "rpr-out-file": Case("reproduce --quick --out {t}/afile", "afile", A_FILE),
    "rpr-out-parent-file": Case("reproduce --quick --out {t}/afile/r", "afile is not a directory", A_FILE),
    "rpr-out-readonly": Case("reproduce --quick --out {ro}/r", "--out"),
    "rpr-out-readonly-itself": Case("reproduce --quick --out {ro}", "--out"),
    "rpr-runs-zero": Case("reproduce --runs 0 --out {t}/r", "--runs"),
    "rpr-runs-neg": Case("reproduce --runs -5 --out {t}/r", "--runs"),
    "rpr-runs-huge": Case(f"reproduce --runs {HUGE_INT} --out {{t}}/r", "--runs"),
    "rpr-runs-word": Case("reproduce --runs many --out {t}/r", "--runs"),
    "rpr-nees-runs-low": Case("reproduce --runs 3 --nees-runs 2 --out {t}/r", "--nees-runs"),
    "rpr-nees-runs-huge": Case(f"reproduce --runs 3 --nees-runs {HUGE_INT} --out {{t}}/r", "--nees-runs"),
    "rpr-duration-nan": Case("reproduce --quick --duration nan --out {t}/r", "--duration"),
    "rpr-duration-inf": Case("reproduce --quick --duration inf --out {t}/r", "--duration"),
    "rpr-duration-zero": Case("reproduce --quick --duration 0 --out {t}/r", "--duration"),
    "rpr-duration-huge": Case("reproduce --quick --duration 1e9 --out {t}/r", "--duration"),
    "rpr-duration-tiny": Case("reproduce --quick --duration 1e-6 --out {t}/r", "--duration"),
    # ---- bench-data -----------------------------------------------------------------------------------------
    "bench-missing-dir": Case("bench-data {t}/none", "none"),
    "bench-empty-path": Case("bench-data ''", "''"),
    "bench-empty-dir": Case("bench-data {t}/adir", "adir", A_DIR),
    "bench-junk-dir": Case("bench-data {t}/junk", "no readable recording", (("junk", "/"), ("junk/a.ulg", "x"))),
    "bench-filters-empty": Case("bench-data {t} --filters ''", "--filters"),
    "bench-filters-unknown": Case("bench-data {t} --filters nope", "'nope'"),
    "bench-filters-bool": Case("bench-data {t} --filters mekf:gyro_noise=true", "gyro_noise"),
    "bench-out-empty": Case("bench-data {flight} --filters mekf --out ''", "--out"),
    "bench-out-dir": Case("bench-data {flight} --filters mekf --out {t}/adir", "adir", A_DIR),
    "bench-out-parent-file": Case("bench-data {flight} --filters mekf --out {t}/afile/b.json", "afile", A_FILE),
    "bench-out-no-parent": Case("bench-data {flight} --filters mekf --out {t}/nodir/b.json", "nodir does not exist"),
    "bench-out-readonly": Case("bench-data {flight} --filters mekf --out {ro}/b.json", "--out"),
    "bench-no-reference": Case("bench-data {t}/nr", "reference"),  # {t}/nr/f.h5 written by test_bad_input
    # ---- --declination (degrees east, finite, within +-180; a flight with a known field keeps its own) ----------
    "info-decl-nan": Case("info {flight} --declination nan", "--declination: expected a finite number, found 'nan'"),
    "info-decl-200": Case("info {flight} --declination 200", "--declination: expected degrees east of true north, "
                          "a finite number from -180 to 180, found '200'"),
    "est-decl-word": Case(f"{EST} --declination x", "--declination: expected a number, found 'x'"),
    "est-decl-inf": Case(f"{EST} --declination=-inf", "--declination: expected a finite number, found '-inf'"),
    "cmp-decl-200": Case("compare {flight} --declination -200", "--declination: expected degrees east"),
    "rep-decl-nan": Case("report {flight} --out {t}/r.html --declination nan", "--declination: expected a finite"),
    "bench-decl-x": Case("bench-data {flight} --declination x", "--declination: expected a number, found 'x'"),
    # the simulated flight's site field has its own declination, -8.0 deg
    "est-decl-field": Case(f"{EST} --declination 5", "--declination: expected the declination of the flight's known "
                           "field site.mag_n (-8.0"),
    "info-decl-field": Case("info {flight} --declination 5", "found +5.000 deg"),
}


# ---------------------------------------------------------------------------------------------------------------
# fixtures


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("flight") / "fw.h5"
    assert main(["simulate", "--duration", "3", "--seed", "1", "--out", str(out)]) == 0
    return out


def _mount_tmpfs(where: Path, options: str) -> bool:
    """Mount a tmpfs at ``where`` (root only); True when it worked."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)], capture_output=True)
    return res.returncode == 0


def _unmount(where: Path) -> None:
    subprocess.run(["umount", str(where)], capture_output=True)


@pytest.fixture(scope="module")
def read_only(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path | str]:
    """A folder no write can reach (a read-only tmpfs as root; else a folder without write
    permission), or the reason there is none."""
    d = tmp_path_factory.mktemp("ro")
    if os.geteuid() == 0:
        if not _mount_tmpfs(d, "ro,size=64k"):
            yield "root, and no read-only tmpfs could be mounted (needs CAP_SYS_ADMIN)"
            return
        try:
            yield d
        finally:
            _unmount(d)
    else:
        d.chmod(0o555)
        try:
            yield d
        finally:
            d.chmod(0o755)


def _tree(root: Path) -> dict[str, int]:
    """Every path under root -> its size (folders -1)."""
    return {str(p.relative_to(root)): (-1 if p.is_dir() else p.stat().st_size) for p in root.rglob("*")}


#: A line of the documented progress of experiment, reproduce and bench-data (not an error line).
PROGRESS = re.compile(r"^(experiment|reproduce|bench-data|faults \w+): +\d+%\|")


def _run_case(case: Case, tmp: Path, flight: Path, ro: Path | str, capsys: pytest.CaptureFixture[str]) -> str:
    if "{ro}" in case.argv and isinstance(ro, str):
        pytest.skip(ro)
    for name, text in case.files:
        p = tmp / name
        if text == "/":
            p.mkdir()
        elif text == "|":
            os.mkfifo(p)
        else:
            p.write_bytes(text.encode("utf-8", "surrogateescape"))
    argv = shlex.split(case.argv.format(flight=flight, t=tmp, ro=ro))
    before = _tree(tmp)
    flight_before = _tree(flight.parent)
    capsys.readouterr()
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's own errors
        rc = exc.code if isinstance(exc.code, int) else 1
    err = capsys.readouterr().err
    assert rc == case.rc, err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip() and not PROGRESS.match(ln)]
    assert len(lines) == 1, err
    assert case.expect in lines[0], lines[0]
    assert _tree(tmp) == before, "partial output left"
    assert _tree(flight.parent) == flight_before
    if isinstance(ro, Path):
        assert list(ro.iterdir()) == []
    return lines[0]


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input(
    name: str,
    tmp_path: Path,
    flight: Path,
    read_only: Path | str,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Non-zero exit, one line naming the problem, no traceback, nothing written."""
    monkeypatch.chdir(tmp_path)
    case = CASES[name]
    if name == "bench-no-reference":  # a recording without truth or reference
        from windahrs.store import load_flight, save_flight

        (tmp_path / "nr").mkdir()
        save_flight(load_flight(flight).replace(truth=None), tmp_path / "nr" / "f.h5")
    _run_case(case, tmp_path, flight, read_only, capsys)


def test_enough_cases() -> None:
    """The issue asks for at least 150 bad inputs over every command."""
    assert len(CASES) >= 150
    commands = {c.argv.split()[0] for c in CASES.values() if c.argv}
    assert commands >= {"simulate", "info", "filters", "estimate", "compare", "report", "experiment", "reproduce",
                        "bench-data", "faults", "sweep", "sweep-report"}


# ---------------------------------------------------------------------------------------------------------------
# Ctrl-C and a full file system: the CLI in a subprocess


def _cli(args: list[str], cwd: Path, stderr: Path) -> subprocess.Popen[bytes]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "src"), os.environ.get("PYTHONPATH", "")])}
    with open(stderr, "wb") as err:
        return subprocess.Popen([sys.executable, "-m", "windahrs.cli", *args], cwd=cwd, env=env,
                                stdout=subprocess.DEVNULL, stderr=err)


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a running process (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _wait_until(what: str, ready: Callable[[], bool], proc: subprocess.Popen[bytes], timeout: float = 300.0) -> None:
    t0 = time.monotonic()
    while not ready():
        if proc.poll() is not None:
            pytest.fail(f"the command ended (status {proc.returncode}) before {what}")
        if time.monotonic() - t0 > timeout:
            proc.kill()
            pytest.fail(f"no {what} within {timeout:g} s")
        time.sleep(0.05)


@pytest.fixture(scope="module")
def long_flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 10-minute flight: ins-wind runs on it for seconds, time enough to interrupt it."""
    out = tmp_path_factory.mktemp("long") / "long.h5"
    assert main(["simulate", "--duration", "600", "--seed", "3", "--out", str(out)]) == 0
    return out


SIGINT_CASES: dict[str, tuple[str, str]] = {
    # name: (argv, what shows the command is working: "cpu" or the progress line's prefix)
    "estimate": ("estimate {long} --filter ins-wind --out {t}/out/est.h5", "cpu"),
    "experiment": ("experiment --runs 50 --duration 30 --filters ins-wind,mekf", "experiment:"),
    "reproduce": ("reproduce --quick --runs 2 --duration 10 --out {t}/out/repro", "reproduce:"),
    "bench-data": ("bench-data {recs} --filters ins-wind,mekf --out {t}/out/bench.json", "bench-data:"),
}


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc to see the command working")
@pytest.mark.parametrize("name", list(SIGINT_CASES))
def test_sigint_leaves_nothing(name: str, tmp_path: Path, long_flight: Path) -> None:
    """Ctrl-C while the command works: exit status 130, one line saying so, no traceback,
    and nothing left in the output folder (no file, no temporary file, no created folder)."""
    argv, signal_of_work = SIGINT_CASES[name]
    (tmp_path / "out").mkdir()
    recs = tmp_path / "recs"
    recs.mkdir()
    shutil.copy(long_flight, recs / "a.h5")
    shutil.copy(long_flight, recs / "b.h5")
    args = shlex.split(argv.format(long=long_flight, t=tmp_path, recs=recs))
    err = tmp_path / "stderr.txt"
    if signal_of_work == "cpu":
        # the CPU time the command needs to start (imports, the estimator built) and fail
        # on a missing file; past it by a second, it is running the estimator
        base = _cli(["estimate", str(tmp_path / "none.h5"), "--filter", "ins-wind"], tmp_path, err)
        t0 = time.monotonic()
        while base.poll() is None and time.monotonic() - t0 < 120:
            start_cpu = _cpu_seconds(base.pid)
            time.sleep(0.02)
        base.wait()
        proc = _cli(args, tmp_path, err)
        _wait_until("estimator run", lambda: _cpu_seconds(proc.pid) > start_cpu + 1.0, proc)
    else:
        proc = _cli(args, tmp_path, err)
        _wait_until("progress line", lambda: signal_of_work in err.read_text(errors="replace"), proc)
    proc.send_signal(signal.SIGINT)
    rc = proc.wait(timeout=120)
    text = err.read_text(errors="replace")
    assert rc == 130, text
    assert "Traceback" not in text
    lines = [ln for ln in text.splitlines() if ln.strip() and not PROGRESS.match(ln)]
    assert lines == [f"windahrs {name}: interrupted; nothing was written"], text
    assert list((tmp_path / "out").iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "recs", "stderr.txt"]


@pytest.fixture(scope="module")
def full_disk(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A 64 KiB tmpfs (root only), or a skip saying why there is none."""
    d = tmp_path_factory.mktemp("full")
    if not _mount_tmpfs(d, "size=64k"):
        pytest.skip("no full file system to write on: mounting a small tmpfs needs root (or CAP_SYS_ADMIN)")
    try:
        yield d
    finally:
        _unmount(d)


@pytest.mark.parametrize(
    "argv",
    [
        "simulate --duration 3 --out {full}/x.h5",
        "estimate {flight} --filter mekf --out {full}/e.h5",
        "report {flight} --filters mekf --out {full}/r.html",
    ],
)
def test_full_file_system(argv: str, full_disk: Path, flight: Path, tmp_path: Path) -> None:
    """An output on a file system that fills up while it is written: exit status 1 (not the
    input's fault), one line naming the user's path and the reason, no crash (h5py segfaults
    writing HDF5 to a full disk), nothing left on the file system."""
    err = tmp_path / "stderr.txt"
    proc = _cli(shlex.split(argv.format(full=full_disk, flight=flight)), tmp_path, err)
    rc = proc.wait(timeout=300)
    text = err.read_text(errors="replace")
    assert rc == 1, text
    assert "Traceback" not in text
    lines = text.strip().splitlines()
    assert len(lines) == 1, text
    name = argv.split("/")[-1]
    assert f"{full_disk}/{name}: cannot write (No space left on device)" in lines[0]
    assert list(full_disk.iterdir()) == []


# ---------------------------------------------------------------------------------------------------------------
# what is written: the user's umask; nothing left by a command that fails after creating its output


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_files_get_the_users_umask(umask: int, tmp_path: Path, flight: Path) -> None:
    """Files are created as a plain open() would (0o666 less the umask), not 0o600."""
    old = os.umask(umask)
    try:
        assert main(["estimate", str(flight), "--filter", "mekf", "--out", str(tmp_path / "e.h5")]) == 0
        assert main(["bench-data", str(flight), "--filters", "mekf", "--out", str(tmp_path / "b.json")]) == 0
    finally:
        os.umask(old)
    for name in ("e.h5", "b.json"):
        assert (tmp_path / name).stat().st_mode & 0o777 == 0o666 & ~umask, name


@pytest.mark.parametrize("existing", [False, True])
def test_reproduce_failing_late_removes_what_it_wrote(
    existing: bool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """reproduce failing while it writes its results (here: after its first file): the
    folder it created is removed; in a folder that existed, only the files it added."""
    import windahrs.experiments.reproduce as rep
    import windahrs.report.reproduction as rr

    def fake_run(*args: object, **kwargs: object) -> object:
        return object()

    def half_write(res: object, out: Path) -> list[Path]:
        (out / "results.json").write_text("{}")
        raise RuntimeError("the figures failed")

    monkeypatch.setattr(rep, "run_reproduction", fake_run)
    monkeypatch.setattr(rr, "write_reproduction", half_write)
    out = tmp_path / "new" / "repro"
    if existing:
        out.mkdir(parents=True)
        (out / "mine.txt").write_text("the user's")
    assert main(["reproduce", "--quick", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1].endswith("RuntimeError: the figures failed") and "Traceback" not in err
    if existing:
        assert sorted(p.name for p in out.iterdir()) == ["mine.txt"]
    else:
        assert list(tmp_path.iterdir()) == []


def test_ctrl_c_while_the_file_is_written_leaves_nothing(
    tmp_path: Path, flight: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Ctrl-C in the last moment of a write (the temporary file written, being synced):
    exit status 130, neither the output nor its temporary file left."""

    def interrupted(fd: int) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fsync", interrupted)
    assert main(["estimate", str(flight), "--filter", "mekf", "--out", str(tmp_path / "e.h5")]) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == "windahrs estimate: interrupted; nothing was written"
    assert list(tmp_path.iterdir()) == []
