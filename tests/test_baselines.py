"""Library baselines (windahrs.baselines): frames, units, declination, streaming.

The flights are simulated with the default IMU and magnetometer except a 100 Hz IMU
(speed) and no magnetometer hard iron (so that heading errors measure the adapters, not
the sensor); the adapters use no other sensor. Bounds sit above the worst of 12 seeds
measured (numbers beside them and in docs/baselines.md), since a change in the simulator
changes the realisation.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from windahrs.baselines import (
    AhrsEkf,
    AhrsEkfParams,
    ImuFusion,
    ImuFusionParams,
    Madgwick,
    MadgwickParams,
    Mahony,
    MahonyParams,
    Vqf,
    VqfOffline,
    VqfParams,
)
from windahrs.baselines._common import LibraryEstimator
from windahrs.conventions import DEG
from windahrs.estimate import Estimate
from windahrs.filters.base import (
    EVENT_IMU,
    Estimator,
    InitialState,
    MissingSensorError,
    merge_events,
    replay,
)
from windahrs.flight import Flight, MagStream, Site
from windahrs.rotation import euler_from_quat, quat_angle, quat_from_euler, quat_mul, quat_rotate_inv
from windahrs.sim.fixedwing import FixedWingScenario
from windahrs.sim.quadrotor import QuadrotorScenario
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.sim.sensors import MagModel, SensorSuite

SENSORS = SensorSuite(
    imu_rate=100.0, mag=MagModel(hard_iron=0.0), gnss=None, pitot=None, vanes=None
)
T_SCORE = 15.0  # s: scores start after every library has converged (VQF 9-axis needs ~9 s)

ALL = ("ahrs-ekf", "madgwick", "mahony", "vqf", "vqf-offline", "imufusion")
STREAMING = ("ahrs-ekf", "madgwick", "mahony", "vqf", "imufusion")


def make(name: str, **params: object) -> LibraryEstimator:
    cls: dict[str, tuple[type[LibraryEstimator], type]] = {
        "ahrs-ekf": (AhrsEkf, AhrsEkfParams),
        "madgwick": (Madgwick, MadgwickParams),
        "mahony": (Mahony, MahonyParams),
        "vqf": (Vqf, VqfParams),
        "vqf-offline": (VqfOffline, VqfParams),
        "imufusion": (ImuFusion, ImuFusionParams),
    }
    est_cls, par_cls = cls[name]
    return est_cls(par_cls(**params))  # type: ignore[call-arg]


def wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def errors_deg(est: Estimate, flight: Flight, t0: float = T_SCORE) -> tuple[float, float, float]:
    """Tilt RMSE, heading RMSE and mean heading error (estimate - truth), deg, t >= t0."""
    assert flight.truth is not None
    sel = flight.imu.t >= t0
    q, qt = est.q_nb[sel], flight.truth.q_nb[sel]
    down = np.array([0.0, 0.0, 1.0])
    cos_tilt = np.sum(quat_rotate_inv(q, down) * quat_rotate_inv(qt, down), axis=1)
    tilt = np.arccos(np.clip(cos_tilt, -1.0, 1.0))
    dyaw = wrap(euler_from_quat(q)[:, 2] - euler_from_quat(qt)[:, 2])
    rms = lambda x: float(np.sqrt(np.mean(x**2))) / DEG  # noqa: E731
    return rms(tilt), rms(dyaw), float(np.mean(dyaw)) / DEG


def rotate_heading(flight: Flight, psi: float) -> Flight:
    """The same flight turned by ``psi`` about the vertical (trajectory and attitude).

    Gyro and accelerometer readings are unchanged (gravity is vertical); the
    magnetometer reads the unchanged Earth field in the turned body (noise kept).
    """
    assert flight.truth is not None and flight.mag is not None
    assert flight.site.mag_n is not None
    tr = flight.truth
    q_new = quat_mul(quat_from_euler([0.0, 0.0, psi]), tr.q_nb)
    k = np.searchsorted(tr.t, flight.mag.t)
    noise = flight.mag.mag_b - quat_rotate_inv(tr.q_nb[k], flight.site.mag_n)
    mag_b = quat_rotate_inv(q_new[k], flight.site.mag_n) + noise
    return flight.replace(
        mag=MagStream(t=flight.mag.t, mag_b=mag_b), truth=dataclasses.replace(tr, q_nb=q_new)
    )


@pytest.fixture(scope="module")
def level() -> Flight:
    """Fixed wing, straight and level at heading 131.8 deg, 30 s, no wind (Dalian site,
    declination -8 deg)."""
    sc = make_scenario("fixedwing", wind=0.0, duration=30.0)
    assert isinstance(sc, FixedWingScenario)
    sc = dataclasses.replace(sc, plan="level", heading0=2.3)
    return simulate(sc, np.random.default_rng(20240611), sensors=SENSORS)


@pytest.fixture(scope="module")
def quad() -> Flight:
    """Quadrotor flying a square at constant yaw 34.4 deg, 30 s, no wind: tilts of up to
    25 deg in both axes at the corners, ~5 deg of drag tilt on the legs."""
    sc = make_scenario("quadrotor", wind=0.0, duration=30.0)
    assert isinstance(sc, QuadrotorScenario)
    sc = dataclasses.replace(sc, mode="waypoints", yaw=0.6)
    return simulate(sc, np.random.default_rng(20240612), sensors=SENSORS)


@pytest.fixture(scope="module")
def level_runs(level: Flight) -> dict[str, Estimate]:
    return {name: make(name).run(level) for name in ALL}


# --- accuracy: the frame and unit conversions -----------------------------------------

# (tilt RMSE, heading RMSE) in deg after 15 s, measured over 12 seeds (median / max):
# level: ekf 0.8/1.8 tilt, 3.8 heading max; madgwick 0.23/0.54, 0.76; mahony 0.34/0.49,
# 0.67; vqf 0.30/0.47, 0.42; vqf-offline 0.29/0.47, 0.49; imufusion 1.1/2.5, 2.6.
# The EKF and Fusion estimate no gyro bias: the 0.4 deg/s bias of the simulated gyro
# shows as a tilt and heading lag (bias / gain). Bounds sit above the worst seed.
LEVEL_BOUND = {  # tilt, heading
    "ahrs-ekf": (3.0, 5.0),
    "madgwick": (1.0, 1.5),
    "mahony": (1.0, 1.5),
    "vqf": (1.0, 1.5),
    "vqf-offline": (1.0, 1.5),
    "imufusion": (3.5, 3.5),
}


@pytest.mark.parametrize("name", ALL)
def test_level_flight_attitude_matches_truth(
    name: str, level: Flight, level_runs: dict[str, Estimate]
) -> None:
    est = level_runs[name]
    assert est.filter == name
    assert est.q_nb.shape == (len(level.imu.t), 4)
    assert est.cov is None and est.innovations == {}
    tilt, heading, _ = errors_deg(est, level)
    assert tilt < LEVEL_BOUND[name][0], (tilt, heading)
    assert heading < LEVEL_BOUND[name][1], (tilt, heading)


# quad (median / max over 12 seeds): tilt ekf 3.5/4.0, madgwick 2.4/2.8, mahony 4.8/5.2,
# vqf 4.2/4.8, vqf-offline 3.7/4.2, imufusion 4.0/4.6; heading ekf 2.8/4.1, madgwick
# 1.3/2.0, mahony 3.6/3.8, vqf 1.3/1.8, vqf-offline 0.7/1.3, imufusion 3.8/4.9. The tilt
# errors are the rotor-drag specific force (SPEC 5.3): an accelerometer-levelled filter
# reads the drag as tilt, ~5 deg at 3 m/s. A frame slip costs tens of degrees.
QUAD_BOUND = {
    "ahrs-ekf": (5.5, 5.5),
    "madgwick": (4.0, 3.0),
    "mahony": (6.5, 5.0),
    "vqf": (6.5, 3.0),
    "vqf-offline": (5.5, 2.0),
    "imufusion": (6.0, 6.0),
}


@pytest.mark.parametrize("name", ALL)
def test_quadrotor_attitude_matches_truth(name: str, quad: Flight) -> None:
    tilt, heading, _ = errors_deg(make(name).run(quad), quad)
    assert tilt < QUAD_BOUND[name][0], (tilt, heading)
    assert heading < QUAD_BOUND[name][1], (tilt, heading)


@pytest.mark.parametrize("name", ALL)
def test_rotated_flight_gives_the_same_heading_offset(
    name: str, level: Flight, level_runs: dict[str, Estimate]
) -> None:
    psi = 70.0 * DEG  # a mirrored heading (sign slip) would show -70 deg
    turned = rotate_heading(level, psi)
    est = make(name).run(turned)
    sel = level.imu.t >= T_SCORE
    yaw0 = euler_from_quat(level_runs[name].q_nb[sel])[:, 2]
    yaw1 = euler_from_quat(est.q_nb[sel])[:, 2]
    offset = float(np.mean(wrap(yaw1 - yaw0))) / DEG
    assert abs(offset - 70.0) < 1.5, offset
    tilt, heading, _ = errors_deg(est, turned)
    assert tilt < LEVEL_BOUND[name][0] and heading < LEVEL_BOUND[name][1], (tilt, heading)


# --- declination -----------------------------------------------------------------------


@pytest.mark.parametrize("name", ALL)
def test_declination_is_applied(name: str, level: Flight, level_runs: dict[str, Estimate]) -> None:
    """The site field has D = -8 deg. Known: heading from true north. Unknown
    (site.mag_n None): magnetic north is taken as north, so the same flight reads
    heading 8 deg higher (true = magnetic + D); the gyro-bias lag cancels in the pair."""
    assert level.site.mag_n is not None
    d = float(np.arctan2(level.site.mag_n[1], level.site.mag_n[0])) / DEG
    assert d == pytest.approx(-8.0, abs=0.1)
    _, _, mean_known = errors_deg(level_runs[name], level)
    assert abs(mean_known) < LEVEL_BOUND[name][1], mean_known
    unknown = level.replace(site=Site(mag_n=None))
    _, _, mean_unknown = errors_deg(make(name).run(unknown), unknown)
    assert mean_unknown - mean_known == pytest.approx(-d, abs=0.2)


# --- streaming -------------------------------------------------------------------------


def feed_by_hand(est: LibraryEstimator, flight: Flight, **kw: object) -> np.ndarray:
    """Stream a flight sample by sample through the public push interface; the state
    after each IMU sample (and the magnetometer samples at or before it)."""
    has = frozenset({"imu", "mag"} if flight.mag is not None else {"imu"})
    s = est.streamer(flight.site, has=has, **kw)  # type: ignore[arg-type]
    t, kinds, vals = merge_events(flight, has)
    out = []
    seen_imu = False
    for i in range(len(t)):
        if kinds[i] == EVENT_IMU:
            if seen_imu:
                out.append(s.state.q_nb)
            seen_imu = True
        s.push(int(kinds[i]), float(t[i]), vals[i])
    out.append(s.state.q_nb)
    return np.array(out)


@pytest.fixture(scope="module")
def short(level: Flight) -> Flight:
    """The first 12 s of the level flight, with NaN samples in both streams."""
    assert level.mag is not None and level.truth is not None
    n = int(np.searchsorted(level.imu.t, 12.0))
    m = int(np.searchsorted(level.mag.t, 12.0))
    w = level.imu.w_b[:n].copy()
    w[[0, 37, 38, 500]] = np.nan
    mag = level.mag.mag_b[:m].copy()
    mag[[3, 40]] = np.nan
    imu = dataclasses.replace(level.imu, t=level.imu.t[:n], w_b=w, f_b=level.imu.f_b[:n])
    tr = level.truth
    return level.replace(
        imu=imu,
        mag=MagStream(t=level.mag.t[:m], mag_b=mag),
        truth=dataclasses.replace(
            tr,
            t=tr.t[:n],
            q_nb=tr.q_nb[:n],
            v_n=None,
            wind_n=None,
            gyro_bias_b=None,
            accel_bias_b=None,
            p_n=None,
        ),
    )


@pytest.mark.parametrize("name", STREAMING)
def test_streaming_by_hand_equals_run(name: str, short: Flight) -> None:
    est = make(name, rate=100.0) if name in ("vqf", "imufusion") else make(name)
    batch = est.run(short)
    streamed = feed_by_hand(est, short)
    np.testing.assert_allclose(streamed, batch.q_nb, rtol=0, atol=1e-9)
    assert batch.skipped["imu"] == 4 and batch.skipped["mag"] == 2


@pytest.mark.parametrize("use_mag", ["auto", "off"])
@pytest.mark.parametrize("with_initial", [False, True])
def test_vqf_batch_path_equals_streaming(use_mag: str, with_initial: bool, short: Flight) -> None:
    """vqf's run() uses updateBatch; it must equal the per-sample replay."""
    est = Vqf(VqfParams(use_mag=use_mag))  # type: ignore[arg-type]
    initial = None
    if with_initial:
        assert short.truth is not None
        initial = InitialState(q_nb=short.truth.q_nb[0], gyro_bias_b=np.array([1e-3, 0, -2e-3]))
    batch = est.run(short, initial=initial)
    has = frozenset({"imu", "mag"}) if use_mag == "auto" else frozenset({"imu"})
    period = float(np.median(np.diff(short.imu.t)))
    s = est.streamer(short.site, initial=initial, has=has, period=period)
    streamed = replay(est, s, short, *merge_events(short, has))
    np.testing.assert_allclose(batch.q_nb, streamed.q_nb, rtol=0, atol=1e-9)
    assert batch.gyro_bias_b is not None and streamed.gyro_bias_b is not None
    np.testing.assert_allclose(batch.gyro_bias_b, streamed.gyro_bias_b, rtol=0, atol=1e-9)
    assert batch.skipped == streamed.skipped
    # Row 0 is NaN: both show the placeholder (the initial attitude, or level-north).
    q0 = initial.q_nb if initial is not None else np.array([1.0, 0, 0, 0])
    assert quat_angle(batch.q_nb[0], q0) < 1e-12


