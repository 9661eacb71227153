"""Fault injection (windahrs.sim.faults) and the fault matrix (windahrs faults): each fault does
what it says and only in its span, seeded and composable; bad parameters are refused naming
the field; the command writes the documented JSON."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import windahrs as wa
from windahrs.cli import main
from windahrs.estimate import Estimate, Innovations
from windahrs.experiments.faults import (
    FaultCase,
    counts,
    first_flag,
    matrix_markdown,
    recovery_time,
    run_fault_matrix,
)
from windahrs.flags import FLAGS
from windahrs.flight import Flight
from windahrs.io import read_flight
from windahrs.sim import faults as F

ROW_KEYS = {
    "fault", "filter", "nan_count", "flagged", "flag_delay_s", "recover_s", "rms_before_deg",
    "rms_during_deg", "rms_after_deg", "max_during_deg",
}


@pytest.fixture(scope="module")
def flight() -> Flight:
    return wa.simulate("fixedwing", seed=2, wind=5.0, duration=8.0)


def _in(t: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return (t >= lo) & (t < hi)


def test_magnet_adds_its_field_only_in_its_span(flight: Flight) -> None:
    off = (10e-6, -20e-6, 30e-6)
    g = F.inject(flight, [F.MagMagnet(start=2.0, duration=1.5, offset_b=off)], seed=0)
    assert flight.mag is not None and g.mag is not None
    d = g.mag.mag_b - flight.mag.mag_b
    m = _in(flight.mag.t, 2.0, 3.5)
    assert m.sum() == 75  # 50 Hz x 1.5 s
    np.testing.assert_allclose(d[m], np.tile(off, (m.sum(), 1)), atol=1e-15)
    assert not d[~m].any()
    assert "mag-magnet:start=2:duration=1.5" in g.meta["faults"]
    np.testing.assert_array_equal(g.truth.q_nb, flight.truth.q_nb)  # type: ignore[union-attr]


@pytest.mark.parametrize(
    ("fault", "stream"),
    [(F.GnssOutage(start=1.0, duration=2.0), "gnss"), (F.MagAbsent(start=0.0, duration=3.0), "mag"),
     (F.ImuDropout(start=4.0, duration=0.5), "imu")],
)
def test_removals_remove_exactly_the_span(flight: Flight, fault: F.Fault, stream: str) -> None:
    before = getattr(flight, stream).t
    after = getattr(F.inject(flight, [fault], seed=0), stream).t
    lo, hi = fault.span
    np.testing.assert_array_equal(after, before[~_in(before, lo, hi)])


def test_spike_nan_stuck_saturation(flight: Flight) -> None:
    t, w, f = flight.imu.t, flight.imu.w_b, flight.imu.f_b
    g = F.inject(flight, [F.GyroSpike(start=2.0, magnitude=30.0, axis=1)], seed=0)
    d = g.imu.w_b - w
    k = int(np.searchsorted(t, 2.0))
    assert d[k, 1] == pytest.approx(30.0) and np.count_nonzero(d) == 1
    g = F.inject(flight, [F.AccelSpike(start=2.0, duration=0.02)], seed=0)
    assert np.count_nonzero(g.imu.f_b - f) == 4  # four samples of z in 20 ms at 200 Hz
    g = F.inject(flight, [F.ImuNaN(start=3.0, duration=0.5, sensor="gyro")], seed=0)
    m = _in(t, 3.0, 3.5)
    assert np.isnan(g.imu.w_b[m]).all() and np.isfinite(g.imu.w_b[~m]).all() and np.isfinite(g.imu.f_b).all()
    g = F.inject(flight, [F.ImuStuck(start=3.0, duration=0.5)], seed=0)
    k0 = int(np.argmax(m)) - 1
    assert (g.imu.f_b[m] == f[k0]).all() and (g.imu.w_b[m] == w[k0]).all()
    np.testing.assert_array_equal(g.imu.f_b[~m], f[~m])
    g = F.inject(flight, [F.AccelSaturation(start=1.0, duration=6.0, limit=9.0)], seed=0)
    m = _in(t, 1.0, 7.0)
    assert np.abs(g.imu.f_b[m]).max() == 9.0 and np.abs(f[m]).max() > 9.0
    np.testing.assert_array_equal(g.imu.f_b[~m], f[~m])


def test_air_and_gnss_faults(flight: Flight) -> None:
    air = flight.air
    assert air is not None and air.aoa is not None
    m = _in(air.t, 2.0, 4.0)
    k0 = int(np.argmax(m)) - 1
    frozen = F.inject(flight, [F.PitotBlockage(start=2.0, duration=2.0)], seed=0).air
    assert frozen is not None and (frozen.tas[m] == air.tas[k0]).all()
    zero = F.inject(flight, [F.PitotBlockage(start=2.0, duration=2.0, mode="zero")], seed=0).air
    assert zero is not None and (zero.tas[m] == 0).all() and (zero.tas[~m] == air.tas[~m]).all()
    ramp = F.inject(flight, [F.PitotBlockage(start=2.0, duration=2.0, mode="ramp", rate=2.0)], seed=0).air
    assert ramp is not None
    np.testing.assert_allclose(ramp.tas[m], air.tas[k0] + 2.0 * (air.t[m] - 2.0))
    vane = F.inject(flight, [F.VaneFailure(start=2.0, duration=2.0, vane="aoa", mode="nan")], seed=0).air
    assert vane is not None and vane.aoa is not None and vane.sideslip is not None
    assert np.isnan(vane.aoa[m]).all() and np.isfinite(vane.aoa[~m]).all() and (vane.sideslip == air.sideslip).all()
    gnss = flight.gnss
    assert gnss is not None
    jumped = F.inject(flight, [F.GnssJump(start=1.0, duration=1.0, jump_n=(0.0, -3.0, 0.0))], seed=0).gnss
    assert jumped is not None
    mg = _in(gnss.t, 1.0, 2.0)
    np.testing.assert_allclose((jumped.v_n - gnss.v_n)[mg], np.tile([0.0, -3.0, 0.0], (mg.sum(), 1)), atol=1e-12)
    assert not (jumped.v_n - gnss.v_n)[~mg].any()


def test_seeded_reproducible_and_composable(flight: Flight) -> None:
    vib = F.VibrationBurst(start=1.0, duration=1.0)
    jit = F.ImuJitter(start=5.0, duration=1.0)
    a = F.inject(flight, [vib, jit], seed=7)
    b = F.inject(flight, [vib, jit], seed=7)
    c = F.inject(flight, [vib, jit], seed=8)
    np.testing.assert_array_equal(a.imu.f_b, b.imu.f_b)
    np.testing.assert_array_equal(a.imu.t, b.imu.t)
    assert not np.array_equal(a.imu.f_b, c.imu.f_b)
    # composition: each fault draws from its own stream, so adding one leaves the others' draws alone
    mag = F.MagMagnet(start=6.0, duration=1.0)
    d = F.inject(flight, [vib, jit, mag], seed=7)
    np.testing.assert_array_equal(d.imu.f_b, a.imu.f_b)
    np.testing.assert_array_equal(d.imu.t, a.imu.t)
    assert d.mag is not None and flight.mag is not None and not np.array_equal(d.mag.mag_b, flight.mag.mag_b)
    # the jitter moved stamps only in its span, and not the data
    m = _in(flight.imu.t, 5.0, 6.0)
    assert (a.imu.t[m] != flight.imu.t[m]).all() and (a.imu.t[~m] == flight.imu.t[~m]).all()
    assert (a.imu.w_b[m] == flight.imu.w_b[m]).all()
    # the input flight is untouched
    assert "faults" not in flight.meta


def test_stamp_faults_refused_as_flight_and_repaired_from_csv(flight: Flight, tmp_path: Path) -> None:
    faults = [F.DuplicateStamps(start=2.0, duration=1.0, count=3), F.OutOfOrder(start=4.0, duration=1.0, count=2)]
    with pytest.raises(F.FaultError, match="inject_raw"):
        F.inject(flight, faults, seed=0)
    raw = F.inject_raw(flight, faults, seed=0)
    assert len(raw.imu["t"]) == len(flight.imu.t) + 3
    assert (np.diff(raw.imu["t"]) == 0).sum() == 3 and (np.diff(raw.imu["t"]) < 0).sum() == 2
    back = read_flight(raw.write_csv_dir(tmp_path / "log"))
    assert back.repairs["imu"]["duplicates"] == 3 and back.repairs["imu"]["reordered"] == 4
    np.testing.assert_allclose(back.imu.t, flight.imu.t, atol=1e-9)
    np.testing.assert_allclose(back.imu.w_b, flight.imu.w_b, rtol=1e-12)


def test_first_change_is_when_the_faults_began_to_act(flight: Flight) -> None:
    """The onset the matrix counts a flag's delay from: a value fault's start, the first
    duplicated or swapped stamp of a stamp fault (at random in its span), None for none."""
    assert F.inject_raw(flight, [F.GyroSpike(start=3.0)], seed=0).first_change() == pytest.approx(3.0, abs=0.01)
    assert F.inject_raw(flight, [F.GnssOutage(start=2.0, duration=1.0)], seed=0).first_change() == pytest.approx(
        2.0, abs=0.11
    )
    raw = F.inject_raw(flight, [F.DuplicateStamps(start=2.0, duration=4.0, count=2)], seed=1)
    dup = raw.imu["t"][1:][np.diff(raw.imu["t"]) == 0]
    assert raw.first_change() == pytest.approx(dup.min()) and dup.min() > 2.0
    same = F.inject_raw(flight, [F.GyroSaturation(start=2.0, duration=1.0, limit=100.0)], seed=0)
    assert same.first_change() is None


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: F.GyroSpike(start=1.0, magnitude=float("inf")), "GyroSpike.magnitude"),
        (lambda: F.GnssOutage(start=-1.0, duration=2.0), "GnssOutage.start"),
        (lambda: F.MagAbsent(start=1.0, duration=0.0), "MagAbsent.duration"),
        (lambda: F.PitotBlockage(start=1.0, duration=1.0, mode="melt"), "PitotBlockage.mode"),
        (lambda: F.MagMagnet(start=1.0, duration=1.0, offset_b=(1.0, 2.0)), "MagMagnet.offset_b"),  # type: ignore[arg-type]
        (lambda: F.ImuNaN(start=1.0, duration=1.0, fraction=1.5), "ImuNaN.fraction"),
        (lambda: F.GyroSpike(start=1.0, axis=3), "GyroSpike.axis"),
        (lambda: F.DuplicateStamps(start=1.0, duration=1.0, count=0), "DuplicateStamps.count"),
        (lambda: F.ImuJitter(start="soon", duration=1.0), "ImuJitter.start"),  # type: ignore[arg-type]
        (lambda: F.parse_fault("gnss-outage:start=1:during=2"), "GnssOutage.during"),
        (lambda: F.parse_fault("gnss-outage:start=1"), "GnssOutage.duration"),
        (lambda: F.parse_fault("compass-on-fire:start=1"), "fault"),
    ],
)
def test_bad_parameters_name_the_field(make, field: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(F.FaultError) as exc:
        make()
    assert exc.value.field == field and str(exc.value).startswith(f"{field}: expected")


def test_faults_that_do_not_fit_the_flight(flight: Flight) -> None:
    with pytest.raises(F.FaultError, match=r"GnssOutage.start: expected a time within the flight \(0 to 8 s\)"):
        F.inject(flight, [F.GnssOutage(start=20.0, duration=1.0)], seed=0)
    quad = wa.simulate("quadrotor", seed=0, duration=2.0)
    with pytest.raises(F.FaultError, match="PitotBlockage: expected a flight with a air stream"):
        F.inject(quad, [F.PitotBlockage(start=1.0, duration=0.5)], seed=0)


def test_spec_round_trip() -> None:
    for kind, cls in F.FAULTS.items():
        extra = {} if cls.instant else {"duration": 1.5}
        f = cls(start=2.0, **extra)  # type: ignore[arg-type]
        assert F.parse_fault(f.spec()) == f, kind


def test_first_flag_counts_only_what_the_clean_run_did_not() -> None:
    t = np.arange(0.0, 10.0, 0.1)

    def est(rejected_at: list[float], resets: dict[str, np.ndarray] | None = None) -> Estimate:
        acc = ~np.isin(np.round(t, 6), rejected_at)
        inn = Innovations(t=t, nu=np.zeros((len(t), 3)), nis=np.zeros(len(t)), accepted=acc)
        return Estimate(filter="x", t=t, q_nb=np.tile([1.0, 0, 0, 0], (len(t), 1)), innovations={"gnss": inn},
                        resets=resets or {})

    clean = est([5.2])
    assert first_flag(est([5.2]), clean, 5.0) == (None, None)
    assert first_flag(est([5.2, 5.7]), clean, 5.0) == (pytest.approx(5.7), "rejected:gnss")
    assert first_flag(est([6.5]), clean, 5.0) == (None, None)  # beyond 1 s
    reset = {"accel": np.array([[5.4, 0.3, 5.0]])}
    assert first_flag(est([5.7], reset), clean, 5.0) == (pytest.approx(5.4), "reset:accel")


def test_first_flag_reads_per_sample_flags_when_the_estimate_has_them() -> None:
    t = np.arange(0.0, 10.0, 0.1)

    def est(on: list[float]) -> Estimate:
        bit = np.uint32(1 << FLAGS["imu_held"][0])
        flags = np.where(np.isin(np.round(t, 6), on), bit, np.uint32(0)).astype(np.uint32)
        return Estimate(filter="x", t=t, q_nb=np.tile([1.0, 0, 0, 0], (len(t), 1)), flags=flags)

    assert first_flag(est([2.0, 5.3]), est([2.0]), 5.0) == (pytest.approx(5.3), "flag:imu_held")
    assert first_flag(est([2.0, 5.3]), est([2.0, 5.3]), 5.0) == (None, None)


def test_recovery_time() -> None:
    t = np.arange(0.0, 20.0, 0.01)
    e = np.where((t > 5) & (t < 8), 10.0, 1.0)
    # the 1-s window's RMS is under 2 once less than 3/99 of it is at 10 deg
    assert recovery_time(t, e, 5.0, 2.0) == pytest.approx(3.0 - 3.0 / 99.0, abs=0.015)
    assert recovery_time(t, np.full(len(t), 5.0), 5.0, 2.0) is None


def test_matrix_row_on_a_tiny_flight() -> None:
    case = FaultCase("spike", (F.GyroSpike(start=3.0, magnitude=40.0),))
    res = run_fault_matrix("fixedwing", ["mekf"], duration=6.0, seed=1, cases=[case])
    (row,) = res.rows
    assert row.fault == "spike" and row.filter == "mekf" and row.nan_count == 0
    assert row.max_during_deg > row.rms_during_deg > 0 and row.t_start_s == 3.0 and row.t_onset_s == 3.0


def test_a_stamp_fault_is_flagged_from_its_first_bad_stamp() -> None:
    """Five duplicated stamps at random in 10 s: the flag's delay counts from the first (on
    seeds 2-5 of the matrix it came after the span's first second, and the case read as not
    flagged)."""
    case = FaultCase("dup", (F.DuplicateStamps(start=2.0, duration=6.0, count=3),), edge=True)
    res = run_fault_matrix("fixedwing", ["mekf"], duration=10.0, seed=4, cases=[case])
    (row,) = res.rows
    assert row.t_onset_s > row.t_start_s + 1.0  # (seed 4: the first duplicate after 1 s)
    assert row.flagged and row.flag_source == "flag:stamps_repaired" and row.flag_delay_s < 0.1


def test_a_fault_that_changes_no_sample_is_left_out_of_the_counts() -> None:
    # a gyro clipped at 10 rad/s: the simulated fixed wing never turns that fast
    cases = [FaultCase("clip-10", (F.GyroSaturation(start=2.0, duration=2.0, limit=10.0),)),
             FaultCase("clip-0.01", (F.GyroSaturation(start=2.0, duration=2.0, limit=0.01),))]
    res = run_fault_matrix("fixedwing", ["mekf"], duration=6.0, seed=1, cases=cases)
    idle, live = res.rows
    assert idle.no_effect and not live.no_effect
    c = counts(res.rows)
    assert (c.runs, c.no_effect) == (1, 1) and c.flagged == int(live.flagged) and c.with_nan == 0
    assert "the fault changed no sample" in matrix_markdown([res])


def test_faults_command_writes_the_documented_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "m"
    rc = main(["faults", "--duration", "6", "--faults", "gyro-spike", "--filters", "mekf", "--seed", "1",
               "--out", str(out)])
    assert rc == 0
    rows = json.loads((out / "faults.json").read_text())
    assert len(rows) == 1 and ROW_KEYS <= set(rows[0])
    assert rows[0]["fault"] == "gyro-spike" and rows[0]["filter"] == "mekf"
    assert isinstance(rows[0]["flagged"], bool) and rows[0]["nan_count"] == 0
    assert "| gyro-spike | mekf |" in (out / "faults.md").read_text()
    assert "1 runs:" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--filters", "nope"], "filter: unknown 'nope'"),
        (["--faults", "gyro-splke"], "--faults: expected names among"),
        (["--duration", "6"], "--duration: expected at least the end of case"),
        (["--seed", "-1"], "--seed: expected an integer from 0 to 2**63 - 1, found -1"),
    ],
)
def test_faults_command_bad_input(
    args: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "m"
    try:
        rc = main(["faults", *args, "--out", str(out)])
    except SystemExit as exc:  # refused by argparse
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_simulate_with_faults(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "f.h5"
    assert main(["simulate", "--duration", "3", "--fault", "gnss-outage:start=1:duration=1", "--out", str(out)]) == 0
    assert "gnss       21 samples at 10 Hz, 1 gaps" in capsys.readouterr().out
    assert main(["simulate", "--duration", "3", "--fault", "out-of-order:start=1:duration=1", "--out",
                 str(tmp_path / "g.h5")]) == 2
    assert "use inject_raw()" in capsys.readouterr().err and not (tmp_path / "g.h5").exists()
    assert main(["simulate", "--duration", "3", "--fault", "out-of-order:start=1:duration=1", "--csv", "--out",
                 str(tmp_path / "csv")]) == 0
    assert read_flight(tmp_path / "csv").repairs["imu"]["reordered"] == 2
    assert main(["simulate", "--duration", "3", "--fault", "gyro-spike:start=1:magnitude=x", "--out",
                 str(tmp_path / "h.h5")]) == 2
    assert capsys.readouterr().err.strip().endswith("GyroSpike.magnitude: expected a float, found 'x'")


def test_front_door_simulate_with_faults() -> None:
    faults = [F.GnssOutage(start=1.0, duration=1.0), F.VibrationBurst(start=2.0, duration=0.5)]
    a = wa.simulate("fixedwing", seed=4, duration=3.0, faults=faults)
    b = wa.simulate("fixedwing", seed=4, duration=3.0, faults=faults)
    clean = wa.simulate("fixedwing", seed=4, duration=3.0)
    np.testing.assert_array_equal(a.imu.f_b, b.imu.f_b)
    np.testing.assert_array_equal(a.truth.q_nb, clean.truth.q_nb)  # type: ignore[union-attr]
    assert a.gnss is not None and len(a.gnss.t) == 21 and "gnss-outage" in a.meta["faults"]
    with pytest.raises(F.FaultError, match=r"faults\[0\]: expected a Fault"):
        wa.simulate("fixedwing", seed=4, duration=3.0, faults=["gyro-spike"])  # type: ignore[list-item]
