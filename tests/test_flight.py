"""Flight validation and the HDF5 store: every malformed field gives its FlightError,
files round-trip, writes are atomic, truncated files give StoreError."""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np
import pytest

from windahrs.flight import (
    AirDataStream,
    Flight,
    FlightError,
    GnssStream,
    ImuStream,
    MagStream,
    Reference,
    Site,
    Truth,
)
from windahrs.store import StoreError, atomic_path, load_flight, save_flight


def imu(n: int = 50) -> ImuStream:
    t = np.arange(n) * 0.005
    f = np.tile([0.0, 0.0, -9.8], (n, 1))
    return ImuStream(t=t, w_b=np.zeros((n, 3)), f_b=f)


def small_flight() -> Flight:
    n = 50
    t = np.arange(n) * 0.005
    q = np.tile([1.0, 0, 0, 0], (n, 1))
    return Flight(
        imu=imu(n),
        mag=MagStream(t=t[::4], mag_b=np.tile([20e-6, 0, 40e-6], (len(t[::4]), 1))),
        gnss=GnssStream(t=t[::10], v_n=np.ones((5, 3))),
        air=AirDataStream(t=t[::4], tas=np.full(13, 15.0), aoa=np.zeros(13), sideslip=np.zeros(13)),
        truth=Truth(t=t, q_nb=q, v_n=np.ones((n, 3)), wind_n=np.zeros((n, 3))),
        site=Site(mag_n=np.array([20e-6, 0, 40e-6])),
        meta={"source": "test", "seed": 3},
    )


@pytest.mark.parametrize(
    ("build", "field", "found_part"),
    [
        (
            lambda: ImuStream(t=np.arange(5.0), w_b=np.zeros((5, 2)), f_b=np.ones((5, 3)) * 9.8),
            "imu.w_b",
            "(5, 2)",
        ),
        (
            lambda: ImuStream(t=np.arange(5.0), w_b=np.zeros((4, 3)), f_b=np.ones((5, 3)) * 9.8),
            "imu.w_b",
            "4 rows",
        ),
        (
            lambda: ImuStream(
                t=np.array([0.0, 1.0, 1.0]), w_b=np.zeros((3, 3)), f_b=np.ones((3, 3)) * 9
            ),
            "imu.t",
            "t[1]",
        ),
        (
            lambda: ImuStream(
                t=np.array([0.0, 2.0, 1.0]), w_b=np.zeros((3, 3)), f_b=np.ones((3, 3)) * 9
            ),
            "imu.t",
            "t[1]",
        ),
        (
            lambda: ImuStream(
                t=np.array([0.0, np.nan]), w_b=np.zeros((2, 3)), f_b=np.ones((2, 3)) * 9
            ),
            "imu.t",
            "NaN",
        ),
        (
            lambda: ImuStream(t=np.array([]), w_b=np.zeros((0, 3)), f_b=np.ones((0, 3))),
            "imu.t",
            "empty",
        ),
        (
            lambda: ImuStream(
                t=np.arange(3.0), w_b=np.full((3, 3), np.inf), f_b=np.ones((3, 3)) * 9
            ),
            "imu.w_b",
            "inf",
        ),
        (
            lambda: ImuStream(
                t=np.arange(3.0), w_b=np.full((3, 3), 100.0), f_b=np.ones((3, 3)) * 9
            ),
            "imu.w_b",
            "deg/s",
        ),
        (
            lambda: ImuStream(
                t=np.arange(3.0), w_b=np.zeros((3, 3)), f_b=np.tile([0, 0, -1.0], (3, 1))
            ),
            "imu.f_b",
            "in g",
        ),
        (lambda: ImuStream(t=np.arange(3.0), w_b="abc", f_b=np.ones((3, 3))), "imu.w_b", "str"),
        (
            lambda: MagStream(t=np.arange(3.0), mag_b=np.full((3, 3), 30.0)),
            "mag.mag_b",
            "microtesla",
        ),
        (lambda: MagStream(t=np.arange(3.0), mag_b=np.full((3, 3), 0.3)), "mag.mag_b", "gauss"),
        (lambda: GnssStream(t=np.arange(3.0), v_n=np.full((3, 3), 1e4)), "gnss.v_n", "1e+04"),
        (
            lambda: AirDataStream(
                t=np.arange(3.0), tas=np.ones(3), aoa=np.full(3, 10.0), sideslip=np.zeros(3)
            ),
            "air.aoa",
            "degrees",
        ),
        (
            lambda: Truth(t=np.arange(3.0), q_nb=np.tile([2.0, 0, 0, 0], (3, 1))),
            "truth.q_nb",
            "norm 2",
        ),
        (lambda: Truth(t=np.arange(3.0), q_nb=np.full((3, 4), np.nan)), "truth.q_nb", "NaN"),
        (
            lambda: Reference(t=np.arange(3.0), q_nb=np.tile([1.0, 0, 0, 0], (3, 1)), kind="guess"),
            "reference.kind",
            "guess",
        ),  # type: ignore[arg-type]
        (lambda: Site(gravity=1.0), "site.gravity", "1.0"),
        (lambda: Site(mag_n=np.array([30.0, 0, 0])), "site.mag_n", "30"),
        (lambda: Flight(imu=None), "imu", "NoneType"),  # type: ignore[arg-type]
        (lambda: Flight(imu=imu(), mag=imu()), "mag", "ImuStream"),  # type: ignore[arg-type]
        (lambda: Flight(imu=imu(), meta={"x": [1, 2]}), "meta['x']", "list"),
    ],
)
def test_each_malformed_field_names_itself(build, field: str, found_part: str) -> None:
    with pytest.raises(FlightError) as info:
        build()
    assert info.value.field == field
    assert found_part in str(info.value)


