"""The wind-triangle fit (windahrs.windfit) and the paper filter's wind=fit: recovery of a
known wind and pitot scale, refusals naming what is missing, vector values in filter specs
and TOML, and the fit on the real ALFA flight."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import require_data
from windahrs.estimate import Estimate
from windahrs.filters.base import MissingSensorError
from windahrs.filters.paper import PaperEKF, PaperParams
from windahrs.filters.registry import make_estimator
from windahrs.flight import AirDataStream, Flight, GnssStream, ImuStream
from windahrs.io import read_flight
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.windfit import (
    MIN_HEADING_SPAN_DEG,
    WindFit,
    WindFitError,
    describe_wind_fit,
    fit_flight_wind,
    fit_wind,
    heading_span_deg,
)

ALFA_SEQUENCE = "carbonZ_2018-07-18-15-53-31_1_engine_failure"


def _triangle(wind_n, k: float, *, turn_rate: float = 0.05, duration: float = 200.0, vertical: float = 0.0):
    """GNSS velocity at 10 Hz and airspeed at 20 Hz of a vehicle turning at turn_rate rad/s
    with a varying airspeed through a constant wind: |v - w| = k tas exactly (up to the
    interpolation of GNSS to the air-data times)."""
    w = np.asarray(wind_n, dtype=np.float64)

    def air_velocity(t):
        tas = 15.0 + 2.0 * np.sin(0.3 * t)
        return tas, np.column_stack([np.cos(turn_rate * t) * tas, np.sin(turn_rate * t) * tas,
                                     vertical * np.sin(0.1 * t)])

    t_g = np.arange(0.0, duration, 0.1)
    _, va_g = air_velocity(t_g)
    v_n = w + va_g
    t_a = np.arange(0.05, duration - 0.1, 0.05)
    tas_true, va_a = air_velocity(t_a)
    tas = np.linalg.norm(va_a, axis=1) / k  # the pitot reads 1/k of the true airspeed
    return t_g, v_n, t_a, tas, tas_true


def test_fit_recovers_a_known_wind_and_scale() -> None:
    t_g, v_n, t_a, tas, _ = _triangle([3.0, -2.0, 0.0], 1.1)
    fit = fit_wind(t_g, v_n, t_a, tas)
    np.testing.assert_allclose(fit.wind_n, [3.0, -2.0, 0.0], atol=1e-3)
    assert abs(fit.scale - 1.1) < 1e-3
    assert fit.horizontal and not fit.scale_held and fit.pairs == len(t_a)
    assert fit.heading_span_deg > 350.0 and fit.rms < 1e-2
    # a 3-D wind with vertical motion
    t_g, v_n, t_a, tas, _ = _triangle([-4.0, 1.5, 0.7], 0.95, vertical=2.0)
    fit3 = fit_wind(t_g, v_n, t_a, tas, horizontal=False)
    np.testing.assert_allclose(fit3.wind_n, [-4.0, 1.5, 0.7], atol=1e-3)
    assert abs(fit3.scale - 0.95) < 1e-3
    # k held at its true value: the wind alone
    t_g, v_n, t_a, tas, _ = _triangle([3.0, -2.0, 0.0], 1.1)
    held = fit_wind(t_g, v_n, t_a, tas, scale=1.1)
    np.testing.assert_allclose(held.wind_n, [3.0, -2.0, 0.0], atol=1e-3)
    assert held.scale_held and held.scale == 1.1 and held.sigma_scale == 0.0 and "(held)" in held.text()


def test_fit_is_robust_to_noise_and_outliers() -> None:
    rng = np.random.default_rng(3)
    t_g, v_n, t_a, tas, _ = _triangle([5.0, 4.0, 0.0], 1.05, duration=300.0)
    v_n = v_n + rng.normal(0.0, 0.1, v_n.shape)
    tas = tas + rng.normal(0.0, 0.3, tas.shape)
    tas[::50] += 8.0  # a pitot spike every 2.5 s
    fit = fit_wind(t_g, v_n, t_a, tas)
    np.testing.assert_allclose(fit.wind_n[:2], [5.0, 4.0], atol=0.1)
    assert abs(fit.scale - 1.05) < 0.01
    assert (fit.sigma_wind_n[:2] > 0).all() and fit.sigma_scale > 0


def test_fit_refuses_a_straight_line_naming_the_heading_span() -> None:
    t_g, v_n, t_a, tas, _ = _triangle([3.0, -2.0, 0.0], 1.0, turn_rate=0.0)
    with pytest.raises(WindFitError, match=r"ill-conditioned.*course covers 0\.0 deg.*turns"):
        fit_wind(t_g, v_n, t_a, tas)
    # a 45 deg arc is not enough either
    t_g, v_n, t_a, tas, _ = _triangle([3.0, -2.0, 0.0], 1.0, turn_rate=math.radians(45.0) / 200.0)
    with pytest.raises(WindFitError, match=f"expected at least {MIN_HEADING_SPAN_DEG:g} deg"):
        fit_wind(t_g, v_n, t_a, tas)


def test_fit_refuses_an_implausible_pitot_scale() -> None:
    # straight and noisy: the degenerate answer (the wind = the ground velocity, k near 0)
    rng = np.random.default_rng(5)
    t_g, v_n, t_a, tas, _ = _triangle([3.0, -2.0, 0.0], 1.0, turn_rate=0.0)
    noisy = v_n + rng.normal(0.0, 0.3, v_n.shape)
    with pytest.raises(WindFitError, match=r"k held at 1 the air-relative course covers [0-9.]+ deg, expected at"):
        fit_wind(t_g, noisy, t_a, tas + rng.normal(0.0, 0.3, tas.shape))
    # turns, but a pitot reading a third of the airspeed: k = 3
    t_g, v_n, t_a, tas, _ = _triangle([3.0, -2.0, 0.0], 3.0)
    with pytest.raises(WindFitError, match=r"pitot scale k 3 is outside 0.5 to 2 .*is the pitot broken\?"):
        fit_wind(t_g, v_n, t_a, tas)
    assert fit_wind(t_g, v_n, t_a, tas * 3.0).scale == pytest.approx(1.0, abs=1e-3)


def test_fit_refuses_missing_or_unpaired_streams() -> None:
    t_g, v_n, t_a, tas, _ = _triangle([3.0, -2.0, 0.0], 1.0)
    imu = ImuStream(t=t_g, w_b=np.zeros((len(t_g), 3)), f_b=np.tile([0.0, 0.0, -9.8], (len(t_g), 1)))
    with pytest.raises(WindFitError, match="found no GNSS velocity"):
        fit_flight_wind(Flight(imu=imu, air=AirDataStream(t=t_a, tas=tas)))
    with pytest.raises(WindFitError, match="found no airspeed"):
        fit_flight_wind(Flight(imu=imu, gnss=GnssStream(t=t_g, v_n=v_n)))
    with pytest.raises(WindFitError, match="found no GNSS velocity .*and no airspeed"):
        fit_flight_wind(Flight(imu=imu))
    with pytest.raises(WindFitError, match=r"airspeed samples with GNSS velocity within 1 s, found 0"):
        fit_wind(t_g, v_n, t_a + 1000.0, tas)  # no overlap in time
    with pytest.raises(WindFitError, match=r"found 0 \(of 3997 airspeed samples, 0 of them > 0 m/s, and 2000 GNSS"):
        fit_wind(t_g, v_n, t_a, -tas)  # a pitot reading its negative offset on the ground
    with pytest.raises(WindFitError, match="expected GNSS velocity"):
        fit_wind(t_g[:1], v_n[:1], t_a, tas)
    with pytest.raises(ValueError, match="fit_wind.scale"):
        fit_wind(t_g, v_n, t_a, tas, scale=-1.0)


def test_heading_span() -> None:
    assert heading_span_deg(np.radians([350.0, 10.0])) == pytest.approx(20.0)
    assert heading_span_deg(np.radians([0.0, 90.0, 180.0, 270.0])) == pytest.approx(270.0)
    assert heading_span_deg(np.array([])) == 0.0


def test_info_prints_the_fit(capsys) -> None:
    from windahrs.cli import main

    path = require_data("alfa", ALFA_SEQUENCE)
    assert main(["info", str(path)]) == 0
    assert "wind fit   north -1.6" in capsys.readouterr().out


def test_meta_round_trip_and_description() -> None:
    t_g, v_n, t_a, tas, _ = _triangle([3.0, -2.0, 0.0], 1.1)
    fit = fit_wind(t_g, v_n, t_a, tas)
    back = WindFit.from_meta(fit.as_meta())
    assert back is not None and back.text() == fit.text()
    assert "from 146 deg" in fit.text() and "k 1.1000" in fit.text()
    est = Estimate(filter="paper:wind=fit", t=np.zeros(1), q_nb=np.array([[1.0, 0, 0, 0]]), meta=fit.as_meta())
    assert describe_wind_fit(est) == f"paper:wind=fit: {fit.text()}"
    assert WindFit.from_meta({}) is None


# --- vector values in filter specs and TOML --------------------------------------------


def test_spec_vector_values() -> None:
    est = make_estimator("paper:wind=mean:mean_wind_n=3/-2/0")
    assert est.params.mean_wind_n == (3.0, -2.0, 0.0)  # type: ignore[attr-defined]
    assert est.label == "paper:wind=mean:mean_wind_n=3/-2/0"
    assert make_estimator("paper:wind=mean:mean_wind_n=1.5e0/-2.25/0.5").params.mean_wind_n == (  # type: ignore[attr-defined]
        1.5, -2.25, 0.5)
    with pytest.raises(ValueError, match=r"mean_wind_n: expected numbers separated by '/'.*found '3/x/0' \('x'"):
        make_estimator("paper:wind=mean:mean_wind_n=3/x/0")
    with pytest.raises(ValueError, match=r"PaperParams.mean_wind_n: expected None or 3 finite.*found \(3, -2\)"):
        make_estimator("paper:wind=mean:mean_wind_n=3/-2")
    with pytest.raises(ValueError, match=r"mean_wind_n.*found \(1, 2, nan\)"):
        make_estimator("paper:wind=mean:mean_wind_n=1/2/nan")
    with pytest.raises(ValueError, match=r"mean_wind_n: expected None with wind='fit'"):
        make_estimator("paper:wind=fit:mean_wind_n=1/2/0")
    with pytest.raises(ValueError, match=r"gyro_noise.*found \(1, 2\)"):
        make_estimator("mekf:gyro_noise=1/2")
    with pytest.raises(ValueError, match=r"wind_fit_scale.*found -1"):
        make_estimator("paper:wind=fit:wind_fit_scale=-1")
    with pytest.raises(ValueError, match=r"'oracle', 'mean', 'fit', found 'gust'"):
        make_estimator("paper:wind=gust")


def test_toml_vector_values(tmp_path) -> None:
    good = tmp_path / "paper.toml"
    good.write_text('[windahrs]\nwind = "mean"\nmean_wind_n = [3, -2, 0]\n')
    est = make_estimator("paper", good)
    assert est.params == PaperParams(wind="mean", mean_wind_n=(3.0, -2.0, 0.0))  # type: ignore[attr-defined]
    # the spec's fields on top of the file's
    assert make_estimator("paper:mean_wind_n=1/1/0", good).params.mean_wind_n == (1.0, 1.0, 0.0)  # type: ignore[attr-defined]
    bad = tmp_path / "bad.toml"
    bad.write_text('[windahrs]\nwind = "mean"\nmean_wind_n = [3, "x", 0]\n')
    with pytest.raises(ValueError, match=r"bad.toml: PaperParams.mean_wind_n: expected .*found \(3, 'x', 0\)"):
        make_estimator("paper", bad)
    bad.write_text('[windahrs]\nwind = "mean"\nmean_wind_n = [3, -2]\n')
    with pytest.raises(ValueError, match=r"PaperParams.mean_wind_n.*found \(3, -2\)"):
        make_estimator("paper", bad)


# --- the paper filter with wind=fit ----------------------------------------------------


def test_paper_wind_fit_on_a_simulated_flight() -> None:
    sc = make_scenario("fixedwing", wind=8.0, duration=120.0)  # 60 s: 1.25 m/s off (k trades with the gusts)
    flight = simulate(sc, np.random.default_rng(0))
    assert flight.truth is not None and flight.truth.wind_n is not None and flight.truth.p_n is not None
    est = make_estimator("paper:wind=fit").run(flight)
    fit = WindFit.from_meta(est.meta)
    assert fit is not None and est.meta["wind"] == "fit"
    true_mean = flight.truth.wind_n.mean(axis=0)
    err = float(np.linalg.norm(fit.wind_n[:2] - true_mean[:2]))
    print(f"fit {fit.text()}; flight-mean true wind {np.round(true_mean, 3)}, |error| {err:.3f} m/s")
    assert err < 0.5
    assert np.isfinite(est.q_nb).all()
    # the same wind given as a mean gives the same attitude
    w = [float(v) for v in fit.wind_n]
    same = make_estimator(f"paper:wind=mean:mean_wind_n={w[0]!r}/{w[1]!r}/{w[2]!r}").run(flight)
    np.testing.assert_array_equal(same.q_nb, est.q_nb)


def test_cli_prints_the_fit(tmp_path, capsys) -> None:
    from windahrs.cli import main
    from windahrs.store import save_flight

    flight = simulate(make_scenario("fixedwing", wind=8.0, duration=40.0), np.random.default_rng(0))
    path = tmp_path / "fw.h5"
    save_flight(flight, path)
    assert main(["estimate", str(path), "--filter", "paper:wind=fit"]) == 0
    out = capsys.readouterr().out
    assert "paper:wind=fit: wind fit: north " in out and "pitot scale k " in out
    assert main(["compare", str(path), "--filters", "paper:wind=fit:wind_fit_scale=1,paper-nowind"]) == 0
    err = capsys.readouterr().err
    assert "windahrs: paper:wind=fit:wind_fit_scale=1: wind fit: north " in err and "k 1.0000 (held)" in err


def test_experiment_reports_the_fit() -> None:
    from windahrs.experiments.montecarlo import run_wind_experiment

    rows = run_wind_experiment("fixedwing", 8.0, 40.0, 1, ["paper:wind=fit", "paper:wind=mean"])
    fit, mean = rows
    assert fit.wind_fit_ms is not None and fit.wind_fit_max_ms == fit.wind_fit_ms and fit.wind_fit_ms < 3.0
    assert mean.wind_fit_ms is None and fit.as_dict()["wind_fit_ms"] == fit.wind_fit_ms


def test_paper_without_truth_wind_names_the_alternatives() -> None:
    sc = make_scenario("fixedwing", wind=8.0, duration=5.0)
    flight = simulate(sc, np.random.default_rng(0))
    real = flight.replace(truth=None)
    with pytest.raises(ValueError, match=r"wind=fit .*wind=mean with mean_wind_n"):
        PaperEKF().run(real)
    with pytest.raises(ValueError, match=r"mean_wind_n=3/-2/0\) or use wind=fit"):
        make_estimator("paper:wind=mean").run(real)
    # a straight 5 s of flight (the track within 15 deg): the fit refuses, naming the span
    with pytest.raises(WindFitError, match=r"PaperParams.wind='fit': wind fit: ill-conditioned.*k held at 1 the air"):
        make_estimator("paper:wind=fit").run(real)


def test_alfa_wind_fit_and_the_paper_filter() -> None:
    """ALFA has a pitot and GNSS but no vanes: the wind fit runs and agrees with ArduPilot's
    wind (from 30 s to the failure, as tests/test_benchdata.py compares the INS's); the
    paper's filter, whose air row is the vane direction, refuses naming the vanes."""
    flight = read_flight(require_data("alfa", ALFA_SEQUENCE))
    assert flight.ref_wind is not None
    fit = fit_flight_wind(flight)
    rw = flight.ref_wind
    m = (rw.t >= 30.0) & (rw.t < float(flight.meta["failure_time"]))
    ref = np.nanmean(rw.wind_n[m, :2], axis=0)
    d_err = math.degrees(math.remainder(math.atan2(fit.wind_n[1], fit.wind_n[0]) - math.atan2(ref[1], ref[0]),
                                        2 * math.pi))
    s_err = float(np.hypot(*fit.wind_n[:2]) - np.hypot(*ref))
    print(f"ALFA {fit.text()}; ArduPilot mean {np.round(ref, 2)}; direction {d_err:+.1f} deg, speed {s_err:+.2f} m/s")
    assert abs(d_err) <= 30.0 and abs(s_err) <= 1.5
    assert 0.9 < fit.scale < 1.2
    with pytest.raises(MissingSensorError, match="vanes"):
        make_estimator("paper:wind=fit").run(flight)
