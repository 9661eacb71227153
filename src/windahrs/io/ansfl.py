"""ANSFL quadrotor flights (a DJI flight log and Xsens DOT IMUs, CSV) to Flight.

The ANSFL Quadrotor Dead-Reckoning dataset (Hurwitz and Klein, "Quadrotor Dead Reckoning
with Multiple Inertial Sensors", arXiv 2310.13452, 2023; CC-BY-4.0) holds one directory per
flight of a DJI Phantom 4 RTK carrying up to four Xsens DOT IMUs:

============  ==============================================================================
Flight        file (columns; conversion)
============  ==============================================================================
imu           ``IMU_<k>.csv`` (``time`` s; ``Gyr_X/Y/Z`` deg/s -> rad/s; ``Acc_X/Y/Z``
              m/s^2; the DOT's axes x forward, y left, z up -> FRD: x, -y, -z). The lowest
              k by default; ``imu=k`` picks another. ``Euler_X/Y/Z`` (the DOT's own attitude
              estimate) is never read.
reference     ``GT.csv`` (``roll(degrees)``, ``pitch(degrees)``, ``compass_heading(degrees)``:
              ZYX Euler angles of the FRD airframe in NED, heading clockwise from north), kind
              "autopilot" (the DJI flight controller's own estimate), heading-free (below)
gnss          ``GT.csv`` (``North``, ``East``, ``Down``: RTK position, m, from the first
              sample), differentiated into NED velocity
              (:func:`~windahrs.io.edge.velocity_from_positions`); ``gnss=False`` leaves it out
============  ==============================================================================

Header names are matched after stripping blanks: the DJI file writes ``" pitch(degrees)"``
with a leading space. ``IMU_avg.csv`` and the ``pairs/`` and ``triplets/`` averages of the
upstream dataset are not single IMUs and are not read.

What the reader does not do (the edge converts units and frames, it does not fit data):

* Clocks: the DOT and the DJI logger have their own clocks, both starting at 0 in the files;
  they differ by a few hundred ms on the published flights. ``imu.t`` is the DOT's clock,
  ``gnss.t`` and ``reference.t`` DJI's, as logged (``meta["reference.clock"] = "own"``: the
  commands scoring without ``--align`` say so). ``--align``
  (:mod:`windahrs.experiments.align`) estimates the offset.
* Mounting: the DOT is strapped on a few degrees off the airframe axes; ``--align`` fits that
  constant rotation too.
* Heading: the flight has no magnetometer, so no estimator can share the DJI compass's heading
  datum; the reference is ``heading_free`` and scores remove one constant heading offset.
* GNSS velocity: central differences of 10 Hz positions (``meta["gnss.derived_from"] =
  "position"``). ``Down`` moves in 0.1 m steps (as ``height_above_takeoff`` does), so the
  vertical velocity is quantised by about 0.5 m/s (0.2 m/s RMS: 0.1 m / sqrt(12) * sqrt(2)
  / 0.2 s, the default gnss_sigma); north and east are RTK positions at mm to cm level (a few
  cm/s). The velocity is on DJI's clock, which is declared as a timing uncertainty
  (``meta["gnss.timing_sigma_s"]``, :data:`ANSFL_GNSS_TIMING_SIGMA`), not corrected, and
  as the reference's clock (``meta["gnss.clock"] = "reference"``: both come from
  ``GT.csv``), so ``--align`` moves the GNSS by the offset it fits and lowers the timing
  uncertainty to the fit's (:func:`~windahrs.experiments.align.align_gnss_clock`).

NaN policy: empty cells are NaN (missing samples; reference gaps). Out-of-order and repeated
time stamps are sorted and dropped with counts in ``meta`` (:mod:`windahrs.io.edge`).
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from windahrs.conventions import DEG, P_FLU_FRD
from windahrs.flight import Flight, GnssStream, ImuStream, Reference
from windahrs.io.csv import _read_table, _seconds, _stack
from windahrs.io.edge import (
    LogFormatError,
    flight_errors_name,
    invalid_quat_rows,
    velocity_from_positions,
)
from windahrs.repair import ACCEL_RANGE, GNSS_VELOCITY_RANGE, GYRO_RANGE, RepairLog
from windahrs.rotation import quat_from_euler

__all__ = ["ANSFL_GNSS_TIMING_SIGMA", "ANSFL_GT_FILE", "ansfl_imu_files", "is_ansfl_dir", "read_ansfl"]

#: The DJI flight-controller log of an ANSFL flight directory.
ANSFL_GT_FILE = "GT.csv"
#: The uncertainty, s, of the GNSS velocity's stamps (DJI's clock) against the IMU's (the
#: DOT's): both files start at 0 s on clocks started by hand on two devices, so the offset is
#: unknown; ``--align`` finds 0.16 to 0.41 s, either sign, on the flights in ../shared/data.
#: Declared as ``Flight.meta["gnss.timing_sigma_s"]``, it adds ``(0.5 s a)^2`` to the GNSS
#: velocity's variance (:class:`~windahrs.filters.params.EskfParams`, gnss_timing_sigma).
#: Chosen on the even-numbered flights of ../shared/data/ansfl/Horizontal among 0.05 (ArduPilot's
#: synchronised receiver), 0.1, 0.2, 0.3 and 0.5 s (median tilt RMSE of [ins-wind] 23.8, 21.2,
#: 18.2, 13.7, 7.8 deg), reported on the odd ones (docs/RESULTS.md).
ANSFL_GNSS_TIMING_SIGMA = 0.5
_IMU_NAME = re.compile(r"IMU_(\d+)\.csv")
_IMU_GYRO = ["Gyr_X", "Gyr_Y", "Gyr_Z"]
_IMU_ACCEL = ["Acc_X", "Acc_Y", "Acc_Z"]
_GT_EULER = ["roll(degrees)", "pitch(degrees)", "compass_heading(degrees)"]
_GT_POSITION = ["North", "East", "Down"]
_S = 1_000_000_000  # ns per s, for the CSV helpers' time scale


def ansfl_imu_files(directory: str | os.PathLike[str]) -> dict[int, Path]:
    """The ``IMU_<k>.csv`` files of a flight directory by k, in increasing k ({} if none)."""
    d = Path(directory)
    if not d.is_dir():
        return {}
    found = {}
    for p in d.iterdir():
        m = _IMU_NAME.fullmatch(p.name)
        if m and p.is_file():
            found[int(m[1])] = p
    return dict(sorted(found.items()))


def is_ansfl_dir(directory: str | os.PathLike[str]) -> bool:
    """True for a directory holding ``GT.csv`` and at least one ``IMU_<k>.csv``."""
    d = Path(directory)
    return (d / ANSFL_GT_FILE).is_file() and bool(ansfl_imu_files(d))


def read_ansfl(path: str | os.PathLike[str], *, imu: int | None = None, gnss: bool = True) -> Flight:
    """Read one ANSFL flight directory into a Flight (see the module table).

    path: the directory holding ``GT.csv`` and ``IMU_<k>.csv``. imu: k of the IMU file to
    read (default: the lowest present). gnss: put the velocity differentiated from the RTK
    positions in ``Flight.gnss`` (False: no GNSS stream, e.g. to run an AHRS as an INS would
    not).

    Raises ValueError for a bad ``imu`` or ``gnss`` argument, LogFormatError (not a directory,
    ``GT.csv`` or the asked ``IMU_<k>.csv`` missing, a missing column, malformed CSV; the
    message names the file) and FlightError (values failing the Flight's checks, the field
    prefixed by the directory).
    """
    if imu is not None and (isinstance(imu, bool) or not isinstance(imu, int | np.integer) or imu < 0):
        raise ValueError(f"imu: expected the number k of an IMU_<k>.csv file (an int >= 0), found {imu!r}")
    if not isinstance(gnss, bool | np.bool_):
        raise ValueError(f"gnss: expected True or False, found {gnss!r}")
    d = Path(path)
    if not d.is_dir():
        raise LogFormatError(d, "not a directory (an ANSFL flight is a directory holding GT.csv and IMU_<k>.csv)")
    imus = ansfl_imu_files(d)
    if imu is None:
        if not imus:
            raise LogFormatError(d, "not an ANSFL flight: no IMU_<k>.csv file")
        imu = next(iter(imus))
    if imu not in imus:
        present = ", ".join(p.name for p in imus.values()) or "none"
        raise LogFormatError(d / f"IMU_{imu}.csv", f"no such file (IMU {imu}; this flight has: {present})")
    imu_path = imus[imu]
    gt_path = d / ANSFL_GT_FILE
    imu_table = _read_table(imu_path, "time", _IMU_GYRO + _IMU_ACCEL)
    gt_table = _read_table(gt_path, "time", _GT_EULER + _GT_POSITION, warn_stripped=False)

    meta: dict[str, Any] = {
        "source": d.name,
        "format": "ansfl",
        "ansfl.imu_file": imu_path.name,
        "ansfl.imus": ",".join(str(k) for k in imus),
        "reference.source": "DJI flight controller (GT.csv roll, pitch, compass heading)",
        "reference.heading_free": "no magnetometer: the estimators cannot share the compass's heading datum",
        "clocks": "imu: Xsens DOT; gnss, reference: DJI (offset not removed, see --align)",
        "reference.clock": "own",  # DJI's, not the DOT's (experiments.align.REFERENCE_CLOCK_KEY)
    }
    rep = RepairLog()
    t_imu, v_imu = _seconds(imu_table, _S, 0, "imu", meta, rep)
    t_gt, v_gt = _seconds(gt_table, _S, 0, "reference", meta, rep)
    w_flu = rep.rows("imu", _stack(v_imu, _IMU_GYRO) * DEG, GYRO_RANGE)
    f_flu = rep.rows("imu", _stack(v_imu, _IMU_ACCEL), ACCEL_RANGE)
    q, n_bad = invalid_quat_rows(quat_from_euler(_stack(v_gt, _GT_EULER) * DEG))
    if n_bad:
        meta["reference.invalid_quaternions"] = n_bad
    if gnss:
        meta["gnss.derived_from"] = "position"
        meta["gnss.timing_sigma_s"] = ANSFL_GNSS_TIMING_SIGMA
        meta["gnss.clock"] = "reference"  # GT.csv: the reference's log and clock
    with flight_errors_name(d):
        gnss_stream = None
        if gnss:
            v_n = velocity_from_positions(t_gt, _stack(v_gt, _GT_POSITION))
            gnss_stream = GnssStream(t=t_gt, v_n=rep.rows("gnss", v_n, GNSS_VELOCITY_RANGE))
        return rep.attach(
            Flight(
                imu=ImuStream(t=t_imu, w_b=w_flu @ P_FLU_FRD.T, f_b=f_flu @ P_FLU_FRD.T),
                gnss=gnss_stream,
                reference=Reference(t=t_gt, q_nb=q, kind="autopilot", heading_free=True),
                meta=meta,
                repairs=rep.counts,
            )
        )
