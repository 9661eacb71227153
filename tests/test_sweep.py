"""Sweeps (``windahrs sweep``, ``sweep-report``) and the distributed reproduction.

The cluster tests start a real ``dask scheduler`` and two ``dask worker`` processes on
127.0.0.1 (random free ports; killed in the fixture's teardown), as a user's cluster would
run them.
"""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip("distributed", reason="the dask extra is not installed")
pytest.importorskip("pyarrow", reason="the dask extra is not installed")

from windahrs.cli import main
from windahrs.experiments.sweep import (
    ResultStore,
    parse_spec,
    plan_tasks,
    read_results,
    run_id,
    run_sweep,
)

SRC = Path(__file__).resolve().parents[1] / "src"

TINY = """
[sweep]
seeds = {seeds}
pcrb = {pcrb}

[grid]
vehicle = "fixedwing"
wind = [0.0, 6.0]
duration = {duration}

[[estimator]]
name = "mekf"

[[estimator]]
name = "ins-wind"
params = {{ wind_noise = 0.1 }}
label = "ins-wind-wn0.1"
"""


def tiny(seeds: str = "2", pcrb: bool = False, duration: float = 3.0) -> str:
    return TINY.format(seeds=seeds, pcrb=str(pcrb).lower(), duration=duration)


def _doc(text: str) -> dict[str, object]:
    import tomllib

    return tomllib.loads(text)


