"""[usque] Unscented quaternion estimator (SPEC 4.1; Crassidis & Markley, JGCA 26(4), 2003),
written for Hamilton quaternions and a body-frame error.

The state is the attitude ``q_nb`` with the gyro bias; the filter's uncertainty lives in
the 6-dim tangent vector ``[dp, db]``, ``dp`` the generalised Rodrigues parameters (GRP,
a = 1, f = 4) of the body-frame error ``q_true = q_hat * dq(dp)``. With f = 2(a + 1),
``dp = 4 tan(|dtheta|/4) e = dtheta + O(|dtheta|^3)``.

Everything the error-state [mekf] decides is decided the same way here: parameters
(:class:`~windahrs.filters.params.EskfParams`), initialisation (InitialState or TRIAD,
waiting for a magnetometer sample), the process noise (the Farrenkopf closed form of SPEC
2.4), the measurement models and their noise (:mod:`windahrs.models.observations`:
the accelerometer as gravity only, the magnetometer in 3-D or as heading), the
magnetometer reference, the gates (``| |f| - g |`` and the per-component innovation
test) and the innovation log. Only the way the mean and covariance travel through the
models differs: unscented transforms with 2n + 1 = 13 sigma points, lambda = 1.

Sigma-point predictions: by default all 13 points at once (the models' rotation written
out for a batch); ``Usque(reference=True)`` calls the model functions of
:mod:`windahrs.models.observations` once per point instead and keeps only their
prediction (readable, about four times slower). The tests hold the two equal.

The covariance is that of ``[dp, dbg]``; it is reported as the covariance of the
body-frame rotation-vector error (labels ``att_*``) without conversion, since
``dp = dtheta`` to first order (relative difference ``|dtheta|^2/48``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from windahrs.filters.base import Estimator, InitialState, StateView, Streamer, triad
from windahrs.filters.params import EskfParams
from windahrs.flight import Site
from windahrs.models import observations as obs
from windahrs.models.error_state import Layout, NominalState
from windahrs.rotation import (
    dcm_from_quat,
    euler_from_quat,
    quat_conj,
    quat_exp,
    quat_from_euler,
    quat_mul,
    quat_normalize,
)

__all__ = [
    "GRP_A",
    "GRP_F",
    "USQUE_LAMBDA",
    "Usque",
    "UsqueStreamer",
    "grp_from_quat",
    "process_noise",
    "quat_from_grp",
    "sigma_weights",
]

F64 = NDArray[np.float64]


def mag_reference(site: Site, q_nb: F64, mag_b: F64) -> F64:
    """The nav-frame field: the site's, or (unknown site) the first sample's, with its
    horizontal part taken as north."""
    if site.mag_n is not None:
        return site.mag_n.copy()
    m = dcm_from_quat(q_nb) @ mag_b
    return np.array([np.hypot(m[0], m[1]), 0.0, m[2]])
PointModel = Callable[[F64, F64], F64]

#: Generalised Rodrigues parameters: a and f = 2 (a + 1), so that dp ~ dtheta.
GRP_A = 1.0
GRP_F = 2.0 * (GRP_A + 1.0)
#: Sigma-point spread of the 6-dim state (Crassidis & Markley use lambda = 1).
USQUE_LAMBDA = 1.0
_N = 6
_LAYOUT = Layout(("att", "bg"))


def quat_from_grp(dp: ArrayLike) -> F64:
    """Error quaternion (..., 4) from generalised Rodrigues parameters (..., 3) (SPEC 4.1).

    ``|dp| <= 4`` covers every rotation up to 180 deg; larger ``dp`` give the same
    rotations again with ``dq0 < 0``.
    """
    p = np.asarray(dp, dtype=np.float64)
    s = np.einsum("...i,...i->...", p, p)[..., None]
    # SPEC 4.1: dq0 = (-a s + f sqrt(f^2 + (1 - a^2) s)) / (f^2 + s); a = 1 drops the root.
    q0 = (GRP_F * GRP_F - s) / (GRP_F * GRP_F + s)
    return np.concatenate([q0, (GRP_A + q0) * p / GRP_F], axis=-1)


def grp_from_quat(dq: ArrayLike) -> F64:
    """Generalised Rodrigues parameters (..., 3) of unit error quaternions (..., 4).

    ``dq`` and ``-dq`` give the same result (the one with ``dq0 >= 0``: the shorter
    rotation, ``|dp| <= 4``), so the map is defined for every rotation.
    """
    q = np.asarray(dq, dtype=np.float64)
    sign = np.where(q[..., :1] < 0.0, -1.0, 1.0)
    return GRP_F * sign * q[..., 1:] / (GRP_A + sign * q[..., :1])


def sigma_weights(n: int = _N, lam: float = USQUE_LAMBDA) -> F64:
    """Weights (2n + 1,) of the centre and of the +- points: lambda/(n + lambda) and
    1/(2(n + lambda)); the same for the mean and the covariance."""
    w = np.full(2 * n + 1, 0.5 / (n + lam))
    w[0] = lam / (n + lam)
    return w


def process_noise(gyro_noise: float, gyro_bias_noise: float, dt: float) -> F64:
    """Discrete process noise (6, 6) of ``[dtheta, dbg]`` over ``dt`` s (SPEC 2.4, the
    Farrenkopf closed form; the same as the [att, bg] blocks of the error-state model).
    gyro_noise rad/s/sqrt(Hz), gyro_bias_noise rad/s^2/sqrt(Hz)."""
    sg2, sb2 = gyro_noise**2, gyro_bias_noise**2
    Q = np.zeros((_N, _N))
    i = np.arange(3)
    Q[i, i] = sg2 * dt + sb2 * dt**3 / 3.0
    Q[i, i + 3] = Q[i + 3, i] = -sb2 * dt**2 / 2.0
    Q[i + 3, i + 3] = sb2 * dt
    return Q


def _left(q: F64) -> F64:
    """The matrix (4, 4) of ``p -> q * p``: ``quat_mul(q, p) == _left(q) @ p``."""
    w, x, y, z = q
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


def _rotate_inv(Q: F64, r_n: F64) -> F64:
    """``C_bn(q_i) r_n`` (13, 3) for unit quaternions Q (13, 4): the models' prediction
    ``dcm_from_quat(q).T @ r_n`` for all points at once (expanded, as the matrix
    route costs far more than the arithmetic)."""
    w, v = Q[:, :1], Q[:, 1:]
    x, y, z = r_n
    v_cross_r = v @ np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])  # rows v_i x r_n
    radial = (w * w - np.sum(v * v, axis=1, keepdims=True)) * r_n + 2.0 * (v @ r_n)[:, None] * v
    return radial - 2.0 * w * v_cross_r


def _sqrt_cov(P: F64, spread: float) -> F64:
    """A square root ``L`` (6, 6) with ``L L^T = spread P``: Cholesky of the symmetrised
    matrix; if rounding has left it indefinite, the eigen square root with negative
    eigenvalues clipped to zero."""
    A: F64 = spread * 0.5 * (P + P.T)
    try:
        return np.asarray(np.linalg.cholesky(A), dtype=np.float64)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(A)
        return np.asarray(V * np.sqrt(np.clip(w, 0.0, None)), dtype=np.float64)


def _wrap(a: F64) -> F64:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


class UsqueStreamer(Streamer):
    """USQUE fed sample by sample (see the module docstring)."""

    def __init__(
        self,
        name: str,
        params: EskfParams,
        site: Site,
        initial: InitialState | None,
        has: frozenset[str],
        *,
        reference: bool = False,
    ) -> None:
        super().__init__(name)
        self.p = params
        self.site = site
        self.g_n = site.gravity_n
        self.reference = reference
        self.initial = initial
        self.wait_mag = "mag" in has and params.mag_mode != "off" and initial is None
        self.spread = _N + USQUE_LAMBDA
        self.w = sigma_weights()
        self.q: F64 | None = None
        self.bg = np.zeros(3)
        self.P = np.full((_N, _N), np.nan)
        self.mag_n: F64 | None = None
        self.t_imu: float | None = None
        self.f_last: F64 | None = None
        self._first_mag: F64 | None = None

    # -- initialisation (as [mekf]) ----------------------------------------------------
    def _try_init(self) -> None:
        if self.q is not None or self.f_last is None:
            return
        if self.wait_mag and self._first_mag is None:
            return
        p, ini = self.p, self.initial
        if ini is not None:
            q = quat_normalize(np.asarray(ini.q_nb, dtype=np.float64))
        else:
            q = triad(self.f_last, self._first_mag, self.site.mag_n)
        if ini is not None and ini.gyro_bias_b is not None:
            self.bg = np.asarray(ini.gyro_bias_b, dtype=np.float64).copy()
        s_att = p.init_att if ini is None or ini.sigma_att is None else ini.sigma_att
        s_bias = p.init_bias if ini is None or ini.sigma_bias is None else ini.sigma_bias
        self.q = q
        self.P = np.diag([s_att**2] * 3 + [s_bias**2] * 3)
        if self._first_mag is not None or self.site.mag_n is not None:
            self.mag_n = mag_reference(
                self.site, q, self._first_mag if self._first_mag is not None else np.zeros(3)
            )

    # -- sigma points --------------------------------------------------------------------
    def _sigma(self) -> tuple[F64, F64, F64]:
        """Offsets (13, 6) ``0, +-columns of sqrt((n + lambda) P)`` and the points they
        make about the current estimate: q (13, 4), bg (13, 3)."""
        assert self.q is not None
        L = _sqrt_cov(self.P, self.spread)
        S = np.zeros((2 * _N + 1, _N))
        S[1 : _N + 1] = L.T
        S[_N + 1 :] = -L.T
        Q = quat_from_grp(S[:, :3]) @ _left(self.q).T
        return S, Q, self.bg + S[:, 3:]

    def _propagate(self, w_b: F64, dt: float) -> None:
        """SPEC 4.1 steps 1-4."""
        _, Q, B = self._sigma()
        Q = quat_mul(Q, quat_exp((w_b - B) * dt))
        # Errors relative to the propagated centre (dp_0 = 0 exactly).
        X = np.empty((2 * _N + 1, _N))
        X[:, :3] = grp_from_quat(Q @ _left(quat_conj(Q[0])).T)
        X[0, :3] = 0.0
        X[:, 3:] = B
        x = self.w @ X
        D = X - x
        P = (D.T * self.w) @ D + process_noise(self.p.gyro_noise, self.p.gyro_bias_noise, dt)
        self.P = 0.5 * (P + P.T)
        self.q = quat_normalize(_left(Q[0]) @ quat_from_grp(x[:3]))
        self.bg = x[3:]

    def _update(
        self, sensor: str, t: float, z: F64, h: PointModel, R: F64, gate: float, *, angle: bool = False
    ) -> bool:
        """SPEC 4.1 step 5 for one measurement ``z`` (m,) with the point model ``h``
        (q (13, 4), bg (13, 3)) -> (13, m), noise ``R`` (m, m) and the per-component gate.
        ``angle``: z is an angle (differences wrapped to +-pi)."""
        S, Q, B = self._sigma()
        Y = h(Q, B)
        if angle:
            Y = Y[0] + _wrap(Y - Y[0])
        y = self.w @ Y
        dY = Y - y
        Pyy = (dY.T * self.w) @ dY + R
        Pxy = (S.T * self.w) @ dY
        nu = _wrap(z - y) if angle else z - y
        # One solve for the NIS and the gain: Pyy^-1 [nu, Pxy^T].
        sol = np.linalg.solve(Pyy, np.column_stack([nu, Pxy.T]))
        nis = float(nu @ sol[:, 0])
        accepted = bool(np.all(nu**2 <= gate**2 * np.diag(Pyy)))
        self._log(sensor, t, nu, nis, accepted)
        if not accepted:
            return False
        K = sol[:, 1:].T
        dx = K @ nu
        P = self.P - K @ Pyy @ K.T
        self.P = 0.5 * (P + P.T)
        assert self.q is not None
        self.q = quat_normalize(_left(self.q) @ quat_from_grp(dx[:3]))
        self.bg = self.bg + dx[3:]
        return True

    def _points(self, model: Callable[[NominalState], F64], batch: PointModel) -> PointModel:
        """The point model: ``batch`` or, for the reference, ``model`` called per point."""
        if not self.reference:
            return batch

        def loop(Q: F64, B: F64) -> F64:
            return np.array([model(NominalState(q_nb=Q[i], bg=B[i])) for i in range(len(Q))])

        return loop

    # -- sensors ---------------------------------------------------------------------------
    def _imu(self, t: float, w_b: F64, f_b: F64) -> None:
        self.f_last = f_b
        if self.q is None:
            self._try_init()
            self.t_imu = t
            return
        assert self.t_imu is not None
        dt = t - self.t_imu
        self.t_imu = t
        if dt > 0:
            self._propagate(w_b, dt)
        self._fuse_accel(t, f_b)

    def _fuse_accel(self, t: float, f_b: F64) -> None:
        p = self.p
        g_n = self.g_n
        if abs(np.linalg.norm(f_b) - g_n[2]) > p.accel_norm_gate * g_n[2]:
            self._log("accel", t, np.full(3, np.nan), np.nan, False)
            return
        h = self._points(
            lambda x: obs.specific_force(_LAYOUT, x, g_n)[0],
            lambda Q, B: _rotate_inv(Q, -g_n),
        )
        self._update("accel", t, f_b, h, p.accel_sigma**2 * np.eye(3), p.gate_accel)

    def _mag(self, t: float, mag_b: F64) -> None:
        if self.q is None:
            if self._first_mag is None:
                self._first_mag = mag_b
            self._try_init()
            return
        p = self.p
        if p.mag_mode == "off":
            return
        if self.mag_n is None:
            self.mag_n = mag_reference(self.site, self.q, mag_b)
        m_n = self.mag_n
        if p.mag_mode == "3d":
            h = self._points(
                lambda x: obs.vector_body(_LAYOUT, x, m_n)[0],
                lambda Q, B: _rotate_inv(Q, m_n),
            )
            self._update("mag", t, mag_b, h, p.mag_sigma**2 * np.eye(3), p.gate_mag)
            return
        # Heading only, as [mekf]: tilt-compensate with the current roll/pitch estimate.
        roll, pitch, _ = euler_from_quat(self.q)
        m_h = dcm_from_quat(quat_from_euler([roll, pitch, 0.0])) @ mag_b
        decl = float(np.arctan2(m_n[1], m_n[0]))
        psi_m = np.array([decl - np.arctan2(m_h[1], m_h[0])])
        h = self._points(lambda x: obs.heading(_LAYOUT, x)[0], lambda Q, B: euler_from_quat(Q)[:, 2:])
        sigma = p.mag_sigma / max(float(np.hypot(m_n[0], m_n[1])), 1e-9)
        self._update("mag", t, psi_m, h, np.array([[sigma**2]]), p.gate_mag, angle=True)

    @property
    def state(self) -> StateView:
        # P is the covariance of [dp, dbg]; with f = 4, dp = dtheta + O(|dtheta|^3), so it
        # is reported as the covariance of the body-frame rotation-vector error as is.
        if self.q is None:
            q = triad(self.f_last, None, None) if self.f_last is not None else np.array([1.0, 0, 0, 0])
            return StateView(
                t=self._t_last,
                q_nb=q,
                gyro_bias_b=np.zeros(3),
                v_n=None,
                wind_n=None,
                cov=np.full((_N, _N), np.nan),
                state_labels=_LAYOUT.labels(),
            )
        return StateView(
            t=self._t_last,
            q_nb=self.q.copy(),
            gyro_bias_b=self.bg.copy(),
            v_n=None,
            wind_n=None,
            cov=self.P.copy(),
            state_labels=_LAYOUT.labels(),
        )


class Usque(Estimator):
    """[usque] unscented quaternion estimator: attitude and gyro bias; accelerometer
    (gravity, gated) and magnetometer, with the models, noise and gates of [mekf].

    params: :class:`EskfParams` (the fields of [mekf]; accel_compensation must be "none":
    this filter fuses no GNSS or air data to compensate with). reference: predict the
    sigma points with one call of the measurement model per point (see module docstring).
    """

    name: ClassVar[str] = "usque"
    requires: ClassVar[frozenset[str]] = frozenset({"imu"})
    uses: ClassVar[frozenset[str]] = frozenset({"imu", "mag"})
    default_params: ClassVar[EskfParams] = EskfParams()

    def __init__(self, params: EskfParams | None = None, *, reference: bool = False) -> None:
        p = params if params is not None else self.default_params
        if not isinstance(p, EskfParams):
            raise TypeError(f"params: expected EskfParams, found {type(p).__name__}")
        if p.accel_compensation != "none":
            raise ValueError(
                "accel_compensation: expected 'none' ([usque] fuses no GNSS or air data to "
                f"compensate the accelerometer with), found {p.accel_compensation!r}"
            )
        self.params = p
        self.reference = reference

    def streamer(
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> UsqueStreamer:
        return UsqueStreamer(self.name, self.params, site, initial, has, reference=self.reference)
