"""The airspeed scale, estimated on line: a small EKF beside the filter, as PX4's airspeed
selector runs one (``AirspeedValidator``'s ``WindEstimator``, src/lib/wind_estimator), causal,
run at every air sample before the air-data aid sources.

A pitot reads the dynamic pressure at its own port: its position error, a bent or partly
blocked tube and the calibration of the transducer make the airspeed it reports a few to
30 % off the true airspeed (PX4 ASPD_SCALE, ArduPilot ARSPD_RATIO). Fused as if right, such
an airspeed bends the wind: the wind then takes up the missing airspeed along the heading.
The scale is observable from the wind triangle as the vehicle turns: the ground velocity
less a constant wind has one length at every heading only with the right scale.

States: the horizontal wind N, E (m/s) and the inverse scale ``k = measured / true``
airspeed (PX4's ``tas_scale`` state, in which the measurement is linear):

* prediction: random walks, ``airspeed_scale_wind_noise`` m/s^2/sqrt(Hz) (PX4
  ASPD_WIND_NSD, 0.1) and ``airspeed_scale_noise`` 1/s/sqrt(Hz) (ASPD_SCALE_NSD, 1e-4);
* airspeed: ``tas_m = k |v_n - W|`` (vertical wind 0; v_n the filter's velocity, or the
  last GNSS velocity for [mekf-air]), R = airspeed_scale_tas_sigma^2 (ASPD_TAS_NOISE,
  1.4 m/s: the wind here is a slow random walk, so turbulence is measurement noise), gated
  at :data:`TAS_GATE` sigmas (ASPD_TAS_GATE);
* sideslip (with synthetic_sideslip, or the vane's when the flight has one): ``beta =
  V_y / V_x`` of ``C_bn (v_n - W)`` at the filter's attitude, R =
  airspeed_scale_beta_sigma^2 (ASPD_BETA_NOISE, 0.15 rad), gated at :data:`BETA_GATE`
  (ASPD_BETA_GATE): it ties the wind to the heading, so that the airspeed's length fixes
  the scale;
* initial state: k = 1 with the standard deviation airspeed_scale_sigma (0.3: a pitot 30 %
  off either way), the wind from the first sample's triangle with the spread the scale's
  uncertainty gives it along the heading (``W = v - C_nb V_air / k``: ``dW/dk = C_nb V_air``)
  plus the airspeed's and the sideslip's.

The filter then fuses ``tas_m / k`` (and the air-data vector scaled alike), its variance
increased by the scale's, ``(tas_m / k)^2 var(k) / k^2``, so a scale still uncertain does not
bend the filter's wind. Each air sample logs the scale ``1 / k``, its standard deviation and
the airspeed's innovation in the ``"aspd"`` log (``Estimate.airspeed_scale``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from windahrs.core.kalman import (
    _log,
)
from windahrs.core.layout import (
    _JIT_CORE,
    INN_ASPD,
    W_NU,
    X_Q,
    X_V,
    X_VAIR,
    X_VGNSS,
    record_dtype,
)
from windahrs.core.quat import (
    _dcm9,
)

#: The parameters of this estimator (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = (
    "airspeed_scale",
    "airspeed_scale_sigma",
    "airspeed_scale_noise",
    "airspeed_scale_wind_noise",
    "airspeed_scale_tas_sigma",
    "airspeed_scale_beta_sigma",
)

#: Gate of its airspeed, sigmas: PX4 ASPD_TAS_GATE (4).
TAS_GATE = 4.0
#: Gate of its sideslip, sigmas: PX4 ASPD_BETA_GATE (1).
BETA_GATE = 1.0

#: The estimator's state (KernelState.asc, a (1,) array of :data:`ASC`): float64 fields, then
#: an int64 flag, as the flat state and flags they came from. (name, size, meaning)
ASC_FIELDS: tuple[tuple[str, int, str], ...] = (
    ("k", 3, "wind N, E m/s, inverse scale (measured / true)"),
    ("P", 9, "its covariance, row-major"),
    ("t", 1, "time of its last update, s"),
)
ASC_FLAG_FIELDS: tuple[tuple[str, int, str], ...] = (("ready", 1, "1: initialised"),)
ASC = np.dtype(record_dtype(ASC_FIELDS).descr + record_dtype(ASC_FLAG_FIELDS, np.int64).descr)


def asc_state() -> NDArray[np.void]:
    """A fresh estimator state: not initialised."""
    return np.zeros(1, ASC)


@njit(**_JIT_CORE)
def _update(ac, H0, H1, H2, nu, r, gate):
    """One scalar update of the 3-state estimator; H = (H0, H1, H2). Returns
    (accepted, nis). ac: the estimator's record (:data:`ASC`)."""
    P = ac["P"]
    ph0 = P[0] * H0 + P[1] * H1 + P[2] * H2  # P H^T
    ph1 = P[3] * H0 + P[4] * H1 + P[5] * H2
    ph2 = P[6] * H0 + P[7] * H1 + P[8] * H2
    s = H0 * ph0 + H1 * ph1 + H2 * ph2 + r
    nis = nu * nu / s
    if nis > gate * gate:
        return False, nis
    ac["k"][0] += ph0 / s * nu
    ac["k"][1] += ph1 / s * nu
    ac["k"][2] += ph2 / s * nu
    # P <- P - K S K^T = P - (P H^T)(P H^T)^T / s: symmetric by construction (PX4's
    # WindEstimator updates its 3x3 P in this form too)
    ph = (ph0, ph1, ph2)
    for i in range(3):
        for j in range(3):
            P[3 * i + j] -= ph[i] * ph[j] / s
    return True, nis


