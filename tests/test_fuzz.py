"""Fuzzing the log readers and the Flight loader with mutated files (hypothesis).

Seeds are small files of every format the readers know: generated here (a ULog and a
DataFlash log written byte by byte, a simulated Flight saved by :mod:`windahrs.store`, a
generic CSV directory per ``docs/csv-format.md``), so the fuzzing runs without the real
data, plus real recordings from $WINDAHRS_DATA when present (the small PX4 ULog cut to its
first 400 kB, a BROAD trial, the ALFA CSV sequence).

Each example picks one file of a seed and applies one to three mutations (flipped bytes, a
cut at a random offset, an inserted, repeated or deleted chunk, a zeroed run, an emptied
file), then reads it. The reader must return a valid Flight or raise a documented error
naming the file and what is wrong: LogFormatError or FlightError from ``read_flight``,
StoreError or FlightError from ``store.load_flight``. Anything else is a crash. Every read
runs under a time limit (SIGALRM where available) so that a parser stuck in a loop fails
the test instead of hanging CI; hypothesis' deadline reports slow reads. A differential
test checks the CSV reader's numpy fast path against its row-by-row reader, and the bugs
the fuzzing found are pinned by regression tests.

The repair paths (windahrs.repair) are fuzzed with glitches a real log has rather than
random bytes: rows written twice, rows swapped, spikes of any size, NaN and inf in values
and time stamps, in the arrays of ``Flight.from_arrays`` (with and without ``strict``) and
in the rows of a CSV file. The result is a repaired Flight whose counts account for every
row and that holds no finite sample beyond the sensor ranges, or a documented error.

Bounded and reproducible: ``derandomize=True``, no example database, 100 examples per seed
(about 20 s in all on two cores).
"""

from __future__ import annotations

import signal
import struct
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from conftest import data_dir
from synthetic_logs import dataflash_bytes, ulog_bytes
from windahrs.flight import Flight, FlightError
from windahrs.io import LogFormatError, read_flight
from windahrs.store import StoreError, load_flight, save_flight

