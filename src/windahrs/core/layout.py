"""The compiled filter's state records: what a running error-state or additive EKF carries
between events, and the sensor registry (:data:`SENSORS`) the innovation logs are laid out
from. The parameters and the configuration are named records (:data:`PRM`, :data:`CFG`:
numpy structured scalars read as ``prm["name"]`` in compiled code and in Python alike); the
state, the flags and the scratch space are still flat arrays named by the index constants
below, except the private state of the aid sources that moved to records of their own
(:class:`KernelState`; the move of the state to a record: docs/records.md).

:class:`KernelState` holds nine core fields: the configuration and parameters (two records)
encoded once from the estimator's parameters, the nominal state with the samples it
remembers, flags and counters, the covariance (zero-padded to whole SIMD lanes: the
additive filters' loops and the error-state prediction's rows of Phi P of more than
TRIANGLE_N states run over whole padded rows, the error-state update over the n states),
scratch space and the innovation logs; then the private state of aid sources as records of
their own, declared next to them (``st[:9]`` are the core fields). Helpers take the arrays
they need, not the KernelState: numba reference-counts every array taken out of a tuple.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

_JIT: dict[str, Any] = {"cache": True, "error_model": "numpy"}
#: The per-sample core (the event loop, the update, the predictions, the IMU screen, the
#: resets and the aid sources) is compiled without numba's reference counting of arrays
#: (numba's ``_nrt`` option): it allocates nothing, every array it touches is its caller's
#: and alive for the whole call, and counting the references of every array argument of a
#: call and of every view (two atomic operations each) took a quarter of a filter step
#: (perf: NRT_incref and NRT_decref 24 % of [mekf]'s loop). Code that allocates (the
#: smoother's backward pass, [usque], the batch's parallel loop) keeps ``_JIT``; either may
#: call the other.
_JIT_CORE: dict[str, Any] = {**_JIT, "_nrt": False}
#: The predictions may fuse multiply-adds (FMA: different rounding, no other effect; they
#: symmetrise P explicitly). The updates do not: their exact symmetry relies on plain
#: products and sums.
_JIT_FMA: dict[str, Any] = {**_JIT_CORE, "fastmath": {"contract"}}

#: The rate a run records the covariance at by default, Hz: every k-th IMU sample's, k the
#: IMU's rate over this (:func:`cov_stride`). The covariance changes on the time scale of the
#: aiding (0.1 to 1 s: a GNSS receiver's 5-10 Hz velocity, the attitude's convergence), not
#: the IMU's, and 20 Hz samples the fastest of it twice (PX4's logger keeps EKF2's
#: ``estimator_status``, with the covariance's diagonal, at 5 Hz). Writing the whole record
#: is memory-bound: [ins-wind]'s 18 x 18 at every 200 Hz sample is 31 MB a minute, which
#: took 0.08-0.33 us a sample (the same code on two days of this shared machine; the filter
#: itself about 0.55), and at 20 Hz a tenth of it. ``run(flight, cov_every=1)`` keeps every
#: sample's.
COV_RECORD_HZ = 20.0

#: The covariances a run records at most, in floats (128 MiB): a longer record keeps every
#: k-th IMU sample's (:func:`cov_stride`): at 20 Hz, 18 states for 5 hours.
COV_BUDGET = 1 << 24

#: Width of the scratch rows: the largest covariance (ins-wind with accelerometer and
#: magnetometer bias: 18; ekf10: 10) plus one.
NMAX = 19

#: Covariances up to this size are updated on one triangle, mirrored (scalar code, half the
#: entries: [mekf]'s 6 states; core.kalman._fuse); larger ones on whole rows, which the
#: compiler vectorises ([ins-wind]'s 15: the triangle's rows of varying length were 20 %
#: slower there), and the prediction's rows of Phi P run over the padded width
#: (core.predict._predict_es).
TRIANGLE_N = 8

KIND_MEKF, KIND_MEKF_AIR, KIND_INS = 0, 1, 2
#: The form of the state, cfg["add_form"]: the error state; the additive quaternion with the
#: aid sources' Jacobians on the error state (attitude columns mapped to the quaternion's
#: by the one update, [ekf7], [ekf10]); the additive quaternion with the Jacobians given on
#: the covariance's own columns (the paper's filters, whose Jacobians are on the
#: quaternion's four parameters: windahrs.filters.additive).
ADD_NONE, ADD_ATT, ADD_COV = 0, 1, 2
COMP_NONE, COMP_GNSS, COMP_AIRSPEED = 0, 1, 2
MAG_3D, MAG_HEADING, MAG_OFF = 0, 1, 2
AIR_AUTO, AIR_VECTOR, AIR_AIRSPEED, AIR_OFF = 0, 1, 2, 3
REST_OFF, REST_ON, REST_START, REST_ALIGN = 0, 1, 2, 3

#: The sensor registry: each aid source's innovation log as (key, the Flight stream that
#: feeds it, rows, the rows' labels). Each aid source (windahrs.aid) logs under its key; a
#: new sensor adds a row here and nothing else in the core (the log layout below is sized
#: from it), and the reports label its innovations from it.
AID_LOGS: tuple[tuple[str, str, int, str], ...] = (
    ("accel", "imu", 3, "xyz"),
    ("mag", "mag", 3, "xyz"),  # 1 row when fused as heading
    ("gnss", "gnss", 3, "NED"),
    ("air", "air", 3, "xyz"),
    ("tas", "air", 1, ""),
    ("sideslip", "air", 1, ""),
    ("drag", "imu", 2, "xy"),
    ("aoa", "air", 1, ""),  # an angle-of-attack vane without a sideslip vane (aid.aoa)
    ("rest", "imu", 3, "xyz"),  # the gyro at rest as a measurement of its bias (aid.rest)
    ("level", "imu", 3, "xyz"),  # the INS at rest: the mean specific force as gravity (aid.rest)
    # not a sensor: the resets of the state to a sensor that its gate kept out too long
    # (rows: the sensor's index in this table, the size of the reset, how long it was out)
    ("reset", "imu", 3, ""),
    # not a sensor either: the IMU samples not propagated (windahrs.core.imu_screen; rows:
    # the change of the angular rate rad/s and of the specific force m/s^2 since the last
    # propagated sample, the reason: 1 beyond the sensor's range, 2 a spike)
    ("imu", "imu", 3, ""),
    # not a sensor: the airspeed scale estimator's state after each air sample
    # (windahrs.aid.airspeed_scale; rows: the scale true/measured, its standard deviation,
    # the estimator's airspeed innovation m/s; nis and accepted are its airspeed's)
    ("aspd", "air", 3, ""),
)
SENSORS = tuple(a[0] for a in AID_LOGS)
SENSOR_STREAMS = tuple(a[1] for a in AID_LOGS)
SENSOR_ROWS = tuple(a[2] for a in AID_LOGS)
#: Labels of each log's innovation rows, by key (what reports print).
SENSOR_LABELS = {a[0]: a[3] for a in AID_LOGS}
N_SENSORS = len(SENSORS)
INN_ACCEL, INN_MAG, INN_GNSS = SENSORS.index("accel"), SENSORS.index("mag"), SENSORS.index("gnss")
INN_AIR, INN_TAS, INN_SIDESLIP = SENSORS.index("air"), SENSORS.index("tas"), SENSORS.index("sideslip")
INN_DRAG = SENSORS.index("drag")
INN_AOA = SENSORS.index("aoa")
INN_REST = SENSORS.index("rest")
INN_LEVEL = SENSORS.index("level")
INN_ASPD = SENSORS.index("aspd")
INN_RESET = SENSORS.index("reset")
INN_IMU = SENSORS.index("imu")
#: The logs that are not aid sources' innovations (read by windahrs.core.kalman.read_events).
EVENT_LOGS = (INN_RESET, INN_IMU, INN_ASPD)

#: cfg: the configuration, fixed for a run (the log layout changes when a streamer grows), as
#: one named record of int64 fields, read as ``cfg["name"]`` (:data:`CFG`, as :data:`PRM`).
#: (name, size, meaning)
CFG_FIELDS: tuple[tuple[str, int, str], ...] = (
    ("kind", 1, "KIND_*"),
    ("add_form", 1, "ADD_*: 0 error state; 1 additive quaternion (ekf7/ekf10); 2 additive, H given on P's columns"),
    ("accel_compensation", 1, "COMP_* (mekf-air: always airspeed)"),
    ("mag_mode", 1, "MAG_*"),
    ("air_mode", 1, "AIR_*"),
    ("synthetic_sideslip", 1, "1: fuse the synthetic sideslip"),
    ("wait_mag", 1, "1: initialise only after a magnetometer sample"),
    ("wait_gnss", 1, "1: initialise only after a GNSS sample"),
    ("init_given", 1, "1: an InitialState was given"),
    ("init_bias_given", 1, "... with a gyro bias"),
    ("init_v_given", 1, "... with a velocity"),
    ("init_wind_given", 1, "... with a wind"),
    ("site_mag_known", 1, "1: the site's field is known"),
    ("i_v", 1, "error-state index of the velocity block (-1: none)"),
    ("i_bg", 1, "... gyro bias"),
    ("i_w", 1, "... wind (-1: none)"),
    ("i_ba", 1, "... accelerometer bias (-1: none)"),
    ("dim", 1, "error-state dimension"),
    ("n", 1, "covariance dimension (additive: dim + 1)"),
    ("i_bm", 1, "... magnetometer bias (-1: none)"),
    ("heading_vertical", 1, "heading model: 1 \"vertical\", 0 \"yaw\""),
    ("drag", 1, "1: fuse the multirotor drag (aid.drag)"),
    (
        "accel_noise_online",
        1,
        "the on-line variance X_AVAR in the gravity measurement's noise: 0 no; 1 yes, low-passed from zero;"
        " 2 yes, started as the mean of the samples so far (accel_noise_mean_start)",
    ),
    ("cov_every", 1, "the covariance is recorded at every this-many-th IMU sample (kernel.record)"),
    ("airspeed_scale", 1, "1: estimate the airspeed scale on line (aid.airspeed_scale)"),
    ("rest", 1, "REST_*: fuse the gyro's bias (and the INS's gravity) at rest (aid.rest): never, always, until"
     " the first motion after a rest, until the first motion"),
    ("tilt_only", 1, "1: the gravity update corrects the tilt only (no heading aid: core.kalman._fuse)"),
    ("start_check", 1, "1: the gravity mean's start is checked against a running mean (aid.gravity.start_check)"),
    ("gated_start", 1, "1: a start off the gravity gate fuses samples first, keeps the gyro bias (aid.gravity)"),
    ("rows", 1, "the columns of the prediction's rows of Phi P (kernel.make_state; predict._predict_es)"),
    ("cov_defer", 1, "1: the covariance predicted once per cov_period over the IMU steps (predict.defer_cov)"),
    ("log_off", N_SENSORS, "first row of each sensor's log"),
    ("log_cap", N_SENSORS, "rows of each sensor's log"),
)



#: prm: the parameters, fixed for a run, as one named record: a numpy structured scalar
#: (``np.zeros(1, PRM)[0]``), read as ``prm["name"]`` in compiled code and in Python alike
#: (numba resolves a field by its name at compile time: the same load as a constant index,
#: docs/core.md "Named records"). Filled once by core.kernel.make_state from the estimator's
#: parameters (filters.params.EskfParams, whose names the fields keep; "2" ends a square,
#: "_var" a variance), grouped by the part of the filter that reads them. The paper's family
#: has fields of its own in it (PAPER_PRM_FIELDS below). (name, size, meaning)
PRM_FIELDS: tuple[tuple[str, int, str], ...] = (
    # process model (core.predict)
    ("gyro_noise2", 1, "gyro_noise^2, (rad/s)^2/Hz"),
    ("gyro_bias_noise2", 1, "gyro_bias_noise^2, (rad/s^2)^2/Hz"),
    ("gyro_bias_noise_dv2", 1, "gyro_bias_noise_vertical^2 - gyro_bias_noise^2 (0: one walk), (rad/s^2)^2/Hz"),
    ("gyro_scale_noise2", 1, "gyro_scale_noise^2: rate-proportional gyro noise"),
    ("accel_noise2", 1, "accel_noise^2, the INS input's, (m/s^2)^2/Hz"),
    ("accel_bias_noise2", 1, "accel_bias_noise^2, (m/s^3)^2/Hz"),
    ("wind_noise2", 1, "wind_noise^2, horizontal, (m/s^2)^2/Hz"),
    ("wind_noise_vertical2", 1, "wind_noise_vertical^2 (0: the vertical wind held)"),
    ("mag_bias_noise2", 1, "mag_bias_noise^2, T^2/s"),
    ("gravity", 1, "the site's gravity, m/s^2"),
    # initial state and spreads (core.kernel, core.reset)
    ("init_att_var", 1, "init_att^2, rad^2 (or the given initial state's)"),
    ("init_yaw_var", 1, "init_yaw^2, rad^2 (0: init_att's)"),
    ("init_bias_var", 1, "init_bias^2, (rad/s)^2"),
    ("init_v_var", 1, "init_v^2, (m/s)^2"),
    ("init_wind_var", 1, "init_wind^2, (m/s)^2"),
    ("init_wind_vertical_var", 1, "the initial vertical-wind variance (0: held at zero)"),
    ("init_accel_bias_var", 1, "init_accel_bias^2, (m/s^2)^2"),
    ("init_mag_bias_var", 1, "init_mag_bias^2, T^2"),
    ("init_window", 1, "init_window, s: the specific force averaged before the attitude is initialised"),
    ("init_q", 4, "the given initial attitude q_nb"),
    ("init_bias", 3, "... its gyro bias, rad/s"),
    ("init_v", 3, "... its velocity, m/s"),
    ("init_wind", 3, "... its wind, m/s"),
    ("reset_timeout", 1, "reset_timeout, s (0: never reset)"),
    # IMU screen (core.imu_screen)
    ("gyro_range", 1, "gyro_range, rad/s"),
    ("accel_range", 1, "accel_range, m/s^2"),
    ("imu_spike_gate", 1, "imu_spike_gate (0: off)"),
    ("unmeasured_motion_dt", 1, "unmeasured_motion_dt, s: IMU steps longer than this add the held-sample noise"),
    ("cov_period", 1, "cov_period, s: the INS's covariance predicted over the IMU steps of each (predict.defer_cov)"),
    # gravity (aid.gravity)
    ("accel_var", 1, "accel_sigma^2, (m/s^2)^2"),
    ("accel_norm_gate", 1, "accel_norm_gate, share of g"),
    ("gate_accel2", 1, "gate_accel^2"),
    ("accel_lowpass", 1, "accel_lowpass, s (0: raw samples)"),
    ("accel_fuse_dt", 1, "1 / accel_fuse_rate, s (0: the mean fused at every IMU sample)"),
    ("lowpass_bias", 1, "lowpass_bias: 1 the low-passed means carry their gyro-bias columns"),
    # magnetometer (aid.mag)
    ("mag_sigma", 1, "mag_sigma, T"),
    ("mag_var", 1, "mag_sigma^2, T^2"),
    ("gate_mag2", 1, "gate_mag^2"),
    ("mag_reentry_gate2", 1, "(mag_reentry_gate * gate_mag)^2"),
    ("mag_lowpass", 1, "mag_lowpass, s (0: raw samples)"),
    ("mag_fuse_dt", 1, "1 / mag_fuse_rate, s (0: the mean fused at every sample)"),
    ("mag_norm_gate", 1, "mag_norm_gate, share of the reference's norm (0: off)"),
    ("mag_dip_gate", 1, "mag_dip_gate, rad (0: off)"),
    ("site_mag", 3, "the site's field, NED, T (0: unknown)"),
    ("site_decl", 1, "the site's declination, rad east (0: unknown): a field learned from the data is turned by it"),
    # GNSS velocity (aid.gnss_vel)
    ("gnss_var", 1, "gnss_sigma^2, (m/s)^2"),
    ("gate_gnss2", 1, "gate_gnss^2"),
    ("gnss_timing_sigma", 1, "gnss_timing_sigma, s"),
    # air data (aid.air_vector, aid.tas, aid.sideslip, aid.aoa)
    ("tas_var", 1, "tas_sigma^2, (m/s)^2"),
    ("vane_var", 1, "vane_sigma^2, rad^2"),
    ("sideslip_var", 1, "sideslip_sigma^2, rad^2 (synthetic sideslip)"),
    ("gate_air2", 1, "gate_air^2"),
    # airspeed scale (aid.airspeed_scale)
    ("asc_init_var", 1, "airspeed_scale_sigma^2: initial variance of the inverse scale"),
    ("asc_kn2", 1, "airspeed_scale_noise^2, 1/s^2/Hz"),
    ("asc_wn2", 1, "airspeed_scale_wind_noise^2, (m/s^2)^2/Hz"),
    ("asc_tas_var", 1, "airspeed_scale_tas_sigma^2, (m/s)^2"),
    ("asc_beta_var", 1, "airspeed_scale_beta_sigma^2, rad^2"),
    # multirotor drag (aid.drag)
    ("drag_mcoef", 1, "drag_mcoef, 1/s"),
    ("drag_kx", 1, "air_density / (2 drag_bcoef_x), 1/m (0: no bluff-body term)"),
    ("drag_ky", 1, "air_density / (2 drag_bcoef_y), 1/m"),
    ("drag_var", 1, "drag_sigma^2, (m/s^2)^2"),
    ("gate_drag2", 1, "gate_drag^2"),
    # the gyro at rest (aid.rest)
    ("rest_w2", 1, "rest_gyro_threshold^2, (rad/s)^2"),
    ("rest_f2", 1, "rest_accel_threshold^2, (m/s^2)^2"),
    ("rest_tau", 1, "rest_tau, s"),
    ("rest_min_t", 1, "rest_min_time, s"),
    ("rest_var", 1, "rest_bias_sigma^2, (rad/s)^2"),
    ("rest_clip", 1, "rest_bias_clip, rad/s"),
)


def record_dtype(fields: tuple[tuple[str, int, str], ...], kind: type = np.float64) -> np.dtype[Any]:
    """The structured dtype of (name, size, description) fields of one ``kind`` (size 1: a scalar)."""
    return np.dtype([(f, kind) if n == 1 else (f, kind, (n,)) for f, n, _ in fields])


#: The paper's family (windahrs.filters.additive: paper, paper-nowind, ekf, ukf) has fields of
#: its own in the same records: one record type for every compiled filter, so that the
#: functions they share (core.kalman._fuse, core.predict._predict_add, ...) compile once, not
#: once per record type (measured: the paper's filter's cold compile 52 s with one type, 76 s
#: with two). Its process noise is the core's gyro_noise2 and gyro_bias_noise2.
PAPER_PRM_FIELDS: tuple[tuple[str, int, str], ...] = (
    ("p0_var", 1, "paper: initial variance per quaternion parameter"),
    ("att0_var", 1, "initial attitude variance per axis, rad^2"),
    ("bg0_var", 1, "initial gyro-bias variance per axis"),
    ("q_var", 1, "paper: process variance per quaternion parameter per step"),
    ("paper_acc_var", 1, "paper: accelerometer variance per component"),
    ("paper_mag_var", 1, "paper: magnetometer variance per component"),
    ("air_var", 1, "paper: air-flow variance per component"),
    ("gnss_age", 1, "paper: oldest GNSS velocity the air row uses, s"),
    ("acc_noise", 1, "accelerometer white-noise density"),
    ("acc_unit2", 1, "extra variance of the normalised accelerometer"),
    ("mag_noise", 1, "magnetometer noise per sample, T"),
    ("mag_unit2", 1, "extra variance of the normalised magnetometer"),
    ("g_norm", 1, "|g|, m/s^2"),
    ("spread", 1, "UKF: n + lambda"),
    ("site_field", 3, "the site's field, or 0"),
    ("qstart", 4, "fixed initial attitude"),
    ("b0", 3, "initial gyro bias"),
)

PAPER_CFG_FIELDS: tuple[tuple[str, int, str], ...] = (
    ("paper_kind", 1, "KIND_PAPER, KIND_EKF or KIND_UKF"),
    ("has_mag", 1, "1: the flight has a magnetometer"),
    ("qstart_given", 1, "1: a fixed initial attitude (qstart)"),
    ("use_air", 1, "1: fuse the air-flow row"),
    ("p0_iso", 1, "1: the paper's isotropic initial covariance per quaternion parameter"),
)


PRM = record_dtype(PRM_FIELDS + PAPER_PRM_FIELDS)
CFG = record_dtype(CFG_FIELDS + PAPER_CFG_FIELDS, np.int64)

# x: nominal state and remembered samples (float64).
X_Q = 0  # (4,)
X_BG = 4
X_V = 7
X_W = 10
X_BA = 13
X_MAGN = 16  # nav-frame field reference
X_FLAST = 19  # last specific force
X_VGNSS = 22  # last GNSS velocity
X_AGNSS = 25  # GNSS velocity difference
X_VAIR = 28  # last air-relative velocity, body
X_FMAG = 31  # first magnetometer sample (before initialisation)
X_FV = 34  # first GNSS velocity (before initialisation)
X_TIMU = 37
X_TGNSS = 38
X_BM = 40  # (3,) magnetometer bias
X_FBAR = 43  # (3,) low-passed specific force, body
X_MBAR = 46  # (3,) low-passed magnetic field, body
X_TMBAR = 49  # time of the last magnetometer sample in it
X_FWIN = 50  # (3,) mean specific force of the initialisation window, current body frame
X_NWIN = 53  # samples in it
X_TWIN0 = 54  # time of its first sample
X_WLAST = 55  # (3,) last angular rate sample
X_DW = 58  # (3,) change of the angular rate sample since the previous one, rad/s
X_DF = 61  # (3,) change of the specific force sample since the previous one, m/s^2
X_AINS = 64  # (3,) low-passed GNSS acceleration, NED, over the INS's mean specific force's time (X_FBAR)
X_TOK = 67  # (N_SENSORS,) time each aid source last agreed with the state (NaN: not yet initialised)
X_AVAR = X_TOK + N_SENSORS  # the accelerometer's on-line noise variance, (m/s^2)^2 per axis
X_NAVAR = X_AVAR + 1  # samples averaged into X_AVAR so far
X_JLAG = X_AVAR + 2  # (9,) row-major: how a gyro-bias error moves the low-passed specific force
#   (d X_FBAR / d b_g, the rotation error it accumulates over the mean's age; aid.gravity)
X_NGAIN = X_AVAR + 11  # (2,) the noise low-pass's last step dt s and its gain (core.predict.track_accel_noise)
X_JMAG = X_AVAR + 13  # (9,) row-major: the same for the low-passed magnetic field X_MBAR (aid.mag)
#: (2,) each: the last step dt s of a low-pass at the IMU's (or magnetometer's) rate and its
#: gain (core.predict.steady_gain): the gravity aid's mean, the INS's mean specific force
#: (aid.gnss_vel), the magnetometer's mean
X_FGAIN = X_AVAR + 22
X_LGAIN = X_AVAR + 24
X_MGAIN = X_AVAR + 26
X_TINIT = X_AVAR + 28  # when the filter initialised, s (NaN: not yet): Estimate.init_index
X_RM = X_AVAR + 29  # (3,) running mean of the specific force since the start, body (aid.gravity.start_check)
X_NRM = X_AVAR + 32  # samples in it (0: no start check pending)
X_NFUSE = X_AVAR + 33  # IMU samples the gravity aid's mean took since it was last fused (aid.gravity)
X_TGFUSE = X_AVAR + 34  # when it was last fused, s
X_NMFUSE = X_AVAR + 35  # the same for the magnetometer's mean (aid.mag)
X_TMFUSE = X_AVAR + 36
X_OFFSTART = X_AVAR + 37  # 1: the start's sample was off the gravity gate (aid.gravity, gated_start), else 0
X_KEEPBG = X_AVAR + 38  # for how long after the start, s, gravity updates keep the gyro bias (gated_start)
#: The INS's heading seen by GNSS (aid.gnss_vel.watch_heading): 1 while the mean GNSS acceleration
#: makes the heading observable (with hysteresis), else 0; the seconds of observable motion whose
#: GNSS samples the gate accepted since the heading was last turned or a sample was rejected;
#: the time of the last GNSS sample counted.
X_HOBS = X_AVAR + 39
X_HSEEN = X_AVAR + 40
X_HLAST = X_AVAR + 41
#: The INS's covariance prediction pending over IMU steps whose nominal state was propagated
#: (core.predict.defer_cov): the steps, their summed length s, the sums of the bias-corrected
#: rate times the step (3) and of the specific force times the step (3).
X_PN = X_AVAR + 42
X_PDT = X_AVAR + 43
X_PW = X_AVAR + 44
X_PF = X_AVAR + 47
#: When the air-data aid source last offered a sample to its gate, s (aid.air_vector.air_clock).
X_TAIR = X_AVAR + 50
#: When the magnetometer's 3-D field last passed its gate (fused), s (aid.gnss_vel.reset_to_gnss).
X_TMOK = X_AVAR + 51
#: When GNSS velocity last passed its gate, s (-inf: never since the start; aid.gnss_vel).
X_TGOK = X_AVAR + 52
#: The magnetometer's re-entry gate (aid.mag.fuse_field): when the field first passed its gate
#: since the last sample beyond the full gate, s (NaN: none has; NaN at the start and after a
#: heading reset); the last time a sample was kept out beyond the full gate (or by the
#: disturbance checks) right after a fused one or while the re-entry gate held, s, from which
#: the re-entry gate holds for reset_timeout (-inf: none).
X_TMPASS = X_AVAR + 53
X_TMREIN = X_AVAR + 54
N_X = X_AVAR + 55

# flags (int64): which remembered values are set, log counters, skipped samples.
S_INIT = 0
S_FLAST = 1
S_MAGN = 2
S_VGNSS = 3
S_AGNSS = 4
S_VAIR = 5
S_FMAG = 6
S_FV = 7
S_WPEND = 8  # wind to be initialised from the next air sample
S_SEQ = 9  # sensors that have logged so far
S_FBAR = 10  # the low-passed specific force is set (the gravity aid source's, or the INS's)
S_MBAR = 11  # the low-passed magnetic field is set
S_WIN = 12  # the initialisation window has a sample
S_AINS = 13  # X_AINS is set
K_SKIP = 14  # (4,) NaN samples skipped: imu, mag, gnss, air
S_HEADLESS = 18  # the heading awaits the next magnetometer sample (a start without it, a GNSS reset)
L_CNT = 19  # (N_SENSORS,) log rows used per sensor
L_FIRST = L_CNT + N_SENSORS  # (N_SENSORS,) order of each sensor's first log row (-1: none)
S_NHRESET = L_FIRST + N_SENSORS  # headings an INS took from the field: its resets, after GNSS resets (aid.mag)
N_FLAGS = S_NHRESET + 1

# work: scratch rows of NMAX columns.
W_H = 0  # (3,) measurement Jacobian rows, error-state columns
W_HQ = 3  # (3,) the same in covariance columns (additive)
W_U = 6  # (3,) H P
W_K = 9  # (3,) K^T
W_G = 12  # (3,) G^T = (K S / 2 - P H^T)^T
W_M = 15  # (8,) rows of Phi P; rows 4..7 also Xi(q)
W_X = 23  # (8,) 8x8: attitude/velocity block; rows 4..7 also a 4x4 factor
W_T = 31  # 8 3x3 matrices, in columns 0..2 of rows W_T + 3 i
W_R = 55  # (3,) measurement noise, columns 0..2
W_S = 58  # (3,) innovation covariance
W_SI = 61  # (3,) its inverse
W_NU = 64  # innovation in columns 0..2
W_DX = 65  # error-state correction
W_IMU = 66  # the IMU sample propagated in place of a held one: w_b (3), f_b (3)
W_PEEK = 67  # (20,) rows: P with its pending prediction, as recorded (kernel.record), P left as it is
N_WORK = W_PEEK + 20  # (the covariance's padded size at most: NMAX 19 to whole SIMD lanes of 4)


def mean_rate(t: NDArray[np.float64]) -> float | None:
    """The mean rate of the samples at times t (s), Hz; None for fewer than two or no span."""
    span = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    return (len(t) - 1) / span if span > 0 else None


def cov_stride(n: int, d: int, every: int | str | None = None, rate_hz: float | None = None) -> int:
    """The stride of the recorded covariance for n IMU samples at ``rate_hz`` of a d-state
    filter: the given one; for None the largest that keeps it at :data:`COV_RECORD_HZ` or
    faster (1 without a rate or below it), at least the smallest that keeps n d^2 / stride
    within :data:`COV_BUDGET`; for "budget" the smallest within the budget that divides that
    default (every sample's within the budget: 1 up to 128 MiB), so that the default's rows
    are among its rows."""
    budget = max(1, -(-n * d * d // COV_BUDGET))
    if isinstance(every, str) and every == "budget":
        default = cov_stride(n, d, None, rate_hz)
        return min(s for s in range(budget, default + 1) if default % s == 0)
    if every is not None:
        if isinstance(every, bool) or not isinstance(every, int | np.integer) or every < 1:
            raise ValueError(
                f"cov_every: expected an integer >= 1 (1: every sample) or 'budget', found {every!r}"
            )
        return int(every)
    by_rate = int(rate_hz // COV_RECORD_HZ) if rate_hz is not None and np.isfinite(rate_hz) else 1
    return max(by_rate, budget)


def cov_stride_of(t: NDArray[np.float64], d: int, every: int | str | None = None) -> int:
    """:func:`cov_stride` for a d-state filter on IMU times t (s): the stride a run records
    the covariance at (:meth:`windahrs.core.kernel.CompiledEstimator.prepare`)."""
    return cov_stride(len(t), d, every, mean_rate(t))


class KernelState(NamedTuple):
    """Everything a compiled filter carries between events (arrays, mutated in place);
    the index constants of this module name their entries."""

    cfg: np.void  # CFG record: cfg["name"]
    prm: np.void  # PRM record: prm["name"]
    x: F64  # (N_X,) X_*
    flags: I64  # (N_FLAGS,) S_*, L_*, K_*
    P: F64  # (n_pad, n_pad) covariance in [:n, :n], zero padding to whole SIMD lanes
    work: F64  # (N_WORK, max(n_pad, NMAX)) W_*
    sup: I64  # (2, NMAX) columns where H (row 0) and Hq (row 1) may be non-zero
    inn: F64  # (L, 5) innovation log rows: t, nu (3, NaN-padded), nis
    acc: NDArray[np.bool_]  # (L,) accepted
    # the aid sources' private state: (1,) arrays of their records, declared next to them
    # (compiled code takes element 0, whose fields it reads and writes in place)
    screen: NDArray[np.void]  # core.imu_screen.SCREEN
    rest: NDArray[np.void]  # aid.rest.REST
    asc: NDArray[np.void]  # aid.airspeed_scale.ASC
