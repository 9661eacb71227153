"""BROAD benchmark trials (HDF5) to Flight.

BROAD (Laidig et al., Data 6(7):72, 2021; CC-BY-4.0) holds handheld IMU trials with an
optical motion-capture reference. Per file: ``imu_gyr`` (N, 3) rad/s, ``imu_acc`` (N, 3)
m/s^2, ``imu_mag`` (N, 3) microtesla, ``opt_quat`` (N, 4) w, x, y, z (IMU frame to an
ENU-like frame with an arbitrary heading), ``movement`` (N,) bool, attribute
``sampling_rate`` (Hz). All on one clock, starting at t = 0.

Frames: the body axes stay the IMU's own axes. A handheld board has no forward/right/down,
so no FRD conversion exists; estimators only need the axes to be right-handed and the
same for the three sensors, which they are. The reference's navigation frame is converted
from ENU to NED (:func:`~windahrs.rotation.quat_nav_enu_to_ned`), and the reference is
``heading_free`` because its heading datum is arbitrary.

Scoring: the files' own description says the ``movement`` mask "marks which samples are
part of the movement phase and should be considered for calculation of errors", so by
default it becomes ``Reference.mask``. The reference's NaN rows (optical occlusions) are
gaps, counted in ``meta["reference.gaps"]``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from windahrs.flight import Flight, ImuStream, MagStream, Reference, Site
from windahrs.io.edge import (
    LogFormatError,
    flight_errors_name,
    guard,
    invalid_quat_rows,
)
from windahrs.repair import ACCEL_RANGE, GYRO_RANGE, MAG_RANGE, RepairLog
from windahrs.rotation import quat_nav_enu_to_ned

__all__ = ["BROAD_DATASETS", "broad_movement_mask", "read_broad"]

#: Datasets a BROAD trial must hold.
BROAD_DATASETS: tuple[str, ...] = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement")
_MICROTESLA = 1e-6


def read_broad(
    path: str | os.PathLike[str], *, score: Literal["movement", "all"] = "movement"
) -> Flight:
    """Read a BROAD trial into a Flight (imu, mag, mocap reference; no GNSS or air data).

    path: a BROAD ``.hdf5`` file. score: ``"movement"`` puts the trial's movement mask in
    ``Reference.mask`` (BROAD's own metric); ``"all"`` leaves the mask unset, scoring every
    finite reference sample.

    Site: gravity standard, ``mag_n`` unknown (the lab's field was not published).
    NaN policy: NaN sensor rows stay NaN (missing samples); NaN reference rows are gaps.
    Raises LogFormatError (not HDF5, missing dataset, bad rate, mismatched lengths) and
    FlightError (values failing validation, field prefixed by the file).
    """
    if score not in ("movement", "all"):
        raise ValueError(f"score: expected 'movement' or 'all', found {score!r}")
    p = Path(path)
    raw = _load(p)
    n = raw["imu_gyr"].shape[0]
    rate = raw["sampling_rate"]
    t = np.arange(n, dtype=np.float64) / rate
    gaps = ~np.isfinite(raw["opt_quat"]).all(axis=1)
    q_enu, n_bad = invalid_quat_rows(raw["opt_quat"])
    ok = np.isfinite(q_enu).all(axis=1)
    q_ned = np.full_like(q_enu, np.nan)
    q_ned[ok] = quat_nav_enu_to_ned(q_enu[ok])
    movement = raw["movement"].astype(bool)
    meta: dict[str, Any] = {
        "source": p.name,
        "format": "broad",
        "sampling_rate_hz": rate,
        "reference.gaps": int(np.count_nonzero(gaps)),
        "reference.movement_samples": int(np.count_nonzero(movement)),
        "reference.mask": "movement" if score == "movement" else "none",
        "body_frame": "imu (sensor axes, not FRD)",
    }
    if n_bad:
        meta["reference.invalid_quaternions"] = n_bad
    rep = RepairLog()
    with flight_errors_name(p):
        return rep.attach(
            Flight(
                imu=ImuStream(
                    t=t,
                    w_b=rep.rows("imu", raw["imu_gyr"], GYRO_RANGE),
                    f_b=rep.rows("imu", raw["imu_acc"], ACCEL_RANGE),
                ),
                mag=MagStream(t=t, mag_b=rep.rows("mag", raw["imu_mag"] * _MICROTESLA, MAG_RANGE)),
                reference=Reference(
                    t=t,
                    q_nb=q_ned,
                    kind="mocap",
                    heading_free=True,
                    mask=movement if score == "movement" else None,
                ),
                site=Site(mag_n=None),
                meta=meta,
                repairs=rep.counts,
            )
        )


def broad_movement_mask(path: str | os.PathLike[str]) -> NDArray[np.bool_]:
    """The trial's ``movement`` mask, (N,) bool, on the IMU samples."""
    return _load(Path(path))["movement"].astype(bool)


def _load(p: Path) -> dict[str, Any]:
    """The BROAD datasets as arrays and the rate as a float, checked for shape."""
    if not p.is_file():
        raise LogFormatError(p, "no such file")
    import h5py

    def read() -> dict[str, Any]:
        with h5py.File(p, "r") as f:
            missing = [k for k in BROAD_DATASETS if not isinstance(f.get(k), h5py.Dataset)]
            if missing:
                raise LogFormatError(p, f"not a BROAD trial: missing dataset(s) {missing}")
            out: dict[str, Any] = {k: f[k][()] for k in BROAD_DATASETS}
            out["sampling_rate"] = f.attrs.get("sampling_rate")
        return out

    raw = guard(p, "not a readable HDF5 file (truncated or corrupt?)", read)
    rate = raw["sampling_rate"]
    try:
        rate = float(rate)
    except (TypeError, ValueError):
        raise LogFormatError(
            p, f"attribute 'sampling_rate': expected a rate in Hz, found {rate!r}"
        ) from None
    if not np.isfinite(rate) or rate <= 0:
        raise LogFormatError(p, f"attribute 'sampling_rate': expected > 0 Hz, found {rate!r}")
    raw["sampling_rate"] = rate
    n = raw["imu_gyr"].shape[0]
    widths = {"imu_gyr": 3, "imu_acc": 3, "imu_mag": 3, "opt_quat": 4, "movement": None}
    for key, width in widths.items():
        shape = raw[key].shape
        want = (n,) if width is None else (n, width)
        if shape != want:
            raise LogFormatError(p, f"dataset '{key}': expected shape {want}, found {shape}")
    return raw
