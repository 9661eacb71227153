"""The ANSFL reader (DJI flight log + Xsens DOT CSV): a directory written by the test from a
simulated flight reads back in SI and NED/FRD (the oracle is the simulation, converted by
the test's own code), the IMU choice and the header rules, its errors, and one real flight.

Real-data tests read $WINDAHRS_DATA (default ../shared/data) and skip where it is absent.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from conftest import require_data
from synthetic_logs import ANSFL_GT_HEADER, write_ansfl_dir
from windahrs.flight import Flight
from windahrs.io import LogFormatError, detect_format, read_ansfl, read_flight
from windahrs.io.ansfl import ANSFL_GNSS_TIMING_SIGMA
from windahrs.rotation import quat_angle
from windahrs.sim.scenario import make_scenario, simulate


@pytest.fixture(scope="module")
def sim() -> Flight:
    # A fixed wing at 15 m/s, level for 20 s and then turning: rotation in every axis and a
    # velocity that changes, so frames, signs and the differentiated velocity are exercised.
    return simulate(make_scenario("fixedwing", wind=3.0, duration=30.0), np.random.default_rng(5))


def test_round_trip_units_frames_and_reference(tmp_path: Path, sim: Flight) -> None:
    d = write_ansfl_dir(tmp_path / "path_1", sim)
    assert detect_format(d) == "ansfl"
    f = read_flight(d)
    assert sim.truth is not None and sim.truth.v_n is not None
    # IMU: deg/s -> rad/s, DOT axes (forward, left, up) -> FRD, on the DOT's time stamps
    np.testing.assert_allclose(f.imu.t, sim.imu.t, atol=1e-9)
    np.testing.assert_allclose(f.imu.w_b, sim.imu.w_b, rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(f.imu.f_b, sim.imu.f_b, rtol=1e-8, atol=1e-8)
    # reference: DJI roll, pitch, compass heading (0-360) -> q_nb equal to the truth
    ref = f.reference
    assert ref is not None and (ref.kind, ref.heading_free) == ("autopilot", True)
    step = round(0.1 / float(np.median(np.diff(sim.truth.t))))
    np.testing.assert_allclose(ref.t, sim.truth.t[::step], atol=1e-9)
    assert float(np.max(quat_angle(ref.q_nb, sim.truth.q_nb[::step]))) < 1e-7
    # GNSS: central differences of the NED positions at 10 Hz against the true velocity
    assert f.gnss is not None and f.meta["gnss.derived_from"] == "position"
    assert f.meta["gnss.timing_sigma_s"] == ANSFL_GNSS_TIMING_SIGMA  # DJI's clock, not the DOT's
    err = np.abs(f.gnss.v_n - sim.truth.v_n[::step])
    assert float(np.max(err[1:-1])) < 0.05, "central differences of a smooth path"
    assert f.mag is None and f.truth is None
    assert f.meta["format"] == "ansfl" and f.meta["ansfl.imu_file"] == "IMU_1.csv"


def test_scoring_without_align_says_the_reference_has_its_own_clock(
    tmp_path: Path, sim: Flight, capsys: pytest.CaptureFixture[str]
) -> None:
    """DJI's log and the DOT's are on two clocks: the reader declares it, and compare,
    estimate and report scoring against the reference as logged say so (once), pointing to
    --align; with --align, or on a flight on one clock, they say nothing of it."""
    from windahrs.cli import main
    from windahrs.experiments.align import REFERENCE_CLOCK_KEY, unaligned_clock_note

    d = write_ansfl_dir(tmp_path / "path_5", sim)
    f = read_flight(d)
    assert f.meta[REFERENCE_CLOCK_KEY] == "own" and unaligned_clock_note(f) is not None
    assert unaligned_clock_note(sim) is None  # a simulation: one clock
    said = "windahrs: note: the reference is stamped on a clock of its own, not the IMU's"
    assert main(["compare", str(d), "--filters", "mekf,ekf7"]) == 0
    assert capsys.readouterr().err.count(said) == 1
    assert main(["estimate", str(d), "--filter", "mekf"]) == 0
    err = capsys.readouterr().err
    assert err.count(said) == 1 and err.rstrip().endswith("compare --align fits and removes both")
    assert main(["report", str(d), "--filters", "mekf", "--out", str(tmp_path / "r.html")]) == 0
    assert capsys.readouterr().err.count(said) == 1
    assert main(["compare", str(d), "--filters", "mekf", "--align"]) == 0
    assert "clock of its own" not in capsys.readouterr().err


def test_imu_choice_and_gnss_option(tmp_path: Path, sim: Flight) -> None:
    d = write_ansfl_dir(tmp_path / "path_2", sim, imus=(4, 2))  # IMU k adds k-1 m/s^2 on x
    assert detect_format(d) == "ansfl"
    dx = {k: float(np.mean(read_flight(d, **kw).imu.f_b[:, 0] - sim.imu.f_b[:, 0]))
          for k, kw in ((2, {}), (4, {"imu": 4}))}
    assert dx == pytest.approx({2: 1.0, 4: 3.0}, abs=1e-6)
    flight = read_ansfl(d, imu=2, gnss=False)
    assert flight.gnss is None and flight.meta["ansfl.imus"] == "2,4"
    assert "gnss.timing_sigma_s" not in flight.meta
    with pytest.raises(LogFormatError, match=r"IMU_1\.csv: no such file \(IMU 1; this flight has: IMU_2\.csv, "
                                              r"IMU_4\.csv\)"):
        read_ansfl(d, imu=1)
    for bad in ("1", -1, True, 1.0):
        with pytest.raises(ValueError, match="imu: expected"):
            read_ansfl(d, imu=bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="gnss: expected True or False"):
        read_ansfl(d, gnss="no")  # type: ignore[arg-type]
    with pytest.raises(LogFormatError, match="option not known to the ansfl reader"):
        read_flight(d, multi_id=1)


def test_header_blanks_and_missing_column(tmp_path: Path, sim: Flight) -> None:
    d = write_ansfl_dir(tmp_path / "path_3", sim)
    gt = d / "GT.csv"
    text = gt.read_text()
    assert text.startswith(ANSFL_GT_HEADER + "\n") and " pitch(degrees)" in ANSFL_GT_HEADER
    q_logged = read_ansfl(d).reference
    # a header without the DJI log's leading blanks reads the same
    gt.write_text(text.replace(", ", ",", 3))
    assert ", " not in gt.read_text().splitlines()[0]
    q_plain = read_ansfl(d).reference
    assert q_logged is not None and q_plain is not None
    np.testing.assert_array_equal(q_plain.q_nb, q_logged.q_nb)
    gt.write_text(text.replace(" pitch(degrees)", "pitch_deg"))
    with pytest.raises(LogFormatError, match=r"GT\.csv: missing column\(s\) \['pitch\(degrees\)'\]"):
        read_ansfl(d)


def test_not_an_ansfl_flight(tmp_path: Path, sim: Flight) -> None:
    d = write_ansfl_dir(tmp_path / "path_4", sim)
    (d / "IMU_1.csv").rename(d / "IMU_avg.csv")  # an average of several DOTs is not one IMU
    with pytest.raises(LogFormatError, match="unknown directory format: .* GT.csv with IMU_<k>.csv"):
        detect_format(d)
    with pytest.raises(LogFormatError, match="no IMU_<k>.csv file"):
        read_ansfl(d)
    (d / "IMU_avg.csv").rename(d / "IMU_1.csv")
    (d / "GT.csv").unlink()
    with pytest.raises(LogFormatError, match=r"GT\.csv: no such file"):
        read_ansfl(d)
    with pytest.raises(LogFormatError, match="not a directory"):
        read_ansfl(d / "IMU_1.csv")


def test_real_flight_units_and_streams() -> None:
    f = read_flight(require_data("ansfl", "Horizontal", "path_10"))
    assert f.meta["format"] == "ansfl" and f.meta["ansfl.imu_file"] == "IMU_1.csv"
    rate = 1.0 / float(np.median(np.diff(f.imu.t)))
    assert rate == pytest.approx(120.0, rel=1e-3) and len(f.imu.t) > 5000
    first = f.imu.t < f.imu.t[0] + 1.0
    # the rotors turn and the airframe vibrates: |f| is near g on average, not exactly
    assert 9.0 < float(np.mean(np.linalg.norm(f.imu.f_b[first], axis=1))) < 11.0
    assert float(np.mean(f.imu.f_b[:, 2])) < -9.0  # FRD: z down, a hovering IMU reads -g on z
    w_max = float(np.max(np.abs(f.imu.w_b)))
    assert 0.5 < w_max < 10.0, f"gyro in rad/s: max |w| {w_max:.3g}"
    ref = f.reference
    assert ref is not None and ref.kind == "autopilot" and ref.heading_free
    assert np.isfinite(ref.q_nb).all() and len(ref.t) == 468
    assert f.gnss is not None and len(f.gnss.t) == len(ref.t)
    speed = np.linalg.norm(f.gnss.v_n[:, :2], axis=1)
    assert 2.0 < float(np.max(speed)) < 20.0
    assert math.isclose(float(f.gnss.t[0]), 0.0, abs_tol=1e-12)