@pytest.mark.parametrize("name", ["vqf", "imufusion"])
def test_streaming_without_rate_takes_the_first_interval(name: str, short: Flight) -> None:
    """Without params.rate a streamer holds the first sample until the second gives the
    period; from then on it equals a run with that rate. (The first interval here is
    exactly 1/100 s; a period one ulp away moves VQF's rest detection by a sample.)"""
    streamed = feed_by_hand(make(name), short)
    batch = make(name, rate=1.0 / float(short.imu.t[2] - short.imu.t[1])).run(short)
    # row 0 is NaN, row 1 is the held first sample: identical from row 2 on
    np.testing.assert_allclose(streamed[2:], batch.q_nb[2:], rtol=0, atol=1e-9)


def test_vqf_offline_cannot_stream(level: Flight) -> None:
    with pytest.raises(NotImplementedError, match="non-causal"):
        VqfOffline().streamer(level.site, has=frozenset({"imu", "mag"}))


# --- sensors ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", ALL)
def test_six_axis_without_magnetometer(name: str, short: Flight) -> None:
    """Every adapter runs without a magnetometer (heading then drifts from its start)."""
    no_mag = short.replace(mag=None)
    six = make(name).run(no_mag)
    tilt, _, _ = errors_deg(six, no_mag, t0=5.0)
    assert tilt < LEVEL_BOUND[name][0] + 0.5, tilt
    # use_mag="off" ignores a magnetometer that is there: the same result
    off = make(name, use_mag="off").run(short)
    np.testing.assert_allclose(off.q_nb, six.q_nb, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ALL)
