"""Where the distributed work runs: a Dask ``Client`` on a local cluster or on an existing
scheduler, and the one-function interface (``submit``) the experiments are written against
so that the serial path is the same code.

Dask distributed is an optional dependency (the ``dask`` extra); it is imported only when a
client is opened.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Protocol

from windahrs.filters.base import Estimator, loop_family

__all__ = ["Submit", "default_workers", "open_client", "serial_submit", "warm_families"]


class Submit(Protocol):
    """``submit(fn, *args)``: a handle whose ``result()`` is ``fn(*args)``. Arguments may be
    handles returned by the same ``submit`` (or lists of them): they are resolved first."""

    def __call__(self, fn: Callable[..., Any], *args: Any) -> Any: ...


class _Later:
    """A call made on the first ``result()`` (the serial ``submit``): in this process, in
    the order the results are asked for, and only once."""

    __slots__ = ("args", "fn", "value")

    def __init__(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        self.fn: Callable[..., Any] | None = fn
        self.args = args
        self.value: Any = None

    def result(self) -> Any:
        if self.fn is not None:
            self.value = self.fn(*(_resolve(a) for a in self.args))
            self.fn, self.args = None, ()
        return self.value


def _resolve(arg: Any) -> Any:
    if isinstance(arg, _Later):
        return arg.result()
    if isinstance(arg, list):
        return [_resolve(a) for a in arg]
    return arg


def serial_submit(fn: Callable[..., Any], *args: Any) -> _Later:
    """``fn(*args)`` in this process, when its result is first asked for (handles in ``args``
    resolved then)."""
    return _Later(fn, args)


def warm_families(submit: Submit, items: Sequence[tuple[Estimator, Callable[..., Any], tuple[Any, ...]]]) -> None:
    """Before a cluster's work: for the first item of each compiled family
    (:func:`windahrs.filters.base.loop_family` of its estimator), ``submit(fn, *args)`` (a
    short flight through that estimator), and wait for them all. Each family's compiled
    loop is then in numba's cache, written by one worker while another compiles the next,
    and the workers on the machine load it from there; without this every worker compiles
    every filter on its first flight (on 2 cores, a cold ``reproduce --quick`` spent 218 s,
    two thirds of it compiling the same code twice). On a warm cache each task takes well
    under a second."""
    first: dict[type, tuple[Callable[..., Any], tuple[Any, ...]]] = {}
    for est, fn, args in items:
        first.setdefault(loop_family(est), (fn, args))
    handles = [submit(fn, *args) for fn, args in first.values()]
    for h in handles:
        h.result()


def default_workers() -> int:
    """Worker processes of a local cluster: one per core this process may use."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # pragma: no cover (macOS, Windows)
        return max(os.cpu_count() or 1, 1)


@contextlib.contextmanager
def open_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """A ``dask.distributed.Client``: connected to ``scheduler`` (``tcp://HOST:PORT``) when
    given, else to a new ``LocalCluster`` of ``workers`` processes (default
    :func:`default_workers`) with one thread each (the estimators are compiled, GIL-bound
    Python around them: processes, not threads, scale). Closed on exit.

    Raises ValueError for ``workers < 1`` or both arguments given; ImportError (with the
    extra to install) when dask distributed is missing.
    """
    if scheduler is not None and workers is not None:
        raise ValueError(f"workers: a local cluster's size, not used with scheduler {scheduler!r}; give one of them")
    if workers is not None and workers < 1:
        raise ValueError(f"workers: expected an integer >= 1, found {workers}")
    try:
        import logging

        from distributed import Client, LocalCluster
    except ImportError as exc:  # pragma: no cover (the dask extra is part of the test install)
        raise ImportError("dask distributed is not installed: pip install 'windahrs[dask]'") from exc
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")
        except OSError as exc:
            raise ValueError(f"scheduler: cannot connect to {scheduler!r} ({exc})") from None
        try:
            yield client
        finally:
            client.close()
        return
    cluster = LocalCluster(
        n_workers=workers or default_workers(), threads_per_worker=1, processes=True,
        dashboard_address=None, silence_logs=logging.ERROR,
    )
    try:
        client = Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()
