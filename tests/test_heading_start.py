"""benchmarks/heading_start.py: the split of a recording's heading error at its first seconds."""

from __future__ import annotations

import dataclasses
import importlib.util
import math
from pathlib import Path

import pytest

import windahrs as wa


def _module():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "heading_start.py"
    spec = importlib.util.spec_from_file_location("heading_start", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_two_parts_make_the_whole() -> None:
    """The first seconds and the rest partition the scored samples: their mean squares,
    weighted by their lengths, give the whole flight's heading RMSE; a filter that cannot run
    on the flight gives None."""
    hs = _module()
    flight = wa.simulate("quadrotor", seed=1, wind=5.0, duration=20.0)
    r = hs.split_scores("mekf", flight, flight, 3.0)
    assert r is not None
    n = len(flight.imu.t)
    first = sum(1 for t in flight.imu.t if t - flight.imu.t[0] < 3.0)
    whole = math.sqrt((first * r["heading_first"] ** 2 + (n - first) * r["heading_after"] ** 2) / n)
    assert whole == pytest.approx(r["heading"], rel=1e-9)
    assert r["heading_first"] != pytest.approx(r["heading_after"], rel=1e-3)  # (the start is not the rest)
    no_gnss = dataclasses.replace(wa.simulate("quadrotor", seed=1, wind=0.0, duration=5.0), gnss=None)
    assert hs.split_scores("ins-wind", no_gnss, no_gnss, 3.0) is None
