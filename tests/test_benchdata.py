"""Benchmark on recorded data (BROAD metrics), alignment of a reference, and the real-data
acceptance checks: BROAD trials, PX4 sample.ulg against EKF2, ALFA wind against ArduPilot.

Real-data tests skip, saying why, when ../shared/data (or $WINDAHRS_DATA) is absent.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import require_data
from synthetic_logs import write_ansfl_dir
from trajectories import flight_in_place, rotating_in_place
from windahrs.cli import main
from windahrs.estimate import Estimate
from windahrs.experiments import benchdata
from windahrs.experiments.align import Alignment, apply_alignment, estimate_alignment, quat_average
from windahrs.experiments.benchdata import (
    BenchResult,
    Skipped,
    TrialScore,
    bench_data,
    broad_errors,
    discover_flights,
    discover_trials,
    split_error,
    trial_names,
)
from windahrs.filters.registry import make_estimator, names
from windahrs.flight import Flight, GnssStream, ImuStream, MagStream, Reference
from windahrs.io import read_flight
from windahrs.metrics import attitude_errors, heading_start_note, score
from windahrs.rotation import quat_conj, quat_exp, quat_log, quat_mul, quat_normalize
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.sim.sensors import SensorSuite
from windahrs.store import save_flight

DEG = math.pi / 180.0
BROAD_TRIALS = 7
ALFA_SEQUENCE = "carbonZ_2018-07-18-15-53-31_1_engine_failure"



# -- the error decomposition, on synthetic attitudes -------------------------------------


def _flight_with_reference(q_ref: np.ndarray, t: np.ndarray, *, heading_free: bool) -> Flight:
    """A flight scored against q_ref; with a magnetometer unless heading_free (a recording
    without one scores heading free of its datum: metrics.reference_of)."""
    n = len(t)
    imu = ImuStream(t=t, w_b=np.zeros((n, 3)), f_b=np.tile([0.0, 0.0, -9.80665], (n, 1)))
    kind = "mocap" if heading_free else "autopilot"
    mag = None if heading_free else MagStream(t=t, mag_b=np.tile([20e-6, 0.0, 45e-6], (n, 1)))
    return Flight(imu=imu, mag=mag, reference=Reference(t=t, q_nb=q_ref, kind=kind, heading_free=heading_free))


def _attitudes() -> tuple[np.ndarray, np.ndarray]:
    traj = rotating_in_place(30.0, 50.0)  # roll +-40, pitch +-25 deg, yaw sweeping
    return traj.t, traj.q_nb


def test_split_error_pure_heading_and_pure_tilt() -> None:
    total, heading, incl = split_error(quat_exp(np.array([[0.0, 0.0, 10 * DEG], [0.0, -5 * DEG, 0.0]])))
    assert np.allclose(np.degrees(total), [10.0, 5.0])
    assert np.allclose(np.degrees(heading), [10.0, 0.0])
    assert np.allclose(np.degrees(incl), [0.0, 5.0], atol=1e-6)
    # q and -q are the same error
    t2, h2, _ = split_error(-quat_exp(np.array([0.0, 0.0, 10 * DEG])))
    assert np.isclose(np.degrees(h2), 10.0) and np.isclose(np.degrees(t2), 10.0)


def test_pure_heading_error_gives_heading_only() -> None:
    t, q_ref = _attitudes()
    q_est = quat_mul(quat_exp(np.array([0.0, 0.0, 10 * DEG])), q_ref)  # nav-frame yaw error
    err = broad_errors(Estimate(filter="x", t=t, q_nb=q_est), _flight_with_reference(q_ref, t, heading_free=False))
    assert np.allclose(np.degrees(err.heading), 10.0, atol=1e-9)
    assert np.allclose(np.degrees(err.inclination), 0.0, atol=1e-6)
    assert np.allclose(np.degrees(err.total), 10.0, atol=1e-9)
    # A heading-free reference: the constant heading offset is removed, nothing is left.
    free = broad_errors(Estimate(filter="x", t=t, q_nb=q_est), _flight_with_reference(q_ref, t, heading_free=True))
    assert np.isclose(np.degrees(free.heading_offset), 10.0)
    assert np.degrees(free.total).max() < 1e-6


def test_without_a_magnetometer_heading_is_scored_free_of_its_datum() -> None:
    """Nothing on board a recording without a magnetometer shares its reference's north: a
    constant heading offset is removed before scoring (as for ANSFL's, or mocap)."""
    t, q_ref = _attitudes()
    q_est = quat_mul(quat_exp(np.array([0.0, 0.0, 40 * DEG])), q_ref)
    with_mag = _flight_with_reference(q_ref, t, heading_free=False)
    without = with_mag.replace(mag=None)
    est = Estimate(filter="x", t=t, q_nb=q_est)
    assert np.allclose(np.degrees(broad_errors(est, with_mag).heading), 40.0, atol=1e-9)
    free = broad_errors(est, without)
    assert np.isclose(np.degrees(free.heading_offset), 40.0) and np.degrees(free.total).max() < 1e-4
    assert score(est, without).rmse_total_deg < 1e-4 and score(est, with_mag).rmse_total_deg > 39.0


def test_the_heading_start_note_is_for_gnss_without_a_magnetometer() -> None:
    """The note on heading-free scoring is for a recording scored so for want of a magnetometer
    while GNSS velocity lets an INS learn north: not with a magnetometer, not without GNSS, not
    against a simulation's truth."""
    t, q_ref = _attitudes()
    with_mag = _flight_with_reference(q_ref, t, heading_free=False)
    gnss = GnssStream(t=t[::10], v_n=np.zeros((len(t[::10]), 3)))
    assert heading_start_note(with_mag.replace(gnss=gnss)) is None
    assert heading_start_note(with_mag.replace(mag=None)) is None
    text = heading_start_note(with_mag.replace(mag=None, gnss=gnss))
    assert text is not None and text.startswith("no magnetometer: heading scored free of its datum")
    quad = simulate(make_scenario("quadrotor", wind=0.0, duration=5.0), np.random.default_rng(0))
    assert heading_start_note(quad.replace(mag=None)) is None


def test_a_reference_with_no_valid_sample_says_so() -> None:
    t, q_ref = _attitudes()
    est = Estimate(filter="x", t=t, q_nb=q_ref)
    masked = _flight_with_reference(q_ref, t, heading_free=True)
    masked = masked.replace(reference=Reference(t=t, q_nb=q_ref, kind="mocap", heading_free=True,
                                                mask=np.zeros(len(t), dtype=bool)))
    with pytest.raises(ValueError, match="no valid sample \\(every one masked or NaN"):
        broad_errors(est, masked)
    later = _flight_with_reference(q_ref, t + 1000.0, heading_free=False)  # (valid, but not at est.t)
    with pytest.raises(ValueError, match="no valid sample overlaps the estimate in time"):
        broad_errors(est, later)


def test_pure_tilt_error_gives_inclination_only() -> None:
    t, q_ref = _attitudes()
    axis = np.column_stack([np.cos(0.7 * t), np.sin(0.7 * t), np.zeros_like(t)])  # horizontal, turning
    q_est = quat_mul(quat_exp(5 * DEG * axis), q_ref)
    for free in (False, True):
        flight = _flight_with_reference(q_ref, t, heading_free=free)
        err = broad_errors(Estimate(filter="x", t=t, q_nb=q_est), flight)
        assert np.allclose(np.degrees(err.inclination), 5.0, atol=1e-9)
        assert np.allclose(np.degrees(err.heading), 0.0, atol=1e-6)
        assert np.allclose(np.degrees(err.total), 5.0, atol=1e-9)


def test_inclination_is_the_metrics_tilt_and_parts_compose(rng: np.random.Generator) -> None:
    t, q_ref = _attitudes()
    q_est = quat_mul(quat_exp(rng.normal(0.0, 4 * DEG, (len(t), 3))), q_ref)
    flight = _flight_with_reference(q_ref, t, heading_free=False)
    est = Estimate(filter="x", t=t, q_nb=q_est)
    err = broad_errors(est, flight)
    ref = attitude_errors(est, flight)
    assert np.array_equal(err.index, ref.index)
    assert np.allclose(err.inclination, ref.tilt, atol=1e-9)
    assert np.allclose(err.total, ref.total, atol=1e-9)
    # swing-twist: cos(total/2) = cos(heading/2) cos(inclination/2)
    assert np.allclose(np.cos(err.total / 2), np.cos(err.heading / 2) * np.cos(err.inclination / 2))


def test_reference_gaps_and_mask_are_not_scored() -> None:
    t, q_ref = _attitudes()
    q_gap = q_ref.copy()
    q_gap[100:150] = np.nan
    mask = np.ones(len(t), dtype=bool)
    mask[:50] = False
    n = len(t)
    flight = Flight(
        imu=ImuStream(t=t, w_b=np.zeros((n, 3)), f_b=np.tile([0.0, 0.0, -9.8], (n, 1))),
        reference=Reference(t=t, q_nb=q_gap, kind="mocap", heading_free=True, mask=mask),
    )
    err = broad_errors(Estimate(filter="x", t=t, q_nb=q_ref), flight)
    assert len(err.index) == n - 100
    assert not np.isin(np.r_[0:50, 100:150], err.index).any()


# -- the result record and the file discovery -----------------------------------------


def _result() -> BenchResult:
    rows = [
        TrialScore(trial, f, total, incl, head, 100, 0.1)
        for trial, f, total, incl, head in [
            ("a", "mekf", 1.0, 0.5, 0.8),
            ("a", "vqf", 2.0, 0.6, 1.9),
            ("b", "mekf", 3.0, 0.7, 2.9),
            ("b", "vqf", 4.0, 0.8, 3.9),
            ("c", "mekf", 5.0, 0.9, 4.9),
            ("c", "vqf", 6.0, 1.0, 5.9),
        ]
    ]
    return BenchResult(scores=tuple(rows), trial_names=("a", "b", "c"), filters=("mekf", "vqf"))


def test_json_schema_and_median() -> None:
    out = json.loads(json.dumps(_result().as_json()))
    assert set(out) == {"trials", "median"}
    assert out["trials"][0] == {  # the samples and run time the text table shows, too
        "trial": "a", "filter": "mekf", "total_deg": 1.0, "inclination_deg": 0.5, "heading_deg": 0.8,
        "samples": 100, "seconds": 0.1,
    }
    assert out["median"] == {
        "mekf": {"total_deg": 3.0, "inclination_deg": 0.7, "heading_deg": 2.9},
        "vqf": {"total_deg": 4.0, "inclination_deg": 0.8, "heading_deg": 3.9},
    }


def test_table_has_a_block_per_trial_and_the_median() -> None:
    text = _result().table()
    for trial in ("a", "b", "c"):
        assert f"{trial}: RMSE in deg" in text
    assert "median over 3 trials: RMSE in deg" in text
    assert text.splitlines()[-1].split() == ["vqf", "4.000", "0.800", "3.900"]


def test_discover_trials_sorted_and_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=str(tmp_path)):
        discover_trials(tmp_path)
    with pytest.raises(FileNotFoundError, match="no such directory"):
        discover_trials(tmp_path / "missing")
    for name in ("b.hdf5", "a.h5", "notes.txt"):
        (tmp_path / name).write_bytes(b"")
    assert [p.name for p in discover_trials(tmp_path)] == ["a.h5", "b.hdf5"]


