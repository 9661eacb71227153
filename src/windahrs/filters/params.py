"""Tuning of the error-state filters: one frozen record, validated once, loadable from TOML
with our names or PX4 / ArduPilot parameter names.

Units are SI. Noise *densities* (per sqrt(Hz)) drive the process; measurement noises are
standard deviations per sample. Defaults are for a MEMS IMU in the field (a little more
pessimistic than a datasheet, as vibration and temperature demand); simulations that want
the filter to match the sensor model pass :func:`matched_to` a sensor suite.

TOML layout (any of the tables may be left out)::

    [windahrs]          # our field names, e.g. gyro_noise = 1.5e-4
    mag_mode = "3d"
    [px4]               # PX4 EKF2 names, converted as documented in PX4_MAP
    EKF2_GYR_NOISE = 0.015
    [ardupilot]         # ArduPilot EKF3 names, see ARDUPILOT_MAP
    EK3_EAS_M_NSE = 1.4
"""

from __future__ import annotations

import dataclasses
import functools
import math
import tomllib
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from windahrs.conventions import DEG, G0
from windahrs.repair import ACCEL_RANGE, GYRO_RANGE

__all__ = [
    "ANGLE_FIELDS", "ARDUPILOT_MAP", "FIELD_MAX", "FLIGHT_PARAMS", "LOW_IMU_RATE_HZ", "MAX_MAGNITUDE", "PX4_MAP",
    "EskfParams", "changes_from_mapping", "check_magnitude", "flight_params", "imu_rate_warning", "load_params",
    "matched_to", "read_param_file",
]

#: PX4 and ArduPilot filters use per-step noise at their prediction period; densities
#: are that times sqrt(period). PX4 EKF2 predicts every 10 ms (EKF2_PREDICT_US default).
_PX4_DT = 0.01
_AP_DT = 0.01


#: The largest parameter value any filter accepts. The filters multiply squared parameters
#: together (``gate^2 S``, S built of ``sigma^2`` and the covariance's spreads): below 1e50
#: any product of six such numbers stays finite in double precision, and no physical noise,
#: spread, gate or time comes within many orders of magnitude of it.
MAX_MAGNITUDE = 1e50

#: Fields that are angles in rad: at most pi (an attitude or flow angle is off by 180 deg at most).
ANGLE_FIELDS = frozenset(
    {"init_att", "init_yaw", "vane_sigma", "sideslip_sigma", "mag_dip_gate", "airspeed_scale_beta_sigma"}
)
#: Fields that are angular rates in rad/s, at most the gyro's widest range.
_RATE_FIELDS = ("rest_gyro_threshold", "rest_bias_sigma", "rest_bias_clip")

_GYRO_RANGE = 2000.0 * DEG  # rad/s: +-2000 deg/s, the widest full scale of MEMS gyros (MPU-9250, BMI088)
_ACCEL_RANGE = 16.0 * G0  # m/s^2: +-16 g, the widest common MEMS accelerometer full scale (MPU-9250)
_MAG_RANGE = 4912e-6  # T: +-4912 uT, the AK8963's full scale (the MPU-9250's magnetometer)
_SPEED_OF_SOUND = 340.3  # m/s, ISA sea level: no velocity, wind or error of a subsonic UAV exceeds it

#: Physical ceilings of the sensor-related fields (:func:`check_magnitude`): a standard
#: deviation, initial spread or noise density (per sqrt(Hz), so at 1 Hz bandwidth) cannot
#: exceed the range the sensor measures; angles are at most pi (:data:`ANGLE_FIELDS`);
#: every other number at most :data:`MAX_MAGNITUDE`.
FIELD_MAX: dict[str, float] = {
    **dict.fromkeys(("gyro_noise", "gyro_bias_noise", "gyro_bias_noise_vertical", "init_bias", *_RATE_FIELDS),
                    _GYRO_RANGE),
    "rest_accel_threshold": _ACCEL_RANGE,
    **dict.fromkeys(("accel_noise", "accel_bias_noise", "accel_sigma", "init_accel_bias", "drag_sigma"),
                    _ACCEL_RANGE),
    **dict.fromkeys(("mag_sigma", "init_mag_bias", "mag_bias_noise"), _MAG_RANGE),
    **dict.fromkeys(("gnss_sigma", "tas_sigma", "init_v", "init_wind", "wind_noise", "wind_noise_vertical",
                     "airspeed_scale_tas_sigma", "airspeed_scale_wind_noise"), _SPEED_OF_SOUND),
    # the inverse scale's spread and random walk: a pitot reads from nothing to a few times the airspeed
    **dict.fromkeys(("airspeed_scale_sigma", "airspeed_scale_noise"), 1.0),
    "mag_reentry_gate": 1.0,  # a share of gate_mag
    # s: PX4 EKF2 takes EKF2_PREDICT_US from 1 000 to 20 000 us
    "cov_period": 0.02,
}


def check_magnitude(name: str, value: object, *, owner: str = "") -> None:
    """ValueError naming ``owner.name`` unless ``value`` is a finite number (not a bool) from
    0 to :data:`MAX_MAGNITUDE` (to pi for :data:`ANGLE_FIELDS`)."""
    where = f"{owner}.{name}" if owner else name
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
        raise ValueError(f"{where}: expected a finite number >= 0, found {value!r}")
    top = math.pi if name in ANGLE_FIELDS else FIELD_MAX.get(name, MAX_MAGNITUDE)
    if value > top:
        unit = ""
        if name in ANGLE_FIELDS:
            unit = " rad (an angle)"
        elif name == "cov_period":
            unit = " s (PX4 EKF2_PREDICT_US's largest, 20 000 us)"
        elif name in FIELD_MAX:
            unit = " (the sensor's physical range)"
        raise ValueError(f"{where}: expected at most {top:.6g}{unit}, found {value!r}")


