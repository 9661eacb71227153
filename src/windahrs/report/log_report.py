"""The page of ``windahrs report``: several estimators on one flight or log, in one
self-contained HTML file.

Sections: what was run (estimators, those that could not run and why, the alignment);
the sensor streams (rates, gaps, missing samples, saturation); attitude RMSE against the
flight's truth or reference (:func:`windahrs.metrics.score`, the numbers ``windahrs
compare`` prints) with attitude and error plots; innovations and NIS per sensor; the
wind estimate against the log's own wind (or the simulation's). Every part says so when
it has nothing to show: a flight without truth or reference has no error panels, a log
without a wind estimate no wind comparison, an estimator without innovations or wind
states is listed as such.

Running the estimators and estimating the alignment are the caller's (the CLI's): this
module only turns their results into text.

    html = build_log_report(flight, [("mekf", est_mekf), ("vqf", est_vqf)],
                            alignment=estimate_alignment(est_mekf, flight), aligned_on="mekf")
    write_html("report.html", html)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from windahrs.core.layout import SENSOR_LABELS
from windahrs.estimate import Estimate
from windahrs.experiments.align import (  # the alignment's text lives beside it; re-exported
    ALIGN_RESIDUAL_DEG,
    Alignment,
    alignment_warning,
    apply_alignment,
    describe_alignment,
)
from windahrs.flags import flag_spans
from windahrs.flight import Flight
from windahrs.metrics import Score, attitude_errors, chi2_band, reference_of, score
from windahrs.repair import repairs_text
from windahrs.report.figures import spans_png, timeseries_png
from windahrs.report.html import Cell, Image, Section, Table, format_cell, render_html
from windahrs.rotation import euler_from_quat

__all__ = [
    "ALIGN_RESIDUAL_DEG",
    "GAP_FACTOR",
    "SATURATION_REPEATS",
    "StreamStats",
    "alignment_warning",
    "build_log_report",
    "describe_alignment",
    "reference_text",
    "stream_stats",
]

F64 = NDArray[np.float64]

#: A step longer than this many median steps counts as a gap.
GAP_FACTOR = 3.0
#: A channel is flagged as saturated when its largest |value| occurs in at least this many
#: samples: a clipped sensor sits at its full scale, a free signal touches its peak once.
SATURATION_REPEATS = 3

_REFERENCE_TEXT = {
    "truth": "the simulation truth",
    "mocap": "motion capture",
    "autopilot": "the autopilot's own estimate",
}

# name -> [(group label, unit, scale to that unit, columns)]; what the saturation check reads.
_CHANNELS: dict[str, list[tuple[str, str, float, tuple[str, ...]]]] = {
    "imu": [("gyro", "rad/s", 1.0, ("x", "y", "z")), ("accel", "m/s^2", 1.0, ("x", "y", "z"))],
    "mag": [("mag", "uT", 1e6, ("x", "y", "z"))],
    "gnss": [("velocity", "m/s", 1.0, ("N", "E", "D"))],
    "air": [("airspeed", "m/s", 1.0, ("",)), ("aoa", "rad", 1.0, ("",)), ("sideslip", "rad", 1.0, ("",))],
}



# ---------------------------------------------------------------------------------------
# sensor streams


@dataclass(frozen=True)
class StreamStats:
    """What a stream looks like. name; samples; rate_hz: 1 / median step; largest_gap_s:
    the longest step, s; gaps: steps longer than GAP_FACTOR median steps; nan_rows:
    samples with a NaN in any value; largest: text of the largest |value| per channel
    group (None for streams not checked); saturated: samples where some channel sits at
    its largest |value| and that value occurs SATURATION_REPEATS times or more (None: not
    checked); saturated_channels: which channels, with their value."""

    name: str
    samples: int
    rate_hz: float
    largest_gap_s: float
    gaps: int
    nan_rows: int
    largest: str | None = None
    saturated: int | None = None
    saturated_channels: str = ""


def _time_stats(t: F64) -> tuple[float, float, int]:
    if len(t) < 2:
        return math.nan, math.nan, 0
    dt = np.diff(t)
    med = float(np.median(dt))
    return 1.0 / med, float(dt.max()), int(np.count_nonzero(dt > GAP_FACTOR * med))


def _nan_rows(*arrays: F64 | None) -> int:
    present = [a.reshape(len(a), -1) for a in arrays if a is not None]
    if not present:
        return 0
    return int(np.count_nonzero(~np.isfinite(np.hstack(present)).all(axis=1)))


def _saturation(name: str, columns: list[F64]) -> tuple[str, int, str]:
    """(largest |value| per group, saturated samples, flagged channels) of one stream."""
    largest = []
    flagged = []
    at_extreme = np.zeros(len(columns[0]) if columns else 0, dtype=bool)
    for (group, unit, scale, axes), values in zip(_CHANNELS[name], columns, strict=True):
        a = np.abs(values)
        finite = np.isfinite(a)
        if not finite.any():
            largest.append(f"{group} –")
            continue
        peak = np.max(a, axis=0, where=finite, initial=0.0)
        largest.append(f"{group} {format_cell(float(peak.max()) * scale)} {unit}")
        for j, ax in enumerate(axes):
            hit = finite[:, j] & (a[:, j] >= peak[j] * (1.0 - 1e-9))
            if peak[j] > 0 and np.count_nonzero(hit) >= SATURATION_REPEATS:
                at_extreme |= hit
                label = f"{group} {ax}".strip()
                flagged.append(f"{label} at {format_cell(float(peak[j]) * scale)} {unit} x{np.count_nonzero(hit)}")
    return ", ".join(largest), int(np.count_nonzero(at_extreme)), "; ".join(flagged)


def stream_stats(flight: Flight) -> list[StreamStats]:
    """Sensor summary of a flight: every sensor stream present, then the reference and
    the log's wind when present (timing and NaN only; see :class:`StreamStats`)."""
    out = []
    sensors: dict[str, list[F64]] = {"imu": [flight.imu.w_b, flight.imu.f_b]}
    if flight.mag is not None:
        sensors["mag"] = [flight.mag.mag_b]
    if flight.gnss is not None:
        sensors["gnss"] = [flight.gnss.v_n]
    if flight.air is not None:
        air = flight.air
        nan = np.full(len(air.t), np.nan)
        aoa = air.aoa if air.aoa is not None else nan
        beta = air.sideslip if air.sideslip is not None else nan
        sensors["air"] = [air.tas[:, None], aoa[:, None], beta[:, None]]
    for name, columns in sensors.items():
        t = getattr(flight, name).t
        rate, gap, gaps = _time_stats(t)
        if name == "air" and flight.air is not None:
            nan_rows = _nan_rows(flight.air.tas, flight.air.aoa, flight.air.sideslip)
        else:
            nan_rows = _nan_rows(*columns)
        largest, sat, which = _saturation(name, columns)
        out.append(StreamStats(name, len(t), rate, gap, gaps, nan_rows, largest, sat, which))
    if flight.reference is not None:
        ref = flight.reference
        rate, gap, gaps = _time_stats(ref.t)
        out.append(StreamStats(f"reference ({ref.kind})", len(ref.t), rate, gap, gaps, _nan_rows(ref.q_nb)))
    if flight.ref_wind is not None:
        w = flight.ref_wind
        rate, gap, gaps = _time_stats(w.t)
        out.append(StreamStats("log wind", len(w.t), rate, gap, gaps, _nan_rows(w.wind_n)))
    return out