def test_required_magnetometer_missing(name: str, level: Flight) -> None:
    est = make(name, use_mag="required")
    with pytest.raises(MissingSensorError, match="mag"):
        est.run(level.replace(mag=None))
    if name != "vqf-offline":
        with pytest.raises(MissingSensorError, match=name):
            est.streamer(level.site, has=frozenset({"imu"}))


def test_gyro_bias_where_the_library_estimates_one(
    level: Flight, level_runs: dict[str, Estimate]
) -> None:
    assert level.truth is not None and level.truth.gyro_bias_b is not None
    truth = level.truth.gyro_bias_b[-1]
    for name, tol in (("vqf", 0.02), ("vqf-offline", 0.02), ("mahony", 0.05)):
        bias = level_runs[name].gyro_bias_b
        assert bias is not None and bias.shape == (len(level.imu.t), 3)
        assert np.max(np.abs(bias[-1] - truth)) < tol * DEG, (name, bias[-1], truth)
    for name in ("ahrs-ekf", "madgwick", "imufusion"):
        assert level_runs[name].gyro_bias_b is None


def test_initial_state_is_used(short: Flight) -> None:
    """Started at the truth, every streaming adapter is right from the first second
    (without it, they start level and north: 130 deg off in heading)."""
    assert short.truth is not None
    initial = InitialState.from_truth(short)
    for name in STREAMING:
        est = make(name).run(short, initial=initial)
        err = quat_angle(est.q_nb[:100], short.truth.q_nb[:100]) / DEG
        assert float(np.max(err)) < 3.0, (name, float(np.max(err)))


