"""The compiled core of the error-state and additive EKFs (windahrs.core, windahrs.aid):
every output equals the previous main's (tests/golden/detail.npz, written by
tests/golden/make_golden.py on commit addd942, when a readable twin still checked each case)
on short flights that exercise every branch: vanes, pitot only, NaN in every stream, a
quadrotor, from the truth, non-default parameters, no site field; and a streamer equals its
batch run bit for bit."""

from __future__ import annotations

import importlib.util
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from windahrs.estimate import Estimate
from windahrs.filters.base import MissingSensorError, merge_events, replay
from windahrs.filters.registry import make_estimator
from windahrs.flags import FLAGS

HERE = Path(__file__).resolve().parent / "golden"
_spec = importlib.util.spec_from_file_location("make_golden", HERE / "make_golden.py")
assert _spec is not None and _spec.loader is not None
golden = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(golden)

TOL = 1e-9
CASES = {c[0]: c[1:] for c in golden.detail_cases()}


@cache
def _stored() -> dict[str, np.ndarray]:
    with np.load(HERE / "detail.npz") as z:
        return {k: z[k] for k in z.files}


@cache
def _run(key: str) -> Estimate:
    kind, fname, params, truth = CASES[key]
    return golden.run_detail(kind, fname, params, truth)


@pytest.mark.parametrize("key", list(CASES))
def test_outputs_equal_the_previous_main(key: str) -> None:
    """States to TOL, covariance diagonal to TOL relative, innovations to TOL relative,
    gate decisions, logged sensors and skipped counts identical."""
    now = golden.summary(_run(key))
    ref = {k.split("|")[-1]: v for k, v in _stored().items() if k.rsplit("|", 1)[0] == key}
    assert set(now) == set(ref), key
    assert list(now["sensors"]) == list(ref["sensors"])
    np.testing.assert_array_equal(now["skipped"], ref["skipped"])
    # Intended change (stop 21): the rows before the filter starts, NaN covariances in the
    # stored answers (and NaN velocity and wind, a tilt-only attitude), now hold the state and
    # covariance it would start from (core.kernel._initial_state): finite, not compared
    pre = np.isnan(ref["cov_diag"]).any(axis=1)
    assert np.isfinite(now["cov_diag"]).all()
    for name in ("q_nb", "gyro_bias_b", "v_n", "wind_n"):
        if name in ref:
            assert np.isfinite(now[name]).all(), name
            assert len(now[name]) == len(pre), name
            np.testing.assert_allclose(now[name][~pre], ref[name][~pre], rtol=0, atol=TOL, err_msg=name)
    np.testing.assert_allclose(now["cov_diag"][~pre], ref["cov_diag"][~pre], rtol=TOL, atol=0)
    for s in ref["sensors"]:
        np.testing.assert_array_equal(now[f"inn_{s}_t"], ref[f"inn_{s}_t"], err_msg=s)
        np.testing.assert_array_equal(now[f"inn_{s}_accepted"], ref[f"inn_{s}_accepted"], err_msg=s)
        a, b = now[f"inn_{s}_nu"], ref[f"inn_{s}_nu"]
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=s)
        scale = float(np.nanmax(np.abs(b), initial=0.0))
        np.testing.assert_allclose(a, b, rtol=TOL, atol=TOL * scale, err_msg=s)
        np.testing.assert_allclose(now[f"inn_{s}_nis"], ref[f"inn_{s}_nis"], rtol=TOL, atol=TOL, err_msg=s)


@pytest.mark.parametrize("key", [k for k in CASES if k.endswith("|nan")])
def test_the_nan_case_exercises_what_it_should(key: str) -> None:
    kind = CASES[key][0]
    est = _run(key)
    uses = make_estimator(kind).uses
    assert all(v > 0 for s, v in est.skipped.items() if s in uses)
    assert np.isnan(est.q_nb).sum() == 0 and est.cov is not None and np.isfinite(est.cov).all()
    assert est.first_initialised > 0 and est.flags is not None
    assert all(est.flags[: est.first_initialised] & (1 << FLAGS["not_initialised"][0]))


