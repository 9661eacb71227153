"""Input repair at the edge (windahrs.repair): a flight with duplicated, out-of-order and
spiked samples is read, repaired and reported, with a count per kind in ``Flight.repairs``,
in ``windahrs info``, in the Estimate and in ``windahrs estimate``; units are still checked
on the bulk of the data; truncated logs are read up to their last complete message with a
warning. Real-data tests read $WINDAHRS_DATA (default ../shared/data) and skip without it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import windahrs as wa
from conftest import require_data
from synthetic_logs import dataflash_bytes, ulog_bytes
from test_io import make_flight, write_csv_dir
from windahrs.cli import main
from windahrs.estimate import load_estimate, save_estimate
from windahrs.flight import Flight, FlightError, ImuStream
from windahrs.io import read_flight
from windahrs.io.edge import TruncatedLogWarning
from windahrs.repair import ACCEL_RANGE, GYRO_RANGE, SPIKE_SHARE, RepairLog, repairs_text
from windahrs.store import load_flight, save_flight

RATE = 200.0


def raw_imu(n: int = 2000) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Time (s), gyro (rad/s), accel (m/s^2) and mag (T) of a gently rotating sensor."""
    t = np.arange(n) / RATE
    gyro = np.column_stack([0.2 * np.sin(t), 0.1 * np.cos(0.5 * t), np.full(n, 0.05)])
    accel = np.tile([0.0, 0.0, -9.80665], (n, 1))
    mag = np.tile([20e-6, 0.0, 45e-6], (n, 1))
    return t, gyro, accel, mag


def glitched(n: int = 2000) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """raw_imu with, in this order: row 100 repeated (a duplicated stamp), rows 300 and 301
    swapped (out of order), a 40 rad/s gyro spike at 500, a 400 m/s^2 accel spike at 700
    and an inf at 900 (row numbers of the clean arrays)."""
    t, g, a, m = raw_imu(n)
    g[500, 0] = 40.0
    a[700, 2] = 400.0
    g[900, 1] = np.inf
    order = np.r_[np.arange(0, 101), 100, np.arange(101, n)]  # 100 twice
    order[[302, 303]] = order[[303, 302]]  # clean rows 301 and 302 swapped
    return t[order], g[order], a[order], m[order]


EXPECTED_IMU = {"reordered": 2, "duplicates": 1, "infinite": 1, "out_of_range": 2}


def test_from_arrays_repairs_and_counts() -> None:
    t, g, a, m = glitched()
    f = Flight.from_arrays(t, g, a, m)
    assert f.repairs == {"imu": EXPECTED_IMU}
    t0, g0, a0, _ = raw_imu()
    np.testing.assert_array_equal(f.imu.t, t0)
    bad = np.zeros(len(t0), dtype=bool)
    bad[[500, 900]] = True
    assert np.isnan(f.imu.w_b[bad]).all() and np.isnan(f.imu.f_b[700]).all()
    np.testing.assert_array_equal(f.imu.w_b[~bad], g0[~bad])
    np.testing.assert_array_equal(np.delete(f.imu.f_b, 700, axis=0), np.delete(a0, 700, axis=0))
    assert "repairs    imu: 2 samples out of order sorted, 1 sample with a repeated time stamp dropped" in f.summary()


def test_strict_refuses_each_glitch() -> None:
    t, g, a, _ = raw_imu()
    dup = t.copy()
    dup[10] = dup[9]
    with pytest.raises(FlightError, match=r"^t: expected strictly increasing time, found t\[9\]"):
        Flight.from_arrays(dup, g, a, strict=True)
    spike = g.copy()
    spike[50, 2] = -40.0
    with pytest.raises(FlightError, match=r"^gyro: expected \|component\| within 38.4 rad/s .* found 40 at row 50"):
        Flight.from_arrays(t, spike, a, strict=True)
    inf = a.copy()
    inf[7, 0] = np.inf
    with pytest.raises(FlightError, match=r"^accel: .* found inf at row 7"):
        Flight.from_arrays(t, g, inf, strict=True)
    assert Flight.from_arrays(t, g, a, strict=True).repairs == {}


