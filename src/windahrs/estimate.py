"""``Estimate``: what every estimator returns, and its HDF5 form.

One row per IMU sample: attitude, gyro bias, velocity and wind where estimated, and the
covariance of the error state in the tangent space, labelled per dimension. Per-sensor
innovations carry the normalised innovation squared (NIS) and whether the update was
accepted by its gate. Samples with NaN are skipped by the estimators and counted here.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

from windahrs.flight import FlightError
from windahrs.repair import repairs_text
from windahrs.store import atomic_h5, open_h5, read_errors, read_record, read_repairs, write_record, write_repairs

__all__ = [
    "ESTIMATE_FORMAT", "Deferred", "Estimate", "EstimatorWarning", "Innovations", "load_estimate", "save_estimate",
]

F64 = NDArray[np.float64]
ESTIMATE_FORMAT = "windahrs.estimate"
ESTIMATE_VERSION = 1

#: Labels of error-state dimensions. Attitude errors are body-frame rotation vectors (rad).
STATE_LABELS: dict[str, tuple[str, ...]] = {
    "att": ("att_x", "att_y", "att_z"),
    "bg": ("bg_x", "bg_y", "bg_z"),
    "v": ("v_n", "v_e", "v_d"),
    "wind": ("wind_n", "wind_e", "wind_d"),
    "wind2": ("wind_n", "wind_e"),
    "ba": ("ba_x", "ba_y", "ba_z"),
    "quat": ("q_w", "q_x", "q_y", "q_z"),
}


#: Below this share of a gated sensor's samples accepted over a flight, the Estimate warns.
LOW_ACCEPTANCE = 0.5


class EstimatorWarning(UserWarning):
    """Something a user must know about an estimate: a reset of the state to a sensor that
    its gate had kept out, or a sensor whose samples were mostly rejected."""


@dataclass(frozen=True)
class Innovations:
    """Innovations of one sensor. t (M,) s; nu (M, m) innovation z - h(x) in the
    measurement's units; nis (M,) nu^T S^-1 nu; accepted (M,) bool (False: rejected by the
    gate, the state was not updated)."""

    t: F64
    nu: F64
    nis: F64
    accepted: NDArray[np.bool_]

    def __post_init__(self) -> None:
        n = len(self.t)
        for name in ("nu", "nis", "accepted"):
            if len(getattr(self, name)) != n:
                raise FlightError(f"innovations.{name}", f"{n} rows", f"{len(getattr(self, name))}")

    @property
    def dim(self) -> int:
        return int(self.nu.shape[1]) if self.nu.ndim == 2 else 1

    def accepted_share(self) -> float:
        """The share of the logged time the updates were accepted (1 without rows): each row
        stands for the time to the next (the last row: the median interval), at most the time
        after which a stream without a sample is absent (:func:`windahrs.flags.absent_after`),
        neither accepted nor rejected. A mean fused
        below its rate (accel_fuse_rate, mag_fuse_rate) logs a row per fusion, of k samples,
        but a row per sample that its disturbance gate keeps out, so the share of rows
        undercounts the accepted ones (measured: 36 % of the rows, 55 % of the samples, on a
        quadrotor whose field was off by 40 % for 20 of 60 s, [mekf]); for a log of a row per
        sample it is the share of rows."""
        n = len(self.t)
        if n == 0:
            return 1.0
        if n == 1:
            return float(self.accepted[0])
        from windahrs.flags import absent_after  # (flags reads Estimates: imported here)

        d = np.diff(self.t)
        period = float(np.median(d))  # (once: absent_after takes it)
        w = np.minimum(np.append(d, period), absent_after(self.t, period=period))
        total = float(w.sum())
        return float(np.dot(w, self.accepted) / total) if total > 0 else float(np.mean(self.accepted))


class Deferred:
    """A value computed when first read: ``Deferred(fn)`` given for a deferred field of
    :class:`Estimate` (its ``flags``) stands for ``fn()``, called at most once. The per-sample
    flags cost a few tenths of a microsecond per sample to build, which a Monte Carlo run that
    never reads them need not pay; until read, the Estimate keeps what ``fn`` needs (its
    flight)."""

    __slots__ = ("fn",)

    def __init__(self, fn: Callable[[], Any]) -> None:
        self.fn = fn


class _DeferredField:
    """The descriptor of a deferred dataclass field: stores what is set, resolves a
    :class:`Deferred` on the first read (the dataclass's default is ``__get__(None, cls)``:
    None)."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.key = "_deferred_" + name

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return None
        value = obj.__dict__.get(self.key)
        if isinstance(value, Deferred):
            value = value.fn()
            obj.__dict__[self.key] = value
        return value

    def __set__(self, obj: Any, value: Any) -> None:
        obj.__dict__[self.key] = value


