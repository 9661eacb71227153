"""Same answers: every windahrs estimator gives the attitudes that commit addd942 gave
(tests/golden/attitudes.npz, written by tests/golden/make_golden.py) on the reproduction's
first seed at 0, 5 and 8 m/s, a fixed wing and a quadrotor, within 1e-6 rad; except the
filters whose answers were changed on purpose, regenerated alone and listed with the
commit and the reason in make_golden.REGENERATED."""

from __future__ import annotations

import importlib.util
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from windahrs.experiments.reproduce import Case, _estimator
from windahrs.filters.registry import make_estimator
from windahrs.rotation import quat_conj, quat_log, quat_mul

HERE = Path(__file__).resolve().parent / "golden"
_spec = importlib.util.spec_from_file_location("make_golden", HERE / "make_golden.py")
assert _spec is not None and _spec.loader is not None
golden = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(golden)

TOL_RAD = 1e-6


@cache
def _stored() -> dict[str, np.ndarray]:
    with np.load(HERE / "attitudes.npz") as z:
        return {k: z[k] for k in z.files}


@cache
def _flights() -> dict[str, tuple[float | None, object]]:
    return {name: (w, fl) for name, w, fl in golden.flights()}


def _keys() -> list[str]:
    return sorted(k for k in _stored() if k != "commit")


@pytest.mark.parametrize("key", _keys())
def test_attitude_equals_the_golden_run(key: str) -> None:
    fname, spec, *matched = key.split("|")
    w, fl = _flights()[fname]
    est = _estimator(Case(w, spec, "none")) if matched else make_estimator(spec)
    q = est.run(fl).q_nb[:: golden.EVERY]  # type: ignore[attr-defined]
    ref = _stored()[key]
    err = np.linalg.norm(quat_log(quat_mul(quat_conj(ref), q)), axis=1)
    assert err.max() <= TOL_RAD, f"{key}: max {err.max():.3g} rad at sample {int(err.argmax()) * golden.EVERY}"


def test_every_estimator_of_ours_is_covered() -> None:
    specs = {k.split("|")[1] for k in _keys()}
    assert specs == set(golden.FILTERS)
