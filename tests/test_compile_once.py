"""Each compiled loop is compiled once, whichever way it is called: a second
specialisation of a whole filter costs 10-50 s on a cold numba cache (a fresh install's
first run, the suite's first test of it). The usual causes: a literal constant passed from
compiled code (typed ``Literal[bool](True)``), a read-only array (a global, a broadcast
view), None against a record."""

from __future__ import annotations

import numpy as np

import windahrs as wa
from windahrs.core import kernel
from windahrs.filters import additive
from windahrs.sim import gust_response


def test_the_error_state_loop_has_one_signature_for_run_batch_stream_and_smoother() -> None:
    fl = wa.simulate("quadrotor", wind=5.0, duration=3.0, seed=1)
    est = wa.estimator("mekf")
    est.run(fl)
    est.run_batch([fl, fl], threads=1)
    wa.estimator("mekf-smooth").run(fl)
    s = est.streamer(fl.site)
    imu = fl.imu
    for k in range(5):
        s.imu(float(imu.t[k]), imu.w_b[k], imu.f_b[k])
    assert len(kernel.run_events.signatures) == 1, kernel.run_events.signatures


def test_the_additive_loop_and_the_gust_loop_have_one_signature_each() -> None:
    """(Functions called only from compiled code, such as the additive filters'
    ``_update_vector``, list no signatures when their caller came from the cache; the
    loops called from Python do.)"""
    for vehicle in ("paper", "fixedwing", "quadrotor"):
        fl = wa.simulate(vehicle, wind=5.0, duration=3.0, seed=2)
        for name in ("paper-nowind", "ekf", "ukf"):
            assert np.isfinite(wa.estimator(name).run(fl).q_nb).all()
    assert len(additive.run_events.signatures) == 1, additive.run_events.signatures
    assert len(gust_response._implicit_response.signatures) == 1, gust_response._implicit_response.signatures
