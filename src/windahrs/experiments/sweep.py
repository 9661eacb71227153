"""Sweeps: many simulated flights × estimators, described by a TOML file, run on Dask and
stored as Parquet (``windahrs sweep``).

A spec lists scenarios (a ``[grid]`` whose list values are crossed, and/or ``[[scenario]]``
tables), estimators (``[[estimator]]``: a registry name and a parameter set) and seeds.
Each row of the result (a run × estimator) has a content-addressed id: a hash of the
scenario, the estimator (name and parameters), the seed and the windahrs version. A run
(one scenario and seed) is simulated once and every estimator of the spec that lacks a
row runs on it; rows are appended as Parquet part files, each written atomically, to a
dataset directory, so a rerun skips the ids already present.

Spec format (docs/sweep.md)::

    [sweep]
    seeds = 5                 # seeds 0..4, or a list of integers >= 0
    pcrb = true               # PCRB ratio for the estimators with a bound (default true)

    [grid]                    # each value a scalar or a list; lists are crossed
    vehicle = "fixedwing"     # fixedwing | quadrotor | paper
    wind = [0.0, 4.0, 8.0]    # W20, m/s (paper: the paper's wind speed)
    turbulence = true         # Dryden turbulence on the mean wind
    duration = 20.0           # s
    # altitude = 50.0         # m (default: the vehicle's)

    [[estimator]]
    name = "mekf"
    params = { accel_sigma = 0.5 }   # fields of its parameter record (optional)
    label = "mekf-a0.5"              # the name in tables (default: NAME:field=value...)
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import itertools
import json
import math
import os
import time
import tomllib
import uuid
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from windahrs.experiments.cluster import warm_families

__all__ = [
    "SCENARIO_KEYS", "EstimatorSpec", "ResultStore", "RunTask", "ScenarioSpec", "SweepSpec", "SweepSummary",
    "chunk_size", "load_spec", "parse_spec", "plan_tasks", "read_results", "run_sweep", "run_task", "run_tasks",
    "windahrs_version",
]

#: Refused before any work: more rows (runs × estimators) than this in one spec.
MAX_ROWS = 1_000_000
#: Refused: flights longer than this, s (one hour of 200 Hz IMU is 720 000 samples per run).
MAX_DURATION_S = 3600.0
#: Refused: more estimators than this in one spec.
MAX_ESTIMATORS = 100
#: Rows buffered in memory before a part file is written; also written every FLUSH_S seconds.
FLUSH_ROWS = 500
FLUSH_S = 10.0

#: Scenario keys: name -> (types accepted, what the error message says is expected).
SCENARIO_KEYS: dict[str, tuple[tuple[type, ...], str]] = {
    "vehicle": ((str,), "a vehicle name (fixedwing, quadrotor, paper)"),
    "wind": ((int, float), "a number, m/s"),
    "turbulence": ((bool,), "true or false"),
    "duration": ((int, float), "a number, s"),
    "altitude": ((int, float), "a number, m"),
}
SCENARIO_DEFAULTS: dict[str, Any] = {"vehicle": "fixedwing", "wind": 0.0, "turbulence": True, "duration": 20.0,
                                     "altitude": None}
SWEEP_KEYS = {"seeds", "pcrb"}
ESTIMATOR_KEYS = {"name", "params", "label"}
TOP_KEYS = {"sweep", "grid", "scenario", "estimator"}


def windahrs_version() -> str:
    """The installed windahrs version (part of every run id)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("windahrs")
    except PackageNotFoundError:  # pragma: no cover (a source tree never installed)
        return "unknown"


@dataclass(frozen=True)
class ScenarioSpec:
    """One simulated scenario: vehicle, W20 m/s, Dryden turbulence on/off, duration s,
    altitude m (None: the vehicle's default)."""

    vehicle: str
    wind: float
    turbulence: bool
    duration: float
    altitude: float | None

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def build(self) -> Any:
        """The simulator's scenario (:func:`windahrs.sim.scenario.make_scenario`)."""
        from windahrs.sim.paper import PaperScenario
        from windahrs.sim.scenario import make_scenario

        sc = make_scenario(self.vehicle, wind=self.wind, duration=self.duration, altitude=self.altitude)
        if isinstance(sc, PaperScenario):
            return dataclasses.replace(sc, turbulence=self.turbulence)
        return dataclasses.replace(sc, wind=dataclasses.replace(sc.wind, turbulence=self.turbulence))


