"""The merged events (windahrs.filters.base.merge_events, compiled merge_into): every sample
of the streams used, by time, and at equal times in the kinds' order (IMU, magnetometer,
GNSS, air), checked against a lexsort on (kind, time)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from windahrs.filters.base import EVENT_AIR, EVENT_GNSS, EVENT_IMU, EVENT_MAG, merge_events
from windahrs.sim.scenario import make_scenario, simulate


def _reference(flight, use):  # type: ignore[no-untyped-def]
    parts = [(flight.imu.t, EVENT_IMU, np.column_stack([flight.imu.w_b, flight.imu.f_b]))]
    nan3 = lambda n: np.full((n, 3), np.nan)  # noqa: E731
    if "mag" in use:
        parts.append((flight.mag.t, EVENT_MAG, np.column_stack([flight.mag.mag_b, nan3(len(flight.mag.t))])))
    if "gnss" in use:
        parts.append((flight.gnss.t, EVENT_GNSS, np.column_stack([flight.gnss.v_n, nan3(len(flight.gnss.t))])))
    if "air" in use:
        a = flight.air
        aoa = np.full(len(a.t), np.nan) if a.aoa is None else a.aoa
        beta = np.full(len(a.t), np.nan) if a.sideslip is None else a.sideslip
        parts.append((a.t, EVENT_AIR, np.column_stack([a.tas, aoa, beta, nan3(len(a.t))])))
    t = np.concatenate([p[0] for p in parts])
    kinds = np.concatenate([np.full(len(p[0]), p[1]) for p in parts])
    vals = np.concatenate([p[2] for p in parts])
    order = np.lexsort((kinds, t))
    return t[order], kinds[order], vals[order]


@pytest.mark.parametrize("use", [{"imu"}, {"imu", "mag"}, {"imu", "gnss", "air"}, {"imu", "mag", "gnss", "air"}])
def test_the_events_are_in_time_then_kind_order(use: set[str]) -> None:
    fl = simulate(make_scenario("fixedwing", wind=8.0, duration=4.0), np.random.default_rng(3))
    # ties off the IMU grid too: the GNSS at the magnetometer's times, NaN samples and no vanes
    g = fl.gnss
    assert fl.mag is not None and g is not None and fl.air is not None
    t_g = fl.mag.t[: len(g.t)] + 0.0
    v = g.v_n.copy()
    v[2] = np.nan
    fl = dataclasses.replace(fl, gnss=dataclasses.replace(g, t=t_g, v_n=v[: len(t_g)]),
                             air=dataclasses.replace(fl.air, aoa=None, sideslip=None))  # fmt: skip
    t, kinds, vals = merge_events(fl, frozenset(use))
    rt, rk, rv = _reference(fl, use)
    assert len(np.intersect1d(fl.imu.t, fl.mag.t)) and len(np.intersect1d(fl.mag.t, t_g))  # (ties)
    np.testing.assert_array_equal(t, rt)
    np.testing.assert_array_equal(kinds, rk)
    np.testing.assert_array_equal(vals, rv)  # (NaN where NaN)
    assert kinds.dtype == np.int64 and vals.shape == (len(t), 6)
