"""Memory reused for the large outputs of compiled runs (the recorded states and covariances,
the innovation logs).

Each run records into fresh arrays that its Estimate then owns. When a program drops one
Estimate and runs again (a sweep that keeps a metric, a benchmark), glibc has handed the
freed megabytes back to the kernel, and the next run takes a page fault on the first touch
of every 4 kB page: 1175 per 60 s run of [mekf], about 0.2 us per IMU sample on this VM,
a fifth of the whole run (docs/core.md, "No reference counting in the per-sample core").
:func:`empty` hands out an array whose memory is a block of its own, owned by a small
object (:class:`_Block`); when the last view of it is gone, the block goes to a free list
instead of back to glibc, and the next request of the same size takes it, its pages
already mapped. Nothing else changes: the arrays are uninitialised as ``np.empty``'s,
each has its own block (keeping one array keeps no other alive), and a block is reused only
once nothing refers to it. The free list keeps at most :data:`POOL_BYTES`; lists and dicts
are changed by single operations (atomic under the GIL), so any thread may free a block.

Also here: :func:`stream_store3` and :func:`stream_fence`, with which the kernel records the
covariance around the caches (non-temporal stores; plain Python forms for
``NUMBA_DISABLE_JIT``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.core.extending import intrinsic, overload
from numpy.typing import NDArray

#: Free memory kept for reuse at most, bytes (256 MiB: the outputs of a few long runs).
POOL_BYTES = 1 << 28
#: Smaller arrays come from numpy as usual (glibc reuses small blocks itself).
MIN_BYTES = 1 << 18

_free: dict[int, list[NDArray[np.uint8]]] = {}
#: The bytes on the free list, kept as blocks come and go (summing the list at every release
#: took a few microseconds per block once it held a few hundred). A list of one, changed by
#: single operations; under threads it may drift by a block from the true sum, which only
#: moves the cap by as much.
_held = [0]


class _Block:
    """The owner of a block of memory that numpy views (its ``__array_interface__``); back to
    the free list when the last view is gone."""

    def __init__(self, mem: NDArray[np.uint8]) -> None:
        self.mem = mem
        self.__array_interface__ = mem.__array_interface__

    def __del__(self) -> None:
        free, held = _free, _held  # (None once the interpreter is tearing the module down)
        if free is None or held is None:
            return
        n = self.mem.nbytes
        if held[0] + n <= POOL_BYTES:
            free.setdefault(n, []).append(self.mem)
            held[0] += n


def clear() -> None:
    """Empty the free list (its blocks go back to glibc once unreferenced): for a caller that
    needs room for the blocks it is about to free (the tests)."""
    _free.clear()
    _held[0] = 0


def empty(shape: tuple[int, ...], dtype: type[np.float64] | type[np.int64] = np.float64) -> NDArray[Any]:
    """``np.empty(shape, dtype)`` (float64 or int64), its memory reused from a freed array
    of the same size when there is one (see the module)."""
    n = math.prod(shape) * 8
    if n < MIN_BYTES:
        return np.empty(shape, dtype)
    try:
        mem = _free.get(n, []).pop()
        _held[0] -= n
    except IndexError:
        mem = np.empty(n, np.uint8)
    return np.asarray(_Block(mem)).view(dtype).reshape(shape)


def stream_store3(arr: NDArray[np.float64], i: int, j: int, k: int, val: float) -> None:
    """``arr[i, j, k] = val``; compiled, a non-temporal store (LLVM's ``!nontemporal``,
    :func:`_store_nt3`): written around the caches, for the covariance the kernel records at
    every sample and never reads back (an [ins-wind] sample's 1.8 kB evicted the filter's own
    working set; docs/core.md). This plain form runs with ``NUMBA_DISABLE_JIT=1``."""
    arr[i, j, k] = val


def stream_fence() -> None:
    """A full memory fence once compiled (``mfence`` on x86, :func:`_fence`): the
    non-temporal stores before it are visible to every thread after it (e.g. the one that
    reads a batch's outputs once its parallel loop has joined); nothing in plain Python."""


@intrinsic
def _store_nt3(typingctx, arr, i, j, k, val):
    """:func:`stream_store3` compiled: the store, marked non-temporal, no bounds check (as
    numba's indexing by default)."""
    sig = types.void(arr, i, j, k, val)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, list(args[1:4]), wraparound=False)
        store = builder.store(args[4], ptr)
        store.set_metadata("nontemporal", builder.module.add_metadata([ir.IntType(32)(1)]))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _fence(typingctx):
    """:func:`stream_fence` compiled."""
    sig = types.void()

    def codegen(context, builder, signature, args):
        builder.fence("seq_cst")
        return context.get_dummy_value()

    return sig, codegen


@overload(stream_store3, inline="always")
def _stream_store3_compiled(arr, i, j, k, val):
    return lambda arr, i, j, k, val: _store_nt3(arr, i, j, k, val)  # type: ignore[call-arg]


@overload(stream_fence, inline="always")
def _stream_fence_compiled():
    return lambda: _fence()  # type: ignore[call-arg]
