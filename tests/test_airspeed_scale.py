"""The airspeed scale estimated on line (windahrs.aid.airspeed_scale) and the angle of attack
of a vane without a sideslip vane (windahrs.aid.aoa): the simulated acceptance, batch equals
stream, defaults, bad input, and ALFA's pitot (about 27 % low) against ArduPilot's wind."""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import pytest

from windahrs.core.kalman import read_airspeed_scale
from windahrs.filters.base import merge_events, replay
from windahrs.filters.params import EskfParams
from windahrs.filters.registry import make_estimator
from windahrs.flight import Flight
from windahrs.sim.faults import FaultError, PitotScale, VaneFailure, inject
from windahrs.sim.scenario import make_scenario, simulate

#: The issue's acceptance: a pitot reading 25 % low (0.75 of the true airspeed: the scale,
#: true / measured, is 1 / 0.75), W20 = 8 m/s, the fixed wing's turns; from 60 s on the wind
#: within 0.5 m/s of the truth (RMS) and the scale within 3 %.
TRUE_SCALE = 1.0 / 0.75


@cache
def _low_pitot(seed: int = 0, duration: float = 120.0) -> Flight:
    f = simulate(make_scenario("fixedwing", wind=8.0, duration=duration), np.random.default_rng(seed))
    return inject(f, [PitotScale(start=0.0, duration=1e9, scale=0.75)], seed=seed)


def _wind_rms_after(est, f: Flight, t0: float) -> float:  # type: ignore[no-untyped-def]
    assert f.truth is not None and f.truth.wind_n is not None and est.wind_n is not None
    m = est.t >= t0
    return float(np.sqrt(np.mean(np.sum((est.wind_n[m, :2] - f.truth.wind_n[m, :2]) ** 2, axis=1))))


@pytest.mark.parametrize("spec", ["ins-wind:airspeed_scale=true", "mekf-air:airspeed_scale=true"])
def test_a_pitot_25_percent_low_does_not_bend_the_wind(spec: str) -> None:
    f = _low_pitot()
    est = make_estimator(spec).run(f)
    a = est.airspeed_scale
    assert a is not None and a.shape[1] == 5
    late = a[:, 0] >= 60.0
    err = np.abs(a[late, 1] / TRUE_SCALE - 1.0)
    assert err.max() <= 0.03, f"{spec}: scale off by up to {100 * err.max():.1f} % after 60 s"
    assert _wind_rms_after(est, f, 60.0) <= 0.5
    # the scale's spread closes from its +-30 % start
    assert a[0, 2] > 0.2 and a[-1, 2] < 0.03


def test_without_the_scale_the_low_pitot_bends_the_wind() -> None:
    f = _low_pitot()
    est = make_estimator("ins-wind").run(f)
    assert est.airspeed_scale is None
    assert _wind_rms_after(est, f, 60.0) > 2.0


def test_the_scale_stays_near_one_on_a_right_pitot() -> None:
    f = simulate(make_scenario("fixedwing", wind=8.0, duration=120.0), np.random.default_rng(0))
    a = make_estimator("ins-wind:airspeed_scale=true").run(f).airspeed_scale
    assert a is not None and abs(a[-1, 1] - 1.0) <= 0.05


def test_streaming_equals_batch_with_the_scale() -> None:
    f = _low_pitot(0, 40.0)
    est = make_estimator("ins-wind:airspeed_scale=true")
    has = frozenset(s for s in ("imu", "mag", "gnss", "air") if getattr(f, s) is not None) & est.uses
    t_ev, kinds, vals = merge_events(f, has)
    streamer = est.streamer(f.site, has=has)
    streamed = replay(est, streamer, f, t_ev, kinds, vals)
    batch = est.run(f, cov_every=1)  # (the streamer records every sample's covariance)
    for name in ("q_nb", "v_n", "wind_n", "cov"):
        np.testing.assert_array_equal(getattr(streamed, name), getattr(batch, name), err_msg=name)
    st = streamer._st  # type: ignore[attr-defined]
    np.testing.assert_array_equal(read_airspeed_scale(st.cfg, st.flags, st.inn, st.acc), batch.airspeed_scale)


def test_defaults_and_bad_values() -> None:
    assert EskfParams().airspeed_scale is False
    assert EskfParams().airspeed_scale_sigma == 0.3
    for name, bad in (("airspeed_scale_sigma", 0.0), ("airspeed_scale_sigma", 2.0), ("airspeed_scale_tas_sigma", -1.0),
                      ("airspeed_scale", 1)):
        with pytest.raises(ValueError, match=name):
            EskfParams(**{name: bad})
    with pytest.raises(ValueError, match="does not use parameter 'airspeed_scale'"):
        make_estimator("mekf:airspeed_scale=true")
    with pytest.raises(FaultError, match="PitotScale.scale"):
        PitotScale(start=0.0, duration=1.0, scale=0.0)