@dataclass(frozen=True)
class EskfParams:
    """Parameters of [mekf], [mekf-air], [ins-wind] and [ekf7].

    Process (continuous densities): gyro_noise rad/s/sqrt(Hz); gyro_bias_noise
    rad/s^2/sqrt(Hz); accel_noise m/s^2/sqrt(Hz) (INS input); accel_bias_noise
    m/s^3/sqrt(Hz) (0: no accelerometer-bias states in [ins-wind]); accel_noise_measured
    ([ins-wind], [ins-drag]; default True): the INS input's density is at least the
    accelerometer's noise measured on line in the flight (``sqrt(var dt)``, var the variance
    of the sample-to-sample differences, ``|f_k - f_k-1|^2 / 6`` per axis, low-passed over
    3 s, VQF's tau_acc: :func:`windahrs.core.predict.track_accel_noise`): a hard-mounted
    IMU's rotor vibration (ANSFL's quadrotor: 3.7 m/s^2 per sample at 120 Hz, 0.34
    m/s^2/sqrt(Hz)) is 17 times accel_noise's datasheet density, and an INS that takes its
    velocity from such samples at the datasheet's density trusts them that much too far
    (measured: ANSFL tilt with the GNSS on the IMU's clock, 5.47 -> 5.30 deg median over 16
    flights; ALFA 4.44 -> 4.28; the simulated flights and PX4's pre-filtered logs, whose
    measured noise is under accel_noise, unchanged); wind_noise,
    wind_noise_vertical m/s^2/sqrt(Hz) (high enough to follow turbulence: an airframe
    in gusts sees the wind change by about sigma * sqrt(2 V / L) per sqrt(s)). wind_vertical:
    estimate the vertical wind (False: hold it at zero, as PX4 EKF2's 2-D wind state; for
    a wind observed only through the horizontal drag, where it is not observable).

    Accelerometer as a gravity measurement ([mekf], [mekf-air], [ekf7]): accel_sigma m/s^2
    per axis (noise plus unmodelled acceleration); fused only when ``| |f| - g | <
    accel_norm_gate * g``; accel_compensation: "none", "gnss" (GNSS velocity differences)
    or "airspeed" (``w x V_air`` from pitot and vanes, SPEC 3.2.2). accel_lowpass s: when
    > 0 the (compensated) specific force is first low-passed with this time constant in a
    gyro-compensated, almost inertial frame (the running mean is rotated into each new
    body frame by the gyro increment), and that mean is the measurement, gated and fused
    at every IMU sample: linear accelerations of bounded velocity average out there while
    gravity does not (VQF's tau_acc; [mekf] default 3 s, 0: raw samples).
    accel_fuse_rate Hz (with accel_lowpass; error-state filters): the mean is fused at this
    rate rather than at every IMU sample, each fusion with R / k for the k samples it stands
    for (the information per second kept), while the gain is small (the prior tilt variance
    under a tenth of the sample's noise: ``core.kalman.samples_to_fuse``; every sample at a
    start or after a reset). The mean changes over accel_lowpass seconds, so fusing it at
    every sample repeats it; the update was 43 % of [mekf]'s per-sample time ([mekf]
    default 50 Hz, 0: every sample; docs/RESULTS.md section 25 gives its measured effect).
    lowpass_bias (with accel_lowpass, mag_lowpass): the means' measurement models include
    the gyro bias, ``H_b = H_att J``: their samples were rotated into the current body frame
    by the bias-corrected gyro, so a bias error turned each by the bias times its age (J,
    tau I at rest, kept rotated with the body by the kernel; :mod:`windahrs.aid.gravity`),
    and a bias correction turns the means to what the new bias would have made of them.
    The magnetometer's mean carries them in 3-D fusion only (a known site field): on the
    heading-only model (the field's site unknown, e.g. indoors) they took the field's
    spatial changes into the vertical gyro bias (BROAD heading 0.775 -> 1.118 deg). Without
    them a 1 deg/s gyro bias keeps the tilt about tau x bias off for tens of seconds.
    Default True in [mekf] (docs/RESULTS.md section 18: the simulated quadrotor's tilt,
    4 seeds x calm and 8 m/s, summed 5.01 -> 3.68 deg; PX4 sample.ulg 0.214 -> 0.149;
    ANSFL 5.07 -> 4.54; BROAD 1.015 / 0.552 -> 1.003 / 0.560 total / inclination; the
    simulated fixed wing's coordinated turns, which [mekf] takes for gravity, 4.9 -> 5.7).
    accel_noise_online (with accel_lowpass): add to accel_sigma^2 the accelerometer's noise
    variance estimated on line from the differences of consecutive samples, ``|f_k -
    f_k-1|^2 / 6`` per axis averaged over accel_lowpass: rotor vibration (several m/s^2 on a
    hard-mounted IMU, aliased into low frequencies the mean keeps) then weighs the mean
    down, while the smooth motion of a handheld or flying vehicle barely enters it ([mekf]
    default; measured: ANSFL quadrotor tilt 8.1 -> 6.2 deg on the even flights that chose
    it, 9.8 -> 6.8 on the odd ones; BROAD 02/07/10 inclination 0.462 -> 0.463, 15/24/30/32
    0.580 -> 0.621 deg; docs/RESULTS.md). accel_noise_mean_start (with accel_noise_online):
    the on-line variance starts as the mean of the samples so far, until the low-pass's
    own gain (accel_lowpass) takes over, as VQF starts its low-pass filters; False: it is
    low-passed from zero, so that in the first seconds the mean of a vibrating accelerometer
    was fused as if it were almost noise-free (default True; measured: ANSFL quadrotor tilt
    6.23 -> 4.71 deg on the even flights that chose it, 6.92 -> 6.40 on the odd ones;
    BROAD 02/07/10 unchanged, 15/24/30/32 inclination 0.614 -> 0.615 deg; docs/RESULTS.md).
    gyro_scale_noise 1/sqrt(Hz): attitude process noise proportional to the rate,
    ``(gyro_scale_noise |w|)^2`` added to gyro_noise^2 (scale-factor and axis-misalignment
    errors; 1e-3: about 0.1 % of the angle turned per second of rotation; error-state
    filters only, [ekf7] and [ekf10] ignore it; [mekf] default 1e-3).
    gyro_bias_noise_vertical rad/s^2/sqrt(Hz) (error-state filters; 0: gyro_bias_noise's):
    the bias's walk about the nav vertical (the body's component along C_bn e_3) at a
    density of its own, at most gyro_bias_noise (a larger value, or a gyro_bias_noise set
    below it, e.g. from a log's EKF2_GYR_B_NOISE, gives one walk at gyro_bias_noise's), the
    rest at gyro_bias_noise's. Gravity observes the bias across the
    vertical, only a heading aid (the magnetometer) along it, and a disturbed field taken
    into a fast-walking bias turns the heading: VQF learns that part far slower
    (biasVerticalForgettingFactor). [mekf] default: 1e-4 (PX4 EKF2_GYR_B_NOISE's density)
    across, 2e-5 along (measured: BROAD inclination 0.458 -> 0.399 deg on 02/07/10, 0.619 ->
    0.609 on the rest, total 1.003 -> 0.993; PX4 sample.ulg tilt 0.176 -> 0.158; costs: PX4
    heading 0.715 -> 0.740, the simulated quadrotor's tilt 3.68 -> 4.49 summed over 8 cases,
    and on the simulated fixed wing without air data, where [mekf]'s turns read as tilt,
    5.5-5.9 -> 7.4-7.9 deg and a clean flight's field residual past mag_drift's limit;
    docs/RESULTS.md section 32).

    Magnetometer: mag_mode "3d", "heading" (yaw only) or "off"; mag_sigma tesla per axis
    (noise only when the bias is a state, else noise plus residual hard iron);
    init_mag_bias tesla, the spread of the residual hard iron after calibration (> 0 with
    mag_mode "3d" adds magnetometer-bias states, as PX4's EKF2 and ArduPilot's EKF3 carry;
    0: none); mag_bias_noise tesla/s/sqrt(Hz), its random walk. [ins-wind] carries the
    states by default (1 uT, the AK8975 residual of SPEC 5.4), the other filters do not.
    mag_3d_needs_site: with mag_mode "3d" and a site whose field is unknown (its dip then
    comes from one sample and indoor fields are not uniform), fuse the heading only
    ([mekf] default). heading_model: "yaw" (SPEC 3.3: ZYX yaw, ``H = [0, sin r, cos r] / cos p``,
    singular at pitch +-90 deg) or "vertical" (the heading of the nav-frame field
    ``C_nb m`` against the reference's, corrected by a rotation about the nav vertical
    only, ``H_att = (C_bn e_3)^T``: no tilt terms, no singularity; [mekf] default).
    mag_lowpass s: the magnetometer low-passed like the specific force (accel_lowpass),
    the mean fused ([mekf] default 9 s, VQF's tau_mag; 0: raw samples). mag_fuse_rate Hz
    (with mag_lowpass; error-state filters): that mean fused at this rate, as accel_fuse_rate
    does the gravity mean ([mekf] default 10 Hz: the mean changes over 9 s; 0: every
    sample). Disturbance
    checks on the fused field m (0: off): rejected when ``| |m| - |m_ref| | >
    mag_norm_gate |m_ref|`` or when its dip in the nav frame (estimated attitude) is more
    than mag_dip_gate rad from the reference's ([mekf] defaults 0.1 and 10 deg, VQF's).
    GNSS velocity: gnss_sigma m/s per axis. Air data: air_mode "auto" (the vector when the
    flight has vanes, else airspeed and synthetic sideslip), "vector", "airspeed" or "off";
    tas_sigma m/s, vane_sigma rad, sideslip_sigma rad (synthetic zero sideslip;
    synthetic_sideslip switches it). A flight with an angle-of-attack vane and no sideslip
    vane fuses the airspeed and the angle of attack alone (:mod:`windahrs.aid.aoa`, with
    vane_sigma; "auto" and "vector").

    Airspeed scale ([mekf-air], [ins-wind], [ekf10]; :mod:`windahrs.aid.airspeed_scale`):
    airspeed_scale switches a small EKF beside the filter, as PX4's airspeed selector runs,
    which estimates the pitot's scale (true / measured airspeed) with its own horizontal
    wind, and the filter fuses the airspeed it corrects. airspeed_scale_sigma: the initial
    standard deviation of the inverse scale (measured / true) about 1 (0.3: a pitot up to
    30 % off either way); airspeed_scale_noise 1/s/sqrt(Hz), its random walk (PX4
    ASPD_SCALE_NSD, 1e-4); airspeed_scale_wind_noise m/s^2/sqrt(Hz), its wind's (PX4
    ASPD_WIND_NSD, 0.1); airspeed_scale_tas_sigma m/s, its airspeed noise (PX4
    ASPD_TAS_NOISE, 1.4: turbulence included); airspeed_scale_beta_sigma rad, its sideslip
    noise (PX4 ASPD_BETA_NOISE, 0.15).

    Multirotor drag ([ins-wind], [ins-drag]; PX4 EKF2's drag fusion): drag switches the
    fusion of the accelerometer's body x and y as ``f_xy = -drag_mcoef u_xy - air_density
    u_xy |u_xy| / (2 drag_bcoef_xy)`` with ``u = C_bn (v - W)`` the air-relative velocity:
    drag_mcoef 1/s, the rotor momentum drag (EKF2_MCOEF, default 0.15); drag_bcoef_x,
    drag_bcoef_y kg/m^2, the ballistic coefficients of the bluff body (EKF2_BCOEF_X/Y,
    default 100; 0: no bluff-body term); drag_sigma m/s^2 per axis (EKF2_DRAG_NOISE is its
    variance, default 2.5 (m/s^2)^2: rotor vibration); gate_drag; air_density kg/m^3
    (ISA sea level).

    GNSS velocity ([ins-wind]): gnss_sigma m/s per axis, the floor of a receiver's own speed
    accuracy where the flight gives it (``GnssStream.v_sigma``: PX4 EKF2's
    ``max(sacc, EKF2_GPS_V_NOISE)``, :mod:`windahrs.aid.gnss_vel`); gnss_timing_sigma s, the uncertainty
    of its time stamps against the IMU's: a velocity late or early by tau is off by the
    vehicle's acceleration times tau, so ``(gnss_timing_sigma a_k)^2`` is added to R per axis,
    with a the GNSS stream's own acceleration (its last velocity difference quotient; no
    attitude needed, which a lost INS would get wrong). ArduPilot EKF3 adds the same term
    with 0.05 s (``gpsNEVelVarAccScale``) for a receiver on the autopilot's clock; default 0
    (the simulator's GNSS has no latency, and a receiver on the IMU's clock needs little). A
    reader whose GNSS is logged on another device's clock declares its timing uncertainty in
    ``Flight.meta["gnss.timing_sigma_s"]`` (:data:`FLIGHT_PARAMS`), used while this field is
    left at 0 (the ANSFL reader: :data:`windahrs.io.ansfl.ANSFL_GNSS_TIMING_SIGMA`).

    Gates: a measurement is rejected when a component's innovation exceeds ``gate`` of its
    standard deviation (PX4's test ratio), per sensor. mag_reentry_gate, a share of gate_mag:
    once a field sample right after a fused one is kept out, the field must be within
    mag_reentry_gate * gate_mag sigmas to be fused again, until it has passed that for 0.5 s
    (vqf's magMinUndisturbedTime) or reset_timeout after the last sample beyond gate_mag
    (1: no re-entry gate). Default 0.5: 1.5 sigma at [ins-wind]'s
    gate_mag 3 (PX4's), which a clean 3-D field sample passes 65 % of the time
    (:func:`windahrs.aid.mag.fuse_field`, docs/ROBUSTNESS.md section 10).

    Initial standard deviations: init_att rad (per axis), init_bias rad/s, init_v m/s,
    init_wind m/s, init_accel_bias m/s^2. init_yaw rad: the attitude's spread about the nav
    vertical instead of init_att's (at the start and wherever a reset sets the attitude's
    spread again; 0, the default: init_att's, except for [ins-wind] without a magnetometer,
    whose heading nothing measures at the start: pi, unknown, until the GNSS accelerations
    turn it), for a start whose heading nothing measures yet (docs/estimators.md,
    docs/RESULTS.md sections 15 and 16).

    Start and recovery. init_window s: without a given initial state, the attitude is
    initialised from the mean specific force over the first init_window seconds of IMU
    samples (rotated into the current body frame by the gyro, as VQF averages its first
    samples instead of trusting one): rotor vibration of several m/s^2 averages out over
    about a hundred samples, and a multirotor's attitude loop (about 1 Hz) over a second.
    Default 0, the first sample: 1 s was measured worse on BROAD's heading (trials 02 and
    15: 0.66 -> 1.24 and 0.78 -> 1.17 deg, cause not yet found) and no better on the ANSFL
    flights, where a start that far off is caught by the reset below. reset_timeout s: when
    the accelerometer's gravity direction ([mekf], [mekf-air], [ekf7], [ekf10]) has been more
    than 45 deg from the state's for this long, or the magnetometer's heading more than
    45 deg from it (the same filters, and [ins-wind] twice per run at most, its wind then
    restarted: :func:`windahrs.aid.mag.heading_reset`), the filter has lost it: the
    attitude is levelled to the specific force (and the gyro bias reset), or turned about
    the vertical onto the field's heading, its spread reopened, logged in
    ``Estimate.resets`` and warned about. A gate that trusts a wrong state must not lock the
    filter out for good, and an EKF update cannot turn a filter that is upside down
    (default 5 s, PX4 EKF2_NOAID_TOUT, the longest EKF2 dead-reckons before it resets to
    its aiding; 0: never). GNSS velocity kept out as long resets the INS to it
    (:mod:`windahrs.aid.gnss_vel`: velocity, attitude spread, biases, wind; the heading then
    turns to the next magnetometer sample). start_check (with accel_lowpass and
    reset_timeout > 0; the filters that fuse gravity): once accel_lowpass seconds have passed
    since the start, the plain mean of the specific force since then (VQF's start of its
    low-pass filters) is held against the state's gravity by the same test, and failing it
    the filter is levelled to it at once: the low-passed mean starts at one sample, which
    rotor vibration can turn by tens of degrees, and forgets it only over accel_lowpass,
    while the gyro bias takes up the drift (default True; measured: ANSFL quadrotor tilt,
    aligned on vqf, path_6 29.9 -> 22.6 deg, path_7 9.3 -> 6.8, path_11 7.9 -> 6.9, the other
    13 flights, BROAD and the simulated flights unchanged; docs/RESULTS.md section 23).
    gated_start (with start_check; the error-state filters): a start sample that the gravity
    gate rejects (its length off gravity by more than accel_norm_gate) is no reading of
    gravity to start from, yet the mean starts at it and holds it for seconds (ANSFL path_6:
    0.46 g under rotor vibration, 37 deg from its first second's mean, [mekf] 50 deg off for
    3 s). After such a start the gravity aid fuses each sample rather than the mean for the
    first second (the state takes their plain mean, VQF's start of its low-pass), the start
    check restarts the mean from the plain one (VQF's low-pass state at accel_lowpass), and
    for 2 accel_lowpass the update leaves the gyro bias as it is (a considered state, the
    Schmidt-Kalman update): the state starts off by the sample's error, and its correction
    is no drift (taken for one, the start's error turned into a gyro bias that held the tilt
    off for tens of seconds; VQF clips its bias correction for the same reason, biasClip).
    A start within the gate (BROAD, PX4 sample.ulg, the simulated flights) is unchanged.
    Default True; measured: ANSFL quadrotor tilt, aligned on vqf, median 4.457 -> 4.333 deg
    on the even flights that chose it, 6.204 -> 4.850 on the odd ones, path_6 22.6 -> 9.3;
    BROAD, PX4 and the simulated flights unchanged (:mod:`windahrs.aid.gravity`,
    GATED_START_SAMPLES_S, GATED_START_BIAS_TAUS).

    Held samples. unmeasured_motion_dt s: an IMU step longer than this is taken to hold a
    point sample over motion it did not measure, and adds the noise of that to the
    prediction: per body axis ``(dw dt)^2 / 3`` on the attitude and ``(df dt)^2 / 3`` on the
    INS velocity, with dw, df the changes of the gyro and accelerometer samples since the
    previous ones (the change happened at an unmeasured instant of the step, uniformly
    distributed; :func:`windahrs.core.predict.held_sample_variance`). It needs no assumed
    angular acceleration or jerk: the flight's own samples give it, step by step, and it
    vanishes for a vehicle at rest. Default 1/50 s: autopilot logs at 50 Hz or more carry
    means over the interval (PX4 and ArduPilot integrate their IMUs at >= 1 kHz into delta
    angles and velocities, and EKF2 predicts every 10 ms), which the densities above
    model, while slower streams are telemetry point samples (MAVLink RAW_IMU/SCALED_IMU,
    ROS/mavros ``imu/data_raw``, streamed at 50 Hz at most); a gap in a fast stream is
    such a step too. 0: every step (point samples at any rate); a value above every step
    (e.g. 1e9): never ([mekf], [mekf-air], [ins-wind], [ekf7], [ekf10]).

    Covariance period ([ins-wind]). cov_period s: the nominal state is propagated at every
    IMU sample and the covariance once over the samples of each period (their summed step at
    their mean rate and specific force, with the attitude they end at), as PX4 EKF2 predicts
    at its filter update period (``EKF2_PREDICT_US``, default 10 000 us, taken from 1 000 to
    20 000). [ins-wind]'s default 0.01 s (the field's: 0, every sample's): a 200 Hz IMU's
    covariance at 100 Hz, a 100 Hz one's at every sample as before; it changes the attitude
    of the simulated 8 m/s flights by at most 3.4e-5 rad (docs/RESULTS.md section 46).
    Anything that reads or changes the covariance (an update, a reset, the record) has it
    brought up to date first. 0: every sample's.
    Not with the drag aid ([ins-drag], ``drag=true``: its update reads the covariance at every
    sample), nor in the smoothers (their backward pass recomputes each sample's prior).

    IMU screen (:mod:`windahrs.core.imu_screen`; the same filters): a sample is held, and
    the last propagated one propagated in its place, when an axis is beyond gyro_range rad/s
    or accel_range m/s^2 (defaults: the ranges beyond which the readers' edge repair sets a
    sample to NaN, :data:`windahrs.repair.GYRO_RANGE` and :data:`windahrs.repair.ACCEL_RANGE`,
    the widest full scales of autopilot IMUs plus 10 %), or when its change since the last propagated sample exceeds
    imu_spike_gate times the root mean square of the recent changes (default 8: Gaussian
    noise never gets there, a sinusoidal vibration reaches 1.4; 0: no spike test) and the
    next sample does not confirm it as motion. Held samples are logged in
    ``Estimate.alerts["imu"]``.

    Rest (:mod:`windahrs.aid.rest`; [mekf], [mekf-air], [ins-wind], [ekf7], [ekf10]):
    rest_detection ("on", "off", "start": until the first motion after a rest, "align": until
    the first motion, or "auto": on without a heading aid, in the error-state filters that
    fuse gravity, where it is the only measurement of the vertical gyro bias; "align" in the
    INS, its stationary alignment, unless its start is given; else off)
    fuses, while the vehicle is at rest, the low-passed angular rate as the gyro bias (the
    INS: the low-passed specific force as gravity instead): every
    sample within rest_gyro_threshold rad/s
    and rest_accel_threshold m/s^2 of its rest_tau s low-pass, the mean rate within
    rest_bias_clip rad/s, and the mean rate steady (within the rest gate, gate_accel) for
    rest_min_time s; rest_bias_sigma rad/s, the measurement's
    spread. Defaults: VQF's restThGyr 2 deg/s, restThAcc 0.5 m/s^2, restFilterTau 0.5 s,
    restMinT 1.5 s, biasSigmaRest 0.03 deg/s, biasClip 2 deg/s.
    """

    gyro_noise: float = 0.01 * DEG
    gyro_bias_noise: float = 2e-5
    accel_noise: float = 2e-3 * G0
    accel_noise_measured: bool = True
    accel_bias_noise: float = 1e-4
    wind_noise: float = 0.5
    wind_noise_vertical: float = 0.3
    wind_vertical: bool = True
    accel_sigma: float = 0.5
    accel_norm_gate: float = 0.15
    accel_compensation: Literal["none", "gnss", "airspeed"] = "none"
    accel_lowpass: float = 0.0
    accel_fuse_rate: float = 0.0
    lowpass_bias: bool = False
    gyro_scale_noise: float = 0.0
    gyro_bias_noise_vertical: float = 0.0
    mag_mode: Literal["3d", "heading", "off"] = "3d"
    mag_sigma: float = 1.5e-6
    mag_3d_needs_site: bool = False
    heading_model: Literal["yaw", "vertical"] = "yaw"
    mag_lowpass: float = 0.0
    mag_fuse_rate: float = 0.0
    mag_norm_gate: float = 0.0
    mag_dip_gate: float = 0.0
    gnss_sigma: float = 0.2
    gnss_timing_sigma: float = 0.0
    air_mode: Literal["auto", "vector", "airspeed", "off"] = "auto"
    tas_sigma: float = 0.5
    vane_sigma: float = 1.0 * DEG
    sideslip_sigma: float = 0.3
    synthetic_sideslip: bool = True
    airspeed_scale: bool = False
    airspeed_scale_sigma: float = 0.3
    airspeed_scale_noise: float = 1e-4
    airspeed_scale_wind_noise: float = 0.5
    airspeed_scale_tas_sigma: float = 1.4
    airspeed_scale_beta_sigma: float = 0.15
    gate_accel: float = 5.0
    gate_mag: float = 5.0
    gate_gnss: float = 5.0
    gate_air: float = 5.0
    mag_reentry_gate: float = 0.5
    init_att: float = 10.0 * DEG
    init_yaw: float = 0.0
    init_bias: float = 0.5 * DEG
    init_v: float = 1.0
    init_wind: float = 5.0
    init_accel_bias: float = 0.05
    init_mag_bias: float = 0.0
    mag_bias_noise: float = 1e-8
    drag: bool = False
    drag_mcoef: float = 0.15
    drag_bcoef_x: float = 100.0
    drag_bcoef_y: float = 100.0
    drag_sigma: float = math.sqrt(2.5)
    gate_drag: float = 5.0
    air_density: float = 1.225
    init_window: float = 0.0
    accel_noise_online: bool = False
    accel_noise_mean_start: bool = True
    reset_timeout: float = 5.0
    start_check: bool = True
    gated_start: bool = True
    unmeasured_motion_dt: float = 1.0 / 50.0
    cov_period: float = 0.0
    gyro_range: float = GYRO_RANGE
    accel_range: float = ACCEL_RANGE
    imu_spike_gate: float = 8.0
    rest_detection: Literal["auto", "on", "off", "start", "align"] = "auto"
    rest_gyro_threshold: float = 2.0 * DEG
    rest_accel_threshold: float = 0.5
    rest_tau: float = 0.5
    rest_min_time: float = 1.5
    rest_bias_sigma: float = 0.03 * DEG
    rest_bias_clip: float = 2.0 * DEG

    def __post_init__(self) -> None:
        choices = {
            "accel_compensation": ("none", "gnss", "airspeed"),
            "mag_mode": ("3d", "heading", "off"),
            "heading_model": ("yaw", "vertical"),
            "air_mode": ("auto", "vector", "airspeed", "off"),
            "rest_detection": ("auto", "on", "off", "start", "align"),
        }
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name in choices:
                if v not in choices[f.name]:
                    raise ValueError(f"{f.name}: expected one of {choices[f.name]}, found {v!r}")
            elif f.type in ("bool", bool):  # refused, not coerced: 2 or "yes" is no flag
                if not isinstance(v, bool):
                    raise ValueError(f"{f.name}: expected true or false, found {v!r}")
            else:
                check_magnitude(f.name, v)
        for name in ("gyro_noise", "mag_sigma", "gnss_sigma", "tas_sigma", "vane_sigma", "accel_sigma", "drag_sigma"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name}: expected > 0, found {getattr(self, name)!r}")
        for name in ("init_att", "init_bias", "init_v", "init_wind", "init_accel_bias", "airspeed_scale_sigma",
                     "rest_tau",
                     "airspeed_scale_tas_sigma", "airspeed_scale_beta_sigma"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name}: expected > 0, found {getattr(self, name)!r}")

    def replace(self, **changes: Any) -> EskfParams:
        return dataclasses.replace(self, **changes)


