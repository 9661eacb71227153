"""Adapters around the attitude estimators users already know, so that ours can be
compared with them on the same Flight: ``ahrs`` (EKF, Madgwick, Mahony), ``vqf``
(VQF and the non-causal offline VQF) and ``imufusion`` (x-io Fusion).

Each adapter is an :class:`~windahrs.filters.base.Estimator`: it converts frames and
units at the edge (NED nav, FRD body, SI in; ``q_nb`` with heading from true north out),
holds the latest magnetometer sample between magnetometer samples, and streams sample by
sample. The libraries are optional dependencies (``pip install 'windahrs[baselines]'``),
imported when an adapter first runs. See docs/baselines.md.
"""

from windahrs.baselines.ahrs_lib import (
    AhrsEkf,
    AhrsEkfParams,
    Madgwick,
    MadgwickParams,
    Mahony,
    MahonyParams,
)
from windahrs.baselines.imufusion_lib import ImuFusion, ImuFusionParams
from windahrs.baselines.vqf_lib import Vqf, VqfOffline, VqfParams

__all__ = [
    "AhrsEkf",
    "AhrsEkfParams",
    "ImuFusion",
    "ImuFusionParams",
    "Madgwick",
    "MadgwickParams",
    "Mahony",
    "MahonyParams",
    "Vqf",
    "VqfOffline",
    "VqfParams",
]