@njit(**_JIT_CORE)
def _init(prm, x, ac, c, vn, ve, tas, t):
    """Initialise from the sample's air velocity (X_VAIR, scale 1) at the attitude c (C_nb
    row-major) and the ground velocity vn, ve m/s."""
    ax, ay, az = x[X_VAIR], x[X_VAIR + 1], x[X_VAIR + 2]
    an = c[0] * ax + c[1] * ay + c[2] * az
    ae = c[3] * ax + c[4] * ay + c[5] * az
    ac["k"][0], ac["k"][1], ac["k"][2] = vn - an, ve - ae, 1.0
    pk = prm["asc_init_var"]
    own = prm["asc_tas_var"] + tas * tas * prm["asc_beta_var"]
    P = ac["P"]
    P[0], P[1], P[3], P[4] = an * an * pk + own, an * ae * pk, an * ae * pk, ae * ae * pk + own
    P[2], P[6], P[5], P[7] = an * pk, an * pk, ae * pk, ae * pk
    P[8] = pk
    ac["t"] = t
    ac["ready"] = 1


@njit(**_JIT_CORE)
def airspeed_scale_step(prm, x, flags, ac, inn, acc, cfg, work, t, tas, beta, syn, use_v):
    """The estimator at an air sample: tas m/s measured, beta rad the sideslip vane's (NaN:
    none; syn: fuse a zero sideslip then), at t s; X_VAIR holds the sample's air velocity
    at scale 1. Returns (the airspeed corrected, tas / k, m/s; the variance its scale adds
    (m/s)^2); logs the scale in the "aspd" log. ac: the estimator's record (:data:`ASC`)."""
    c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    vv = X_V if use_v else X_VGNSS
    vn, ve, vd = x[vv], x[vv + 1], x[vv + 2]
    if ac["ready"] == 0:
        _init(prm, x, ac, c, vn, ve, tas, t)
    P = ac["P"]
    dt = t - ac["t"]
    if dt > 0:
        P[0] += prm["asc_wn2"] * dt
        P[4] += prm["asc_wn2"] * dt
        P[8] += prm["asc_kn2"] * dt
        ac["t"] = t
    # airspeed: tas = k |v - W|
    un, ue = vn - ac["k"][0], ve - ac["k"][1]
    n = max(math.sqrt(un * un + ue * ue + vd * vd), 1e-3)
    k = ac["k"][2]
    nu_tas = tas - k * n
    ok, nis = _update(ac, -k * un / n, -k * ue / n, n, nu_tas, prm["asc_tas_var"], TAS_GATE)
    # sideslip: beta = V_y / V_x of C_bn (v - W)
    if syn or math.isfinite(beta):
        un, ue = vn - ac["k"][0], ve - ac["k"][1]
        ux = c[0] * un + c[3] * ue + c[6] * vd
        uy = c[1] * un + c[4] * ue + c[7] * vd
        if ux > 1.0:  # flying forward through the air
            b = beta if math.isfinite(beta) else 0.0
            h0 = -(c[1] / ux - uy * c[0] / (ux * ux))
            h1 = -(c[4] / ux - uy * c[3] / (ux * ux))
            _update(ac, h0, h1, 0.0, b - uy / ux, prm["asc_beta_var"], BETA_GATE)
    k = max(ac["k"][2], 0.1)  # (a pitot reading a tenth of the airspeed is no pitot)
    nu = work[W_NU]
    nu[0], nu[1], nu[2] = 1.0 / k, math.sqrt(max(P[8], 0.0)) / (k * k), nu_tas
    _log(cfg, flags, inn, acc, nu, np.int64(INN_ASPD), t, np.int64(3), nis, ok)
    tc = tas / k
    return tc, tc * tc * P[8] / (k * k)