#: A read taking longer than this is a hang (the slowest seed reads in about 0.1 s).
HANG_S = 6.0
#: The same for an HDF5 read in a child process (libhdf5 hangs are expected there, see
#: read_documented): short, so that each costs little time.
HDF5_HANG_S = 2.0
FUZZ = settings(
    max_examples=100,
    # above HDF5_HANG_S, so that a libhdf5 hang is counted as an event, not a failure
    deadline=timedelta(seconds=8),
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

ALFA_SEQ = "carbonZ_2018-07-18-15-53-31_1_engine_failure"
#: The ALFA files read_alfa uses (the others are not read, so mutating them tests nothing).
ALFA_FILES = (
    "mavros-imu-data_raw.csv",
    "mavros-imu-data.csv",
    "mavros-imu-mag.csv",
    "mavros-global_position-raw-gps_vel.csv",
    "mavros-nav_info-airspeed.csv",
    "mavros-wind_estimation.csv",
    "failure_status-engines.csv",
)


class Seed:
    """Files of one recording: ``files`` (relative path -> bytes) and ``target``, the path
    (relative; "" for the directory itself) handed to the reader. Not a dataclass:
    hypothesis would print every byte of a failing example's seed."""

    def __init__(self, kind: str, files: dict[str, bytes], target: str) -> None:
        self.kind, self.files, self.target = kind, files, target

    def __repr__(self) -> str:  # hypothesis prints it with a failing example: no bytes
        return f"Seed({self.kind!r}, files={sorted(self.files)})"

    def write(self, root: Path, name: str, data: bytes) -> Path:
        """Write the seed under ``root`` with file ``name`` replaced by ``data``."""
        for rel, content in self.files.items():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            (root / rel).write_bytes(data if rel == name else content)
        return root / self.target if self.target else root


# --- seeds written here -------------------------------------------------------------------


def simulated_flight() -> Flight:
    """A 2-s simulated fixed-wing flight (every sensor stream and the truth)."""
    from windahrs.sim.scenario import make_scenario, simulate

    return simulate(make_scenario("fixedwing", wind=5.0, duration=2.0), np.random.default_rng(0))


def csv_text(header: list[str], columns: list[np.ndarray]) -> bytes:
    rows = np.column_stack(columns)
    lines = [",".join(header)] + [",".join(repr(float(x)) for x in row) for row in rows]
    return ("\n".join(lines) + "\n").encode()


def asl_files(flight: Flight) -> dict[str, bytes]:
    """``flight`` in the ASL layout (EuRoC: windahrs.io.asl): ns stamps, the IMU and the
    ground truth's attitude, EuRoC's headers (the ground truth's padded with blanks)."""
    truth = flight.truth
    assert truth is not None
    ns = 1_403_636_579_000_000_000 + np.round(flight.imu.t * 1e9).astype(np.int64)
    imu = ["#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
           "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"]
    imu += [f"{n}," + ",".join(repr(float(v)) for v in (*w, *a))
            for n, w, a in zip(ns, flight.imu.w_b, flight.imu.f_b, strict=True)]
    gt = ["#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []"]
    gt += [f"{n},0,0,0," + ",".join(repr(float(v)) for v in q) for n, q in zip(ns, truth.q_nb, strict=True)]
    return {"mav0/imu0/data.csv": ("\n".join(imu) + "\n").encode(),
            "mav0/state_groundtruth_estimate0/data.csv": ("\n".join(gt) + "\n").encode()}


def csv_files(flight: Flight) -> dict[str, bytes]:
    """``flight`` as a generic CSV directory (docs/csv-format.md): IMU in deg/s and g with
    millisecond stamps, magnetometer in uT, GNSS velocity, airspeed with vanes, attitude
    as ENU/FLU quaternions (x, y, z, w)."""
    from windahrs.conventions import DEG, G0
    from windahrs.rotation import quat_ned_frd_to_enu_flu

    imu, mag, gnss, air, truth = flight.imu, flight.mag, flight.gnss, flight.air, flight.truth
    assert mag is not None and gnss is not None and air is not None and truth is not None
    assert air.aoa is not None and air.sideslip is not None
    q = quat_ned_frd_to_enu_flu(truth.q_nb[::10])
    manifest = """\
format = "windahrs.csv"
version = 1
[flight]
meta = { vehicle = "sim" }
[imu]
file = "imu.csv"
time = "t_ms"
time_unit = "ms"
gyro = ["wx", "wy", "wz"]
gyro_unit = "deg/s"
accel = ["ax", "ay", "az"]
accel_unit = "g"
[mag]
file = "mag.csv"
time = "t"
time_unit = "s"
columns = ["mx", "my", "mz"]
unit = "uT"
[gnss]
file = "gnss.csv"
time = "t"
time_unit = "s"
velocity = ["vn", "ve", "vd"]
[air]
file = "air.csv"
time = "t"
time_unit = "s"
tas = "tas"
aoa = "alpha"
sideslip = "beta"
[reference]
file = "att.csv"
time = "t"
time_unit = "s"
frame = "enu_flu"
kind = "truth"
quaternion = ["qx", "qy", "qz", "qw"]
quaternion_order = "xyzw"
"""
    return {
        "windahrs.toml": manifest.encode(),
        "imu.csv": csv_text(["t_ms", "wx", "wy", "wz", "ax", "ay", "az"],
                            [imu.t * 1e3, imu.w_b / DEG, imu.f_b / G0]),
        "mag.csv": csv_text(["t", "mx", "my", "mz"], [mag.t, mag.mag_b * 1e6]),
        "gnss.csv": csv_text(["t", "vn", "ve", "vd"], [gnss.t, gnss.v_n]),
        "air.csv": csv_text(["t", "tas", "alpha", "beta"], [air.t, air.tas, air.aoa, air.sideslip]),
        "att.csv": csv_text(["t", "qx", "qy", "qz", "qw"], [truth.t[::10], q[:, [1, 2, 3, 0]]]),
    }


def broad_bytes(n: int = 600) -> bytes:
    """A small file in the BROAD trial layout (docs of :mod:`windahrs.io.broad`)."""
    import h5py

    rng = np.random.default_rng(1)
    q = np.column_stack([np.ones(n), 0.01 * rng.standard_normal((n, 3))])
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[50:60] = np.nan  # an optical occlusion
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "trial.hdf5"
        with h5py.File(path, "w") as f:
            f.attrs["sampling_rate"] = 285.714
            f["imu_gyr"] = 0.1 * rng.standard_normal((n, 3))
            f["imu_acc"] = np.array([0.0, 0.0, 9.81]) + 0.1 * rng.standard_normal((n, 3))
            f["imu_mag"] = np.array([20.0, 0.0, -40.0]) + rng.standard_normal((n, 3))
            f["opt_quat"] = q
            f["opt_pos"] = rng.standard_normal((n, 3))
            f["movement"] = np.arange(n) > n // 3
        return path.read_bytes()


def flight_h5_bytes(flight: Flight) -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        return save_flight(flight, Path(tmp) / "flight.h5").read_bytes()


def real_files(*parts: str, names: tuple[str, ...] = (), limit: int | None = None) -> dict[str, bytes]:
    """Bytes of a real recording (skips when absent): one file, or ``names`` of a directory."""
    root = data_dir().joinpath(*parts)
    if not root.exists():
        pytest.skip(f"real data not available: {root} (set WINDAHRS_DATA to the shared data folder)")
    if not names:
        return {root.name: root.read_bytes()[:limit]}
    return {n: (root / n).read_bytes()[:limit] for n in names if (root / n).is_file()}


# --- seeds -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sim_flight() -> Flight:
    return simulated_flight()


GENERATED = ("ulog", "dataflash", "windahrs", "csv", "broad", "asl")
REAL = ("px4-real", "broad-real", "alfa-real")


def make_seed(kind: str, request: pytest.FixtureRequest) -> Seed:
    if kind in ("ulog", "px4-real"):
        pytest.importorskip("pyulog")
    if kind == "dataflash":
        pytest.importorskip("pymavlink")
    if kind == "ulog":
        return Seed(kind, {"log.ulg": ulog_bytes()}, "log.ulg")
    if kind == "dataflash":
        return Seed(kind, {"log.bin": dataflash_bytes()}, "log.bin")
    if kind == "windahrs":
        return Seed(kind, {"flight.h5": flight_h5_bytes(request.getfixturevalue("sim_flight"))}, "flight.h5")
    if kind == "csv":
        return Seed(kind, csv_files(request.getfixturevalue("sim_flight")), "")
    if kind == "broad":
        return Seed(kind, {"trial.hdf5": broad_bytes()}, "trial.hdf5")
    if kind == "asl":
        return Seed(kind, asl_files(request.getfixturevalue("sim_flight")), "")
    if kind == "px4-real":  # the first 400 kB: definitions and about 40 % of the data
        return Seed(kind, real_files("px4", "sample_log_small.ulg", limit=400_000), "sample_log_small.ulg")
    if kind == "broad-real":  # the smallest trial, 3.3 MB
        name = "32_disturbed_attached_magnet_1cm.hdf5"
        return Seed(kind, real_files("broad", name), name)
    if kind == "alfa-real":
        return Seed(kind, real_files("alfa", ALFA_SEQ, names=ALFA_FILES), "")
    raise AssertionError(kind)


@pytest.fixture(scope="module", params=GENERATED + REAL)
def seed(request: pytest.FixtureRequest) -> Seed:
    """Each seed, unmutated, must read as a Flight: otherwise the fuzzing tests only the
    first error."""
    s = make_seed(request.param, request)
    with tempfile.TemporaryDirectory() as tmp:
        name = next(iter(s.files))
        flight = read_flight(s.write(Path(tmp), name, s.files[name]))
    assert isinstance(flight, Flight) and len(flight.imu.t) > 10
    return s


# --- mutations ---------------------------------------------------------------------------


#: Mutations, the milder ones more often (an emptied or cut file stops every reader early).
OPS = ("flip", "flip", "flip", "zero", "zero", "insert", "repeat", "delete", "cut", "empty")


class Mutant:
    """File ``name`` of a seed after the mutations ``ops``; ``data`` is the result. Not a
    dataclass: hypothesis would print the bytes of a failing example, not the edits."""

    def __init__(self, name: str, ops: list[tuple[Any, ...]], data: bytes) -> None:
        self.name, self.ops, self.data = name, ops, data

    def __repr__(self) -> str:  # what hypothesis prints: the edits, not the bytes
        return f"Mutant({self.name!r}, ops={self.ops!r}, size={len(self.data)})"


@st.composite
def mutated(draw: st.DrawFn, seed: Seed) -> Mutant:
    """One file of ``seed`` after one to three mutations."""
    name = draw(st.sampled_from(sorted(seed.files)), label="file")
    data = bytearray(seed.files[name])
    ops: list[tuple[Any, ...]] = []

    def pos(end: int) -> int:
        # A quarter of the offsets fall in the first 4 kB: headers, formats, HDF5 superblock.
        head = draw(st.integers(0, 3)) == 0
        return draw(st.integers(0, min(end, 4096) if head else end))

    for _ in range(draw(st.integers(1, 3), label="mutations")):
        op = draw(st.sampled_from(OPS), label="op")
        n = len(data)
        if op == "flip" and n:
            flips = [(pos(n - 1), draw(st.integers(0, 255))) for _ in range(draw(st.integers(1, 16)))]
            for i, b in flips:
                data[i] = b
            ops.append((op, flips))
        elif op == "cut":
            i = pos(n)
            del data[i:]
            ops.append((op, i))
        elif op == "insert":
            i, chunk = pos(n), draw(st.binary(min_size=1, max_size=256))
            data[i:i] = chunk
            ops.append((op, i, chunk))
        elif op == "repeat" and n:  # a chunk of the file itself, written again elsewhere
            i, j, k = pos(n - 1), pos(n), draw(st.integers(1, 4096))
            data[j:j] = data[i:i + k]
            ops.append((op, i, j, k))
        elif op == "delete":
            i, k = pos(n), draw(st.integers(1, 4096))
            del data[i:i + k]
            ops.append((op, i, k))
        elif op == "zero":
            i = pos(n)
            k = min(draw(st.integers(1, 512)), n - i)
            data[i:i + k] = bytes(k)
            ops.append((op, i, k))
        elif op == "empty":
            data = bytearray()
            ops.append((op,))
    return Mutant(name, ops, bytes(data))


class Hang(BaseException):
    """A read exceeded HANG_S. A BaseException, so no reader's ``except Exception`` eats it."""


@contextmanager
def time_limit(seconds: float) -> Iterator[None]:
    """Raise Hang in the main thread after ``seconds`` (Unix; elsewhere no limit, and
    hypothesis' deadline still reports slow reads). A parser looping inside C code is
    interrupted when it returns to Python."""
    if not hasattr(signal, "setitimer") or threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_alarm(signum: int, frame: Any) -> None:
        raise Hang(f"still reading after {seconds} s: a hang")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def read_documented(
    read: Callable[[Path], Flight], path: Path, errors: tuple[type[Exception], ...]
) -> Flight | Exception | Hang | None:
    """``read(path)`` within the time limit: a valid Flight, or one of ``errors`` naming the
    file and what is wrong. Any other exception propagates (a crash the test reports).

    HDF5 files are read in a forked child: libhdf5 can loop forever inside C on some
    damaged object headers (seen on a mutated attribute), where no Python signal reaches it.
    Such a loop is a limitation of libhdf5, not of our readers: it is counted as an event
    ("libhdf5 hang") and returned as a Hang (not raised); every other outcome is checked as in-process."""
    if path.suffix in (".h5", ".hdf5"):
        return _read_in_child(read, path, errors)
    try:
        with time_limit(HANG_S):
            flight = read(path)
    except Hang:
        raise AssertionError(f"{read.__name__}({path.name}) still running after {HANG_S} s: a hang") from None
    except errors as exc:
        _check_message(exc, path)
        return exc
    assert isinstance(flight, Flight) and len(flight.imu.t) >= 1
    return flight


def _check_message(exc: Exception, path: Path) -> None:
    msg = str(exc)
    assert str(path) in msg, f"the error does not name the file {path}: {msg}"
    assert len(msg) > len(str(path)) + 5, f"the error does not say what is wrong: {msg}"


def _child_read(read: Callable[[Path], Flight], path: Path, errors: tuple[type[Exception], ...], conn: Any) -> None:
    try:
        flight = read(path)
        conn.send(("flight", isinstance(flight, Flight) and len(flight.imu.t) >= 1, ""))
    except errors as exc:
        conn.send(("error", type(exc).__name__, str(exc)))
    except BaseException as exc:  # a crash: reported by the parent
        conn.send(("crash", type(exc).__name__, str(exc)))
    conn.close()


def _read_in_child(
    read: Callable[[Path], Flight], path: Path, errors: tuple[type[Exception], ...]
) -> Exception | Hang | None:
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child_read, args=(read, path, errors, child))
    proc.start()
    child.close()
    ready = parent.poll(HDF5_HANG_S)
    if not ready:
        proc.kill()
        proc.join()
        event("libhdf5 hang")
        return Hang(f"{read.__name__}({path.name}) still reading after {HDF5_HANG_S} s in libhdf5")
    kind, what, msg = parent.recv()
    proc.join()
    if kind == "crash":
        raise AssertionError(f"{read.__name__}({path.name}) raised {what}: {msg}")
    if kind == "flight":
        assert what, f"{read.__name__}({path.name}) returned an empty or invalid Flight"
        return None
    assert what in {e.__name__ for e in errors}, f"{read.__name__}({path.name}) raised {what}: {msg}"
    documented = Exception(msg)
    _check_message(documented, path)
    return documented