# --- the spec ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (tiny().replace("[grid]", "[grid]\nwindspeed = 3.0"), r"grid\.windspeed: unknown key"),
        (tiny().replace("[sweep]", "[sweep]\nworkers = 2"), r"sweep\.workers: unknown key"),
        (tiny() + "\n[extra]\nx = 1\n", r"^extra: unknown key"),
        (tiny().replace("wind = [0.0, 6.0]", 'wind = [0.0, "6"]'),
         r"^grid\.wind\[1\]: expected a number, m/s, found a string '6'"),
        (tiny().replace("wind = [0.0, 6.0]", "wind = true"),
         r"grid\.wind: expected a number, m/s, found a boolean True"),
        (tiny().replace('vehicle = "fixedwing"', "vehicle = 1"), r"grid\.vehicle: expected a vehicle name"),
        (tiny().replace('vehicle = "fixedwing"', 'vehicle = "blimp"'), r"vehicle: expected one of .*'blimp'"),
        (tiny().replace("[grid]", "[grid]\nturbulence = 1"),
         r"grid\.turbulence: expected true or false, found an integer 1"),
        (tiny(seeds="2.0"), r"sweep\.seeds: expected a count or a list of integers, found a float 2.0"),
        (tiny(seeds="[0, 1, 1]"), r"sweep\.seeds: expected distinct seeds, found 1 twice"),
        (tiny(seeds="[0, -1]"), r"sweep\.seeds\[1\]: expected an integer from 0"),
        (tiny(seeds="0"), r"sweep\.seeds: expected a count from 1"),
        (tiny(seeds="600000"), r"sweep: expected at most 1000000 rows .* 2 x 2 x 600000 = 2400000"),
        (tiny(duration=1e6),
         r"^grid \(vehicle='fixedwing', wind=0.0, duration=1000000.0\): duration: expected > 0 and <= 3600 s"),
        (tiny(duration=-1.0), r"duration: expected > 0 and <= 3600 s, found -1.0"),
        (tiny().replace('name = "mekf"', 'name = "nope"'), r"estimator\[0\]: .*nope"),
        (tiny().replace("wind_noise = 0.1", "no_such_field = 1"), r"estimator\[1\]: .*no_such_field"),
        (tiny().replace('label = "ins-wind-wn0.1"', 'label = "mekf"'), r"estimator\[1\]\.label: expected distinct"),
        (tiny().replace('label = "ins-wind-wn0.1"', "label = 3"), r"estimator\[1\]\.label: expected a string"),
        (tiny().replace('name = "mekf"', 'name = "mekf"\nspec = "x"'), r"estimator\[0\]\.spec: unknown key"),
        (tiny().split("[[estimator]]")[0], r"estimator: expected at least one"),
        ("[sweep]\nseeds = 1\n[[estimator]]\nname = 'mekf'\n", r"grid, scenario: expected"),
        (tiny().replace("[grid]", "[grid]\naltitude = 0.5"), r"altitude: expected 2 to 3000 m, found 0.5"),
    ],
)
def test_spec_errors_name_the_field_and_value(text: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        parse_spec(_doc(text))


def test_spec_grid_and_list_and_ids() -> None:
    spec = parse_spec(_doc(tiny(seeds="[3, 7]") + '\n[[scenario]]\nvehicle = "quadrotor"\nwind = 2\nduration = 3.0\n'))
    assert [s.wind for s in spec.scenarios] == [0.0, 6.0, 2.0]
    assert isinstance(spec.scenarios[2].wind, float)  # an integer where a number is expected: accepted, exact
    assert spec.seeds == (3, 7) and spec.rows == 12
    sc, est = spec.scenarios[0], spec.estimators[1]
    ids = {run_id(s, e, seed, "1") for s in spec.scenarios for e in spec.estimators for seed in spec.seeds}
    assert len(ids) == 12  # every row its own address
    assert run_id(sc, est, 3, "1") == run_id(sc, est, 3, "1")
    assert run_id(sc, est, 3, "1") != run_id(sc, est, 3, "2")  # the version is part of the address
    relabelled = parse_spec(_doc(tiny().replace('label = "ins-wind-wn0.1"', 'label = "other"'))).estimators[1]
    assert run_id(sc, relabelled, 3, "1") == run_id(sc, est, 3, "1")  # a label is a name, not a parameter


def test_example_spec_is_valid() -> None:
    from windahrs.experiments.sweep import load_spec

    spec = load_spec(SRC.parent / "examples" / "sweep_quick.toml")
    assert (len(spec.scenarios), len(spec.estimators), len(spec.seeds), spec.rows) == (3, 3, 5, 45)


def test_cli_spec_error_is_one_line_and_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    spec = tmp_path / "s.toml"
    spec.write_text(tiny().replace("[grid]", "[grid]\ngrade = 'tactical'"))
    out = tmp_path / "r.parquet"
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "grid.grade: unknown key" in err[0]
    assert not out.exists()


# --- resume and interruption -------------------------------------------------------------


def _metrics(path: Path) -> dict[str, tuple[object, ...]]:
    """Row id -> every column but the timings; asserts each id is present once."""
    cols = read_results(path).to_pydict()
    ids = cols["run_id"]
    raw = [pq_id for p in ResultStore(path).parts() for pq_id in _ids(p)]
    assert len(raw) == len(set(raw)), "a row was written twice"
    keep = [c for c in cols if c not in ("seconds", "sim_seconds")]
    return {rid: tuple("nan" if isinstance(v, float) and math.isnan(v) else v
                       for v in (cols[c][i] for c in keep)) for i, rid in enumerate(ids)}


def _ids(part: Path) -> list[str]:
    import pyarrow.parquet as pq

    return pq.read_table(part, columns=["run_id"]).column("run_id").to_pylist()


def test_resume_skips_completed_ids(tmp_path: Path) -> None:
    out = tmp_path / "r.parquet"
    first = run_sweep(parse_spec(_doc(tiny(seeds="[0]"))), out)
    assert (first.computed, first.skipped, first.total) == (4, 0, 4)
    before = _metrics(out)
    parts = ResultStore(out).parts()
    grown = parse_spec(_doc(tiny(seeds="[0, 1]")))
    second = run_sweep(grown, out)
    assert (second.computed, second.skipped, second.total) == (4, 4, 8)
    after = _metrics(out)
    assert len(after) == 8 and all(after[k] == v for k, v in before.items())
    assert all(p.exists() for p in parts)  # nothing rewritten
    assert plan_tasks(grown, ResultStore(out).completed_ids()) == ([], 8)
    assert run_sweep(grown, out).computed == 0


def test_interrupt_keeps_finished_rows_valid(tmp_path: Path) -> None:
    spec = parse_spec(_doc(tiny(seeds="3")))
    out = tmp_path / "r.parquet"

    def stop(done: int, total: int) -> None:
        if done >= 4:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, out, progress=stop)
    kept = _metrics(out)
    assert len(kept) == 4  # the two runs finished before Ctrl-C, and nothing half-written
    assert not list(out.glob(".*"))
    run_sweep(spec, out)
    full = _metrics(out)
    assert len(full) == spec.rows and all(full[k] == v for k, v in kept.items())


