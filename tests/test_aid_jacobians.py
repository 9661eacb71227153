"""Every aid source's analytic Jacobian against central finite differences of its own
innovation, on the shipped (compiled) functions of windahrs.aid.

Each aid source is called with its gate at 0 sigmas, so that it computes the innovation
``nu = z - h(x)``, the Jacobian H on its support columns and R, logs the rejection and
leaves the state alone; ``h(x) = z - nu``. The state is perturbed on its manifold (the
attitude by a body-frame rotation ``q Exp(dtheta)``, the rest additively)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from windahrs.aid.air_vector import fuse_air_vector
from windahrs.aid.air_velocity import remember_air
from windahrs.aid.aoa import fuse_aoa
from windahrs.aid.drag import fuse_drag
from windahrs.aid.gnss_vel import fuse_gnss
from windahrs.aid.gravity import fuse_gravity
from windahrs.aid.mag import fuse_mag
from windahrs.aid.sideslip import fuse_sideslip
from windahrs.aid.tas import fuse_tas
from windahrs.core import layout as K
from windahrs.core.kernel import layout_for, make_state
from windahrs.filters.params import EskfParams
from windahrs.flight import Site
from windahrs.rotation import quat_exp, quat_mul, quat_normalize

SITE = Site(mag_n=np.array([20e-6, -3e-6, 45e-6]))
STEP = 1e-6
#: (kind, parameters) of the layouts: [att, bg], [att, bg, wind], the full INS with biases.
LAYOUTS = {
    "mekf": ("mekf", EskfParams()),
    "mekf-bm": ("mekf", EskfParams(init_mag_bias=1e-6)),
    "mekf-air": ("mekf-air", EskfParams()),
    "ins": ("ins-wind", EskfParams(init_mag_bias=1e-6)),
}
ZERO_GATES = {k: 0.0 for k in ("gate_accel2", "gate_mag2", "gate_gnss2", "gate_air2", "gate_drag2")}


def _state(kind: str, params: EskfParams, rng: np.random.Generator):  # type: ignore[no-untyped-def]
    st = make_state(kind, False, params, SITE, None, frozenset({"imu", "mag", "gnss", "air"}),
                    np.full(K.N_SENSORS, 4, dtype=np.int64))  # fmt: skip
    for name in ZERO_GATES:
        st.prm[name] = 0.0
    st.flags[K.S_INIT] = st.flags[K.S_MAGN] = st.flags[K.S_VGNSS] = 1
    x = st.x
    x[K.X_Q : K.X_Q + 4] = quat_normalize(rng.normal(size=4))
    x[K.X_BG : K.X_BG + 3] = rng.normal(size=3) * 0.01
    x[K.X_V : K.X_V + 3] = rng.normal(size=3) * 3 + [12.0, 0, 0]
    x[K.X_W : K.X_W + 3] = rng.normal(size=3) * 3
    x[K.X_BA : K.X_BA + 3] = rng.normal(size=3) * 0.1
    x[K.X_BM : K.X_BM + 3] = rng.normal(size=3) * 1e-6
    x[K.X_MAGN : K.X_MAGN + 3] = SITE.mag_n
    x[K.X_VGNSS : K.X_VGNSS + 3] = rng.normal(size=3) * 3 + [12.0, 0, 0]
    n = int(st.cfg["n"])
    st.P[:n, :n] = np.eye(n) * 0.01
    return st


def _inject(st, dx: np.ndarray):  # type: ignore[no-untyped-def]
    """A copy of the state perturbed by the error vector dx (layout order)."""
    st2 = st._replace(x=st.x.copy(), work=st.work.copy(), sup=st.sup.copy(), flags=st.flags.copy())
    x, cfg = st2.x, st2.cfg
    x[K.X_Q : K.X_Q + 4] = quat_mul(x[K.X_Q : K.X_Q + 4], quat_exp(dx[0:3]))
    for c_idx, x_idx in (("i_v", K.X_V), ("i_bg", K.X_BG), ("i_w", K.X_W), ("i_ba", K.X_BA), ("i_bm", K.X_BM)):
        i = int(cfg[c_idx])
        if i >= 0:
            x[x_idx : x_idx + 3] += dx[i : i + 3]
    return st2


def _h_and_H(st, aid: str, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """h(x) (m,) and H (m, dim) of one aid source at the state."""
    cfg, prm, x, flags, P, work, sup, inn, acc = st[:9]
    flags[K.L_CNT : K.L_CNT + K.N_SENSORS] = 0  # room in the logs
    if aid == "gravity":
        fuse_gravity(cfg, prm, x, flags, P, work, sup, inn, acc, 0.0, np.r_[np.zeros(3), z], 0.01)
    elif aid == "mag":
        fuse_mag(cfg, prm, x, flags, P, work, sup, inn, acc, 0.0, z)
    elif aid == "gnss":
        fuse_gnss(cfg, prm, x, flags, P, work, sup, inn, acc, 0.0, z)
    elif aid == "drag":
        fuse_drag(cfg, prm, x, flags, P, work, sup, inn, acc, 0.0, np.r_[np.zeros(3), z, 0.0])
    else:
        tas, aoa, beta = 15.0, 0.05, -0.03
        use_v = bool(cfg["i_v"] >= 0)
        _, ca, sa, cb, sb = remember_air(x, flags, tas, aoa, beta)
        if aid == "air":
            fuse_air_vector(cfg, prm, x, flags, P, work, sup, inn, acc, 0.0, tas, ca, sa, cb, sb, use_v, 0.0)
        elif aid == "tas":
            fuse_tas(cfg, prm, x, flags, P, work, sup, inn, acc, 0.0, tas, use_v, 0.0)
        elif aid == "aoa":
            fuse_aoa(cfg, prm, x, flags, P, work, sup, inn, acc, 0.0, aoa, tas, use_v, 0.0)
        else:
            fuse_sideslip(cfg, prm, x, flags, P, work, sup, inn, acc, 0.0, tas, use_v, 0.0)
        z = {"air": x[K.X_VAIR : K.X_VAIR + 3].copy(), "tas": np.array([tas]), "sideslip": np.zeros(1),
             "aoa": np.array([aoa])}[aid]
    m = len(z)
    dim = int(cfg["dim"])
    H = np.zeros((m, dim))
    # the support: the columns of row 0 of sup that the aid source wrote (the rest of H is 0)
    nsup = {"gravity": 6 if cfg["i_ba"] >= 0 else 3, "mag": 6 if cfg["i_bm"] >= 0 else 3, "gnss": 3}
    cols = sorted({int(c) for c in sup[0, : nsup.get(aid, 11)] if 0 <= c < dim})
    for c in cols:
        H[:, c] = work[K.W_H : K.W_H + m, c]
    nu = work[K.W_NU, :m].copy()
    return z - nu, H


CASES = [
    ("mekf", "gravity"), ("mekf", "mag"), ("mekf-bm", "mag"), ("mekf-air", "air"), ("mekf-air", "tas"),
    ("mekf-air", "sideslip"), ("ins", "gnss"), ("ins", "air"), ("ins", "tas"), ("ins", "sideslip"),
    ("ins", "mag"), ("ins", "drag"), ("mekf-air", "aoa"), ("ins", "aoa"),
]  # fmt: skip


@pytest.mark.parametrize(("layout", "aid"), CASES)
def test_jacobian_matches_finite_differences(layout: str, aid: str) -> None:
    kind, params = LAYOUTS[layout]
    if aid == "drag":
        params = params.replace(drag=True, drag_bcoef_x=30.0, drag_bcoef_y=60.0)
    if aid == "gravity":
        params = params.replace(accel_bias_noise=0.0)
    dim = layout_for(kind, params).dim  # type: ignore[arg-type]
    rng = np.random.default_rng(7)
    for _ in range(5):
        st = _state(kind, params, rng)
        z = {"gravity": [0.3, -0.2, -9.7], "mag": [21e-6, -2e-6, 44e-6], "gnss": [12.0, 1.0, -0.5], "drag": [-1.0, 0.4]}
        z0 = np.array(z.get(aid, [0.0]), dtype=float)
        h, H = _h_and_H(st, aid, z0)
        H_fd = np.empty_like(H)
        for j in range(dim):
            e = np.zeros(dim)
            e[j] = STEP
            hp, _ = _h_and_H(_inject(st, e), aid, z0)
            hm, _ = _h_and_H(_inject(st, -e), aid, z0)
            H_fd[:, j] = (hp - hm) / (2 * STEP)
        scale = float(np.abs(H_fd).max())
        floor = 1e-8 * float(np.abs(h).max())
        assert np.abs(H - H_fd).max() <= 1e-6 * scale + floor, (aid, np.abs(H - H_fd).max(), scale)


def test_airspeed_carries_no_attitude_information() -> None:
    kind, params = LAYOUTS["ins"]
    _, H = _h_and_H(_state(kind, params, np.random.default_rng(3)), "tas", np.zeros(1))
    assert np.all(H[:, :3] == 0)
    assert math.isfinite(float(np.abs(H).sum())) and np.abs(H).sum() > 0
