"""Aid source: the magnetometer, in 3-D or as heading only (SPEC 3.3).

* 3-D: ``h = C_bn m_n (+ b_m)``, ``H_att = [h]x`` (and ``I`` on the hard-iron states when
  the layout carries them), R = mag_sigma^2 I.
* Heading, "yaw" model: the tilt-compensated heading against the ZYX yaw,
  ``H = [0, sin r, cos r] / cos p`` (singular at pitch +-90 deg).
* Heading, "vertical" model: the heading of the nav-frame field ``C_nb m`` against the
  reference's, corrected about the nav vertical only, ``H_att = (C_bn e_3)^T``.

The reference field ``m_n`` is the site's, or (site unknown) the first sample's with its
horizontal part taken as north. Preprocessing: an optional low-pass of the field in the
gyro-compensated frame (mag_lowpass, VQF's tau_mag). Gates: norm and dip disturbance checks
(mag_norm_gate, mag_dip_gate; a rejected sample logs NaN), then the innovation (gate_mag).
Innovation key: ``"mag"`` (3 rows in 3-D, 1 for heading).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from windahrs.core.kalman import (
    _bias_rows,
    _fuse,
    _log,
    _vector_rows,
    att_var_along,
    lag_age,
    lag_bias_rows,
    per_sample_nis,
    samples_to_fuse,
    within_gate,
)
from windahrs.core.layout import (
    _JIT_CORE,
    ADD_COV,
    ADD_NONE,
    INN_MAG,
    KIND_INS,
    MAG_3D,
    MAG_OFF,
    S_HEADLESS,
    S_MAGN,
    S_MBAR,
    S_NHRESET,
    S_WPEND,
    W_H,
    W_NU,
    W_R,
    W_S,
    X_BM,
    X_HSEEN,
    X_JMAG,
    X_MAGN,
    X_MBAR,
    X_MGAIN,
    X_NMFUSE,
    X_Q,
    X_TMBAR,
    X_TMFUSE,
    X_TMOK,
    X_TMPASS,
    X_TMREIN,
    X_TOK,
)
from windahrs.core.predict import (
    steady_gain,
)
from windahrs.core.quat import (
    _dcm9,
    _euler,
    _qmul,
    _qnormalize,
    _quat_from_euler,
    _wrap_pi,
)
from windahrs.core.reset import accepted_at, log_reset, reopen, set_attitude_cov, timed_out

#: The parameters of this aid source (fields of :class:`windahrs.filters.params.EskfParams`).
PARAMS = (
    "mag_mode",
    "mag_sigma",
    "mag_3d_needs_site",
    "heading_model",
    "mag_lowpass",
    "mag_norm_gate",
    "mag_dip_gate",
    "gate_mag",
    "mag_reentry_gate",
    "reset_timeout",
)
#: A heading further than this (rad) from the field's has lost it: a magnetic disturbance
#: that the norm and dip checks let through bends the field by far less (45 deg, as the
#: gravity aid source's tilt, :data:`windahrs.aid.gravity.LOST_COS`).
LOST_HEADING = math.radians(45.0)
COS_LOST_HEADING = math.cos(LOST_HEADING)
#: How many times an INS turns its heading to the magnetometer in one run, by the reset below
#: (:func:`heading_reset`) or after a GNSS reset (:mod:`windahrs.aid.gnss_vel`), together:
#: PX4 EKF2's in-flight budget of magnetometer resets when its mag fusion has failed for
#: reset_timeout_max (``_nb_mag_3d_reset_available = 2``, mag_control.cpp), after which a
#: field that still disagrees is only gated: a magnetometer that is itself wrong cannot turn
#: a heading GNSS keeps right more than twice.
INS_HEADING_RESETS = 2

#: ... and of its hard-iron states (error-state filters only).
BIAS_PARAMS = ("init_mag_bias", "mag_bias_noise")
#: ... and the low-passed field fused at a lower rate (the error-state filters:
#: windahrs.core.kalman.samples_to_fuse).
FUSE_RATE_PARAMS = ("mag_fuse_rate",)


@njit(**_JIT_CORE)
def _set_mag_reference(cfg, prm, x, flags, mx, my, mz):
    """The reference field m_n: the site's field, or the sample's with its horizontal part
    at the site's declination (magnetic north when it is unknown: prm["site_decl"] 0)."""
    if cfg["site_mag_known"] == 1:
        for a in range(3):
            x[X_MAGN + a] = prm["site_mag"][a]
    else:
        c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
        m0 = c[0] * mx + c[1] * my + c[2] * mz
        m1 = c[3] * mx + c[4] * my + c[5] * mz
        m2 = c[6] * mx + c[7] * my + c[8] * mz
        h = math.hypot(m0, m1)
        x[X_MAGN] = h * math.cos(prm["site_decl"])
        x[X_MAGN + 1] = h * math.sin(prm["site_decl"])
        x[X_MAGN + 2] = m2
    flags[S_MAGN] = 1