def test_sweep_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("matplotlib")
    spec = tmp_path / "s.toml"
    spec.write_text(tiny(pcrb=True))
    out = tmp_path / "r.parquet"
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "1"]) == 0
    assert "8 rows computed, 0 already present, of 8" in capsys.readouterr().out
    cols = read_results(out).to_pydict()
    mekf = [i for i, e in enumerate(cols["estimator"]) if e == "mekf"]
    assert all(math.isfinite(cols["pcrb_ratio_x"][i]) and cols["rmse_total_deg"][i] > 0 for i in mekf)
    assert all(math.isnan(v) for e, v in zip(cols["estimator"], cols["pcrb_ratio_x"], strict=True)
               if e == "ins-wind-wn0.1") is False  # ins-wind has a bound too (the "ins" model)
    rep = tmp_path / "rep"
    assert main(["sweep-report", str(out), "--out", str(rep)]) == 0
    html = (rep / "report.html").read_text()
    assert "data:image/png;base64," in html and "ins-wind-wn0.1" in html
    assert len(list(rep.glob("*.png"))) == 2
    assert main(["sweep-report", str(tmp_path / "missing"), "--out", str(rep)]) == 2


# --- a real scheduler and workers ----------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _listening(port: int, proc: subprocess.Popen[bytes], deadline: float) -> bool:
    """Whether the process ``proc`` is alive and something accepts connections on ``port``
    before ``deadline`` (time.monotonic); False once it has exited (it killed, if not)."""
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return False
        with socket.socket() as s:
            s.settimeout(1.0)
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return proc.poll() is None
        time.sleep(0.2)
    proc.kill()
    return False


