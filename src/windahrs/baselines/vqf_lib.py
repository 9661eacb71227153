"""Adapters for ``vqf`` (dlaidig/vqf, 2.x): the real-time VQF and the non-causal
``offlineVQF``.

VQF works in the sensor frame as given and an ENU earth frame: we feed our FRD body-frame
gyro (rad/s), specific force (m/s^2) and magnetometer (microtesla; VQF takes any unit)
unchanged and get ``q`` = FRD body -> ENU, which :func:`~windahrs.rotation.quat_nav_enu_to_ned`
re-expresses w.r.t. NED. VQF's 9-axis heading is from magnetic north: the adapter rotates
it by the site's declination. Inputs are float64 and C-contiguous (the bindings refuse
anything else). The constructor takes the sample PERIOD (not the rate) and the model is
fixed-rate: time-stamp jitter is ignored and gaps are integrated as one period.
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from windahrs.baselines._common import (
    LibraryEstimator,
    LibraryStreamer,
    MagMode,
    check_flag,
    check_mag_mode,
    check_number,
    check_rate,
    declination,
    held_mag,
    import_library,
    q_about_down,
)
from windahrs.estimate import Estimate
from windahrs.filters.base import InitialState, Streamer
from windahrs.flight import Flight, Site
from windahrs.rotation import quat_identity, quat_mul, quat_nav_enu_to_ned, quat_normalize

__all__ = ["Vqf", "VqfOffline", "VqfParams"]

F64 = NDArray[np.float64]

#: Our parameter names -> VQF's.
_VQF_NAMES = {
    "tau_acc": "tauAcc",
    "tau_mag": "tauMag",
    "motion_bias_est": "motionBiasEstEnabled",
    "rest_bias_est": "restBiasEstEnabled",
    "mag_dist_rejection": "magDistRejectionEnabled",
    "bias_sigma_init": "biasSigmaInit",
    "bias_forgetting_time": "biasForgettingTime",
    "bias_clip": "biasClip",
    "bias_sigma_motion": "biasSigmaMotion",
    "bias_sigma_rest": "biasSigmaRest",
    "rest_min_t": "restMinT",
    "rest_th_gyr": "restThGyr",
    "rest_th_acc": "restThAcc",
    "mag_new_first_time": "magNewFirstTime",
}


@dataclass(frozen=True)
class VqfParams:
    """VQF settings a user tunes (library defaults; VQF's own units, which are degrees
    for the bias-related ones).

    rate: IMU sample rate, Hz (the period handed to VQF is ``1/rate``); None takes the
    flight's median period in ``run`` and the first interval when streaming.
    tau_acc, tau_mag: time constants of the inclination and heading corrections, s
    (0: full correction at every sample; VQF's negative "disable" is not offered, use
    ``use_mag="off"``).
    motion_bias_est, rest_bias_est: gyro bias estimation in motion / at rest.
    mag_dist_rejection: magnetic disturbance detection and rejection.
    bias_sigma_init (deg/s), bias_forgetting_time (s), bias_clip (deg/s),
    bias_sigma_motion, bias_sigma_rest (deg/s): bias estimator tuning.
    rest_min_t (s), rest_th_gyr (deg/s), rest_th_acc (m/s^2): rest detection.
    mag_new_first_time: time (s) before a first magnetic field is accepted as the
    reference when disturbance rejection is on.
    use_mag: "auto", "required" or "off" (6-axis).
    """

    rate: float | None = None
    tau_acc: float = 3.0
    tau_mag: float = 9.0
    motion_bias_est: bool = True
    rest_bias_est: bool = True
    mag_dist_rejection: bool = True
    bias_sigma_init: float = 0.5
    bias_forgetting_time: float = 100.0
    bias_clip: float = 2.0
    bias_sigma_motion: float = 0.1
    bias_sigma_rest: float = 0.03
    rest_min_t: float = 1.5
    rest_th_gyr: float = 2.0
    rest_th_acc: float = 0.5
    mag_new_first_time: float = 5.0
    use_mag: MagMode = "auto"

    def __post_init__(self) -> None:
        check_rate("VqfParams", self.rate)
        flags = ("motion_bias_est", "rest_bias_est", "mag_dist_rejection")
        zero_ok = ("mag_new_first_time", "tau_acc", "tau_mag")
        for name in _VQF_NAMES:
            if name in flags:
                check_flag("VqfParams", name, getattr(self, name))
            else:
                check_number("VqfParams", name, getattr(self, name), strict=name not in zero_ok)
        check_mag_mode("VqfParams", self.use_mag)

    def vqf_kwargs(self) -> dict[str, Any]:
        """The settings as VQF keyword arguments (camelCase names)."""
        d = asdict(self)
        return {v: d[k] for k, v in _VQF_NAMES.items()}


#: ENU -> NED nav frame: 180 deg about (1, 1, 0)/sqrt(2) (as quat_nav_enu_to_ned).
_Q_NED_ENU = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])


class _VqfStreamer(LibraryStreamer):
    frame_q = _Q_NED_ENU
    needs_period = True
    estimates_bias = True

    def __init__(self, params: VqfParams, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._params = params
        self._vqf: Any = None
        self._zero = np.zeros(3)

    def make_vqf(self, period: float) -> Any:
        """A VQF with the parameters, seeded with the initial attitude and bias.

        VQF has no initial-attitude argument: the attitude is written into its
        gyro-integration quaternion (its state setter); the inclination is corrected
        from the first accelerometer sample anyway.
        """
        vqf = import_library("vqf")
        lib = vqf.VQF(float(period), **self._params.vqf_kwargs())
        if self._initial is not None:
            st = lib.state
            st["gyrQuat"] = [float(x) for x in self._q_placeholder]
            lib.state = st
            if self._initial.gyro_bias_b is not None:
                lib.setBiasEstimate(np.ascontiguousarray(self._bias_placeholder))
        return lib

    def __deepcopy__(self, memo: dict[int, Any]) -> _VqfStreamer:
        # The C++ VQF object cannot be copied; a new one with the same sampling time and
        # parameters takes over its complete state (Streamer.snapshot / restore).
        new = object.__new__(type(self))
        memo[id(self)] = new
        for key, value in self.__dict__.items():
            if key != "_vqf":
                new.__dict__[key] = copy.deepcopy(value, memo)
        lib = self.__dict__.get("_vqf")
        if lib is not None:
            assert self._period is not None  # set when the VQF object was made
            vqf = import_library("vqf")
            clone = vqf.VQF(float(self._period), **self._params.vqf_kwargs())
            clone.state = copy.deepcopy(lib.state)
            new.__dict__["_vqf"] = clone
        return new

    def _start(self, w_b: F64, f_b: F64, mag_ut: F64 | None) -> None:
        assert self._period is not None
        self._vqf = self.make_vqf(self._period)
        self._update(self._period, w_b, f_b, mag_ut)

    def _update(self, dt: float, w_b: F64, f_b: F64, mag_ut: F64 | None) -> None:
        if not self._use_mag:
            self._vqf.update(w_b, f_b)
        else:
            # VQF ignores an all-zero magnetometer sample: that is its 6-axis update.
            self._vqf.update(w_b, f_b, self._zero if mag_ut is None else mag_ut)

    def _q_lib(self) -> F64:
        return np.asarray(
            self._vqf.getQuat9D() if self._use_mag else self._vqf.getQuat6D(), dtype=np.float64
        )

    def _bias(self) -> F64:
        return np.array(self._vqf.getBiasEstimate()[0], dtype=np.float64)


class Vqf(LibraryEstimator):
    """``vqf.VQF``, the real-time filter (inclination and heading corrections with
    gyro bias estimation), per sample; ``gyro_bias_b`` from ``getBiasEstimate``.

    ``run`` uses VQF's ``updateBatch`` (the same C++ update called in a loop), which
    tests/test_baselines.py checks equal to the per-sample streaming result to 1e-9.
    """

    name: ClassVar[str] = "vqf"
    params_type: ClassVar[type] = VqfParams

    def __init__(self, params: VqfParams | None = None) -> None:
        self.params = params or VqfParams()

    def _make_streamer(
        self, site: Site, initial: InitialState | None, use_mag: bool, period: float | None
    ) -> LibraryStreamer:
        return _VqfStreamer(
            self.params, self.name, site, initial=initial, use_mag=use_mag, period=period
        )

    def run(self, flight: Flight, *, initial: InitialState | None = None) -> Estimate:
        """Estimate the whole flight with ``updateBatch`` (equal to the streaming run)."""
        self.check(flight)
        has = self._has(flight)
        period = self._period(flight)
        s = self.streamer(flight.site, initial=initial, has=has, period=period)
        assert isinstance(s, _VqfStreamer)
        imu = flight.imu
        n = len(imu.t)
        ok = np.isfinite(imu.w_b).all(axis=1) & np.isfinite(imu.f_b).all(axis=1)
        idx = np.flatnonzero(ok)
        q = np.empty((n, 4))
        bias = np.empty((n, 3))
        # Rows before the first valid sample show the streamer's placeholder state.
        st0 = s.state
        q[:] = st0.q_nb
        bias[:] = st0.gyro_bias_b
        if len(idx):
            lib = s.make_vqf(period)
            gyr = np.ascontiguousarray(imu.w_b[idx])
            acc = np.ascontiguousarray(imu.f_b[idx])
            if "mag" in has:
                mag, _ = held_mag(flight, imu.t[idx])
                out = lib.updateBatch(gyr, acc, np.ascontiguousarray(mag))
                q_enu = out["quat9D"]
            else:
                out = lib.updateBatch(gyr, acc)
                q_enu = out["quat6D"]
            q_valid = quat_normalize(np.asarray(q_enu) @ s.out_matrix.T)
            # A skipped (NaN) row keeps the state of the last valid row before it.
            k = np.searchsorted(idx, np.arange(n), side="right") - 1
            have = k >= 0
            q[have] = q_valid[k[have]]
            bias[have] = np.asarray(out["bias"])[k[have]]
        skipped = {"imu": int(n - len(idx)), "mag": 0, "gnss": 0, "air": 0}
        if "mag" in has and flight.mag is not None:
            skipped["mag"] = int((~np.isfinite(flight.mag.mag_b).all(axis=1)).sum())
        return Estimate(
            filter=self.name,
            t=imu.t.copy(),
            q_nb=q,
            gyro_bias_b=bias,
            skipped=skipped,
            params=self.params_text(),
            repairs={k: dict(v) for k, v in flight.repairs.items()},
        )


class VqfOffline(LibraryEstimator):
    """``vqf.offlineVQF``: non-causal (a forward and a backward VQF pass to estimate the
    bias, zero-phase filtering of the inclination and heading corrections). It needs the
    whole recording, so it CANNOT stream: :meth:`streamer` raises NotImplementedError.

    The magnetometer is held (zero-order) between samples and, being non-causal, the
    first magnetometer sample is also used before it arrived (offlineVQF, unlike VQF,
    does not skip all-zero samples). Rows with NaN are left out of the batch and show
    the estimate of the previous valid row, as the streaming adapters do.
    """

    name: ClassVar[str] = "vqf-offline"
    params_type: ClassVar[type] = VqfParams

    def __init__(self, params: VqfParams | None = None) -> None:
        self.params = params or VqfParams()

    def _make_streamer(
        self, site: Site, initial: InitialState | None, use_mag: bool, period: float | None
    ) -> LibraryStreamer:
        raise NotImplementedError(
            "vqf-offline is non-causal (a forward and a backward pass over the whole "
            "recording) and cannot stream; use 'vqf' to stream, or run() on a Flight"
        )

    def streamer(
        self,
        site: Site,
        *,
        initial: InitialState | None = None,
        has: frozenset[str] = frozenset(),
        period: float | None = None,
    ) -> Streamer:
        """Always raises NotImplementedError: offlineVQF is non-causal."""
        return self._make_streamer(site, initial, False, period)

    def run(self, flight: Flight, *, initial: InitialState | None = None) -> Estimate:
        """Estimate the whole flight with ``offlineVQF``. ``initial`` is ignored (offline
        VQF has no initial state; the backward pass makes one unnecessary)."""
        self.check(flight)
        has = self._has(flight)
        use_mag = self._use_mag(has)
        period = self._period(flight)
        vqf = import_library("vqf")
        imu = flight.imu
        n = len(imu.t)
        ok = np.isfinite(imu.w_b).all(axis=1) & np.isfinite(imu.f_b).all(axis=1)
        idx = np.flatnonzero(ok)
        q = np.tile(quat_identity(), (n, 1))
        bias = np.zeros((n, 3))
        decl = declination(flight.site) if use_mag else 0.0
        if len(idx):
            gyr = np.ascontiguousarray(imu.w_b[idx])
            acc = np.ascontiguousarray(imu.f_b[idx])
            params = self.params.vqf_kwargs()
            mag = None
            if use_mag:
                mag, have_mag = held_mag(flight, imu.t[idx])
                if have_mag.any():
                    mag[~have_mag] = mag[int(np.argmax(have_mag))]
                    mag = np.ascontiguousarray(mag)
                else:
                    mag, use_mag, decl = None, False, 0.0
            out = vqf.offlineVQF(gyr, acc, mag, float(period), params)
            q_enu = out["quat9D"] if use_mag else out["quat6D"]
            q_valid = quat_normalize(quat_mul(q_about_down(decl), quat_nav_enu_to_ned(q_enu)))
            k = np.searchsorted(idx, np.arange(n), side="right") - 1
            k = np.maximum(k, 0)  # rows before the first valid one show its estimate
            q = q_valid[k]
            bias = np.asarray(out["bias"])[k]
        skipped = {"imu": int(n - len(idx)), "mag": 0, "gnss": 0, "air": 0}
        if "mag" in has and flight.mag is not None:
            skipped["mag"] = int((~np.isfinite(flight.mag.mag_b).all(axis=1)).sum())
        return Estimate(
            filter=self.name,
            t=imu.t.copy(),
            q_nb=q,
            gyro_bias_b=bias,
            skipped=skipped,
            params=self.params_text(),
            repairs={k: dict(v) for k, v in flight.repairs.items()},
        )