#: What a flight may declare about its own sensors (a ``Flight.meta`` key its reader sets)
#: -> the field it sets when the estimator's parameters leave that field at its default:
#: ``gnss.timing_sigma_s``, the uncertainty of the GNSS stream's time stamps against the
#: IMU's, s (a reader of two devices logging on separate clocks knows the stamps disagree,
#: not by how much).
FLIGHT_PARAMS: dict[str, str] = {"gnss.timing_sigma_s": "gnss_timing_sigma"}


@functools.cache
def _defaults() -> EskfParams:
    """EskfParams() built and validated once (every run asks which fields are defaults)."""
    return EskfParams()


def flight_params(params: EskfParams, meta: Mapping[str, Any], used: frozenset[str] | None = None) -> EskfParams:
    """``params`` with the fields a flight's ``meta`` declares (:data:`FLIGHT_PARAMS`),
    each where the parameters leave it at its default and (``used``) the estimator uses it;
    a value set explicitly wins. ValueError naming the meta key for a bad value."""
    changes: dict[str, Any] = {}
    default = _defaults()
    for key, name in FLIGHT_PARAMS.items():
        if key not in meta or (used is not None and name not in used):
            continue
        if getattr(params, name) != getattr(default, name):
            continue
        value = meta[key]
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
            raise ValueError(f"flight meta[{key!r}]: expected a finite number >= 0, found {value!r}")
        changes[name] = float(value)
    return params.replace(**changes) if changes else params


