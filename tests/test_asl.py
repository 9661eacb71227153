"""The ASL layout reader (EuRoC MAV, TUM-VI; windahrs.io.asl), on simulated flights written in
that layout: a sensor frame pointing x up (as EuRoC's ADIS16448) and a z-up world frame of an
arbitrary heading. No ASL recording is in ../shared/data."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest

import windahrs as wa
from windahrs.io import LogFormatError, detect_format, read_flight
from windahrs.metrics import attitude_errors
from windahrs.rotation import dcm_from_quat, quat_from_euler, quat_mul

#: The sensor frame S: the body turned 90 deg about its y axis, so that S's x points up.
Q_BS = quat_from_euler(np.radians([0.0, -90.0, 0.0]))
#: The world frame R: NED turned to z up (a half turn about x), then 40 deg about its vertical.
Q_RN = quat_mul(quat_from_euler(np.radians([0.0, 0.0, 40.0])), np.array([0.0, 1.0, 0.0, 0.0]))

IMU_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
EUROC_GT_HEADER = ("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
                   "q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1]")
TUMVI_MOCAP_HEADER = "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []"


@cache
def _sim() -> wa.Flight:
    return wa.simulate("quadrotor", seed=3, wind=0.0, duration=20.0)


def _csv(*values: float) -> str:
    return ",".join(f"{v:.17g}" for v in values)


def _write(root: Path, reference: str = "euroc") -> Path:
    """The simulated flight in the ASL layout under root/MH_sim/mav0; returns root/MH_sim."""
    f = _sim()
    assert f.truth is not None
    seq = root / "MH_sim"
    (seq / "mav0" / "imu0").mkdir(parents=True)
    c_sb = dcm_from_quat(Q_BS).T
    ns = 1_403_636_579_000_000_000 + np.round(f.imu.t * 1e9).astype(np.int64)
    w_s, f_s = f.imu.w_b @ c_sb.T, f.imu.f_b @ c_sb.T
    rows = [IMU_HEADER] + [f"{n}," + _csv(*w, *a) for n, w, a in zip(ns, w_s, f_s, strict=True)]
    (seq / "mav0" / "imu0" / "data.csv").write_text("\n".join(rows) + "\n")
    q_rs = quat_mul(quat_mul(Q_RN, f.truth.q_nb), Q_BS)
    t_ns = 1_403_636_579_000_000_000 + np.round(f.truth.t * 1e9).astype(np.int64)
    if reference == "euroc":
        d, header = seq / "mav0" / "state_groundtruth_estimate0", EUROC_GT_HEADER
        rows = [header] + [f"{n},0,0,0,{_csv(*q)},0,0,0" for n, q in zip(t_ns, q_rs, strict=True)]
    else:
        d, header = seq / "mav0" / "mocap0", TUMVI_MOCAP_HEADER
        rows = [header] + [f"{n},0,0,0,{_csv(*q)}" for n, q in zip(t_ns, q_rs, strict=True)]
    d.mkdir(parents=True)
    (d / "data.csv").write_text("\n".join(rows) + "\n")
    return seq


@pytest.mark.parametrize("reference", ["euroc", "tumvi"])
def test_an_asl_recording_reads_into_a_level_body_and_ned(tmp_path: Path, reference: str) -> None:
    seq = _write(tmp_path, reference)
    assert detect_format(seq) == "asl" and detect_format(seq / "mav0") == "asl"
    flight = read_flight(seq)
    ref = flight.reference
    assert flight.meta["format"] == "asl" and ref is not None and ref.kind == "mocap" and ref.heading_free
    assert len(flight.imu.t) == len(_sim().imu.t) and flight.imu.t[0] == 0.0
    # the body frame is level at the start: the first second's mean specific force points up
    first = flight.imu.f_b[flight.imu.t <= 1.0].mean(axis=0)
    np.testing.assert_allclose(first / np.linalg.norm(first), [0.0, 0.0, -1.0], atol=1e-9)
    # the reference and the IMU agree on gravity: the specific force in NED, averaged, is up
    f_n = np.einsum("nij,nj->ni", dcm_from_quat(ref.q_nb), flight.imu.f_b)
    mean = f_n.mean(axis=0)
    assert np.degrees(np.arccos(-mean[2] / np.linalg.norm(mean))) < 0.5
    # and an estimator run on it scores as on the simulated flight with the same sensor (the
    # IMU alone; the bodies differ by the start's tilt: measured 0.292 against 0.351 deg)
    imu_only = _sim().replace(mag=None, gnss=None, air=None)
    tilt = np.degrees(attitude_errors(wa.estimator("mekf").run(flight), flight).tilt[50:])
    sim_tilt = np.degrees(attitude_errors(wa.estimator("mekf").run(imu_only), imu_only).tilt[50:])
    assert np.sqrt(np.mean(tilt**2)) < 1.5 * np.sqrt(np.mean(sim_tilt**2)) + 0.1


def test_bench_data_finds_asl_recordings_in_a_folder(tmp_path: Path) -> None:
    from windahrs.experiments.benchdata import discover_flights

    seq = _write(tmp_path)
    assert discover_flights(tmp_path).flights == (seq,)


def test_bad_asl_recordings_name_the_file(tmp_path: Path) -> None:
    seq = _write(tmp_path)
    gt = seq / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    gt.write_text(gt.read_text().replace("q_RS_w", "q_w", 1))
    with pytest.raises(LogFormatError, match=r"state_groundtruth_estimate0.*missing column 'q_RS_w'"):
        read_flight(seq)
    imu = seq / "mav0" / "imu0" / "data.csv"
    imu.write_text("timestamp,a,b\n1,2,3\n")
    with pytest.raises(LogFormatError, match=r"imu0.*'#timestamp'"):
        read_flight(seq)
    with pytest.raises(LogFormatError, match="not an ASL recording"):
        read_flight(tmp_path, fmt="asl")