@dataclass(frozen=True)
class Estimate:
    """The output of an estimator run on a Flight.

    filter: registry name; t (N,) s (the IMU times); q_nb (N, 4); gyro_bias_b (N, 3)
    rad/s or None; v_n (N, 3) m/s or None; wind_n (N, 3) m/s (velocity of the air) or
    None; cov (N, n, n) error-state covariance with ``state_labels`` (n,) naming each
    dimension (attitude errors are body-frame rotation vectors, rad) or None; cov_index:
    None (a covariance at every sample), or the (M,) sample indices of cov's M rows (the
    compiled core's filters keep every k-th by default, at 20 Hz and within a budget:
    :data:`windahrs.core.layout.COV_RECORD_HZ`, :data:`~windahrs.core.layout.COV_BUDGET`);
    innovations per sensor; skipped: NaN samples skipped per stream; params: text of the
    parameters used; meta: free-form. resets: per sensor (its innovation key), the resets
    of the state to it after its gate had kept it out for the filter's ``reset_timeout``,
    (K, 3) rows of [t s, size (rad for an attitude reset, m/s for a velocity reset), how
    long the sensor had been kept out s (NaN: the heading was unknown, at a start without
    the magnetometer or after a reset, and turned to its next sample; negative, -T: the
    start check, the plain mean of the first T s off the state,
    :func:`windahrs.aid.gravity.start_check`)];
    :meth:`warnings` says them in words. alerts: what
    the checks of :mod:`windahrs.filters.checks` found, e.g. ``"tilt"``: (K, 3) rows
    [t_start s, t_end s, largest disagreement deg] where the estimate's tilt disagreed with
    the mean specific force (lost gravity); ``"bias"``: (K, 3) rows [t_start s, t_end s,
    largest axis deg/s] where the gyro-bias estimate was beyond 2 deg/s for 3 s;
    ``"imu"``: (K, 4) rows [t s, change of the
    angular rate rad/s, of the specific force m/s^2, outcome: 1 beyond the sensor's range,
    2 a spike (both not propagated), 3 motion (propagated one sample late)] of the IMU
    samples the estimator's screen held (:mod:`windahrs.core.imu_screen`). flags: (N,)
    uint32, one bit per reason (:data:`windahrs.flags.FLAGS`: rejected per sensor,
    disturbance detected, fallback active, reset done, sensor absent, ...) at each sample,
    or None (an estimator that keeps no such record), built when first read (a run whose
    flags nobody reads does not pay for them); ``windahrs.flags.flag_spans`` turns
    them into time spans with their reasons. repairs: what the edge repaired in the input
    flight before the run (``Flight.repairs``: stream -> kind -> count, see
    :mod:`windahrs.repair`). airspeed_scale: the pitot's scale estimated on line
    (``airspeed_scale=true``, :mod:`windahrs.aid.airspeed_scale`) at each air sample, (K, 5)
    rows [t s, scale (true / measured airspeed), its standard deviation, the scale
    estimator's airspeed innovation m/s, accepted (1) or rejected (0) by its gate], or None.
    init_index: the first sample at which the estimator had started (``len(t)``: it never
    did), or None (not recorded: the covariance's first finite row tells,
    :attr:`first_initialised`). The filters on the error-state core record the state and
    covariance they would start from in the rows before it, finite, flagged
    ``not_initialised``.
    """

    filter: str
    t: F64
    q_nb: F64
    gyro_bias_b: F64 | None = None
    v_n: F64 | None = None
    wind_n: F64 | None = None
    cov: F64 | None = None
    state_labels: tuple[str, ...] = ()
    innovations: dict[str, Innovations] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)
    params: str = ""
    meta: dict[str, Any] = field(default_factory=dict)
    resets: dict[str, F64] = field(default_factory=dict)
    alerts: dict[str, F64] = field(default_factory=dict)
    flags: NDArray[np.uint32] | None = _DeferredField()  # type: ignore[assignment]
    cov_index: NDArray[np.int64] | None = None
    repairs: dict[str, dict[str, int]] = field(default_factory=dict)
    airspeed_scale: F64 | None = None
    init_index: int | None = None

    def __post_init__(self) -> None:
        n = len(self.t)
        if self.airspeed_scale is not None and (self.airspeed_scale.ndim != 2 or self.airspeed_scale.shape[1] != 5):
            raise FlightError("estimate.airspeed_scale", "shape (K, 5)", str(self.airspeed_scale.shape))
        if self.cov_index is not None:
            ci = self.cov_index
            if ci.ndim != 1 or (len(ci) and (ci[0] < 0 or ci[-1] >= n or np.any(np.diff(ci) <= 0))):
                raise FlightError("estimate.cov_index", f"increasing sample indices in [0, {n})", str(ci[:5]))
        flags = self.__dict__.get("_deferred_flags")  # (not resolved here)
        if flags is not None and not isinstance(flags, Deferred) and flags.shape != (n,):
            raise FlightError("estimate.flags", f"shape ({n},)", str(flags.shape))
        if self.q_nb.shape != (n, 4):
            raise FlightError("estimate.q_nb", f"shape ({n}, 4)", str(self.q_nb.shape))
        for name in ("gyro_bias_b", "v_n", "wind_n"):
            v = getattr(self, name)
            if v is not None and v.shape != (n, 3):
                raise FlightError(f"estimate.{name}", f"shape ({n}, 3)", str(v.shape))
        if self.cov is not None:
            m = len(self.state_labels)
            nc = n if self.cov_index is None else len(self.cov_index)
            if self.cov.shape != (nc, m, m):
                raise FlightError(
                    "estimate.cov", f"shape ({nc}, {m}, {m}) from state_labels and cov_index", str(self.cov.shape)
                )

    @property
    def cov_t(self) -> F64:
        """The times of the covariance's rows, s (``t``, or ``t[cov_index]``)."""
        return self.t if self.cov_index is None else self.t[self.cov_index]

    @property
    def cov_rows(self) -> NDArray[np.int64]:
        """The sample index of each of the covariance's rows."""
        return np.arange(len(self.t)) if self.cov_index is None else self.cov_index

    @property
    def first_initialised(self) -> int:
        """The index of the first sample after the estimator initialised: :attr:`init_index`
        when recorded, else its covariance's first finite row (NaN until then); 0 without a
        covariance, ``len(t)`` if it never did."""
        if self.init_index is not None:
            return self.init_index
        if self.cov is None or len(self.cov) == 0:
            return 0
        ok = np.isfinite(self.cov[:, 0, 0])
        return int(self.cov_rows[np.argmax(ok)]) if ok.any() else len(self.t)

    def block(self, prefix: str) -> F64 | None:
        """Covariance block (M, k, k) of the dimensions whose labels start with ``prefix``
        (e.g. "att", "bg", "wind"), or None when absent; its rows at :attr:`cov_t`."""
        if self.cov is None:
            return None
        idx = [i for i, lab in enumerate(self.state_labels) if lab.startswith(prefix)]
        if not idx:
            return None
        return self.cov[:, idx][:, :, idx]

    def att_cov(self) -> F64 | None:
        """Attitude error covariance (M, 3, 3), body-frame rotation vector, rad^2, at :attr:`cov_t`."""
        return self.block("att_")

    def __getstate__(self) -> dict[str, Any]:
        """What pickles (Dask, multiprocessing): a deferred field resolved first."""
        _ = self.flags
        return dict(self.__dict__)

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    def _heading_retaken_after(self, t: float) -> bool:
        """Whether the GNSS reset at t s was followed by the heading taken from the field
        (a magnetometer reset row "out for NaN s" before the next GNSS reset): an INS does
        so at most twice per run (:data:`windahrs.aid.mag.INS_HEADING_RESETS`)."""
        mag = self.resets.get("mag")
        if mag is None or not len(mag):
            return False
        later = [r for r in np.asarray(self.resets["gnss"])[:, 0] if r > t]
        end = min(later) if later else np.inf
        return bool(np.any((mag[:, 0] >= t) & (mag[:, 0] < end) & ~np.isfinite(mag[:, 2])))

    def warnings(self, *, repairs: bool = True) -> list[str]:
        """One line per thing the user must know, naming the estimator, what and when: the
        repairs of its input (``repairs``; left out with ``repairs=False``), each reset (see
        ``resets``), and each gated sensor of which less than :data:`LOW_ACCEPTANCE` of the
        samples were accepted."""
        out = []
        text = repairs_text(self.repairs) if repairs else None
        if text:
            out.append(f"{self.filter}: input repaired at the edge: {text}")
        for sensor, rows in self.resets.items():
            for t, size, out_for in rows:
                if sensor == "accel":
                    what = f"attitude levelled to it by {np.degrees(size):.1f} deg, gyro bias reset"
                elif sensor == "mag":
                    what = f"heading turned to it by {np.degrees(size):.1f} deg"
                elif sensor == "gnss":
                    what = f"velocity reset to it by {size:.1f} m/s; attitude levelled, biases and wind restarted"
                    if self._heading_retaken_after(t):
                        what += ", heading turned to the next magnetometer sample"
                elif sensor == "air":  # (aid.air_vector.reset_wind)
                    what = f"wind restarted from it, by {size:.1f} m/s"
                else:
                    what = f"state reset to it by {size:.3g}"
                if not np.isfinite(out_for):  # the heading unknown: a start without it, a GNSS reset
                    out.append(f"{self.filter}: {sensor} taken for the heading (absent at the start, or after "
                               f"a reset); at t = {t:.2f} s {what}")
                    continue
                if out_for < 0:  # the start check (windahrs.aid.gravity.start_check)
                    out.append(f"{self.filter}: {sensor} mean over the first {-out_for:.1f} s off the state (by more "
                               f"than 45 deg, or 25 deg at gravity's length; the start check); at t = {t:.2f} s {what}")
                    continue
                why = {
                    "gnss": "rejected",
                    "accel": "off the state (by more than 45 deg, or 25 deg at gravity's length)",
                    "air": "rejected while GNSS held the velocity",
                }.get(sensor, "more than 45 deg off the state")
                if sensor == "mag" and self.v_n is not None and self.wind_n is not None:  # an INS's (aid.mag)
                    what += ", wind restarted from the next air sample"
                out.append(f"{self.filter}: {sensor} {why} for {out_for:.1f} s; at t = {t:.2f} s {what}")
        for t0, t1, deg in self.alerts.get("tilt", ()):
            out.append(f"{self.filter}: tilt disagrees with the mean specific force by up to {deg:.0f} deg "
                       f"from t = {t0:.1f} to {t1:.1f} s (lost gravity?)")
        bias = self.alerts.get("bias")
        if bias is not None and len(bias):
            out.append(f"{self.filter}: gyro bias estimated beyond 2 deg/s for 3 s or more (up to "
                       f"{bias[:, 2].max():.1f} deg/s, {len(bias)} span(s) from t = {bias[0, 0]:.1f} s): "
                       "more than a calibrated gyro's, "
                       "an attitude error absorbed into the bias?")
        held = self.alerts.get("imu")
        if held is not None and np.any(held[:, 3] < 3):
            lost = held[held[:, 3] < 3]
            n_range = int(np.sum(lost[:, 3] == 1))
            out.append(f"{self.filter}: {len(lost)} IMU samples not propagated ({n_range} beyond the sensor's range, "
                       f"{len(lost) - n_range} spikes), the first at t = {lost[0, 0]:.2f} s")
        for sensor, inn in self.innovations.items():
            n = len(inn.accepted)
            if n < 10 or inn.accepted.all():  # (too few to judge, or the share is 1: not weighed)
                continue
            share = inn.accepted_share()
            if share < LOW_ACCEPTANCE:
                why = "a disturbed sensor, or a lost state"
                if sensor == "mag" and "gnss" in self.innovations:  # (an INS: GNSS holds its heading)
                    why = ("a disturbed sensor, a lost state, or a field off the heading GNSS velocity shows, "
                           "as from a compass mounted or calibrated wrong")
                out.append(f"{self.filter}: only {100 * share:.0f} % of {n} {sensor} samples accepted "
                           f"(gated out: {why})")
        return out


