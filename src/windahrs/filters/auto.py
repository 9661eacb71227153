"""[auto]: look at the flight and run the windahrs estimator its sensors support.

The choice, from the streams the flight has (a stream counts when it has at least one
finite sample; a logged but empty stream would leave a filter waiting for it forever):

==========================  ===============================================================
the flight has              auto runs
==========================  ===============================================================
GNSS velocity               [ins-wind]: the accelerometer as the INS input, GNSS velocity,
                            the magnetometer (3-D, with its hard-iron bias) and air data
                            (pitot and vanes) when present, wind states; without a
                            magnetometer, [mekf]'s tilt until the INS knows its heading
                            (below)
no GNSS, air data           [mekf] with its field defaults (:data:`~windahrs.filters.eskf.
                            MEKF_FIELD`) and ``accel_compensation = "airspeed"``; the
                            magnetometer when present
no GNSS, no air data        [mekf] with its field defaults; the magnetometer when present
                            (an IMU alone runs too: tilt, and a heading that drifts)
==========================  ===============================================================

A GNSS stream the flight declares unsynchronised (``meta["gnss.timing_sigma_s"]`` above
:data:`MAX_GNSS_TIMING_S`) counts as absent.

GNSS velocity without a magnetometer (or with ``mag_mode=off``): [mekf] and [ins-wind] run
side by side. The INS starts with its heading unknown (init_yaw pi, its default then), and
until the GNSS accelerations turn it, GNSS velocity fused under a heading wrong by tens of
degrees tilts it; once it knows its heading it is the better of the two. So the output is
[mekf]'s tilt turned to the INS's heading until the first sample at which the INS's
covariance puts its heading's 1 sigma under :data:`HANDOVER_HEADING_SIGMA`
(:func:`handover_index`), the INS's from then on (:func:`splice`);
``meta["auto_handover_s"]`` says when, and without such a sample [mekf] runs alone. After
the handover, [mekf]'s tilt stands in again (with the INS's heading) while the INS's latest
GNSS sample was rejected by its gate (:func:`gate_closed`): GNSS then disagrees with the
INS, which nothing else checks, while gravity checks [mekf]'s tilt at every sample
(ArduPilot's EKF3 likewise moves to the lane whose innovations pass);
``meta["auto_gate_closed_s"]`` says for how long.

Started with its heading unknown, the INS may also claim its heading while far off it (ANSFL
path_16: 15 deg at 1.6 s, about 110 deg off, then 20 deg off in tilt for 8 s). So auto matches
the heading on GNSS velocity as a strapdown INS aligns in motion (:func:`gnss_heading`): the
change of GNSS velocity over each GNSS interval against [mekf]'s specific force rotated and
integrated, one turn about the vertical fitted on all the intervals so far, with its 1 sigma
from the residuals. Once that sigma is under :data:`HANDOVER_HEADING_SIGMA` on at least
:data:`ALIGN_MIN_INTERVALS` intervals (:func:`aligned_index`, at t_m s), the INS runs again from
the start with that heading, its attitude's spread that sigma but no less than the INS's own
init_att (replayed: what a system does with the IMU and GNSS samples it buffered until t_m, so
that its state at any t >= t_m uses the samples up to t alone). From t_m the output is on one
of the two INS runs (:func:`lane_choice`): first on the one that knows its heading at t_m (the
matched run, unless the first had claimed its own by then), then on the other only once the
log-likelihood ratio of their GNSS innovations since t_m (:func:`lane_scores`) passes
:data:`LANE_SWITCH_LLR` in its favour, Wald's sequential test at 5 % both ways, so that the
output does not switch back and forth between runs whose headings differ. ArduPilot's EKF3
chooses between its lanes by their innovation test ratios, PX4's yaw estimator weights its
bank of headings by their likelihood. ``meta["auto_heading_matched_s"]`` is t_m and
``meta["auto_matched_share"]`` the share of the samples from the matched run; ``auto_handover_s``
is then the first sample taken from either run. Measured on the 16 ANSFL flights
(docs/RESULTS.md section 40; ``benchmarks/auto_check.py``, tilt aligned on vqf): median tilt
3.682 -> 3.322 deg, the flights more than 10 % worse than the better of [mekf] and [ins-wind]
4 -> 0, at most one switch of run per flight; nothing tuned (the 15 deg is PX4's, the
intervals' count a statistical floor, the bound Wald's at 5 %). On a flight with little
horizontal acceleration (the simulated quadrotor holding its position, the simulated fixed
wing's first straight seconds) sigma stays above 15 deg and nothing changes.

Measured on the 16 ANSFL flights (docs/RESULTS.md section 34; GNSS moved onto the IMU's
clock by ``--align``): median tilt 3.965 deg against [mekf]'s 4.442 and [ins-wind]'s 5.299,
the handover 0.6-2.7 s after the start; even / odd flights 4.17 / 3.82 against [mekf]'s
4.34 / 4.85; nothing tuned (the threshold is PX4's). On path_16 the INS claimed its heading
1.6 s after the start while still about 110 deg off, then rejected GNSS for 5 s: tilt 9.21
deg with the handover alone, 4.72 with the gate rule, the other 15 flights unchanged by it.
The total after one constant heading offset rises from 5.76 to 17.0 deg: the INS's heading
is true north and wrong for its first seconds, [mekf]'s relative and steady. PX4's EKF2
fuses GNSS only once its yaw is aligned (by the magnetometer, or in flight by its GSF yaw
estimator); that estimator ahead of the INS's start was tried and measured worse (section
34: the INS waits 6-7 s for it, and its attitude meanwhile is poorer than [mekf]'s). Until
stop 28 GNSS counted as absent on such a flight, measured then, median tilt on the even /
odd flights: [ins-wind] 5.43 / 4.84 deg, [mekf] 4.69 / 6.40, better on one half and worse
on the other (docs/RESULTS.md, sections 15 and 16; 15.8 / 12.1 with the heading's spread at
init_att's 10 deg); at stop 22, [ins-wind] 5.43 / 4.84 (all 16: 5.30), [mekf] 4.46 / 6.20
(all 16: 4.54; docs/RESULTS.md section 23).

The smoother (``auto-smooth``, ``--smooth``) runs the INS's smoother on such a flight: its
backward pass carries the heading the INS converged to back to the start, which undoes what
the causal INS gets wrong before it converges. Measured on the same 16 flights
(docs/RESULTS.md section 34), median tilt / total: [ins-wind]'s smoother 2.737 / 2.940,
[mekf]'s 3.376 / 5.046, vqf-offline 3.542 / 4.929; on the even / odd flights, tilt 3.38 /
2.35 against [mekf]'s 3.84 / 3.09 (no parameter chosen: the rule is the only change).

A flight that starts still (on the ground): the INS levels on its accelerometers while it
stands still before it first moves (its stationary alignment, :mod:`windahrs.aid.rest`),
first rest_min_time after the start; until then GNSS velocity is its only view of the
tilt, and at rest a poor one. So [mekf] runs beside it, and the output is [mekf]'s tilt
turned to the INS's heading until the INS's first levelling (:func:`levelled_index`), when
that comes within :func:`still_start_s` of the start (a later one is a rest that began after
the start, a hover that passes for rest, by when GNSS has aligned the INS); the INS's from
then on; ``meta["auto_levelled_s"]`` says when. Measured (docs/RESULTS.md section 38;
``benchmarks/auto_check.py``): PX4 ``sample_log_small.ulg`` (6.5 s on the ground) tilt
against EKF2 0.586 -> 0.152 deg ([mekf] 0.146, [ins-wind] alone 0.586 -> 0.475 with its
levelling); the simulated flights and the other recordings within 1 % of before.

After the run, an INS that fails the tilt check is replaced by the run without GNSS when
that one fails it for less time (see :meth:`Auto.run`).

Why [mekf] can compensate with air data and no GNSS: the airspeed compensation (SPEC 3.2.2)
subtracts ``(w - b_g) x V_air`` from the specific force, the centripetal acceleration of a
turn at constant airspeed, and ``V_air`` is the air-data sample's own air-relative velocity
(true airspeed along the vanes' direction, or along body x without vanes;
:func:`windahrs.aid.air_velocity.remember_air`), which the kernel keeps for every filter
kind. Neither a velocity state nor GNSS enters it (``tests/test_auto.py`` holds it to
``mekf:accel_compensation=airspeed`` and shows that it changes the answer).

Not chosen automatically:

* the multirotor drag aid ([ins-drag]): its coefficients belong to the airframe (PX4's
  defaults left a 3.4 m/s wind error on the simulated quadrotor, docs/RESULTS.md section 6)
  and a flight does not say what flew it. ``auto:drag=true`` reaches it, on flights with GNSS
  (see Parameters); ``auto:drag=true:wind_vertical=false`` is [ins-drag]'s configuration.
* [mekf-air]: with GNSS, [ins-wind] fuses the same air data with the velocity estimated
  rather than taken as an input.

Parameters: ``auto:field=value`` (and a ``--params`` file) set fields of
:class:`~windahrs.filters.params.EskfParams` on top of the chosen estimator's own
defaults. A field that neither [ins-wind] nor [mekf] uses is refused when the spec is built,
as for any estimator. A field that only one of them uses (``gnss_sigma``: the INS;
``accel_lowpass``: [mekf]) is passed on when that one is chosen, and otherwise left out
with its name in ``Estimate.meta["auto_ignored"]`` (and in the line ``windahrs estimate``
prints): refusing it would make a spec fail on exactly the flights auto exists to take,
and the field concerns a sensor or an aid the flight does not have. An explicit
``accel_compensation`` wins over the airspeed compensation auto would choose.

The output says what ran: ``Estimate.filter`` is auto's label (``"auto"``, or the spec), and
``Estimate.meta`` holds ``auto`` (the registry spec of the estimator that ran, e.g.
``"ins-wind"`` or ``"mekf:accel_compensation=airspeed"``: :func:`make_estimator` of it
gives the same answers), ``sensors`` (the streams it fused, e.g. ``"imu,mag,gnss,air"``),
``auto_reason`` and, when some overrides were not used, ``auto_ignored``.

Streaming: ``auto.stream(site, has=...)`` chooses from ``has``, the streams you announce
(default: all four, so [ins-wind]; announce only what you will feed). A streamer runs one
estimator: it does not hand over from [mekf] on GNSS without a magnetometer (announced
without "mag", it is [ins-wind] from the start).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from windahrs.core.kernel import CompiledEstimator, CompiledStreamer
from windahrs.core.layout import cov_stride_of
from windahrs.estimate import Estimate, Innovations
from windahrs.filters.base import Estimator, InitialState
from windahrs.filters.checks import checked
from windahrs.filters.eskf import InsWind, Mekf
from windahrs.filters.params import EskfParams, changes_from_mapping, read_param_file
from windahrs.flight import Flight, Site
from windahrs.rotation import euler_from_quat, quat_exp, quat_mul, quat_rotate, quat_rotate_inv

__all__ = [
    "Auto", "AutoChoice", "GnssHeading", "aligned_index", "describe_choice", "gate_closed", "gnss_heading",
    "handover_index", "lane_choice", "lane_scores", "levelled_index", "splice", "still_start_s", "usable_streams",
]

F64 = NDArray[np.float64]

#: A GNSS stream whose time stamps the flight declares uncertain beyond this (s,
#: ``Flight.meta["gnss.timing_sigma_s"]``, e.g. a velocity differentiated from positions
#: logged on another device's clock, as the ANSFL reader declares) is left out: the INS takes
#: its attitude from the GNSS accelerations, and a timing error tau turns an acceleration a
#: into a velocity error tau a, more than the 0.2 m/s a receiver's velocity carries at 2 m/s^2
#: once tau passes 0.1 s (PX4 and ArduPilot compensate their receiver's delay, EKF2_GPS_DELAY,
#: to within tens of ms). Measured on the ANSFL flights: ins-wind 10.0 deg median tilt with
#: the declared 0.5 s, mekf 6.5 deg.
MAX_GNSS_TIMING_S = 0.1

#: An INS that fails the tilt check for more than this share of the flight is compared with
#: the run without GNSS (:meth:`Auto.run`); a shorter, transient failure (a launch, a lock-out
#: its GNSS reset ended) keeps the INS and its wind and velocity (ALFA: 10.7 s of 132 s).
FALLBACK_SHARE = 0.25

#: On a flight with GNSS velocity and no magnetometer, the INS takes over from [mekf] once the
#: 1 sigma of its heading is below this, rad: PX4 EKF2's bound for a usable heading from its
#: yaw estimator (EKFGSF_yaw, 15 deg), the heading error at which an INS's GNSS updates turn
#: it rather than tilt it (docs/RESULTS.md section 34; 10 deg measured 3.855 deg median tilt on
#: ANSFL, 15 deg 3.965, 25 deg 4.658: not tuned, PX4's kept).
HANDOVER_HEADING_SIGMA = math.radians(15.0)

#: The heading matched on GNSS velocity (:func:`gnss_heading`) is taken once it rests on at least
#: this many GNSS intervals: its residual variance, on 2 k - 1 degrees of freedom, is then known
#: to within 50 % (1 sigma, sqrt(2 / dof) <= 0.5 from dof >= 8), and its sigma with it.
ALIGN_MIN_INTERVALS = 5

#: The output moves from one INS run to the other once the log-likelihood ratio of their GNSS
#: innovations since the match (half the difference of their :func:`lane_scores`) passes this
#: bound in the other's favour: Wald's sequential test with 5 % errors both ways, ln(0.95 /
#: 0.05) = ln 19. Between the two bounds the output stays where it is (:func:`lane_choice`):
#: no switching back and forth between runs whose headings differ while the evidence is even.
LANE_SWITCH_LLR = math.log(19.0)

#: The estimators auto chooses from, by registry name.
CANDIDATES: dict[str, type[CompiledEstimator]] = {"ins-wind": InsWind, "mekf": Mekf}
_ORDER = ("imu", "mag", "gnss", "air")


def usable_streams(flight: Flight) -> frozenset[str]:
    """The streams of ``flight`` with at least one finite sample ("imu", "mag", "gnss", "air")."""
    rows: dict[str, Any] = {"imu": np.hstack([flight.imu.w_b, flight.imu.f_b])}
    if flight.mag is not None:
        rows["mag"] = flight.mag.mag_b
    if flight.gnss is not None:
        rows["gnss"] = flight.gnss.v_n
    if flight.air is not None:
        rows["air"] = flight.air.tas[:, None]
    return frozenset(k for k, v in rows.items() if np.isfinite(v).all(axis=1).any())


def _text(value: Any) -> str:
    """A parameter value as the registry's spec parser reads it back."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(float(value)) if isinstance(value, float) else str(value)


