"""The receiver's own speed accuracy (``GnssStream.v_sigma``): validated by the Flight, read
from PX4 logs, stored, carried through the event rows and the streamer, and taken by the INS
as the velocity's noise where it is worse than ``gnss_sigma`` (PX4 EKF2's
``max(sacc, EKF2_GPS_V_NOISE)``, the vertical 1.5 times)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import windahrs as wa
from conftest import require_data
from windahrs.aid.gnss_vel import VERTICAL_SACC_RATIO
from windahrs.filters.base import EVENT_GNSS, merge_events, replay
from windahrs.filters.registry import make_estimator
from windahrs.flight import Flight, FlightError, GnssStream
from windahrs.store import load_flight, save_flight


@pytest.fixture(scope="module")
def fw() -> Flight:
    return wa.simulate("fixedwing", seed=2, wind=5.0, duration=30.0)


def _with_sigma(flight: Flight, sigma: float | np.ndarray) -> Flight:
    g = flight.gnss
    assert g is not None
    return flight.replace(gnss=GnssStream(t=g.t, v_n=g.v_n, v_sigma=np.broadcast_to(sigma, g.t.shape).copy()))


def _run(spec: str, flight: Flight) -> wa.Estimate:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return make_estimator(spec).run(flight)


def test_the_flight_checks_it() -> None:
    t, v = np.arange(4.0), np.zeros((4, 3))
    g = GnssStream(t=t, v_n=v, v_sigma=np.array([0.3, np.nan, 0.0, 2.0]))
    assert g.v_sigma is not None and np.isnan(g.v_sigma[1])
    with pytest.raises(FlightError, match=r"gnss\.v_sigma: expected a speed accuracy in m/s.*found -1 at row 2"):
        GnssStream(t=t, v_n=v, v_sigma=np.array([0.3, 0.3, -1.0, 0.3]))
    with pytest.raises(FlightError, match=r"gnss\.v_sigma: expected 4 rows"):
        GnssStream(t=t, v_n=v, v_sigma=np.array([0.3, 0.3]))
    with pytest.raises(FlightError, match=r"gnss\.v_sigma"):
        GnssStream(t=t, v_n=v, v_sigma=np.array([0.3, np.inf, 0.3, 0.3]))


def test_stored_and_in_the_event_rows(fw: Flight, tmp_path: Path) -> None:
    f = _with_sigma(fw, 0.7)
    back = load_flight(save_flight(f, tmp_path / "f.h5"))
    assert back.gnss is not None and back.gnss.v_sigma is not None
    np.testing.assert_array_equal(back.gnss.v_sigma, 0.7)
    _, kinds, vals = merge_events(f, frozenset({"imu", "gnss"}))
    rows = vals[kinds == EVENT_GNSS]
    np.testing.assert_array_equal(rows[:, 3], 0.7)
    assert np.isnan(rows[:, 4:]).all()
    _, kinds, vals = merge_events(fw, frozenset({"imu", "gnss"}))
    assert np.isnan(vals[kinds == EVENT_GNSS][:, 3:]).all()  # (none given: NaN)


def test_the_ins_takes_it_where_worse_than_gnss_sigma(fw: Flight) -> None:
    plain = _run("ins-wind", fw)
    better = _run("ins-wind", _with_sigma(fw, 0.05))  # (below gnss_sigma 0.2: the floor stands)
    np.testing.assert_array_equal(better.q_nb, plain.q_nb)
    worse = _run("ins-wind", _with_sigma(fw, 2.0))
    nis_plain = np.nanmedian(plain.innovations["gnss"].nis)
    nis_worse = np.nanmedian(worse.innovations["gnss"].nis)
    # R 100 times larger horizontally, 225 vertically: the innovations' NIS falls by far more than 10x
    assert nis_worse < 0.1 * nis_plain, (nis_plain, nis_worse)
    assert VERTICAL_SACC_RATIO == 1.5
    # NaN rows (not given) are fused at gnss_sigma: a stream half NaN, half 0.05, is the plain run
    half = np.where(np.arange(len(fw.gnss.t)) % 2 == 0, np.nan, 0.05)  # type: ignore[union-attr]
    np.testing.assert_array_equal(_run("ins-wind", _with_sigma(fw, half)).q_nb, plain.q_nb)


def test_streaming_equals_batch_with_it(fw: Flight) -> None:
    f = _with_sigma(fw, np.linspace(0.1, 3.0, len(fw.gnss.t)))  # type: ignore[union-attr]
    est = make_estimator("ins-wind")
    has = frozenset(s for s in ("imu", "mag", "gnss", "air") if getattr(f, s) is not None) & est.uses
    t_ev, kinds, vals = merge_events(f, has)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        streamed = replay(est, est.streamer(f.site, has=has), f, t_ev, kinds, vals)
        batch = est.run(f, cov_every=1)
    np.testing.assert_array_equal(streamed.q_nb, batch.q_nb)
    np.testing.assert_array_equal(streamed.cov, batch.cov)
    s = est.streamer(f.site, has=has)
    for bad in (-0.5, np.inf):
        with pytest.raises(ValueError, match="v_sigma: expected a speed accuracy"):
            s.gnss(1.0, np.zeros(3), bad)


def test_read_from_px4_logs() -> None:
    f = wa.read(require_data("px4", "sample_log_small.ulg"))
    assert f.gnss is not None and f.gnss.v_sigma is not None
    assert 0.3 < float(np.nanmedian(f.gnss.v_sigma)) < 1.0  # (the VTOL's receiver on the ground: 0.46-0.72 m/s)
    assert f.meta["gnss.v_sigma"].startswith("s_variance_m_s")


def test_read_from_a_generic_csv_directory(tmp_path: Path) -> None:
    """``speed_accuracy`` names the column of the receiver's speed accuracy, in the velocity's
    unit; it goes with velocity columns only."""
    t = np.arange(0.0, 2.0, 0.01)
    imu = "\n".join(f"{x:.2f},0,0,0,0,0,-9.80665" for x in t)
    (tmp_path / "imu.csv").write_text("t,wx,wy,wz,fx,fy,fz\n" + imu + "\n")
    gnss = "\n".join(f"{x:.1f},1,0,0,{36 * x:.1f}" for x in t[::10])
    (tmp_path / "gnss.csv").write_text("t,vn,ve,vd,sacc\n" + gnss + "\n")
    manifest = """format = "windahrs.csv"