@dataclass(frozen=True)
class EstimatorSpec:
    """A registry estimator with a parameter set (field -> value) and its label in tables."""

    name: str
    params: tuple[tuple[str, Any], ...]
    label: str

    def build(self) -> Any:
        from windahrs.filters.registry import make_estimator, with_overrides

        est = make_estimator(self.name)
        if not self.params:
            return est
        built = with_overrides(est, self.name, dict(self.params))
        built.label = self.label
        return built

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "params": {k: v for k, v in self.params}}


@dataclass(frozen=True)
class SweepSpec:
    scenarios: tuple[ScenarioSpec, ...]
    estimators: tuple[EstimatorSpec, ...]
    seeds: tuple[int, ...]
    pcrb: bool = True

    @property
    def rows(self) -> int:
        return len(self.scenarios) * len(self.estimators) * len(self.seeds)


def run_id(scenario: ScenarioSpec, estimator: EstimatorSpec, seed: int, version: str) -> str:
    """Content address of a row: SHA-256 (first 16 hex digits) of the canonical JSON of the
    scenario, the estimator's name and parameters, the seed and the windahrs version."""
    doc = {"scenario": scenario.as_dict(), "estimator": estimator.as_dict(), "seed": seed, "version": version}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


# --- parsing and validation ---------------------------------------------------------------


def _type_name(v: object) -> str:
    return {bool: "a boolean", int: "an integer", float: "a float", str: "a string", list: "a list",
            dict: "a table"}.get(type(v), type(v).__name__)


def _check_type(field: str, value: object, types: tuple[type, ...], expected: str) -> None:
    # bool is an int in Python; a TOML true is never a number here.
    if isinstance(value, bool) and bool not in types:
        ok = False
    else:
        ok = isinstance(value, types)
    if not ok:
        raise ValueError(f"{field}: expected {expected}, found {_type_name(value)} {value!r}")


def _unknown(where: str, table: dict[str, Any], known: set[str] | dict[str, Any]) -> None:
    for key in table:
        if key not in known:
            raise ValueError(f"{where}{key}: unknown key (known: {', '.join(sorted(known))}), found {table[key]!r}")


def _scenario(where: str, values: dict[str, Any]) -> ScenarioSpec:
    full = {**SCENARIO_DEFAULTS, **values}
    for key, v in values.items():
        types, expected = SCENARIO_KEYS[key]
        _check_type(f"{where}{key}", v, types, expected)
    dur = float(full["duration"])
    if not (math.isfinite(dur) and 0 < dur <= MAX_DURATION_S):
        raise ValueError(f"{where}duration: expected > 0 and <= {MAX_DURATION_S:g} s, found {full['duration']!r}")
    spec = ScenarioSpec(
        vehicle=full["vehicle"], wind=float(full["wind"]), turbulence=full["turbulence"], duration=dur,
        altitude=None if full["altitude"] is None else float(full["altitude"]),
    )
    try:
        spec.build()
    except ValueError as exc:
        raise ValueError(f"{where.rstrip('. :')}: {exc}") from None
    return spec


def _grid(table: dict[str, Any]) -> list[ScenarioSpec]:
    _unknown("grid.", table, SCENARIO_KEYS)
    axes: list[list[Any]] = []
    for key, v in table.items():
        values = v if isinstance(v, list) else [v]
        if not values:
            raise ValueError(f"grid.{key}: expected a value or a non-empty list, found []")
        types, expected = SCENARIO_KEYS[key]
        for i, x in enumerate(values):
            _check_type(f"grid.{key}[{i}]" if isinstance(v, list) else f"grid.{key}", x, types, expected)
        axes.append(values)
    n = math.prod(len(a) for a in axes)
    if n > MAX_ROWS:
        raise ValueError(f"grid: expected at most {MAX_ROWS} scenarios, found {n}")
    out = []
    for combo in itertools.product(*axes):
        chosen = dict(zip(table, combo, strict=True))
        where = "grid (" + ", ".join(f"{k}={v!r}" for k, v in chosen.items()) + "): "
        out.append(_scenario(where, chosen))
    return out


