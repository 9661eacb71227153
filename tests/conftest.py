"""Shared fixtures: real-data location and small simulated flights."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def data_dir() -> Path:
    """Where the real recordings live: $WINDAHRS_DATA or ../shared/data beside the repo."""
    return Path(os.environ.get("WINDAHRS_DATA", REPO.parent / "shared" / "data"))


def require_data(*parts: str) -> Path:
    """Path of a real recording, or skip the test saying what is missing."""
    p = data_dir().joinpath(*parts)
    if not p.exists():
        pytest.skip(f"real data not available: {p} (set WINDAHRS_DATA to the shared data folder)")
    return p


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
