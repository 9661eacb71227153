"""Batched runs: several flights through one compiled estimator in one compiled call, the
runs advancing in parallel on numba's threads (a ``prange`` over the runs around the one
event loop, :func:`windahrs.core.kernel.run_events`). There is no second copy of any filter
maths: each run is the single-flight loop on its own state, so a batched run gives the
Estimate that :meth:`~windahrs.core.kernel.CompiledEstimator.run` gives, bit for bit
(tests/test_batch.py).

Flights of different lengths are packed end to end, not padded: the events, the outputs,
the covariances, the innovation logs and the scratch space of all runs sit in one buffer
each, and run ``r`` works on its own slice, ``[off[r], off[r + 1])``. Each Estimate's
arrays are views of these buffers: all the Estimates together take the memory of the runs
done one by one, but one Estimate kept alone keeps its chunk's buffers alive (copy what
you keep, or keep the results together). The flights go in chunks of about a quarter
(:func:`chunk_size`): while one chunk's filters run, the Python work of the others (events
merged and states encoded before, Estimates built and checked after) overlaps them, and
each run's Estimate is built as soon as that run has ended (a flag the parallel loop sets
per run), not once its whole chunk has, so that only the last run's is left after the
threads are done. The runs go longest first and are handed to the threads one at a time,
so a long flight does not leave a thread idle at the end of a chunk.

Threads: ``threads`` runs at once (default: numba's current thread count, which is
``NUMBA_NUM_THREADS``, by default the number of cores, unless ``numba.set_num_threads``
changed it); the count is restored after the call. The function releases the GIL. The
runs share no mutable data (each has its own state, scratch and output slices; the
events are read only), so the parallel loop is safe. numba's OpenMP and TBB threading
layers accept calls from several Python threads at once (e.g. a Dask worker with several
threads); its fallback layer, workqueue, does not (numba aborts the process), so there the
calls take a lock and run one at a time (as does the first call, which chooses the layer).
GNU OpenMP is not fork-safe: start worker processes with ``spawn`` (Dask's default) once a
batch has run in the parent.

The compiled loop is cached beside the sources like the rest of the core (``cache=True``;
numba caches parallel functions too).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

from windahrs.core import pool
from windahrs.core.kernel import CompiledEstimator, PreparedRun, run_events
from windahrs.core.layout import _JIT, I64, L_CNT, N_SENSORS, KernelState
from windahrs.core.smooth import no_smoothing
from windahrs.estimate import Estimate
from windahrs.filters.base import COV_RECORDS, CovRecord, InitialState, initial_per_flight
from windahrs.flight import Flight

__all__ = ["chunk_size", "run_batch"]


@njit(parallel=True, nogil=True, **_JIT)
def _run_packed(
    cfg, prm, x, flags, sup, screen, rest, asc,
    P, p_off, p_n, work, w_off, w_cols, inn, acc, l_off,
    t_ev, kinds, vals, e_off,
    q, bg, v, w, n_off, cov, c_off, c_rows, dims,
    order, done, rec, sm,
):  # fmt: skip
    """Run ``order``'s runs in parallel, each through :func:`run_events` with recording.
    cfg, prm, x, flags (R, ...), sup (R, 2, NMAX) and the aid sources' records screen, rest, asc (R, 1):
    the runs' fixed-size state records;
    P, work (flat): run r's covariance (p_n[r], p_n[r]) at p_off[r], its scratch (rows,
    w_cols[r]) at w_off[r]; inn (L, 5), acc (L,): its logs in rows l_off[r]:l_off[r + 1];
    t_ev, kinds, vals: its events in e_off[r]:e_off[r + 1]; q, bg, v, w: its outputs in
    rows n_off[r]:n_off[r + 1] (v, w: (0, 3) when not in the layout); cov (flat): its
    (c_rows[r], dims[r], dims[r]) covariances at c_off[r]. done (R,): set to 1 when run r
    has ended (after run_events' memory fence: its outputs are visible to every thread
    then), so that its Estimate can be built while the others run. rec: True, given at run
    time: a literal True here would be typed Literal[bool] and make numba compile a second
    run_events (30-50 s cold) instead of reusing the streamer's and the single run's. sm: the
    empty smoothing record (:func:`windahrs.core.smooth.no_smoothing`), for the same reason."""
    for i in prange(order.shape[0]):
        r = order[i]
        n0, n1, e0, e1 = n_off[r], n_off[r + 1], e_off[r], e_off[r + 1]
        m, d = p_n[r], dims[r]
        rows = (w_off[r + 1] - w_off[r]) // w_cols[r]
        st = KernelState(
            cfg[r],
            prm[r],
            x[r],
            flags[r],
            P[p_off[r] : p_off[r] + m * m].reshape((m, m)),
            work[w_off[r] : w_off[r + 1]].reshape((rows, w_cols[r])),
            sup[r],
            inn[l_off[r] : l_off[r + 1]],
            acc[l_off[r] : l_off[r + 1]],
            screen[r],
            rest[r],
            asc[r],
        )
        out_cov = cov[c_off[r] : c_off[r + 1]].reshape((c_rows[r], d, d))
        run_events(
            st, t_ev[e0:e1], kinds[e0:e1], vals[e0:e1],
            q[n0:n1], bg[n0:n1], v[n0:n1], w[n0:n1], out_cov, rec, sm,
        )  # fmt: skip
        done[r] = 1


def _offsets(sizes: Sequence[int]) -> I64:
    return np.concatenate([[0], np.cumsum(np.asarray(sizes, dtype=np.int64))]).astype(np.int64)


def _threads(threads: int | None) -> int:
    top = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
    if threads is None:
        return int(numba.get_num_threads())
    if isinstance(threads, bool) or not isinstance(threads, int | np.integer) or not 1 <= threads <= top:
        raise ValueError(f"threads: expected an integer from 1 to {top} (NUMBA_NUM_THREADS), found {threads!r}")
    return int(threads)


def _pack(runs: list[PreparedRun]) -> tuple[tuple[object, ...], list[PreparedRun]]:
    """The runs' arrays packed end to end (the arguments of :func:`_run_packed`, without
    ``order``), and the runs with their states and outputs replaced by views of them."""
    sts = [r.st for r in runs]
    cfg, prm, x, flags, sup, screen, rest, asc = (
        np.stack([getattr(s, f) for s in sts]) for f in ("cfg", "prm", "x", "flags", "sup", "screen", "rest", "asc")
    )
    p_n = np.array([s.P.shape[0] for s in sts], dtype=np.int64)
    p_off = _offsets([s.P.size for s in sts])
    P = np.concatenate([s.P.ravel() for s in sts])
    w_cols = np.array([s.work.shape[1] for s in sts], dtype=np.int64)
    w_off = _offsets([s.work.size for s in sts])
    work = np.concatenate([s.work.ravel() for s in sts])
    l_off = _offsets([len(s.inn) for s in sts])
    # the logs: the rows logged so far (none in a fresh state) copied, the rest left
    # unwritten (kalman._log writes a row before anything reads it): a log has room for
    # every sample of its stream, megabytes per flight that a copy would touch for nothing
    inn = pool.empty((int(l_off[-1]), 5))
    acc = np.zeros(int(l_off[-1]), dtype=np.bool_)
    for i, s in enumerate(sts):
        for k in range(N_SENSORS):
            o, c = int(s.cfg["log_off"][k]), int(s.flags[L_CNT + k])
            inn[l_off[i] + o : l_off[i] + o + c] = s.inn[o : o + c]
            acc[l_off[i] + o : l_off[i] + o + c] = s.acc[o : o + c]
    e_off = _offsets([len(r.t_ev) for r in runs])
    E = int(e_off[-1])
    t_ev, kinds, vals = pool.empty((E,)), pool.empty((E,), np.int64), pool.empty((E, 6))
    np.concatenate([r.t_ev for r in runs], out=t_ev)
    np.concatenate([r.kinds for r in runs], out=kinds)
    np.concatenate([r.vals for r in runs], out=vals)
    n_off = _offsets([len(r.q) for r in runs])
    N = int(n_off[-1])
    q, bg = pool.empty((N, 4)), pool.empty((N, 3))
    v = pool.empty((N if len(runs[0].v) else 0, 3))
    w = pool.empty((N if len(runs[0].w) else 0, 3))
    dims = np.array([r.cov.shape[1] for r in runs], dtype=np.int64)
    c_rows = np.array([r.cov.shape[0] for r in runs], dtype=np.int64)
    c_off = _offsets([r.cov.size for r in runs])
    cov = pool.empty((int(c_off[-1]),))
    views = []
    for i, r in enumerate(runs):
        n0, n1 = int(n_off[i]), int(n_off[i + 1])
        l0, l1 = int(l_off[i]), int(l_off[i + 1])
        st = KernelState(
            cfg=cfg[i],
            prm=prm[i],
            x=x[i],
            flags=flags[i],
            P=P[p_off[i] : p_off[i + 1]].reshape(r.st.P.shape),
            work=work[w_off[i] : w_off[i + 1]].reshape(r.st.work.shape),
            sup=sup[i],
            inn=inn[l0:l1],
            acc=acc[l0:l1],
            screen=screen[i],
            rest=rest[i],
            asc=asc[i],
        )
        views.append(r._replace(
            st=st,
            q=q[n0:n1],
            bg=bg[n0:n1],
            v=v[n0:n1],
            w=w[n0:n1],
            cov=cov[c_off[i] : c_off[i + 1]].reshape(r.cov.shape),
        ))  # fmt: skip
    args = (cfg, prm, x, flags, sup, screen, rest, asc, P, p_off, p_n, work, w_off, w_cols, inn, acc, l_off,
            t_ev, kinds, vals, e_off, q, bg, v, w, n_off, cov, c_off, c_rows, dims)  # fmt: skip
    return args, views


def run_batch(
    est: CompiledEstimator,
    flights: Sequence[Flight],
    *,
    initial: Sequence[InitialState | None] | None = None,
    threads: int | None = None,
    cov: CovRecord = "full",
    cov_every: int | str | None = None,
) -> list[Estimate]:
    """The Estimates of ``est`` on ``flights`` (in their order), the runs advancing together
    in one compiled call on ``threads`` threads: the same Estimates as ``[est.run(f,
    initial=i, cov_every=cov_every) for f, i in zip(flights, initial)]``. Flights may
    differ in length and in sensors. initial: one InitialState or None per flight (default: None for all);
    threads: runs at once, 1 to NUMBA_NUM_THREADS (default: numba's current count); cov:
    the covariance recorded, "full" (as ``run``), "attitude" (the 3 x 3 attitude block, with
    its labels) or "none" (:data:`~windahrs.filters.base.CovRecord`), at every cov_every-th
    IMU sample (default: as ``run``, at :data:`~windahrs.core.layout.COV_RECORD_HZ` within
    :data:`~windahrs.core.layout.COV_BUDGET` per flight).

    The preparation (merging each flight's events, encoding its state) and the Estimates'
    checks (:func:`~windahrs.filters.checks.checked`) run in Python, one flight after the
    other; they overlap the filters: the flights go in chunks (:func:`chunk_size`), and
    while one chunk's filters run, the next chunk is prepared and each Estimate is built
    as soon as its run has ended. Every flight is checked for its sensors before any
    runs."""
    flights = list(flights)
    inits = initial_per_flight(initial, len(flights))
    n_threads = _threads(threads)
    if cov not in COV_RECORDS:
        raise ValueError(f"cov: expected one of {', '.join(map(repr, COV_RECORDS))}, found {cov!r}")
    for f in flights:
        est.check(f)
    # longest first (by IMU samples), so that the last runs of a chunk are short
    by_length = sorted(range(len(flights)), key=lambda i: -len(flights[i].imu.t))
    size = chunk_size(len(flights), n_threads)
    out: list[Estimate | None] = [None] * len(flights)
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="windahrs-batch") as helper:
        pending: _Chunk | None = None
        for c0 in range(0, len(flights), size):
            chunk = by_length[c0 : c0 + size]
            args, runs = _pack([est.prepare(flights[i], inits[i], cov, cov_every, reuse=False) for i in chunk])
            done, started = np.zeros(len(chunk), dtype=np.int64), threading.Event()
            running = helper.submit(_launch, args, done, n_threads, started)  # after the previous chunk
            if pending is None:  # the first: the helper thread takes the GIL to start it, now
                started.wait()
            else:
                _collect(est, pending, out)
            pending = _Chunk(running, runs, chunk, done)
        if pending is not None:
            _collect(est, pending, out)
    return [e for e in out if e is not None]


def chunk_size(n_runs: int, threads: int) -> int:
    """How many runs go to the threads at once: about a quarter of the runs (so that the
    Python work of the others overlaps them), at least two per thread (so that the
    threads stay busy to the end of a chunk)."""
    return max(2 * threads, -(-n_runs // 4), 1)


def _launch(args: tuple[object, ...], done: I64, threads: int, started: threading.Event) -> None:
    """The packed runs (:func:`_pack`) through :func:`_run_packed` on ``threads`` threads,
    in the order given, each setting its flag in ``done`` when it ends; ``started`` set as
    the call begins (or fails) (numba's thread count and chunk size are per Python thread:
    set here, in the thread that makes the call)."""
    order = np.arange(len(args[0]), dtype=np.int64)  # type: ignore[arg-type]
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(threads)
        with numba.parallel_chunksize(1), _guard():
            started.set()
            _run_packed(*args, order, done, True, no_smoothing())
    finally:
        started.set()
        numba.set_num_threads(before)


class _Chunk(NamedTuple):
    """A chunk of runs handed to the helper thread: its call (:func:`_launch`), the runs
    (views of its packed buffers), their flights' places, their flags (set as each ends)."""

    running: Future[None]
    runs: list[PreparedRun]
    places: list[int]
    done: I64


#: How often the Python thread looks for ended runs while none has, s (a 60 s flight of
#: [mekf] takes about 10 ms on one thread).
POLL_S = 1e-3


def _collect(est: CompiledEstimator, chunk: _Chunk, out: list[Estimate | None]) -> None:
    """Put a chunk's Estimates at their flights' places, each built as soon as its run has
    ended (while the chunk's other runs go on), and raise the compiled loop's error if it
    had one."""
    left = list(range(len(chunk.runs)))
    while left:
        ended = [j for j in left if chunk.done[j]]
        if not ended and chunk.running.done():
            chunk.running.result()  # (an error of the loop: raised here)
            ended = list(left)  # (else every run has ended)
        if not ended:
            time.sleep(POLL_S)  # (a sleep costs a third of the CPU time of a wait on the Future)
            continue
        for j in ended:
            out[chunk.places[j]] = est.finish(chunk.runs[j])
            left.remove(j)
    chunk.running.result()


#: Serialises the parallel calls where numba's threading layer cannot take concurrent ones.
_LAYER_LOCK = threading.Lock()


def _guard() -> contextlib.AbstractContextManager[object]:
    """A lock around the parallel call when numba's threading layer is workqueue (not
    thread-safe: numba aborts the process on concurrent calls) or not chosen yet (the first
    call chooses it); nothing for OpenMP and TBB."""
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel call yet
        layer = None
    return _LAYER_LOCK if layer in (None, "workqueue") else contextlib.nullcontext()
