"""A GNSS stream declared on the reference's clock (``meta["gnss.clock"] = "reference"``, the
ANSFL reader's) is moved by the clock offset ``--align`` fits, and its declared timing
uncertainty lowered to the fit's: the sign is checked on a synthetic ANSFL directory whose
DJI log is stamped late by a known amount (the oracle is the simulation's own clock), and
on one real flight (skipped without ../shared/data).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from conftest import require_data
from synthetic_logs import write_ansfl_dir
from windahrs.experiments.align import GNSS_CLOCK_KEY, Alignment, align_gnss_clock
from windahrs.experiments.benchdata import bench_data
from windahrs.experiments.compare import align_reference, compare
from windahrs.filters.registry import make_estimator
from windahrs.flight import Flight
from windahrs.io import read_ansfl
from windahrs.io.ansfl import ANSFL_GNSS_TIMING_SIGMA
from windahrs.sim.scenario import make_scenario, simulate

LATE_S = 0.3  # the DJI log's stamps are this late against the IMU's (the simulation's) clock


@pytest.fixture(scope="module")
def sim() -> Flight:
    # A quadrotor manoeuvring in wind: rotation for the clock fit, and a velocity that
    # changes, so a wrong shift shows in the GNSS against the truth.
    return simulate(make_scenario("quadrotor", wind=3.0, duration=30.0), np.random.default_rng(5))


@pytest.fixture(scope="module")
def late_dir(tmp_path_factory: pytest.TempPathFactory, sim: Flight) -> Path:
    d = write_ansfl_dir(tmp_path_factory.mktemp("ansfl") / "path_1", sim)
    gt = d / "GT.csv"
    lines = gt.read_text().splitlines()
    rows = [line.split(",", 1) for line in lines[1:]]
    gt.write_text("\n".join([lines[0], *(f"{float(t) + LATE_S:.10g},{rest}" for t, rest in rows)]) + "\n")
    return d


def _gnss_error(flight: Flight, sim: Flight) -> float:
    """RMS of the GNSS velocity against the truth at the GNSS stamps, m/s."""
    assert flight.gnss is not None and sim.truth is not None
    t = flight.gnss.t
    inside = (t > sim.truth.t[0] + 1.0) & (t < sim.truth.t[-1] - 1.0)
    truth = np.column_stack([np.interp(t[inside], sim.truth.t, sim.truth.v_n[:, a]) for a in range(3)])
    return float(np.sqrt(np.mean((flight.gnss.v_n[inside] - truth) ** 2)))


def test_shift_sign_and_lowered_timing(late_dir: Path, sim: Flight) -> None:
    pytest.importorskip("vqf", reason="the alignment is fitted on vqf (pip install 'windahrs[baselines]')")
    flight = read_ansfl(late_dir)
    assert flight.meta[GNSS_CLOCK_KEY] == "reference"
    assert flight.meta["gnss.timing_sigma_s"] == ANSFL_GNSS_TIMING_SIGMA
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # vqf as the brief's benchmarks fit on it (mekf's 6-D tilt lags in the turns)
        outcome = align_reference(flight, ("vqf", make_estimator("vqf").run(flight)))
    al = outcome.alignment
    assert al is not None and al.time_offset_s == pytest.approx(LATE_S, abs=0.02)  # reference stamps late
    moved = outcome.run_flight(flight)
    assert moved.gnss is not None and flight.gnss is not None
    # moved back onto the IMU's clock: each stamp earlier by the fitted offset
    np.testing.assert_allclose(moved.gnss.t, flight.gnss.t - al.time_offset_s)
    assert outcome.gnss_shift_s == pytest.approx(-al.time_offset_s)
    assert moved.meta["gnss.time_shift_s"] == pytest.approx(-al.time_offset_s)
    # the declared timing uncertainty is the fit's: a 10 Hz reference, 0.1 s / sqrt(12)
    assert moved.meta["gnss.timing_sigma_s"] == pytest.approx(0.1 / math.sqrt(12.0), rel=1e-6)
    assert outcome.gnss_timing_sigma_s == moved.meta["gnss.timing_sigma_s"] < ANSFL_GNSS_TIMING_SIGMA
    assert moved.meta[GNSS_CLOCK_KEY] == "estimate" and flight.meta[GNSS_CLOCK_KEY] == "reference"
    # the truth says the moved stream is right: 0.3 s of a turn's acceleration was the error
    before, after = _gnss_error(flight, sim), _gnss_error(moved, sim)
    assert after < 0.2 * before, (before, after)
    assert align_gnss_clock(moved, al) is moved  # moved once: now on the estimate's clock
    assert f"GNSS on the reference's clock: stamps moved by {-al.time_offset_s * 1e3:+.1f} ms" in (outcome.text or "")


def test_bench_data_runs_the_other_filters_on_the_moved_gnss(late_dir: Path) -> None:
    pytest.importorskip("vqf", reason="the alignment is fitted on vqf (pip install 'windahrs[baselines]')")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = bench_data([late_dir], ["vqf", "ins-wind"], align=True)
        cmp = compare(read_ansfl(late_dir), "vqf,ins-wind", align=True)
        logged = make_estimator("ins-wind").run(read_ansfl(late_dir))
    fields = res.as_json()["alignment"]["path_1"]
    assert fields["gnss_time_shift_s"] == pytest.approx(-LATE_S, abs=0.02)
    assert fields["gnss_timing_sigma_s"] == pytest.approx(0.1 / math.sqrt(12.0), rel=1e-6)
    assert cmp.as_json()[1]["gnss_time_shift_s"] == pytest.approx(fields["gnss_time_shift_s"])
    # ins-wind ran on the moved stream: its GNSS stamps (innovation times) are earlier
    ins = dict(cmp.estimates)["ins-wind"]
    t_moved, t_logged = ins.innovations["gnss"].t, logged.innovations["gnss"].t
    assert t_moved[0] == pytest.approx(t_logged[0] - LATE_S, abs=0.02)
    assert [s.ok for s in res.scores] == [True, True]


def test_not_declared_or_not_fitted_leaves_the_gnss(late_dir: Path) -> None:
    flight = read_ansfl(late_dir)
    al = Alignment(q_mount=np.array([1.0, 0.0, 0.0, 0.0]), time_offset_s=0.25, time_sigma_s=0.01)
    other = flight.replace(meta={k: v for k, v in flight.meta.items() if k != GNSS_CLOCK_KEY})
    assert align_gnss_clock(other, al) is other
    assert align_gnss_clock(flight.replace(gnss=None), al).gnss is None
    moved = align_gnss_clock(flight, al)
    assert moved.gnss is not None and moved.gnss.t[0] == pytest.approx(flight.gnss.t[0] - 0.25)  # type: ignore[union-attr]
    with pytest.raises(ValueError, match="time_offset_s: expected a finite time"):
        align_gnss_clock(flight, Alignment(q_mount=al.q_mount, time_offset_s=math.nan))
    with pytest.raises(ValueError, match="time_sigma_s: expected >= 0 s"):
        align_gnss_clock(flight, Alignment(q_mount=al.q_mount, time_offset_s=0.1, time_sigma_s=-1.0))


def test_auto_hands_over_to_the_ins_once_it_knows_a_heading(sim: Flight) -> None:
    """Without a magnetometer the INS has no heading to start with: mekf's tilt until it
    knows one (filters.auto; the mechanics in tests/test_auto.py)."""
    headless = sim.replace(mag=None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = make_estimator("auto").run(headless)
        with_mag = make_estimator("auto").run(sim)
    assert est.meta["auto"] == "ins-wind" and est.meta["sensors"] == "imu,gnss"
    assert "without a magnetometer" in est.meta["auto_reason"] and est.meta["auto_handover_s"] > 0
    assert with_mag.meta["auto"] == "ins-wind" and "auto_handover_s" not in with_mag.meta


def test_real_ansfl_flight_shift_agrees_with_the_gnss_accelerations() -> None:
    # path_8: --align finds the DJI stamps about 0.4 s early; the GNSS acceleration
    # (velocity differences) then matches the IMU's (rotated by vqf, gravity removed)
    # better once moved than as logged.
    root = require_data("ansfl", "Horizontal", "path_8")
    pytest.importorskip("vqf", reason="the alignment is fitted on vqf (pip install 'windahrs[baselines]')")
    flight = read_ansfl(root)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = make_estimator("vqf").run(flight)
    outcome = align_reference(flight, ("vqf", est))
    assert outcome.alignment is not None and -0.5 < outcome.alignment.time_offset_s < -0.3
    moved = outcome.run_flight(flight)
    assert moved.meta["gnss.timing_sigma_s"] < 0.05

    from windahrs.rotation import quat_rotate

    a_n = quat_rotate(est.q_nb, flight.imu.f_b) + np.array([0.0, 0.0, 9.80665])
    k = round(0.2 / float(np.median(np.diff(flight.imu.t))))
    a_imu = np.column_stack([np.convolve(a_n[:, i], np.ones(k) / k, "same") for i in range(3)])

    def agreement(f: Flight) -> float:
        assert f.gnss is not None
        a_g = np.gradient(f.gnss.v_n, f.gnss.t, axis=0)
        t = f.gnss.t[(f.gnss.t > 1.0) & (f.gnss.t < flight.imu.t[-1] - 1.0)]
        g = np.hypot(*(np.interp(t, f.gnss.t, a_g[:, i]) for i in range(2)))
        m = np.hypot(*(np.interp(t, flight.imu.t, a_imu[:, i]) for i in range(2)))
        return float(np.corrcoef(g, m)[0, 1])

    assert agreement(moved) > agreement(flight) + 0.1, (agreement(flight), agreement(moved))


@pytest.mark.parametrize("spec", ["ins-wind", "mekf"])
def test_init_yaw_spreads_the_attitude_about_the_nav_vertical(sim: Flight, spec: str) -> None:
    from windahrs.rotation import dcm_from_quat

    flight = sim.replace(mag=None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        wide = make_estimator(f"{spec}:init_yaw=1.0").run(flight)
        plain = make_estimator(spec).run(flight)
    # without a magnetometer [ins-wind]'s heading is unknown at the start (pi); [mekf]'s init_att
    plain_yaw = math.pi if spec == "ins-wind" else math.radians(10.0)
    for est, yaw_sigma in ((wide, 1.0), (plain, plain_yaw)):
        P, q = est.att_cov(), est.q_nb[est.cov_rows[0]]
        assert P is not None
        d = dcm_from_quat(q)[2]  # the nav vertical in the body frame, C_bn e_3
        assert float(d @ P[0] @ d) == pytest.approx(yaw_sigma**2, rel=0.02)
    # about the vertical only: the tilt's spread is init_att's in both
    P_w, P_p = wide.att_cov(), plain.att_cov()
    assert P_w is not None and P_p is not None
    assert np.trace(P_w[0]) - 1.0 == pytest.approx(np.trace(P_p[0]) - plain_yaw**2, abs=1e-5)
    with pytest.raises(ValueError, match="init_yaw"):
        make_estimator("ins-wind:init_yaw=-1")


def test_the_benchmarks_real_data_loop_runs_on_the_moved_gnss(late_dir: Path) -> None:
    """aligned_recordings (benchmarks/auto_check.py, silent.py) gives the flight the filters
    run on as bench-data --align has it: the GNSS moved onto the IMU's clock."""
    pytest.importorskip("vqf", reason="the alignment is fitted on vqf (pip install 'windahrs[baselines]')")
    from windahrs.experiments.benchdata import aligned_recordings

    logged = read_ansfl(late_dir)
    ((path, run, scored),) = list(aligned_recordings(late_dir.parent))
    assert path == late_dir
    assert run.gnss is not None and logged.gnss is not None
    assert run.gnss.t[0] == pytest.approx(logged.gnss.t[0] - LATE_S, abs=0.02)
    assert run.meta["gnss.timing_sigma_s"] < logged.meta["gnss.timing_sigma_s"]
    assert scored.reference is not None and logged.reference is not None
    assert scored.reference.t[0] == pytest.approx(logged.reference.t[0] - LATE_S, abs=0.02)