def test_constructor_repairs_nothing_and_checks_units_on_the_bulk() -> None:
    t, g, a, _ = raw_imu()
    # A simulated fault reaches the estimators as made: one 60 rad/s spike (above the old
    # 50 rad/s unit check) is accepted by the record, not refused, not set to NaN.
    g1 = g.copy()
    g1[100] = [60.0, 0.0, 0.0]
    assert ImuStream(t=t, w_b=g1, f_b=a).w_b[100, 0] == 60.0
    # deg/s data: most samples beyond the gyro range, refused with the hint, by both paths
    deg = np.degrees(g) + 45.0
    with pytest.raises(FlightError, match=r"imu\.w_b: .*deg/s\? multiply by pi/180"):
        ImuStream(t=t, w_b=deg, f_b=a)
    with pytest.raises(FlightError, match=r"^gyro: .*deg/s\? pass gyro_units='deg/s'"):
        Flight.from_arrays(t, deg, a)
    with pytest.raises(FlightError, match="strictly increasing"):
        ImuStream(t=t[::-1], w_b=g, f_b=a)
    # spikes up to SPIKE_SHARE of the samples are repaired; beyond it, units
    k = int(SPIKE_SHARE * len(t))
    many = g.copy()
    many[:k, 0] = 2 * GYRO_RANGE
    assert Flight.from_arrays(t, many, a).repairs["imu"]["out_of_range"] == k
    many[: k + 1, 0] = 2 * GYRO_RANGE
    with pytest.raises(FlightError, match="deg/s"):
        Flight.from_arrays(t, many, a)


def test_repair_log_ranges() -> None:
    log = RepairLog()
    a = np.array([[0.0, 0.0, -9.8], [0.0, 0.0, 1.01 * ACCEL_RANGE], [np.nan, 0.0, 0.0], [0.0, -np.inf, 0.0]]
                 + [[0.0, 0.0, -9.8]] * 200)
    out = log.rows("imu", a, ACCEL_RANGE)
    # the NaN is a missing sample (the whole row NaN), not a repair; the inf is one
    assert log.counts == {"imu": {"infinite": 1, "out_of_range": 1}}
    assert np.isnan(out[1:4]).all() and np.isfinite(out[[0, 4]]).all() and np.isfinite(a[1]).all()  # a copy
    assert repairs_text(log.counts) == "imu: 1 sample infinite set to NaN, 1 sample beyond the sensor range set to NaN"
    with pytest.raises(FlightError, match=r"repairs\['imu'\]"):
        Flight.from_arrays(*raw_imu()[:3]).replace(repairs={"imu": {"spikes": 1}})


def test_repairs_saved_loaded_and_carried_to_the_estimate(tmp_path: Path) -> None:
    f = Flight.from_arrays(*glitched())
    back = load_flight(save_flight(f, tmp_path / "f.h5"))
    assert back.repairs == f.repairs == {"imu": EXPECTED_IMU}
    est = wa.estimator("mekf").run(back)
    assert est.repairs == {"imu": EXPECTED_IMU}
    lines = est.warnings()
    assert lines[0].startswith("mekf: input repaired at the edge: imu: 2 samples out of order sorted")
    assert not any("input repaired" in w for w in est.warnings(repairs=False))
    assert load_estimate(save_estimate(est, tmp_path / "e.h5")).repairs == est.repairs
    vqf = pytest.importorskip("vqf")
    assert vqf is not None
    assert wa.estimator("vqf").run(back).repairs == est.repairs


