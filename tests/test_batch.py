"""Batched runs (windahrs.core.batch): several flights through one compiled estimator in one
parallel call give the Estimates of the flights run one by one."""

from __future__ import annotations

import dataclasses
import threading
from functools import cache

import numba
import numpy as np
import pytest

from windahrs.estimate import Estimate
from windahrs.filters.base import InitialState
from windahrs.filters.registry import make_estimator
from windahrs.flight import Flight
from windahrs.rotation import quat_conj, quat_log, quat_mul
from windahrs.sim.scenario import make_scenario, simulate

#: the issue's bound on batched against single-stream attitudes, rad
TOL_RAD = 1e-9


@cache
def _flights(vehicle: str) -> tuple[Flight, ...]:
    """Three short flights of different lengths, winds and seeds; the second with NaN
    samples in every stream (skipped and counted)."""
    out = []
    for seed, (wind, duration) in enumerate([(8.0, 9.0), (4.0, 14.0), (0.0, 6.0)]):
        fl = simulate(make_scenario(vehicle, wind=wind, duration=duration), np.random.default_rng(seed))
        if seed == 1:
            for stream, field in (("imu", "w_b"), ("mag", "mag_b"), ("gnss", "v_n"), ("air", "tas")):
                s = getattr(fl, stream)
                if s is not None:
                    getattr(s, field)[len(s.t) // 3] = np.nan
        out.append(fl)
    return tuple(out)


def _angle(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    return np.linalg.norm(quat_log(quat_mul(quat_conj(q1), q2)), axis=1)


def _assert_same(one: Estimate, batched: Estimate) -> None:
    ok = np.isfinite(one.q_nb).all(axis=1)
    assert ok.all()
    assert _angle(one.q_nb, batched.q_nb).max() <= TOL_RAD
    for name in ("gyro_bias_b", "v_n", "wind_n", "cov"):
        a, b = getattr(one, name), getattr(batched, name)
        assert (a is None) == (b is None), name
        if a is not None:
            np.testing.assert_allclose(b, a, rtol=0, atol=1e-12, err_msg=name)
    assert one.state_labels == batched.state_labels
    assert one.skipped == batched.skipped
    assert one.innovations.keys() == batched.innovations.keys()
    for key, inn in one.innovations.items():
        other = batched.innovations[key]
        np.testing.assert_array_equal(other.t, inn.t)
        np.testing.assert_allclose(other.nu, inn.nu, rtol=0, atol=1e-12, err_msg=key)
        np.testing.assert_array_equal(other.accepted, inn.accepted)
    assert one.resets.keys() == batched.resets.keys()
    assert one.alerts.keys() == batched.alerts.keys()


@pytest.mark.parametrize(
    ("spec", "vehicle"),
    [("mekf", "fixedwing"), ("ins-wind", "fixedwing"), ("mekf-air", "fixedwing"), ("ekf10", "fixedwing"),
     ("ins-drag", "quadrotor")],
)  # fmt: skip
def test_batched_equals_single_stream(spec: str, vehicle: str) -> None:
    flights = _flights(vehicle)
    est = make_estimator(spec)
    threads = min(2, numba.config.NUMBA_NUM_THREADS)
    batched = est.run_batch(flights, threads=threads)
    assert len(batched) == len(flights)
    assert [len(e.t) for e in batched] == [len(f.imu.t) for f in flights]
    assert sum(e.skipped["imu"] for e in batched) == 1  # the second flight's NaN sample
    for fl, b in zip(flights, batched, strict=True):
        _assert_same(est.run(fl), b)


def test_batched_with_initial_states_and_one_thread() -> None:
    flights = _flights("fixedwing")
    initial = [InitialState.from_truth(flights[0], sigma_att=0.01), None, InitialState.from_truth(flights[2])]
    est = make_estimator("ins-wind")
    batched = est.run_batch(flights, initial=initial, threads=1)
    for fl, ini, b in zip(flights, initial, batched, strict=True):
        _assert_same(est.run(fl, initial=ini), b)
    # the initial state matters: without it the first flight's first attitude differs
    assert _angle(batched[0].q_nb[:1], est.run(flights[0]).q_nb[:1])[0] > 1e-6


def test_a_flight_the_estimator_cannot_run_is_named_before_any_run() -> None:
    flights = _flights("fixedwing")
    no_gnss = dataclasses.replace(flights[1], gnss=None)
    with pytest.raises(ValueError, match="GNSS velocity"):
        make_estimator("ins-wind").run_batch([flights[0], no_gnss])


def test_bad_arguments() -> None:
    flights = _flights("fixedwing")
    est = make_estimator("mekf")
    with pytest.raises(ValueError, match=r"initial: expected one entry per flight \(3\), found 1"):
        est.run_batch(flights, initial=[None])
    top, before = numba.config.NUMBA_NUM_THREADS, numba.get_num_threads()
    for bad in (0, top + 1, 1.5):
        with pytest.raises(ValueError, match="threads: expected an integer from 1 to"):
            est.run_batch(flights, threads=bad)  # type: ignore[arg-type]
    assert est.run_batch([]) == []
    est.run_batch(flights[:1], threads=1)
    assert numba.get_num_threads() == before  # the call restored numba's count


def test_estimators_without_a_batched_core_run_one_by_one() -> None:
    flights = _flights("fixedwing")[:2]
    est = make_estimator("ekf")
    for fl, b in zip(flights, est.run_batch(flights), strict=True):
        np.testing.assert_array_equal(b.q_nb, est.run(fl).q_nb)


@pytest.mark.parametrize("spec", ["mekf", "ins-wind", "ekf7", "ekf"])
def test_the_attitude_covariance_alone_is_the_full_ones_block(spec: str) -> None:
    flights = _flights("fixedwing")[:2]
    est = make_estimator(spec)
    full = est.run_batch(flights)
    att = est.run_batch(flights, cov="attitude")
    none = est.run_batch(flights, cov="none")
    for f, a, n in zip(full, att, none, strict=True):
        block = f.att_cov()
        assert block is not None and a.cov is not None
        assert a.state_labels == tuple(lab for lab in f.state_labels if lab.startswith("att_"))
        assert len(a.state_labels) == 3
        np.testing.assert_array_equal(a.cov, block)
        assert n.cov is None and n.state_labels == ()
        for e in (a, n):
            np.testing.assert_array_equal(e.q_nb, f.q_nb)
            np.testing.assert_array_equal(e.gyro_bias_b, f.gyro_bias_b)
    with pytest.raises(ValueError, match="cov: expected one of 'full', 'attitude', 'none', found 'att'"):
        est.run_batch(flights, cov="att")  # type: ignore[arg-type]


def test_calls_from_several_python_threads_at_once() -> None:
    """As from a Dask worker with several threads: each call gets its own runs' Estimates."""
    flights = _flights("fixedwing")
    est = make_estimator("mekf")
    ref = [est.run(f).q_nb for f in flights]
    got: dict[int, list[np.ndarray]] = {}

    def work(i: int) -> None:
        order = flights if i % 2 == 0 else flights[::-1]
        out = [e.q_nb for e in est.run_batch(order, threads=min(2, numba.config.NUMBA_NUM_THREADS))]
        got[i] = out if i % 2 == 0 else out[::-1]

    pool = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in pool:
        t.start()
    for t in pool:
        t.join()
    assert sorted(got) == [0, 1, 2, 3]
    for out in got.values():
        for a, b in zip(out, ref, strict=True):
            np.testing.assert_array_equal(a, b)


def test_a_covariance_stride_as_in_run() -> None:
    flights = _flights("fixedwing")
    est = make_estimator("ins-wind")
    for cov in ("full", "attitude"):
        batched = est.run_batch(flights, cov_every=7, cov=cov)  # type: ignore[attr-defined]
        for fl, b in zip(flights, batched, strict=True):
            one = est.run(fl, cov_every=7)  # type: ignore[call-arg]
            assert b.cov is not None and one.cov is not None and b.cov_index is not None
            np.testing.assert_array_equal(b.cov_index, np.arange(0, len(fl.imu.t), 7))
            np.testing.assert_array_equal(b.cov_index, one.cov_index)
            block = one.cov if cov == "full" else one.att_cov()
            np.testing.assert_array_equal(b.cov, block)
            np.testing.assert_array_equal(b.q_nb, one.q_nb)


def test_several_chunks_keep_the_flights_order() -> None:
    """Six flights on one thread go in three chunks (their Python work overlapping the
    filters); each Estimate is still its own flight's."""
    from windahrs.core.batch import chunk_size

    assert chunk_size(6, 1) == 2 and chunk_size(3, 2) == 4 and chunk_size(100, 2) == 25
    base = _flights("fixedwing")
    flights = [base[2], base[0], base[1], base[1], base[2], base[0]]
    est = make_estimator("mekf")
    batched = est.run_batch(flights, threads=1)
    singles = {id(f): est.run(f) for f in base}
    for fl, b in zip(flights, batched, strict=True):
        _assert_same(singles[id(fl)], b)


def test_an_error_of_the_compiled_loop_is_raised_not_waited_for(monkeypatch: pytest.MonkeyPatch) -> None:
    """The Estimates are built as each run ends (its flag set by the parallel loop); a loop
    that fails after some runs have ended raises its error from run_batch, in every chunk."""
    from windahrs.core import batch

    def failing(*args: object) -> None:
        done = args[-3]  # (..., order, done, rec, sm)
        done[0] = 1  # type: ignore[index]  # (one run ended, the others never will)
        raise RuntimeError("the loop failed")

    monkeypatch.setattr(batch, "_run_packed", failing)
    flights = list(_flights("fixedwing")) * 2
    with pytest.raises(RuntimeError, match="the loop failed"):
        make_estimator("mekf").run_batch(flights, threads=1)