def test_pitot_only_fuses_airspeed_and_sideslip() -> None:
    for kind in ("mekf-air", "ins-wind", "ekf10"):
        inn = _run(f"{kind}|pitot").innovations
        assert {"tas", "sideslip"} <= set(inn) and "air" not in inn


def test_tight_gates_of_the_variants_reject_some_samples() -> None:
    for i, (kind, p) in enumerate(golden.VARIANTS):
        est = _run(f"{kind}|nan|variant{i}")
        if p.mag_mode == "heading":
            assert est.innovations["mag"].nu.shape[1] == 1
        if min(p.gate_mag, p.gate_air, p.gate_accel) < 5.0:
            assert any(not inn.accepted.all() for inn in est.innovations.values())


@pytest.mark.parametrize("kind", golden.KINDS)
def test_streaming_equals_batch(kind: str) -> None:
    """The streamer fed sample by sample (through base.replay, reading its state at every
    IMU sample) equals the batch run exactly, on the flight with NaN in every stream."""
    est = make_estimator(kind)
    f = golden.case_flight("nan")
    has = frozenset(s for s in ("imu", "mag", "gnss", "air") if getattr(f, s) is not None) & est.uses
    t_ev, kinds, vals = merge_events(f, has)
    streamed = replay(est, est.streamer(f.site, has=has), f, t_ev, kinds, vals)
    batch = est.run(f, cov_every=1)  # (the streamer records every sample's covariance)
    for name in ("q_nb", "gyro_bias_b", "v_n", "wind_n", "cov"):
        a, b = getattr(streamed, name), getattr(batch, name)
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a, b, err_msg=name)
    assert list(streamed.innovations) == list(batch.innovations)
    for s, inn in batch.innovations.items():
        np.testing.assert_array_equal(streamed.innovations[s].nu, inn.nu)
        np.testing.assert_array_equal(streamed.innovations[s].accepted, inn.accepted)
    assert streamed.skipped == batch.skipped


def test_quadrotor_without_air_data_is_refused() -> None:
    for kind in golden.NEEDS_AIR:
        with pytest.raises(MissingSensorError, match=rf"filter '{kind}' needs air data \('air'\)"):
            make_estimator(kind).run(golden.case_flight("quadrotor"))


def test_estimates_are_labelled_with_the_registry_spec() -> None:
    spec = "mekf:mag_mode=heading"
    assert make_estimator(spec).run(golden.case_flight("nan")).filter == spec


_BRIDGE = """
import sys, numpy as np
from windahrs.filters.registry import make_estimator
from windahrs.sim.scenario import make_scenario, simulate
f = simulate(make_scenario("fixedwing", wind=8.0, duration=1.0), np.random.default_rng(4))
out = {k: make_estimator(k).run(f).q_nb for k in sys.argv[2].split(",")}
np.savez(sys.argv[1], **out)
"""
BRIDGED = ("mekf", "ins-wind", "ekf10", "ins-drag")


def test_the_source_without_jit_gives_the_compiled_answers(tmp_path: Path) -> None:
    """The readable reference is the same source run by the Python interpreter
    (NUMBA_DISABLE_JIT=1, in a subprocess): a bridge run on a 1 s flight equals the
    compiled run (in this process, where the suite has compiled the kernels already)."""
    import os
    import subprocess
    import sys

    from windahrs.sim.scenario import make_scenario, simulate

    out = tmp_path / "nojit.npz"
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    subprocess.run([sys.executable, "-c", _BRIDGE, str(out), ",".join(BRIDGED)], check=True, env=env, timeout=300)
    f = simulate(make_scenario("fixedwing", wind=8.0, duration=1.0), np.random.default_rng(4))
    with np.load(out) as z:
        for k in BRIDGED:
            np.testing.assert_allclose(z[k], make_estimator(k).run(f).q_nb, rtol=0, atol=1e-9, err_msg=k)
