"""The command line: simulate and info (on every format the readers know), their output, and
their errors."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from synthetic_logs import ulog_bytes, write_ansfl_dir
from test_io import make_flight, write_csv_dir
from windahrs.cli import main


def test_simulate_then_info(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "fw.h5"
    rc = main(
        [
            "simulate",
            "--vehicle",
            "fixedwing",
            "--wind",
            "8",
            "--duration",
            "5",
            "--seed",
            "3",
            "--out",
            str(out),
        ]
    )
    assert rc == 0 and out.is_file()
    text = capsys.readouterr().out
    assert "imu        1001 samples at 200 Hz" in text
    assert "air        251 samples at 50 Hz" in text
    assert main(["info", str(out)]) == 0
    info = capsys.readouterr().out
    assert f"file       {out}" in info
    assert "truth      yes" in info and "meta       seed = 3" in info
    assert "gnss       51 samples at 10 Hz" in info


@pytest.mark.parametrize("vehicle", ["quadrotor", "paper"])
def test_simulate_other_vehicles(
    vehicle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "f.h5"
    assert (
        main(
            ["simulate", "--vehicle", vehicle, "--wind", "5", "--duration", "3", "--out", str(out)]
        )
        == 0
    )
    assert f"vehicle = {vehicle}" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--duration", "-3"], "duration: expected > 0 s, found -3.0"),
        (["--wind", "-1"], "wind: expected W20 >= 0 m/s, found -1.0"),
        (["--seed", "-1"], "--seed: expected an integer from 0 to 2**63 - 1, found -1"),
        (["--altitude", "1"], "altitude: expected 2 to 3000 m, found 1.0"),
    ],
)
def test_simulate_bad_input_writes_nothing(
    args: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "x.h5"
    try:
        rc = main(["simulate", *args, "--out", str(out)])
    except SystemExit as exc:  # refused by argparse
        rc = exc.code
    assert rc == 2
    assert message in capsys.readouterr().err
    assert os.listdir(tmp_path) == []


def test_unknown_vehicle_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["simulate", "--vehicle", "rocket", "--out", "x.h5"])
    assert info.value.code == 2
    assert "invalid choice: 'rocket'" in capsys.readouterr().err


def test_info_on_truncated_and_missing_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "fw.h5"
    main(["simulate", "--duration", "2", "--out", str(out)])
    (tmp_path / "t.h5").write_bytes(out.read_bytes()[:3000])
    assert main(["info", str(tmp_path / "t.h5")]) == 2
    assert "truncated or corrupt" in capsys.readouterr().err
    assert main(["info", str(tmp_path / "none.h5")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_info_on_logs_and_directories(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ulg = tmp_path / "synthetic.ulg"
    ulg.write_bytes(ulog_bytes())
    assert main(["info", str(ulg)]) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"file       {ulg}\nformat     ulog\nduration   ")
    assert "imu        400 samples at 200 Hz" in text and "reference  autopilot, " in text

    flight = make_flight(np.random.default_rng(3))
    csv_dir = write_csv_dir(flight, tmp_path / "csv")
    assert main(["info", str(csv_dir)]) == 0
    text = capsys.readouterr().out
    assert "format     csv" in text and "mag        100 samples at 25 Hz" in text
    assert "reference  mocap, 80 samples at 20 Hz, heading-free" in text

    from trajectories import flight_in_place
    from windahrs.sim.sensors import SensorSuite

    ansfl = write_ansfl_dir(tmp_path / "path_1", flight_in_place(SensorSuite(), seed=1, duration=3.0))
    assert main(["info", str(ansfl)]) == 0
    text = capsys.readouterr().out
    assert "format     ansfl" in text and "gnss       31 samples at 10 Hz" in text
    assert "reference  autopilot, 31 samples at 10 Hz, heading-free" in text

    assert main(["info", str(tmp_path)]) == 2  # a folder of recordings is not one recording
    assert "unknown directory format" in capsys.readouterr().err


def test_console_script_help_lists_commands() -> None:
    res = subprocess.run(
        [sys.executable, "-m", "windahrs.cli", "--help"], capture_output=True, text=True, check=True
    )
    assert "simulate" in res.stdout and "info" in res.stdout


@pytest.fixture(scope="module")
def gusty_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cli") / "fw.h5"
    assert main(["simulate", "--wind", "8", "--duration", "6", "--seed", "2", "--out", str(out)]) == 0
    return out


def test_estimate_writes_an_estimate_and_prints_rmse(
    gusty_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from windahrs.estimate import load_estimate

    capsys.readouterr()
    out = tmp_path / "est.h5"
    assert main(["estimate", str(gusty_file), "--filter", "ins-wind", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "ins-wind: RMSE vs truth from sample 50: roll" in text and "total" in text
    est = load_estimate(out)
    assert est.filter == "ins-wind" and est.wind_n is not None and est.cov is not None
    assert set(est.innovations) >= {"gnss", "mag", "air"}


def test_damaged_estimate_file_gives_store_error(
    gusty_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An estimate file whose innovations group holds a dataset, or cut short: one
    StoreError naming the file, nothing else."""
    import h5py

    from windahrs.estimate import load_estimate
    from windahrs.store import StoreError

    out = tmp_path / "est.h5"
    assert main(["estimate", str(gusty_file), "--filter", "mekf", "--out", str(out)]) == 0
    data = out.read_bytes()
    with h5py.File(out, "a") as f:
        name = next(iter(f["innovations"]))
        del f["innovations"][name]
        f["innovations"][name] = [1.0, 2.0]
    with pytest.raises(StoreError, match=r"est\.h5: unreadable estimate"):
        load_estimate(out)
    cut = tmp_path / "cut.h5"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(StoreError, match=r"cut\.h5"):
        load_estimate(cut)