def glitch_csv(d: Path) -> None:
    """In the CSV directory's imu.csv: a repeated row, a swapped pair and a gyro spike."""
    path = d / "imu.csv"
    lines = path.read_text().splitlines()
    cells = lines[51].split(",")
    lines[51] = ",".join([cells[0], "3000", *cells[2:]])  # 3000 deg/s on x: beyond range
    lines[30], lines[31] = lines[31], lines[30]
    lines.insert(20, lines[20])
    path.write_text("\n".join(lines) + "\n")


def test_csv_flight_repaired_and_reported_by_info_and_estimate(
    tmp_path: Path, rng: np.random.Generator, capsys: pytest.CaptureFixture[str]
) -> None:
    d = write_csv_dir(make_flight(rng), tmp_path / "rec")
    glitch_csv(d)
    f = read_flight(d)
    assert f.repairs == {"imu": {"reordered": 2, "duplicates": 1, "out_of_range": 1}}
    assert np.isnan(f.imu.w_b[50]).all()
    assert main(["info", str(d)]) == 0
    out = capsys.readouterr().out
    assert ("repairs    imu: 2 samples out of order sorted, 1 sample with a repeated time stamp dropped, "
            "1 sample beyond the sensor range set to NaN") in out
    assert main(["estimate", str(d), "--filter", "mekf", "--out", str(tmp_path / "e.h5")]) == 0
    err = capsys.readouterr().err
    line = [w for w in err.splitlines() if "input repaired" in w]
    assert line == [f"windahrs estimate: warning: {d}: input repaired at the edge: imu: 2 samples out of order sorted, "
                    "1 sample with a repeated time stamp dropped, 1 sample beyond the sensor range set to NaN"]
    assert load_estimate(tmp_path / "e.h5").repairs == f.repairs


def test_csv_every_stream_repaired_and_counted(tmp_path: Path, rng: np.random.Generator) -> None:
    """Glitches beyond each sensor's range, one per stream (the rest of the rows as written):
    magnetometer 10 mT, GNSS 600 m/s, airspeed 2000 km/h, a 500 deg vane, an inf."""
    flight = make_flight(rng)
    d = write_csv_dir(flight, tmp_path / "rec")

    def cell(name: str, row: int, col: int, value: str) -> None:
        lines = (d / name).read_text().splitlines()
        cells = lines[row + 1].split(",")
        cells[col] = value
        lines[row + 1] = ",".join(cells)
        (d / name).write_text("\n".join(lines) + "\n")

    cell("mag.csv", 5, 1, "10000")  # uT
    cell("gnss.csv", 3, 2, "600")
    cell("air.csv", 7, 1, "2000")  # km/h
    cell("air.csv", 9, 2, "500")  # deg
    cell("air.csv", 11, 3, "-inf")
    f = read_flight(d)
    assert f.repairs == {"mag": {"out_of_range": 1}, "gnss": {"out_of_range": 1},
                         "air": {"infinite": 1, "out_of_range": 2}}
    assert f.mag is not None and f.gnss is not None and f.air is not None and f.air.aoa is not None
    assert np.isnan(f.mag.mag_b[5]).all() and np.isnan(f.gnss.v_n[3]).all() and np.isnan(f.air.tas[7])
    assert np.isnan(f.air.aoa[9]) and np.isfinite(f.air.tas[9])  # a bad vane leaves the airspeed
    assert f.air.sideslip is not None and np.isnan(f.air.sideslip[11])
    assert np.isfinite(f.mag.mag_b[[4, 6]]).all() and np.isfinite(f.air.aoa[[8, 10]]).all()


def test_arrays_flight_reported_by_cli_compare(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    t, g, a, m = glitched()
    level = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))  # a reference to score against
    path = save_flight(Flight.from_arrays(t, g, a, m, reference=level), tmp_path / "arrays.h5")
    assert main(["info", str(path)]) == 0
    assert "repairs    imu: " in capsys.readouterr().out
    assert main(["compare", str(path), "--filters", "mekf,ekf7"]) == 0
    captured = capsys.readouterr()
    assert "mekf" in captured.out and "ekf7" in captured.out
    line = f"windahrs compare: warning: {path}: input repaired at the edge: imu: 2 samples out of order sorted"
    assert captured.err.count(line) == 1  # once per flight, not per filter