@njit(**_JIT_CORE)
def _mag_disturbed(prm, x, cfg, mx, my, mz, rx, ry, rz):
    """The disturbance checks: the field to be fused fails the norm or dip check."""
    if cfg["i_bm"] >= 0:
        mx, my, mz = mx - x[X_BM], my - x[X_BM + 1], mz - x[X_BM + 2]
    r_norm = math.sqrt(rx * rx + ry * ry + rz * rz)
    ng = prm["mag_norm_gate"]
    if ng > 0 and abs(math.sqrt(mx * mx + my * my + mz * mz) - r_norm) > ng * r_norm:
        return True
    dg = prm["mag_dip_gate"]
    if dg > 0:
        c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
        n0 = c[0] * mx + c[1] * my + c[2] * mz
        n1 = c[3] * mx + c[4] * my + c[5] * mz
        n2 = c[6] * mx + c[7] * my + c[8] * mz
        # |dip - dip_ref| > dg: the angle between (horizontal, down) of the two fields, both
        # in the half-plane of a horizontal part >= 0, is the difference of their dips, so
        # the test is on its cosine (two square roots where two atan2 and two hypot were)
        hm, hr = math.sqrt(n0 * n0 + n1 * n1), math.sqrt(rx * rx + ry * ry)
        if hm * hr + n2 * rz < math.cos(dg) * math.sqrt((hm * hm + n2 * n2) * (hr * hr + rz * rz)):
            return True
    return False


@njit(inline="always", **_JIT_CORE)
def mag_reference(cfg, prm, x, flags, mx, my, mz):
    """The nav-frame reference field (set from this sample on first use): (rx, ry, rz) T."""
    if flags[S_MAGN] == 0:
        _set_mag_reference(cfg, prm, x, flags, mx, my, mz)
    return x[X_MAGN], x[X_MAGN + 1], x[X_MAGN + 2]


@njit(inline="always", **_JIT_CORE)
def measured_heading(roll, pitch, mx, my, mz, rx, ry):
    """The heading (ZYX yaw, rad) that the field sample m (body) gives against the
    reference's horizontal direction, tilt-compensated with the estimate's roll and pitch."""
    ql = _quat_from_euler(roll, pitch, 0.0)
    c = _dcm9(ql[0], ql[1], ql[2], ql[3])
    m0 = c[0] * mx + c[1] * my + c[2] * mz
    m1 = c[3] * mx + c[4] * my + c[5] * mz
    return math.atan2(ry, rx) - math.atan2(m1, m0)


