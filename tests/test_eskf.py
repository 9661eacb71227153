"""Error-state filters [mekf], [mekf-air], [ins-wind] and the additive [ekf7], [ekf10]
(reference implementations): Jacobians, zero-noise exactness, consistency, streaming,
bad input, parameters."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from trajectories import flight_in_place
from windahrs.core import layout as K
from windahrs.core.linearize import Linearization
from windahrs.filters.base import InitialState, MissingSensorError, merge_events
from windahrs.filters.ekf7 import Ekf7, Ekf10
from windahrs.filters.eskf import InsWind, Mekf, MekfAir
from windahrs.filters.params import EskfParams, load_params, matched_to
from windahrs.filters.registry import make_estimator
from windahrs.flight import Flight, Site
from windahrs.metrics import chi2_band, nees_attitude
from windahrs.models.additive import Xi, vector_obs_jacobian
from windahrs.models.error_state import Layout
from windahrs.rotation import quat_angle, quat_conj, quat_exp, quat_log, quat_mul
from windahrs.sim.atmosphere import WindConfig
from windahrs.sim.fixedwing import FixedWingScenario
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.sim.sensors import AccelModel, MagModel, SensorSuite

FULL = Layout(("att", "v", "bg", "wind", "ba", "bm"))
SITE = Site(mag_n=np.array([20e-6, -3e-6, 45e-6]))
#: The nominal state's blocks as keywords of Linearization.set_state (q_nb apart).
STATE_BLOCKS = (("v", "v_n"), ("bg", "bg"), ("wind", "wind_n"), ("ba", "ba"), ("bm", "bm"))


def random_state(rng: np.random.Generator) -> dict[str, np.ndarray]:
    return {
        "q_nb": quat_exp(rng.normal(size=3)),
        "bg": rng.normal(size=3) * 0.01,
        "v_n": rng.normal(size=3) * 10 + [15, 0, 0],
        "wind_n": rng.normal(size=3) * 3,
        "ba": rng.normal(size=3) * 0.05,
        "bm": rng.normal(size=3) * 1e-6,
    }


def inject(layout: Layout, s: dict[str, np.ndarray], dx: np.ndarray) -> dict[str, np.ndarray]:
    """The state perturbed by the error dx: ``q Exp(dtheta)``, additive elsewhere."""
    out = dict(s, q_nb=quat_mul(s["q_nb"], quat_exp(dx[layout.sl("att")])))
    for block, key in STATE_BLOCKS:
        if layout.has(block):
            out[key] = s[key] + dx[layout.sl(block)]
    return out


def boxminus(layout: Layout, a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> np.ndarray:
    """Error-state difference a - b in the layout's coordinates."""
    dx = np.zeros(layout.dim)
    dx[layout.sl("att")] = quat_log(quat_mul(quat_conj(b["q_nb"]), a["q_nb"]))
    for block, key in STATE_BLOCKS:
        if layout.has(block):
            dx[layout.sl(block)] = a[key] - b[key]
    return dx


def nominal(lin: Linearization) -> dict[str, np.ndarray]:
    """The nominal state of the linearisation (after its prediction)."""
    x = lin.st.x
    idx = {"q_nb": (K.X_Q, 4), "v_n": (K.X_V, 3), "bg": (K.X_BG, 3), "wind_n": (K.X_W, 3),
           "ba": (K.X_BA, 3), "bm": (K.X_BM, 3)}  # fmt: skip
    return {key: x[i : i + m].copy() for key, (i, m) in idx.items()}


LAYOUTS = [FULL, Layout(("att", "bg")), Layout(("att", "bg", "ba", "bm")), Layout(("att", "bg", "wind")),
           Layout(("att", "v", "bg", "ba"))]  # fmt: skip