def _sensor_section(flight: Flight) -> Section:
    rows: list[list[Cell]] = []
    highlight: dict[tuple[int, int], Literal["good", "bad"]] = {}
    for i, s in enumerate(stream_stats(flight)):
        rows.append(
            [s.name, s.samples, s.rate_hz, s.largest_gap_s, s.gaps, s.nan_rows, s.largest, s.saturated,
             s.saturated_channels or None]
        )
        if s.nan_rows:
            highlight[(i, 5)] = "bad"
    table = Table(
        ["stream", "samples", "rate [Hz]", "largest gap [s]", f"gaps > {GAP_FACTOR:g} steps", "NaN samples",
         "largest |value|", "samples at a repeated extreme", "channels at a repeated extreme"],
        rows,
        caption="Sensor streams",
        highlight=highlight,
    )
    text = (
        f"Rate: 1 / median time step. Gaps: steps longer than {GAP_FACTOR:g} median steps; largest gap: the "
        "longest step. NaN samples: samples with a NaN in any value (estimators skip them). Saturation: for each "
        "channel, the samples at its largest absolute value, counted only when that value occurs "
        f"{SATURATION_REPEATS} times or more (a clipped sensor sits at its full scale, a free signal touches its "
        "peak once). A flag to check, not a verdict: a slow or coarsely quantised signal can repeat its peak too "
        "(e.g. a vehicle resting on the ground), so compare the value with the sensor's full scale. Magnetic "
        "field in uT."
    )
    return Section("Sensors", paragraphs=[text], tables=[table])