def _dens(dt: float) -> Callable[[float], float]:
    return lambda v: v * math.sqrt(dt)


#: PX4 EKF2 parameter -> (our field, conversion).
PX4_MAP: dict[str, tuple[str, Callable[[float], float]]] = {
    "EKF2_GYR_NOISE": ("gyro_noise", _dens(_PX4_DT)),
    "EKF2_GYR_B_NOISE": ("gyro_bias_noise", _dens(_PX4_DT)),
    "EKF2_ACC_NOISE": ("accel_noise", _dens(_PX4_DT)),
    "EKF2_ACC_B_NOISE": ("accel_bias_noise", _dens(_PX4_DT)),
    "EKF2_WIND_NSD": ("wind_noise", float),
    "EKF2_MAG_NOISE": ("mag_sigma", lambda v: v * 1e-4),  # gauss -> tesla
    "EKF2_MAG_GATE": ("gate_mag", float),
    "EKF2_MAG_B_NOISE": ("mag_bias_noise", lambda v: v * 1e-4 * math.sqrt(_PX4_DT)),  # gauss/s
    "EKF2_GPS_V_NOISE": ("gnss_sigma", float),
    "EKF2_PREDICT_US": ("cov_period", lambda v: v * 1e-6),  # us
    "EKF2_GPS_V_GATE": ("gate_gnss", float),
    "EKF2_EAS_NOISE": ("tas_sigma", float),
    "EKF2_TAS_GATE": ("gate_air", float),
    "EKF2_BETA_NOISE": ("sideslip_sigma", float),
    "EKF2_GRAV_NOISE": ("accel_sigma", lambda v: v * G0),  # in g
    "EKF2_MCOEF": ("drag_mcoef", float),
    "EKF2_BCOEF_X": ("drag_bcoef_x", float),
    "EKF2_BCOEF_Y": ("drag_bcoef_y", float),
    "EKF2_DRAG_NOISE": ("drag_sigma", math.sqrt),  # a variance, (m/s^2)^2
    # the airspeed selector's wind estimator (windahrs.aid.airspeed_scale)
    "ASPD_SCALE_NSD": ("airspeed_scale_noise", float),
    "ASPD_WIND_NSD": ("airspeed_scale_wind_noise", float),
    "ASPD_TAS_NOISE": ("airspeed_scale_tas_sigma", float),
    "ASPD_BETA_NOISE": ("airspeed_scale_beta_sigma", float),
}