version = 1
[imu]
file = "imu.csv"
time = "t"
time_unit = "s"
frame = "ned_frd"
gyro = ["wx", "wy", "wz"]
gyro_unit = "rad/s"
accel = ["fx", "fy", "fz"]
accel_unit = "m/s^2"
[gnss]
file = "gnss.csv"
time = "t"
time_unit = "s"
frame = "ned_frd"
velocity = ["vn", "ve", "vd"]
unit = "km/h"
speed_accuracy = "sacc"
"""
    (tmp_path / "windahrs.toml").write_text(manifest)
    f = wa.read(tmp_path)
    assert f.gnss is not None and f.gnss.v_sigma is not None
    np.testing.assert_allclose(f.gnss.v_sigma, 10.0 * f.gnss.t, atol=1e-9)  # (36 km/h per s = 10 m/s per s)
    np.testing.assert_allclose(f.gnss.v_n[:, 0], 1 / 3.6)
    assert f.meta["gnss.v_sigma"] == "column 'sacc' (the receiver's speed accuracy)"
    by_position = manifest.replace('velocity = ["vn", "ve", "vd"]', 'position = ["vn", "ve", "vd"]')
    (tmp_path / "windahrs.toml").write_text(by_position)
    with pytest.raises(ValueError, match="gnss.speed_accuracy"):
        wa.read(tmp_path)


def test_read_from_ardupilot_logs(tmp_path: Path) -> None:
    """``GPA.SAcc``, logged with each GPS row at its TimeUS, is the stream's v_sigma; a log
    without GPA has none."""
    from synthetic_logs import dataflash_bytes

    (tmp_path / "a.bin").write_bytes(dataflash_bytes(gpa=True))
    (tmp_path / "b.bin").write_bytes(dataflash_bytes())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a, b = wa.read(tmp_path / "a.bin"), wa.read(tmp_path / "b.bin")
    assert a.gnss is not None and a.gnss.v_sigma is not None and b.gnss is not None
    np.testing.assert_allclose(a.gnss.v_sigma, [0.5] + [0.8] * (len(a.gnss.t) - 1), rtol=1e-6)
    assert b.gnss.v_sigma is None and "gnss.v_sigma" not in b.meta
    assert a.meta["gnss.v_sigma"].startswith("GPA.SAcc")
    np.testing.assert_array_equal(a.gnss.v_n, b.gnss.v_n)