def test_bench_data_says_what_compare_says_on_reading(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """bench-data warns, per recording and naming it, of what the edge repaired and of a
    low-rate IMU, as compare does for one flight (it used to say neither)."""
    t, g, a, m = glitched()
    level = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))
    repaired = save_flight(Flight.from_arrays(t, g, a, m, reference=level), tmp_path / "repaired.h5")
    t0, g0, a0, m0 = raw_imu()
    k = slice(None, None, 20)  # 10 Hz
    slow = save_flight(Flight.from_arrays(t0[k], g0[k], a0[k], m0[k], reference=level[: len(t0[k])]),
                       tmp_path / "slow.h5")
    assert main(["bench-data", str(tmp_path), "--filters", "mekf,ekf7"]) == 0
    err = capsys.readouterr().err
    line = f"windahrs bench-data: warning: {repaired}: input repaired at the edge: imu: 2 samples out of order sorted"
    assert err.count(line) == 1  # once per recording, not per filter
    assert err.count(f"windahrs: warning: {slow}: the IMU runs at 10 Hz: its samples are taken as point") == 1
    assert f"{repaired}: the IMU runs at" not in err


# --- truncated logs -----------------------------------------------------------------------


@pytest.mark.parametrize(("name", "make"), [("cut.ulg", ulog_bytes), ("cut.bin", dataflash_bytes)])
def test_truncated_log_read_up_to_last_message_with_warning(tmp_path: Path, name: str, make: object) -> None:
    data = make()  # type: ignore[operator]
    full = tmp_path / ("full" + name[3:])
    full.write_bytes(data)
    whole = read_flight(full)
    key = "ulog.truncated_bytes" if name.endswith(".ulg") else "dataflash.truncated_bytes"
    assert key not in whole.meta
    cut = tmp_path / name
    cut.write_bytes(data[:-5])  # the last message loses 5 bytes
    with pytest.warns(TruncatedLogWarning, match=rf"{name}: truncated: its last message is incomplete: "
                      rf"read up to byte (\d+), (\d+) bytes dropped") as rec:
        f = read_flight(cut)
    dropped = f.meta[key]
    assert f"{dropped} bytes dropped" in str(rec[0].message)
    assert f"read up to byte {len(data) - 5 - dropped}," in str(rec[0].message)
    assert 0 < dropped < 300  # one message, not the file
    assert len(whole.imu.t) - 1 <= len(f.imu.t) <= len(whole.imu.t)
    np.testing.assert_array_equal(f.imu.w_b, whole.imu.w_b[: len(f.imu.t)])


def test_truncated_log_warning_in_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(ulog_bytes()[:-9])
    assert main(["info", str(cut)]) == 0
    captured = capsys.readouterr()
    assert f"windahrs info: warning: {cut}: truncated: its last message is incomplete" in captured.err
    assert "meta       ulog.truncated_bytes = " in captured.out