#: ArduPilot EKF3 parameter -> (our field, conversion). Gates are in percent of sigma.
ARDUPILOT_MAP: dict[str, tuple[str, Callable[[float], float]]] = {
    "EK3_GYRO_P_NSE": ("gyro_noise", _dens(_AP_DT)),
    "EK3_GBIAS_P_NSE": ("gyro_bias_noise", _dens(_AP_DT)),
    "EK3_ACC_P_NSE": ("accel_noise", _dens(_AP_DT)),
    "EK3_ABIAS_P_NSE": ("accel_bias_noise", _dens(_AP_DT)),
    "EK3_WIND_P_NSE": ("wind_noise", float),
    "EK3_MAG_M_NSE": ("mag_sigma", lambda v: v * 1e-4),
    "EK3_MAG_I_GATE": ("gate_mag", lambda v: v / 100.0),
    "EK3_MAGB_P_NSE": ("mag_bias_noise", lambda v: v * 1e-4 * math.sqrt(_AP_DT)),  # gauss/s
    "EK3_VELNE_M_NSE": ("gnss_sigma", float),
    "EK3_VEL_I_GATE": ("gate_gnss", lambda v: v / 100.0),
    "EK3_EAS_M_NSE": ("tas_sigma", float),
    "EK3_EAS_I_GATE": ("gate_air", lambda v: v / 100.0),
}