@pytest.mark.parametrize("layout", LAYOUTS, ids=lambda L: "-".join(L.blocks))
def test_linearization_jacobians_match_finite_differences(layout: Layout) -> None:
    """core.linearize reads each shipped aid source's H on any layout (the aid sources
    themselves: tests/test_aid_jacobians.py): H = -d nu / d(error) at a fixed sample, the
    columns outside the aid's support exactly 0, R as the parameters give it."""
    rng = np.random.default_rng(1)
    params = EskfParams()
    lin = Linearization(layout, params, SITE)
    aids = {"gravity": lin.gravity, "mag": lin.mag}
    if layout.has("v"):
        aids["gnss"] = lin.gnss
    if layout.has("wind"):
        aids.update(air=lambda: lin.air_vector(15.0, 0.05, -0.03), tas=lambda: lin.tas(15.0), sideslip=lin.sideslip)
    for _ in range(3):
        x = random_state(rng)
        for name, aid in aids.items():
            lin.set_state(**x)
            H, R = aid()
            m = H.shape[0]

            def nu(s: dict[str, np.ndarray], aid=aid, m=m) -> np.ndarray:
                lin.set_state(**s)
                aid()
                return lin.st.work[K.W_NU, :m].copy()

            cols = []
            for i in range(layout.dim):
                e = np.zeros(layout.dim)
                e[i] = 1e-6
                cols.append(-(nu(inject(layout, x, e)) - nu(inject(layout, x, -e))) / 2e-6)
            H_fd = np.column_stack(cols)
            scale = np.abs(H_fd).max()
            assert np.abs(H - H_fd).max() <= 1e-6 * scale, (name, np.abs(H - H_fd).max(), scale)
            assert np.all(H[np.abs(H_fd) == 0] == 0), name
            var = {"gravity": params.accel_sigma, "mag": params.mag_sigma, "gnss": params.gnss_sigma,
                   "tas": params.tas_sigma, "sideslip": params.sideslip_sigma}.get(name)  # fmt: skip
            if var is not None:
                assert np.array_equal(R, var**2 * np.eye(m)), name
    if layout.has("v"):
        lin.set_state(**x)
        assert np.array_equal(lin.gnss()[0][:, layout.sl("v")], np.eye(3))
    if layout.has("wind"):
        lin.set_state(**x)
        assert np.all(lin.tas(15.0)[0][:, :3] == 0)  # airspeed carries no attitude information


def test_process_transition_matches_finite_differences() -> None:
    """The shipped prediction (core.predict._predict_es): Phi P Phi^T (its prediction of P
    less that of 0, Q) against Phi from central differences of the nominal propagation."""
    rng = np.random.default_rng(3)
    params = EskfParams(gyro_noise=1e-4, gyro_bias_noise=1e-5, accel_noise=1e-3, wind_noise=0.1,
                        wind_noise_vertical=0.1, accel_bias_noise=1e-4, mag_bias_noise=1e-8)  # fmt: skip
    lin = Linearization(FULL, params, SITE)
    for dt, w_scale in ((0.005, 1.0), (0.05, 3.0), (0.005, 1e-9)):
        x = random_state(rng)
        w, f = rng.normal(size=3) * w_scale, rng.normal(size=3) * 3 + [0, 0, -9.8]
        P = np.eye(FULL.dim)
        lin.set_state(**x)
        Q = lin.predict(np.zeros_like(P), w, f, dt)  # with P = 0 the prediction is Q alone
        lin.set_state(**x)
        Phi_PPhiT = lin.predict(P, w, f, dt) - Q
        x1 = nominal(lin)

        def step(s: dict[str, np.ndarray]) -> np.ndarray:
            lin.set_state(**s)
            lin.predict(P, w, f, dt)
            return boxminus(FULL, nominal(lin), x1)

        eps = 1e-6
        cols = []
        for i in range(FULL.dim):
            e = np.zeros(FULL.dim)
            e[i] = eps
            cols.append((step(inject(FULL, x, e)) - step(inject(FULL, x, -e))) / (2 * eps))
        Phi_fd = np.column_stack(cols)
        assert np.allclose(Phi_fd @ Phi_fd.T, Phi_PPhiT, atol=1e-6 * np.abs(Phi_PPhiT).max())
        # Linearization.transition's Phi is the same
        lin.set_state(**x)
        Phi, Q2 = lin.transition(w, f, dt)
        assert np.array_equal(Q2, Q)
        assert np.allclose(Phi, Phi_fd, atol=1e-6 * np.abs(Phi_fd).max())