def test_real_ulog_truncated_copy(tmp_path: Path) -> None:
    src = require_data("px4", "sample_log_small.ulg")
    data = src.read_bytes()
    whole = read_flight(src)
    assert "ulog.truncated_bytes" not in whole.meta  # a complete log reads without the warning
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[: len(data) * 2 // 3 + 1])
    with pytest.warns(TruncatedLogWarning, match="bytes dropped"):
        f = read_flight(cut)
    assert 0 < f.meta["ulog.truncated_bytes"] < 65536 + 3  # at most one message
    assert 0 < len(f.imu.t) < len(whole.imu.t)
    np.testing.assert_array_equal(f.imu.w_b, whole.imu.w_b[: len(f.imu.t)])


def test_repair_times_say_where_and_are_saved(tmp_path: Path) -> None:
    f = Flight.from_arrays(*glitched())
    t0 = raw_imu()[0]
    where = f.repair_times["imu"]
    assert set(where) == set(EXPECTED_IMU) and all(len(where[k]) == n for k, n in EXPECTED_IMU.items())
    np.testing.assert_array_equal(where["duplicates"], t0[[100]])  # the kept row of the repeat
    np.testing.assert_array_equal(where["reordered"], t0[[301, 302]])  # the swapped rows, in place
    np.testing.assert_array_equal(where["out_of_range"], t0[[500, 700]])
    np.testing.assert_array_equal(where["infinite"], t0[[900]])
    back = load_flight(save_flight(f, tmp_path / "f.h5"))
    assert back.repair_times.keys() == f.repair_times.keys()
    for k, v in f.repair_times["imu"].items():
        np.testing.assert_array_equal(back.repair_times["imu"][k], v)
    clean = Flight.from_arrays(*raw_imu())
    assert clean.repair_times == {} and load_flight(save_flight(clean, tmp_path / "c.h5")).repair_times == {}


def test_repair_times_of_a_csv_flight(tmp_path: Path, rng: np.random.Generator) -> None:
    d = write_csv_dir(make_flight(rng), tmp_path / "rec")
    glitch_csv(d)
    f = read_flight(d)
    where = f.repair_times["imu"]
    assert {k: len(v) for k, v in where.items()} == {"reordered": 2, "duplicates": 1, "out_of_range": 1}
    np.testing.assert_array_equal(where["out_of_range"], f.imu.t[[50]])
    np.testing.assert_array_equal(where["reordered"], f.imu.t[[29, 30]])
    np.testing.assert_array_equal(where["duplicates"], f.imu.t[[19]])


@pytest.mark.parametrize(
    ("times", "match"),
    [
        ({"imu": {"spikes": [1.0]}}, "kinds among"),
        ({"engine": {"duplicates": [1.0]}}, "streams among"),
        ({"imu": {"duplicates": [np.nan]}}, "finite times"),
        ({"imu": {"duplicates": [[1.0, 2.0]]}}, "1-D array"),
        ({"imu": [1.0]}, "a dict kind -> times"),
    ],
)
def test_repair_times_are_validated(times: object, match: str) -> None:
    with pytest.raises(FlightError, match=match):
        Flight.from_arrays(*raw_imu()[:3]).replace(repair_times=times)


def test_repair_log_locates_a_series_before_a_reader_drops_rows() -> None:
    """A reader that drops rows after cleaning (DataFlash's GNSS without a fix) locates the
    series first; rows set to NaN afterwards are located on the stream the Flight holds."""
    from windahrs.flight import GnssStream

    rep = RepairLog()
    t_us = np.array([0, 100_000, 100_000, 300_000, 200_000, 400_000, 500_000])
    t_us, (fix,) = rep.series("gnss", t_us, np.array([1, 1, 1, 0, 1, 1, 1]))
    sec = t_us * 1e-6
    rep.locate("gnss", sec)
    ok = fix == 1  # the 0.3 s row has no fix: dropped
    v = np.zeros((int(ok.sum()), 3))
    v[-1, 0] = 1e4  # beyond the GNSS range: NaN
    gnss = GnssStream(t=sec[ok], v_n=rep.rows("gnss", v, 500.0))
    t, g, a, _ = raw_imu(200)
    f = rep.attach(Flight(imu=ImuStream(t=t, w_b=g, f_b=a), gnss=gnss, repairs=rep.counts))
    where = f.repair_times["gnss"]
    np.testing.assert_allclose(where["duplicates"], [0.1])
    np.testing.assert_allclose(where["reordered"], [0.2, 0.3])
    np.testing.assert_allclose(where["out_of_range"], [0.5])
    assert f.repairs == {"gnss": {"reordered": 2, "duplicates": 1, "out_of_range": 1}}