def from_mapping(
    base: EskfParams,
    data: Mapping[str, Any],
    where: str = "params",
    *,
    allowed: frozenset[str] | None = None,
    filter_name: str = "",
) -> EskfParams:
    """Apply a ``{table: {key: value}}`` mapping (the TOML layout) to ``base``.

    ``allowed``: the fields the estimator uses (None: all). Our names outside it are
    refused, naming the filter; PX4 and ArduPilot names that map outside it are skipped
    with a warning (a PX4 or ArduPilot parameter file sets far more than one estimator
    uses)."""
    changes = changes_from_mapping(data, where, allowed=allowed, filter_name=filter_name)
    try:
        return base.replace(**changes)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def changes_from_mapping(
    data: Mapping[str, Any],
    where: str = "params",
    *,
    allowed: frozenset[str] | None = None,
    filter_name: str = "",
) -> dict[str, Any]:
    """The fields a ``{table: {key: value}}`` mapping (the TOML layout) sets, in our names
    and units: field -> value (checked as :func:`from_mapping` does, values not yet
    validated by :class:`EskfParams`)."""
    every = {f.name for f in dataclasses.fields(EskfParams)}
    fields = every if allowed is None else set(allowed)
    changes: dict[str, Any] = {}
    skipped: list[str] = []
    for table, entries in data.items():
        if table not in ("windahrs", "px4", "ardupilot"):
            raise ValueError(f"{where}: expected tables [windahrs], [px4] or [ardupilot], found [{table}]")
        if not isinstance(entries, Mapping):
            raise ValueError(f"{where}: [{table}] must be a table, found {type(entries).__name__}")
        for key, value in entries.items():
            if table == "windahrs":
                if key not in fields:
                    what = f"filter {filter_name!r} does not use" if key in every else "unknown"
                    raise ValueError(f"{where}: {what} parameter {key!r}; known: {', '.join(sorted(fields))}")
                changes[key] = value
            else:
                mapping = PX4_MAP if table == "px4" else ARDUPILOT_MAP
                if key not in mapping:
                    raise ValueError(
                        f"{where}: [{table}] {key!r} has no windahrs equivalent; mapped: {', '.join(mapping)}"
                    )
                name, conv = mapping[key]
                if not isinstance(value, int | float) or isinstance(value, bool):
                    raise ValueError(f"{where}: [{table}] {key}: expected a number, found {value!r}")
                try:
                    check_magnitude(key, value, owner=f"[{table}]")
                except ValueError as exc:
                    raise ValueError(f"{where}: {exc}") from None
                if name not in fields:
                    skipped.append(f"{key} ({name})")
                    continue
                changes[name] = conv(float(value))
    if skipped:
        warnings.warn(
            f"{where}: {filter_name or 'the filter'} does not use {', '.join(skipped)}; skipped", stacklevel=4
        )
    return changes


