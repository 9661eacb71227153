"""Adapters for the ``ahrs`` package (Mayitzin/ahrs, 0.4): EKF, Madgwick and Mahony.

The three filters are driven sample by sample: each ``update`` takes the previous
quaternion and returns the next, so the adapter carries the quaternion (in the filter's
own navigation frame) and passes the measured ``dt`` of every sample.

What each filter expects, read from its source (``ahrs/filters/*.py``, 0.4.0):

============  =====================================  ====================================
filter        accelerometer / navigation frame       magnetometer
============  =====================================  ====================================
EKF           NEGATED specific force (points down),  any unit (normalised); reference
              ``frame='NED'``: q is FRD body -> NED  ``magnetic_ref`` = the site field
                                                     (default: Munich, WMM)
Madgwick      raw specific force; reference          any unit; reference horizontal
              ``[0, 0, 1]`` = up, field along +x:    component along +x (magnetic north)
              q is FRD body -> NWU
Mahony        raw specific force; reference up;      any unit; horizontal field along
              field along +y: q is FRD body -> ENU   +y (magnetic north)
============  =====================================  ====================================

Madgwick and Mahony therefore measure heading from magnetic north, in two different
frames; the EKF measures it from the reference field, i.e. true north when the site's
field is known.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from windahrs.baselines._common import (
    LibraryEstimator,
    LibraryStreamer,
    MagMode,
    check_mag_mode,
    check_number,
    declination,
    import_library,
)
from windahrs.filters.base import InitialState, triad
from windahrs.flight import Site

__all__ = [
    "AhrsEkf",
    "AhrsEkfParams",
    "Madgwick",
    "MadgwickParams",
    "Mahony",
    "MahonyParams",
]

F64 = NDArray[np.float64]

#: NED <-> NWU: 180 deg about north (its own inverse up to sign).
_Q_NED_NWU = np.array([0.0, 1.0, 0.0, 0.0])
#: NED <-> ENU: 180 deg about (1, 1, 0)/sqrt(2) (its own inverse up to sign).
_Q_NED_ENU = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])


# --- parameters ---------------------------------------------------------------------


@dataclass(frozen=True)
class AhrsEkfParams:
    """``ahrs.filters.EKF`` settings (library defaults).

    var_gyr: gyro noise variance, (rad/s)^2; var_acc: accelerometer noise variance of the
    normalised reading; var_mag: magnetometer noise variance of the normalised reading.
    use_mag: "auto" (fuse when the flight has one), "required", "off" (6-axis).
    """

    var_gyr: float = 0.3**2
    var_acc: float = 0.5**2
    var_mag: float = 0.8**2
    use_mag: MagMode = "auto"

    def __post_init__(self) -> None:
        for name in ("var_gyr", "var_acc", "var_mag"):
            check_number("AhrsEkfParams", name, getattr(self, name))
        check_mag_mode("AhrsEkfParams", self.use_mag)


@dataclass(frozen=True)
class MadgwickParams:
    """``ahrs.filters.Madgwick`` settings (library defaults).

    gain_imu: gradient-step gain (beta, rad/s) of the 6-axis update; gain_marg: of the
    9-axis update. use_mag: "auto", "required" or "off".
    """

    gain_imu: float = 0.033
    gain_marg: float = 0.041
    use_mag: MagMode = "auto"

    def __post_init__(self) -> None:
        check_number("MadgwickParams", "gain_imu", self.gain_imu)
        check_number("MadgwickParams", "gain_marg", self.gain_marg)
        check_mag_mode("MadgwickParams", self.use_mag)


@dataclass(frozen=True)
class MahonyParams:
    """``ahrs.filters.Mahony`` settings (library defaults).

    k_p: proportional gain, 1/s; k_i: integral gain of the gyro bias estimate, 1/s^2
    (0 disables the bias estimate). use_mag: "auto", "required" or "off".
    """

    k_p: float = 1.0
    k_i: float = 0.3
    use_mag: MagMode = "auto"

    def __post_init__(self) -> None:
        check_number("MahonyParams", "k_p", self.k_p)
        check_number("MahonyParams", "k_i", self.k_i, strict=False)
        check_mag_mode("MahonyParams", self.use_mag)


# --- streamers ----------------------------------------------------------------------


class _AhrsStreamer(LibraryStreamer):
    """Carries the quaternion of an ``ahrs`` filter in the filter's own frame.

    The first IMU sample initialises (``initial`` or the accelerometer and the held
    magnetometer sample, as the library's own batch does with ``acc2q``/``ecompass``);
    later samples update. Without an ``initial`` attitude and before the first
    magnetometer sample, heading is unknown: the attitude is re-initialised from the
    first magnetometer sample, as the library's batch does from ``acc[0], mag[0]``
    (Madgwick would otherwise take a minute to turn to north at its 4.7 deg/s).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._q = self._q_placeholder.copy()
        self._await_heading = False

    def _q_lib(self) -> F64:
        return self._q

    def _start(self, w_b: F64, f_b: F64, mag_ut: F64 | None) -> None:
        if self._initial is None:
            self._q = self.library_from_ned(self.triad_library_nav(f_b, mag_ut))
            self._await_heading = self._use_mag and mag_ut is None
        self._on_start()

    def _on_start(self) -> None:
        """Hook: build the library object."""

    def _update(self, dt: float, w_b: F64, f_b: F64, mag_ut: F64 | None) -> None:
        if self._await_heading and mag_ut is not None:
            self._q = self.library_from_ned(self.triad_library_nav(f_b, mag_ut))
            self._await_heading = False
            self._on_heading_init()
            return
        self._q = self._step(self._q, dt, w_b, f_b, mag_ut)

    def _on_heading_init(self) -> None:
        """Hook: the heading was just re-initialised from the magnetometer."""

    def _step(self, q: F64, dt: float, w_b: F64, f_b: F64, mag_ut: F64 | None) -> F64:
        raise NotImplementedError


class _MadgwickStreamer(_AhrsStreamer):
    frame_q = _Q_NED_NWU

    def __init__(self, params: MadgwickParams, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._params = params
        self._lib: Any = None

    def _on_start(self) -> None:
        ahrs = import_library("ahrs")
        self._lib = ahrs.filters.Madgwick(
            gain_imu=self._params.gain_imu, gain_marg=self._params.gain_marg
        )

    def _step(self, q: F64, dt: float, w_b: F64, f_b: F64, mag_ut: F64 | None) -> F64:
        lib = self._lib
        # Madgwick picks ONE gain at construction (gain_imu unless built with data from a
        # magnetometer) and uses it in both updates: set the one that matches the update.
        if mag_ut is None:
            lib.gain = self._params.gain_imu
            return np.asarray(lib.updateIMU(q, w_b, f_b, dt=dt), dtype=np.float64)
        lib.gain = self._params.gain_marg
        return np.asarray(lib.updateMARG(q, w_b, f_b, mag_ut, dt=dt), dtype=np.float64)


class _MahonyStreamer(_AhrsStreamer):
    frame_q = _Q_NED_ENU
    estimates_bias = True

    def __init__(self, params: MahonyParams, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._params = params
        self._lib: Any = None

    def _on_start(self) -> None:
        ahrs = import_library("ahrs")
        lib = ahrs.filters.Mahony(b0=self._bias_placeholder.copy())
        # Assigned after construction: the constructor rejects k_I = 0.
        lib.k_P = float(self._params.k_p)
        lib.k_I = float(self._params.k_i)
        self._lib = lib

    def _step(self, q: F64, dt: float, w_b: F64, f_b: F64, mag_ut: F64 | None) -> F64:
        if mag_ut is None:
            return np.asarray(self._lib.updateIMU(q, w_b, f_b, dt=dt), dtype=np.float64)
        return np.asarray(self._lib.updateMARG(q, w_b, f_b, mag_ut, dt=dt), dtype=np.float64)

    def _bias(self) -> F64:
        return np.array(self._lib.b, dtype=np.float64)


class _EkfStreamer(_AhrsStreamer):
    """ahrs EKF in its NED frame. Its measurement model is chosen by whether the filter
    was BUILT with magnetometer data (``self.mag``), not by the ``mag`` argument of
    ``update``: a 6-axis filter runs until the first magnetometer sample, then a 9-axis
    one built with a placeholder ``mag`` takes over, inheriting the covariance ``P``."""

    def __init__(self, params: AhrsEkfParams, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._params = params
        self._ekf6: Any = None
        self._ekf9: Any = None
        mag_n = self._site.mag_n
        self._m_ref: F64 | None = None if mag_n is None else mag_n / np.linalg.norm(mag_n)
        # The EKF's reference field carries the declination, so its frame is true NED: the
        # site's field, or (unknown) one whose horizontal part is at the site's declination.
        d = declination(self._site)
        self._north = np.array([np.cos(d), np.sin(d), 0.0])

    def triad_library_nav(self, f_b: F64, mag_ut: F64 | None) -> F64:
        return triad(f_b, mag_ut, self._north if self._m_ref is None else self._m_ref)

    def _build(self, with_mag: bool, P: F64 | None) -> Any:
        ahrs = import_library("ahrs")
        m_ref = self._m_ref if self._m_ref is not None else self._north
        kw: dict[str, Any] = {
            "frame": "NED",
            "frequency": 1.0 / self._period if self._period else 100.0,
            "magnetic_ref": np.array(m_ref, dtype=np.float64),
            "var_gyr": self._params.var_gyr,
            "var_acc": self._params.var_acc,
            "var_mag": self._params.var_mag,
        }
        if P is not None:
            kw["P"] = P
        if with_mag:
            kw["mag"] = np.zeros((1, 3))  # marks the filter as 9-axis; never computed
        return ahrs.filters.EKF(**kw)

    def _on_start(self) -> None:
        self._ekf6 = self._build(False, None)

    def _on_heading_init(self) -> None:
        self._ekf9 = None  # a fresh 9-axis filter (default P) at the next update
        self._ekf6 = None

    def _ekf_with_mag(self, f_b: F64, mag_ut: F64) -> Any:
        if self._ekf9 is None:
            if self._m_ref is None:
                # Unknown site field: the declination's north, the dip from this sample and
                # gravity (the specific force points up: f.m = -|f||m| sin(dip)).
                cos_fm = float(f_b @ mag_ut) / float(np.linalg.norm(f_b) * np.linalg.norm(mag_ut))
                sin_dip = float(np.clip(-cos_fm, -1.0, 1.0))
                self._m_ref = np.array([*(np.sqrt(1.0 - sin_dip**2) * self._north[:2]), sin_dip])
            P = None if self._ekf6 is None else np.array(self._ekf6.P)
            self._ekf9 = self._build(True, P)
        return self._ekf9

    def _step(self, q: F64, dt: float, w_b: F64, f_b: F64, mag_ut: F64 | None) -> F64:
        # ahrs EKF wants gravity, not specific force: negate the accelerometer.
        if mag_ut is None:
            if self._ekf6 is None:
                self._ekf6 = self._build(False, None)
            return np.asarray(self._ekf6.update(q, w_b, -f_b, dt=dt), dtype=np.float64)
        ekf = self._ekf_with_mag(f_b, mag_ut)
        return np.asarray(ekf.update(q, w_b, -f_b, mag_ut, dt=dt), dtype=np.float64)


# --- estimators ---------------------------------------------------------------------


class AhrsEkf(LibraryEstimator):
    """``ahrs.filters.EKF`` (4-state quaternion EKF, no gyro bias), per sample.

    Converted at the edge: accelerometer negated, magnetometer in microtesla (the filter
    normalises it), the site's field as magnetic reference (true north; when the site
    field is unknown, magnetic north and the dip measured at the first magnetometer
    sample), ``frame='NED'``, measured ``dt`` per sample.
    """

    name: ClassVar[str] = "ahrs-ekf"
    params_type: ClassVar[type] = AhrsEkfParams

    def __init__(self, params: AhrsEkfParams | None = None) -> None:
        self.params = params or AhrsEkfParams()

    def _make_streamer(
        self, site: Site, initial: InitialState | None, use_mag: bool, period: float | None
    ) -> LibraryStreamer:
        return _EkfStreamer(
            self.params,
            self.name,
            site,
            initial=initial,
            use_mag=use_mag,
            period=period,
            magnetic_heading=False,
        )


class Madgwick(LibraryEstimator):
    """``ahrs.filters.Madgwick`` (gradient descent), per sample ``updateMARG`` /
    ``updateIMU``. Raw accelerometer; its frame is NWU (converted to NED); heading from
    magnetic north (rotated by the declination)."""

    name: ClassVar[str] = "madgwick"
    params_type: ClassVar[type] = MadgwickParams

    def __init__(self, params: MadgwickParams | None = None) -> None:
        self.params = params or MadgwickParams()

    def _make_streamer(
        self, site: Site, initial: InitialState | None, use_mag: bool, period: float | None
    ) -> LibraryStreamer:
        return _MadgwickStreamer(
            self.params, self.name, site, initial=initial, use_mag=use_mag, period=period
        )


class Mahony(LibraryEstimator):
    """``ahrs.filters.Mahony`` (explicit complementary filter with gyro bias), per
    sample. Raw accelerometer; its frame is ENU (converted to NED); heading from magnetic
    north (rotated by the declination). ``gyro_bias_b`` is its integral term ``b``."""

    name: ClassVar[str] = "mahony"
    params_type: ClassVar[type] = MahonyParams

    def __init__(self, params: MahonyParams | None = None) -> None:
        self.params = params or MahonyParams()

    def _make_streamer(
        self, site: Site, initial: InitialState | None, use_mag: bool, period: float | None
    ) -> LibraryStreamer:
        return _MahonyStreamer(
            self.params, self.name, site, initial=initial, use_mag=use_mag, period=period
        )