def _seeds(value: object) -> tuple[int, ...]:
    if isinstance(value, int) and not isinstance(value, bool):
        if not 1 <= value <= MAX_ROWS:
            raise ValueError(f"sweep.seeds: expected a count from 1 to {MAX_ROWS} or a list of seeds, found {value}")
        return tuple(range(value))
    if isinstance(value, list):
        if not value:
            raise ValueError("sweep.seeds: expected at least one seed, found []")
        if len(value) > MAX_ROWS:
            raise ValueError(f"sweep.seeds: expected at most {MAX_ROWS} seeds, found {len(value)}")
        for i, s in enumerate(value):
            _check_type(f"sweep.seeds[{i}]", s, (int,), "an integer >= 0")
            if not 0 <= s < 2**63:
                raise ValueError(f"sweep.seeds[{i}]: expected an integer from 0 to 2**63-1, found {s}")
        if len(set(value)) != len(value):
            dup = next(s for s in value if value.count(s) > 1)
            raise ValueError(f"sweep.seeds: expected distinct seeds, found {dup} twice")
        return tuple(value)
    raise ValueError(f"sweep.seeds: expected a count or a list of integers, found {_type_name(value)} {value!r}")


def _estimator(i: int, table: object) -> EstimatorSpec:
    where = f"estimator[{i}]"
    if not isinstance(table, dict):
        raise ValueError(f"{where}: expected a table, found {_type_name(table)} {table!r}")
    _unknown(f"{where}.", table, ESTIMATOR_KEYS)
    if "name" not in table:
        raise ValueError(f"{where}.name: missing (a registry name, see 'windahrs filters')")
    _check_type(f"{where}.name", table["name"], (str,), "a registry name")
    params = table.get("params", {})
    _check_type(f"{where}.params", params, (dict,), "a table of parameter = value")
    for k, v in params.items():
        if isinstance(v, dict):
            raise ValueError(f"{where}.params.{k}: expected a number, string, boolean or list, found a table {v!r}")
    name = table["name"]
    label = table.get("label", ":".join([name, *(f"{k}={v}" for k, v in sorted(params.items()))]))
    _check_type(f"{where}.label", label, (str,), "a string")
    spec = EstimatorSpec(name=name, params=tuple(sorted(params.items())), label=label)
    try:
        spec.build()
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    return spec