# ---------------------------------------------------------------------------------------
# text helpers


def reference_text(flight: Flight) -> str:
    """What estimates are scored against, in words ("" when nothing)."""
    try:
        _, _, kind, free = reference_of(flight)
    except ValueError:
        return ""
    text = _REFERENCE_TEXT.get(kind, kind)
    return text + (" (heading-free: a constant heading offset is removed before scoring)" if free else "")


def _states(est: Estimate) -> str:
    parts = ["attitude"]
    parts += [name for name, v in (("gyro bias", est.gyro_bias_b), ("velocity", est.v_n), ("wind", est.wind_n))
              if v is not None]
    if est.cov is not None:
        parts.append("covariance")
    return ", ".join(parts)


# ---------------------------------------------------------------------------------------
# sections


def _overview(
    flight: Flight,
    results: Sequence[tuple[str, Estimate]],
    failures: Mapping[str, str],
    alignment: Alignment | None,
    aligned_on: str | None,
    notes: Sequence[str],
) -> Section:
    src = flight.meta.get("source", "")
    fmt = flight.meta.get("format", "")
    streams = ", ".join(f"{n} ({len(t)} samples)" for n, t in flight.streams().items())
    paras = [
        f"Flight {src or '(no source name)'}{f' ({fmt})' if fmt else ''}: {flight.duration:.2f} s; streams {streams}."
    ]
    ref = reference_text(flight)
    paras.append(
        f"Estimates are scored against {ref}." if ref
        else "The flight has neither simulation truth nor a reference attitude: no errors can be computed, and "
        "the report shows the estimates only."
    )
    if alignment is not None:
        paras.append(
            "R" + describe_alignment(alignment, aligned_on)[1:] + ". The one alignment is applied for every "
            "estimator; it also absorbs whatever constant error the estimator it was fitted on has."
        )
        warning = alignment_warning(alignment)
        if warning:
            paras.append(f"Warning: {warning}.")
    repaired = repairs_text(flight.repairs)
    if repaired:
        paras.append(f"Input repaired at the edge (windahrs.repair), so each estimator saw it repaired: {repaired}.")
    paras += list(notes)
    rows: list[list[Cell]] = []
    highlight: dict[tuple[int, int], Literal["good", "bad"]] = {}
    for spec, est in results:
        skipped = {k: v for k, v in est.skipped.items() if v}
        rows.append(
            [spec, "ran", _states(est), ", ".join(est.innovations) or "none logged",
             ", ".join(f"{k} {v}" for k, v in skipped.items()) or "0"]
        )
    for spec, why in failures.items():
        highlight[(len(rows), 1)] = "bad"
        rows.append([spec, f"not run: {why}", None, None, None])
    table = Table(
        ["filter", "status", "states", "innovations from", "skipped NaN samples"],
        rows,
        caption="Estimators",
        highlight=highlight,
    )
    return Section("What was run", paragraphs=paras, tables=[table])