def test_additive_jacobian_equals_tangent_form() -> None:
    """The additive filters' vector Jacobian (models.additive) projected on the unit sphere
    is the error-state one (aid.mag's H_att = [C_bn r]x) through ``dq = Xi(q) dtheta / 2``."""
    rng = np.random.default_rng(4)
    layout = Layout(("att", "bg"))
    for _ in range(10):
        q = quat_exp(rng.normal(size=3))
        r = rng.normal(size=3)
        r *= 3e-5 / np.linalg.norm(r)  # a field in tesla (aid.mag's reference)
        lin = Linearization(layout, EskfParams(), Site(mag_n=r))
        lin.set_state(q)
        H = lin.mag()[0]
        proj = np.eye(4) - np.outer(q, q)
        assert np.allclose(vector_obs_jacobian(q, r) @ proj, 2 * H[:, :3] @ Xi(q).T, atol=1e-12 * np.abs(r).max())


# --- zero noise -----------------------------------------------------------------------

NOISELESS = SensorSuite().noiseless()


@pytest.mark.parametrize("estimator", [Mekf(), Ekf7()], ids=["mekf", "ekf7"])
def test_zero_noise_from_truth_stays_exact_gravity_filters(estimator) -> None:
    fl = flight_in_place(NOISELESS, seed=0, duration=60.0)
    est = estimator.run(fl, initial=InitialState.from_truth(fl))
    err = quat_angle(est.q_nb, fl.truth.q_nb)
    assert fl.duration == pytest.approx(60.0)
    assert err.max() < 1e-6


def test_zero_noise_ins_is_exact_in_gusts_and_with_air_data() -> None:
    """The INS takes the accelerometer as input: exact for any motion, gusts included.
    With air data the wind must be constant for the data to be noise-free (turbulence is
    process noise of the wind states)."""
    gusty = simulate(
        make_scenario("fixedwing", wind=8.0, duration=60.0), np.random.default_rng(5), sensors=NOISELESS
    )
    gusty = gusty.replace(air=None)
    calm = FixedWingScenario(duration=60.0, wind=WindConfig(w20=8.0, turbulence=False, shear=False))
    steady = simulate(calm, np.random.default_rng(5), sensors=NOISELESS)
    for fl in (gusty, steady):
        est = InsWind().run(fl, initial=InitialState.from_truth(fl))
        assert quat_angle(est.q_nb, fl.truth.q_nb).max() < 1e-6
    assert np.abs(est.wind_n - steady.truth.wind_n).max() < 1e-6


@pytest.mark.parametrize("estimator", [MekfAir(), Ekf10()], ids=["mekf-air", "ekf10"])
def test_zero_noise_air_data_filters_stay_close(estimator) -> None:
    """w x V_air compensation is exact in continuous time only (the discrete truth differs
    by O(dt)), so these filters stay close rather than exact."""
    calm = FixedWingScenario(duration=60.0, wind=WindConfig(w20=8.0, turbulence=False, shear=False))
    fl = simulate(calm, np.random.default_rng(5), sensors=NOISELESS)
    est = estimator.run(fl, initial=InitialState.from_truth(fl))
    assert np.degrees(quat_angle(est.q_nb, fl.truth.q_nb).max()) < 0.1


# --- consistency --------------------------------------------------------------------

RUNS = 50


def mc_suite(gnss: bool) -> SensorSuite:
    return SensorSuite(
        imu_rate=100.0,
        accel=AccelModel(bias_init_sigma=0.0),
        mag=MagModel(rate=20.0, hard_iron=0.0),
        gnss=SensorSuite().gnss if gnss else None,
        pitot=None,
        vanes=None,
    )