# --- parameters ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("cls", "field", "value"),
    [
        (AhrsEkfParams, "var_acc", float("nan")),
        (AhrsEkfParams, "use_mag", "yes"),
        (MadgwickParams, "gain_imu", -0.1),
        (MadgwickParams, "gain_marg", 0.0),
        (MahonyParams, "k_p", 0.0),
        (MahonyParams, "k_i", -1.0),
        (VqfParams, "rate", 0.0),
        (VqfParams, "tau_acc", -3.0),
        (VqfParams, "rest_bias_est", 1),
        (ImuFusionParams, "gain", -0.5),
        (ImuFusionParams, "rate", float("inf")),
        (ImuFusionParams, "rejection_timeout", -1.0),
    ],
)
def test_bad_params_name_the_field(cls: type, field: str, value: object) -> None:
    with pytest.raises(ValueError, match=f"{cls.__name__}.{field}"):
        cls(**{field: value})


def test_library_defaults() -> None:
    """Our defaults are the libraries' own."""
    import imufusion
    import vqf

    lib = vqf.VQF(0.01).params
    for ours, theirs in VqfParams().vqf_kwargs().items():
        assert lib[ours] == pytest.approx(theirs), ours
    s = imufusion.AhrsSettings()
    p = ImuFusionParams()
    for name in ("gain", "gyroscope_range", "acceleration_rejection", "magnetic_rejection"):
        assert getattr(s, name) == pytest.approx(getattr(p, name)), name
    assert s.rejection_timeout == pytest.approx(p.rejection_timeout)


def test_estimators_are_estimators() -> None:
    names = set()
    for name in ALL:
        est = make(name)
        assert isinstance(est, Estimator)
        assert est.name == name
        assert est.requires == frozenset({"imu"})
        names.add(est.name)
    assert names == set(ALL)


def test_params_from_toml(tmp_path: Path) -> None:
    path = tmp_path / "mad.toml"
    path.write_text('[windahrs]\ngain_marg = 0.1\nuse_mag = "off"\n')
    p = Madgwick.load_params(path)
    assert p == MadgwickParams(gain_marg=0.1, use_mag="off")
    path.write_text("[windahrs]\ngain = 0.1\n")
    with pytest.raises(ValueError, match="unknown parameter 'gain'"):
        Madgwick.load_params(path)
    path.write_text("[px4]\nEKF2_GYR_NOISE = 0.1\n")
    with pytest.raises(ValueError, match=r"\[windahrs\]"):
        Vqf.load_params(path)
    path.write_text("[windahrs]\ngain = -1.0\n")
    with pytest.raises(ValueError, match="ImuFusionParams.gain"):
        ImuFusion.load_params(path)