def test_one_vane_fuses_its_angle_of_attack() -> None:
    """A flight whose sideslip vane reads nothing: the airspeed, the angle of attack alone and
    the synthetic sideslip are fused (before, the airspeed and the sideslip only)."""
    f = simulate(make_scenario("fixedwing", wind=5.0, duration=60.0), np.random.default_rng(1))
    f1 = inject(f, [VaneFailure(start=0.0, duration=1e9, vane="sideslip", mode="nan")], seed=1)
    assert f1.air is not None and np.isnan(f1.air.sideslip).all() and np.isfinite(f1.air.aoa).all()
    for spec in ("ins-wind", "mekf-air", "ekf10"):
        est = make_estimator(spec).run(f1)
        inn = est.innovations
        assert {"tas", "aoa", "sideslip"} <= set(inn) and "air" not in inn, spec
        assert inn["aoa"].accepted.mean() > 0.95, spec
        # the innovation is the vane's noise (1 deg) and the filter's angle error: a few deg at most
        assert np.sqrt(np.mean(inn["aoa"].nu[inn["aoa"].accepted] ** 2)) < math.radians(3.0), spec
    # air_mode "airspeed" leaves the vane out
    est = make_estimator("ins-wind:air_mode=airspeed").run(f1)
    assert "aoa" not in est.innovations


def test_batch_run_and_saved_estimate_keep_the_scale(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from windahrs.estimate import load_estimate, save_estimate

    f = _low_pitot(0, 40.0)
    est = make_estimator("ins-wind:airspeed_scale=true")
    one = est.run(f)
    (batched,) = est.run_batch([f], threads=1)
    np.testing.assert_array_equal(batched.airspeed_scale, one.airspeed_scale)
    back = load_estimate(save_estimate(one, tmp_path / "e.h5"))
    np.testing.assert_array_equal(back.airspeed_scale, one.airspeed_scale)


def test_the_commands_print_the_scale(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    from windahrs.cli import main

    out = tmp_path / "f.h5"
    fault = "pitot-scale:start=0:duration=40:scale=0.75"
    assert main(["simulate", "--duration", "40", "--wind", "8", "--fault", fault, "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["estimate", str(out), "--filter", "ins-wind:airspeed_scale=true"]) == 0
    assert "ins-wind:airspeed_scale=true: airspeed scale (true / measured) 1.3" in capsys.readouterr().out
    assert main(["compare", str(out), "--filters", "ins-wind,ins-wind:airspeed_scale=true"]) == 0
    text = capsys.readouterr().out
    assert text.count("airspeed scale") == 1  # only the filter that estimated it
    assert main(["experiment", "--runs", "1", "--duration", "40", "--filters", "ins-wind:airspeed_scale=true",
                 "--fault", fault]) == 0
    text = capsys.readouterr().out
    assert "airspeed scale (true / measured) at the end 1.3" in text and f"faults: {fault}" in text


def test_alfa_scale_from_its_own_wind_triangle() -> None:
    """ALFA's pitot against its GNSS velocity and heading: measured/|v - W_ArduPilot| has a
    median 0.92 (scale 1.09) and a constant-wind least-squares fit gives 1.07; the on-line
    scale, with the INS's own heading (8 deg RMS off ArduPilot's), ends at 0.99. It must stay
    within the +-30 % it starts with, settle (its spread below 3 %), and accept the airspeed."""
    from conftest import require_data
    from windahrs.io import read_flight

    f = read_flight(require_data("alfa", "carbonZ_2018-07-18-15-53-31_1_engine_failure"))
    with pytest.warns(Warning):
        a = make_estimator("ins-wind:airspeed_scale=true").run(f).airspeed_scale
    assert a is not None
    assert 0.9 <= a[-1, 1] <= 1.15 and a[-1, 2] < 0.03
    assert a[:, 4].mean() > 0.9


def test_an_airspeed_near_zero_goes_only_to_the_air_data_vector() -> None:
    """A pitot reading within gate_air sigmas of zero (2.5 m/s at the defaults), or negative,
    cannot be told from still air (PX4 sample_log_small.ulg on the ground reads -3 m/s): the
    airspeed, the angle of attack, the synthetic sideslip and the airspeed scale, singular at
    zero, leave it out; the paper's air-data vector, linear, still fuses it
    (core.kernel.flying_on_the_air)."""
    import dataclasses

    f = simulate(make_scenario("fixedwing", wind=5.0, duration=40.0), np.random.default_rng(2))
    assert f.air is not None
    tas = f.air.tas.copy()
    low = (f.air.t >= 20.0) & (f.air.t < 30.0)
    tas[low] = np.where(f.air.t[low] < 25.0, 2.4, -3.0)
    f2 = f.replace(air=dataclasses.replace(f.air, tas=tas))

    def inside(t: np.ndarray, lo: float = 20.0, hi: float = 30.0) -> bool:
        return bool(((t >= lo) & (t < hi)).any())

    for spec in ("ins-wind:air_mode=airspeed", "mekf-air:air_mode=airspeed", "ekf10:air_mode=airspeed",
                 "ins-wind:air_mode=airspeed:airspeed_scale=true"):
        inn = make_estimator(spec).run(f2).innovations
        for k in ("tas", "sideslip"):
            t = inn[k].t
            assert not inside(t) and inside(t, 30.0, 40.0) and inside(t, 0.0, 20.0), (spec, k)
    for spec in ("ins-wind", "mekf-air", "ins-wind:airspeed_scale=true"):  # the vector (both vanes) goes on
        assert inside(make_estimator(spec).run(f2).innovations["air"].t), spec
    # the threshold is gate_air tas_sigma: at tas_sigma 0.4 (2.0 m/s) the 2.4 m/s readings are fused
    t = make_estimator("ins-wind:air_mode=airspeed:tas_sigma=0.4").run(f2).innovations["tas"].t
    assert inside(t, 20.0, 25.0) and not inside(t, 25.0, 30.0)