@dataclass(frozen=True)
class AutoChoice:
    """What auto runs for a set of streams: ``name`` ("ins-wind" or "mekf"), the built
    ``estimator``, ``spec`` (the registry spec that builds the same estimator), ``sensors``
    (the streams it fuses, in the order imu, mag, gnss, air), ``reason`` (one phrase) and
    ``ignored`` (override fields the chosen estimator does not use)."""

    name: str
    estimator: CompiledEstimator
    spec: str
    sensors: tuple[str, ...]
    reason: str
    ignored: tuple[str, ...]

    def meta(self) -> dict[str, str]:
        """The entries auto adds to ``Estimate.meta``."""
        out = {"auto": self.spec, "sensors": ",".join(self.sensors), "auto_reason": self.reason}
        if self.ignored:
            out["auto_ignored"] = ",".join(self.ignored)
        return out


class Auto(Estimator):
    """[auto] the estimator the flight's sensors support: [ins-wind] with GNSS velocity, else
    [mekf] (airspeed-compensated with air data); see the module docstring for the choice,
    the parameters and the output."""

    name = "auto"
    requires = frozenset({"imu"})
    uses = frozenset(_ORDER)
    candidates: ClassVar[dict[str, type[CompiledEstimator]]] = CANDIDATES

    def __init__(self, overrides: Mapping[str, Any] | None = None) -> None:
        given = dict(overrides or {})
        known = self.param_names()
        for key in given:
            if key not in known:
                every = {f.name for f in dataclasses.fields(EskfParams)}
                what = "does not use" if key in every else "has no"
                raise ValueError(
                    f"filter 'auto' {what} parameter {key!r} (neither {' nor '.join(self.candidates)} uses it); "
                    f"its parameters: {', '.join(sorted(known))}"
                )
        EskfParams().replace(**given)  # each value checked once, here (ValueError naming the field)
        self.overrides: dict[str, Any] = given

    @classmethod
    def param_names(cls) -> frozenset[str]:
        """Every field one of the candidates uses."""
        return frozenset().union(*(c.param_names() for c in cls.candidates.values()))

    @classmethod
    def load_params(cls, path: Any) -> dict[str, Any]:
        """The overrides of a TOML parameter file (the layout of
        :mod:`windahrs.filters.params`); fields checked against :meth:`param_names`."""
        data = read_param_file(path)
        return changes_from_mapping(data, str(path), allowed=cls.param_names(), filter_name=cls.name)

    def with_overrides(self, overrides: Mapping[str, Any]) -> Auto:
        """A new auto with ``overrides`` on top of this one's."""
        return Auto({**self.overrides, **overrides})

    def params_text(self) -> str:
        return f"auto overrides {self.overrides!r}"

    def choose(self, streams: Iterable[str]) -> AutoChoice:
        """The estimator for a flight (or streamer) with ``streams`` (names from "imu",
        "mag", "gnss", "air")."""
        has = frozenset(streams)
        name = "ins-wind" if "gnss" in has else "mekf"
        extra = {"accel_compensation": "airspeed"} if name == "mekf" and "air" in has else {}
        cls = self.candidates[name]
        used = cls.param_names()
        fields = {**extra, **{k: v for k, v in self.overrides.items() if k in used}}
        ignored = tuple(k for k in self.overrides if k not in used)
        est = cls(cls.default_params.replace(**fields))
        spec = name + "".join(f":{k}={_text(v)}" for k, v in fields.items())
        p = est.params
        fused = {"imu"}
        if "mag" in has and p.mag_mode != "off":
            fused.add("mag")
        if name == "ins-wind":
            fused.add("gnss")
            reason = "GNSS velocity present"
            if "air" in has and p.air_mode != "off":
                fused.add("air")
        else:
            reason = "no GNSS velocity"
            if "air" in has and p.accel_compensation == "airspeed":
                fused.add("air")
                reason += "; air data compensates the turns"
        est.label = spec
        sensors = tuple(s for s in _ORDER if s in fused)
        return AutoChoice(name, est, spec, sensors, reason, ignored)

    def run(
        self,
        flight: Flight,
        *,
        initial: InitialState | None = None,
        smooth: bool = False,
        cov_every: int | None = None,
    ) -> Estimate:
        """Choose from the flight's streams (:func:`usable_streams`) and run the choice;
        ``filter`` is auto's label and ``meta`` says what ran (:meth:`AutoChoice.meta`).
        cov_every: the covariance at every cov_every-th IMU sample, as the compiled filters'
        ``run`` (default 20 Hz; :func:`default_cov_record`).

        Fallback: when the INS fails the tilt check of :mod:`windahrs.filters.checks` (its
        attitude does not see the mean specific force, less the GNSS acceleration, as
        gravity) for more than :data:`FALLBACK_SHARE` of the flight, the flight is run
        again without GNSS ([mekf]) and the run that failed the check for less time is
        kept, as ArduPilot's EKF3 switches to the lane with the smaller error score;
        ``meta["auto_fallback"]`` says why. Only the kept run's warnings are emitted.

        smooth: run the choice's offline smoother (:func:`windahrs.core.smooth.smooth`)
        instead, the fallback judged on the smoothed runs."""
        self.check(flight)
        streams = usable_streams(flight)
        timing = float(flight.meta.get("gnss.timing_sigma_s", 0.0) or 0.0)
        unsynced = "gnss" in streams and timing > MAX_GNSS_TIMING_S
        no_heading = "gnss" in streams and ("mag" not in streams or self.overrides.get("mag_mode") == "off")
        headless = no_heading and not smooth  # (the causal run's rule: see the module docstring)
        choice = self.choose(streams - {"gnss"} if unsynced or headless else streams)
        if unsynced:
            choice = dataclasses.replace(
                choice, reason=f"GNSS velocity stamped on another clock (timing uncertain by {timing:g} s, "
                f"beyond {MAX_GNSS_TIMING_S:g} s): attitude without it")
        elif headless:
            choice = dataclasses.replace(
                choice, reason="GNSS velocity without a magnetometer: no heading to start the INS with, "
                "attitude without it")
        elif no_heading:
            choice = dataclasses.replace(
                choice, reason="GNSS velocity without a magnetometer, smoothed: the backward pass carries the "
                "heading the INS converges to back to the start")
        est, caught = _run_quietly(choice.estimator, flight, initial, smooth)
        if headless and not unsynced and initial is None:
            est, caught, choice = self._handover(flight, streams, est, caught, choice)
        elif "gnss" in choice.sensors and not smooth and initial is None:
            k = self._levelled(est, choice)
            if k:
                est, caught, choice = self._still_start(flight, streams, est, caught, k, choice)
        duration = float(flight.imu.t[-1] - flight.imu.t[0])
        if "gnss" in choice.sensors and _alert_seconds(est) > FALLBACK_SHARE * duration:
            other = self.choose(streams - {"gnss"})
            est2, caught2 = _run_quietly(other.estimator, flight, initial, smooth)
            if _alert_seconds(est2) < _alert_seconds(est):
                why = (f"{choice.spec}'s tilt disagreed with the mean specific force for "
                       f"{_alert_seconds(est):.1f} s, {other.spec}'s for {_alert_seconds(est2):.1f} s")
                choice, est, caught = other, est2, caught2
                est = dataclasses.replace(est, meta={**est.meta, "auto_fallback": why})
        for w in caught:
            text = str(w.message).replace(est.filter, f"{self.label} ({est.filter})", 1)
            warnings.warn(text, w.category, stacklevel=2)
        if not smooth:  # (the runs kept every sample's covariance for the handover: the default's now)
            est = default_cov_record(est, cov_every)
        return dataclasses.replace(est, filter=self.label, meta={**est.meta, **choice.meta()})

    def _handover(
        self,
        flight: Flight,
        streams: frozenset[str],
        before: Estimate,
        caught: list[warnings.WarningMessage],
        choice: AutoChoice,
    ) -> tuple[Estimate, list[warnings.WarningMessage], AutoChoice]:
        """GNSS without a magnetometer (module docstring): the INS run beside ``before``
        (the run without GNSS, ``choice``), and ``before``'s tilt with the INS's heading
        until the INS knows its heading (:func:`handover_index`) and while its GNSS gate is
        closed (:func:`gate_closed`), the INS otherwise (:func:`splice`), checked again
        (:func:`~windahrs.filters.checks.checked`); or ``before`` when the INS never knows
        it. Returns the estimate, its warnings and what ran."""
        ins_choice = self.choose(streams)
        try:
            ins, _ = _run_quietly(ins_choice.estimator, flight, None)
        except ValueError as exc:  # (an INS that cannot run this flight: the run without GNSS stands)
            return before, caught, dataclasses.replace(choice, reason=f"{choice.reason}; the INS beside it: {exc}")
        n = len(ins.t)
        k = handover_index(ins)
        if k is not None:  # (and not before a still start's levelling: _still_start)
            k = max(k, self._levelled(ins, ins_choice) or 0)
        lane, use_b, matched = ins, np.zeros(n, dtype=bool), {}
        heading = gnss_heading(flight, before)
        j = aligned_index(heading) if heading is not None else None
        if heading is not None and j is not None:  # the INS again, from the matched heading
            t_al, sigma_m = float(heading.t[j]), math.degrees(heading.sigma[j])
            i0 = min(before.first_initialised, n - 1)  # (before's nav frame, where it has one)
            params = ins_choice.estimator.params
            start = InitialState(q_nb=_about_vertical(before.q_nb[i0], float(heading.psi[j])),
                                 sigma_att=max(float(heading.sigma[j]), params.init_att))
            try:
                ins_b, _ = _run_quietly(ins_choice.estimator, flight, start)
            except ValueError:  # (the INS as it started stands)
                ins_b = None
            if ins_b is not None:
                gate2 = params.gate_gnss**2
                # (it starts on the run that knows its heading at the match: the matched one,
                # unless the first had claimed its own before)
                at = int(np.searchsorted(ins.t, t_al))
                first_knew = k is not None and k <= at
                scores = lane_scores(ins, t_al, gate2), lane_scores(ins_b, t_al, gate2)
                use_b = lane_choice(*scores, start_b=not first_knew) & (ins.t >= t_al)
                lane = _lanes(ins, ins_b, use_b)
                matched = {"auto_heading_matched_s": round(t_al - float(flight.imu.t[0]), 3),
                           "auto_matched_share": round(float(use_b.mean()), 3)}
        early = ~use_b & (np.arange(n) < (n if k is None else k))  # (the matched INS: from its start)
        sig = f"{math.degrees(HANDOVER_HEADING_SIGMA):g} deg (1 sigma)"
        if early.all():
            why = f"; the INS beside it never knew its heading to {sig}"
            if matched:
                why += ", nor did its run from the heading GNSS velocity matched outweigh it"
            return before, caught, dataclasses.replace(choice, reason=choice.reason + why)
        t_h = float(flight.imu.t[int(np.argmin(early))] - flight.imu.t[0])
        closed = gate_closed(lane) & ~early
        take = early | closed
        est, held = _spliced(before, lane, take, flight)
        dt = flight.imu.period if len(flight.imu.t) > 1 else 0.0
        reason = (f"GNSS velocity without a magnetometer: {choice.spec}'s tilt with the INS's heading until "
                  f"{t_h:.2f} s, the INS after (once it knew its heading to {sig}), but for its tilt while its "
                  "GNSS gate is closed")
        if use_b.any():
            t_m = matched["auto_heading_matched_s"]
            reason += (f"; from {t_m:.2f} s the INS also ran from the heading GNSS velocity matched then (to "
                       f"{sigma_m:.1f} deg, 1 sigma), taken for {100 * matched['auto_matched_share']:.0f} % of the "
                       "flight, where its GNSS innovations were the likelier")
        meta = {"auto_handover_s": t_h, "auto_gate_closed_s": round(float(closed.sum()) * dt, 3), **matched}
        est = dataclasses.replace(est, meta={**est.meta, **meta})
        return est, held, dataclasses.replace(ins_choice, reason=reason)

    @staticmethod
    def _levelled(ins: Estimate, choice: AutoChoice) -> int | None:
        """The INS's first levelling at a still start (:func:`levelled_index`), or None."""
        params = getattr(choice.estimator, "params", None)
        if not isinstance(params, EskfParams):
            return None
        return levelled_index(ins, still_start_s(params))

    def _still_start(
        self,
        flight: Flight,
        streams: frozenset[str],
        ins: Estimate,
        caught: list[warnings.WarningMessage],
        k: int,
        choice: AutoChoice,
    ) -> tuple[Estimate, list[warnings.WarningMessage], AutoChoice]:
        """A flight that starts still (module docstring): the run without GNSS beside the
        INS, and its tilt with the INS's heading until sample k, where the INS levelled on its
        accelerometers (:meth:`_levelled`), the INS after (:func:`splice`), checked again.
        Returns the estimate, its warnings and what ran."""
        other = self.choose(streams - {"gnss"})
        try:
            before, _ = _run_quietly(other.estimator, flight, None)
        except ValueError:  # (the INS alone then)
            return ins, caught, choice
        est, held = _spliced(before, ins, np.arange(len(ins.t)) < k, flight)
        t_l = float(flight.imu.t[k] - flight.imu.t[0])
        reason = (f"{choice.reason}; {other.spec}'s tilt with the INS's heading until {t_l:.2f} s, when the "
                  "INS, started still, levelled on its accelerometers")
        est = dataclasses.replace(est, meta={**est.meta, "auto_levelled_s": t_l})
        return est, held, dataclasses.replace(choice, reason=reason)

    def streamer(
        self, site: Site, *, initial: InitialState | None = None, has: frozenset[str] = frozenset()
    ) -> CompiledStreamer:
        """The chosen estimator's streamer, chosen from ``has`` (the streams that will be fed)."""
        choice = self.choose(has)
        est = choice.estimator
        return est.streamer(site, initial=initial, has=frozenset(has) & est.uses)