def _score_table(scores: Sequence[Score], caption: str) -> Table:
    rows: list[list[Cell]] = []
    figures = np.array(
        [[*s.rmse_from50_deg, *s.rmse_steady_deg, s.rmse_tilt_deg, s.rmse_total_deg] for s in scores], dtype=float
    ).reshape(len(scores), 8)
    for s, f in zip(scores, figures, strict=True):
        # NaN: a span without a scored reference sample, shown as a dash and said in the caption
        rows.append([s.filter, *(float(v) if np.isfinite(v) else None for v in f)])
    highlight: dict[tuple[int, int], Literal["good", "bad"]] = {}
    if len(rows) > 1:
        for j in range(8):
            col = figures[:, j]
            if np.isfinite(col).any():
                highlight[(int(np.nanargmin(col)), j + 1)] = "good"
    if not np.isfinite(figures).all():
        caption += " (–: no reference sample scored in that span)"
    columns = ["filter", "roll", "pitch", "yaw", "roll, 2nd half", "pitch, 2nd half", "yaw, 2nd half", "tilt",
               "total"]
    return Table(columns, rows, caption=caption, highlight=highlight)


def _attitude_section(
    flight: Flight,
    scored: Flight,
    results: Sequence[tuple[str, Estimate]],
    alignment: Alignment | None,
) -> Section:
    ref = reference_text(flight)
    images = []
    tables = []
    paras = []
    curves: dict[str, Any] = {spec: (est.t, np.degrees(euler_from_quat(est.q_nb))) for spec, est in results}
    ref_label = None
    if ref:
        t_ref, q_ref, kind, free = reference_of(scored)
        ref_label = kind + (" (aligned)" if alignment is not None else "")
        curves[ref_label] = (t_ref, np.degrees(euler_from_quat(q_ref)))
        scores = []
        errors = {}
        for spec, est in results:
            try:
                scores.append(_relabel(score(est, scored), spec))
                e = attitude_errors(est, scored)
            except ValueError as exc:
                paras.append(f"{spec}: not scored ({exc}).")
                continue
            errors[spec] = (e.t, np.degrees(np.column_stack([e.euler, e.tilt])))
        what = "aligned reference" if alignment is not None else _short(kind)
        cap = (
            f"RMSE [deg] against the {what}: roll, pitch, yaw, tilt and total from sample 50; "
            "roll, pitch, yaw over the second half"
        )
        if scores:
            tables.append(_score_table(scores, cap))
        if alignment is not None:
            raw = []
            for spec, est in results:
                try:
                    raw.append(_relabel(score(est, flight), spec))
                except ValueError:
                    continue
            if raw:
                tables.append(_score_table(raw, f"RMSE [deg] against the {_short(kind)} as logged (no alignment)"))
        paras.insert(
            0,
            "Errors are estimate minus reference: per axis the difference of ZYX Euler angles; tilt the angle "
            "between the two down axes (independent of heading); total the rotation angle between the two "
            "attitudes. The best value of each column is marked.",
        )
        if free:
            paras.append("The reference's heading datum is arbitrary: its yaw curve is offset from the estimates'.")
        if errors:
            images.append(
                Image(
                    timeseries_png(
                        next(iter(errors.values()))[0], errors, "error [deg]", "Attitude error",
                        panels=["roll", "pitch", "yaw", "tilt"],
                    ),
                    f"Attitude error against {ref} (estimate minus reference), deg",
                    alt="attitude error against time per estimator",
                )
            )
    else:
        paras.append("No truth or reference in this flight: no errors, only the estimated attitudes.")
    images.insert(
        0,
        Image(
            timeseries_png(
                flight.imu.t, curves, "angle [deg]", "Attitude", panels=["roll", "pitch", "yaw"],
                reference=ref_label,
            ),
            "Attitude (ZYX Euler angles, deg) of each estimator" + (f" and of {ref} (black)" if ref else ""),
            alt="roll, pitch and yaw against time",
        ),
    )
    heading = "Attitude against the reference" if ref else "Attitude"
    return Section(heading, paragraphs=paras, tables=tables, images=images)


