"""The error-state layout of the MEKF, the air-data MEKF and the INS (SPEC 2.4, 2.5), and
a nominal state to go with it.

Nominal state: attitude ``q_nb``, gyro bias ``bg``, and optionally velocity ``v_n`` (INS),
wind ``wind_n``, accelerometer bias ``ba`` and magnetometer bias ``bm`` (hard iron, tesla).
Error state: body-frame attitude error ``dtheta`` (``q = q_hat * Exp(dtheta)``) and additive
errors of the rest, ordered by a :class:`Layout`. The models themselves are the compiled
core's (:mod:`windahrs.core.predict`, the aid sources of :mod:`windahrs.aid`), linearised at
a state of any layout by :mod:`windahrs.core.linearize`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from windahrs.rotation import quat_exp, quat_mul, quat_normalize

__all__ = ["BLOCK_SIZES", "Layout", "NominalState"]

F64 = NDArray[np.float64]

BLOCK_SIZES = {"att": 3, "v": 3, "bg": 3, "wind": 3, "ba": 3, "bm": 3}


@dataclass(frozen=True)
class Layout:
    """Which error-state blocks exist, in order: attitude first, gyro bias always present."""

    blocks: tuple[str, ...]

    def __post_init__(self) -> None:
        unique = len(set(self.blocks)) == len(self.blocks)
        if self.blocks[:1] != ("att",) or "bg" not in self.blocks or not unique:
            raise ValueError(f"Layout.blocks: expected 'att' first, 'bg', no repeat; found {self.blocks}")
        for b in self.blocks:
            if b not in BLOCK_SIZES:
                raise ValueError(f"Layout.blocks: expected names from {tuple(BLOCK_SIZES)}, found {b!r}")

    @property
    def dim(self) -> int:
        return sum(BLOCK_SIZES[b] for b in self.blocks)

    def sl(self, block: str) -> slice:
        """Slice of ``block`` in the error vector (KeyError when absent)."""
        start = 0
        for b in self.blocks:
            if b == block:
                return slice(start, start + BLOCK_SIZES[b])
            start += BLOCK_SIZES[b]
        raise KeyError(block)

    def has(self, block: str) -> bool:
        return block in self.blocks

    def labels(self) -> tuple[str, ...]:
        names = {
            "att": ("att_x", "att_y", "att_z"),
            "bg": ("bg_x", "bg_y", "bg_z"),
            "v": ("v_n", "v_e", "v_d"),
            "wind": ("wind_n", "wind_e", "wind_d"),
            "ba": ("ba_x", "ba_y", "ba_z"),
            "bm": ("bm_x", "bm_y", "bm_z"),
        }
        return tuple(lab for b in self.blocks for lab in names[b])


@dataclass(frozen=True)
class NominalState:
    """q_nb (4,), bg (3,) rad/s, and when in the layout: v_n, wind_n (3,) m/s, ba (3,) m/s^2,
    bm (3,) tesla."""

    q_nb: F64
    bg: F64
    v_n: F64 | None = None
    wind_n: F64 | None = None
    ba: F64 | None = None
    bm: F64 | None = None

    def inject(self, layout: Layout, dx: F64) -> NominalState:
        """Apply an error-state correction: ``q * Exp(dtheta)``, additive elsewhere."""
        q = quat_normalize(quat_mul(self.q_nb, quat_exp(dx[layout.sl("att")])))

        def add(name: str, value: F64 | None) -> F64 | None:
            return value + dx[layout.sl(name)] if layout.has(name) and value is not None else value

        return NominalState(
            q_nb=q,
            bg=self.bg + dx[layout.sl("bg")],
            v_n=add("v", self.v_n),
            wind_n=add("wind", self.wind_n),
            ba=add("ba", self.ba),
            bm=add("bm", self.bm),
        )
