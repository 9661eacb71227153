"""Recordings in the ASL dataset layout (EuRoC MAV, TUM-VI) to Flight.

The ASL layout (ETH Zurich's Autonomous Systems Lab; Burri et al., "The EuRoC micro aerial
vehicle datasets", IJRR 2016; Schubert et al., "The TUM VI benchmark", IROS 2018) keeps one
directory per sensor under ``mav0/``, each with a ``data.csv`` whose first column is the time
stamp in ns and whose one header line carries the units:

============  ==============================================================================
Flight        file (columns; conversion)
============  ==============================================================================
imu           ``mav0/imu0/data.csv`` (``#timestamp [ns]``; ``w_RS_S_x/y/z [rad s^-1]``;
              ``a_RS_S_x/y/z [m s^-2]``), turned into the body frame below
reference     ``mav0/state_groundtruth_estimate0/data.csv`` (EuRoC) or, without it,
              ``mav0/mocap0/data.csv`` (TUM-VI): ``q_RS_w/x/y/z``, the attitude of the IMU's
              frame S in the world frame R; kind "mocap", heading-free
============  ==============================================================================

Header names are matched by their name before the unit (``q_RS_w`` in ``" q_RS_w []"``):
EuRoC's ground-truth file writes ``#timestamp`` and pads its names with a blank. The IMU and
the reference share the recording's clock (EuRoC's ground truth is time-aligned to the IMU).
EuRoC's ``vicon0`` and ``leica0`` are not read: the first is the pose of the Vicon markers,
not of the IMU, and the second a position.

Frames (the edge converts, it does not fit: ``--align`` fits what is left):

* World: R is the motion capture's frame, whose vertical is its own (EuRoC's and TUM-VI's
  point z up) and whose heading is arbitrary. The reader finds R's up as the mean over the
  recording of the specific force turned into R (``C_RS f_S``: gravity, the accelerations
  averaging out over a flight that starts and ends at rest) and turns R by the smallest
  rotation that takes that up to NED's; the reference is heading-free.
* Body: S is the IMU's own frame. EuRoC's ADIS16448 points x up (a resting accelerometer
  reads about +9.8 m/s^2 on x), which puts a level vehicle at 90 deg of pitch, where Euler
  angles, and the heading of a splice or a metric taken from them, are singular. The body
  frame B is S turned by the smallest rotation that takes the mean specific force over the
  first second (the vehicle standing still: gravity) to B's up, as an autopilot's board
  rotation does (PX4's SENS_BOARD_ROT); ``meta["asl.mount_rpy_deg"]`` gives it (roll,
  pitch, yaw in deg, a string). The IMU
  samples and the reference are turned alike, so the attitude is B's.

NaN policy and repairs as the other CSV readers (:mod:`windahrs.io.csv`): empty cells are NaN,
out-of-order and repeated time stamps are sorted and dropped with counts in ``repairs``.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from windahrs.flight import Flight, ImuStream, Reference
from windahrs.io.csv import _read_table, _seconds, _stack
from windahrs.io.edge import LogFormatError, flight_errors_name, invalid_quat_rows
from windahrs.repair import ACCEL_RANGE, GYRO_RANGE, RepairLog
from windahrs.rotation import dcm_from_quat, euler_from_quat, quat_from_dcm, quat_mul

__all__ = ["ASL_IMU_FILE", "ASL_REFERENCE_FILES", "is_asl_dir", "read_asl"]

F64 = NDArray[np.float64]

#: The IMU file of an ASL recording, under its ``mav0`` directory.
ASL_IMU_FILE = Path("imu0") / "data.csv"
#: The reference attitude files, under ``mav0``, in the order they are looked for: EuRoC's
#: ground truth of the IMU's state, then TUM-VI's motion capture of the IMU's pose.
ASL_REFERENCE_FILES = (Path("state_groundtruth_estimate0") / "data.csv", Path("mocap0") / "data.csv")
#: The seconds of the start whose mean specific force sets the body frame's vertical.
MOUNT_WINDOW_S = 1.0
_GYRO = ("w_RS_S_x", "w_RS_S_y", "w_RS_S_z")
_ACCEL = ("a_RS_S_x", "a_RS_S_y", "a_RS_S_z")
_QUAT = ("q_RS_w", "q_RS_x", "q_RS_y", "q_RS_z")
_S = 1  # the time stamps are ns


def _mav0(directory: Path) -> Path:
    """The ``mav0`` directory of a recording given as itself or as its parent."""
    return directory if (directory / ASL_IMU_FILE).is_file() else directory / "mav0"


def is_asl_dir(directory: str | os.PathLike[str]) -> bool:
    """True for a directory holding ``mav0/imu0/data.csv``, or a ``mav0`` directory holding
    ``imu0/data.csv``."""
    d = Path(directory)
    return (d / "mav0" / ASL_IMU_FILE).is_file() or (d.name == "mav0" and (d / ASL_IMU_FILE).is_file())


def _columns(path: Path, names: tuple[str, ...]) -> tuple[str, list[str]]:
    """The header's own spellings (stripped) of the time column and of ``names``, each
    matched by the name before its unit (``"q_RS_w []"`` for ``q_RS_w``)."""
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            header = next(csv.reader(fh), [])
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise LogFormatError(path, f"not a readable CSV file: {exc}") from None
    cols = [h.strip() for h in header]
    if not cols or not cols[0].startswith("#timestamp"):
        raise LogFormatError(path, f"expected a header starting with '#timestamp', found {cols[:1]}")

    def find(name: str) -> str:
        for c in cols:
            if c.split(" ")[0] == name:
                return c
        shown = ", ".join(cols[:10]) + (", ..." if len(cols) > 10 else "")
        raise LogFormatError(path, f"missing column {name!r}; the header has: {shown}")

    return cols[0], [find(n) for n in names]


def _turn_to(u: F64, target: F64) -> F64:
    """The smallest rotation (3x3) that takes the unit vector u to the unit vector target
    (scipy's ``Rotation.align_vectors`` of the one pair: its shortest rotation)."""
    rot, _ = Rotation.align_vectors(target[None, :], u[None, :])
    return np.asarray(rot.as_matrix(), dtype=np.float64)


def _unit_mean(name: str, path: Path, rows: F64) -> F64:
    ok = rows[np.isfinite(rows).all(axis=1)]
    m = ok.mean(axis=0) if len(ok) else np.full(3, np.nan)
    n = float(np.linalg.norm(m))
    if not np.isfinite(n) or n < 1.0:
        raise LogFormatError(path, f"{name}: no mean specific force to find the vertical from (found {m})")
    return m / n


def read_asl(path: str | os.PathLike[str]) -> Flight:
    """Read one ASL recording (EuRoC MAV, TUM-VI) into a Flight (see the module).

    path: the sequence directory holding ``mav0/``, or ``mav0`` itself.

    Raises LogFormatError (not such a directory, the IMU file missing, a missing column,
    malformed CSV; the message names the file) and FlightError (values failing the Flight's
    checks, the field prefixed by the directory).
    """
    d = Path(path)
    if not d.is_dir():
        raise LogFormatError(d, "not a directory (an ASL recording is a directory holding mav0/imu0/data.csv)")
    if not is_asl_dir(d):
        raise LogFormatError(d, f"not an ASL recording: no mav0/{ASL_IMU_FILE.as_posix()}")
    mav0 = _mav0(d)
    imu_path = mav0 / ASL_IMU_FILE
    t_col, imu_cols = _columns(imu_path, _GYRO + _ACCEL)
    imu_table = _read_table(imu_path, t_col, imu_cols, warn_stripped=False)
    ref_path = next((mav0 / p for p in ASL_REFERENCE_FILES if (mav0 / p).is_file()), None)
    meta: dict[str, Any] = {
        "source": (d.parent.name if d.name == "mav0" else d.name),
        "format": "asl",
        "asl.imu_file": imu_path.relative_to(mav0).as_posix(),
    }
    rep = RepairLog()
    origin = int(imu_table.time.min())
    t_imu, v_imu = _seconds(imu_table, _S, origin, "imu", meta, rep)
    if len(t_imu) == 0:
        raise LogFormatError(imu_path, "no IMU samples")
    w_s = rep.rows("imu", _stack(v_imu, imu_cols[:3]), GYRO_RANGE)
    f_s = rep.rows("imu", _stack(v_imu, imu_cols[3:]), ACCEL_RANGE)
    # the body frame: S turned so that the first second's mean specific force points up
    up_s = _unit_mean("imu", imu_path, f_s[t_imu - t_imu[0] <= MOUNT_WINDOW_S])
    c_bs = _turn_to(up_s, np.array([0.0, 0.0, -1.0]))
    q_sb = quat_from_dcm(c_bs.T)  # (the body's attitude in S: C_sb = C_bs^T)
    rpy = np.degrees(euler_from_quat(quat_from_dcm(c_bs)))
    meta["asl.mount_rpy_deg"] = " ".join(f"{v:+.3f}" for v in rpy)  # (roll pitch yaw of S in B)
    reference = None
    if ref_path is not None:
        r_t, r_cols = _columns(ref_path, _QUAT)
        ref_table = _read_table(ref_path, r_t, r_cols, warn_stripped=False)
        t_ref, v_ref = _seconds(ref_table, _S, origin, "reference", meta, rep)
        q_rs, n_bad = invalid_quat_rows(_stack(v_ref, r_cols))
        if n_bad:
            meta["reference.invalid_quaternions"] = n_bad
        # the world's vertical: the mean over the recording of the specific force in R
        ok = np.isfinite(q_rs).all(axis=1)
        if ok.sum() >= 2:
            q_at = np.column_stack([np.interp(t_imu, t_ref[ok], q_rs[ok, k]) for k in range(4)])
            f_r = np.einsum("nij,nj->ni", dcm_from_quat(q_at / np.linalg.norm(q_at, axis=1, keepdims=True)), f_s)
            inside = (t_imu >= t_ref[ok][0]) & (t_imu <= t_ref[ok][-1])
            up_r = _unit_mean("reference", ref_path, f_r[inside])
            q_nr = quat_from_dcm(_turn_to(up_r, np.array([0.0, 0.0, -1.0])))
            q_nb = quat_mul(quat_mul(q_nr, q_rs), q_sb)
            meta["reference.file"] = ref_path.relative_to(mav0).as_posix()
            meta["reference.source"] = "motion capture (the IMU's pose in its frame, ASL layout)"
            meta["reference.heading_free"] = "the motion capture's heading is arbitrary"
            reference = (t_ref, q_nb)
    with flight_errors_name(d):
        return rep.attach(
            Flight(
                imu=ImuStream(t=t_imu, w_b=w_s @ c_bs.T, f_b=f_s @ c_bs.T),
                reference=None if reference is None else Reference(
                    t=reference[0], q_nb=reference[1], kind="mocap", heading_free=True
                ),
                meta=meta,
                repairs=rep.counts,
            )
        )