def _short(kind: str) -> str:
    return {"truth": "truth", "mocap": "motion capture", "autopilot": "autopilot's estimate"}.get(kind, kind)


def _relabel(s: Score, spec: str) -> Score:
    # Rows are named by the spec the user gave (with overrides), as compare prints them.
    return Score(spec, s.reference, s.rmse_from50_deg, s.rmse_steady_deg, s.rmse_tilt_deg, s.rmse_total_deg)


def _innovation_section(results: Sequence[tuple[str, Estimate]]) -> Section:
    sensors: list[str] = []
    for _, est in results:
        sensors += [s for s in est.innovations if s not in sensors]
    without = [spec for spec, est in results if not est.innovations]
    paras = [
        "NIS: the normalised innovation squared nu^T S^-1 nu of each update; for a consistent filter it follows a "
        "chi-square distribution with as many degrees of freedom as the update has dimensions: mean = dimension, "
        "95 % of the samples inside the band. Statistics over every update with a finite NIS, rejected ones "
        "included (accepted: the share the filter's gate let through).",
    ]
    if without:
        paras.append(f"No innovations from {', '.join(without)} (it logs none).")
    if not sensors:
        return Section("Innovations and NIS", paragraphs=paras)
    rows: list[list[Cell]] = []
    highlight: dict[tuple[int, int], Literal["good", "bad"]] = {}
    for spec, est in results:
        for sensor, inn in est.innovations.items():
            nis = inn.nis[np.isfinite(inn.nis)]
            lo, hi = chi2_band(inn.dim, 1)
            inside = float(np.mean((nis >= lo) & (nis <= hi)) * 100) if len(nis) else math.nan
            acc = inn.accepted_share() * 100 if len(inn.t) else math.nan  # (of the time: fusion rates)
            mean = float(np.mean(nis)) if len(nis) else math.nan
            if math.isfinite(inside):
                highlight[(len(rows), 8)] = "good" if inside >= 80.0 else "bad"
            rows.append(
                [spec, sensor, inn.dim, len(inn.t), acc, mean,
                 float(np.median(nis)) if len(nis) else math.nan, inn.dim, inside]
            )
    table = Table(
        ["filter", "sensor", "dim", "updates", "accepted [%]", "mean NIS", "median NIS", "expected mean",
         "inside 95 % band [%]"],
        rows,
        caption="Innovation consistency per sensor",
        highlight=highlight,
    )
    images = []
    for sensor in sensors:
        per = [(spec, est.innovations[sensor]) for spec, est in results if sensor in est.innovations]
        dims = sorted({inn.dim for _, inn in per})
        for dim in dims:
            group = [(spec, inn) for spec, inn in per if inn.dim == dim]
            tag = f"{sensor}" + (f" ({dim}-dim)" if len(dims) > 1 else "")
            lo, hi = chi2_band(dim, 1)
            nis_curves = {spec: (inn.t, inn.nis) for spec, inn in group}
            images.append(
                Image(
                    timeseries_png(
                        group[0][1].t, nis_curves, "NIS", f"NIS: {tag}",
                        hlines={"2.5 %": lo, "97.5 %": hi}, logy=True,
                    ),
                    f"NIS of the {tag} updates, log scale; dotted: the chi-square({dim}) 2.5 and 97.5 % quantiles",
                    alt=f"NIS of {tag} against time",
                )
            )
            comps = SENSOR_LABELS.get(sensor, "")
            panels = [f"{sensor} {c}" for c in comps] if dim == len(comps) else (
                [sensor] if dim == 1 else [f"{sensor} {k}" for k in range(dim)]
            )
            images.append(
                Image(
                    timeseries_png(
                        group[0][1].t, {spec: (inn.t, inn.nu.reshape(len(inn.t), -1)) for spec, inn in group},
                        "innovation", f"Innovations: {tag}", panels=panels,
                    ),
                    f"Innovations z - h(x) of the {tag} updates, in each filter's measurement units",
                    alt=f"innovations of {tag} against time",
                )
            )
    paras.append(
        "Innovation units: the windahrs error-state filters use m/s^2 (accel), tesla (mag; rad for heading-only "
        "updates), m/s (gnss, tas, air velocity) and rad (sideslip); the paper's filters use unit vectors "
        "(acc, mag, air)."
    )
    return Section("Innovations and NIS", paragraphs=paras, tables=[table], images=images)


