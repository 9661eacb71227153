"""``windahrs report``: the page built from estimators on one flight (content, numbers
consistent with metrics.score, sensor summary, missing parts said so), the page in
headless Chromium, and the CLI (report and compare --align)."""

from __future__ import annotations

import html
import json
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from browser import dom_images, render_in_chromium, require_chromium
from conftest import require_data
from windahrs.cli import main
from windahrs.estimate import Estimate, Innovations
from windahrs.experiments.align import apply_alignment, estimate_alignment
from windahrs.filters.registry import make_estimator, names
from windahrs.flight import Flight, ImuStream, Reference
from windahrs.metrics import score
from windahrs.report.html import format_cell
from windahrs.report.log_report import (
    SATURATION_REPEATS,
    build_log_report,
    describe_alignment,
    stream_stats,
)
from windahrs.rotation import euler_from_quat, quat_conj, quat_from_euler, quat_mul
from windahrs.sim.scenario import make_scenario, simulate
from windahrs.store import save_flight

HAVE_VQF = "vqf" in names()
MOUNT_RPY_DEG = (1.0, -2.0, 3.0)
REF_LATE_S = 0.05


# ---------------------------------------------------------------------------------------
# helpers


class _Tables(HTMLParser):
    """Every <table> of a page: caption and body rows as cell texts."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: list[tuple[str, list[list[str]]]] = []
        self._text: list[str] | None = None
        self._row: list[str] | None = None
        self._in_body = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "table":
            self.tables.append(("", []))
        elif tag == "tbody":
            self._in_body = True
        elif tag == "tr" and self._in_body:
            self._row = []
        elif tag in ("td", "caption"):
            self._text = []

    def handle_endtag(self, tag: str) -> None:
        if tag == "caption" and self._text is not None:
            self.tables[-1] = ("".join(self._text), self.tables[-1][1])
            self._text = None
        elif tag == "td" and self._text is not None and self._row is not None:
            self._row.append("".join(self._text))
            self._text = None
        elif tag == "tr" and self._row is not None:
            self.tables[-1][1].append(self._row)
            self._row = None
        elif tag == "tbody":
            self._in_body = False

    def handle_data(self, data: str) -> None:
        if self._text is not None:
            self._text.append(data)


def tables(page: str) -> dict[str, list[list[str]]]:
    p = _Tables()
    p.feed(page)
    return {caption: rows for caption, rows in p.tables}


def table_starting(page: str, prefix: str) -> list[list[str]]:
    found = [rows for caption, rows in tables(page).items() if caption.startswith(prefix)]
    assert len(found) == 1, (prefix, list(tables(page)))
    return found[0]


def score_cells(est: Estimate, flight: Flight, spec: str) -> list[str]:
    s = score(est, flight)
    return [spec, *(format_cell(v) for v in (*s.rmse_from50_deg, *s.rmse_steady_deg, s.rmse_tilt_deg,
                                             s.rmse_total_deg))]


def headings(page: str) -> list[str]:
    return [html.unescape(h) for h in re.findall(r"<h2>(.*?)</h2>", page)]


def with_reference(flight: Flight) -> Flight:
    """The simulation as a recording would have it: truth replaced by an autopilot-like
    reference at 50 Hz, mounted MOUNT_RPY_DEG off the IMU and stamped REF_LATE_S late."""
    tr = flight.truth
    assert tr is not None
    q_mount = quat_from_euler(np.radians(MOUNT_RPY_DEG))
    ref = Reference(t=tr.t[::4] + REF_LATE_S, q_nb=quat_mul(tr.q_nb[::4], quat_conj(q_mount)), kind="autopilot")
    return flight.replace(truth=None, reference=ref)


# ---------------------------------------------------------------------------------------
# fixtures: one short simulated flight, estimators run once


@pytest.fixture(scope="module")
def sim() -> Flight:
    # The paper's scenario rotates from the start (the fixed wing flies level for its first seconds).
    return simulate(make_scenario("paper", wind=5.0, duration=10.0), np.random.default_rng(7))


@pytest.fixture(scope="module")
def sim_results(sim: Flight) -> list[tuple[str, Estimate]]:
    specs = ["mekf", "ins-wind", "mekf:mag_mode=heading"] + (["vqf"] if HAVE_VQF else [])
    return [(s, make_estimator(s).run(sim)) for s in specs]


@pytest.fixture(scope="module")
def sim_page(sim: Flight, sim_results: list[tuple[str, Estimate]]) -> str:
    return build_log_report(sim, sim_results, failures={"paper:wind=oracle": "a made-up reason <b>"})


# ---------------------------------------------------------------------------------------
# the page from a simulated flight


def test_report_has_every_section_and_is_self_contained(sim_page: str) -> None:
    assert headings(sim_page) == ["What was run", "Sensors", "Attitude against the reference",
                                  "Innovations and NIS", "Wind"]
    assert sim_page.startswith("<!DOCTYPE html>")
    for ref in ("http://", "https://", "<script", "<link", "url("):
        assert ref not in sim_page
    assert "a made-up reason &lt;b&gt;" in sim_page  # escaped
    assert "Estimates are scored against the simulation truth." in sim_page


def test_score_table_matches_metrics_score(sim: Flight, sim_results: list[tuple[str, Estimate]],
                                           sim_page: str) -> None:
    rows = table_starting(sim_page, "RMSE [deg] against the truth")
    assert rows == [score_cells(est, sim, spec) for spec, est in sim_results]


def test_estimators_table_lists_runs_and_failures(sim_results: list[tuple[str, Estimate]], sim_page: str) -> None:
    rows = table_starting(sim_page, "Estimators")
    assert [r[0] for r in rows] == [s for s, _ in sim_results] + ["paper:wind=oracle"]
    assert rows[-1][1] == "not run: a made-up reason <b>"
    by = {r[0]: r for r in rows}
    assert "wind" in by["ins-wind"][2] and "wind" not in by["mekf"][2]
    assert by["ins-wind"][3] == ", ".join(dict(sim_results)["ins-wind"].innovations)
    if HAVE_VQF:
        assert by["vqf"][3] == "none logged"
        assert "No innovations from vqf" in sim_page


def test_innovation_table_counts_every_update(sim_results: list[tuple[str, Estimate]], sim_page: str) -> None:
    rows = table_starting(sim_page, "Innovation consistency per sensor")
    expected = []
    for spec, est in sim_results:
        for sensor, inn in est.innovations.items():
            nis = inn.nis[np.isfinite(inn.nis)]
            expected.append([spec, sensor, str(inn.dim), str(len(inn.t)), format_cell(100 * np.mean(inn.accepted)),
                             format_cell(float(np.mean(nis)))])
    assert [r[:6] for r in rows] == expected
    # heading-only magnetometer updates are 1-dim, the vector ones 3-dim: separate figures
    assert "NIS of the mag (1-dim) updates" in sim_page and "NIS of the mag (3-dim) updates" in sim_page


def test_wind_table_against_the_true_wind(sim: Flight, sim_results: list[tuple[str, Estimate]],
                                          sim_page: str) -> None:
    rows = table_starting(sim_page, "Wind (velocity of the air, NED)")
    assert [r[0] for r in rows] == ["ins-wind", "true wind"]
    est = dict(sim_results)["ins-wind"]
    assert sim.truth is not None and sim.truth.wind_n is not None and est.wind_n is not None
    late = est.t >= 0.5 * (sim.imu.t[0] + sim.imu.t[-1])
    d = est.wind_n[late] - sim.truth.wind_n[late]  # the truth is on the IMU grid: no interpolation
    assert rows[0][1] == format_cell(float(np.mean(est.wind_n[late, 0])))
    assert rows[0][6] == format_cell(float(np.sqrt(np.mean(np.sum(d[:, :2] ** 2, axis=1)))))
    assert rows[1][6] == "–"
    assert "Without wind states: mekf" in sim_page


def test_sensor_table(sim: Flight, sim_page: str) -> None:
    rows = {r[0]: r for r in table_starting(sim_page, "Sensor streams")}
    assert list(rows) == ["imu", "mag", "gnss", "air"]
    assert rows["imu"][1:6] == ["2001", "200", "0.00500", "0", "0"]
    assert rows["air"][1:3] == ["501", "50.0"]


def test_report_is_deterministic(sim: Flight) -> None:
    bare = sim.replace(truth=None, air=None, gnss=None)
    est = Estimate("plain", bare.imu.t, np.tile([1.0, 0.0, 0.0, 0.0], (len(bare.imu.t), 1)))
    assert build_log_report(bare, [("plain", est)]) == build_log_report(bare, [("plain", est)])


# ---------------------------------------------------------------------------------------
# what is missing is said, not an error


def test_flight_without_reference_or_wind(sim: Flight) -> None:
    bare = sim.replace(truth=None, air=None)
    est = Estimate("plain", bare.imu.t, np.tile([1.0, 0.0, 0.0, 0.0], (len(bare.imu.t), 1)))
    page = build_log_report(bare, [("plain", est)])
    assert headings(page) == ["What was run", "Sensors", "Attitude", "Innovations and NIS", "Wind"]
    assert "neither simulation truth nor a reference attitude" in page
    assert "Attitude error" not in page and "RMSE [deg]" not in page
    assert "No innovations from plain" in page
    assert "None of the estimators estimates wind (plain)." in page
    assert "The flight carries no wind of its own" in page
    assert page.count("<img ") == 1  # the attitude only


def test_report_of_failures_only_and_bad_input(sim: Flight) -> None:
    page = build_log_report(sim, [], failures={"mekf-air": "needs air data"})
    assert headings(page) == ["What was run", "Sensors"]
    with pytest.raises(ValueError, match="results: expected at least one"):
        build_log_report(sim, [])
    est = Estimate("x", sim.imu.t, np.tile([1.0, 0.0, 0.0, 0.0], (len(sim.imu.t), 1)))
    al = estimate_alignment(Estimate("truth", sim.truth.t, sim.truth.q_nb), with_reference(sim))  # type: ignore[union-attr]
    with pytest.raises(ValueError, match="expected a reference attitude to align"):
        build_log_report(sim, [("x", est)], alignment=al)


def test_report_says_what_was_repaired(sim: Flight) -> None:
    est = Estimate("x", sim.imu.t, np.tile([1.0, 0.0, 0.0, 0.0], (len(sim.imu.t), 1)))
    bare = sim.replace(truth=None, air=None, gnss=None)
    assert "repaired" not in build_log_report(bare, [("x", est)])
    page = build_log_report(bare.replace(repairs={"imu": {"duplicates": 2, "out_of_range": 1}}), [("x", est)])
    assert ("Input repaired at the edge (windahrs.repair), so each estimator saw it repaired: imu: 2 samples with a "
            "repeated time stamp dropped, 1 sample beyond the sensor range set to NaN.") in html.unescape(page)


def test_innovations_with_nan_nis_and_rejections(sim: Flight) -> None:
    t = sim.imu.t[::10]
    nis = np.full(len(t), 2.0)
    nis[:5] = np.nan  # e.g. an accelerometer update skipped
    acc = np.ones(len(t), dtype=bool)
    acc[:10] = False
    inn = Innovations(t=t, nu=np.zeros((len(t), 2)), nis=nis, accepted=acc)
    est = Estimate("odd", sim.imu.t, sim.truth.q_nb.copy(), innovations={"thing": inn})  # type: ignore[union-attr]
    bare = sim.replace(truth=None, air=None, gnss=None)  # fewer figures to draw
    rows = table_starting(build_log_report(bare, [("odd", est)]), "Innovation consistency")
    assert rows == [["odd", "thing", "2", str(len(t)), format_cell(100 * (len(t) - 10) / len(t)), "2.00", "2.00",
                     "2", "100"]]


# ---------------------------------------------------------------------------------------
# the sensor summary's definitions


def test_stream_stats_gaps_nan_and_saturation() -> None:
    t = np.arange(1000) * 0.01
    t[500:] += 0.5  # one gap of 0.51 s
    t[800:] += 0.025  # a step of 0.035 s: over 3 median steps too
    w = 0.1 * np.sin(np.arange(1000) / 30.0)[:, None] * np.ones(3)
    w[100:104, 0] = 5.0  # x clipped at 5 rad/s for 4 samples
    w[200, 1] = -0.3  # y peaks once: not saturation
    f = np.tile([0.0, 0.0, -9.81], (1000, 1))
    f[300] = np.nan
    flight = Flight(imu=ImuStream(t=t, w_b=w, f_b=f))
    (s,) = stream_stats(flight)
    assert (s.samples, s.gaps, s.nan_rows) == (1000, 2, 1)
    assert s.rate_hz == pytest.approx(100.0)
    assert s.largest_gap_s == pytest.approx(0.51)
    # accel z sits at 9.81 in every sample: a constant counts as a repeated extreme too
    assert s.saturated == 999
    assert s.saturated_channels == "gyro x at 5.00 rad/s x4; accel z at 9.81 m/s^2 x999"
    assert s.largest == "gyro 5.00 rad/s, accel 9.81 m/s^2"
    f2 = f + np.random.default_rng(0).normal(0, 0.01, f.shape)
    (s2,) = stream_stats(flight.replace(imu=ImuStream(t=t, w_b=w, f_b=f2)))
    assert s2.saturated == 4 and s2.saturated_channels == "gyro x at 5.00 rad/s x4"
    assert SATURATION_REPEATS == 3


# ---------------------------------------------------------------------------------------
# alignment


def test_aligned_report_shows_both_score_tables(sim: Flight) -> None:
    recording = with_reference(sim)
    assert sim.truth is not None
    perfect = Estimate("perfect", sim.truth.t, sim.truth.q_nb)
    al = estimate_alignment(perfect, recording)
    assert al.mount_angle_deg == pytest.approx(3.7555, abs=1e-3)
    assert al.time_offset_s == pytest.approx(REF_LATE_S, abs=1e-4)
    est = make_estimator("mekf").run(recording)
    page = build_log_report(recording, [("mekf", est), ("perfect", perfect)], alignment=al, aligned_on="perfect")
    assert "R" + describe_alignment(al, "perfect")[1:] in html.unescape(page)
    assert "Estimates are scored against the autopilot&#x27;s own estimate." in page
    aligned = table_starting(page, "RMSE [deg] against the aligned reference")
    assert aligned == [score_cells(est, apply_alignment(recording, al), "mekf"),
                       score_cells(perfect, apply_alignment(recording, al), "perfect")]
    assert float(aligned[1][-1]) < 0.05  # what remains of the truth against its aligned copy
    logged = table_starting(page, "RMSE [deg] against the autopilot's estimate as logged")
    assert logged[1][-1] == format_cell(score(perfect, recording).rmse_total_deg)
    assert float(logged[1][-1]) > 3.0
    assert "Warning:" not in page


# ---------------------------------------------------------------------------------------
# real logs


def test_report_on_px4_sample_log() -> None:
    from windahrs.io import read_flight

    flight = read_flight(require_data("px4", "sample.ulg"))
    est = make_estimator("mekf").run(flight)
    al = estimate_alignment(est, flight)
    page = build_log_report(flight, [("mekf", est)], alignment=al, aligned_on="mekf")
    assert table_starting(page, "RMSE [deg] against the aligned reference") == [
        score_cells(est, apply_alignment(flight, al), "mekf")
    ]
    assert table_starting(page, "RMSE [deg] against the autopilot's estimate as logged") == [
        score_cells(est, flight, "mekf")
    ]
    sensors = {r[0]: r for r in table_starting(page, "Sensor streams")}
    assert list(sensors) == ["imu", "mag", "reference (autopilot)"]
    assert sensors["imu"][1:3] == ["17070", "250"]
    assert "The flight carries no wind of its own" in page


def test_report_on_alfa_sequence_compares_the_logs_wind() -> None:
    from windahrs.io import read_flight

    flight = read_flight(require_data("alfa", "carbonZ_2018-07-18-15-53-31_1_engine_failure"))
    results = [(s, make_estimator(s).run(flight)) for s in ("mekf", "ins-wind")]
    page = build_log_report(flight, results)
    assert [r[0] for r in table_starting(page, "Wind (velocity of the air")] == ["ins-wind", "log's wind"]
    assert table_starting(page, "RMSE [deg] against the autopilot's estimate") == [
        score_cells(est, flight, s) for s, est in results
    ]
    sensors = {r[0]: r for r in table_starting(page, "Sensor streams")}
    assert list(sensors) == ["imu", "mag", "gnss", "air", "reference (autopilot)", "log wind"]
    assert sensors["imu"][2] == "10.1" and sensors["reference (autopilot)"][2] == "2.48"


# ---------------------------------------------------------------------------------------
# in a real browser


def test_report_renders_in_headless_chromium(sim_page: str, tmp_path: Path) -> None:
    require_chromium()
    page = tmp_path / "report.html"
    page.write_text(sim_page, encoding="utf-8")
    shot, dom, console_errors = render_in_chromium(page, screenshot=tmp_path / "shot.png")
    assert console_errors == []
    pixels = imread(shot)
    assert pixels.shape[:2] == (2000, 1200)
    assert float(np.var(pixels[..., :3])) > 1e-3
    assert "Innovation consistency per sensor" in dom
    images = dom_images(dom)
    assert len(images) == sim_page.count("<img ") and len(images) >= 5
    assert all(im.natural_width == 900 for im in images)


# ---------------------------------------------------------------------------------------
# the command line


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory, sim: Flight) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("logreport")
    quad = simulate(make_scenario("quadrotor", wind=3.0, duration=5.0), np.random.default_rng(3))
    out = {"truth": d / "truth.h5", "recording": d / "recording.h5", "quad": d / "quad.h5", "bare": d / "bare.h5"}
    save_flight(sim, out["truth"])
    save_flight(with_reference(sim), out["recording"])
    save_flight(quad, out["quad"])
    save_flight(quad.replace(gnss=None, truth=None), out["bare"])
    return out


def test_cli_report_lists_a_filter_that_cannot_run(files: dict[str, Path], tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r.html"
    assert main(["report", str(files["quad"]), "--filters", "mekf,mekf-air", "--out", str(out)]) == 0
    std = capsys.readouterr()
    assert f"wrote {out}" in std.out
    assert "filter mekf-air not run: filter 'mekf-air' needs air data" in std.err
    page = out.read_text(encoding="utf-8")
    rows = table_starting(page, "Estimators")
    assert rows[1][:2] == ["mekf-air", "not run: filter 'mekf-air' needs air data ('air'), which the flight does "
                                       "not have"]
    assert "<title>windahrs report: quad.h5</title>" in page


def test_cli_report_fails_when_no_filter_runs(files: dict[str, Path], tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r.html"
    assert main(["report", str(files["quad"]), "--filters", "mekf-air", "--out", str(out)]) == 2
    assert "--filters: no filter could run" in capsys.readouterr().err
    assert main(["report", str(files["quad"]), "--filters", "mekf,nope", "--out", str(out)]) == 2
    assert "unknown 'nope'" in capsys.readouterr().err
    assert not out.exists()


def test_cli_report_defaults_and_align_without_reference(files: dict[str, Path], tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r.html"
    assert main(["report", str(files["bare"]), "--align", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "--align: the flight has no reference attitude; nothing to align" in err
    page = out.read_text(encoding="utf-8")
    ran = [r[0] for r in table_starting(page, "Estimators")]
    assert ran == (["auto", "mekf", "vqf"] if HAVE_VQF else ["auto", "mekf"])
    assert "auto ran mekf on imu,mag (no GNSS velocity)." in page
    assert "Default filter ins-wind left out: filter &#x27;ins-wind&#x27; needs GNSS velocity" in page


def test_cli_report_with_align(files: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from windahrs.store import load_flight

    out = tmp_path / "r.html"
    assert main(["report", str(files["recording"]), "--filters", "mekf", "--align", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    flight = load_flight(files["recording"])
    al = estimate_alignment(make_estimator("mekf").run(flight), flight)
    assert describe_alignment(al, "mekf") in text
    assert "against the aligned reference" in out.read_text(encoding="utf-8")


def test_cli_compare_align(files: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    from windahrs.store import load_flight

    capsys.readouterr()
    assert main(["compare", str(files["recording"]), "--filters", "mekf,ins-wind", "--align"]) == 0
    text = capsys.readouterr().out
    flight = load_flight(files["recording"])
    est = make_estimator("mekf").run(flight)
    al = estimate_alignment(est, flight)
    line = describe_alignment(al, "mekf")
    assert text.startswith(line + "\n")
    m = re.search(r"mount (\S+) deg .* time offset (\S+) ms", line)
    assert m is not None
    assert float(m[1]) == pytest.approx(al.mount_angle_deg, abs=1e-3)
    assert float(m[2]) == pytest.approx(al.time_offset_s * 1e3, abs=0.05)
    assert "RMSE in deg against autopilot (aligned)" in text
    sc = score(est, apply_alignment(flight, al))
    assert f"{sc.rmse_tilt_deg:8.3f}{sc.rmse_total_deg:8.3f}" in text.splitlines()[3]

    assert main(["compare", str(files["recording"]), "--filters", "mekf,ins-wind", "--align", "--json"]) == 0
    std = capsys.readouterr()
    rows = json.loads(std.out)
    assert line in std.err
    assert [r["aligned_on"] for r in rows] == ["mekf", "mekf"]
    assert rows[0]["mount_deg"] == pytest.approx(al.mount_angle_deg)
    assert rows[0]["time_offset_s"] == pytest.approx(al.time_offset_s)
    # the whole alignment is in the JSON, not only in the stderr line
    assert rows[0]["mount_rpy_deg"] == pytest.approx(np.degrees(euler_from_quat(al.q_mount)).tolist())
    assert rows[0]["mount_q"] == pytest.approx(al.q_mount.tolist())
    assert rows[0]["residual_deg"] == pytest.approx(al.residual_deg)
    assert rows[0]["rate_agreement"] == pytest.approx(al.correlation)
    assert rows[0]["samples"] == al.samples and rows[0]["warning"] is None
    keys = set(rows[0]) - set(sc.as_dict())
    assert keys == {"aligned_on", "mount_deg", "mount_rpy_deg", "mount_q", "time_offset_s", "rate_agreement",
                    "residual_deg", "samples", "warning", "gnss_time_shift_s", "gnss_timing_sigma_s"}
    assert {k: rows[0][k] for k in keys} == {k: rows[1][k] for k in keys}  # one alignment for every filter
    assert rows[0]["rmse_total_deg"] == pytest.approx(sc.rmse_total_deg)

    # a simulation's truth needs no alignment: scored as is, and said so
    assert main(["compare", str(files["truth"]), "--filters", "mekf", "--align"]) == 0
    std = capsys.readouterr()
    assert "simulation truth is in the estimators' frame" in std.err
    assert "RMSE in deg against truth;" in std.out


@pytest.mark.parametrize("command", ["report", "compare"])
def test_align_help_says_which_estimate(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "FIRST filter's estimate" in text
    # the help names only options the command has (report has no --json)
    assert ("--json" in text) == (command == "compare")
