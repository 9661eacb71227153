"""The shipped models linearised at a given state: the compiled error-state prediction
(:func:`windahrs.core.predict._predict_es`) as ``Phi P Phi^T + Q``, and each aid source's
measurement Jacobian H and noise R (:mod:`windahrs.aid`), for an error-state
:class:`~windahrs.models.error_state.Layout` of one's choosing. This is how the posterior
Cramér-Rao bound (:mod:`windahrs.pcrb`) evaluates the filters' own models on the truth.

Error state (SPEC 2.4): body-frame attitude error ``q = q_hat * Exp(dtheta)`` first, then
the additive errors of the layout's other blocks in its order; units SI (rad, m/s, rad/s,
m/s^2, tesla). The kernels assume the attitude at column 0 and the velocity, when present,
at column 3 (as :func:`windahrs.core.kernel.layout_for` lays them out).

How: one :class:`~windahrs.core.layout.KernelState` is built for the layout and reused; each
call writes the nominal state (and P) into it in place and runs the shipped function. The
aid sources run with their gates at NaN sigmas, so that they compute the innovation, H on
their support columns and R, log a rejection and leave the state alone (H is read from the
scratch rows, zeroed before each call, so columns outside the support are exactly 0); the
accelerometer's norm gate and the magnetometer's disturbance gates are off.

Example::

    lin = Linearization(Layout(("att", "bg")), EskfParams(), site)
    lin.set_state(q_nb)
    H, R = lin.gravity()                  # (3, 6), (3, 3)
    P1 = lin.predict(P0, w_b, f_b, dt)    # (6, 6); the nominal state is propagated
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from windahrs.aid.air_vector import fuse_air_vector
from windahrs.aid.air_velocity import remember_air
from windahrs.aid.gnss_vel import fuse_gnss
from windahrs.aid.gravity import fuse_gravity
from windahrs.aid.mag import fuse_mag
from windahrs.aid.sideslip import fuse_sideslip
from windahrs.aid.tas import fuse_tas
from windahrs.core import layout as K
from windahrs.core.kernel import Kind, make_state
from windahrs.core.predict import _predict_es
from windahrs.filters.params import EskfParams
from windahrs.flight import Site
from windahrs.models.error_state import Layout

__all__ = ["Linearization"]

F64 = NDArray[np.float64]

#: The process-noise parameters of the prediction (zeroed for Phi alone).
_PROCESS_NOISE = (
    "gyro_noise2", "gyro_bias_noise2", "accel_noise2", "accel_bias_noise2", "wind_noise2", "wind_noise_vertical2",
    "mag_bias_noise2", "gyro_scale_noise2", "gyro_bias_noise_dv2",
)  # fmt: skip
#: The innovation gates, squared sigmas: NaN rejects every sample whatever its innovation.
_GATES = ("gate_accel2", "gate_mag2", "gate_gnss2", "gate_air2", "gate_drag2")


class Linearization:
    """The shipped prediction and aid sources of an error-state filter with ``layout``,
    ``params`` (:class:`~windahrs.filters.params.EskfParams`: its process noise densities
    and measurement sigmas give Q and R; its gates are ignored) and ``site`` (gravity; the
    Earth field for the magnetometer, tesla, NED).

    Mutable: :meth:`set_state` sets the nominal state every later call linearises at;
    :meth:`predict` propagates it. ``st`` is the KernelState (arrays written in place).
    """

    def __init__(self, layout: Layout, params: EskfParams, site: Site) -> None:
        kind: Kind = "ins-wind" if layout.has("v") else "mekf-air" if layout.has("wind") else "mekf"
        caps = np.ones(K.N_SENSORS, dtype=np.int64)  # one log row per sensor, reset per call
        st = make_state(kind, False, params, site, None, frozenset(), caps, layout=layout)
        for g in _GATES:
            st.prm[g] = math.nan
        st.prm["accel_norm_gate"] = math.inf
        st.prm["mag_norm_gate"] = st.prm["mag_dip_gate"] = 0.0
        st.flags[K.S_INIT] = 1
        if site.mag_n is not None:
            st.x[K.X_MAGN : K.X_MAGN + 3] = site.mag_n
            st.flags[K.S_MAGN] = 1
        self.layout = layout
        self.st = st
        self.dim = layout.dim
        self._row = np.zeros(8)  # a sample row of the aid sources
        self._gravity = float(site.gravity)

    # --- state ------------------------------------------------------------------------

    def set_state(
        self,
        q_nb: ArrayLike,
        *,
        v_n: ArrayLike | None = None,
        bg: ArrayLike | None = None,
        wind_n: ArrayLike | None = None,
        ba: ArrayLike | None = None,
        bm: ArrayLike | None = None,
    ) -> None:
        """The nominal state: q_nb (4,) scalar first, body to NED; v_n, wind_n (3,) m/s
        NED; bg (3,) rad/s; ba (3,) m/s^2; bm (3,) tesla. None sets zeros (a block outside
        the layout is ignored by the models, except v_n: without a velocity state it is the
        air-data models' velocity input, the last GNSS velocity)."""
        x = self.st.x
        x[K.X_Q : K.X_Q + 4] = q_nb
        for i, value in ((K.X_V, v_n), (K.X_VGNSS, v_n), (K.X_BG, bg), (K.X_W, wind_n), (K.X_BA, ba), (K.X_BM, bm)):
            x[i : i + 3] = 0.0 if value is None else value

    @property
    def q_nb(self) -> F64:
        """The nominal attitude (4,) (a copy)."""
        return self.st.x[K.X_Q : K.X_Q + 4].copy()

    # --- process model ----------------------------------------------------------------

    def predict(self, P: F64, w_b: ArrayLike, f_b: ArrayLike, dt: float) -> F64:
        """``Phi P Phi^T + Q`` (dim, dim) over one IMU step of dt s with the gyro sample w_b
        (3,) rad/s and the specific force f_b (3,) m/s^2 (body; the sample at the end of
        the step, SPEC 2.4), from P (dim, dim) at the nominal state, which is propagated
        (attitude; velocity with the INS layout)."""
        st, n = self.st, self.dim
        st.P[:n, :n] = P
        w, f = np.asarray(w_b, dtype=np.float64), np.asarray(f_b, dtype=np.float64)
        _predict_es(st.cfg, st.prm, st.x, st.P, st.work, w[0], w[1], w[2], f[0], f[1], f[2], float(dt))
        return st.P[:n, :n].copy()

    def transition(self, w_b: ArrayLike, f_b: ArrayLike, dt: float) -> tuple[F64, F64]:
        """(Phi, Q) (dim, dim) each of the same step at the nominal state (left unchanged):
        Q is the prediction of P = 0; column i of Phi is that of the noise-free prediction
        of ``e_i e_i^T``, ``Phi e_i (Phi e_i)^T``, over the square root of its diagonal
        entry (so the diagonal of Phi is taken positive: |w dt| < pi/2). For tests; the
        bound uses :meth:`predict`."""
        st, n = self.st, self.dim
        x0 = st.x.copy()
        Q = self.predict(np.zeros((n, n)), w_b, f_b, dt)
        noise = {f: float(st.prm[f]) for f in _PROCESS_NOISE}
        for f in _PROCESS_NOISE:
            st.prm[f] = 0.0
        Phi = np.empty((n, n))
        try:
            for i in range(n):
                st.x[:] = x0
                E = np.zeros((n, n))
                E[i, i] = 1.0
                M = self.predict(E, w_b, f_b, dt)
                Phi[:, i] = M[:, i] / math.sqrt(M[i, i])
        finally:
            for f, v in noise.items():
                st.prm[f] = v
            st.x[:] = x0
        return Phi, Q

    # --- aid sources ------------------------------------------------------------------

    def _begin(self) -> None:
        st = self.st
        st.flags[K.L_CNT : K.L_CNT + K.N_SENSORS] = 0  # room in the logs
        st.work[K.W_H : K.W_H + 3] = 0.0

    def _out(self, m: int) -> tuple[F64, F64]:
        w = self.st.work
        return w[K.W_H : K.W_H + m, : self.dim].copy(), w[K.W_R : K.W_R + m, :m].copy()

    def gravity(self) -> tuple[F64, F64]:
        """The accelerometer as a gravity measurement (aid.gravity): H (3, dim), R (3, 3)
        (m/s^2)^2 = accel_sigma^2 I."""
        st = self.st
        self._begin()
        row = self._row
        row[:] = 0.0
        row[5] = -self._gravity
        fuse_gravity(*st[:9], 0.0, row, 0.0)
        return self._out(3)

    def mag(self) -> tuple[F64, F64]:
        """The magnetometer (aid.mag) in the params' mode: 3-D, H (3, dim), R (3, 3) tesla^2
        = mag_sigma^2 I; heading, H (1, dim), R (1, 1) rad^2."""
        st = self.st
        if st.cfg["mag_mode"] == K.MAG_OFF or st.flags[K.S_MAGN] == 0:
            raise ValueError("mag: expected params.mag_mode other than 'off' and a site with mag_n")
        self._begin()
        m = 3 if st.cfg["mag_mode"] == K.MAG_3D else 1
        self._row[:3] = st.x[K.X_MAGN : K.X_MAGN + 3]  # (any sample: the innovation is not used)
        fuse_mag(*st[:9], 0.0, self._row)
        return self._out(m)

    def gnss(self) -> tuple[F64, F64]:
        """GNSS velocity (aid.gnss_vel; a layout with "v"): H (3, dim), R (3, 3) (m/s)^2 =
        gnss_sigma^2 I."""
        if not self.layout.has("v"):
            raise ValueError("gnss: expected a layout with a velocity block")
        self._begin()
        self._row[:] = 0.0
        fuse_gnss(*self.st[:9], 0.0, self._row)
        return self._out(3)

    def _air(self, tas: float, aoa: float, sideslip: float) -> tuple[bool, float, float, float, float]:
        if not self.layout.has("wind"):
            raise ValueError("air data: expected a layout with a wind block")
        self._begin()
        st = self.st
        if not self.layout.has("v"):
            st.flags[K.S_VGNSS] = 1  # (the velocity input: the last GNSS velocity, x[X_VGNSS])
        return remember_air(st.x, st.flags, float(tas), float(aoa), float(sideslip))

    def air_vector(self, tas: float, aoa: float, sideslip: float) -> tuple[F64, F64]:
        """The air-relative velocity from pitot and vanes (aid.air_vector; a layout with
        "wind"), at the sample's airspeed tas m/s, angle of attack and sideslip rad: H (3,
        dim), R (3, 3) (m/s)^2 = J diag(tas_sigma^2, vane_sigma^2, vane_sigma^2) J^T."""
        _, ca, sa, cb, sb = self._air(tas, aoa, sideslip)
        fuse_air_vector(*self.st[:9], 0.0, float(tas), ca, sa, cb, sb, self.layout.has("v"), 0.0)
        return self._out(3)

    def tas(self, tas: float) -> tuple[F64, F64]:
        """True airspeed (aid.tas; a layout with "wind"): H (1, dim) with no attitude
        columns, R (1, 1) (m/s)^2 = tas_sigma^2."""
        self._air(tas, math.nan, math.nan)
        fuse_tas(*self.st[:9], 0.0, float(tas), self.layout.has("v"), 0.0)
        return self._out(1)

    def sideslip(self) -> tuple[F64, F64]:
        """The synthetic zero sideslip (aid.sideslip; a layout with "wind"): H (1, dim),
        R (1, 1) rad^2 = sideslip_sigma^2."""
        self._air(0.0, math.nan, math.nan)
        fuse_sideslip(*self.st[:9], 0.0, 0.0, self.layout.has("v"), 0.0)
        return self._out(1)
