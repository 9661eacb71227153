"""Error-state process model shared by the MEKF, the air-data MEKF and the INS (SPEC 2.4, 2.5).

Nominal state: attitude ``q_nb``, gyro bias ``bg``, and optionally velocity ``v_n`` (INS),
wind ``wind_n``, accelerometer bias ``ba`` and magnetometer bias ``bm`` (hard iron, tesla).
Error state: body-frame attitude error ``dtheta`` (``q = q_hat * Exp(dtheta)``) and additive
errors of the rest, ordered by a :class:`Layout`.

Discrete model over one IMU step ``dt`` with gyro ``w_m`` and specific force ``f_m``
(the sample at the *end* of the step, see docs/conventions.md)::

    q_k  = q_{k-1} * Exp((w_m - bg) dt)
    v_k  = v_{k-1} + (C_nb(q_k) (f_m - ba) + g_n) dt
    bg, ba, bm, wind: random walks

Error transition (closed forms, SPEC 2.4; the velocity rows differentiate the update
above exactly through ``dtheta_k = Phi11 dtheta_{k-1} + Phi12 dbg``)::

    Phi[att, att] = Phi11 = C(Exp(w dt))^T        Phi[att, bg] = Phi12
    Phi[v, att]   = -C_k [f]x dt Phi11             Phi[v, bg]   = -C_k [f]x dt Phi12
    Phi[v, ba]    = -C_k dt

Process noise: the Farrenkopf closed form for [att, bg] and ``sigma^2 dt`` for the rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from windahrs.rotation import dcm_from_quat, quat_exp, quat_mul, quat_normalize, skew

__all__ = ["BLOCK_SIZES", "Layout", "NominalState", "ProcessNoise", "attitude_transition", "predict"]

F64 = NDArray[np.float64]

BLOCK_SIZES = {"att": 3, "v": 3, "bg": 3, "wind": 3, "ba": 3, "bm": 3}


@dataclass(frozen=True)
class Layout:
    """Which error-state blocks exist, in order: attitude first, gyro bias always present."""

    blocks: tuple[str, ...]

    def __post_init__(self) -> None:
        unique = len(set(self.blocks)) == len(self.blocks)
        if self.blocks[:1] != ("att",) or "bg" not in self.blocks or not unique:
            raise ValueError(f"Layout.blocks: expected 'att' first, 'bg', no repeat; found {self.blocks}")
        for b in self.blocks:
            if b not in BLOCK_SIZES:
                raise ValueError(f"Layout.blocks: expected names from {tuple(BLOCK_SIZES)}, found {b!r}")

    @property
    def dim(self) -> int:
        return sum(BLOCK_SIZES[b] for b in self.blocks)

    def sl(self, block: str) -> slice:
        """Slice of ``block`` in the error vector (KeyError when absent)."""
        start = 0
        for b in self.blocks:
            if b == block:
                return slice(start, start + BLOCK_SIZES[b])
            start += BLOCK_SIZES[b]
        raise KeyError(block)

    def has(self, block: str) -> bool:
        return block in self.blocks

    def labels(self) -> tuple[str, ...]:
        names = {
            "att": ("att_x", "att_y", "att_z"),
            "bg": ("bg_x", "bg_y", "bg_z"),
            "v": ("v_n", "v_e", "v_d"),
            "wind": ("wind_n", "wind_e", "wind_d"),
            "ba": ("ba_x", "ba_y", "ba_z"),
            "bm": ("bm_x", "bm_y", "bm_z"),
        }
        return tuple(lab for b in self.blocks for lab in names[b])


@dataclass(frozen=True)
class NominalState:
    """q_nb (4,), bg (3,) rad/s, and when in the layout: v_n, wind_n (3,) m/s, ba (3,) m/s^2,
    bm (3,) tesla."""

    q_nb: F64
    bg: F64
    v_n: F64 | None = None
    wind_n: F64 | None = None
    ba: F64 | None = None
    bm: F64 | None = None

    def inject(self, layout: Layout, dx: F64) -> NominalState:
        """Apply an error-state correction: ``q * Exp(dtheta)``, additive elsewhere."""
        q = quat_normalize(quat_mul(self.q_nb, quat_exp(dx[layout.sl("att")])))

        def add(name: str, value: F64 | None) -> F64 | None:
            return value + dx[layout.sl(name)] if layout.has(name) and value is not None else value

        return NominalState(
            q_nb=q,
            bg=self.bg + dx[layout.sl("bg")],
            v_n=add("v", self.v_n),
            wind_n=add("wind", self.wind_n),
            ba=add("ba", self.ba),
            bm=add("bm", self.bm),
        )


@dataclass(frozen=True)
class ProcessNoise:
    """Continuous noise densities: gyro rad/s/sqrt(Hz), gyro bias rad/s^2/sqrt(Hz),
    accelerometer m/s^2/sqrt(Hz), horizontal and vertical wind m/s^2/sqrt(Hz),
    accelerometer bias m/s^3/sqrt(Hz), magnetometer bias tesla/s/sqrt(Hz); gyro_scale
    1/sqrt(Hz): rate-proportional gyro noise, the attitude density becomes
    ``gyro^2 + (gyro_scale |w - bg|)^2`` (scale-factor and misalignment errors)."""

    gyro: float
    gyro_bias: float
    accel: float = 0.0
    wind_h: float = 0.0
    wind_v: float = 0.0
    accel_bias: float = 0.0
    mag_bias: float = 0.0
    gyro_scale: float = 0.0


def attitude_transition(w: F64, dt: float) -> tuple[F64, F64]:
    """Phi11 and Phi12 (3x3 each) of the attitude/bias error for rate ``w`` over ``dt``."""
    a = float(np.linalg.norm(w))
    W = skew(w)
    W2 = W @ W
    if a * dt < 1e-6:
        # Series: the closed forms lose precision for tiny rotation angles.
        phi11 = np.eye(3) - dt * W + 0.5 * dt**2 * W2
        phi12 = -dt * np.eye(3) + 0.5 * dt**2 * W - dt**3 / 6.0 * W2
    else:
        s, c = np.sin(a * dt), np.cos(a * dt)
        phi11 = np.eye(3) - s / a * W + (1 - c) / a**2 * W2
        phi12 = -dt * np.eye(3) + (1 - c) / a**2 * W - (a * dt - s) / a**3 * W2
    return phi11, phi12


def predict(
    layout: Layout,
    x: NominalState,
    P: F64,
    w_m: F64,
    f_m: F64,
    dt: float,
    noise: ProcessNoise,
    gravity_n: F64,
) -> tuple[NominalState, F64]:
    """One IMU step of the nominal state and the error covariance (module docstring)."""
    w = w_m - x.bg
    q = quat_normalize(quat_mul(x.q_nb, quat_exp(w * dt)))
    phi11, phi12 = attitude_transition(w, dt)
    n = layout.dim
    Phi = np.eye(n)
    A, B = layout.sl("att"), layout.sl("bg")
    Phi[A, A] = phi11
    Phi[A, B] = phi12
    Q = np.zeros((n, n))
    sg2, sb2 = noise.gyro**2, noise.gyro_bias**2
    if noise.gyro_scale > 0:
        sg2 = sg2 + noise.gyro_scale**2 * (w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    Q[A, A] = (sg2 * dt + sb2 * dt**3 / 3.0) * np.eye(3)
    Q[A, B] = Q[B, A] = -sb2 * dt**2 / 2.0 * np.eye(3)
    Q[B, B] = sb2 * dt * np.eye(3)
    v_n = x.v_n
    if layout.has("v"):
        assert x.v_n is not None
        f = f_m - (x.ba if x.ba is not None else 0.0)
        C = dcm_from_quat(q)
        v_n = x.v_n + (C @ f + gravity_n) * dt
        V = layout.sl("v")
        CFdt = -C @ skew(f) * dt
        Phi[V, A] = CFdt @ phi11
        Phi[V, B] = CFdt @ phi12
        Q[V, V] = noise.accel**2 * dt * np.eye(3)
        if layout.has("ba"):
            Phi[V, layout.sl("ba")] = -C * dt
    if layout.has("wind"):
        Wn = layout.sl("wind")
        Q[Wn, Wn] = np.diag([noise.wind_h**2, noise.wind_h**2, noise.wind_v**2]) * dt
    if layout.has("ba"):
        Ba = layout.sl("ba")
        Q[Ba, Ba] = noise.accel_bias**2 * dt * np.eye(3)
    if layout.has("bm"):
        Bm = layout.sl("bm")
        Q[Bm, Bm] = noise.mag_bias**2 * dt * np.eye(3)
    P_new = Phi @ P @ Phi.T + Q
    P_new = 0.5 * (P_new + P_new.T)
    return NominalState(q_nb=q, bg=x.bg, v_n=v_n, wind_n=x.wind_n, ba=x.ba, bm=x.bm), P_new
