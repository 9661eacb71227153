"""Input repair at the edge: what the readers and :meth:`Flight.from_arrays
<windahrs.flight.Flight.from_arrays>` do to a sensor stream before it becomes a Flight
stream, and the counts they keep (``Flight.repairs``).

One policy for every source, so that one glitch does not refuse a whole recording and
nothing is changed without a count:

=================  ========================================================================
kind               what is done
=================  ========================================================================
``unsortable``     a row whose time stamp is not finite cannot be placed in time: dropped
``reordered``      rows out of time order are sorted (stable); counted: rows moved
``duplicates``     a repeated time stamp keeps its first row (first in the file); the
                   others are dropped
``infinite``       a row holding +-inf (no sensor measures it: a parser's or a logger's
                   overflow) becomes NaN, a missing sample. A NaN is the documented
                   missing sample, not a repair: the row becomes all NaN (a row with any
                   NaN is missing) and is counted as missing, not here
``out_of_range``   a row with a component beyond the sensor's range (:data:`GYRO_RANGE`,
                   :data:`ACCEL_RANGE`, ...) cannot have been measured: it becomes NaN, a
                   missing sample, unless they are the bulk of the data
                   (:func:`is_bulk`: more than :data:`SPIKE_SHARE` of the finite rows, and
                   more than one row), which is a unit slip (deg/s for rad/s), left for
                   the stream's validation to refuse with its hint
=================  ========================================================================

Where: besides the counts, the times of the repaired rows (s, on the flight's clock) are
kept in ``Flight.repair_times`` (stream -> kind -> times): for ``reordered`` the rows moved
by the sort, at their new place; for ``duplicates`` the kept row each dropped one repeated;
for ``infinite`` and ``out_of_range`` the rows set to NaN. ``unsortable`` rows have no time.
:class:`RepairLog` records the rows' places as it repairs and :meth:`RepairLog.attach` turns
them into times on the Flight the reader built; the per-sample flags ``stamps_repaired``
and ``values_repaired`` (:mod:`windahrs.flags`) mark them.

The Flight's own constructors repair nothing: they refuse unsorted or repeated time stamps
and infinite values, and check units on the bulk of the data (the same
:func:`is_bulk` rule), so a record is never changed behind its author's back; a
simulated fault (a spike of any size) reaches the estimators as made. Repair is the edge's
job: every reader, and ``Flight.from_arrays`` unless ``strict=True``.

Ranges are per axis, at a sensor's full scale plus :data:`CALIBRATION_MARGIN`, the largest
scale correction an autopilot's calibration applies: a clipped sample, calibrated, may read
slightly beyond the full scale and is still a measurement.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from windahrs.conventions import DEG, G0

if TYPE_CHECKING:
    from windahrs.flight import Flight

__all__ = [
    "ACCEL_RANGE",
    "AIRSPEED_RANGE",
    "ANGLE_RANGE",
    "CALIBRATION_MARGIN",
    "GNSS_VELOCITY_RANGE",
    "GYRO_RANGE",
    "MAG_RANGE",
    "REPAIR_KINDS",
    "SPIKE_SHARE",
    "RepairLog",
    "RepairWarning",
    "beyond_range",
    "clean_series",
    "finite_rows",
    "is_bulk",
    "repairs_text",
]

F64 = NDArray[np.float64]

#: The kinds of repair, in the order they are applied and reported.
REPAIR_KINDS: tuple[str, ...] = ("unsortable", "reordered", "duplicates", "infinite", "out_of_range")

#: Words for each kind in :func:`repairs_text`.
_KIND_TEXT = {
    "unsortable": "with a non-finite time stamp dropped",
    "reordered": "out of order sorted",
    "duplicates": "with a repeated time stamp dropped",
    "infinite": "infinite set to NaN",
    "out_of_range": "beyond the sensor range set to NaN",
}

#: Scale correction an autopilot's calibration may apply beyond full scale: ArduPilot's
#: accelerometer calibration refuses scale factors more than 10 % from 1
#: (``AP_InertialSensor::_calibrate_accel``).
CALIBRATION_MARGIN = 1.10
#: Gyroscope range, rad/s per axis: +-2000 deg/s, the largest full scale of the MEMS gyros
#: on UAV autopilots (InvenSense MPU-6000/MPU-9250, ICM-20602, ICM-20689, ICM-42688-P and
#: Bosch BMI088 datasheets), plus the calibration margin: 38.4 rad/s. A +-4000 deg/s part
#: (ICM-456xx) set to its full range would have its samples beyond 2200 deg/s counted here.
GYRO_RANGE = CALIBRATION_MARGIN * 2000.0 * DEG
#: Accelerometer range, m/s^2 per axis: +-24 g, the BMI088's full scale (the largest of
#: the MPU-9250's and ICM-20602's +-16 g and the BMI088's +-24 g), plus the calibration
#: margin: 258.9 m/s^2.
ACCEL_RANGE = CALIBRATION_MARGIN * 24.0 * G0
#: Magnetometer range, tesla per axis: +-4912 uT, the AK8963's full scale (in the
#: MPU-9250; the widest of the HMC5883L's +-8.1 G, the IST8310's +-1600 uT, the RM3100's
#: +-800 uT and the LIS3MDL's +-16 G), plus the calibration margin.
MAG_RANGE = CALIBRATION_MARGIN * 4912e-6
#: GNSS velocity range, m/s per NED component: u-blox receivers' operational limit (M8 and
#: M9 datasheets: velocity 500 m/s; the export-control limit is 515 m/s).
GNSS_VELOCITY_RANGE = 500.0
#: True airspeed range, m/s: Mach 1.2 at sea level. The common pitot sensors end well
#: below it (the MS4525DO 5 psi part at 237 m/s at sea level, 1 psi at 106 m/s); no
#: pitot-equipped small UAV flies near it.
AIRSPEED_RANGE = 400.0
#: Vane angles (angle of attack, sideslip) range, rad: an angle is within +-pi.
ANGLE_RANGE = float(np.pi)
#: Beyond this share of a stream's finite rows outside the sensor range, the rows are the
#: bulk of the data, not spikes: a unit slip, refused by the stream's validation. A glitch
#: is one or a few samples; 1 % is 2 s of a 200 Hz IMU.
SPIKE_SHARE = 0.01


class RepairWarning(UserWarning):
    """The input of a flight was repaired at the edge (``Flight.repairs`` says how); the
    command line says so once per flight it reads."""


def clean_series(
    t: NDArray[Any], *values: NDArray[Any]
) -> tuple[NDArray[Any], list[NDArray[Any]], dict[str, int]]:
    """Sort a time series and drop repeated and non-finite time stamps.

    t: (N,) time stamps in any unit (integers keep their precision). values: arrays whose
    first axis is N. Returns ``(t, values, counts)``: the cleaned series and the counts of
    ``unsortable`` (non-finite stamp, dropped), ``reordered`` (rows not at their sorted
    place) and ``duplicates`` (repeated stamps dropped, keeping the first row in the file:
    the sort is stable).
    """
    t, vals, counts, _ = _clean_series(t, *values)
    return t, vals, counts


def _clean_series(
    t: NDArray[Any], *values: NDArray[Any]
) -> tuple[NDArray[Any], list[NDArray[Any]], dict[str, int], dict[str, NDArray[np.int64]]]:
    """:func:`clean_series`, and the places in the cleaned series of the rows each kind
    touched (``reordered``: the moved rows; ``duplicates``: the row each dropped one
    repeated; may repeat a place)."""
    t = np.asarray(t)
    vals = [np.asarray(v) for v in values]
    counts = dict.fromkeys(("unsortable", "reordered", "duplicates"), 0)
    moved = np.empty(0, dtype=np.int64)
    if t.dtype.kind == "f" and not np.isfinite(t).all():
        ok = np.isfinite(t)
        counts["unsortable"] = int(np.count_nonzero(~ok))
        t = t[ok]
        vals = [v[ok] for v in vals]
    if t.size > 1 and (np.diff(t) < 0).any():
        order = np.argsort(t, kind="stable")
        moved = np.flatnonzero(order != np.arange(t.size))
        counts["reordered"] = len(moved)
        t = t[order]
        vals = [v[order] for v in vals]
    keep = np.ones(t.size, dtype=bool)
    if t.size > 1:
        keep[1:] = np.diff(t) != 0
    counts["duplicates"] = int(t.size - np.count_nonzero(keep))
    where = {"reordered": moved, "duplicates": np.flatnonzero(~keep)}
    if counts["duplicates"]:
        place = np.cumsum(keep) - 1  # a row's place once the repeats are dropped (a repeat: its kept row's)
        where = {k: place[v] for k, v in where.items()}
        t = t[keep]
        vals = [v[keep] for v in vals]
    return t, vals, counts, where


def finite_rows(a: NDArray[Any]) -> F64:
    """Float copy of ``a`` with every row holding a non-finite value set to NaN (missing)."""
    out = np.array(a, dtype=np.float64)
    bad = ~np.isfinite(out).all(axis=1) if out.ndim == 2 else ~np.isfinite(out)
    out[bad] = np.nan
    return out


def beyond_range(a: NDArray[Any], limit: float) -> tuple[NDArray[np.bool_], float]:
    """Rows of ``a`` ((N,) or (N, k)) with a finite component beyond ``+-limit``, and their
    share of the rows with a finite value (0 when none)."""
    x = np.abs(np.asarray(a, dtype=np.float64))
    x = x if x.ndim == 2 else x.reshape(len(x), 1)
    with np.errstate(invalid="ignore"):
        over: NDArray[np.bool_] = np.asarray((np.isfinite(x) & (x > limit)).any(axis=1))
    finite = int(np.count_nonzero(np.isfinite(x).any(axis=1)))
    return over, (float(np.count_nonzero(over)) / finite if finite else 0.0)


def is_bulk(over: NDArray[np.bool_], share: float) -> bool:
    """Rows beyond the range (``over``, ``share`` of the finite rows, from
    :func:`beyond_range`) are the bulk of the data, not spikes: more than
    :data:`SPIKE_SHARE` of the rows and more than one row (one sample is never the bulk,
    even in a short stream: 20 GNSS samples with one glitch)."""
    return share > SPIKE_SHARE and int(np.count_nonzero(over)) > 1


class RepairLog:
    """Counts of repairs per stream and kind, as a reader builds a Flight, and where they
    were.

    ``counts``: stream name -> kind (:data:`REPAIR_KINDS`) -> count, non-zero counts only:
    the value of ``Flight.repairs``. The places of the repaired rows (in the stream's
    cleaned series, and in the arrays given to :meth:`rows`) are kept until
    :meth:`attach` turns them into ``Flight.repair_times``; a reader that drops rows of a
    stream after :meth:`series` calls :meth:`locate` with the series' times first.
    """

    def __init__(self) -> None:
        self.counts: dict[str, dict[str, int]] = {}
        self._places: dict[str, dict[str, list[NDArray[np.int64]]]] = {}  # not yet located
        self._times: dict[str, dict[str, list[F64]]] = {}

    def _keep(self, stream: str, kind: str, places: NDArray[np.int64]) -> None:
        if len(places):
            self._places.setdefault(stream, {}).setdefault(kind, []).append(np.asarray(places, dtype=np.int64))

    def locate(self, stream: str, t: F64) -> None:
        """Turn the places kept for ``stream`` into times: ``t`` (s, on the flight's clock)
        is the stream's series as cleaned, row for row."""
        t = np.asarray(t, dtype=np.float64)
        for kind, places in self._places.pop(stream, {}).items():
            p = np.concatenate(places)
            p = p[(p >= 0) & (p < len(t))]
            self._times.setdefault(stream, {}).setdefault(kind, []).append(t[p])

    def times(self) -> dict[str, dict[str, F64]]:
        """The located times per stream and kind (sorted, unique), the value of
        ``Flight.repair_times``."""
        return {
            stream: {kind: np.unique(np.concatenate(v)) for kind, v in kinds.items()}
            for stream, kinds in self._times.items()
        }

    def attach(self, flight: Flight) -> Flight:
        """``flight`` (a :class:`~windahrs.flight.Flight` whose streams hold, row for row,
        the series and rows this log repaired) with ``repair_times``: the places not yet
        located are located on its streams' times."""
        for stream in list(self._places):
            part = getattr(flight, stream, None)
            if part is not None:
                self.locate(stream, part.t)
        self._places.clear()
        found = self.times()
        return flight.replace(repair_times=found) if found else flight

    def add(self, stream: str, kind: str, n: int) -> None:
        """Count ``n`` repairs of ``kind`` on ``stream`` (nothing for 0)."""
        if kind not in REPAIR_KINDS:
            raise ValueError(f"kind: expected one of {REPAIR_KINDS}, found {kind!r}")
        if n:
            per = self.counts.setdefault(stream, {})
            per[kind] = per.get(kind, 0) + int(n)

    def series(
        self, stream: str, t: NDArray[Any], *values: NDArray[Any]
    ) -> tuple[NDArray[Any], list[NDArray[Any]]]:
        """:func:`clean_series`, counted on ``stream``."""
        t, vals, counts, where = _clean_series(t, *values)
        for kind, n in counts.items():
            self.add(stream, kind, n)
        self._places.pop(stream, None)  # (places of an earlier series of the stream: not of this one)
        for kind, places in where.items():
            self._keep(stream, kind, places)
        return t, vals

    def rows(self, stream: str, a: NDArray[Any], limit: float | None = None) -> F64:
        """``a`` ((N,) or (N, k)) as floats, its rows with a non-finite value NaN (those with
        an inf counted ``infinite``) and, given the sensor's ``limit``, its rows beyond it NaN (counted
        ``out_of_range``) unless they are the bulk of the data (:func:`is_bulk`: a unit
        slip, left as they are for the stream's validation to refuse)."""
        out = np.array(a, dtype=np.float64)
        x = out if out.ndim == 2 else out.reshape(len(out), 1)  # a view: edits reach out
        inf = np.isinf(x).any(axis=1)
        self.add(stream, "infinite", int(np.count_nonzero(inf)))
        self._keep(stream, "infinite", np.flatnonzero(inf))
        x[~np.isfinite(x).all(axis=1)] = np.nan
        if limit is not None:
            over, share = beyond_range(x, limit)
            if not is_bulk(over, share):
                x[over] = np.nan
                self.add(stream, "out_of_range", int(np.count_nonzero(over)))
                self._keep(stream, "out_of_range", np.flatnonzero(over))
        return out


def repairs_text(repairs: dict[str, dict[str, int]]) -> str | None:
    """One line saying the repairs (``Flight.repairs``), or None when there are none:
    ``imu: 1 sample out of order sorted, 2 samples with a repeated time stamp dropped; ...``."""
    parts = []
    for stream, counts in repairs.items():
        words = [
            f"{counts[k]} sample{'' if counts[k] == 1 else 's'} {_KIND_TEXT[k]}" for k in REPAIR_KINDS if counts.get(k)
        ]
        if words:
            parts.append(f"{stream}: " + ", ".join(words))
    return "; ".join(parts) if parts else None