#: The spans listed per estimator in the flags table (the figure shows them all).
MAX_SPAN_ROWS = 25


def _flags_section(flight: Flight, results: Sequence[tuple[str, Estimate]]) -> Section | None:
    """What each estimator flagged, when and why (``Estimate.flags``, windahrs.flags): a
    timeline per estimator and the spans with their reasons."""
    spans = {spec: flag_spans(est.t, est.flags) for spec, est in results if est.flags is not None}
    spans = {spec: s for spec, s in spans.items() if s}
    if not spans:
        return None
    t = flight.imu.t
    rows: list[list[Any]] = []
    for spec, ss in spans.items():
        for sp in ss[:MAX_SPAN_ROWS]:
            rows.append([spec, sp.flag, round(sp.t0, 3), round(sp.t1, 3), sp.reason])
        if len(ss) > MAX_SPAN_ROWS:
            rows.append([spec, f"... {len(ss) - MAX_SPAN_ROWS} more", None, None, "(in the figure)"])
    png = spans_png(
        {spec: [(sp.t0, sp.t1, sp.flag) for sp in ss] for spec, ss in spans.items()},
        (float(t[0]), float(t[-1])),
        "Flags",
    )
    return Section(
        "What the estimators flagged",
        paragraphs=[
            "Per estimator, the spans of samples where it rejected a sensor, detected a disturbance, held an "
            "IMU sample, reset its state, fell back to fewer sensors, or went without a sensor (docs/ROBUSTNESS.md)."
        ],
        tables=[Table(["estimator", "flag", "from [s]", "to [s]", "reason"], rows, caption="Flagged spans")],
        images=[Image(png, "Flagged spans per estimator", alt="flag spans against time per estimator")],
    )


def _wind_section(flight: Flight, results: Sequence[tuple[str, Estimate]]) -> Section:
    windy = [(spec, est) for spec, est in results if est.wind_n is not None]
    log_label, log_t, log_w = None, None, None
    if flight.ref_wind is not None:
        log_label, log_t, log_w = "log's wind", flight.ref_wind.t, flight.ref_wind.wind_n
    elif flight.truth is not None and flight.truth.wind_n is not None:
        log_label, log_t, log_w = "true wind", flight.truth.t, flight.truth.wind_n
    paras = []
    no_wind = [spec for spec, est in results if est.wind_n is None]
    if not windy:
        paras.append("None of the estimators estimates wind" + (f" ({', '.join(no_wind)})." if no_wind else "."))
    elif no_wind:
        paras.append(f"Without wind states: {', '.join(no_wind)}.")
    if log_label is None:
        paras.append("The flight carries no wind of its own (no logged wind estimate, no simulation truth): "
                     "nothing to compare the estimates with.")
    if not windy and log_label is None:
        return Section("Wind", paragraphs=paras)
    t_mid = 0.5 * (flight.imu.t[0] + flight.imu.t[-1])
    rows: list[list[Cell]] = []
    for spec, est in windy:
        assert est.wind_n is not None
        late = est.t >= t_mid
        w = est.wind_n[late]
        err_h: Cell = None
        err_d: Cell = None
        if log_t is not None and log_w is not None:
            ref = _interp_rows(log_t, log_w, est.t[late])
            d = w - ref
            ok = np.isfinite(d).all(axis=1)
            if ok.any():
                err_h = float(np.sqrt(np.mean(np.sum(d[ok, :2] ** 2, axis=1))))
                err_d = float(np.sqrt(np.mean(d[ok, 2] ** 2)))
        rows.append([spec, *_wind_means(w), err_h, err_d])
    if log_t is not None and log_w is not None and log_label is not None:
        rows.append([log_label, *_wind_means(log_w[log_t >= t_mid]), None, None])
    table = Table(
        ["source", "mean N [m/s]", "mean E [m/s]", "mean D [m/s]", "mean horizontal speed [m/s]",
         "blowing from [deg]", "RMSE horizontal [m/s]", "RMSE down [m/s]"],
        rows,
        caption=f"Wind (velocity of the air, NED) over the second half of the flight (t >= {t_mid:.1f} s)"
        + (f", against the {log_label}" if log_label else ""),
    )
    paras.append(
        "Means and RMSE over the second half, when the wind states have converged; the log's wind is "
        "interpolated linearly at the estimate's times. Blowing from: the direction the mean horizontal wind "
        "comes from, clockwise from north."
    )
    curves: dict[str, Any] = {spec: (est.t, est.wind_n) for spec, est in windy}
    if log_label is not None and log_t is not None:
        curves[log_label] = (log_t, log_w)
    image = Image(
        timeseries_png(flight.imu.t, curves, "wind [m/s]", "Wind", panels=["north", "east", "down"],
                       reference=log_label),
        "Wind estimates (velocity of the air, m/s, NED)" + (f" and the {log_label} (black)" if log_label else ""),
        alt="wind north, east and down against time",
    )
    return Section("Wind", paragraphs=paras, tables=[table], images=[image])