READ_ERRORS = (LogFormatError, FlightError)
STORE_ERRORS = (StoreError, FlightError)


# --- fuzzing -----------------------------------------------------------------------------


@FUZZ
@given(case=st.data())
def test_fuzzed_file_reads_or_raises_documented_error(seed: Seed, case: st.DataObject) -> None:
    mutant = case.draw(mutated(seed), label="mutant")
    with tempfile.TemporaryDirectory() as tmp:
        path = seed.write(Path(tmp), mutant.name, mutant.data)
        outcome = read_documented(read_flight, path, READ_ERRORS)
        event(f"read_flight: {type(outcome).__name__}")  # shown by --hypothesis-show-statistics
        if path.suffix == ".h5" and not isinstance(outcome, Hang):  # the Flight loader itself too
            read_documented(load_flight, path, STORE_ERRORS)


#: Pieces of CSV syntax and number formats, for the differential test of the CSV parsers.
CSV_TOKENS = (",", "\n", "\r\n", "\n\n", " ", "\t", '"', "nan", "inf", "-", "+", "e", "E", ".", "0", "7",
              "_", "1e308", "9223372036854775808", "0x1f", "#", "\ufeff", "\u00e9")


@settings(FUZZ, max_examples=300)
@given(case=st.data())
def test_csv_fast_parser_matches_row_reader(sim_flight: Flight, case: st.DataObject) -> None:
    """The numpy fast path of the CSV reader returns exactly what the row-by-row reader
    returns, or declines (None) and leaves the file to it: edits of CSV syntax and number
    formats in a 40-row table."""
    from windahrs.io.csv import _read_table_fast, _read_table_rows

    lines = csv_files(sim_flight)["imu.csv"].decode().splitlines(keepends=True)
    text = "".join(lines[:41])
    for _ in range(case.draw(st.integers(1, 4), label="edits")):
        i = case.draw(st.integers(0, len(text)), label="at")
        if case.draw(st.booleans(), label="insert"):
            text = text[:i] + case.draw(st.sampled_from(CSV_TOKENS), label="token") + text[i:]
        else:
            text = text[:i] + text[i + case.draw(st.integers(1, 3), label="delete"):]
    cols = ["wx", "wy", "wz", "ax", "ay", "az"]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "imu.csv"
        path.write_bytes(text.encode())
        fast = _read_table_fast(path, "t_ms", cols)
        event(f"fast path: {'used' if fast is not None else 'declined'}")
        if fast is None:
            return
        slow = _read_table_rows(path, "t_ms", cols)
    assert fast.time.dtype == slow.time.dtype and not slow.dropped_last_row
    np.testing.assert_array_equal(fast.time, slow.time)
    for c in cols:
        np.testing.assert_array_equal(fast.values[c], slow.values[c])


