"""Error-state Kalman filters, readable reference implementation (SPEC 2.4, 2.5, 3).

Three estimators share one core:

* [mekf]: attitude error and gyro bias; accelerometer as a gravity measurement (gated on
  ``|f|`` and on its innovation, optionally compensated by GNSS velocity differences or by
  ``w x V_air``), magnetometer in 3-D or heading only. Its defaults (:data:`MEKF_FIELD`)
  fuse the means of the specific force and of the field in an almost inertial frame
  (``accel_lowpass``, ``mag_lowpass``), add rate-proportional gyro noise and take only the
  heading, about the vertical, from the magnetometer when the site's field is unknown.
* [mekf-air]: the paper's idea done right: [mekf] plus wind states, fusing the air-data
  vector ``C_bn (V_gnss - W)`` (pitot and vanes) or, with a pitot alone, true airspeed and
  a synthetic zero sideslip; the accelerometer is compensated by ``w x V_air``.
* [ins-wind]: the accelerometer as an input; attitude, velocity, gyro bias, wind (and
  optionally accelerometer bias); fuses GNSS velocity, magnetometer and air data. The
  recommended estimator.

Each may carry magnetometer-bias (hard-iron) states with a 3-D magnetometer
(``init_mag_bias > 0``; the [ins-wind] default).

The compiled twins live in :mod:`windahrs.filters.compiled` and are tested equal to this
code sample by sample.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import NDArray

from windahrs.filters.base import Estimator, InitialState, StateView, Streamer, triad
from windahrs.filters.params import EskfParams
from windahrs.flight import Site
from windahrs.models import observations as obs
from windahrs.models.error_state import Layout, NominalState, ProcessNoise, predict
from windahrs.rotation import air_direction, dcm_from_quat, euler_from_quat, quat_exp, quat_from_euler

__all__ = ["MEKF_FIELD", "EskfStreamer", "InsWind", "Mekf", "MekfAir", "effective_mag_mode", "layout_for"]

F64 = NDArray[np.float64]
Kind = Literal["mekf", "mekf-air", "ins-wind"]


def mag_reference(site: Site, q_nb: F64, mag_b: F64) -> F64:
    """The nav-frame field: the site's, or (unknown site) the first sample's, with its
    horizontal part taken as north."""
    if site.mag_n is not None:
        return site.mag_n.copy()
    m = dcm_from_quat(q_nb) @ mag_b
    return np.array([np.hypot(m[0], m[1]), 0.0, m[2]])


def effective_mag_mode(params: EskfParams, site: Site) -> Literal["3d", "heading", "off"]:
    """How the magnetometer is fused: ``params.mag_mode``, except "3d" becomes "heading"
    with ``mag_3d_needs_site`` when the site's field is unknown (its dip would come from
    one sample)."""
    if params.mag_mode == "3d" and params.mag_3d_needs_site and site.mag_n is None:
        return "heading"
    return params.mag_mode


def lowpass_gain(dt: float, tau: float) -> float:
    """Weight of a new sample in a first-order low-pass of time constant tau after dt."""
    return float(1.0 - np.exp(-dt / tau)) if dt > 0 else 0.0


def layout_for(kind: Kind, params: EskfParams, *, additive: bool = False) -> Layout:
    """The error-state blocks of ``kind`` with ``params`` (the one rule, shared with the
    compiled twins): [ins-wind] adds velocity and (accel_bias_noise > 0) accelerometer
    bias; [mekf-air] and [ins-wind] wind; every kind a magnetometer bias when
    ``init_mag_bias > 0`` with the 3-D magnetometer, except the quaternion-additive
    filters (``additive``: [ekf7], [ekf10])."""
    blocks = ["att", "bg"]
    if kind == "ins-wind":
        blocks.insert(1, "v")
    if kind in ("mekf-air", "ins-wind"):
        blocks.append("wind")
    if kind == "ins-wind" and params.accel_bias_noise > 0:
        blocks.append("ba")
    if params.init_mag_bias > 0 and params.mag_mode == "3d" and not additive:
        blocks.append("bm")
    return Layout(tuple(blocks))


class EskfStreamer(Streamer):
    """The shared error-state core, fed sample by sample."""

    #: the quaternion-additive subclass ([ekf7], [ekf10]) sets this
    additive: ClassVar[bool] = False

    def __init__(
        self,
        name: str,
        kind: Kind,
        params: EskfParams,
        site: Site,
        initial: InitialState | None,
        has: frozenset[str],
    ) -> None:
        super().__init__(name)
        self.kind = kind
        self.p = params
        self.site = site
        self.g_n = site.gravity_n
        self.layout = layout_for(kind, params, additive=self.additive)
        self.noise = ProcessNoise(
            gyro=params.gyro_noise,
            gyro_bias=params.gyro_bias_noise,
            accel=params.accel_noise,
            wind_h=params.wind_noise,
            wind_v=params.wind_noise_vertical,
            accel_bias=params.accel_bias_noise,
            mag_bias=params.mag_bias_noise,
            gyro_scale=params.gyro_scale_noise,
        )
        self.initial = initial
        self.wait_mag = "mag" in has and params.mag_mode != "off" and initial is None
        self.wait_gnss = kind == "ins-wind" and (initial is None or initial.v_n is None)
        self.x: NominalState | None = None
        self.P = np.zeros((0, 0))
        self.mag_n: F64 | None = None
        self.t_imu: float | None = None
        self.f_last: F64 | None = None
        self.w_last = np.zeros(3)
        self.v_gnss: F64 | None = None
        self.t_gnss: float | None = None
        self.a_gnss_n: F64 | None = None
        self.v_air_b: F64 | None = None
        self._first_mag: F64 | None = None
        self._first_v: F64 | None = None
        # low-passed specific force and magnetic field (body frame, rotated by the gyro)
        self.f_bar: F64 | None = None
        self.m_bar: F64 | None = None
        self.t_mbar = 0.0
        self.mag_fusion = effective_mag_mode(params, site)

    # -- initialisation ---------------------------------------------------------------
    def _try_init(self) -> None:
        if self.x is not None or self.f_last is None:
            return
        if self.wait_mag and self._first_mag is None:
            return
        if self.wait_gnss and self._first_v is None:
            return
        p, ini, L = self.p, self.initial, self.layout
        if ini is not None:
            q = np.asarray(ini.q_nb, dtype=np.float64)
        else:
            q = triad(self.f_last, self._first_mag, self.site.mag_n)
        bg = np.zeros(3) if ini is None or ini.gyro_bias_b is None else np.asarray(ini.gyro_bias_b, float)
        v = None
        if L.has("v"):
            v = np.array(ini.v_n if ini is not None and ini.v_n is not None else self._first_v, dtype=float)
        wind = None
        if L.has("wind"):
            wind = np.zeros(3) if ini is None or ini.wind_n is None else np.asarray(ini.wind_n, float)
        ba = np.zeros(3) if L.has("ba") else None
        bm = np.zeros(3) if L.has("bm") else None
        self.x = NominalState(q_nb=q, bg=bg, v_n=v, wind_n=wind, ba=ba, bm=bm)

        def sig(given: float | None, default: float) -> float:
            return default if given is None else given

        d = np.zeros(L.dim)
        d[L.sl("att")] = sig(ini.sigma_att if ini else None, p.init_att) ** 2
        d[L.sl("bg")] = sig(ini.sigma_bias if ini else None, p.init_bias) ** 2
        if L.has("v"):
            d[L.sl("v")] = sig(ini.sigma_v if ini else None, p.init_v if ini is None else p.gnss_sigma) ** 2
        if L.has("wind"):
            d[L.sl("wind")] = sig(ini.sigma_wind if ini else None, p.init_wind) ** 2
        if L.has("ba"):
            d[L.sl("ba")] = p.init_accel_bias**2
        if L.has("bm"):
            d[L.sl("bm")] = p.init_mag_bias**2
        self.P = np.diag(d)
        if self._first_mag is not None or self.site.mag_n is not None:
            self.mag_n = mag_reference(
                self.site, q, self._first_mag if self._first_mag is not None else np.zeros(3)
            )
        if p.accel_lowpass > 0:
            self.f_bar = np.array(self.f_last, dtype=float)
        self._init_wind_pending = L.has("wind") and (ini is None or ini.wind_n is None)

    # -- generic prediction and update -------------------------------------------------
    def _predict(self, w_b: F64, f_b: F64, dt: float) -> None:
        assert self.x is not None
        self.x, self.P = predict(self.layout, self.x, self.P, w_b, f_b, dt, self.noise, self.g_n)

    def _fuse(self, sensor: str, t: float, nu: F64, H: F64, R: F64, gate: float) -> bool:
        assert self.x is not None
        S = H @ self.P @ H.T + R
        nis = float(nu @ np.linalg.solve(S, nu))
        accepted = bool(np.all(nu**2 <= gate**2 * np.diag(S)))
        self._log(sensor, t, nu, nis, accepted)
        if not accepted:
            return False
        K = np.linalg.solve(S, H @ self.P).T
        IKH = np.eye(self.layout.dim) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T
        self.P = 0.5 * (self.P + self.P.T)
        self.x = self.x.inject(self.layout, K @ nu)
        return True

    # -- sensors ----------------------------------------------------------------------
    def _imu(self, t: float, w_b: F64, f_b: F64) -> None:
        self.f_last = f_b
        if self.x is None:
            self._try_init()
            self.t_imu = t
            self.w_last = w_b
            return
        assert self.t_imu is not None
        dt = t - self.t_imu
        self.t_imu = t
        self.w_last = w_b
        if dt > 0:
            self._rotate_lowpass(w_b, dt)
            self._predict(w_b, f_b, dt)
        if self.kind != "ins-wind":
            self._fuse_accel(t, w_b, f_b, dt)

    def _rotate_lowpass(self, w_b: F64, dt: float) -> None:
        """Carry the low-passed vectors into the new body frame: ``v <- C(Exp(w dt))^T v``
        with the bias-corrected rate of the prediction (nav-fixed vectors stay fixed)."""
        if self.f_bar is None and self.m_bar is None:
            return
        assert self.x is not None
        Ct = dcm_from_quat(quat_exp((w_b - self.x.bg) * dt)).T
        if self.f_bar is not None:
            self.f_bar = Ct @ self.f_bar
        if self.m_bar is not None:
            self.m_bar = Ct @ self.m_bar

    def _fuse_accel(self, t: float, w_b: F64, f_b: F64, dt: float) -> None:
        assert self.x is not None
        p = self.p
        g = self.g_n[2]
        a_b = None
        comp = "airspeed" if self.kind == "mekf-air" else p.accel_compensation
        if comp == "airspeed" and self.v_air_b is not None:
            a_b = np.cross(w_b - self.x.bg, self.v_air_b)
        elif comp == "gnss" and self.a_gnss_n is not None:
            a_b = dcm_from_quat(self.x.q_nb).T @ self.a_gnss_n
        if self.f_bar is not None:
            # the mean of the compensated specific force is the gravity measurement
            f_c = f_b if a_b is None else f_b - a_b
            self.f_bar = self.f_bar + lowpass_gain(dt, p.accel_lowpass) * (f_c - self.f_bar)
            f_b, a_b = self.f_bar, None
        if abs(np.linalg.norm(f_b) - g) > p.accel_norm_gate * g:
            self._log("accel", t, np.full(3, np.nan), np.nan, False)
            return
        h, H = obs.specific_force(self.layout, self.x, self.g_n, a_b)
        self._fuse("accel", t, f_b - h, H, p.accel_sigma**2 * np.eye(3), p.gate_accel)

    def _mag(self, t: float, mag_b: F64) -> None:
        if self.x is None:
            if self._first_mag is None:
                self._first_mag = mag_b
            self._try_init()
            return
        mode = self.mag_fusion
        if mode == "off":
            return
        if self.mag_n is None:
            self.mag_n = mag_reference(self.site, self.x.q_nb, mag_b)
        p = self.p
        if p.mag_lowpass > 0:
            if self.m_bar is None:
                self.m_bar = np.array(mag_b, dtype=float)
            else:
                self.m_bar = self.m_bar + lowpass_gain(t - self.t_mbar, p.mag_lowpass) * (mag_b - self.m_bar)
            self.t_mbar = t
            mag_b = self.m_bar
        if self._mag_disturbed(mag_b):
            self._log("mag", t, np.full(3 if mode == "3d" else 1, np.nan), np.nan, False)
            return
        if mode == "3d":
            h, H = obs.magnetometer(self.layout, self.x, self.mag_n)
            self._fuse("mag", t, mag_b - h, H, self.p.mag_sigma**2 * np.eye(3), self.p.gate_mag)
            return
        sigma = self.p.mag_sigma / max(float(np.hypot(self.mag_n[0], self.mag_n[1])), 1e-9)
        if p.heading_model == "vertical":
            # The field's heading in the nav frame against the reference's; a correction
            # about the nav vertical only: H_att = (C_bn e3)^T, the third row of C_nb.
            C = dcm_from_quat(self.x.q_nb)
            m_n = C @ mag_b
            psi = float(np.arctan2(self.mag_n[1], self.mag_n[0]) - np.arctan2(m_n[1], m_n[0]))
            H = np.zeros((1, self.layout.dim))
            H[0, self.layout.sl("att")] = C[2]
            nu = np.array([(psi + np.pi) % (2 * np.pi) - np.pi])
            self._fuse("mag", t, nu, H, np.array([[sigma**2]]), self.p.gate_mag)
            return
        # Heading only (ZYX yaw): tilt-compensate with the current roll/pitch estimate.
        roll, pitch, _ = euler_from_quat(self.x.q_nb)
        m_h = dcm_from_quat(quat_from_euler([roll, pitch, 0.0])) @ mag_b
        decl = float(np.arctan2(self.mag_n[1], self.mag_n[0]))
        psi_m = decl - np.arctan2(m_h[1], m_h[0])
        h, H = obs.heading(self.layout, self.x)
        nu = np.array([(psi_m - h[0] + np.pi) % (2 * np.pi) - np.pi])
        self._fuse("mag", t, nu, H, np.array([[sigma**2]]), self.p.gate_mag)

    def _mag_disturbed(self, mag_b: F64) -> bool:
        """The magnetic disturbance checks (mag_norm_gate, mag_dip_gate) on the field to be
        fused, hard iron removed when it is a state."""
        p = self.p
        if p.mag_norm_gate <= 0 and p.mag_dip_gate <= 0:
            return False
        assert self.x is not None and self.mag_n is not None
        m = mag_b - self.x.bm if self.x.bm is not None else mag_b
        r = self.mag_n
        r_norm = float(np.linalg.norm(r))
        if p.mag_norm_gate > 0 and abs(float(np.linalg.norm(m)) - r_norm) > p.mag_norm_gate * r_norm:
            return True
        if p.mag_dip_gate > 0:
            m_n = dcm_from_quat(self.x.q_nb) @ m
            dip = np.arctan2(m_n[2], np.hypot(m_n[0], m_n[1]))
            if abs(float(dip - np.arctan2(r[2], np.hypot(r[0], r[1])))) > p.mag_dip_gate:
                return True
        return False

    def _gnss(self, t: float, v_n: F64) -> None:
        if self.t_gnss is not None and self.v_gnss is not None and t > self.t_gnss:
            self.a_gnss_n = (v_n - self.v_gnss) / (t - self.t_gnss)
        self.v_gnss, self.t_gnss = v_n, t
        if self.x is None:
            if self._first_v is None:
                self._first_v = v_n
            self._try_init()
            return
        if self.kind == "ins-wind":
            h, H = obs.gnss_velocity(self.layout, self.x)
            self._fuse("gnss", t, v_n - h, H, self.p.gnss_sigma**2 * np.eye(3), self.p.gate_gnss)

    def _air(self, t: float, tas: float, aoa: float, sideslip: float) -> None:
        vanes = np.isfinite(aoa) and np.isfinite(sideslip)
        self.v_air_b = tas * air_direction(aoa, sideslip) if vanes else np.array([tas, 0.0, 0.0])
        if self.x is None or self.kind == "mekf" or self.p.air_mode == "off":
            return
        v_in = None
        extra = 0.0
        if self.kind == "mekf-air":
            if self.v_gnss is None:
                return
            v_in = self.v_gnss
            extra = self.p.gnss_sigma**2
        if getattr(self, "_init_wind_pending", False):
            self._init_wind(v_in, vanes)
        mode = self.p.air_mode
        if mode == "auto":
            mode = "vector" if vanes else "airspeed"
        p = self.p
        if mode == "vector" and vanes:
            z = self.v_air_b
            h, H = obs.air_velocity(self.layout, self.x, v_in)
            J = obs.air_direction_jacobian(tas, aoa, sideslip)
            R = J @ np.diag([p.tas_sigma**2, p.vane_sigma**2, p.vane_sigma**2]) @ J.T + extra * np.eye(3)
            self._fuse("air", t, z - h, H, R, p.gate_air)
            return
        h, H = obs.airspeed(self.layout, self.x, v_in)
        self._fuse("tas", t, np.array([tas]) - h, H, np.array([[p.tas_sigma**2 + extra]]), p.gate_air)
        if p.synthetic_sideslip:
            h, H = obs.sideslip(self.layout, self.x, v_in)
            r = p.sideslip_sigma**2 + extra / max(tas, 1.0) ** 2
            self._fuse("sideslip", t, -h, H, np.array([[r]]), p.gate_air)

    def _init_wind(self, v_in: F64 | None, vanes: bool) -> None:
        """Wind from the first air-data sample: ``W = V - C_nb V_air`` (SPEC 2.6)."""
        assert self.x is not None and self.v_air_b is not None
        v = self.x.v_n if self.x.v_n is not None else v_in
        if v is None:
            return
        w = v - dcm_from_quat(self.x.q_nb) @ self.v_air_b
        if not vanes:
            w[2] = 0.0
        self.x = dataclasses.replace(self.x, wind_n=w)
        self._init_wind_pending = False

    @property
    def state(self) -> StateView:
        if self.x is None:
            q = triad(self.f_last, None, None) if self.f_last is not None else np.array([1.0, 0, 0, 0])
            n = self.layout.dim
            return StateView(
                t=self._t_last,
                q_nb=q,
                gyro_bias_b=np.zeros(3),
                v_n=np.full(3, np.nan) if self.layout.has("v") else None,
                wind_n=np.full(3, np.nan) if self.layout.has("wind") else None,
                cov=np.full((n, n), np.nan),
                state_labels=self.layout.labels(),
            )
        return StateView(
            t=self._t_last,
            q_nb=self.x.q_nb.copy(),
            gyro_bias_b=self.x.bg.copy(),
            v_n=None if self.x.v_n is None else self.x.v_n.copy(),
            wind_n=None if self.x.wind_n is None else self.x.wind_n.copy(),
            cov=self._tangent_cov(),
            state_labels=self.layout.labels(),
        )

    def _tangent_cov(self) -> F64:
        """The error-state covariance in the tangent space of the layout."""
        return self.P.copy()


class _EskfEstimator(Estimator):
    kind: ClassVar[Kind]
    default_params: ClassVar[EskfParams] = EskfParams()

    def __init__(self, params: EskfParams | None = None) -> None:
        self.params = params if params is not None else self.default_params

    def streamer(
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> EskfStreamer:
        return EskfStreamer(self.name, self.kind, self.params, site, initial, has)


#: [mekf]'s defaults for a 9-D AHRS in the field (handheld, robots, vehicles; BROAD-type
#: motion): gravity and field as means in an almost inertial frame (3 s, 9 s, VQF's time
#: constants), rate-proportional gyro noise, heading-only magnetometer about the vertical
#: when the site's field is unknown, magnetic disturbance checks (10 %, 10 deg).
MEKF_FIELD = EskfParams(
    accel_lowpass=3.0,
    gyro_scale_noise=1e-3,
    mag_3d_needs_site=True,
    heading_model="vertical",
    mag_lowpass=9.0,
    mag_norm_gate=0.1,
    mag_dip_gate=float(np.radians(10.0)),
)


class Mekf(_EskfEstimator):
    """[mekf] error-state EKF: attitude error and gyro bias; accelerometer (gravity, gated)
    and magnetometer. Reference implementation. Defaults: :data:`MEKF_FIELD`."""

    name = "mekf"
    kind = "mekf"
    requires = frozenset({"imu"})
    uses = frozenset({"imu", "mag", "gnss", "air"})
    default_params = MEKF_FIELD


class MekfAir(_EskfEstimator):
    """[mekf-air] [mekf] plus wind states fusing air data with GNSS velocity as input."""

    name = "mekf-air"
    kind = "mekf-air"
    requires = frozenset({"imu", "air", "gnss"})
    uses = frozenset({"imu", "mag", "gnss", "air"})
    default_params = EskfParams(accel_compensation="airspeed")


class InsWind(_EskfEstimator):
    """[ins-wind] error-state INS with wind states: the recommended estimator."""

    name = "ins-wind"
    kind = "ins-wind"
    requires = frozenset({"imu", "gnss"})
    uses = frozenset({"imu", "mag", "gnss", "air"})
    default_params = EskfParams(init_mag_bias=1e-6)