def test_nan_samples_are_allowed_in_sensor_streams_and_counted() -> None:
    s = imu(10)
    w = s.w_b.copy()
    w[3] = np.nan
    f = Flight(imu=ImuStream(t=s.t, w_b=w, f_b=s.f_b))
    assert "1 missing" in f.summary()


def test_reference_gaps_are_kept_as_nan_and_quaternions_renormalised() -> None:
    q = np.array([[1.0, 0, 0, 0], [np.nan] * 4, [-1.0000001, 0, 0, 0]])
    ref = Reference(t=np.arange(3.0), q_nb=q, kind="mocap", heading_free=True)
    assert np.isnan(ref.q_nb[1]).all()
    assert np.allclose(ref.q_nb[2], [1, 0, 0, 0])


def test_round_trip(tmp_path: Path) -> None:
    f = small_flight()
    path = save_flight(f, tmp_path / "f.h5")
    g = load_flight(path)
    for name in ("imu", "mag", "gnss", "air", "truth"):
        a, b = getattr(f, name), getattr(g, name)
        for k, v in vars(a).items():
            if isinstance(v, np.ndarray):
                assert np.array_equal(v, getattr(b, k)), (name, k)
    assert g.meta == f.meta
    assert np.array_equal(g.site.mag_n, f.site.mag_n)
    assert g.reference is None and g.ref_wind is None


def test_write_is_atomic_on_error_and_interrupt(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "out.h5"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_bytes(b"partial")
        raise RuntimeError("boom")
    assert os.listdir(tmp_path) == []
    # Ctrl-C in the middle of writing a flight: nothing left, an old file untouched.
    save_flight(small_flight(), target)
    before = target.read_bytes()
    import windahrs.store as store

    def interrupted(group, record):
        raise KeyboardInterrupt

    monkeypatch.setattr(store, "write_record", interrupted)
    with pytest.raises(KeyboardInterrupt):
        save_flight(small_flight(), target)
    assert os.listdir(tmp_path) == ["out.h5"]
    assert target.read_bytes() == before


def test_missing_truncated_foreign_and_corrupt_files(tmp_path: Path) -> None:
    with pytest.raises(StoreError, match="no such file"):
        load_flight(tmp_path / "nope.h5")
    good = save_flight(small_flight(), tmp_path / "good.h5")
    data = good.read_bytes()
    (tmp_path / "trunc.h5").write_bytes(data[: len(data) // 2])
    with pytest.raises(StoreError, match="trunc.h5"):
        load_flight(tmp_path / "trunc.h5")
    (tmp_path / "empty.h5").write_bytes(b"")
    with pytest.raises(StoreError, match="empty.h5"):
        load_flight(tmp_path / "empty.h5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f.attrs["format"] = "something.else"
    with pytest.raises(StoreError, match="expected format 'windahrs.flight'"):
        load_flight(tmp_path / "other.h5")
    with h5py.File(tmp_path / "future.h5", "w") as f:
        f.attrs["format"] = "windahrs.flight"
        f.attrs["version"] = 99
    with pytest.raises(StoreError, match="version 99"):
        load_flight(tmp_path / "future.h5")
    # Valid HDF5, malformed contents: the FlightError names the file and the field.
    with h5py.File(good, "r+") as f:
        del f["imu/w_b"]
        f["imu/w_b"] = np.zeros((3, 2))
    with pytest.raises(FlightError, match=r"good.h5:imu.w_b"):
        load_flight(good)


def test_air_data_one_vane_stores_the_other_angle_as_nan() -> None:
    # An angle-of-attack vane without a sideslip vane (and the reverse): the missing angle
    # is NaN, the airspeed stays a measurement, and the stream has no pair of vanes.
    air = AirDataStream(t=np.arange(3.0), tas=np.full(3, 20.0), aoa=np.full(3, 0.05))
    assert air.sideslip is not None and np.isnan(air.sideslip).all()
    assert not air.has_vanes and air.vane_names == ("aoa",)
    beta_only = AirDataStream(t=np.arange(3.0), tas=np.full(3, 20.0), sideslip=np.zeros(3))
    assert beta_only.aoa is not None and np.isnan(beta_only.aoa).all()
    assert beta_only.vane_names == ("sideslip",)
    both = AirDataStream(t=np.arange(3.0), tas=np.full(3, 20.0), aoa=np.zeros(3),
                         sideslip=np.array([np.nan, 0.0, np.nan]))
    assert both.has_vanes  # one sample with both angles
    f = Flight(imu=ImuStream(t=np.arange(3.0), w_b=np.zeros((3, 3)),
                             f_b=np.tile([0.0, 0.0, -9.8], (3, 1))), air=air)
    assert "vanes (aoa, sideslip): only aoa" in f.summary()