def parse_spec(doc: dict[str, Any]) -> SweepSpec:
    """Validate a parsed TOML sweep spec (see the module docstring). Raises ValueError naming
    the field and the value found: unknown keys, wrong types (integers are accepted where a
    number is expected; nothing else is converted), unknown vehicles or estimators, bad
    parameters, and sizes past :data:`MAX_ROWS`, :data:`MAX_DURATION_S`,
    :data:`MAX_ESTIMATORS` (checked before any simulation)."""
    _unknown("", doc, TOP_KEYS)
    sweep = doc.get("sweep", {})
    _check_type("sweep", sweep, (dict,), "a table")
    _unknown("sweep.", sweep, SWEEP_KEYS)
    if "seeds" not in sweep:
        raise ValueError("sweep.seeds: missing (a count, or a list of integer seeds)")
    seeds = _seeds(sweep["seeds"])
    pcrb = sweep.get("pcrb", True)
    _check_type("sweep.pcrb", pcrb, (bool,), "true or false")
    scenarios: list[ScenarioSpec] = []
    if "grid" in doc:
        _check_type("grid", doc["grid"], (dict,), "a table")
        scenarios += _grid(doc["grid"])
    listed = doc.get("scenario", [])
    _check_type("scenario", listed, (list,), "an array of tables ([[scenario]])")
    for i, table in enumerate(listed):
        if not isinstance(table, dict):
            raise ValueError(f"scenario[{i}]: expected a table, found {_type_name(table)} {table!r}")
        _unknown(f"scenario[{i}].", table, SCENARIO_KEYS)
        scenarios.append(_scenario(f"scenario[{i}].", table))
    if not scenarios:
        raise ValueError("grid, scenario: expected a [grid] table or [[scenario]] tables, found neither")
    if len(set(scenarios)) != len(scenarios):
        dup = next(s for s in scenarios if scenarios.count(s) > 1)
        raise ValueError(f"scenario: expected distinct scenarios, found {dup.as_dict()} twice")
    tables = doc.get("estimator", [])
    _check_type("estimator", tables, (list,), "an array of tables ([[estimator]])")
    if not tables:
        raise ValueError("estimator: expected at least one [[estimator]] table, found none")
    if len(tables) > MAX_ESTIMATORS:
        raise ValueError(f"estimator: expected at most {MAX_ESTIMATORS} estimators, found {len(tables)}")
    rows = len(scenarios) * len(tables) * len(seeds)
    if rows > MAX_ROWS:
        raise ValueError(
            f"sweep: expected at most {MAX_ROWS} rows (scenarios x estimators x seeds), found {len(scenarios)} x "
            f"{len(tables)} x {len(seeds)} = {rows}"
        )
    estimators = [_estimator(i, t) for i, t in enumerate(tables)]
    for i, e in enumerate(estimators):
        for j in range(i):
            if estimators[j].label == e.label:
                raise ValueError(f"estimator[{i}].label: expected distinct labels, found {e.label!r} twice")
            if (estimators[j].name, estimators[j].params) == (e.name, e.params):
                raise ValueError(f"estimator[{i}]: the same name and parameters as estimator[{j}] ({e.name!r})")
    return SweepSpec(tuple(scenarios), tuple(estimators), seeds, pcrb)


def load_spec(path: str | os.PathLike[str]) -> SweepSpec:
    """Read and validate a TOML sweep spec (:func:`parse_spec`)."""
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{p}: not valid TOML ({exc})") from None
    try:
        return parse_spec(doc)
    except ValueError as exc:
        raise ValueError(f"{p}: {exc}") from None


# --- one run ------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunTask:
    """One flight (scenario and seed) and the estimators to run on it, with their row ids."""

    scenario: ScenarioSpec
    seed: int
    estimators: tuple[tuple[EstimatorSpec, str], ...]
    pcrb: bool
    version: str


def _convergence_deg() -> float:
    """Total-error threshold of the convergence time, deg: the reproduction's."""
    from windahrs.experiments.reproduce import CONVERGENCE_DEG

    return CONVERGENCE_DEG


def _bound_model(name: str) -> str | None:
    from windahrs.experiments.reproduce import PHYSICAL

    return PHYSICAL.get(name)


