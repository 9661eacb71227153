"""The conventions of windahrs, decided once.

=================  ===========================================================
item               choice
=================  ===========================================================
frames             navigation NED (x north, y east, z down), body FRD
                   (x forward, y right wing, z down). ENU/RFU (the paper) and
                   ENU/FLU (ROS) only at the I/O edge, see :mod:`windahrs.rotation`.
quaternion         Hamilton product, scalar first ``[w, x, y, z]``; ``q_nb``
                   rotates body vectors into nav: ``v_n = q_nb * v_b * q_nb^*``;
                   ``w >= 0`` on output.
error state        body-frame (right) perturbation ``q = q_hat * Exp(dtheta)``.
units              SI inside: rad, rad/s, m/s, m/s^2, tesla, seconds (float).
                   Degrees, g, gauss, microtesla, microseconds only at the edges.
names              ``quantity_frame``: ``w_b``, ``f_b``, ``mag_b``, ``v_n``,
                   ``wind_n``, ``q_nb``, ``C_nb`` (maps b to n).
randomness         every function that draws takes ``rng: numpy.random.Generator``.
=================  ===========================================================

Time stamps of inertial samples: the gyro sample at ``t[k]`` is the mean body rate
over ``(t[k-1], t[k]]`` and the accelerometer sample at ``t[k]`` is the specific force
that, rotated with the attitude at ``t[k]``, holds over that interval. The simulator
generates truth this way and every filter propagates with the same rule, so a
noise-free simulation is reproduced exactly.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "ACCEL_UNITS",
    "DEG",
    "G0",
    "GRAVITY_N",
    "GYRO_UNITS",
    "MAG_DALIAN_N",
    "MAG_NOMINAL_FIELD",
    "MAG_RELATIVE_UNITS",
    "MAG_UNITS",
    "SPEED_UNITS",
    "P_ENU_NED",
    "P_FLU_FRD",
    "UP_N",
]

#: Standard gravity, m/s^2.
G0: float = 9.80665

#: One degree in radians.
DEG: float = float(np.pi / 180.0)

#: Gravity vector in NED, m/s^2 (points down).
GRAVITY_N = np.array([0.0, 0.0, G0])

#: Unit vector "up" in NED: what a level, unaccelerated accelerometer reads, normalised.
UP_N = np.array([0.0, 0.0, -1.0])

#: The fixed matrix converting ENU to NED and RFU to FRD (and back: it is its own
#: inverse). A proper rotation, 180 deg about (1, 1, 0)/sqrt(2). SPEC 1.5.
P_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

#: Body FLU (x forward, y left, z up; ROS REP-103, vqf's examples) to FRD and back: a
#: proper rotation, 180 deg about x.
P_FLU_FRD = np.diag([1.0, -1.0, -1.0])

#: Units the edge converts from, to SI (rad/s, m/s^2, tesla, m/s): factor per unit name.
#: The one table for every reader and :meth:`windahrs.flight.Flight.from_arrays`.
GYRO_UNITS: dict[str, float] = {"rad/s": 1.0, "deg/s": DEG}
ACCEL_UNITS: dict[str, float] = {"m/s^2": 1.0, "g": G0}
MAG_UNITS: dict[str, float] = {
    "T": 1.0, "mT": 1e-3, "uT": 1e-6, "nT": 1e-9, "G": 1e-4, "gauss": 1e-4, "mG": 1e-7,
}
SPEED_UNITS: dict[str, float] = {"m/s": 1.0, "km/h": 1.0 / 3.6, "kn": 1852.0 / 3600.0}

#: Magnetometer "units" for a field whose unit is unknown (a logger's raw counts, an
#: uncalibrated scale): the readings are scaled so that their median norm is
#: :data:`MAG_NOMINAL_FIELD` (:func:`windahrs.flight.mag_to_tesla`). Only the direction of
#: the field is information then; use it for heading.
MAG_RELATIVE_UNITS: tuple[str, ...] = ("normalised", "arbitrary")

#: The placeholder magnitude of a field in :data:`MAG_RELATIVE_UNITS`, tesla: 50 uT, the
#: middle of the Earth's surface field (about 25 to 65 uT, WMM/IGRF), so that noise and
#: bias parameters given in tesla keep about their meaning relative to the field. It is not
#: a measurement.
MAG_NOMINAL_FIELD: float = 50e-6

#: Earth's magnetic field at Dalian (38.9 N, 121.6 E), IGRF-13 for 2018, NED, tesla.
#: |B| = 53.1 uT, declination -8.0 deg, inclination +57.0 deg (SPEC 1.6). The site of
#: the paper, used as the simulator's default.
MAG_DALIAN_N = np.array([28632e-9, -4032e-9, 44583e-9])