@njit(inline="always", **_JIT_CORE)
def fuse_mag(cfg, prm, x, flags, P, work, sup, inn, acc, t, row):
    """A magnetometer sample (finite) of an initialised filter: row[:3] tesla, body, at t s."""
    mx, my, mz = row[0], row[1], row[2]
    mode = cfg["mag_mode"]
    if mode == MAG_OFF:
        return
    rx, ry, rz = mag_reference(cfg, prm, x, flags, mx, my, mz)
    if flags[S_HEADLESS] == 1:  # started without it (core.kernel.MAG_WAIT), or reset (aid.gnss_vel): its heading now
        flags[S_HEADLESS] = 0
        if cfg["site_mag_known"] == 1:  # (else the reference was just taken from this sample)
            x[X_TOK + INN_MAG] = np.nan  # logged as out for NaN s: absent, not rejected
            _reset_heading(cfg, prm, x, flags, inn, acc, P, work, t, _heading_offset(cfg, x, mx, my, mz, rx, ry))
            if cfg["kind"] != KIND_INS:  # (an INS's GNSS saw its heading; its GNSS reset restarts the wind)
                _restart_heading_tied(cfg, prm, flags, P)
        return
    nu = work[W_NU]
    dtm = 0.0  # the mean's last sample interval, s
    if prm["mag_lowpass"] > 0:  # fuse the low-passed field
        if flags[S_MBAR] == 0:
            x[X_MBAR], x[X_MBAR + 1], x[X_MBAR + 2] = mx, my, mz
            lag_age(x, np.int64(X_JMAG), 1.0)
            flags[S_MBAR] = 1
        else:
            dtm = t - x[X_TMBAR]
            a = steady_gain(x, np.int64(X_MGAIN), dtm, prm["mag_lowpass"])
            x[X_MBAR] = x[X_MBAR] + a * (mx - x[X_MBAR])
            x[X_MBAR + 1] = x[X_MBAR + 1] + a * (my - x[X_MBAR + 1])
            x[X_MBAR + 2] = x[X_MBAR + 2] + a * (mz - x[X_MBAR + 2])
            if prm["lowpass_bias"] > 0:
                lag_age(x, np.int64(X_JMAG), a)
        x[X_TMBAR] = t
        mx, my, mz = x[X_MBAR], x[X_MBAR + 1], x[X_MBAR + 2]
    sensor = np.int64(INN_MAG)
    if (prm["mag_norm_gate"] > 0 or prm["mag_dip_gate"] > 0) and _mag_disturbed(prm, x, cfg, mx, my, mz, rx, ry, rz):
        nu[0], nu[1], nu[2] = np.nan, np.nan, np.nan
        md = np.int64(3) if mode == MAG_3D else np.int64(1)
        _log(cfg, flags, inn, acc, nu, sensor, t, md, np.nan, np.bool_(False))
        accepted_at(x, sensor, t)  # a disturbed field: the gate is not keeping it out
        _kept_out(prm, x, t, True)
        return
    if heading_reset(cfg, prm, x, flags, P, work, inn, acc, t, mx, my, mz, rx, ry):
        return
    kf = 1.0
    c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    if prm["mag_lowpass"] > 0 and cfg["add_form"] == ADD_NONE and prm["mag_fuse_dt"] > 0:  # the mean at mag_fuse_rate
        kf = mag_samples_to_fuse(cfg, prm, x, P, t, dtm, c, mx, my, mz, rx, ry)
        if kf == 0.0:  # (this sample is in the next fusion)
            return
    if mode == MAG_3D:
        y0 = c[0] * rx + c[3] * ry + c[6] * rz
        y1 = c[1] * rx + c[4] * ry + c[7] * rz
        y2 = c[2] * rx + c[5] * ry + c[8] * rz
        _vector_rows(work, sup[0], y0, y1, y2, prm["mag_var"] / kf)
        nsup = _mean_bias_rows(cfg, prm, x, flags, work, sup[0], np.int64(3), np.int64(3))
        h0, h1, h2 = y0, y1, y2
        ibm = cfg["i_bm"]
        if ibm >= 0:  # + bm, H_bm = I
            h0, h1, h2 = y0 + x[X_BM], y1 + x[X_BM + 1], y2 + x[X_BM + 2]
            nsup = _bias_rows(work, sup[0], ibm, nsup)
        nu[0], nu[1], nu[2] = mx - h0, my - h1, mz - h2
        m, ns = np.int64(3), np.int64(nsup)
        if fuse_field(cfg, prm, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, kf):
            x[X_TMOK] = t
        per_sample_nis(cfg, flags, inn, sensor, kf)
        return
    sigma = prm["mag_sigma"] / max(math.hypot(rx, ry), 1e-9)
    if cfg["heading_vertical"] == 1:
        # the field's heading in the nav frame against the reference's, corrected about
        # the nav vertical only: H_att = third row of C_nb
        n0 = c[0] * mx + c[1] * my + c[2] * mz
        n1 = c[3] * mx + c[4] * my + c[5] * mz
        nu[0] = _wrap_pi(math.atan2(ry, rx) - math.atan2(n1, n0))
        work[W_H, 0], work[W_H, 1], work[W_H, 2] = c[6], c[7], c[8]
        sup[0, 0], sup[0, 1], sup[0, 2] = 0, 1, 2
        work[W_R, 0] = sigma**2 / kf
        m, ns = np.int64(1), np.int64(3)
        fuse_field(cfg, prm, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, kf)
        per_sample_nis(cfg, flags, inn, sensor, kf)
        return
    # heading only (ZYX yaw): tilt-compensate with the current roll/pitch estimate
    roll, pitch, yaw = _euler(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    nu[0] = _wrap_pi(measured_heading(roll, pitch, mx, my, mz, rx, ry) - yaw)
    cp = math.cos(pitch)
    work[W_H, 0], work[W_H, 1], work[W_H, 2] = 0.0, math.sin(roll) / cp, math.cos(roll) / cp
    sup[0, 0], sup[0, 1], sup[0, 2] = 0, 1, 2
    work[W_R, 0] = sigma**2 / kf
    m, ns = np.int64(1), np.int64(3)
    fuse_field(cfg, prm, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, kf)
    per_sample_nis(cfg, flags, inn, sensor, kf)


#: How long, s, the field must pass the re-entry gate, with no sample beyond the full gate,
#: to release it (:func:`fuse_field`): vqf's magMinUndisturbedTime, the time its field must
#: stay within its thresholds before it is taken as undisturbed again.
REENTRY_CLEAR = 0.5


@njit(inline="always", **_JIT_CORE)
def _kept_out(prm, x, t, beyond_full):
    """Remember that a field sample at t s was kept out, beyond the full gate (or by the
    disturbance checks), or only by the re-entry gate (:func:`fuse_field`)."""
    if beyond_full:
        if x[X_TMPASS] == x[X_TMPASS] or t - x[X_TMREIN] <= prm["reset_timeout"]:
            x[X_TMREIN] = t
        x[X_TMPASS] = np.nan


@njit(inline="always", **_JIT_CORE)
def fuse_field(cfg, prm, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, kf):
    """_fuse with the magnetometer's gate, gate_mag^2 (times kf, the samples the mean stands
    for), or while it holds the re-entry gate's. Returns whether the sample was fused.

    The re-entry gate (EskfParams.mag_reentry_gate, a share of gate_mag) is a Schmitt trigger
    on the innovation. It arms when a field sample right after a fused one is kept out (by the
    disturbance checks, or beyond gate_mag sigma). The samples must then fall within the
    re-entry gate to be fused. It releases :data:`REENTRY_CLEAR` s after the first sample
    that does, if none has gone beyond the full gate since, as vqf takes a field it found
    disturbed as undisturbed again once it has stayed within its thresholds for
    magMinUndisturbedTime; or reset_timeout after the last sample beyond the full gate, which
    keeps a state that drifted while the field was out from being held off a field the full
    gate would take (the heading reset does not help there: the heading is not lost). Arming
    at once also keeps more of a disturbance's onset out, where its samples cross the gate
    back and forth; arming only after REENTRY_CLEAR s kept out, which spares a lone outlier,
    lost that (docs/ROBUSTNESS.md section 10).

    Why: a disturbance that fades slowly (a motor current, a swinging payload) re-enters the
    full gate while still off by nearly gate_mag sigma, and those last sigma turn the heading
    and the gyro bias. The fault matrix's mag-drift-30s, a 20 uT bump over 30 s, left the
    simulated quadrotor 5-7 deg off in heading after it had ended (docs/ROBUSTNESS.md
    sections 9 and 10). Default half the gate: 1.5 sigma at [ins-wind]'s gate_mag 3 (PX4's
    EKF2_MAG_GATE), which a clean 3-D sample passes 65 % of the time (each component 87 %);
    2.5 sigma (96 %) at the other filters' 5. A field not fused since the start or since the
    heading was reset to one of its samples (a magnetometer that starts late, the heading it
    gave not yet confirmed) does not arm it."""
    g2 = prm["gate_mag2"] * kf
    rein = t - x[X_TMREIN] <= prm["reset_timeout"]
    if _fuse(cfg, x, flags, P, work, sup, inn, acc, sensor, t, m, ns, prm["mag_reentry_gate2"] * kf if rein else g2):
        if x[X_TMPASS] != x[X_TMPASS]:  # (NaN: a new run of fused samples)
            x[X_TMPASS] = t
        if t - x[X_TMPASS] >= REENTRY_CLEAR:
            x[X_TMREIN] = -np.inf
        return True
    _kept_out(prm, x, t, not (rein and within_gate(work[W_NU], work[W_S : W_S + 3], m, g2)))
    return False


@njit(inline="always", **_JIT_CORE)
def mag_samples_to_fuse(cfg, prm, x, P, t, dtm, c, mx, my, mz, rx, ry):
    """How many magnetometer samples the low-passed field m (body) stands for, or 0 when it is
    not fused now (:func:`windahrs.core.kalman.samples_to_fuse`, at mag_fuse_rate; dtm: the
    mean's last sample interval, s; c: C_nb row-major). Its gain is small while the prior
    attitude variance it measures, times the field's length squared, is at most
    DECIMATE_PRIOR_SHARE of a sample's noise variance: in 3-D the attitude across the field
    (across m), as heading the attitude about the vertical, against (mag_sigma / |m_n,h|)^2."""
    if cfg["mag_mode"] == MAG_3D:
        mn2 = mx * mx + my * my + mz * mz
        mn = math.sqrt(mn2) if mn2 > 0 else 1.0
        across = P[0, 0] + P[1, 1] + P[2, 2] - att_var_along(P, mx / mn, my / mn, mz / mn)
        prior, noise = across * mn2, prm["mag_var"]
    else:
        prior = att_var_along(P, c[6], c[7], c[8])
        noise = (prm["mag_sigma"] / max(math.hypot(rx, ry), 1e-9)) ** 2
    return samples_to_fuse(x, np.int64(X_NMFUSE), np.int64(X_TMFUSE), t, prm["mag_fuse_dt"], 0.5 * dtm, prior, noise)


@njit(inline="always", **_JIT_CORE)
def _mean_bias_rows(cfg, prm, x, flags, work, sup, m, nsup):
    """With lowpass_bias, the low-passed field's gyro-bias columns (H_b = H_att J, J its
    bias sensitivity x[X_JMAG], :func:`windahrs.core.kalman.lag_bias_rows`) on the m rows
    just written; returns the support size. Called in 3-D fusion only, where the kernel
    keeps J (``core.kernel._rotate_lowpass``): on the heading-only model the columns took the
    field's changes from place to place into the vertical gyro bias (docs/RESULTS.md 18)."""
    ib = cfg["i_bg"]
    if flags[S_MBAR] == 1 and prm["lowpass_bias"] > 0 and ib >= 0 and cfg["add_form"] != ADD_COV:
        return lag_bias_rows(work, sup, x, np.int64(X_JMAG), ib, m, nsup)
    return nsup


@njit(inline="always", **_JIT_CORE)
def heading_reset(cfg, prm, x, flags, P, work, inn, acc, t, mx, my, mz, rx, ry):
    """The heading's reset clock at a field sample m (body) against the reference r: a
    heading within LOST_HEADING of the field's restarts it (accepted by the gate or not);
    one further off for reset_timeout (a field that passes the disturbance checks, which
    restart the clock too) is turned to the field's. In an INS at most INS_HEADING_RESETS
    times, and the states tied to the heading follow (:func:`_restart_heading_tied`): its GNSS
    velocity keeps whatever tilt an update makes consistent, but a heading held 45 deg off
    by its own confident covariance is never corrected by a field its gate rejects
    (simulated quadrotor in 8 m/s wind started 90 or 180 deg off in heading: 12 to 159 deg
    RMS for the whole flight before this reset, docs/RESULTS.md section 35). Returns whether
    it reset (the sample is then not fused)."""
    sensor = np.int64(INN_MAG)
    n0, n1 = _nav_horizontal(cfg, x, mx, my, mz)
    # |heading offset| < LOST_HEADING: the angle between the two horizontal fields, on its
    # cosine (the offset's two atan2 only for a reset)
    if rx * n0 + ry * n1 >= COS_LOST_HEADING * math.sqrt((rx * rx + ry * ry) * (n0 * n0 + n1 * n1)):
        accepted_at(x, sensor, t)  # the state still knows the heading, accepted or not
    elif timed_out(prm, x, sensor, t):
        ins = cfg["kind"] == KIND_INS
        if ins and (heading_seen_by_gnss(prm, x) or not spend_heading_reset(flags)):
            return False
        _reset_heading(cfg, prm, x, flags, inn, acc, P, work, t, _turn_to(rx, ry, n0, n1))
        if ins:
            if cfg["kind"] != KIND_INS:
                _restart_heading_tied(cfg, prm, flags, P)
        return True
    return False


@njit(inline="always", **_JIT_CORE)
def heading_seen_by_gnss(prm, x):
    """Whether GNSS has seen the INS's heading for reset_timeout since it was last turned
    (:func:`windahrs.aid.gnss_vel.watch_heading`): then a field that disagrees is the field's
    fault (a compass mounted or calibrated wrong), and the heading is not turned to it."""
    return x[X_HSEEN] >= prm["reset_timeout"]


@njit(inline="always", **_JIT_CORE)
def spend_heading_reset(flags):
    """Whether the INS may still take its heading from the field (INS_HEADING_RESETS per
    run, here and after a GNSS reset, aid.gnss_vel); counts the one it takes."""
    if flags[S_NHRESET] >= INS_HEADING_RESETS:
        return False
    flags[S_NHRESET] += 1
    return True


@njit(inline="always", **_JIT_CORE)
def _nav_horizontal(cfg, x, mx, my, mz):
    """The field sample m (body; less the hard iron when estimated) in the nav frame by the
    state's attitude: its north and east parts, T."""
    if cfg["i_bm"] >= 0:
        mx, my, mz = mx - x[X_BM], my - x[X_BM + 1], mz - x[X_BM + 2]
    c = _dcm9(x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    return c[0] * mx + c[1] * my + c[2] * mz, c[3] * mx + c[4] * my + c[5] * mz


@njit(inline="always", **_JIT_CORE)
def _turn_to(rx, ry, n0, n1):
    """The rotation about the nav vertical, rad, that turns the horizontal field (n0, n1)
    onto the reference's (rx, ry)."""
    return _wrap_pi(math.atan2(ry, rx) - math.atan2(n1, n0))


@njit(inline="always", **_JIT_CORE)
def _heading_offset(cfg, x, mx, my, mz, rx, ry):
    """The rotation about the nav vertical, rad, that turns the field sample m (body; less
    the hard iron when estimated) onto the reference's heading."""
    n0, n1 = _nav_horizontal(cfg, x, mx, my, mz)
    return _turn_to(rx, ry, n0, n1)


@njit(**_JIT_CORE)
def _reset_heading(cfg, prm, x, flags, inn, acc, P, work, t, d):
    """The field's heading d rad off the state's for reset_timeout: turn the attitude about
    the nav vertical by d, reopen the attitude's spread (PX4 EKF2 resets its yaw to the
    magnetometer likewise)."""
    h = 0.5 * d
    x[X_HSEEN] = 0.0  # (GNSS has not seen this heading yet)
    q = _qmul(math.cos(h), 0.0, 0.0, math.sin(h), x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3])
    x[X_Q], x[X_Q + 1], x[X_Q + 2], x[X_Q + 3] = _qnormalize(q[0], q[1], q[2], q[3])
    set_attitude_cov(cfg, prm, x, P, work)
    log_reset(cfg, flags, inn, acc, work, x, np.int64(INN_MAG), t, abs(d))
    x[X_TMPASS], x[X_TMREIN] = np.nan, -np.inf  # (a heading from one sample: no re-entry gate yet)


@njit(**_JIT_CORE)
def _restart_heading_tied(cfg, prm, flags, P):
    """After an INS's heading was turned to the field, or an attitude filter's was first
    taken from a magnetometer that started late: the wind, fitted to the air data through
    the wrong heading, restarts from the next air sample as at initialisation (turning the
    heading alone left the air data's innovations to tilt the attitude: on the ALFA flight,
    8 to 35 deg; and turned [mekf-air]'s heading straight back, 33 deg off, in the fault
    matrix's mag-late on the fixed wing, seed 1), and the hard iron's spread is reopened
    (PX4's resetMagStates resets the body field with the heading). The velocity stays: GNSS
    measures it, whatever the heading."""
    if cfg["i_w"] >= 0:
        reopen(cfg, P, cfg["i_w"], prm["init_wind_var"], prm["init_wind_vertical_var"])
        flags[S_WPEND] = 1
    if cfg["i_bm"] >= 0:
        reopen(cfg, P, cfg["i_bm"], prm["init_mag_bias_var"], prm["init_mag_bias_var"])
