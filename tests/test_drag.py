"""The multirotor drag aid source and the wind scoring: ins-drag observes the wind of a
simulated quadrotor without a pitot, where ins-wind cannot; the wind metric on known
series; the experiment command reports it."""

from __future__ import annotations

import dataclasses
import json
from functools import cache

import numpy as np
import pytest

from windahrs.cli import main
from windahrs.filters.registry import make_estimator
from windahrs.flight import Flight
from windahrs.metrics import score, wind_errors
from windahrs.sim.scenario import make_scenario, simulate

#: the simulated airframe's drag (QuadrotorScenario.mu, no bluff-body term)
MATCHED = "ins-drag:drag_mcoef=0.3:drag_bcoef_x=0:drag_bcoef_y=0"


@cache
def quadrotor() -> Flight:
    return simulate(make_scenario("quadrotor", wind=8.0, duration=60.0), np.random.default_rng(11))


def test_drag_makes_the_wind_observable_without_a_pitot() -> None:
    f = quadrotor()
    assert f.air is None
    drag = make_estimator(MATCHED).run(f)
    plain = make_estimator("ins-wind").run(f)
    w_drag, w_plain = wind_errors(drag, f), wind_errors(plain, f)
    assert w_drag.rmse_h < 1.0 and abs(w_drag.direction_deg) < 15.0, w_drag
    assert w_plain.rmse_h > 5.0, w_plain  # no air data: the wind states learn nothing
    inn = drag.innovations["drag"]
    assert inn.nu.shape == (len(f.imu.t) - 1, 2) and inn.accepted.mean() > 0.99
    assert score(drag, f).rmse_tilt_deg < 1.0
    # the vertical wind is held at zero, as EKF2's 2-D wind state
    assert drag.wind_n is not None and np.all(drag.wind_n[1:, 2] == 0.0)


def test_ins_wind_with_drag_on_leaves_the_vertical_wind_free() -> None:
    est = make_estimator("ins-wind:drag=true:drag_mcoef=0.3:drag_bcoef_x=0:drag_bcoef_y=0").run(quadrotor())
    assert "drag" in est.innovations and est.wind_n is not None and np.ptp(est.wind_n[1:, 2]) > 0


def test_wind_errors_on_known_series() -> None:
    f = quadrotor()
    assert f.truth is not None and f.truth.wind_n is not None
    est = make_estimator("ins-wind").run(f)
    c, s = np.cos(np.radians(10.0)), np.sin(np.radians(10.0))
    w = f.truth.wind_n[np.searchsorted(f.truth.t, est.t)].copy()
    w[:, :2] = w[:, :2] @ np.array([[c, s], [-s, c]])  # the true wind turned 10 deg clockwise
    w[:, :2] += 0.5  # and offset
    e = wind_errors(dataclasses.replace(est, wind_n=w), f)
    k = est.t >= 30.0
    true_h = f.truth.wind_n[np.searchsorted(f.truth.t, est.t[k]), :2]
    assert e.rmse_h == pytest.approx(np.sqrt(np.mean(np.sum((w[k, :2] - true_h) ** 2, axis=1))))
    mean_est, mean_true = w[k, :2].mean(axis=0), true_h.mean(axis=0)
    turn = np.degrees(np.arctan2(mean_est[1], mean_est[0]) - np.arctan2(mean_true[1], mean_true[0]))
    assert e.direction_deg == pytest.approx(turn) and 5.0 < e.direction_deg < 15.0
    with pytest.raises(ValueError, match="t_from"):
        wind_errors(est, f, t_from=1e6)
    with pytest.raises(ValueError, match="wind states"):
        wind_errors(make_estimator("mekf").run(f), f)


def test_experiment_reports_the_wind(capsys: pytest.CaptureFixture[str]) -> None:
    args = ["experiment", "--vehicle", "quadrotor", "--wind", "8", "--runs", "1", "--duration", "40"]
    assert main([*args, "--filters", f"{MATCHED},mekf", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert rows[0]["wind_rmse_h_ms"] < 1.5 and abs(rows[0]["wind_direction_deg"]) < 15.0
    assert rows[1]["wind_rmse_h_ms"] is None
    assert main([*args, "--filters", f"{MATCHED},mekf"]) == 0
    out = capsys.readouterr().out
    assert "wind m/s" in out and "from 30 s on" in out


def test_a_field_the_estimator_does_not_use_is_refused() -> None:
    with pytest.raises(ValueError, match="filter 'mekf' does not use parameter 'drag_mcoef'"):
        make_estimator("mekf:drag_mcoef=0.3")
    with pytest.raises(ValueError, match="filter 'ekf7' does not use parameter 'gyro_scale_noise'"):
        make_estimator("ekf7:gyro_scale_noise=1e-3")
    with pytest.raises(ValueError, match="filter 'usque' does not use parameter 'init_mag_bias'"):
        make_estimator("usque:init_mag_bias=1e-6")  # it carries no hard-iron states
    with pytest.raises(ValueError, match="has no parameter 'no_such_field'"):
        make_estimator("ins-drag:no_such_field=1")


def test_parameter_files_follow_the_same_rule(tmp_path) -> None:  # type: ignore[no-untyped-def]
    p = tmp_path / "p.toml"
    p.write_text("[px4]\nEKF2_MCOEF = 0.25\nEKF2_GYR_NOISE = 0.015\n")
    with pytest.warns(UserWarning, match=r"does not use EKF2_MCOEF \(drag_mcoef\)"):
        mekf = make_estimator("mekf", params_file=p)
    assert mekf.params.gyro_noise == pytest.approx(0.015 * 0.1)  # type: ignore[attr-defined]
    drag = make_estimator("ins-drag", params_file=p)
    assert drag.params.drag_mcoef == 0.25  # type: ignore[attr-defined]
    p.write_text("[windahrs]\ndrag_mcoef = 0.25\n")
    with pytest.raises(ValueError, match="filter 'mekf' does not use parameter 'drag_mcoef'"):
        make_estimator("mekf", params_file=p)