def consistency(est_cls, suite: SensorSuite, dim: int) -> dict[str, float]:
    params = matched_to(suite, est_cls.default_params)
    nees, nis = [], {}
    for seed in range(RUNS):
        fl = flight_in_place(suite, seed=seed, duration=20.0, phase=0.1 * seed)
        rng = np.random.default_rng(1000 + seed)
        sig = np.radians(2.0)
        truth0 = InitialState.from_truth(fl)
        q0 = quat_mul(truth0.q_nb, quat_exp(rng.normal(size=3) * sig))
        init = InitialState(q_nb=q0, v_n=truth0.v_n, sigma_att=sig)
        est = est_cls(params).run(fl, initial=init)
        nees.append(nees_attitude(est, fl))
        for k, inn in est.innovations.items():
            nis.setdefault(k, []).append(inn.nis[: len(inn.nis) // 10 * 10])
    avg = np.mean(nees, axis=0)
    lo, hi = chi2_band(dim, RUNS)
    out = {
        "nees": float(avg.mean()),
        "in_band": float(np.mean((avg >= lo) & (avg <= hi))),
        "lo": lo,
        "hi": hi,
    }
    for k, rows in nis.items():
        n = min(len(r) for r in rows)
        out[f"nis_{k}"] = float(np.mean([r[:n] for r in rows], axis=0).mean())
    return out


@pytest.mark.parametrize(
    ("est_cls", "gnss"), [(Mekf, False), (Ekf7, False), (InsWind, True)], ids=["mekf", "ekf7", "ins-wind"]
)
def test_nees_and_nis_inside_chi2_bands(est_cls, gnss: bool) -> None:
    res = consistency(est_cls, mc_suite(gnss), 6)
    print(est_cls.name, res)
    assert res["lo"] <= res["nees"] <= res["hi"]
    assert res["in_band"] >= 0.90
    lo3, hi3 = chi2_band(3, RUNS)
    for k, v in res.items():
        if k.startswith("nis_"):
            assert lo3 <= v <= hi3, (k, v)


# --- streaming, bad input, params ---------------------------------------------------------


@pytest.mark.parametrize("name", ["mekf", "mekf-air", "ins-wind", "ekf7", "ekf10"])
def test_streaming_equals_batch(name: str) -> None:
    fl = simulate(make_scenario("fixedwing", wind=5.0, duration=5.0), np.random.default_rng(7))
    est = make_estimator(name)
    batch = est.run(fl)
    has = frozenset(s for s in ("imu", "mag", "gnss", "air") if getattr(fl, s) is not None)
    s = est.streamer(fl.site, has=has)
    t, kinds, vals = merge_events(fl, has & est.uses)
    for i in range(len(t)):
        s.push(int(kinds[i]), float(t[i]), vals[i])
    st = s.state
    assert np.array_equal(st.q_nb, batch.q_nb[-1])
    assert np.array_equal(st.cov, batch.cov[-1])


def test_missing_sensor_errors_name_filter_and_sensor() -> None:
    fl = simulate(make_scenario("quadrotor", wind=0.0, duration=2.0), np.random.default_rng(0))
    with pytest.raises(MissingSensorError, match=r"'mekf-air' needs air data \('air'\)"):
        MekfAir().run(fl)
    with pytest.raises(MissingSensorError, match=r"'ins-wind' needs GNSS velocity \('gnss'\)"):
        InsWind().run(fl.replace(gnss=None))
    with pytest.raises(ValueError, match="unknown 'nope'; known filters: .*ins-wind"):
        make_estimator("nope")


def test_nan_samples_are_skipped_counted_and_never_reach_the_state() -> None:
    fl = simulate(make_scenario("fixedwing", wind=5.0, duration=5.0), np.random.default_rng(8))
    w = fl.imu.w_b.copy()
    w[100:103] = np.nan
    m = fl.mag.mag_b.copy()
    m[10] = np.nan
    v = fl.gnss.v_n.copy()
    v[5] = np.nan
    tas = fl.air.tas.copy()
    tas[7] = np.nan
    bad = fl.replace(
        imu=type(fl.imu)(t=fl.imu.t, w_b=w, f_b=fl.imu.f_b),
        mag=type(fl.mag)(t=fl.mag.t, mag_b=m),
        gnss=type(fl.gnss)(t=fl.gnss.t, v_n=v),
        air=type(fl.air)(t=fl.air.t, tas=tas, aoa=fl.air.aoa, sideslip=fl.air.sideslip),
    )
    for est in (Mekf(), InsWind(), MekfAir(), Ekf7()):
        out = est.run(bad)
        assert np.isfinite(out.q_nb).all() and np.isfinite(out.cov).all()
        assert out.skipped["imu"] == 3 and out.skipped["mag"] == 1
        if est.name in ("ins-wind", "mekf-air"):
            assert out.skipped["gnss"] == 1 and out.skipped["air"] == 1


def test_params_from_toml_with_px4_and_ardupilot_names(tmp_path: Path) -> None:
    f = tmp_path / "p.toml"
    f.write_text(
        '[windahrs]\nmag_mode = "heading"\n[px4]\nEKF2_GYR_NOISE = 0.015\nEKF2_BETA_NOISE = 0.2\n'
        "[ardupilot]\nEK3_EAS_M_NSE = 1.4\nEK3_EAS_I_GATE = 400\n"
    )
    p = load_params(f)
    assert p.mag_mode == "heading" and p.sideslip_sigma == 0.2 and p.tas_sigma == 1.4 and p.gate_air == 4.0
    assert p.gyro_noise == pytest.approx(0.0015)
    f.write_text("[windahrs]\ngyro_nois = 1.0\n")
    with pytest.raises(ValueError, match="unknown parameter 'gyro_nois'"):
        load_params(f)
    f.write_text('[windahrs]\nmag_mode = "sideways"\n')
    with pytest.raises(
        ValueError, match=r"mag_mode: expected one of \('3d', 'heading', 'off'\), found 'sideways'"
    ):
        load_params(f)
    f.write_text("[px4]\nEKF2_FOO = 1\n")
    with pytest.raises(ValueError, match="'EKF2_FOO' has no windahrs equivalent"):
        load_params(f)
    f.write_text("[windahrs\n")
    with pytest.raises(ValueError, match="not valid TOML"):
        load_params(f)
    with pytest.raises(ValueError, match="gyro_noise: expected > 0"):
        EskfParams(gyro_noise=0.0)


def test_heading_only_magnetometer_mode_runs_and_converges() -> None:
    fl = simulate(make_scenario("fixedwing", wind=0.0, duration=30.0), np.random.default_rng(9))
    est = Mekf(EskfParams(mag_mode="heading")).run(fl)
    err = quat_angle(est.q_nb, fl.truth.q_nb)
    assert np.degrees(np.sqrt(np.mean(err[len(err) // 2 :] ** 2))) < 3.0


def test_an_angle_of_attack_vane_alone_adds_its_angle_to_airspeed_and_synthetic_sideslip() -> None:
    # A fixed wing with an angle-of-attack vane but no sideslip vane: the airspeed, the angle
    # of attack alone (windahrs.aid.aoa) and the synthetic sideslip are fused; with
    # air_mode "airspeed" the vane is not fused (it still turns the sample's air velocity, as
    # both vanes do, for the wind's first value); the paper's filter (the air-flow direction
    # needs both vanes) refuses the flight by name.
    fl = simulate(make_scenario("fixedwing", wind=5.0, duration=5.0), np.random.default_rng(9))
    assert fl.air is not None and fl.air.has_vanes
    aoa_only = fl.replace(air=type(fl.air)(t=fl.air.t, tas=fl.air.tas, aoa=fl.air.aoa))
    pitot = fl.replace(air=type(fl.air)(t=fl.air.t, tas=fl.air.tas))
    assert aoa_only.air is not None and not aoa_only.air.has_vanes
    for name in ("ins-wind", "mekf-air", "ekf10"):
        est = make_estimator(name)
        one, none, both = est.run(aoa_only), est.run(pitot), est.run(fl)
        assert np.isfinite(one.q_nb).all(), name
        assert "aoa" in one.innovations and "aoa" not in none.innovations, name
        assert not np.array_equal(one.q_nb, none.q_nb), name  # the vane does matter
        assert not np.array_equal(one.q_nb, both.q_nb), name  # and so do both
        off = make_estimator(f"{name}:air_mode=airspeed").run(aoa_only)
        assert "aoa" not in off.innovations and {"tas", "sideslip"} <= set(off.innovations), name
    with pytest.raises(MissingSensorError, match=r"'paper'.*found air data with only one vane \(aoa\)"):
        make_estimator("paper").run(aoa_only)
    # air data is there: the message says its vanes are missing, not the air data (as on ALFA)
    with pytest.raises(MissingSensorError) as pitot_only:
        make_estimator("paper").run(pitot)
    assert str(pitot_only.value).startswith("filter 'paper' needs air data with both vanes ('air'), which the "
                                            "flight does not have: ")
    assert str(pitot_only.value).endswith("found air data without vanes (pitot only)")


@pytest.mark.parametrize(("kind", "additive"), [("mekf", False), ("ins-wind", False), ("mekf", True)])
def test_held_sample_noise_is_the_measured_change_over_the_step(kind: str, additive: bool) -> None:
    """A step longer than unmeasured_motion_dt adds (dw dt)^2/3 per body axis to the attitude
    (1/4 Xi diag Xi^T on the additive quaternion) and C diag((df dt)^2/3) C^T to the INS
    velocity; a shorter step adds nothing."""
    from windahrs.core.kernel import layout_for, make_state
    from windahrs.core.predict import add_held_sample_noise

    params = EskfParams()
    caps = np.full(K.N_SENSORS, 4, dtype=np.int64)
    st = make_state(kind, additive, params, SITE, None, frozenset({"imu"}), caps)  # type: ignore[arg-type]
    rng = np.random.default_rng(4)
    q = quat_exp(rng.normal(size=3))
    dw, df = np.array([0.3, -0.1, 0.05]), np.array([2.0, 0.5, -1.0])
    st.x[K.X_Q : K.X_Q + 4] = q
    st.x[K.X_DW : K.X_DW + 3], st.x[K.X_DF : K.X_DF + 3] = dw, df
    add_held_sample_noise(st.cfg, st.prm, st.x, st.P, st.work, 0.019)  # 53 Hz: not held
    assert not st.P.any()
    dt = 0.1
    add_held_sample_noise(st.cfg, st.prm, st.x, st.P, st.work, dt)
    d_att, d_v = (dw * dt) ** 2 / 3.0, (df * dt) ** 2 / 3.0
    if additive:
        X = Xi(q)
        np.testing.assert_allclose(st.P[:4, :4], 0.25 * X @ np.diag(d_att) @ X.T, rtol=1e-12, atol=1e-18)
        assert not st.P[4:].any()
        return
    np.testing.assert_allclose(st.P[:3, :3], np.diag(d_att), rtol=1e-12)
    L = layout_for(kind, params)  # type: ignore[arg-type]
    if L.has("v"):
        from scipy.spatial.transform import Rotation

        C = Rotation.from_quat(q, scalar_first=True).as_matrix()
        v = L.sl("v")
        np.testing.assert_allclose(st.P[v, v], C @ np.diag(d_v) @ C.T, rtol=1e-12, atol=1e-18)
        np.testing.assert_array_equal(st.P, st.P.T)
    assert np.count_nonzero(st.P) == 3 + (9 if L.has("v") else 0)


def test_flight_declared_gnss_timing_is_used_unless_set() -> None:
    from windahrs.filters.params import flight_params

    meta = {"gnss.timing_sigma_s": 0.5}
    assert flight_params(EskfParams(), meta).gnss_timing_sigma == 0.5
    assert flight_params(EskfParams(gnss_timing_sigma=0.05), meta).gnss_timing_sigma == 0.05  # explicit wins
    assert flight_params(EskfParams(), meta, frozenset({"gyro_noise"})) == EskfParams()  # not used: untouched
    with pytest.raises(ValueError, match=r"meta\['gnss.timing_sigma_s'\]: expected a finite number >= 0"):
        flight_params(EskfParams(), {"gnss.timing_sigma_s": "late"})
    flight = simulate(make_scenario("fixedwing", wind=5.0, duration=6.0), np.random.default_rng(2))
    est = make_estimator("ins-wind").run(flight)
    declared = make_estimator("ins-wind").run(dataclasses.replace(flight, meta={**flight.meta, **meta}))
    assert "gnss_timing_sigma=0.5" in declared.params and "gnss_timing_sigma=0.0" in est.params
    # a larger GNSS variance while the vehicle accelerates: the velocity follows GNSS less
    assert not np.allclose(declared.v_n, est.v_n)


def _vibrating_rest(sigma: float, seconds: float = 4.0, rate: float = 120.0) -> Flight:
    """A level IMU at rest whose accelerometer reads white vibration of ``sigma`` m/s^2 per
    axis (a hard-mounted IMU on a multirotor), seeded."""
    rng = np.random.default_rng(11)
    n = int(seconds * rate)
    f_b = np.array([0.0, 0.0, -9.80665]) + rng.normal(scale=sigma, size=(n, 3))
    w_b = rng.normal(scale=1e-4, size=(n, 3))
    return Flight.from_arrays(gyro=w_b, accel=f_b, rate=rate)


def test_online_accel_noise_starts_as_the_mean_of_the_samples_so_far() -> None:
    """accel_noise_mean_start: in the first half second of a vibrating accelerometer the
    gravity innovations are weighed by the vibration measured so far (NIS per axis below 1:
    the mean's own noise is smaller than a sample's), while a variance low-passed from zero
    weighs the first means by little more than accel_sigma (NIS over 1, three times as
    large; measured 0.36 and 1.20 per axis)."""
    sigma = 1.0  # (3 m/s^2 would put the first samples outside the norm gate)
    flight = _vibrating_rest(sigma)
    nis = {}
    for start in (True, False):
        est = make_estimator(f"mekf:accel_noise_mean_start={str(start).lower()}")
        inn = est.run(flight).innovations["accel"]
        early = (inn.t < 0.5) & np.isfinite(inn.nis)
        assert early.sum() > 30
        nis[start] = float(np.mean(inn.nis[early])) / 3.0
    assert nis[True] < 0.6, nis
    assert nis[False] > 1.0 and nis[False] > 2.5 * nis[True], nis
    with pytest.raises(ValueError, match="accel_noise_mean_start"):
        make_estimator("mekf:accel_noise_mean_start=2")


def test_vertical_bias_walk_q_and_phi() -> None:
    """gyro_bias_noise_vertical (core.predict._bias_walk_vertical): Q's gyro-bias density is
    s_b^2 I + (s_v^2 - s_b^2) u u^T, u = C_bn e_3 at the predicted attitude, with SPEC 2.4's
    attitude terms, exactly symmetric; Linearization.transition's Phi does not carry it."""
    from windahrs.rotation import quat_from_euler, quat_rotate_inv

    layout = Layout(("att", "bg"))
    sb, sv, sg, dt = 1e-4, 2e-5, 1e-3, 0.01
    w = np.array([0.1, -0.2, 0.3])
    q = quat_from_euler([0.3, -0.2, 1.0])
    one = Linearization(layout, EskfParams(gyro_noise=sg, gyro_bias_noise=sb), SITE)
    two = Linearization(layout, EskfParams(gyro_noise=sg, gyro_bias_noise=sb, gyro_bias_noise_vertical=sv), SITE)
    one.set_state(q)
    two.set_state(q)
    Phi1, _ = one.transition(w, np.zeros(3), dt)
    Phi2, Q = two.transition(w, np.zeros(3), dt)
    assert np.array_equal(Phi1, Phi2)
    assert np.array_equal(Q, Q.T)
    two.predict(np.zeros((6, 6)), w, np.zeros(3), dt)  # to the predicted attitude, where u is taken
    u = quat_rotate_inv(two.q_nb, np.array([0.0, 0.0, 1.0]))
    Sb = sb**2 * np.eye(3) + (sv**2 - sb**2) * np.outer(u, u)
    want = np.block([[sg**2 * dt * np.eye(3) + Sb * dt**3 / 3, -Sb * dt**2 / 2], [-Sb * dt**2 / 2, Sb * dt]])
    np.testing.assert_allclose(Q, want, rtol=1e-12, atol=1e-24)
