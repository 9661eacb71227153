"""Adapter for ``imufusion`` (xioTechnologies/Fusion, Python bindings 1.3).

Fusion wants the gyroscope in DEGREES per second, the accelerometer in g (our specific
force divided by standard gravity) and the magnetometer in any calibrated unit
(microtesla here). It computes in single precision. Its update takes no time step: the
adapter calls ``set_sample_period(dt)`` before every update with the measured interval.
``AhrsSettings(convention=...)`` is SILENTLY ignored by the bindings (the keyword is
parsed and dropped): the adapter assigns ``settings.convention = CONVENTION_NED`` after
construction, otherwise the output is NWU (a 180 deg roll in NED). ``sample_rate`` sets
the length of the start-up ramp (3 s of high gain, counted in samples) and turns the
rejection timeout (s) into samples: it must be the real rate (default 100 Hz).
Heading is from magnetic north; the adapter rotates it by the site's declination.
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
    check_rate,
    import_library,
)
from windahrs.conventions import G0
from windahrs.filters.base import InitialState
from windahrs.flight import Site

__all__ = ["ImuFusion", "ImuFusionParams"]

F64 = NDArray[np.float64]
_DEG_PER_RAD = 180.0 / np.pi


@dataclass(frozen=True)
class ImuFusionParams:
    """Fusion AHRS settings (library defaults).

    rate: IMU sample rate, Hz (Fusion's ``sample_rate``); None takes the flight's median
    rate in ``run`` and the first interval when streaming.
    gain: complementary-filter gain (0.5). gyroscope_range: deg/s, 0 = no over-range
    detection. acceleration_rejection, magnetic_rejection: deg, 0 = off (the library's
    README suggests 10 and 20). rejection_timeout: s, 0 = rejection off.
    use_mag: "auto", "required" or "off" (6-axis).
    """

    rate: float | None = None
    gain: float = 0.5
    gyroscope_range: float = 0.0
    acceleration_rejection: float = 0.0
    magnetic_rejection: float = 0.0
    rejection_timeout: float = 0.0
    use_mag: MagMode = "auto"

    def __post_init__(self) -> None:
        check_rate("ImuFusionParams", self.rate)
        check_number("ImuFusionParams", "gain", self.gain, strict=False)
        for name in (
            "gyroscope_range",
            "acceleration_rejection",
            "magnetic_rejection",
            "rejection_timeout",
        ):
            check_number("ImuFusionParams", name, getattr(self, name), strict=False)
        if self.acceleration_rejection > 90.0 or self.magnetic_rejection > 90.0:
            raise ValueError(
                "ImuFusionParams.acceleration_rejection/magnetic_rejection: expected "
                f"at most 90 deg, found {self.acceleration_rejection!r}, "
                f"{self.magnetic_rejection!r}"
            )
        check_mag_mode("ImuFusionParams", self.use_mag)


class _ImufusionStreamer(LibraryStreamer):
    needs_period = True

    def __init__(self, params: ImuFusionParams, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._params = params
        self._lib: Any = None

    def _start(self, w_b: F64, f_b: F64, mag_ut: F64 | None) -> None:
        imufusion = import_library("imufusion")
        assert self._period is not None
        p = self._params
        settings = imufusion.AhrsSettings()
        # Assigned one by one: the constructor drops its `convention` keyword.
        settings.convention = imufusion.CONVENTION_NED
        settings.sample_rate = 1.0 / self._period
        settings.gain = p.gain
        settings.gyroscope_range = p.gyroscope_range
        settings.acceleration_rejection = p.acceleration_rejection
        settings.magnetic_rejection = p.magnetic_rejection
        settings.rejection_timeout = p.rejection_timeout
        if settings.convention != imufusion.CONVENTION_NED:  # pragma: no cover
            raise RuntimeError("imufusion: could not set the NED convention")
        lib = imufusion.Ahrs()
        lib.set_settings(settings)
        if self._initial is not None:
            # Known attitude: no start-up ramp (whose 6-axis update would also zero the
            # heading while it lasts).
            lib.set_quaternion(np.ascontiguousarray(self._q_placeholder))
            lib.skip_startup()
        self._lib = lib
        self._update(self._period, w_b, f_b, mag_ut)

    def _update(self, dt: float, w_b: F64, f_b: F64, mag_ut: F64 | None) -> None:
        lib = self._lib
        lib.set_sample_period(dt)
        gyro = w_b * _DEG_PER_RAD
        acc = f_b / G0
        if mag_ut is None:
            lib.update_no_magnetometer(gyro, acc)
        else:
            lib.update(gyro, acc, mag_ut)

    def _q_lib(self) -> F64:
        return np.asarray(self._lib.get_quaternion(), dtype=np.float64)


class ImuFusion(LibraryEstimator):
    """``imufusion.Ahrs`` (Madgwick's revised complementary filter with start-up ramp
    and optional rejection), per sample, NED convention. No gyro bias estimate (Fusion's
    separate ``Bias`` corrects offsets only at rest)."""

    name: ClassVar[str] = "imufusion"
    params_type: ClassVar[type] = ImuFusionParams

    def __init__(self, params: ImuFusionParams | None = None) -> None:
        self.params = params or ImuFusionParams()

    def _make_streamer(
        self, site: Site, initial: InitialState | None, use_mag: bool, period: float | None
    ) -> LibraryStreamer:
        return _ImufusionStreamer(
            self.params, self.name, site, initial=initial, use_mag=use_mag, period=period
        )