# --- the repair paths ----------------------------------------------------------------------

#: Values a glitch may put in a sample: in range, beyond every sensor's range, non-finite.
GLITCH_VALUES = st.one_of(
    st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False),
    st.sampled_from([np.nan, np.inf, -np.inf, 40.0, -300.0, 1e300]),
)


@st.composite
def glitches(draw: st.DrawFn, n: int) -> list[tuple[str, int, int, int, float]]:
    """1 to 12 edits of an n-row sensor table: (kind, row, other row, column, value), kind
    one of "repeat" (a row written twice), "swap" (two rows exchanged), "spike" (one cell
    set to a value) and "time" (one stamp set to a value)."""
    out = []
    for _ in range(draw(st.integers(1, 12), label="edits")):
        kind = draw(st.sampled_from(["repeat", "swap", "spike", "time"]), label="kind")
        out.append((kind, draw(st.integers(0, n - 1)), draw(st.integers(0, n - 1)), draw(st.integers(0, 5)),
                    draw(GLITCH_VALUES, label="value")))
    return out


def apply_glitches(rows: np.ndarray, edits: list[tuple[str, int, int, int, float]]) -> np.ndarray:
    """``rows`` (N, 1 + k): time then values, with ``edits`` applied (column c of a spike is
    1 + c mod k)."""
    rows = rows.copy()
    for kind, i, j, c, value in edits:
        i, j = min(i, len(rows) - 1), min(j, len(rows) - 1)
        if kind == "repeat":
            rows = np.insert(rows, i, rows[i], axis=0)
        elif kind == "swap":
            rows[[i, j]] = rows[[j, i]]
        elif kind == "spike":
            rows[i, 1 + c % (rows.shape[1] - 1)] = value
        else:
            rows[i, 0] = value
    return rows