def test_filters_lists_one_estimators_parameters(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["filters", "mekf"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("mekf: error-state EKF")
    assert "  accel_lowpass               3.0\n" in out  # [mekf]'s field default, not EskfParams'
    assert "gnss_sigma" not in out  # a field [mekf] does not use is not offered
    assert main(["filters", "mekf:accel_lowpass=1"]) == 0  # a spec: its overrides shown
    assert "  accel_lowpass               1\n" in capsys.readouterr().out
    assert main(["filters", "vqf"]) == 0
    assert "tau_acc" in capsys.readouterr().out
    assert main(["filters", "auto"]) == 0
    assert "passed on to the estimator it chooses" in capsys.readouterr().out


def test_estimate_with_params_file_and_bad_names(
    gusty_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    p = tmp_path / "p.toml"
    p.write_text('[windahrs]\nmag_mode = "heading"\n[px4]\nEKF2_MAG_NOISE = 0.02\n')
    assert main(["estimate", str(gusty_file), "--filter", "mekf", "--params", str(p)]) == 0
    capsys.readouterr()
    assert main(["estimate", str(gusty_file), "--filter", "nope"]) == 2
    assert "unknown 'nope'; known filters:" in capsys.readouterr().err
    assert main(["estimate", str(tmp_path / "missing.h5"), "--filter", "mekf"]) == 2
    assert "missing.h5" in capsys.readouterr().err


def test_compare_table_and_json(gusty_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import json

    capsys.readouterr()
    assert main(["compare", str(gusty_file), "--filters", "mekf,ins-wind,paper:wind=mean"]) == 0
    table = capsys.readouterr().out
    assert "RMSE in deg against truth" in table
    assert "paper:wind=mean" in table
    assert main(["compare", str(gusty_file), "--filters", "mekf,ins-wind", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["filter"] for r in rows] == ["mekf", "ins-wind"]
    for r in rows:
        assert r["reference"] == "truth"
        assert len(r["rmse_from50_deg"]) == 3 and len(r["rmse_steady_deg"]) == 3
        assert r["rmse_total_deg"] >= r["rmse_tilt_deg"] * 0.99


def test_low_rate_imu_is_noted_with_the_held_sample_noise(
    gusty_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A 10 Hz IMU (every 20th sample of the 200 Hz flight): compare says on stderr that its
    samples are taken as held point samples (docs/estimators.md); the 200 Hz flight gets no
    warning."""
    import dataclasses

    from windahrs.store import load_flight, save_flight

    capsys.readouterr()
    assert main(["compare", str(gusty_file), "--filters", "mekf"]) == 0
    assert "IMU runs at" not in capsys.readouterr().err
    f = load_flight(gusty_file)
    imu = dataclasses.replace(f.imu, t=f.imu.t[::20], w_b=f.imu.w_b[::20], f_b=f.imu.f_b[::20])
    slow = save_flight(dataclasses.replace(f, imu=imu), tmp_path / "slow.h5")
    assert main(["compare", str(slow), "--filters", "mekf"]) == 0
    err = capsys.readouterr().err
    assert "warning: the IMU runs at 10 Hz: its samples are taken as point samples" in err
    assert "unmeasured_motion_dt" in err


def test_experiment_command(capsys: pytest.CaptureFixture[str]) -> None:
    import json

    assert main(["experiment", "--runs", "1", "--duration", "4", "--filters", "ins-wind,mekf", "--json"]) == 0
    std = capsys.readouterr()
    rows = json.loads(std.out)
    assert [r["filter"] for r in rows] == ["ins-wind", "mekf"] and rows[0]["runs"] == 1
    # Off a terminal, progress comes as whole lines (a start line, one per 30 s, an end
    # line), not tqdm's carriage-return redraws.
    assert "\r" not in std.err
    lines = [ln for ln in std.err.splitlines() if ln.startswith("experiment:")]
    assert len(lines) >= 2 and "0/2" in lines[0] and "100%" in lines[-1] and "2/2" in lines[-1]
    with pytest.raises(SystemExit) as info:
        main(["experiment", "--runs", "0"])
    assert info.value.code == 2
    assert "--runs: expected an integer from 1 to 2**63 - 1, found 0" in capsys.readouterr().err
