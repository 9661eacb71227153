"""The Monte Carlo runner: estimators in simulated wind, N seeded flights of one scenario, every estimator on
each, RMSE aggregated over runs (``windahrs experiment``).

Aggregation: per axis, the root of the mean over runs of the squared per-run RMSE (the
RMSE over all runs' samples when runs have equal length).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from windahrs.filters.registry import make_estimator
from windahrs.metrics import WIND_FROM_S, Score, WindErrors, score, wind_errors
from windahrs.sim.faults import Fault, inject
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.windfit import WindFit

__all__ = ["ExperimentRow", "run_wind_experiment"]


@dataclass(frozen=True)
class ExperimentRow:
    """One estimator's result over the runs: RMSE in degrees, from sample 50 and over the
    second half, per axis; tilt and total from sample 50; for an estimator with wind
    states, the horizontal wind RMSE m/s and the direction error of the mean wind, deg,
    from :data:`~windahrs.metrics.WIND_FROM_S` on (:func:`~windahrs.metrics.wind_errors`;
    RMS over runs, and the largest direction error of a run), else None. For an estimator
    that fits a constant wind (``paper:wind=fit``, :mod:`windahrs.windfit`): wind_fit_ms,
    the horizontal distance of the fitted wind from the flight's time-mean true wind, m/s,
    RMS over runs, and wind_fit_max_ms, the largest of a run; else None."""

    filter: str
    runs: int
    rmse_from50_deg: tuple[float, float, float]
    rmse_steady_deg: tuple[float, float, float]
    rmse_tilt_deg: float
    rmse_total_deg: float
    seconds: float
    wind_rmse_h_ms: float | None = None
    wind_direction_deg: float | None = None
    wind_direction_max_deg: float | None = None
    wind_fit_ms: float | None = None
    wind_fit_max_ms: float | None = None
    #: the airspeed scale estimated on line (``airspeed_scale=true``) at the end of each run,
    #: mean over runs and the largest deviation of a run from that mean; None without it
    airspeed_scale: float | None = None
    airspeed_scale_spread: float | None = None

    def as_dict(self) -> dict[str, object]:
        return {
            "filter": self.filter,
            "runs": self.runs,
            "rmse_from50_deg": list(self.rmse_from50_deg),
            "rmse_steady_deg": list(self.rmse_steady_deg),
            "rmse_tilt_deg": self.rmse_tilt_deg,
            "rmse_total_deg": self.rmse_total_deg,
            "seconds": self.seconds,
            "wind_rmse_h_ms": self.wind_rmse_h_ms,
            "wind_direction_deg": self.wind_direction_deg,
            "wind_direction_max_deg": self.wind_direction_max_deg,
            "wind_fit_ms": self.wind_fit_ms,
            "wind_fit_max_ms": self.wind_fit_max_ms,
            "airspeed_scale": self.airspeed_scale,
            "airspeed_scale_spread": self.airspeed_scale_spread,
        }


def _rms(values: list[float] | np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def run_wind_experiment(
    vehicle: str,
    w20: float,
    duration: float,
    runs: int,
    specs: Sequence[str],
    *,
    altitude: float | None = None,
    seed0: int = 0,
    progress: Callable[[int, int], None] | None = None,
    faults: Sequence[Fault] = (),
) -> list[ExperimentRow]:
    """Simulate ``runs`` flights (seeds ``seed0 ...``), apply ``faults`` to each (seeded
    alike; :func:`windahrs.sim.faults.inject`) and score each estimator spec on each.

    Raises ValueError for a bad spec before any simulation. ``progress(done, total)`` is
    called after each estimator run.
    """
    if runs < 1:
        raise ValueError(f"runs: expected >= 1, found {runs}")
    estimators = [make_estimator(s) for s in specs]
    scenario = make_scenario(vehicle, wind=w20, duration=duration, altitude=altitude)
    scores: dict[str, list[Score]] = {s: [] for s in specs}
    winds: dict[str, list[WindErrors]] = {s: [] for s in specs}
    fits: dict[str, list[float]] = {s: [] for s in specs}
    scales: dict[str, list[float]] = {s: [] for s in specs}
    seconds = dict.fromkeys(specs, 0.0)
    import time

    done, total = 0, runs * len(specs)
    for r in range(runs):
        flight = simulate(scenario, np.random.default_rng(seed0 + r))
        if faults:
            flight = inject(flight, faults, seed=seed0 + r)
        for spec, est in zip(specs, estimators, strict=True):
            t0 = time.perf_counter()
            result = est.run(flight)
            seconds[spec] += time.perf_counter() - t0
            scores[spec].append(score(result, flight))
            if result.wind_n is not None and duration > WIND_FROM_S:
                winds[spec].append(wind_errors(result, flight))
            fit = WindFit.from_meta(result.meta)
            if fit is not None and flight.truth is not None and flight.truth.wind_n is not None:
                fits[spec].append(float(np.linalg.norm(fit.wind_n[:2] - flight.truth.wind_n[:, :2].mean(axis=0))))
            if result.airspeed_scale is not None:
                scales[spec].append(float(result.airspeed_scale[-1, 1]))
            done += 1
            if progress is not None:
                progress(done, total)
    rows = []
    for spec in specs:
        sc, wd, wf, ks = scores[spec], winds[spec], fits[spec], scales[spec]
        rows.append(
            ExperimentRow(
                filter=spec,
                runs=runs,
                rmse_from50_deg=tuple(_rms([s.rmse_from50_deg[i] for s in sc]) for i in range(3)),  # type: ignore[arg-type]
                rmse_steady_deg=tuple(_rms([s.rmse_steady_deg[i] for s in sc]) for i in range(3)),  # type: ignore[arg-type]
                rmse_tilt_deg=_rms([s.rmse_tilt_deg for s in sc]),
                rmse_total_deg=_rms([s.rmse_total_deg for s in sc]),
                seconds=seconds[spec] / runs,
                wind_rmse_h_ms=_rms([w.rmse_h for w in wd]) if wd else None,
                wind_direction_deg=_rms([w.direction_deg for w in wd]) if wd else None,
                wind_direction_max_deg=max(abs(w.direction_deg) for w in wd) if wd else None,
                wind_fit_ms=_rms(wf) if wf else None,
                wind_fit_max_ms=max(wf) if wf else None,
                airspeed_scale=float(np.mean(ks)) if ks else None,
                airspeed_scale_spread=float(np.max(np.abs(np.subtract(ks, np.mean(ks))))) if ks else None,
            )
        )
    return rows