def load_params(
    path: str | Path,
    base: EskfParams | None = None,
    *,
    allowed: frozenset[str] | None = None,
    filter_name: str = "",
) -> EskfParams:
    """Read parameters from a TOML file (layout in the module docstring); ``allowed`` and
    ``filter_name`` as in :func:`from_mapping`."""
    p = Path(path)
    data = read_param_file(p)
    return from_mapping(base or EskfParams(), data, where=str(p), allowed=allowed, filter_name=filter_name)


def read_param_file(path: str | Path) -> dict[str, Any]:
    """The tables of a TOML parameter file; ValueError naming the file when it is missing
    or not valid TOML (every estimator's parameter loader reads through this)."""
    text = str(path)
    p = Path(path)
    if not text:
        raise ValueError("parameter file: expected a path, found ''")
    if p.is_dir():
        raise ValueError(f"{p}: is a directory, expected a TOML parameter file")
    if p.exists() and not p.is_file():  # reading a FIFO would wait forever
        raise ValueError(f"{p}: not a regular file (a device, FIFO or socket), expected a TOML parameter file")
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"{p}: no such parameter file") from None
    except NotADirectoryError:
        raise ValueError(f"{p}: no such parameter file (a part of its path is a file)") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{p}: not valid TOML (not UTF-8 text: {exc.reason} at byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{p}: not valid TOML ({exc})") from None
    except OSError as exc:
        raise ValueError(f"{p}: cannot read the parameter file ({exc.strerror or exc})") from None


#: Below this IMU rate (Hz) a stream is taken to hold point samples (unmeasured_motion_dt
#: = 1 / LOW_IMU_RATE_HZ) and the CLI says so (imu_rate_warning).
LOW_IMU_RATE_HZ = 50.0


def imu_rate_warning(t_imu: Any) -> str | None:
    """A note when the IMU times ``t_imu`` (N,) s run below :data:`LOW_IMU_RATE_HZ`.

    Such a stream is telemetry (MAVLink RAW_IMU/SCALED_IMU, ROS/mavros ``imu/data_raw``):
    point samples, each held by the prediction over motion it did not measure. The filters
    on the compiled core add that motion's noise by themselves, from the sample-to-sample
    changes (``unmeasured_motion_dt``, docs/estimators.md "Low-rate IMUs"); the note says
    so, and that the attitude will be coarser than from a >= 100 Hz IMU."""
    import numpy as np

    t = np.asarray(t_imu, dtype=np.float64)
    if t.size < 2:
        return None
    rate = 1.0 / float(np.median(np.diff(t)))
    if rate >= LOW_IMU_RATE_HZ:
        return None
    return (
        f"the IMU runs at {rate:.3g} Hz: its samples are taken as point samples held over motion they did not "
        f"measure, and mekf, mekf-air, ins-wind, ekf7 and ekf10 add that motion's noise from the sample-to-sample "
        f"changes (unmeasured_motion_dt; do not also raise gyro_noise and accel_noise for the rate); expect a "
        f"coarser attitude than from a >= 100 Hz IMU (docs/estimators.md, 'Low-rate IMUs')"
    )


def matched_to(suite: Any, base: EskfParams | None = None) -> EskfParams:
    """Parameters equal to a simulator SensorSuite's noise (for consistency studies).

    The simulated sensors have white noise, no gyro scale-factor error and an undisturbed
    field: the filter then fuses raw samples (accel_lowpass = mag_lowpass = 0, whose means
    are correlated from sample to sample), adds no rate-proportional process noise
    (gyro_scale_noise = 0), a gyro-bias walk alike about every axis
    (gyro_bias_noise_vertical = 0) and has no magnetic disturbance checks (mag_norm_gate =
    mag_dip_gate = 0, mag_3d_needs_site off; the field's innovation gate at least 5 sigma, as
    the other sensors': [ins-wind]'s 3 is for slowly turning disturbances, and on a consistent
    filter it rejects about 0.8 % of good 3-axis samples) and takes the INS input's density as given, not
    measured (accel_noise_measured off: the measure also holds the motion's own sample-to-sample
    changes). heading_model is kept (it matters only with mag_mode "heading")."""
    b = base or EskfParams()
    ch: dict[str, Any] = {
        "accel_lowpass": 0.0,
        "accel_noise_measured": False,
        "mag_lowpass": 0.0,
        "gyro_scale_noise": 0.0,
        "mag_norm_gate": 0.0,
        "mag_dip_gate": 0.0,
        "mag_3d_needs_site": False,
        "gate_mag": max(b.gate_mag, 5.0),
        "gyro_noise": max(suite.gyro.noise_density, 1e-12),
        "gyro_bias_noise": suite.gyro.bias_rw,
        "gyro_bias_noise_vertical": 0.0,  # (the simulated bias walks alike about every axis)
        "accel_noise": max(suite.accel.noise_density, 1e-12),
        "init_bias": max(suite.gyro.bias_init_sigma, 1e-9),
        "accel_bias_noise": max(suite.accel.bias_rw, 1e-9),
        "init_accel_bias": max(suite.accel.bias_init_sigma, 1e-9),
    }
    dt = 1.0 / suite.imu_rate
    ch["accel_sigma"] = max(suite.accel.noise_density / math.sqrt(dt), 1e-9)
    if suite.mag is not None:
        if suite.mag.hard_iron == 0:
            ch.update(mag_sigma=max(suite.mag.noise, 1e-12), init_mag_bias=0.0)
        elif b.init_mag_bias > 0 and b.mag_mode == "3d":
            # the hard iron is a state: a constant of known spread
            ch.update(mag_sigma=max(suite.mag.noise, 1e-12), init_mag_bias=suite.mag.hard_iron, mag_bias_noise=0.0)
        else:
            ch["mag_sigma"] = max(math.hypot(suite.mag.noise, suite.mag.hard_iron), 1e-12)
    if suite.gnss is not None:
        ch["gnss_sigma"] = max(suite.gnss.noise, 1e-9)
    if suite.pitot is not None:
        ch["tas_sigma"] = max(suite.pitot.noise, 1e-9)
    if suite.vanes is not None:
        ch["vane_sigma"] = max(suite.vanes.noise, 1e-9)
    return b.replace(**ch)