def test_bench_data_rejects_a_bad_spec_before_reading(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown 'nosuch'"):
        bench_data([tmp_path / "missing.hdf5"], ["nosuch"])
    with pytest.raises(ValueError, match="duplicates"):
        bench_data([tmp_path / "missing.hdf5"], ["mekf", "mekf"])


def test_failed_rows_and_skipped_in_json_and_table() -> None:
    ok = [TrialScore(t, "mekf", 1.0 + i, 0.5, 0.8, 100, 0.1) for i, t in enumerate(("a", "b"))]
    failed = TrialScore("b", "ins-wind", math.nan, math.nan, math.nan, 0, math.nan, error="needs GNSS")
    res = BenchResult(
        scores=(ok[0], TrialScore("a", "ins-wind", 3.0, 2.0, 1.0, 100, 0.1), ok[1], failed),
        trial_names=("a", "b"), filters=("mekf", "ins-wind"), skipped=(Skipped("x.ulg", "empty file"),),
    )
    out = json.loads(json.dumps(res.as_json(), allow_nan=False))
    assert out["trials"][3] == {"trial": "b", "filter": "ins-wind", "error": "needs GNSS"}
    assert out["median"]["ins-wind"] == {"total_deg": 3.0, "inclination_deg": 2.0, "heading_deg": 1.0}
    assert out["median"]["mekf"]["total_deg"] == 1.5
    assert out["skipped"] == [{"path": "x.ulg", "reason": "empty file"}] and "alignment" not in out
    text = res.table()
    assert "ins-wind    failed: needs GNSS" in text
    assert "(over the trials each filter ran on: ins-wind on 1 of 2)" in text
    assert text.endswith("skipped 1:\n  x.ulg: empty file")
    never = BenchResult(scores=(failed,), trial_names=("b",), filters=("ins-wind",))
    assert json.loads(json.dumps(never.as_json(), allow_nan=False))["median"]["ins-wind"]["total_deg"] is None
    assert never.table().splitlines()[-2].split() == ["ins-wind", "-", "-", "-"]


@pytest.fixture(scope="module")
def mixed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder as users have them: a simulated quadrotor without GNSS (windahrs .h5), two
    ANSFL flights written from a simulated IMU turning in place, a damaged log, an HDF5 file of another
    kind, a note, a hidden folder, and a link back to the top."""
    root = tmp_path_factory.mktemp("mixed")
    quad = simulate(make_scenario("quadrotor", wind=3.0, duration=6.0), np.random.default_rng(2))
    (root / "sim").mkdir()
    save_flight(quad.replace(gnss=None), root / "sim" / "quad.h5")
    turning = flight_in_place(SensorSuite(), seed=4, duration=20.0)
    for k in (10, 9):
        d = write_ansfl_dir(root / "ansfl" / "Horizontal" / f"path_{k}", turning)
        (d / "stray.ulg").write_text("a flight directory is not descended into")
    (root / "sim" / "broken.ulg").write_text("not a ULog")
    with h5py.File(root / "sim" / "other.h5", "w") as f:
        f["x"] = np.zeros(3)
    (root / "notes.txt").write_text("not a recording, not listed")
    (root / ".cache").mkdir()
    (root / ".cache" / "old.ulg").write_text("hidden, not listed")
    (root / "loop").symlink_to(root, target_is_directory=True)
    return root


def test_discover_flights_walks_any_folder(mixed: Path, tmp_path: Path) -> None:
    found = discover_flights(mixed)
    # broken.ulg is a ULog by its name: reading it fails later, and bench_data skips it then
    assert [p.relative_to(mixed).as_posix() for p in found.flights] == [
        "ansfl/Horizontal/path_9", "ansfl/Horizontal/path_10", "sim/broken.ulg", "sim/quad.h5"
    ]
    assert [(Path(s.path).name, s.reason.split(":")[0]) for s in found.skipped] == [
        ("other.h5", "unknown HDF5 layout")
    ]
    one = mixed / "ansfl" / "Horizontal" / "path_9"
    assert discover_flights(one).flights == (one,)
    assert discover_flights(mixed / "sim" / "quad.h5").flights == (mixed / "sim" / "quad.h5",)
    with pytest.raises(FileNotFoundError, match="no such file or directory"):
        discover_flights(tmp_path / "missing")
    with pytest.raises(FileNotFoundError, match="no recording the readers know"):
        discover_flights(tmp_path)


def test_a_folder_of_csv_files_no_reader_knows_is_listed_as_skipped(mixed: Path, tmp_path: Path) -> None:
    """A directory of CSV files that is no recording and holds none (an export in a layout
    the readers do not know) is said, not passed over; one without CSV files is passed over."""
    (tmp_path / "exports" / "odd").mkdir(parents=True)
    (tmp_path / "exports" / "odd" / "imu.csv").write_text("a,b\n1,2\n")
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "notes.txt").write_text("not a recording")
    (tmp_path / "quad.h5").symlink_to(mixed / "sim" / "quad.h5")
    found = discover_flights(tmp_path)
    assert [p.name for p in found.flights] == ["quad.h5"]
    assert [(Path(s.path).relative_to(tmp_path).as_posix(), s.reason.split(":")[0]) for s in found.skipped] == [
        ("exports/odd", "unknown directory format")
    ]


def test_trial_names_are_stems_unless_they_repeat(tmp_path: Path) -> None:
    a, b = tmp_path / "Horizontal" / "path_1", tmp_path / "Vertical" / "path_1"
    assert trial_names([a, tmp_path / "x" / "t.hdf5"]) == ["path_1", "t"]
    assert trial_names([a, b]) == ["Horizontal/path_1", "Vertical/path_1"]


#: [ins-wind] started with its heading known to 10 deg (the truth's, yaw 0): the flights turn in
#: place without a magnetometer, where nothing observes the heading and its default spread
#: without one (init_yaw pi) would stay open (a residual of 6.8 deg against the truth)
INS = "ins-wind:init_yaw=0.1745"


def test_bench_data_cli_over_a_mixed_folder(mixed: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench-data", str(mixed), "--filters", f"{INS},mekf", "--align", "--json"]) == 0
    std = capsys.readouterr()
    assert "clock of its own" not in std.err  # aligned: nothing to say
    out = json.loads(std.out)
    rows = {(r["trial"], r["filter"]): r for r in out["trials"]}
    assert list(rows) == [(t, f) for t in ("path_9", "path_10", "quad") for f in (INS, "mekf")]
    assert rows[("quad", INS)]["error"].startswith("filter 'ins-wind' needs GNSS velocity")
    for key in (("path_9", INS), ("path_10", "mekf"), ("quad", "mekf")):
        assert 0.0 <= rows[key]["inclination_deg"] < 10.0, rows[key]
        assert rows[key]["samples"] > 0 and rows[key]["seconds"] >= 0.0, rows[key]  # as the table shows
    assert [(Path(s["path"]).name, s["reason"].split(":")[0]) for s in out["skipped"]] == [
        ("other.h5", "unknown HDF5 layout"), ("broken.ulg", "not a readable ULog file (truncated or corrupt?)")
    ]
    al = out["alignment"]
    assert al["quad"] == {"skipped": "simulation truth is in the estimators' frame and on their clock by "
                                     "construction; nothing to align"}
    fitted = al["path_10"]
    assert set(fitted) == {"aligned_on", "mount_deg", "mount_rpy_deg", "mount_q", "time_offset_s",
                           "rate_agreement", "residual_deg", "samples", "warning", "gnss_time_shift_s",
                           "gnss_timing_sigma_s"}
    # the reference is the truth at 10 Hz on the IMU's clock: nothing to align but ins-wind's own errors
    assert fitted["aligned_on"] == INS and fitted["mount_deg"] < 1.0 and abs(fitted["time_offset_s"]) < 0.01
    assert fitted["rate_agreement"] > 0.99 and fitted["residual_deg"] < 2.0 and fitted["warning"] is None
    assert set(out["median"]) == {"mekf", INS}
    assert out["median"][INS]["total_deg"] == rows[("path_9", INS)]["total_deg"]  # two the same

    ansfl = mixed / "ansfl" / "Horizontal" / "path_9"
    assert main(["bench-data", str(mixed / "ansfl"), "--filters", "mekf"]) == 0
    std = capsys.readouterr()
    text = std.out
    assert text.startswith("path_9: RMSE in deg\nfilter")  # no alignment line without --align
    # scored as logged against a reference on its own clock: said once for the folder
    notes = [line for line in std.err.splitlines() if "clock of its own" in line]
    assert notes == [
        "windahrs: note: 2 recordings (path_9, path_10): the reference is stamped on a clock of its own, not the "
        "IMU's (meta reference.clock=own), at an unknown offset: scored as logged, the errors include that offset "
        "and the sensor's mount; --align fits and removes both"
    ]
    assert "median over 2 trials" in text and "skipped" not in text
    # GNSS velocity without a magnetometer, heading-free: said once for the folder too (the
    # simulated quadrotor, with its magnetometer and truth, is not among them)
    notes = [line for line in std.err.splitlines() if "no magnetometer" in line]
    assert notes == [f"windahrs: note: 2 recordings (path_9, path_10): {heading_start_note(read_flight(ansfl))}"]


def test_bench_data_cli_failures(mixed: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench-data", str(mixed), "--filters", "mekf,nosuch"]) == 2
    assert "unknown 'nosuch'" in capsys.readouterr().err
    (tmp_path / "bad.ulg").write_text("not a ULog")
    assert main(["bench-data", str(tmp_path), "--filters", "mekf"]) == 2
    std = capsys.readouterr()
    assert std.out == "" and "no readable recording" in std.err and "bad.ulg" in std.err


def test_ansfl_flights_with_align(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """bench-data --align over real ANSFL flights: the two shortest, linked (not copied) into
    a folder. The alignment finds the DOT's small mount and the clocks' few hundred ms."""
    horizontal = require_data("ansfl", "Horizontal")
    for name in ("path_12", "path_6"):
        (tmp_path / "Horizontal").mkdir(exist_ok=True)
        (tmp_path / "Horizontal" / name).symlink_to(horizontal / name, target_is_directory=True)
    first = "vqf" if "vqf" in names() else "mekf"
    assert main(["bench-data", str(tmp_path), "--filters", f"{first},ekf7", "--align", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert list(out["alignment"]) == ["path_6", "path_12"] and "skipped" not in out
    for fields in out["alignment"].values():
        assert fields["aligned_on"] == first
        assert fields["mount_deg"] < 6.0, fields  # a few degrees, not a frame error (~180)
        assert 0.1 < abs(fields["time_offset_s"]) < 0.6, fields
        assert fields["rate_agreement"] > 0.95, fields
    for row in out["trials"]:
        assert "error" not in row and math.isfinite(row["inclination_deg"]), row
        if row["filter"] == "vqf":
            assert row["inclination_deg"] < 10.0, row


# -- alignment ----------------------------------------------------------------------------

OFFSET_S = 0.12


def _mount(rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=3)
    return quat_exp(3 * DEG * axis / np.linalg.norm(axis))


def _misaligned(t: np.ndarray, q_true: np.ndarray, mount: np.ndarray, *, heading_free: bool) -> Flight:
    """The truth as a reference seen through a mount and stamped OFFSET_S late (plus, when
    heading-free, an arbitrary heading datum)."""
    q_ref = quat_mul(q_true, quat_conj(mount))
    if heading_free:
        q_ref = quat_mul(quat_exp(np.array([0.0, 0.0, 0.7])), q_ref)
    return _flight_with_reference(q_ref, t + OFFSET_S, heading_free=heading_free)


def _smooth_estimate(t: np.ndarray, q_true: np.ndarray) -> Estimate:
    """The truth with a slowly varying 0.1 deg error, as a good estimator would give."""
    err = 0.1 * DEG * np.column_stack([np.sin(0.3 * t + k) for k in range(3)])
    return Estimate(filter="x", t=t, q_nb=quat_mul(q_true, quat_exp(err)))


def _mount_error_deg(found: np.ndarray, mount: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(quat_log(quat_mul(quat_conj(found), mount)))))


def test_alignment_recovers_mount_and_offset_on_a_simulated_fixed_wing(rng: np.random.Generator) -> None:
    flight = simulate(make_scenario("fixedwing", wind=4.0, duration=60.0), rng)
    assert flight.truth is not None
    t, q = flight.truth.t, flight.truth.q_nb
    mount = _mount(rng)
    misaligned = _misaligned(t, q, mount, heading_free=False)
    al = estimate_alignment(_smooth_estimate(t, q), misaligned)
    assert abs(al.time_offset_s - OFFSET_S) < 0.005
    assert _mount_error_deg(al.q_mount, mount) < 0.1
    assert al.correlation > 0.99
    # Applied, the reference matches the truth again (up to the 0.1 deg estimate error).
    aligned = apply_alignment(misaligned, al)
    err = broad_errors(Estimate(filter="truth", t=t, q_nb=q), aligned)
    assert np.degrees(err.total).max() < 0.05
    assert aligned.meta["reference.time_offset_s"] == al.time_offset_s


def test_alignment_with_a_heading_free_reference(rng: np.random.Generator) -> None:
    traj = rotating_in_place(60.0, 200.0)
    mount = _mount(rng)
    misaligned = _misaligned(traj.t, traj.q_nb, mount, heading_free=True)
    al = estimate_alignment(_smooth_estimate(traj.t, traj.q_nb), misaligned)
    assert abs(al.time_offset_s - OFFSET_S) < 0.005
    assert _mount_error_deg(al.q_mount, mount) < 0.1
    assert al.residual_deg < 0.2


def test_alignment_bad_input() -> None:
    t, q = _attitudes()
    flight = _flight_with_reference(q, t, heading_free=False)
    with pytest.raises(ValueError, match="max_offset_s"):
        estimate_alignment(Estimate(filter="x", t=t, q_nb=q), flight, max_offset_s=0.0)
    still = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))
    with pytest.raises(ValueError, match="barely rotates"):
        estimate_alignment(Estimate(filter="x", t=t, q_nb=still), _flight_with_reference(still, t, heading_free=False))
    with pytest.raises(ValueError, match="reference"):
        apply_alignment(flight.replace(reference=None), Alignment(q_mount=np.array([1.0, 0, 0, 0]), time_offset_s=0.0))


def test_quat_average_is_sign_insensitive(rng: np.random.Generator) -> None:
    q0 = quat_exp(np.array([0.3, -0.2, 0.5]))
    q = quat_mul(q0, quat_exp(rng.normal(0.0, 0.01, (500, 3))))
    q[::2] *= -1.0
    assert _mount_error_deg(quat_average(q), quat_normalize(q0)) < 0.1


# -- real data ------------------------------------------------------------------------------


def test_broad_trials_mekf_and_vqf() -> None:
    folder = require_data("broad")
    paths = discover_trials(folder)
    assert len(paths) == BROAD_TRIALS, f"expected the {BROAD_TRIALS} BROAD trials in {folder}"
    specs = ["mekf"]
    if "vqf" in names():
        specs.append("vqf")
    calls: list[tuple[int, int]] = []
    result = bench_data(paths, specs, progress=lambda done, total: calls.append((done, total)))
    assert calls[-1] == (len(paths) * len(specs),) * 2
    out = json.loads(json.dumps(result.as_json()))
    assert [(r["trial"], r["filter"]) for r in out["trials"]] == [(p.stem, s) for p in paths for s in specs]
    for row in out["trials"]:
        for key in benchdata.METRICS:
            assert math.isfinite(row[key]) and 0.0 <= row[key] < 90.0, row
        assert row["inclination_deg"] <= row["total_deg"] + 1e-9
        assert row["heading_deg"] <= row["total_deg"] + 1e-9
    assert set(out["median"]) == set(specs)
    assert all(math.isfinite(v) for m in out["median"].values() for v in m.values())
    text = result.table()
    assert all(f"{p.stem}: RMSE in deg" in text for p in paths)
    if "vqf" not in specs:
        pytest.skip("vqf adapter not in the registry (pip install 'windahrs[baselines]'); mekf checked")


def test_sample_ulg_mekf_tilt_against_ekf2() -> None:
    flight = read_flight(require_data("px4", "sample.ulg"))
    assert flight.reference is not None and flight.reference.kind == "autopilot"
    tilt = score(make_estimator("mekf").run(flight), flight).rmse_tilt_deg
    # Issue acceptance: at most 0.5 deg RMS. Measured 0.42 deg; a constant 0.39 deg
    # rotation between [mekf] and EKF2 (estimate_alignment) makes up most of it.
    assert tilt <= 0.5, f"[mekf] tilt RMS against EKF2: {tilt:.3f} deg"


# ALFA's raw IMU is a 10 Hz stream of point samples (mavros imu/data_raw), not means over
# the interval as the densities assume for a >= 100 Hz IMU. The filters add the noise of
# holding each sample over motion it did not measure by themselves (unmeasured_motion_dt:
# (dw dt)^2/3 from the sample-to-sample changes), so [ins-wind] and [auto] run with no
# overrides. The older hand rule of docs/estimators.md (1 rad/s^2 and 10 m/s^3 held over
# dt = 0.1 s: gyro_noise=0.018, accel_noise=0.18) still passes with the held-sample noise on
# top for [ins-wind]. [mekf-air] passes only in its old configuration (the rule, no
# held-sample noise): with more attitude noise its magnetometer, self-referenced at an
# attitude 20 deg off (the recording starts in flight) and offset 9-17 uT by the motor, is
# accepted and holds the tilt there while its accelerometer is gated out for good (the
# default [mekf-air] failed before too, 61.5 deg off in direction).
ALFA_SPECS = (
    "ins-wind",
    "ins-wind:airspeed_scale=true",
    "auto",
    "ins-wind:gyro_noise=0.018:accel_noise=0.18",
    "mekf-air:gyro_noise=0.018:unmeasured_motion_dt=1e9",
)
# ArduPilot's wind estimate is still settling at the start of the recording: its 10 s means
# move from (-5.6, -2.5) m/s N/E at 0-10 s to (-2.5, 0.2) at 40 s, while the wind triangle
# from the autopilot's own attitude, airspeed and GNSS stays near (-1.5, 0.5). Compare from
# 30 s, once both estimates have settled, to the failure.
ALFA_FROM_S = 30.0


def _wind_summary(t: np.ndarray, wind_n: np.ndarray, t0: float, t1: float) -> tuple[float, float]:
    """(direction of the mean horizontal wind in rad, mean horizontal speed in m/s)."""
    w = wind_n[(t >= t0) & (t < t1), :2]
    mean = w.mean(axis=0)
    return math.atan2(mean[1], mean[0]), float(np.linalg.norm(w, axis=1).mean())


@pytest.mark.parametrize("spec", ALFA_SPECS)
def test_alfa_wind_against_the_autopilot(spec: str) -> None:
    flight = read_flight(require_data("alfa", ALFA_SEQUENCE))
    assert flight.ref_wind is not None and "failure_time" in flight.meta
    t_fail = float(flight.meta["failure_time"])
    est = make_estimator(spec).run(flight)
    assert est.wind_n is not None
    d_est, s_est = _wind_summary(est.t, est.wind_n, ALFA_FROM_S, t_fail)
    d_ref, s_ref = _wind_summary(flight.ref_wind.t, flight.ref_wind.wind_n, ALFA_FROM_S, t_fail)
    d_err = math.degrees((d_est - d_ref + math.pi) % (2 * math.pi) - math.pi)
    assert abs(d_err) <= 30.0, f"{spec}: mean wind direction off by {d_err:.1f} deg"
    assert abs(s_est - s_ref) <= 1.5, f"{spec}: mean wind speed {s_est:.2f} vs {s_ref:.2f} m/s"



def test_an_alignment_of_little_common_motion_is_flagged() -> None:
    """The mount and offset are unreliable when the residual is large or the two series'
    body rates hardly agree (a vehicle at rest: PX4 sample_log_small.ulg, agreement 0.198)."""
    from windahrs.experiments.align import ALIGN_MIN_RATE_AGREEMENT, alignment_warning

    q = np.array([1.0, 0.0, 0.0, 0.0])
    assert alignment_warning(Alignment(q, 0.0, correlation=0.99, residual_deg=1.0)) is None
    low = alignment_warning(Alignment(q, 0.0, correlation=0.198, residual_deg=3.2))
    assert low is not None and "agree by only 0.198" in low and "unreliable" in low
    assert alignment_warning(Alignment(q, 0.0, correlation=ALIGN_MIN_RATE_AGREEMENT, residual_deg=1.0)) is None
    big = alignment_warning(Alignment(q, 0.0, correlation=0.99, residual_deg=6.0))
    assert big is not None and "residual" in big


def test_px4_at_rest_alignment_is_flagged() -> None:
    path = require_data("px4", "sample_log_small.ulg")
    flight = read_flight(path)
    from windahrs.experiments.align import alignment_warning

    est = make_estimator("vqf").run(flight)
    al = estimate_alignment(est, flight)
    assert al.correlation < 0.5 and alignment_warning(al) is not None  # measured 0.198
    line = benchdata._alignment_line(benchdata.AlignmentOutcome(alignment=al, aligned_on="vqf", warning="x"))
    assert line.endswith("(unreliable: rate agreement under 0.5: too little common motion)")


def test_estimator_warnings_name_the_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Over a folder, an estimator's warning says which recording it is about (and the other
    recording, which has nothing to warn of, gets no line)."""
    quad = simulate(make_scenario("quadrotor", wind=3.0, duration=6.0), np.random.default_rng(2)).replace(gnss=None)
    save_flight(quad, tmp_path / "calm.h5")
    w = quad.imu.w_b.copy()
    w[600, 0] += 30.0  # one glitched gyro sample: held by the IMU screen, which warns
    save_flight(quad.replace(imu=ImuStream(quad.imu.t, w, quad.imu.f_b)), tmp_path / "spiky.h5")
    assert main(["bench-data", str(tmp_path), "--filters", "mekf"]) == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "warning:" in ln]
    assert lines and all(ln.startswith("windahrs bench-data: warning: spiky: mekf: ") for ln in lines), lines
    assert any("IMU samples not propagated" in ln for ln in lines), lines


def test_naming_warnings_reissues_when_the_block_raises() -> None:
    with pytest.warns(UserWarning, match=r"^trial_3: late$"), pytest.raises(RuntimeError):
        with benchdata._naming_warnings("trial_3"):
            warnings.warn("late", UserWarning, stacklevel=1)
            raise RuntimeError("the run failed")
