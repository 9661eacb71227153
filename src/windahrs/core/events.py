"""Events: the merged, time-ordered sensor samples a compiled filter's loop is fed
(:func:`windahrs.filters.base.merge_events` builds them; EVENT_* are their kinds)."""

from __future__ import annotations

import math

from numba import njit

from windahrs.core.layout import _JIT_CORE
from windahrs.filters.base import EVENT_AIR, EVENT_IMU

__all__ = ["sample_ok"]


@njit(inline="always", **_JIT_CORE)
def sample_ok(kind, row):
    """Whether an event's sample can be used: an IMU sample with 6 finite values, a
    magnetometer or GNSS sample with 3, an air sample with a finite airspeed (NaN vanes
    mean no vanes). The event loops skip the others and count them per stream (K_SKIP +
    kind: the EVENT_* codes are the skip counters' order)."""
    if kind == EVENT_IMU:
        for a in range(6):
            if not math.isfinite(row[a]):
                return False
        return True
    if kind == EVENT_AIR:
        return math.isfinite(row[0])
    return math.isfinite(row[0]) and math.isfinite(row[1]) and math.isfinite(row[2])