@pytest.fixture(scope="module")
def cluster() -> Iterator[tuple[str, list[subprocess.Popen[bytes]]]]:
    """``dask scheduler`` and two ``dask worker`` processes (no nanny: killing one is a
    dead worker, not a restart) on 127.0.0.1; yields the address and the workers. Shared by
    the module's cluster tests; the killed-worker test, which leaves one worker, runs last."""
    from distributed import Client

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")])}
    dask = [sys.executable, "-m", "dask"]
    quiet = {"env": env, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    procs: list[subprocess.Popen[bytes]] = []
    try:
        # the scheduler first, listening before any worker starts: a worker's own port is any
        # free one, and one started beside the scheduler once took the port picked for it (the
        # scheduler died, and the Client hung on the worker's port past its timeout)
        addr = ""
        for _ in range(3):
            port = _free_port()
            sched = subprocess.Popen([*dask, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                      "--no-dashboard"], **quiet)
            procs.append(sched)
            if _listening(port, sched, deadline=time.monotonic() + 60):
                addr = f"tcp://127.0.0.1:{port}"
                break
        if not addr:
            pytest.fail("dask scheduler: not listening after 3 tries (each on a fresh port)")
        workers = [
            subprocess.Popen([*dask, "worker", addr, "--nthreads", "1", "--no-nanny", "--no-dashboard",
                              "--host", "127.0.0.1", "--name", f"w{i}"], **quiet)
            for i in range(2)
        ]
        procs += workers
        with Client(addr, timeout="30s") as c:
            c.wait_for_workers(2, timeout=60)
        yield addr, workers
    finally:
        for p in reversed(procs):
            p.kill()
        for p in procs:
            p.wait(timeout=30)


def test_reproduce_on_workers_equals_serial_bit_for_bit(tmp_path: Path, cluster: tuple[str, list]) -> None:
    import functools

    from distributed import Client

    from windahrs.experiments.reproduce import Case, run_reproduction
    from windahrs.report.reproduction import write_reproduction

    addr, _ = cluster
    cases = [Case(0.0, "paper", "oracle", "fig4_5"), Case(5.0, "paper:wind=mean", "mean", "fig4"),
             Case(5.0, "mekf", "none", "", "gravity"), Case(5.0, "ins-wind", "estimated", "", "ins")]
    kw = {"duration": 2.0, "cases": cases, "nees_runs": 13}  # 13: two NEES-check tasks of the 5 m/s flights
    write_reproduction(run_reproduction(2, **kw), tmp_path / "serial")  # type: ignore[arg-type]
    with Client(addr, timeout="10s") as client:
        res = run_reproduction(2, submit=functools.partial(client.submit, pure=False), **kw)  # type: ignore[arg-type]
    write_reproduction(res, tmp_path / "dask")
    a, b = (json.loads((tmp_path / d / "results.json").read_text()) for d in ("serial", "dask"))
    for r in (a, b):
        del r["meta"]["seconds"]  # wall time, the one field that may differ
    assert a == b
    assert (tmp_path / "serial" / "results.md").read_text() == (tmp_path / "dask" / "results.md").read_text()
    assert [c["nees_check"] is not None for c in a["cases"]] == [False, False, True, True]
    assert all(c["pcrb_ratio"] is not None for c in a["cases"][2:])


def test_killed_worker_every_run_once_equal_to_serial(tmp_path: Path, cluster: tuple[str, list]) -> None:
    from distributed import Client

    addr, workers = cluster
    spec = tmp_path / "s.toml"
    spec.write_text(tiny(seeds="6", pcrb=True, duration=4.0))  # 24 rows, 12 flights of about 0.5 s
    out = tmp_path / "r.parquet"
    codes: list[int] = []
    argv = ["sweep", str(spec), "--out", str(out), "--scheduler", addr]
    run = threading.Thread(target=lambda: codes.append(main(argv)))
    with Client(addr, timeout="10s") as watch:
        victim = next(w for w, info in watch.scheduler_info()["workers"].items() if info["name"] == "w1")
        run.start()
        deadline = time.monotonic() + 120
        while not watch.processing().get(victim):  # kill it while it computes a run
            assert time.monotonic() < deadline, "worker w1 never got a task"
            time.sleep(0.05)
        workers[1].kill()
        workers[1].wait(timeout=30)
        run.join(timeout=300)
        assert not run.is_alive()
        assert victim not in watch.scheduler_info()["workers"]
    assert codes == [0]  # the dead worker's runs went to the other one
    assert main(argv) == 0  # the rerun: nothing to add
    distributed_rows = _metrics(out)
    serial = tmp_path / "serial.parquet"
    assert main(["sweep", str(spec), "--out", str(serial), "--workers", "1"]) == 0
    serial_rows = _metrics(serial)
    assert len(distributed_rows) == 24
    assert distributed_rows == serial_rows


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--workers", "0"], "--workers: expected an integer from 1"),
        (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--workers: a local cluster's size"),
    ],
)
def test_workers_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str) -> None:
    spec = tmp_path / "s.toml"
    spec.write_text(tiny())

    def status(argv: list[str]) -> int | str | None:  # (argparse's own errors exit through SystemExit)
        try:
            return main(argv)
        except SystemExit as exc:
            return exc.code

    assert status(["reproduce", "--quick", "--out", str(tmp_path / "r"), *args]) == 2
    assert status(["sweep", str(spec), "--out", str(tmp_path / "s"), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(message in e for e in err)
    assert not (tmp_path / "r").exists() and not (tmp_path / "s").exists()


def test_warm_families_runs_the_first_estimator_of_each_family_once_before_returning() -> None:
    """cluster.warm_families: one call per compiled family (the additive filters share one,
    the error-state ones another), all finished when it returns."""
    from windahrs.experiments.cluster import serial_submit, warm_families
    from windahrs.filters.registry import make_estimator

    ran: list[str] = []
    items = [(make_estimator(n), ran.append, (n,)) for n in ("paper", "mekf", "ekf", "ins-wind", "usque", "ukf")]
    warm_families(serial_submit, items)  # type: ignore[arg-type]
    assert ran == ["paper", "mekf", "usque"]


def test_sweep_warm_task_runs_what_can_run_and_leaves_the_rest_to_its_tasks() -> None:
    from windahrs.experiments.sweep import EstimatorSpec, ScenarioSpec, _warm_task

    quad = ScenarioSpec("quadrotor", 5.0, True, 20.0, None)
    _warm_task(EstimatorSpec("mekf", (), "mekf"), quad)
    _warm_task(EstimatorSpec("mekf-air", (), "mekf-air"), quad)  # no air data on a quadrotor: skipped