def save_estimate(est: Estimate, path: str | os.PathLike[str]) -> Path:
    """Write an Estimate to HDF5 (format ``windahrs.estimate`` v1), atomically."""
    with atomic_h5(path, ESTIMATE_FORMAT, ESTIMATE_VERSION) as f:
        f.attrs["filter"] = est.filter
        f.attrs["params"] = est.params
        f.attrs["state_labels"] = ",".join(est.state_labels)
        if est.init_index is not None:
            f.attrs["init_index"] = est.init_index
        for name in ("t", "q_nb", "gyro_bias_b", "v_n", "wind_n", "cov", "flags", "cov_index", "airspeed_scale"):
            v = getattr(est, name)
            if v is not None:
                f.create_dataset(name, data=v, compression="gzip", compression_opts=1, shuffle=True)
        g = f.create_group("innovations")
        for sensor, inn in est.innovations.items():
            write_record(g.create_group(sensor), inn)
        sk = f.create_group("skipped")
        for k, v in est.skipped.items():
            sk.attrs[k] = v
        meta = f.create_group("meta")
        for k, v in est.meta.items():
            meta.attrs[k] = v
        for name in ("resets", "alerts"):
            grp = f.create_group(name)
            for k, v in getattr(est, name).items():
                grp.create_dataset(k, data=v)
        write_repairs(f, est.repairs)
    return Path(path)