def run_task(task: RunTask) -> list[dict[str, Any]]:
    """Simulate the task's flight and run its estimators: one row each (:data:`COLUMNS`).

    Metrics (degrees): RMSE per Euler axis, tilt and total from sample 50
    (:func:`windahrs.metrics.score`); convergence_s, the time after which the total error
    stays under the reproduction's 5 deg (NaN if it never does); nees_mean, the attitude and
    gyro-bias NEES averaged over the second half (NaN without a covariance); pcrb_ratio_x/y/z,
    body-axis RMSE over the second half / sqrt(PCRB) of this flight
    (:func:`windahrs.pcrb.reproduction_bound`) for the estimators the reproduction bounds
    (ekf7, mekf, usque: "gravity"; ins-wind: "ins"), NaN for every other estimator or with
    ``pcrb = false``. An estimator that raises gives a row with ``error`` set and NaN metrics;
    the estimator's warnings (:class:`~windahrs.estimate.EstimatorWarning`: resets, gated-out
    sensors) are kept in ``warnings``, not printed.
    """
    from windahrs.estimate import EstimatorWarning
    from windahrs.metrics import attitude_errors, convergence_index, nees_attitude, score
    from windahrs.pcrb import reproduction_bound
    from windahrs.rotation import quat_conj, quat_log, quat_mul
    from windahrs.sim.scenario import simulate

    t_sim = time.perf_counter()
    flight = simulate(task.scenario.build(), np.random.default_rng(task.seed))
    sim_s = time.perf_counter() - t_sim
    assert flight.truth is not None
    bounds: dict[str, Any] = {}
    rows = []
    for spec, rid in task.estimators:
        row: dict[str, Any] = {"run_id": rid, **task.scenario.as_dict(), "seed": task.seed, "estimator": spec.label,
                               "estimator_name": spec.name, "estimator_params": json.dumps(spec.as_dict()["params"],
                                                                                           sort_keys=True),
                               "version": task.version, "error": "", "warnings": ""}
        nan3 = dict.fromkeys(("rmse_roll_deg", "rmse_pitch_deg", "rmse_yaw_deg", "rmse_tilt_deg", "rmse_total_deg",
                              "convergence_s", "nees_mean", "pcrb_ratio_x", "pcrb_ratio_y", "pcrb_ratio_z"), math.nan)
        row.update(nan3)
        t0 = time.perf_counter()
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", EstimatorWarning)
                est = spec.build().run(flight)
        except ValueError as exc:
            row.update(error=str(exc), seconds=time.perf_counter() - t0, sim_seconds=sim_s)
            rows.append(row)
            continue
        row["seconds"] = time.perf_counter() - t0
        row["warnings"] = "; ".join(str(w.message) for w in caught if issubclass(w.category, EstimatorWarning))
        row["sim_seconds"] = sim_s
        sc = score(est, flight)
        row.update(rmse_roll_deg=sc.rmse_from50_deg[0], rmse_pitch_deg=sc.rmse_from50_deg[1],
                   rmse_yaw_deg=sc.rmse_from50_deg[2], rmse_tilt_deg=sc.rmse_tilt_deg,
                   rmse_total_deg=sc.rmse_total_deg)
        err = attitude_errors(est, flight)
        total = np.degrees(err.total)
        k = convergence_index(total, _convergence_deg())
        row["convergence_s"] = float(err.t[k] - err.t[0]) if k < len(total) else math.nan
        n = len(est.t)
        steady = slice(n // 2, None)
        if est.cov is not None:
            with contextlib.suppress(ValueError, np.linalg.LinAlgError):
                row["nees_mean"] = float(np.mean(nees_attitude(est, flight)[steady]))
        model = _bound_model(spec.name)
        if task.pcrb and model is not None:
            if model not in bounds:
                bounds[model] = reproduction_bound([flight], model)
            b = bounds[model]
            if b is not None:
                body = np.degrees(quat_log(quat_mul(quat_conj(est.q_nb), flight.truth.q_nb)))
                ratio = np.sqrt(np.mean(body[steady] ** 2, axis=0)) / np.sqrt(np.mean(b[steady] ** 2, axis=0))
                row.update(pcrb_ratio_x=float(ratio[0]), pcrb_ratio_y=float(ratio[1]), pcrb_ratio_z=float(ratio[2]))
        rows.append(row)
    return rows


# --- storage ------------------------------------------------------------------------------

#: Parquet columns in order: (name, pyarrow type name).
COLUMNS: tuple[tuple[str, str], ...] = (
    ("run_id", "string"), ("vehicle", "string"), ("wind", "float64"), ("turbulence", "bool_"),
    ("duration", "float64"), ("altitude", "float64"), ("seed", "int64"), ("estimator", "string"),
    ("estimator_name", "string"), ("estimator_params", "string"),
    ("rmse_roll_deg", "float64"), ("rmse_pitch_deg", "float64"), ("rmse_yaw_deg", "float64"),
    ("rmse_tilt_deg", "float64"), ("rmse_total_deg", "float64"), ("convergence_s", "float64"),
    ("nees_mean", "float64"), ("pcrb_ratio_x", "float64"), ("pcrb_ratio_y", "float64"), ("pcrb_ratio_z", "float64"),
    ("seconds", "float64"), ("sim_seconds", "float64"), ("version", "string"), ("error", "string"),
    ("warnings", "string"),
)
PART_GLOB = "part-*.parquet"


def _schema() -> Any:
    import pyarrow as pa

    return pa.schema([(name, getattr(pa, kind)()) for name, kind in COLUMNS])


class ResultStore:
    """A Parquet dataset directory of sweep rows: part files ``part-*.parquet``, each
    written to a hidden temporary file and renamed into place, so the directory only ever
    holds complete parts (a reader, or a rerun after a crash, sees every row written so far
    and nothing half-written). Rows are buffered and written every :data:`FLUSH_ROWS`
    rows or :data:`FLUSH_S` seconds, and on :meth:`flush`."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        if self.path.exists() and not self.path.is_dir():
            raise ValueError(f"out: expected a dataset directory (or a new name), found the file {self.path}")
        self._rows: list[dict[str, Any]] = []
        self._last = time.monotonic()
        self.written = 0

    def parts(self) -> list[Path]:
        return sorted(self.path.glob(PART_GLOB)) if self.path.is_dir() else []

    def completed_ids(self) -> set[str]:
        """Ids of every row already in the dataset."""
        import pyarrow.parquet as pq

        ids: set[str] = set()
        for p in self.parts():
            ids.update(pq.read_table(p, columns=["run_id"]).column("run_id").to_pylist())
        return ids

    def add(self, rows: Sequence[dict[str, Any]]) -> None:
        self._rows.extend(rows)
        if len(self._rows) >= FLUSH_ROWS or time.monotonic() - self._last >= FLUSH_S:
            self.flush()

    def flush(self) -> None:
        """Write the buffered rows as one new part file (atomically)."""
        self._last = time.monotonic()
        if not self._rows:
            return
        import pyarrow as pa
        import pyarrow.parquet as pq

        self.path.mkdir(parents=True, exist_ok=True)
        table = pa.Table.from_pylist(self._rows, schema=_schema())
        name = f"part-{time.strftime('%Y%m%dT%H%M%S')}-{uuid.uuid4().hex[:8]}.parquet"
        tmp = self.path / f".{name}.tmp"
        try:
            pq.write_table(table, tmp)
            os.replace(tmp, self.path / name)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        self.written += len(self._rows)
        self._rows = []


def read_results(path: str | os.PathLike[str]) -> Any:
    """The rows of a sweep's dataset directory as a ``pyarrow.Table`` (parts in name order,
    a row id seen twice kept once: the first). ValueError when there is no part."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    store = ResultStore(path)
    parts = store.parts()
    if not parts:
        raise ValueError(f"results: no sweep result (part-*.parquet) in {path}")
    table = pa.concat_tables([pq.read_table(p, schema=_schema()) for p in parts])
    ids = table.column("run_id").to_pylist()
    if len(set(ids)) != len(ids):
        seen: set[str] = set()
        keep = []
        for i in ids:
            keep.append(i not in seen)
            seen.add(i)
        table = table.filter(pa.array(keep))
    return table.sort_by([("vehicle", "ascending"), ("wind", "ascending"), ("estimator", "ascending"),
                          ("seed", "ascending")])


