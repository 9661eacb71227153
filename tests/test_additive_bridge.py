"""The bridge run: the compiled additive-quaternion filters (paper, paper-nowind, ekf, ukf)
run as plain Python (``NUMBA_DISABLE_JIT=1``, the readable path of the same source) give
the attitudes of the compiled run."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from windahrs.filters.registry import make_estimator
from windahrs.sim.paper import PaperScenario
from windahrs.sim.scenario import simulate

SPECS = ("paper", "paper-nowind", "ekf", "ukf")
DURATION = 1.0  # s: the readable path runs at ~1 ms per sample

_CHILD = """
import sys
import numba
import numpy as np
from windahrs.filters.registry import make_estimator
from windahrs.sim.paper import PaperScenario
from windahrs.sim.scenario import simulate

flight = simulate(PaperScenario(wind_speed=5.0, duration={duration}), np.random.default_rng(11))
out = {{spec: make_estimator(spec).run(flight).q_nb for spec in {specs!r}}}
np.savez(sys.argv[1], **out)
print("jit disabled:", bool(numba.config.DISABLE_JIT))
"""


def test_readable_source_gives_the_compiled_attitudes(tmp_path: Path) -> None:
    flight = simulate(PaperScenario(wind_speed=5.0, duration=DURATION), np.random.default_rng(11))
    compiled = {spec: make_estimator(spec).run(flight).q_nb for spec in SPECS}
    path = tmp_path / "bridge.npz"
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    src = str(Path(__file__).resolve().parents[1] / "src")
    env["PYTHONPATH"] = os.pathsep.join([src, env.get("PYTHONPATH", "")])
    code = _CHILD.format(duration=DURATION, specs=SPECS)
    done = subprocess.run([sys.executable, "-c", code, str(path)], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "jit disabled: True" in done.stdout
    with np.load(path) as readable:
        for spec in SPECS:
            assert readable[spec].shape == compiled[spec].shape
            # the same operations in the same order: equal but for the compiler's rounding
            np.testing.assert_allclose(readable[spec], compiled[spec], rtol=0, atol=1e-12, err_msg=spec)