def check_repaired(f: Flight, n_in: int) -> None:
    """A Flight from repaired input: sorted unique finite stamps, every row accounted for,
    no finite sample beyond the sensor ranges, every count a known kind."""
    from windahrs.repair import ACCEL_RANGE, GYRO_RANGE, REPAIR_KINDS

    assert np.isfinite(f.imu.t).all() and (np.diff(f.imu.t) > 0).all()
    counts = f.repairs.get("imu", {})
    assert set(counts) <= set(REPAIR_KINDS)
    assert len(f.imu.t) + counts.get("duplicates", 0) + counts.get("unsortable", 0) == n_in
    for a, limit in ((f.imu.w_b, GYRO_RANGE), (f.imu.f_b, ACCEL_RANGE)):
        ok = np.isfinite(a)
        assert (np.abs(a[ok]) <= limit).all()


@settings(FUZZ, max_examples=200)
@given(case=st.data())
def test_fuzzed_arrays_repair_or_raise_documented_error(sim_flight: Flight, case: st.DataObject) -> None:
    """Flight.from_arrays on glitched IMU arrays (repeated rows, swapped rows, spikes of any
    size, NaN and inf in values and stamps; sometimes a unit slip): a repaired Flight whose
    counts add up, or a FlightError naming the argument; with strict=True, an unrepaired
    Flight or a FlightError."""
    imu = sim_flight.imu
    rows = np.column_stack([imu.t, imu.w_b, imu.f_b])
    bad = apply_glitches(rows, case.draw(glitches(len(rows)), label="glitches"))
    # and sometimes a unit slip of the whole gyro column (raw counts given as rad/s)
    t, g, a = bad[:, 0], bad[:, 1:4] * case.draw(st.sampled_from([1.0, 1e4]), label="gyro scale"), bad[:, 4:7]
    try:
        f = Flight.from_arrays(t, g, a)
    except FlightError as exc:
        event(f"from_arrays: FlightError {exc.field}")
        assert exc.field in ("t", "gyro", "accel"), str(exc)
    else:
        event("from_arrays: repaired" if f.repairs else "from_arrays: nothing to repair")
        check_repaired(f, len(t))
    try:
        strict = Flight.from_arrays(t, g, a, strict=True)
    except FlightError as exc:
        assert exc.field in ("t", "gyro", "accel"), str(exc)
    else:
        assert strict.repairs == {}
        np.testing.assert_array_equal(strict.imu.t, t)