def _interp_rows(t_src: F64, v_src: F64, t: F64) -> F64:
    """Linear interpolation of (N, k) rows at times t; NaN outside the source's span."""
    out = np.column_stack([np.interp(t, t_src, v_src[:, j]) for j in range(v_src.shape[1])])
    out[(t < t_src[0]) | (t > t_src[-1])] = np.nan
    return out


def _wind_means(w: F64) -> list[Cell]:
    w = w[np.isfinite(w).all(axis=1)]
    if len(w) == 0:
        return [None] * 5
    m = w.mean(axis=0)
    speed = float(np.mean(np.hypot(w[:, 0], w[:, 1])))
    # The air moves toward m; it comes from the opposite direction.
    from_deg = math.degrees(math.atan2(-m[1], -m[0])) % 360.0
    return [float(m[0]), float(m[1]), float(m[2]), speed, from_deg]


# ---------------------------------------------------------------------------------------
# the page


def build_log_report(
    flight: Flight,
    results: Sequence[tuple[str, Estimate]],
    *,
    alignment: Alignment | None = None,
    aligned_on: str | None = None,
    failures: Mapping[str, str] | None = None,
    notes: Sequence[str] = (),
    title: str | None = None,
) -> str:
    """The report page (self-contained HTML text) of estimators run on one flight.

    flight: the Flight as read; results: (spec, Estimate) per estimator that ran, in the
    order to show; alignment: a constant mount rotation and time offset (from
    :func:`windahrs.experiments.align.estimate_alignment`) applied to the flight's
    reference before scoring (both the aligned and the as-logged scores are shown);
    aligned_on: the spec whose estimate the alignment was fitted on; failures: spec ->
    why it did not run, listed with the estimators; notes: extra paragraphs for the first
    section; title: the page title (default from the flight's source).

    Raises ValueError when results is empty and there are no failures to report, or when
    an alignment is given for a flight without a reference (a simulation's truth needs none).
    """
    failures = dict(failures or {})
    if not results and not failures:
        raise ValueError("results: expected at least one (spec, Estimate), found none")
    scored = apply_alignment(flight, alignment) if alignment is not None else flight
    name = flight.meta.get("source") or "flight"
    sections = [
        _overview(flight, results, failures, alignment, aligned_on, notes),
        _sensor_section(flight),
    ]
    if results:
        sections += [
            _attitude_section(flight, scored, results, alignment),
            _innovation_section(results),
            _wind_section(flight, results),
        ]
        flagged = _flags_section(flight, results)
        if flagged is not None:
            sections.append(flagged)
    return render_html(title or f"windahrs report: {name}", sections)
