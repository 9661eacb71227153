"""windahrs: UAV attitude estimation in wind.

The front door (``docs/python.md``)::

    import windahrs as wa

    flight = wa.read("flight.ulg")                     # or wa.simulate / wa.Flight.from_arrays
    est = wa.estimator("ins-wind").run(flight)         # an Estimate: q_nb, bias, wind, covariance
    print(wa.score(est, flight))                       # RMSE against truth or the log's reference
    print(wa.compare(flight, ["mekf", "vqf"]))         # the table ``windahrs compare`` prints

Importing windahrs does no work: each name loads its module on first use.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

    from windahrs.estimate import Estimate
    from windahrs.experiments.compare import CompareResult
    from windahrs.filters.base import Estimator, InitialState, Streamer
    from windahrs.flight import Flight, FlightError, Site
    from windahrs.metrics import Score
    from windahrs.sim.faults import Fault
    from windahrs.sim.scenario import Scenario
    from windahrs.sim.sensors import SensorSuite

__all__ = [
    "CompareResult",
    "Estimate",
    "Estimator",
    "Flight",
    "FlightError",
    "InitialState",
    "Score",
    "Site",
    "Streamer",
    "compare",
    "estimator",
    "read",
    "score",
    "simulate",
    "smooth",
]

#: Names loaded on first use: name -> module.
_LAZY = {
    "CompareResult": "windahrs.experiments.compare",
    "Estimate": "windahrs.estimate",
    "Estimator": "windahrs.filters.base",
    "Flight": "windahrs.flight",
    "FlightError": "windahrs.flight",
    "InitialState": "windahrs.filters.base",
    "Score": "windahrs.metrics",
    "Site": "windahrs.flight",
    "Streamer": "windahrs.filters.base",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'windahrs' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


def read(path: str | os.PathLike[str], *, fmt: str | None = None, **options: Any) -> Flight:
    """Read a recording into a Flight: PX4 ULog (``.ulg``), ArduPilot DataFlash (``.bin``,
    ``.log``), a BROAD trial or a windahrs flight file (``.hdf5``/``.h5``), an ALFA or
    generic-CSV directory (:func:`windahrs.io.read_flight`; ``fmt`` skips the detection,
    ``options`` go to the reader). Raises LogFormatError (a ValueError) naming the file."""
    from windahrs.io import read_flight

    return read_flight(path, fmt=fmt, **options)


def estimator(spec: str, **params: Any) -> Estimator:
    """The estimator of a registry spec (``"ins-wind"``, ``"paper:wind=mean"``; see
    ``windahrs filters``), the compiled implementation under the plain name, with keyword
    ``params`` as overrides of fields of its parameter record
    (``wa.estimator("mekf", mag_mode="heading")``), checked as the registry checks a spec's
    (a field the estimator does not use is refused).

    Raises ValueError for an unknown name or field (the registry's message), or a value
    its parameter record rejects.
    """
    from windahrs.filters.registry import make_estimator, with_overrides

    est = make_estimator(spec)
    if not params:
        return est
    built = with_overrides(est, spec.split(":")[0], params)
    built.label = spec + "".join(f":{k}={v}" for k, v in params.items())
    return built


def smooth(
    estimator: str | Estimator, flight: Flight, *, initial: InitialState | None = None, method: str = "auto"
) -> Estimate:
    """The offline smoother of an error-state estimator (a spec such as ``"ins-wind"`` or
    ``"auto"``, or an Estimator: ``mekf``, ``mekf-air``, ``ins-wind``, ``ins-drag``, ``auto``)
    over the whole flight (:mod:`windahrs.core.smooth`): the Estimate with the smoothed
    attitude, gyro bias, velocity, wind and covariance, labelled ``NAME-smooth``. method:
    ``"auto"`` (two filters, forward and backward in time, where every sensor fused has a
    time-reversed model; else Rauch-Tung-Striebel), ``"two-filter"`` or ``"rts"``;
    ``Estimate.meta["smoother"]`` says which ran. ValueError naming an estimator it cannot
    smooth, a method it cannot run on the flight, or a flight beyond its memory budget."""
    from windahrs.core.smooth import smooth as _smooth
    from windahrs.filters.registry import make_estimator

    est = make_estimator(estimator) if isinstance(estimator, str) else estimator
    return _smooth(est, flight, initial=initial, method=method)


def score(estimate: Estimate, flight: Flight, *, remove_heading: bool | None = None) -> Score:
    """RMSE of ``estimate`` against the flight's truth (simulation) or reference (mocap,
    autopilot), in degrees: per axis from sample 50 and over the second half, tilt and
    total (:func:`windahrs.metrics.score`). ``remove_heading``: remove a constant heading
    offset first (default: when the reference is heading-free)."""
    from windahrs.metrics import score as _score

    return _score(estimate, flight, remove_heading=remove_heading)


def simulate(
    scenario: str | Scenario = "fixedwing",
    *,
    seed: int | None = None,
    rng: np.random.Generator | None = None,
    wind: float | None = None,
    duration: float | None = None,
    altitude: float | None = None,
    sensors: SensorSuite | None = None,
    site: Site | None = None,
    faults: Sequence[Fault] = (),
) -> Flight:
    """A simulated flight with its truth.

    scenario: a vehicle name ("fixedwing", "quadrotor", "paper") with ``wind`` (W20, m/s;
    for "paper" the paper's wind speed), ``duration`` (s) and ``altitude`` (m), or a
    Scenario object (then those three must be left out). Exactly one of ``seed`` (int
    >= 0) or ``rng`` draws every random number. sensors, site: default suite and the
    paper's site (:func:`windahrs.sim.scenario.simulate`). faults: sensor faults
    (:mod:`windahrs.sim.faults`) applied to the streams after the simulation, the truth
    untouched, drawing from the same generator after it (``docs/ROBUSTNESS.md``).
    """
    import numpy as np

    from windahrs.sim.scenario import make_scenario
    from windahrs.sim.scenario import simulate as _simulate

    if (seed is None) == (rng is None):
        found = "both" if seed is not None else "neither"
        raise ValueError(f"seed, rng: expected one of an integer seed or a numpy Generator, found {found}")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
        raise ValueError(f"seed: expected an integer >= 0, found {seed!r}")
    if faults:  # refused before the simulation's work, not after
        from windahrs.sim.faults import Fault, FaultError

        for i, f in enumerate(faults):
            if not isinstance(f, Fault):
                raise FaultError(f"faults[{i}]", "a Fault (windahrs.sim.faults)", type(f).__name__)
    if isinstance(scenario, str):
        sc = make_scenario(scenario, wind=0.0 if wind is None else wind, duration=duration, altitude=altitude)
    else:
        given = [k for k, v in (("wind", wind), ("duration", duration), ("altitude", altitude)) if v is not None]
        if given:
            raise ValueError(f"{', '.join(given)}: expected to be set in the Scenario object, found keywords")
        sc = scenario
    gen = rng if rng is not None else np.random.default_rng(seed)
    flight = _simulate(sc, gen, sensors, site)
    if faults:
        from windahrs.sim.faults import inject

        flight = inject(flight, faults, rng=gen)
    return flight if seed is None else flight.replace(meta={**flight.meta, "seed": seed})


def compare(
    flight: Flight | str | os.PathLike[str],
    specs: str | Sequence[str | Estimator],
    *,
    align: bool = False,
) -> CompareResult:
    """Run estimators on one flight (or a file :func:`read` knows) and score each: exactly
    what ``windahrs compare`` prints is ``str(result)``, its ``--json`` is
    ``result.as_json()``, the rows are ``result.rows`` (:class:`~windahrs.metrics.Score`)
    and the estimates ``result.estimates``. specs: registry specs (a list or "a,b,c") or
    estimators. align: fit one mount rotation and clock offset of the reference to the
    FIRST filter's estimate and score all against it
    (:func:`windahrs.experiments.compare.compare`)."""
    from windahrs.experiments.compare import compare as _compare
    from windahrs.flight import Flight as _Flight

    fl = flight if isinstance(flight, _Flight) else read(flight)
    return _compare(fl, specs, align=align)