def load_estimate(path: str | os.PathLike[str]) -> Estimate:
    """Read an Estimate written by :func:`save_estimate` (StoreError on a bad file)."""
    with read_errors(path, "unreadable estimate"), open_h5(path, ESTIMATE_FORMAT, (ESTIMATE_VERSION,)) as f:
        labels = str(f.attrs["state_labels"])
        names = ("t", "q_nb", "gyro_bias_b", "v_n", "wind_n", "cov", "flags", "cov_index", "airspeed_scale")
        arrays = {k: f[k][()] for k in names if k in f}
        inns = {
            k: read_record(g, Innovations, f"{path}:/innovations/{k}")
            for k, g in f["innovations"].items()
        }
        return Estimate(
            filter=str(f.attrs["filter"]),
            params=str(f.attrs["params"]),
            state_labels=tuple(labels.split(",")) if labels else (),
            innovations=inns,
            skipped={k: int(v) for k, v in f["skipped"].attrs.items()},
            meta=dict(f["meta"].attrs.items()),
            resets=_float_group(f, "resets"),
            alerts=_float_group(f, "alerts"),
            repairs=read_repairs(f),
            init_index=int(f.attrs["init_index"]) if "init_index" in f.attrs else None,
            **arrays,
        )


def _float_group(f: h5py.File, name: str) -> dict[str, F64]:
    """The datasets of group ``name`` as float arrays by name (none when absent: older files)."""
    return {k: np.asarray(d[()], dtype=np.float64) for k, d in f[name].items()} if name in f else {}
