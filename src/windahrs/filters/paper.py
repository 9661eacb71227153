"""[paper] and [paper-nowind]: the paper's 4-state EKF, faithful to its printed constants
(eqs 6, 30-33) with every error of SPEC 8 corrected, fusing the normalised accelerometer,
magnetometer and (paper) the air-flow direction (SPEC 3.2.1, 3.1, 3.4.3).

The quaternion parameters themselves are the state; the paper's process and measurement
models live in :mod:`windahrs.models.additive` (and ``core.dense.propagate_cov``), the
update and the normalisation are the compiled core's (``core.kalman._fuse``,
``core.predict._normalise_add``), sequenced by the compiled loop of
:mod:`windahrs.filters.additive`. Shared rules (SPEC 2.3): innovation ``z - h(x)``
(never the printed ``z - H x``), Joseph-form covariance update, normalisation of ``q``
after every propagation and update with the covariance projected by the normalisation
Jacobian. Accelerometer, magnetometer and air-data rows are fused as separate sequential
3-row updates when each sample arrives (the sensors run at different rates); their
innovations are logged as "accel", "mag" and "air".
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray

from windahrs.estimate import STATE_LABELS
from windahrs.filters.additive import (
    KIND_PAPER,
    AdditiveEstimator,
    AdditiveStreamer,
    KernelConfig,
    KernelState,
    WindProvider,
    bad_param,
    check_choice,
    check_number,
    params_from_toml,
    unfused_counts,
)
from windahrs.filters.base import InitialState, MissingSensorError
from windahrs.flight import Flight, Site
from windahrs.windfit import WindFit, WindFitError, fit_flight_wind

__all__ = [
    "PaperEKF",
    "PaperEKFNoWind",
    "PaperNoWindParams",
    "PaperParams",
    "WindProvider",
]

F64 = NDArray[np.float64]

InitMode = Literal["paper", "triad"]
WindMode = Literal["oracle", "mean", "fit"]


@dataclass(frozen=True)
class PaperNoWindParams:
    """Constants of the paper's filter (SPEC 7.1), per IMU step at 200 Hz.

    init: "paper" starts from ``q0 = [1, 0, 0, 0]`` (eq. 30); "triad" from the first
    accelerometer and magnetometer samples (what the paper's text says instead, T29).
    p0_var: initial variance of each quaternion parameter (eq. 31), 1.
    process_var: variance added to each quaternion parameter per IMU step (eq. 32), 1.
    acc_var, mag_var: variance of each component of the normalised accelerometer and
    magnetometer vectors (eq. 33), 1.
    """

    init: InitMode = "paper"
    p0_var: float = 0.2846
    process_var: float = 0.02
    acc_var: float = 10.0
    mag_var: float = 20.0

    def __post_init__(self) -> None:
        check_choice(self, "init", ("paper", "triad"))
        for name in ("p0_var", "process_var", "acc_var", "mag_var"):
            check_number(self, name, positive=True)


@dataclass(frozen=True)
class PaperParams(PaperNoWindParams):
    """The paper's constants (see :class:`PaperNoWindParams`) plus its air-data row.

    air_var: variance of each component of the air-flow direction; the paper gives none
    (its R is 6x6 for 9 rows, T31), 20 like the magnetometer's is this library's choice.
    wind: how the filter "knows" the wind, which the paper assumes known without saying
    how: "oracle" is the instantaneous TRUE wind of a simulation (an oracle no real
    vehicle has; it reproduces the paper's claim, SPEC 7.4), "mean" a constant wind:
    ``mean_wind_n`` or, when None, the time mean of the flight's truth (or reference)
    wind, "fit" the constant wind fitted from the flight itself (its GNSS velocity and
    airspeed, the wind triangle ``|v - w| = k * airspeed``, :mod:`windahrs.windfit`; real
    data). mean_wind_n: (north, east, down) m/s or None (in a filter spec
    ``mean_wind_n=3/-2/0``, in TOML ``mean_wind_n = [3, -2, 0]``). gnss_max_age: s, a GNSS
    velocity older than this is not used for the air-flow row (nor paired with an airspeed
    sample by the wind fit). wind_fit_scale: with wind="fit", None fits the pitot scale k
    with the wind; a number holds k (a calibrated pitot; see :func:`windahrs.windfit.fit_wind`).
    """

    air_var: float = 20.0
    wind: WindMode = "oracle"
    mean_wind_n: tuple[float, float, float] | None = None
    gnss_max_age: float = 1.0
    wind_fit_scale: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        check_number(self, "air_var", positive=True)
        check_number(self, "gnss_max_age", positive=True)
        check_choice(self, "wind", ("oracle", "mean", "fit"))
        if self.wind_fit_scale is not None:
            check_number(self, "wind_fit_scale", positive=True)
        m = self.mean_wind_n
        if m is not None:
            ok = isinstance(m, tuple | list) and len(m) == 3
            ok = ok and all(isinstance(v, int | float) and not isinstance(v, bool) for v in m)
            if not ok or not np.isfinite(np.asarray(m, dtype=np.float64)).all():
                raise bad_param(self, "mean_wind_n", "None or 3 finite numbers (north, east, down) m/s")
            object.__setattr__(self, "mean_wind_n", tuple(float(v) for v in m))
            if self.wind == "fit":
                raise bad_param(self, "mean_wind_n", "None with wind='fit' (the fit gives the wind)")



class OracleWind:
    """The true wind of a simulation, ``t -> wind_n`` (3,) m/s NED, linearly interpolated
    in the truth samples t_tr (M,), wind_n (M, 3); ``at(t)`` (K, 3) for many times."""

    def __init__(self, t_tr: F64, wind_n: F64) -> None:
        self._t, self._w = t_tr, wind_n

    def at(self, t: F64) -> F64:
        return np.column_stack([np.interp(t, self._t, self._w[:, i]) for i in range(3)])

    def __call__(self, t: float) -> F64:
        return np.array([np.interp(t, self._t, self._w[:, i]) for i in range(3)])


class ConstantWind:
    """A constant wind ``t -> wind_n`` (3,) m/s NED; ``at(t)`` (K, 3) for many times.
    fit: the wind-triangle fit it came from (``wind="fit"``), else None."""

    def __init__(self, wind_n: F64, fit: WindFit | None = None) -> None:
        self._w = np.asarray(wind_n, dtype=np.float64)
        self.fit = fit

    def at(self, t: F64) -> F64:
        return np.tile(self._w, (len(t), 1))

    def __call__(self, t: float) -> F64:
        return self._w.copy()


def _paper_config(p: PaperNoWindParams, initial: InitialState | None, *, use_air: bool) -> KernelConfig:
    q_start: F64 | None = None
    if initial is not None:
        q_start = np.asarray(initial.q_nb, dtype=np.float64)
    elif p.init == "paper":
        q_start = np.array([1.0, 0.0, 0.0, 0.0])
    sigma_att0 = None if initial is None else initial.sigma_att
    air = p if isinstance(p, PaperParams) else None
    return KernelConfig(
        kind=KIND_PAPER,
        n=4,
        q_start=q_start,
        use_air=use_air and air is not None,
        p0_iso=sigma_att0 is None,
        p0_var=p.p0_var,
        att0_var=0.0 if sigma_att0 is None else sigma_att0**2,
        process_var=p.process_var,
        acc_var=p.acc_var,
        mag_var=p.mag_var,
        air_var=0.0 if air is None else air.air_var,
        gnss_max_age=0.0 if air is None else air.gnss_max_age,
    )


class PaperEKFNoWind(AdditiveEstimator):
    """The paper's EKF "without considering wind": accelerometer and magnetometer only.

    4 states (the quaternion; no gyro bias, T7), Picard-4 transition with the raw gyro
    (eq. 6), the paper's q0, P0, Q, R (eqs 30-33, :class:`PaperNoWindParams`), normalised
    vectors (T11, T12), innovation ``z - h(x)`` (T26), Joseph form, normalisation with
    covariance projection. The covariance is reported on the quaternion parameters (4x4,
    labels q_w..q_z): this filter is 4x4 by definition, and its P (tens of degrees) is not
    consistent with its errors (SPEC 6.3), so score it by RMSE only.
    """

    name: ClassVar[str] = "paper-nowind"
    requires: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})
    uses: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})
    labels: ClassVar[tuple[str, ...]] = STATE_LABELS["quat"]

    def __init__(self, params: PaperNoWindParams | None = None) -> None:
        self.params = PaperNoWindParams() if params is None else params

    @classmethod
    def load_params(cls, path: str | os.PathLike[str]) -> PaperNoWindParams:
        """PaperNoWindParams from a TOML file with a ``[windahrs]`` table of its field names."""
        return params_from_toml(PaperNoWindParams, path)

    def config(self, initial: InitialState | None) -> KernelConfig:
        return _paper_config(self.params, initial, use_air=False)


class PaperEKF(AdditiveEstimator):
    """The paper's EKF "considering wind" (SPEC 7.3 (ii)): :class:`PaperEKFNoWind` plus the
    air-flow direction row (SPEC 3.4.3).

    Air data: ``z = d(alpha_m, beta_m) = [cos a cos b, sin b, sin a cos b]`` from the
    vanes, ``h = C_bn u``, ``u = (V_n - W_n)/|V_n - W_n|`` with ``V_n`` the latest GNSS
    velocity and ``W_n`` the wind the filter is given (``params.wind``):

    * "oracle": the instantaneous TRUE wind of the simulation at the air-data time. No
      real vehicle knows it; it is what the paper implicitly assumes and what reproduces
      its claim (SPEC 7.4). Needs a Flight with truth.
    * "mean": a constant wind, ``params.mean_wind_n`` or the flight's time-mean truth (or
      reference) wind; gusts then corrupt the row (SPEC 3.4.3).
    * "fit": the constant wind fitted from the flight's own GNSS velocity and airspeed
      (:func:`windahrs.windfit.fit_flight_wind`, horizontal: ``w_d = 0``); what a real log
      allows. The fit and its pitot scale k are in ``Estimate.meta`` (``wind_fit_*``). The
      air row is a direction (vanes against ``V_n - W``): it uses no airspeed, so k enters
      only the fit, where the airspeed is taken as ``k * airspeed``.

    R of the air row is ``air_var`` (20) per component: the paper does not give it (T31).
    Needs vanes (angle of attack and sideslip) and GNSS velocity. Air samples without a
    recent GNSS velocity or below 0.5 m/s air-relative speed are not fused; their counts
    are in ``Estimate.meta`` (keys ``unfused_*``).
    """

    name: ClassVar[str] = "paper"
    requires: ClassVar[frozenset[str]] = frozenset({"imu", "mag", "gnss", "air"})
    uses: ClassVar[frozenset[str]] = frozenset({"imu", "mag", "gnss", "air"})
    labels: ClassVar[tuple[str, ...]] = STATE_LABELS["quat"]

    def __init__(self, params: PaperParams | None = None) -> None:
        self.params = PaperParams() if params is None else params

    @classmethod
    def load_params(cls, path: str | os.PathLike[str]) -> PaperParams:
        """PaperParams from a TOML file with a ``[windahrs]`` table of its field names."""
        return params_from_toml(PaperParams, path)

    def check(self, flight: Flight) -> None:
        if flight.air is None or not flight.air.has_vanes:
            if flight.air is None:
                found = "no air data"
            elif flight.air.vane_names:
                found = f"air data with only one vane ({flight.air.vane_names[0]})"
            else:
                found = "air data without vanes (pitot only)"
            # With air data present, what is missing is its vanes (not "air data").
            raise MissingSensorError(
                self.name,
                "air",
                f": the air-flow direction needs vanes (angle of attack and sideslip), found {found}",
                what=None if flight.air is None else "air data with both vanes",
            )
        super().check(flight)

    def wind_provider(self, flight: Flight) -> WindProvider:
        """The wind ``t -> wind_n`` (3,) m/s NED that ``params.wind`` gives for ``flight``.

        ValueError when the flight cannot provide it ("oracle" without truth, "mean"
        without ``mean_wind_n``, truth wind or reference wind).
        """
        p = self.params
        tr = flight.truth
        if p.wind == "oracle":
            if tr is None or tr.wind_n is None:
                raise ValueError(
                    "PaperParams.wind: expected a flight with simulation truth for the 'oracle' "
                    "wind (the oracle needs flight.truth.wind_n), found none; for real data use "
                    "wind=fit (the wind fitted from the flight's GNSS velocity and airspeed: "
                    "paper:wind=fit) or wind=mean with mean_wind_n (paper:wind=mean:mean_wind_n=3/-2/0)"
                )
            return OracleWind(tr.t, tr.wind_n)
        if p.wind == "fit":
            try:
                fit = fit_flight_wind(flight, scale=p.wind_fit_scale, max_gap=p.gnss_max_age)
            except WindFitError as exc:
                raise WindFitError(f"PaperParams.wind='fit': {exc}") from None
            return ConstantWind(fit.wind_n, fit)
        if p.mean_wind_n is not None:
            mean = np.array(p.mean_wind_n)
        elif tr is not None and tr.wind_n is not None:
            mean = tr.wind_n.mean(axis=0)
        elif flight.ref_wind is not None and np.isfinite(flight.ref_wind.wind_n).all(1).any():
            mean = np.nanmean(flight.ref_wind.wind_n, axis=0)
        else:
            raise ValueError(
                "PaperParams.mean_wind_n: expected a mean wind (or a flight with truth or "
                "reference wind to average), found None and neither in the flight; give "
                "mean_wind_n (paper:wind=mean:mean_wind_n=3/-2/0) or use wind=fit"
            )
        return ConstantWind(mean)

    def streamer(
        self,
        site: Site,
        *,
        initial: InitialState | None = None,
        has: frozenset[str] = frozenset(),
        wind: WindProvider | None = None,
    ) -> AdditiveStreamer:
        """A streaming instance. ``has`` empty means every stream the filter uses.
        ``wind``: the wind provider (see :meth:`wind_provider`); it may be omitted only for
        ``wind="mean"`` with ``mean_wind_n`` set, or when no air data will be fed."""
        has = has or self.uses
        p = self.params
        if wind is None and p.wind == "mean" and p.mean_wind_n is not None:
            wind = ConstantWind(np.array(p.mean_wind_n))
        if wind is None and "air" in has:
            raise ValueError(
                "wind: expected a wind provider (t -> wind_n) for the air-flow row, found None; "
                "build one with PaperEKF.wind_provider(flight)"
            )
        config = _paper_config(p, initial, use_air=wind is not None)
        return AdditiveStreamer(self.name, config, site, has, self.labels, wind)

    def config(self, initial: InitialState | None) -> KernelConfig:
        return _paper_config(self.params, initial, use_air=True)

    def _wind_for(self, flight: Flight) -> WindProvider:
        return self.wind_provider(flight)

    def _meta(self, st: KernelState, wind: WindProvider | None = None) -> dict[str, Any]:
        meta: dict[str, Any] = {"wind": self.params.wind}
        fit = getattr(wind, "fit", None)
        if isinstance(fit, WindFit):
            meta.update(fit.as_meta())
        for reason, count in sorted(unfused_counts(st).items()):
            meta[f"unfused_{reason}"] = count
        return meta