def _spliced(
    before: Estimate, after: Estimate, take: NDArray[np.bool_], flight: Flight
) -> tuple[Estimate, list[warnings.WarningMessage]]:
    """:func:`splice` checked again on ``flight``, and the warnings the check emitted, held back."""
    with warnings.catch_warnings(record=True) as held:
        warnings.simplefilter("always")
        est = checked(splice(before, after, take), flight)
    return est, list(held)


def default_cov_record(est: Estimate, cov_every: int | None = None) -> Estimate:
    """``est`` with the covariance rows a compiled run records with ``cov_every``
    (:func:`~windahrs.core.layout.cov_stride`; None: 20 Hz within the budget) kept of those
    it has (a run with ``cov_every="budget"``, whose rows include the default's; a stride its
    rows do not divide keeps the rows that are on both)."""
    if est.cov is None:
        return est
    every = cov_stride_of(est.t, est.cov.shape[1], cov_every)
    rows = est.cov_rows
    keep = rows % every == 0
    if keep.all():
        return est
    return dataclasses.replace(est, cov=np.ascontiguousarray(est.cov[keep]), cov_index=rows[keep])


def _run_quietly(
    est: Estimator, flight: Flight, initial: InitialState | None, smooth: bool = False
) -> tuple[Estimate, list[warnings.WarningMessage]]:
    """The estimate (smooth: the smoothed one) and the warnings the run emitted, held back."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if smooth:
            from windahrs.core.smooth import smooth as smoothed

            out = smoothed(est, flight, initial=initial, label=est.label)
        elif isinstance(est, CompiledEstimator):  # (every sample's covariance: the handover reads it so)
            out = est.run(flight, initial=initial, cov_every="budget")
        else:
            out = est.run(flight, initial=initial)
    return out, list(caught)


#: The nav vertical, whose body-frame direction C_bn e_3 carries the heading's variance.
_DOWN = np.array([0.0, 0.0, 1.0])


def handover_index(est: Estimate, sigma: float = HANDOVER_HEADING_SIGMA) -> int | None:
    """The first IMU sample at which ``est``'s recorded covariance puts the 1 sigma of its
    heading (the attitude's variance about the nav vertical, ``d^T P_att d``, d = C_bn e_3)
    below ``sigma`` rad; None when it never does, or records no attitude covariance."""
    if est.cov is None or est.cov.shape[1] < 3 or est.state_labels[:3] != ("att_x", "att_y", "att_z"):
        return None
    rows = est.cov_index if est.cov_index is not None else np.arange(len(est.cov))
    d = quat_rotate_inv(est.q_nb[rows], _DOWN)
    var = np.einsum("ni,nij,nj->n", d, est.cov[:, :3, :3], d)
    ok = np.flatnonzero(var < sigma * sigma)  # (NaN rows: not below)
    return int(rows[ok[0]]) if len(ok) else None


@dataclass(frozen=True)
class GnssHeading:
    """The heading matched on GNSS velocity (:func:`gnss_heading`), one row per GNSS interval:
    t (K,) its end, s; psi (K,) rad, the turn about the vertical from the estimate's nav frame
    to north, fitted on the intervals up to that one; sigma (K,) rad, its 1 sigma from the
    fit's residuals (inf before there are any)."""

    t: F64
    psi: F64
    sigma: F64


def gnss_heading(flight: Flight, est: Estimate) -> GnssHeading | None:
    """In-motion heading alignment by velocity matching, causal: over each interval between
    GNSS samples, the change of GNSS velocity (north, east) against the specific force rotated
    by ``est`` (an attitude whose heading is its own, e.g. [mekf]'s without a magnetometer)
    and integrated with gravity, ``dv_gnss = R(psi) dv_imu``. psi is the 2-D Procrustes
    (Wahba) solution on all the intervals so far, ``atan2(sum(dv_imu x dv_gnss), sum(dv_imu .
    dv_gnss))`` (the cross product's vertical component); sigma^2 is the residual variance per
    component (2 k - 1 degrees of freedom) over ``sum |dv_imu|^2``, which takes the GNSS
    noise of the intervals as independent (consecutive differences share a sample: a sigma on
    the safe side). A strapdown INS without a heading sensor aligns so in motion; PX4 EKF2's
    yaw estimator (EKFGSF_yaw) matches the same velocity changes with a bank of headings. The
    horizontal acceleration decides how soon sigma falls: at rest it never does. None without
    GNSS, or with fewer than two of its samples in the IMU's span."""
    imu, g = flight.imu, flight.gnss
    if g is None or len(imu.t) < 2:
        return None
    ok = np.isfinite(g.v_n[:, :2]).all(axis=1) & (g.t >= imu.t[0]) & (g.t <= imu.t[-1])
    tg, vg = g.t[ok], g.v_n[ok, :2]
    if len(tg) < 2:
        return None
    a_n = quat_rotate(est.q_nb, imu.f_b)[:, :2]  # (gravity has no horizontal part)
    a_n = np.where(np.isfinite(a_n), a_n, 0.0)
    step = 0.5 * (a_n[1:] + a_n[:-1]) * np.diff(imu.t)[:, None]  # (trapezoids)
    dv = np.vstack([np.zeros((1, 2)), np.cumsum(step, axis=0)])
    at = np.minimum(np.searchsorted(imu.t, tg), len(imu.t) - 1)
    dvg, dvi = np.diff(vg, axis=0), np.diff(dv[at], axis=0)
    dot = np.cumsum(dvg[:, 0] * dvi[:, 0] + dvg[:, 1] * dvi[:, 1])
    cross = np.cumsum(dvg[:, 1] * dvi[:, 0] - dvg[:, 0] * dvi[:, 1])
    psi = np.arctan2(cross, dot)
    imu2, gnss2 = np.cumsum((dvi**2).sum(axis=1)), np.cumsum((dvg**2).sum(axis=1))
    resid = np.maximum(gnss2 + imu2 - 2.0 * np.hypot(dot, cross), 0.0)  # sum |dv_gnss - R dv_imu|^2 at psi
    dof = 2.0 * np.arange(1, len(dvg) + 1) - 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = np.where(imu2 > 0, np.sqrt(resid / dof / imu2), np.inf)
    return GnssHeading(t=tg[1:], psi=psi, sigma=sigma)


def aligned_index(heading: GnssHeading, sigma: float = HANDOVER_HEADING_SIGMA,
                  min_intervals: int = ALIGN_MIN_INTERVALS) -> int | None:
    """The first row of ``heading`` resting on at least ``min_intervals`` GNSS intervals
    whose 1 sigma is below ``sigma`` rad (PX4's 15 deg, as the handover's), or None."""
    rows = np.flatnonzero((heading.sigma < sigma) & (np.arange(len(heading.t)) >= min_intervals - 1))
    return int(rows[0]) if len(rows) else None


def lane_scores(est: Estimate, since: float, gate2: float, sensor: str = "gnss") -> F64:
    """(N,) per IMU sample of ``est``: the sum, over its ``sensor`` innovations from ``since`` s
    to that sample, of each one's NIS, at most m ``gate2`` for m components (every component
    at its gate, gate2 its gate squared); a sample its gate rejected counts that much. Two
    runs of the same filter on the same data compare by it: half the difference of two sums is
    the log-likelihood ratio of the two runs' innovations (their covariances alike), the
    smaller sum the run that predicted the measurements better (ArduPilot's EKF3 chooses between
    its lanes by their innovation test ratios, PX4's yaw estimator weights its bank by the
    likelihood)."""
    inn = est.innovations.get(sensor)
    if inn is None or len(inn.t) == 0:
        return np.zeros(len(est.t))
    cap = max(inn.dim, 1) * gate2
    nis = np.asarray(inn.nis, dtype=np.float64)
    per = np.where(np.asarray(inn.accepted, dtype=bool), np.minimum(nis, cap), cap)
    per = np.where(np.isfinite(nis) & (inn.t >= since), per, 0.0)
    total = np.r_[0.0, np.cumsum(per)]
    return total[np.searchsorted(inn.t, est.t, side="right")]


def lane_choice(
    score_a: F64, score_b: F64, start_b: bool = False, bound: float = LANE_SWITCH_LLR
) -> NDArray[np.bool_]:
    """(N,) per sample: whether the output is on run b, given the two runs' :func:`lane_scores`.
    It starts on b when ``start_b``, else on a; it moves to b once the log-likelihood ratio
    ``(score_a - score_b) / 2`` exceeds ``bound``, and to a once it falls below ``-bound`` (a
    sequential test: between the bounds it stays where it was)."""
    llr = 0.5 * (np.asarray(score_a, dtype=np.float64) - np.asarray(score_b, dtype=np.float64))
    event = np.where(llr > bound, 1, np.where(llr < -bound, -1, 0))
    last = np.where(event != 0, np.arange(len(event)), -1)
    np.maximum.accumulate(last, out=last)
    return np.where(last >= 0, event[np.clip(last, 0, None)], 1 if start_b else -1) == 1


def _about_vertical(q_nb: F64, psi: F64 | float) -> F64:
    """q_nb (..., 4) turned by psi (...) rad about the nav vertical, normalised."""
    psi = np.asarray(psi, dtype=np.float64)
    zero = np.zeros_like(psi)
    q = quat_mul(quat_exp(np.stack([zero, zero, psi], axis=-1)), q_nb)
    return np.asarray(q / np.linalg.norm(q, axis=-1, keepdims=True), dtype=np.float64)


def _lanes(a: Estimate, b: Estimate, use_b: NDArray[np.bool_]) -> Estimate:
    """Two runs of the same estimator on the same flight as one: ``b``'s samples where
    ``use_b`` (N,), ``a``'s elsewhere; the states, the covariance's rows, and the innovations
    and resets logged while each was the one taken. The rest (alerts, airspeed scale, start,
    parameters, meta) is ``a``'s: check the result again."""
    def pick(x: F64 | None, y: F64 | None) -> F64 | None:
        if x is None or y is None:
            return x
        return np.where(use_b.reshape((-1,) + (1,) * (x.ndim - 1)), y, x)

    def taken(t: F64) -> NDArray[np.bool_]:
        j = np.searchsorted(a.t, t, side="right") - 1
        return (j >= 0) & use_b[np.clip(j, 0, None)]

    cov = a.cov
    if a.cov is not None and b.cov is not None and a.cov.shape == b.cov.shape:
        cov = np.where(use_b[a.cov_rows][:, None, None], b.cov, a.cov)
    def keys(x: dict[str, Any], y: dict[str, Any]) -> list[str]:  # (a's order, then b's own: deterministic)
        return [*x, *(k for k in y if k not in x)]

    inns = {}
    for key in keys(a.innovations, b.innovations):
        ia, ib = a.innovations.get(key), b.innovations.get(key)
        if ia is None or ib is None:  # (a log one run kept: its own rows, where it is taken)
            one: Innovations = ia if ia is not None else b.innovations[key]
            keep = ~taken(one.t) if ia is not None else taken(one.t)
            inns[key] = Innovations(t=one.t[keep], nu=one.nu[keep], nis=one.nis[keep], accepted=one.accepted[keep])
            continue
        ka, kb = ~taken(ia.t), taken(ib.t)
        order = np.argsort(np.r_[ia.t[ka], ib.t[kb]], kind="stable")
        inns[key] = Innovations(t=np.r_[ia.t[ka], ib.t[kb]][order], nu=np.vstack([ia.nu[ka], ib.nu[kb]])[order],
                                nis=np.r_[ia.nis[ka], ib.nis[kb]][order],
                                accepted=np.r_[ia.accepted[ka], ib.accepted[kb]][order])
    resets = {}
    for key in keys(a.resets, b.resets):
        ra = a.resets.get(key, np.empty((0, 3)))
        rb = b.resets.get(key, np.empty((0, 3)))
        rows = np.vstack([ra[~taken(ra[:, 0])], rb[taken(rb[:, 0])]])
        if len(rows):
            resets[key] = rows[np.argsort(rows[:, 0], kind="stable")]
    return dataclasses.replace(
        a, q_nb=np.where(use_b[:, None], b.q_nb, a.q_nb), gyro_bias_b=pick(a.gyro_bias_b, b.gyro_bias_b),
        v_n=pick(a.v_n, b.v_n), wind_n=pick(a.wind_n, b.wind_n), cov=cov, innovations=inns, resets=resets,
    )


def levelled_index(est: Estimate, within: float = math.inf) -> int | None:
    """The IMU sample of ``est``'s first levelling at rest (its ``"level"`` log: an INS
    standing still, :mod:`windahrs.aid.rest`), when it was accepted within ``within`` s of
    the start; None without one."""
    inn = est.innovations.get("level")
    if inn is None or not np.any(inn.accepted):
        return None
    t = float(inn.t[np.flatnonzero(inn.accepted)[0]])
    return min(int(np.searchsorted(est.t, t)), len(est.t) - 1) if t - est.t[0] <= within else None


def still_start_s(params: EskfParams) -> float:
    """How long after the start an INS that stood still from it first levels (aid.rest):
    rest_min_time, and one rest_tau more, the spacing of its measurements. A later first
    levelling is a rest that began after the start (a hover that passes for rest), by when
    GNSS has aligned the INS."""
    return params.rest_tau + params.rest_min_time


def gate_closed(est: Estimate, sensor: str = "gnss") -> NDArray[np.bool_]:
    """(N,) per IMU sample of ``est``: the latest ``sensor`` sample so far was rejected by
    its gate (the state disagrees with that sensor, which no longer corrects it); all False
    without that log."""
    inn = est.innovations.get(sensor)
    if inn is None or len(inn.t) == 0:
        return np.zeros(len(est.t), dtype=bool)
    j = np.searchsorted(inn.t, est.t, side="right") - 1
    return (j >= 0) & ~np.asarray(inn.accepted, dtype=bool)[np.clip(j, 0, None)]


def splice(before: Estimate, after: Estimate, take: NDArray[np.bool_]) -> Estimate:
    """``after`` with the attitude of the samples ``take`` (N,) taken from ``before``'s tilt
    turned to ``after``'s heading (``before`` knows where down is, ``after`` where north
    is), and their gyro bias from ``before``. The covariance (``after``'s labels) follows:
    on those samples the blocks of the states ``before`` estimates are its own, uncorrelated
    with the others, the attitude's variance about the vertical ``after``'s (``P + (v_a -
    v_b) d d^T``, v the variance along d = C_bn e_3). The alerts are dropped: check the
    result again (:func:`~windahrs.filters.checks.checked`)."""
    idx = np.flatnonzero(take)
    q = after.q_nb.copy()
    q[idx] = _about_vertical(
        before.q_nb[idx], euler_from_quat(after.q_nb[idx])[:, 2] - euler_from_quat(before.q_nb[idx])[:, 2]
    )
    bg = None
    if after.gyro_bias_b is not None:
        bg = after.gyro_bias_b.copy()
        if before.gyro_bias_b is not None:
            bg[idx] = before.gyro_bias_b[idx]
    cov = after.cov
    if cov is not None and before.cov is not None:
        cov = cov.copy()
        rows = after.cov_index if after.cov_index is not None else np.arange(len(cov))
        rows_b = before.cov_index if before.cov_index is not None else np.arange(len(before.cov))
        r = np.flatnonzero(take[rows])  # (the recorded rows of those samples)
        mine = [after.state_labels.index(s) for s in before.state_labels if s in after.state_labels]
        theirs = [before.state_labels.index(after.state_labels[i]) for i in mine]
        src = before.cov[np.clip(np.searchsorted(rows_b, rows[r]), 0, len(rows_b) - 1)]
        block = src[:, theirs][:, :, theirs]
        if mine[:3] == [0, 1, 2]:  # the heading's variance: the INS's
            d = quat_rotate_inv(q[rows[r]], _DOWN)
            v_a = np.einsum("ni,nij,nj->n", d, cov[r, :3, :3], d)
            v_b = np.einsum("ni,nij,nj->n", d, block[:, :3, :3], d)
            block[:, :3, :3] += (v_a - v_b)[:, None, None] * d[:, :, None] * d[:, None, :]
        m = np.array(mine)
        cov[r[:, None], m[None, :], :] = 0.0
        cov[r[:, None], :, m[None, :]] = 0.0
        cov[r[:, None, None], m[None, :, None], m[None, None, :]] = block
    alerts = {name: spans for name, spans in after.alerts.items() if name not in ("tilt", "bias")}
    return dataclasses.replace(after, q_nb=q, gyro_bias_b=bg, cov=cov, alerts=alerts)


def _alert_seconds(est: Estimate) -> float:
    """How long the estimate failed the tilt check, s."""
    rows = est.alerts.get("tilt")
    return float(np.sum(rows[:, 1] - rows[:, 0])) if rows is not None and len(rows) else 0.0


def describe_choice(estimate: Estimate) -> str | None:
    """One line saying what auto ran for ``estimate`` (None when auto did not make it)."""
    meta = estimate.meta
    if "auto" not in meta:
        return None
    line = f"{estimate.filter} ran {meta['auto']} on {meta.get('sensors', '?')} ({meta.get('auto_reason', '')})"
    if meta.get("auto_ignored"):
        line += f"; not used by it: {meta['auto_ignored']}"
    if meta.get("auto_fallback"):
        line += f"; fell back from the INS: {meta['auto_fallback']}"
    return line