# --- the sweep ----------------------------------------------------------------------------


def plan_tasks(spec: SweepSpec, done: set[str], version: str | None = None) -> tuple[list[RunTask], int]:
    """The runs still to do: one task per (scenario, seed) with the estimators whose row id
    is not in ``done``; and how many rows are already done."""
    version = version or windahrs_version()
    tasks, skipped = [], 0
    for sc in spec.scenarios:
        for seed in spec.seeds:
            todo = []
            for est in spec.estimators:
                rid = run_id(sc, est, seed, version)
                if rid in done:
                    skipped += 1
                else:
                    todo.append((est, rid))
            if todo:
                tasks.append(RunTask(sc, seed, tuple(todo), spec.pcrb, version))
    return tasks, skipped


#: Tasks per worker thread that the automatic chunking aims for (load balance at the end of a
#: sweep), and the most runs it puts in one task (progress granularity; work lost with a worker).
TASKS_PER_THREAD = 8
MAX_RUNS_PER_TASK = 32


def chunk_size(runs: int, threads: int) -> int:
    """Runs per task: few enough that each worker thread gets about
    :data:`TASKS_PER_THREAD` tasks, at most :data:`MAX_RUNS_PER_TASK`. A run of a 10-20 s
    flight takes tens of milliseconds, as long as the scheduler's and the client's round trip
    for a task on a busy machine: one run per task would measure Dask, not the sweep."""
    return max(1, min(MAX_RUNS_PER_TASK, -(-runs // max(threads * TASKS_PER_THREAD, 1))))


def run_tasks(tasks: Sequence[RunTask]) -> list[dict[str, Any]]:
    """:func:`run_task` on each task, the rows concatenated (one cluster task)."""
    return [row for task in tasks for row in run_task(task)]


@dataclass
class SweepSummary:
    """total rows of the spec, skipped (already present), computed now, failed tasks (and
    why), rows whose estimator raised, the dataset directory and the wall time s."""

    total: int
    skipped: int
    computed: int
    failed: list[str]
    errors: int
    out: Path
    seconds: float


def _warm_task(est: EstimatorSpec, scenario: ScenarioSpec) -> None:
    """``est`` on a 1 s flight of ``scenario`` (:func:`warm_families`). Best effort: an
    estimator that cannot run on it (a sensor the vehicle lacks, any error) is left to its own
    tasks, whose rows record why, as a sweep never stops for one estimator's failure."""
    from windahrs.sim.scenario import MIN_DURATION_S, simulate

    short = dataclasses.replace(scenario, duration=MIN_DURATION_S)
    with contextlib.suppress(Exception), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est.build().run(simulate(short.build(), np.random.default_rng(0)))


def run_sweep(
    spec: SweepSpec,
    out: str | os.PathLike[str],
    client: Any | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    retries: int = 2,
    runs_per_task: int | None = None,
) -> SweepSummary:
    """Run every row of ``spec`` not yet in the dataset directory ``out``.

    ``client``: a ``dask.distributed.Client`` (None: run here, serially). The runs go to
    the cluster in tasks of ``runs_per_task`` runs (default :func:`chunk_size`), each
    submitted with ``retries`` (a task that raises is retried; a task whose worker dies is
    rescheduled by the scheduler); only completed results are written. ``progress(done,
    total)`` counts rows, the skipped ones included. On KeyboardInterrupt the rows
    completed so far are written and the interrupt is re-raised.
    """
    t0 = time.perf_counter()
    store = ResultStore(out)
    tasks, skipped = plan_tasks(spec, store.completed_ids())
    total, done = spec.rows, skipped
    failed: list[str] = []
    errors = 0
    if progress:
        progress(done, total)

    def take(rows: list[dict[str, Any]]) -> None:
        nonlocal done, errors
        store.add(rows)
        done += len(rows)
        errors += sum(bool(r["error"]) for r in rows)
        if progress:
            progress(done, total)

    try:
        if client is None:
            for task in tasks:
                take(run_task(task))
        else:
            from distributed import as_completed

            if tasks:  # each compiled family once, on one worker, before the work (as reproduce)
                scenario = tasks[0].scenario
                warm_families(functools.partial(client.submit, pure=False),
                              [(est.build(), _warm_task, (est, scenario)) for est in spec.estimators])
            threads = sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values())
            size = chunk_size(len(tasks), threads) if runs_per_task is None else runs_per_task
            chunks = [tuple(tasks[i:i + size]) for i in range(0, len(tasks), size)]
            futures = [
                client.submit(run_tasks, chunk, key=f"windahrs-sweep-{chunk[0].estimators[0][1]}", retries=retries,
                              pure=False)
                for chunk in chunks
            ]
            what = {f.key: c for f, c in zip(futures, chunks, strict=True)}
            for fut in as_completed(futures):
                if fut.status == "finished":
                    take(fut.result())
                else:
                    failed += [f"{t.scenario.as_dict()} seed {t.seed}: {fut.exception()!r}" for t in what[fut.key]]
                fut.release()
    finally:
        store.flush()
    return SweepSummary(total, skipped, done - skipped, failed, errors, store.path, time.perf_counter() - t0)