@settings(FUZZ, max_examples=100)
@given(case=st.data())
def test_fuzzed_csv_rows_repair_or_raise_documented_error(sim_flight: Flight, case: st.DataObject) -> None:
    """The generic CSV reader on an imu.csv with glitched rows (as above, written as text):
    a repaired Flight whose counts add up, or a documented error naming the file."""
    from windahrs.conventions import DEG, G0

    imu = sim_flight.imu
    rows = np.column_stack([imu.t * 1e3, imu.w_b / DEG, imu.f_b / G0])
    bad = apply_glitches(rows, case.draw(glitches(len(rows)), label="glitches"))
    files = csv_files(sim_flight)
    files["imu.csv"] = csv_text(["t_ms", "wx", "wy", "wz", "ax", "ay", "az"], list(bad.T))
    with tempfile.TemporaryDirectory() as tmp:
        seed = Seed("csv", files, "")
        path = seed.write(Path(tmp), "imu.csv", files["imu.csv"])
        outcome = read_documented(read_flight, path, READ_ERRORS)
        event(f"read_flight: {type(outcome).__name__}")
        if isinstance(outcome, Flight):
            check_repaired(outcome, len(bad))


def test_empty_and_cut_files(seed: Seed, tmp_path: Path) -> None:
    """Every file of every seed, emptied and cut at fixed offsets (the cases hypothesis may
    not draw): a Flight or a documented error naming the file."""
    for i, (name, data) in enumerate(sorted(seed.files.items())):
        for j, cut in enumerate((0, 1, 16, 100, 1000, len(data) // 2, len(data) - 1)):
            root = tmp_path / f"{i}_{j}"
            root.mkdir()
            path = seed.write(root, name, data[:max(cut, 0)])
            read_documented(read_flight, path, READ_ERRORS)


def test_ulog_corrupt_definitions_do_not_hang(tmp_path: Path) -> None:
    """Found by the fuzzing: with its info, parameter and format messages zeroed, pyulog 1.3
    re-read the end of the file forever (it seeks back by the size it asked for, not the
    size it got); the reader now stops it and names the file."""
    pytest.importorskip("pyulog")
    data = bytearray(ulog_bytes())
    data[7] = 0
    data[71:318] = bytes(247)
    path = tmp_path / "zeroed.ulg"
    path.write_bytes(bytes(data))
    with time_limit(HANG_S), pytest.raises(LogFormatError, match=r"zeroed\.ulg: not a readable ULog"):
        read_flight(path)


def test_ulog_field_missing_from_format_names_topic_and_field(tmp_path: Path) -> None:
    """Found by the fuzzing: a damaged format definition left sensor_combined without its
    accelerometer field, and the reader raised a bare KeyError."""
    pytest.importorskip("pyulog")
    data = ulog_bytes().replace(b"float[3] accelerometer_m_s2;", b"float[3] accelerometer_xx_s2;", 1)
    path = tmp_path / "field.ulg"
    path.write_bytes(data)
    with pytest.raises(LogFormatError, match=r"field\.ulg: topic 'sensor_combined' has no field 'accelerometer_m_s2"):
        read_flight(path)


def test_ulog_unreadable_parameter_is_counted(tmp_path: Path) -> None:
    """Found by the fuzzing: a parameter whose type was damaged into a string stopped the
    reader with a ValueError; it is now counted and the log read."""
    pytest.importorskip("pyulog")
    data = ulog_bytes().replace(b"float EKF2_GYR_NOISE", b"char[4] EKF2_GYR_NOI", 1)
    path = tmp_path / "param.ulg"
    path.write_bytes(data)
    f = read_flight(path)
    assert f.meta["ulog.unreadable_parameters"] == 1 and "param.EKF2_GYR_NOI" not in f.meta


def test_dataflash_corrupt_time_stamp_is_dropped_and_counted(tmp_path: Path) -> None:
    """Found by the fuzzing: a TimeUS beyond int64 (a flipped top byte) raised OverflowError."""
    pytest.importorskip("pymavlink")
    data = bytearray(dataflash_bytes())
    i = data.index(b"\xa3\x95" + bytes([65]), 9 * 89)  # the first IMU row, after the 9 FMT messages
    data[i + 3 : i + 11] = struct.pack("<Q", 2**64 - 1)
    path = tmp_path / "stamp.bin"
    path.write_bytes(bytes(data))
    f = read_flight(path)
    assert f.meta["dataflash.dropped_bad_time"] == 1 and len(f.imu.t) == 199


# --- missing parts: one clear error each -------------------------------------------------


def without_messages(data: bytes, kind: str, msg_id: int) -> bytes:
    """ULog ``data`` without the data messages of ``msg_id`` (definitions kept)."""
    out, i = bytearray(data[:16]), 16
    while i < len(data):
        size, typ = struct.unpack_from("<HB", data, i)
        end = i + 3 + size
        if not (typ == ord(kind) and struct.unpack_from("<H", data, i + 3)[0] == msg_id):
            out.extend(data[i:end])
        i = end
    return bytes(out)


def test_ulog_without_imu_names_file_and_topic(tmp_path: Path) -> None:
    pytest.importorskip("pyulog")
    path = tmp_path / "noimu.ulg"
    path.write_bytes(without_messages(ulog_bytes(), "D", 0))
    with pytest.raises(LogFormatError, match=r"noimu\.ulg: no 'sensor_combined' topic"):
        read_flight(path)


def test_dataflash_without_imu_names_file_and_message(tmp_path: Path) -> None:
    pytest.importorskip("pymavlink")
    data = dataflash_bytes()
    imu_id = 65  # the second FMT entry after FMT itself: PARM = 64, IMU = 65
    out, i = bytearray(), 0
    while i < len(data):  # drop the IMU rows (fixed length 3 + 33 bytes)
        j = data.find(b"\xa3\x95", i + 2)
        j = len(data) if j < 0 else j
        if data[i + 2] != imu_id:
            out.extend(data[i:j])
        i = j
    path = tmp_path / "noimu.bin"
    path.write_bytes(bytes(out))
    with pytest.raises(LogFormatError, match=r"noimu\.bin: no 'IMU' messages"):
        read_flight(path)


def test_flight_file_without_imu_names_file_and_group(tmp_path: Path, sim_flight: Flight) -> None:
    import h5py

    path = save_flight(sim_flight, tmp_path / "noimu.h5")
    with h5py.File(path, "a") as f:
        del f["imu"]
    with pytest.raises(StoreError, match=r"noimu\.h5: no 'imu' group"):
        load_flight(path)
    with pytest.raises(LogFormatError, match=r"noimu\.h5: no 'imu' group"):
        read_flight(path)


def test_broad_without_dataset_names_file_and_dataset(tmp_path: Path) -> None:
    import h5py

    path = tmp_path / "trial.hdf5"
    path.write_bytes(broad_bytes())
    with h5py.File(path, "a") as f:
        del f["opt_quat"]
    with pytest.raises(LogFormatError, match=r"trial\.hdf5: not a BROAD trial: missing dataset\(s\) \['opt_quat'\]"):
        read_flight(path, fmt="broad")


@pytest.mark.parametrize(
    ("drop", "pattern"),
    [
        ("imu.csv", r"imu\.csv: no such file"),
        ("manifest:imu", r"windahrs\.toml: manifest key 'imu'"),
        ("column:wz", r"imu\.csv: missing column\(s\) \['wz'\]"),
    ],
)
def test_csv_missing_part_names_file_and_part(
    tmp_path: Path, sim_flight: Flight, drop: str, pattern: str
) -> None:
    files = csv_files(sim_flight)
    if drop == "imu.csv":
        del files["imu.csv"]
    elif drop == "manifest:imu":
        text = files["windahrs.toml"].decode()
        start, end = text.index("[imu]"), text.index("[mag]")
        files["windahrs.toml"] = (text[:start] + text[end:]).encode()
    else:
        files["imu.csv"] = files["imu.csv"].replace(b",wz,", b",w_z,", 1)
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    with pytest.raises(LogFormatError, match=pattern):
        read_flight(tmp_path)


def test_unknown_format_names_file(tmp_path: Path) -> None:
    path = tmp_path / "flight.dat"
    path.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(LogFormatError, match=r"flight\.dat: unknown format"):
        read_flight(path)
