"""Posterior Cramér-Rao bound (SPEC 6): the recursion equals the Kalman covariance on a
linear model, the flight bound is that recursion on the filters' own Jacobians, the
matched [mekf] attains it, the INS bound does not see the wind, and information only adds."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import block_diag

from trajectories import flight_in_place
from windahrs.core.linearize import Linearization
from windahrs.filters.base import InitialState
from windahrs.filters.eskf import Mekf
from windahrs.filters.params import EskfParams, matched_to
from windahrs.flight import Flight, Truth
from windahrs.pcrb import (
    PcrbNoise,
    efficiency_ratio,
    pcrb,
    pcrb_average,
    pcrb_layout,
    pcrb_recursion,
)
from windahrs.rotation import quat_conj, quat_exp, quat_log, quat_mul
from windahrs.sim.atmosphere import WindConfig
from windahrs.sim.fixedwing import FixedWingScenario
from windahrs.sim.gust_response import rates_from_attitude
from windahrs.sim.scenario import simulate
from windahrs.sim.sensors import AccelModel, MagModel, SensorSuite

# White-noise suite of the consistency tests: no accelerometer bias, no hard iron.
WHITE = SensorSuite(
    imu_rate=100.0,
    accel=AccelModel(bias_init_sigma=0.0),
    mag=MagModel(rate=20.0, hard_iron=0.0),
    gnss=None,
    pitot=None,
    vanes=None,
)
SIGMA_ATT = np.radians(2.0)


def loewner_min(big: np.ndarray, small: np.ndarray) -> float:
    """Smallest eigenvalue over all steps of ``big - small`` scaled by ``big``'s diagonal
    (a congruence, so its sign is the Loewner order's; scale-free across units)."""
    d = np.sqrt(np.diagonal(big, axis1=1, axis2=2))
    diff = (big - small) / (d[:, :, None] * d[:, None, :])
    return float(np.linalg.eigvalsh(diff).min())


# --- (a) the recursion on a linear-Gaussian model --------------------------------------


def test_recursion_equals_kalman_covariance_and_information_form_on_a_linear_model() -> None:
    """Constant velocity in 1-D, position measured at most steps, singular Q (white
    acceleration held over each step) and varying steps."""
    rng = np.random.default_rng(0)
    N = 200
    dts = rng.uniform(0.05, 0.2, N - 1)
    Phis = np.array([[[1.0, dt], [0.0, 1.0]] for dt in dts])
    Qs = np.array([0.3**2 * np.outer([dt**2 / 2, dt], [dt**2 / 2, dt]) for dt in dts])  # rank 1
    Hs: list[np.ndarray | None] = []
    Rs: list[np.ndarray | None] = []
    for k in range(N):
        if k % 7 == 3:
            Hs.append(None)
            Rs.append(None)
        else:
            Hs.append(np.array([[1.0, 0.0]]))
            Rs.append(np.array([[rng.uniform(0.5, 2.0) ** 2]]))
    P0 = np.diag([4.0, 1.0])
    bound = pcrb_recursion(Phis, Qs, Hs, Rs, P0)

    # Independent Kalman covariance loop (short form).
    P = P0.copy()
    kf = []
    for k in range(N):
        if k > 0:
            P = Phis[k - 1] @ P @ Phis[k - 1].T + Qs[k - 1]
        if Hs[k] is not None:
            H, R = Hs[k], Rs[k]
            K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
            P = (np.eye(2) - K @ H) @ P
        kf.append(P)
    kf_a = np.array(kf)

    # Tichavský's information recursion, literally (singular Q is fine).
    J = np.linalg.inv(P0)
    info = []
    for k in range(N):
        if k > 0:
            J = np.linalg.inv(Phis[k - 1] @ np.linalg.inv(J) @ Phis[k - 1].T + Qs[k - 1])
        if Hs[k] is not None:
            J = J + Hs[k].T @ np.linalg.inv(Rs[k]) @ Hs[k]
        info.append(np.linalg.inv(J))
    info_a = np.array(info)

    scale = np.abs(bound).max(axis=(1, 2))[:, None, None]
    assert np.abs(bound - kf_a).max() / scale.min() < 1e-12
    assert (np.abs(bound - kf_a) / scale).max() < 1e-12
    assert (np.abs(bound - info_a) / scale).max() < 1e-12
    # No measurement: the prior only grows.
    assert bound[3, 0, 0] > bound[2, 0, 0]


def test_recursion_rejects_mismatched_inputs() -> None:
    P0 = np.eye(2)
    with pytest.raises(ValueError, match="Phis"):
        pcrb_recursion(np.zeros((3, 2, 2)), np.zeros((2, 2, 2)), [None] * 3, [None] * 3, P0)
    with pytest.raises(ValueError, match="Rs"):
        pcrb_recursion(np.zeros((2, 2, 2)), np.zeros((2, 2, 2)), [None] * 3, [None] * 2, P0)
    with pytest.raises(ValueError, match=r"Hs\[0\]"):
        pcrb_recursion(np.zeros((0, 2, 2)), np.zeros((0, 2, 2)), [np.ones((1, 3))], [np.eye(1)], P0)


# --- the flight bound is that recursion on the filters' Jacobians -----------------------


def white_model(fl: Flight) -> Linearization:
    """The shipped [att, bg] models with the white-noise suite's process noise (the
    Jacobians; R is given explicitly below)."""
    s = WHITE
    params = EskfParams(
        gyro_noise=s.gyro.noise_density, gyro_bias_noise=s.gyro.bias_rw, accel_noise=s.accel.noise_density
    )
    return Linearization(pcrb_layout("gravity"), params, fl.site)


def test_flight_bound_is_the_recursion_on_the_models_jacobians() -> None:
    fl = flight_in_place(WHITE, seed=3, duration=1.0)
    res = pcrb(fl, WHITE, model="gravity", sigma_att=SIGMA_ATT)
    layout = pcrb_layout("gravity")
    tr = fl.truth
    w = rates_from_attitude(tr.t, tr.q_nb)
    dt = 1.0 / WHITE.imu_rate
    lin = white_model(fl)
    Phis, Qs, Hs, Rs = [], [], [], []
    mag_k = set(np.searchsorted(fl.imu.t, fl.mag.t).tolist())
    for k in range(len(tr.t)):
        if k > 0:
            lin.set_state(tr.q_nb[k - 1])  # (Phi, Q) of the step from the truth at k-1
            Phi, Q = lin.transition(w[k], np.zeros(3), dt)
            Phis.append(Phi)
            Qs.append(Q)
        lin.set_state(tr.q_nb[k])
        H = [lin.gravity()[0]]
        R = [WHITE.accel.noise_density**2 / dt * np.eye(3)]
        if k in mag_k:
            H.append(lin.mag()[0])
            R.append(WHITE.mag.noise**2 * np.eye(3))
        Hs.append(np.vstack(H))
        Rs.append(block_diag(*R))
    P0 = np.diag([SIGMA_ATT**2] * 3 + [WHITE.gyro.bias_init_sigma**2] * 3)
    ref = pcrb_recursion(np.array(Phis), np.array(Qs), Hs, Rs, P0)
    assert res.labels == layout.labels()
    assert res.used == {"accel": len(tr.t), "mag": len(fl.mag.t)}
    assert res.max_accel_n == 0.0
    scale = np.abs(ref).max(axis=(1, 2))[:, None, None]
    assert (np.abs(res.cov - ref) / scale).max() < 1e-9


# --- (b) the matched filter attains the bound -------------------------------------------

RUNS = 50


def test_matched_mekf_attains_the_bound_on_a_rotating_body() -> None:
    """[mekf] with parameters equal to the white-noise suite, 50 runs of the same truth
    (noise and initial error differ): RMSE / sqrt(PCRB) over the second half per body axis."""
    fl0 = flight_in_place(WHITE, seed=0)
    bound = pcrb(fl0, WHITE, model="gravity", sigma_att=SIGMA_ATT)
    params = matched_to(WHITE)
    errors = []
    for seed in range(RUNS):
        fl = flight_in_place(WHITE, seed=seed)
        rng = np.random.default_rng(1000 + seed)
        q0 = quat_mul(fl.truth.q_nb[0], quat_exp(rng.normal(size=3) * SIGMA_ATT))
        est = Mekf(params).run(fl, initial=InitialState(q_nb=q0, sigma_att=SIGMA_ATT))
        errors.append(np.degrees(quat_log(quat_mul(quat_conj(est.q_nb), fl.truth.q_nb))))
    e = np.array(errors)
    n = e.shape[1]
    ratio = efficiency_ratio(e, bound.att_std_deg(), slice(n // 2, None))
    print("efficiency ratio per body axis:", ratio)
    assert np.all((ratio >= 0.9) & (ratio <= 1.2)), ratio
    # The filter's own covariance (linearised at its estimate) converges to the bound.
    P_f = np.degrees(np.sqrt(np.diagonal(est.cov[-1])[:3]))
    assert np.allclose(P_f, bound.att_std_deg()[-1], rtol=0.02)


# --- (c), (d) INS: wind and information -------------------------------------------------

FW_SUITE = SensorSuite(imu_rate=50.0)  # every stream divides 50 Hz
FW_DURATION = 32.0  # straight 20 s, then a 30 deg turn: separates accelerometer bias and tilt


def fixedwing(w20: float, turbulence: bool = True) -> Flight:
    cfg = WindConfig(w20=w20, turbulence=turbulence, shear=turbulence)
    return simulate(
        FixedWingScenario(duration=FW_DURATION, wind=cfg), np.random.default_rng(7), sensors=FW_SUITE
    )


@pytest.fixture(scope="module")
def ins_bounds() -> dict[str, object]:
    gusty = fixedwing(8.0)
    out: dict[str, object] = {"gusty": gusty}
    out["calm"] = pcrb(fixedwing(0.0), FW_SUITE, model="ins", sigma_att=np.radians(5.0))
    out["steady"] = pcrb(fixedwing(8.0, turbulence=False), FW_SUITE, model="ins", sigma_att=np.radians(5.0))
    out["gnss"] = pcrb(gusty, FW_SUITE, model="ins", sigma_att=np.radians(5.0))
    return out


def test_ins_bound_does_not_depend_on_the_wind(ins_bounds) -> None:
    calm, steady, gusty = ins_bounds["calm"], ins_bounds["steady"], ins_bounds["gnss"]
    assert gusty.labels == pcrb_layout("ins", accel_bias=True, mag_bias=True).labels()
    # Steady wind leaves rates and specific force unchanged: the same bound.
    assert np.allclose(steady.cov, calm.cov, rtol=1e-6, atol=0)
    # The wind itself never enters the model: replacing the true wind changes nothing.
    fl = ins_bounds["gusty"]
    no_wind = fl.replace(truth=Truth(t=fl.truth.t, q_nb=fl.truth.q_nb, v_n=fl.truth.v_n))
    again = pcrb(no_wind, FW_SUITE, model="ins", sigma_att=np.radians(5.0))
    scale = np.abs(gusty.cov).max(axis=(1, 2))[:, None, None]
    assert (np.abs(again.cov - gusty.cov) / scale).max() < 1e-9  # Truth renormalises q: rounding
    # Turbulence changes the specific force (it excites the accelerometer-bias / tilt
    # separation in straight flight), so compare after the turn has separated them.
    late = calm.t >= 28.0
    a, b = calm.att_std_deg()[late], gusty.att_std_deg()[late]
    rel = np.sqrt(np.mean(b**2, axis=0) / np.mean(a**2, axis=0))
    print("gusty / calm time-averaged attitude bound after the turn:", rel)
    assert np.all(np.abs(rel - 1.0) < 0.10), rel


def test_more_measurements_never_increase_the_ins_bound(ins_bounds) -> None:
    fl = ins_bounds["gusty"]
    with_gnss = ins_bounds["gnss"]
    mag_only = pcrb(fl, FW_SUITE, model="ins", sigma_att=np.radians(5.0), gnss=False)
    with_air = pcrb(fl, FW_SUITE, model="ins", sigma_att=np.radians(5.0), air=True)
    assert "wind_n" in with_air.labels and with_air.sensors == ("mag", "gnss", "air")
    # Without air rows the wind states are decoupled, so compare the common states.
    idx = [with_air.labels.index(lab) for lab in with_gnss.labels]
    air_common = with_air.cov[:, idx][:, :, idx]
    assert loewner_min(mag_only.cov, with_gnss.cov) >= -1e-12
    assert loewner_min(with_gnss.cov, air_common) >= -1e-12
    # Euler bounds are congruences of the attitude block: the order carries over.
    assert np.all(with_air.euler_std_deg() <= with_gnss.euler_std_deg() * (1 + 1e-9))


def test_magnetometer_never_increases_the_gravity_bound() -> None:
    fl = flight_in_place(WHITE, seed=1, duration=5.0)
    both = pcrb(fl, WHITE, model="gravity", sigma_att=SIGMA_ATT)
    acc = pcrb(fl, WHITE, model="gravity", sigma_att=SIGMA_ATT, mag=False)
    assert acc.sensors == ("accel",) and both.sensors == ("accel", "mag")
    assert loewner_min(acc.cov, both.cov) >= -1e-12
    # Without a magnetometer, heading is not observable: its bound stays near the prior.
    assert acc.att_std_deg()[-1, 2] > 10 * both.att_std_deg()[-1, 2]


# --- averaging, ratio, bad input ------------------------------------------------------------


def test_average_of_identical_truths_is_the_single_bound_and_below_the_mean_bound() -> None:
    a = flight_in_place(WHITE, seed=0, duration=2.0)
    b = flight_in_place(WHITE, seed=1, duration=2.0, phase=1.0)
    single = pcrb(a, WHITE, model="gravity", sigma_att=SIGMA_ATT)
    same = pcrb_average([a, a], WHITE, model="gravity", sigma_att=SIGMA_ATT)
    assert same.runs == 2
    assert np.allclose(same.cov, single.cov, rtol=1e-9, atol=0)
    assert np.allclose(same.euler_std_deg(), single.euler_std_deg(), rtol=1e-9)
    mixed = pcrb_average([a, b], WHITE, model="gravity", sigma_att=SIGMA_ATT)
    mean_bound = 0.5 * (single.cov + pcrb(b, WHITE, model="gravity", sigma_att=SIGMA_ATT).cov)
    assert loewner_min(mean_bound, mixed.cov) >= -1e-12  # (E J)^-1 <= E[J^-1]


def test_efficiency_ratio_of_errors_drawn_at_the_bound_is_one() -> None:
    rng = np.random.default_rng(4)
    std = np.column_stack([np.linspace(1.0, 0.1, 400), np.full(400, 0.2), np.full(400, 0.5)])
    e = rng.normal(size=(200, 400, 3)) * std
    r = efficiency_ratio(e, std, slice(200, None))
    assert np.allclose(r, 1.0, atol=0.03)
    assert np.allclose(efficiency_ratio(2 * e, std, np.arange(400) >= 200), 2 * r)
    with pytest.raises(ValueError, match="pcrb_std_deg"):
        efficiency_ratio(e, std[:-1], slice(None))
    with pytest.raises(ValueError, match="window"):
        efficiency_ratio(e, std, slice(400, None))


def test_bad_input_names_the_field() -> None:
    fl = flight_in_place(WHITE, seed=0, duration=1.0)
    with pytest.raises(ValueError, match="model"):
        pcrb(fl, WHITE, model="paper")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="flight.truth"):
        pcrb(fl.replace(truth=None), WHITE, model="gravity")
    with pytest.raises(ValueError, match="gnss"):
        pcrb(fl, WHITE, model="ins", gnss=True)
    with pytest.raises(ValueError, match="air"):
        pcrb(fl, WHITE, model="gravity", air=True)
    with pytest.raises(ValueError, match="P0"):
        pcrb(fl, WHITE, model="gravity", P0=np.eye(9))
    with pytest.raises(ValueError, match="PcrbNoise.mag"):
        PcrbNoise(gyro=1e-4, mag=-1.0)
    with pytest.raises(ValueError, match="noise.mag"):
        pcrb(fl, PcrbNoise(gyro=1e-4, accel=1e-3), model="gravity")
    with pytest.raises(ValueError, match="flights"):
        pcrb_average([], WHITE, model="gravity")
