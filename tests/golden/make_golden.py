"""Regenerate the golden attitudes that tests/test_golden.py compares against.

The committed file was written by this script on commit addd942 (the last main before the
estimator core was restructured), so the test checks that every windahrs estimator still
gives that commit's answers. Rerun it only when a change of answers is intended, and say
which and by how much in the commit message.

    python tests/golden/make_golden.py
    python tests/golden/make_golden.py --only ukf   # rewrite only these filters' attitudes

``--only`` rewrites the listed filters' keys of attitudes.npz and keeps every other key,
the stored commit label and detail.npz; record each such regeneration in
:data:`REGENERATED` (the file holds no per-key note: tests/test_golden.py reads every key
but ``commit`` as a case).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import subprocess
from pathlib import Path
from typing import Any

import numpy as np

from windahrs.estimate import Estimate
from windahrs.experiments.reproduce import Case, _estimator, flight_seed
from windahrs.filters.base import InitialState
from windahrs.filters.params import EskfParams
from windahrs.filters.registry import make_estimator
from windahrs.flight import AirDataStream, Flight, GnssStream, ImuStream, MagStream
from windahrs.sim.atmosphere import WindConfig
from windahrs.sim.fixedwing import FixedWingScenario
from windahrs.sim.paper import PaperScenario
from windahrs.sim.quadrotor import QuadrotorScenario
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.sim.sensors import SensorSuite

HERE = Path(__file__).resolve().parent
#: Our estimators (the outside baselines are not ours to keep equal).
FILTERS = (
    "paper", "paper:wind=mean", "paper-nowind", "ekf", "ukf",
    "ekf7", "ekf10", "mekf", "mekf-air", "ins-wind", "usque",
)
#: Keys rewritten by ``--only`` since the stored commit: filter -> (commit, why).
REGENERATED = {
    "ukf": ("cfeedb9", "sigma points from an LDL^T root instead of an eigen root (determinism, speed)"),
    "mekf": ("stop 16, then branch ansfl", "accel_noise_online on by default (the accelerometer's noise on "
             "line, from the kernel's sample differences; max 2.9e-3 rad from addd942); then "
             "accel_noise_mean_start on by default (that noise starts as the mean of the samples so far, "
             "VQF's filter start; max 1.9e-3 rad from stop 16, fixedwing_8); then lowpass_bias on by default "
             "(the means' gyro-bias columns; stop 20, max 0.106 rad on fixedwing_8, mekf's coordinated turns); "
             "then accel_fuse_rate 50 Hz by default (the gravity mean fused at 50 Hz with R / k while the "
             "gain is small; stop 24, max 5.5e-4 rad, fixedwing_8); then mag_fuse_rate 10 Hz (the field's mean "
             "likewise; stop 24, max 4.7e-4 rad from the previous, fixedwing_8); then the gyro bias's walk at "
             "1e-4 across the vertical, 2e-5 along it (gyro_bias_noise, gyro_bias_noise_vertical; stop 27, "
             "max 0.016 rad from the previous on paper_5, 0.013 fixedwing_8, 0.0035 quadrotor_8; the matched "
             "cases unchanged: the simulator's bias walks alike about every axis)"),
    "ekf7": ("stop 19", "gravity as mekf takes it in the field (accel_lowpass 3 s, accel_noise_online): "
             "max 0.146 rad from stop 18 (fixedwing_8: the mean keeps a coordinated turn's acceleration), "
             "0.030 rad on quadrotor_8; the matched cases unchanged"),
    "usque": ("stop 19", "the same gravity as ekf7 (accel_lowpass 3 s, accel_noise_online); the matched "
              "cases unchanged"),
    "ins-wind": ("stop 35", "the covariance predicted once per 10 ms over the IMU steps (cov_period 0.01 s, "
                 "PX4 EKF2's EKF2_PREDICT_US): max 3.4e-5 rad (paper_5 matched), 2.3e-5 fixedwing_8; "
                 "quadrotor_8 unchanged (its start's rest alignment never ends there, so every step is predicted "
                 "at its sample); the detail cases run it with cov_period 0 and equal addd942's"),
}
#: Physically tuned filters as the reproduction builds them (matched to the sensors).
MATCHED = ("ekf7", "mekf", "usque", "ins-wind", "mekf-air")
EVERY = 5  # keep every 5th IMU sample
DURATION = 20.0


def flights():
    """(name, flight) of the cases: the reproduction's first seed at each wind speed, a
    fixed wing and a quadrotor in 8 m/s wind."""
    for w in (0.0, 5.0, 8.0):
        yield f"paper_{w:g}", w, simulate(
            PaperScenario(duration=DURATION, wind_speed=w), np.random.default_rng(flight_seed(w, 0))
        )
    wind = WindConfig(w20=8.0)
    yield "fixedwing_8", None, simulate(FixedWingScenario(duration=DURATION, wind=wind), np.random.default_rng(7))
    yield "quadrotor_8", None, simulate(QuadrotorScenario(duration=DURATION, wind=wind), np.random.default_rng(8))


# --- the error-state and additive EKFs in detail: every output on short flights that
# exercise every branch (vanes, pitot only, NaN in every stream, quadrotor; from the truth;
# non-default parameters; no site field). These were the cases of the readable references.

KINDS = ("mekf", "mekf-air", "ins-wind", "ekf7", "ekf10")
NEEDS_AIR = ("mekf-air", "ekf10")
CASE_DURATION = 2.5


def _with_nans(f: Flight, rng: np.random.Generator) -> Flight:
    """NaN samples in every stream: the first IMU, magnetometer and GNSS samples (the
    initialisation must wait) and a few later ones; one air sample without vanes."""

    def holes(n: int, first: bool) -> np.ndarray:
        idx = rng.choice(np.arange(1, n), size=max(2, n // 40), replace=False)
        return np.concatenate([[0], idx]) if first else idx

    assert f.mag is not None and f.gnss is not None and f.air is not None and f.air.aoa is not None
    w, fb = f.imu.w_b.copy(), f.imu.f_b.copy()
    i = holes(len(w), True)
    w[i[::2]] = np.nan
    fb[i[1::2]] = np.nan
    w[0] = np.nan
    m = f.mag.mag_b.copy()
    m[holes(len(m), True)] = np.nan
    v = f.gnss.v_n.copy()
    v[holes(len(v), True), 1] = np.nan
    tas, aoa, beta = f.air.tas.copy(), f.air.aoa.copy(), f.air.sideslip.copy()
    j = holes(len(tas), False)
    tas[j[:-1]] = np.nan
    aoa[j[-1]] = np.nan  # a sample without vanes: airspeed + sideslip instead of the vector
    return dataclasses.replace(
        f,
        imu=ImuStream(t=f.imu.t, w_b=w, f_b=fb),
        mag=MagStream(t=f.mag.t, mag_b=m),
        gnss=GnssStream(t=f.gnss.t, v_n=v),
        air=AirDataStream(t=f.air.t, tas=tas, aoa=aoa, sideslip=beta),
    )


def case_flight(name: str) -> Flight:
    if name == "quadrotor":
        return simulate(make_scenario("quadrotor", wind=5.0, duration=CASE_DURATION), np.random.default_rng(3))
    if name == "nosite":
        f = case_flight("nan")
        return dataclasses.replace(f, site=dataclasses.replace(f.site, mag_n=None, declination=None))
    sensors = SensorSuite(vanes=None) if name == "pitot" else SensorSuite()
    f = simulate(make_scenario("fixedwing", wind=8.0, duration=CASE_DURATION), np.random.default_rng(1), sensors)
    return _with_nans(f, np.random.default_rng(2)) if name == "nan" else f


VARIANTS = [
    ("mekf", EskfParams(mag_mode="heading", accel_compensation="gnss")),
    # (the re-entry gate, at half a 1-sigma gate, set back: it came after addd942)
    ("mekf", EskfParams(accel_compensation="airspeed", gate_mag=1.0, mag_mode="3d", mag_reentry_gate=1.0)),
    ("ekf7", EskfParams(mag_mode="heading", accel_compensation="gnss", gate_accel=1.0)),
    ("ins-wind", EskfParams(accel_bias_noise=0.0, mag_mode="heading")),
    # (init_yaw: init_att's, as before the magnetometer-less INS started with its heading unknown)
    ("ins-wind", EskfParams(air_mode="airspeed", synthetic_sideslip=False, gate_air=1.0, mag_mode="off",
                            init_yaw=math.radians(10.0))),
    ("mekf-air", EskfParams(accel_compensation="airspeed", air_mode="airspeed", gate_air=2.0)),
    ("ekf10", EskfParams(accel_compensation="airspeed", mag_mode="off", gate_air=1.5)),
    # magnetometer-bias states (the additive ekf7 carries none)
    ("mekf", EskfParams(init_mag_bias=1e-6)),
    ("mekf-air", EskfParams(accel_compensation="airspeed", init_mag_bias=2e-6, mag_bias_noise=1e-7)),
    ("ekf7", EskfParams(init_mag_bias=1e-6)),
    # low-passed vectors, rate-proportional gyro noise, heading about the vertical, tight
    # magnetic disturbance checks (so that they reject)
    (
        "mekf",
        EskfParams(
            accel_lowpass=0.5,
            accel_norm_gate=0.01,
            accel_compensation="gnss",
            gyro_scale_noise=1e-3,
            mag_mode="heading",
            heading_model="vertical",
            mag_lowpass=1.0,
            mag_norm_gate=0.01,
            # (its 1 % gravity gate rejects the start's sample, which gated_start then does not
            # start from: stored before gated_start, whose own cases are in tests/test_resets.py)
            gated_start=False,
        ),
    ),
    (
        "ekf7",
        EskfParams(accel_lowpass=1.0, mag_lowpass=2.0, mag_mode="heading", heading_model="vertical", mag_dip_gate=0.01),
    ),
    ("mekf-air", EskfParams(accel_compensation="airspeed", accel_lowpass=1.0, init_mag_bias=1e-6, mag_norm_gate=0.01)),
    ("ins-wind", EskfParams(mag_lowpass=1.0, gyro_scale_noise=1e-3, mag_dip_gate=0.01)),
]




def detail_cases() -> list[tuple[str, str, str, EskfParams | None, bool]]:
    """(key, kind, flight, params or None for the defaults, start from the truth)."""
    out = [
        (f"{k}|{f}", k, f, None, False)
        for f in ("vanes", "pitot", "nan", "quadrotor")
        for k in KINDS
        if not (f == "quadrotor" and k in NEEDS_AIR)
    ]
    out += [(f"{k}|vanes|truth", k, "vanes", None, True) for k in KINDS]
    out += [(f"{k}|nan|variant{i}", k, "nan", p, False) for i, (k, p) in enumerate(VARIANTS)]
    out.append(("mekf|nosite", "mekf", "nosite", None, False))
    return out


#: Defaults that changed after addd942 on purpose, set back in the detail cases (which hold
#: the core's mechanics to that commit; tests/test_golden.py holds the new defaults' answers).
DETAIL_DEFAULTS_OF_ADDD942: dict[str, dict[str, Any]] = {
    "mekf": {"accel_noise_online": False, "lowpass_bias": False, "accel_fuse_rate": 0.0, "mag_fuse_rate": 0.0,
             "gyro_bias_noise": 2e-5, "gyro_bias_noise_vertical": 0.0},
    "ekf7": {"accel_lowpass": 0.0, "accel_noise_online": False},
    "usque": {"accel_lowpass": 0.0, "accel_noise_online": False},
    "ins-wind": {"cov_period": 0.0},
}


def run_detail(kind: str, flight_name: str, params: EskfParams | None, truth: bool) -> Estimate:
    f = case_flight(flight_name)
    est = make_estimator(kind)
    if params is None and kind in DETAIL_DEFAULTS_OF_ADDD942:
        params = dataclasses.replace(est.params, **DETAIL_DEFAULTS_OF_ADDD942[kind])  # type: ignore[attr-defined]
    if params is not None:
        est = type(est)(params)  # type: ignore[call-arg]
    # (every sample's covariance: the cases pin it row by row)
    return est.run(f, initial=InitialState.from_truth(f) if truth else None, cov_every=1)  # type: ignore[call-arg]


def summary(e: Estimate) -> dict[str, Any]:
    """What a detail case keeps: states, covariance diagonal, innovations, skipped counts."""
    out: dict[str, Any] = {"q_nb": e.q_nb, "skipped": np.array([e.skipped[s] for s in sorted(e.skipped)])}
    for name in ("gyro_bias_b", "v_n", "wind_n"):
        if getattr(e, name) is not None:
            out[name] = getattr(e, name)
    assert e.cov is not None
    out["cov_diag"] = np.diagonal(e.cov, axis1=1, axis2=2)
    out["sensors"] = np.array(list(e.innovations))
    for s, inn in e.innovations.items():
        out[f"inn_{s}_t"], out[f"inn_{s}_nu"] = inn.t, inn.nu
        out[f"inn_{s}_nis"], out[f"inn_{s}_accepted"] = inn.nis, inn.accepted
    return out


def _rev() -> str:
    git = ["git", "rev-parse", "--short", "HEAD"]
    return subprocess.run(git, capture_output=True, text=True, cwd=HERE).stdout.strip()


def attitudes(only: tuple[str, ...] = FILTERS) -> dict[str, np.ndarray]:
    """The golden attitudes of the filters ``only`` on every flight, by key."""
    out: dict[str, np.ndarray] = {}
    for fname, w, fl in flights():
        for spec in only:
            est = make_estimator(spec)
            try:
                est.check(fl)
            except ValueError:
                continue
            out[f"{fname}|{spec}"] = est.run(fl).q_nb[::EVERY]
            if w is not None and spec in MATCHED:
                out[f"{fname}|{spec}|matched"] = _estimator(Case(w, spec, "none")).run(fl).q_nb[::EVERY]
            print(fname, spec, flush=True)
    return out


def rewrite_only(only: tuple[str, ...]) -> None:
    """Rewrite the keys of the filters ``only`` in attitudes.npz; every other key and the
    commit label stay as stored."""
    unknown = sorted(set(only) - set(FILTERS))
    if unknown:
        raise SystemExit(f"--only: expected filters among {', '.join(FILTERS)}, found {unknown[0]!r}")
    with np.load(HERE / "attitudes.npz") as z:
        stored = {k: z[k] for k in z.files}
    stale = [k for k in stored if k != "commit" and k.split("|")[1] in only]
    new = attitudes(only)
    if set(new) != set(stale):
        raise SystemExit(f"--only: the new keys {sorted(new)} differ from the stored {sorted(stale)}")
    stored.update(new)
    np.savez_compressed(HERE / "attitudes.npz", **stored)
    print(f"rewrote {len(new)} keys of {', '.join(only)} at {_rev()}; record it in REGENERATED")


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--only", help="comma-separated filters whose attitudes alone are rewritten")
    args = ap.parse_args()
    if args.only:
        rewrite_only(tuple(s for s in args.only.split(",") if s))
        return
    out = attitudes()
    rev = _rev()
    np.savez_compressed(HERE / "attitudes.npz", commit=np.array(rev), **out)
    detail: dict[str, Any] = {"commit": np.array(rev)}
    for key, kind, fname, params, truth in detail_cases():
        for name, a in summary(run_detail(kind, fname, params, truth)).items():
            detail[f"{key}|{name}"] = a
        print(key, flush=True)
    np.savez_compressed(HERE / "detail.npz", **detail)


if __name__ == "__main__":
    main()
