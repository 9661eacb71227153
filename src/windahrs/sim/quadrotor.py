"""Quadrotor holding position or flying waypoints in wind, with linear rotor drag
(SPEC 5.3 and 3.6).

Specific force in the body: ``f_xy = -mu (v_r_b)_xy`` (rotor drag of the air-relative
velocity) and ``f_z = -T/m`` (thrust). A PID position controller with a feed-forward of
the drag it can see commands a specific-force vector; the attitude follows the commanded
thrust direction with a first-order lag ``tau``. Nav acceleration is ``C_nb f_b + g_n``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numba
import numpy as np
from numpy.typing import NDArray

from windahrs.conventions import G0
from windahrs.sim.atmosphere import WindConfig, wind_n
from windahrs.sim.gust_response import rates_from_attitude
from windahrs.sim.sensors import TruthTrajectory

__all__ = ["QuadrotorScenario", "quadrotor_truth"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class QuadrotorScenario:
    """A quadrotor flight. duration s; altitude m; mode "hold" (position hold) or
    "waypoints" (a square of side ``leg`` m flown at ``speed`` m/s); drag mu 1/s;
    attitude lag tau s; yaw rad (held constant)."""

    duration: float = 120.0
    altitude: float = 20.0
    wind: WindConfig = field(default_factory=WindConfig)
    mode: Literal["hold", "waypoints"] = "hold"
    leg: float = 40.0
    speed: float = 3.0
    mu: float = 0.3
    tau: float = 0.08
    yaw: float = 0.0
    position_bandwidth: float = 0.8

    def __post_init__(self) -> None:
        if not (np.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"duration: expected > 0 s, found {self.duration!r}")
        if not (np.isfinite(self.altitude) and 2.0 <= self.altitude <= 1000.0):
            raise ValueError(f"altitude: expected 2 to 1000 m, found {self.altitude!r}")
        if self.mode not in ("hold", "waypoints"):
            raise ValueError(f"mode: expected 'hold' or 'waypoints', found {self.mode!r}")
        for name in ("leg", "speed", "mu", "tau", "position_bandwidth"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name}: expected a finite value > 0, found {v!r}")


def _reference(sc: QuadrotorScenario, t: F64) -> tuple[F64, F64]:
    """Position and velocity references (N, 3) NED."""
    n = len(t)
    p = np.zeros((n, 3))
    v = np.zeros((n, 3))
    p[:, 2] = -sc.altitude
    if sc.mode == "waypoints":
        corners = np.array([[0, 0], [sc.leg, 0], [sc.leg, sc.leg], [0, sc.leg]], dtype=float)
        s = (sc.speed * (t - t[0])) % (4 * sc.leg)
        i = (s // sc.leg).astype(int)
        frac = (s % sc.leg)[:, None]
        a, b = corners[i], corners[(i + 1) % 4]
        p[:, :2] = a + (b - a) * frac / sc.leg
        v[:, :2] = (b - a) / sc.leg * sc.speed
    return p, v


@numba.njit(cache=True)
def _quat_mul1(p: F64, q: F64) -> F64:  # pragma: no cover - compiled
    return np.array(
        [
            p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
            p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
            p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
            p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0],
        ]
    )


@numba.njit(cache=True)
def _dcm1(q: F64) -> F64:  # pragma: no cover - compiled
    w, x, y, z = q[0], q[1], q[2], q[3]
    return np.array(
        [
            [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
        ]
    )


@numba.njit(cache=True)
def _fly(
    t: F64,
    p_ref: F64,
    v_ref: F64,
    wind: F64,
    mean_wind: F64,
    mu: float,
    tau: float,
    yaw: float,
    bw: float,
    g: float,
) -> tuple[F64, F64, F64, F64]:  # pragma: no cover - compiled
    n = t.shape[0]
    q = np.zeros((n, 4))
    v = np.zeros((n, 3))
    p = np.zeros((n, 3))
    a = np.zeros((n, 3))
    # Start trimmed: hovering at the reference, tilted against the initial wind.
    p[0] = p_ref[0]
    v[0] = v_ref[0]
    kp = bw * bw
    kd = 2.0 * 0.8 * bw
    ki = 0.25 * bw * kp
    integ = np.zeros(3)
    cy, sy = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    qyaw = np.array([cy, 0.0, 0.0, sy])
    gvec = np.array([0.0, 0.0, g])
    # Initial attitude: level with the commanded yaw, then let the controller settle
    # over a 5 s pre-roll that is not recorded.
    q_cur = qyaw.copy()
    v_cur = v[0].copy()
    p_cur = p[0].copy()
    dt0 = t[1] - t[0] if n > 1 else 0.005
    pre = int(5.0 / dt0)
    total = pre + n
    for j in range(total):
        k = j - pre
        kk = k if k >= 0 else 0
        dt = dt0 if k <= 0 else t[k] - t[k - 1]
        w_air = wind[kk]
        C = _dcm1(q_cur)
        # Controller: commanded nav specific force (thrust only), with the drag of the mean
        # wind fed forward (a real controller cannot see the gusts); the integral absorbs
        # what the feed-forward misses.
        e_p = p_ref[kk] - p_cur
        e_v = v_ref[kk] - v_cur
        integ += e_p * dt
        a_cmd = kp * e_p + kd * e_v + ki * integ
        v_mean_b = C.T @ (v_cur - mean_wind)
        drag_n = C @ np.array([-mu * v_mean_b[0], -mu * v_mean_b[1], 0.0])
        f_cmd = a_cmd - gvec - drag_n
        # Desired attitude: body z along -f_cmd, with the commanded yaw.
        zb = -f_cmd / np.sqrt(np.sum(f_cmd * f_cmd))
        # Tilt quaternion taking [0,0,1] to zb, composed after the yaw.
        ez = np.array([0.0, 0.0, 1.0])
        axis = np.cross(ez, zb)
        s = np.sqrt(np.sum(axis * axis))
        c = zb[2]
        if s > 1e-12:
            ang = np.arctan2(s, c)
            qt = np.array([np.cos(0.5 * ang), 0.0, 0.0, 0.0])
            qt[1:] = np.sin(0.5 * ang) * axis / s
        else:
            qt = np.array([1.0, 0.0, 0.0, 0.0])
        q_des = _quat_mul1(qt, qyaw)
        # First-order attitude lag: body rate = Log(q^* q_des) / tau.
        qe = _quat_mul1(np.array([q_cur[0], -q_cur[1], -q_cur[2], -q_cur[3]]), q_des)
        if qe[0] < 0:
            qe = -qe
        vn = np.sqrt(qe[1] ** 2 + qe[2] ** 2 + qe[3] ** 2)
        rot = 2.0 * np.arctan2(vn, qe[0]) / vn * qe[1:] if vn > 1e-15 else 2.0 * qe[1:]
        w_b = rot / tau
        phi = w_b * dt
        an = np.sqrt(np.sum(phi * phi))
        dq = np.array([np.cos(0.5 * an), 0.0, 0.0, 0.0])
        dq[1:] = (np.sin(0.5 * an) / an if an > 1e-15 else 0.5) * phi
        q_new = _quat_mul1(q_cur, dq)
        q_new /= np.sqrt(np.sum(q_new * q_new))
        # Thrust magnitude: the commanded specific force along the new body z.
        C = _dcm1(q_new)
        thrust = -(C.T @ f_cmd)[2]
        v_r_b = C.T @ (v_cur - w_air)
        f_b = np.array([-mu * v_r_b[0], -mu * v_r_b[1], -thrust])
        acc = C @ f_b + gvec
        v_new = v_cur + acc * dt
        p_new = p_cur + 0.5 * (v_cur + v_new) * dt
        q_cur, v_cur, p_cur = q_new, v_new, p_new
        if k >= 0:
            q[k] = q_cur
            v[k] = v_cur
            p[k] = p_cur
            a[k] = acc
    return q, v, p, a


def quadrotor_truth(
    sc: QuadrotorScenario, t: F64, rng: np.random.Generator, gravity: float = G0
) -> TruthTrajectory:
    """Truth of a quadrotor flight on the grid ``t`` (N,) s."""
    p_ref, v_ref = _reference(sc, t)
    alt = -p_ref[:, 2]
    mean = sc.wind.mean_n(np.array([sc.altitude]))[0]
    speed = max(float(np.linalg.norm(mean)), 1.0)
    track = np.full(len(t), float(np.arctan2(mean[1], mean[0])))
    mean_n, wd = wind_n(sc.wind, t, alt, sc.altitude, speed, track, rng)
    wind = mean_n + wd
    q, v, p, a = _fly(
        t,
        p_ref,
        v_ref,
        np.ascontiguousarray(wind),
        mean_n[0].copy(),
        sc.mu,
        sc.tau,
        sc.yaw,
        sc.position_bandwidth,
        gravity,
    )
    return TruthTrajectory(
        t=t, q_nb=q, w_b=rates_from_attitude(t, q), a_n=a, v_n=v, p_n=p, wind_n=wind
    )
