"""``windahrs reproduce`` end to end on a tiny configuration: the files exist, the three
outputs carry the same numbers, and the report renders in headless Chromium."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from browser import dom_images, render_in_chromium, require_chromium
from windahrs.cli import main
from windahrs.report.html import format_cell


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("rep")
    assert main(["reproduce", "--runs", "1", "--nees-runs", "2", "--duration", "2", "--out", str(out)]) == 0
    return out


def test_outputs_exist_and_follow_the_schema(out_dir: Path) -> None:
    data = json.loads((out_dir / "results.json").read_text())
    keys = {"wind", "filter", "wind_model", "rmse_from50_deg", "rmse_steady_deg", "convergence_samples",
            "pcrb_ratio", "nees_in_band"}
    assert data["cases"] and all(keys <= set(c) for c in data["cases"])
    assert {c["wind"] for c in data["cases"]} == {0.0, 5.0, 8.0}
    models = {c["wind_model"] for c in data["cases"]}
    assert models <= {"oracle", "mean", "estimated", "none"} and {"oracle", "mean", "none"} <= models
    ins = [c for c in data["cases"] if c["filter"] == "ins-wind"]
    assert ins and all(c["pcrb_ratio"] is not None and len(c["pcrb_ratio"]) == 3 for c in ins)
    assert all(c["nees_check"]["runs"] == 2 and len(c["nees_check"]["blocks_in_band"]) == 2 for c in ins)
    assert data["meta"]["nees_runs"] == 2
    for name in ("fig4.png", "fig5.png", "fig6.png", "results.md", "report.html"):
        assert (out_dir / name).stat().st_size > 1000, name


def test_json_markdown_and_html_agree(out_dir: Path) -> None:
    data = json.loads((out_dir / "results.json").read_text())
    md = (out_dir / "results.md").read_text()
    html = (out_dir / "report.html").read_text()
    for c in data["cases"]:
        cell = " / ".join(f"{x:.2f}" for x in c["rmse_from50_deg"])
        assert cell in md and cell in html, (c["filter"], cell)
        assert format_cell(c["convergence_samples"]) in md
    for claim in data["claims"]:
        assert claim["numbers"] in md
    for c in data["cases"]:
        chk = c["nees_check"]
        if chk is not None:
            passing = sum(f >= 0.9 for f in chk["blocks_in_band"])
            cells = (format_cell(chk["nees_mean"]), f"{100 * chk['in_band']:.1f} % in [{chk['band'][0]:.2f}, ",
                     f"{passing} of {len(chk['blocks_in_band'])}")
            for cell in cells:
                assert cell in md and cell in html, (c["filter"], cell)
    assert np.isfinite([v for c in data["cases"] for v in c["rmse_steady_deg"]]).all()


def test_report_renders_in_headless_chromium(out_dir: Path) -> None:
    require_chromium()
    shot, dom, errors = render_in_chromium(out_dir / "report.html")
    assert errors == []
    assert "The paper's claims" in dom
    images = dom_images(dom)
    assert len(images) >= 3 and all(i.src.startswith("data:image/png") for i in images)
    assert all(i.natural_width and i.natural_width > 100 for i in images)
    png = Path(shot).read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_nees_check_extends_the_reproduction_runs_with_the_same_seed_sequence() -> None:
    """The NEES check on more flights keeps the reproduction's runs first and adds the next
    seeds: its runs are exactly what a longer reproduction would have run."""
    from windahrs.experiments.reproduce import Case, case_key, run_reproduction

    case = Case(5.0, "ins-wind", "estimated", "", "ins")
    short = run_reproduction(2, duration=1.0, cases=[case], nees_runs=4, bound_fn=None)
    longer = run_reproduction(4, duration=1.0, cases=[case], bound_fn=None)
    key = case_key(case)
    np.testing.assert_array_equal(short.nees[key], longer.nees[key])
    row = short.cases[0]
    assert row["nees_check"]["runs"] == 4 and row["nees_check"]["block_runs"] == 2
    assert row["nees_check"]["blocks_in_band"][0] == row["nees_in_band"]
    assert longer.cases[0]["nees_check"] is None
    with pytest.raises(ValueError, match="nees_runs"):
        run_reproduction(2, duration=1.0, cases=[case], nees_runs=1)


def test_nees_summary_and_check_on_known_series() -> None:
    """The band of SPEC 6.3 (n = 6, N = 50: [5.08, 7.00]), only second-half steps counted,
    and blocks cut by runs: on series built to land in or out of the band."""
    from windahrs.experiments.reproduce import nees_check, nees_summary

    nees = np.full((100, 10), 6.0)
    nees[:, :5] = 100.0  # first half: out of any band, must not count
    nees[:50, 8:] = 7.2  # block 0: above its band at the last 2 of 5 second-half steps
    s = nees_summary(nees[:50])
    assert s["band"] == pytest.approx([5.08, 7.00], abs=0.005)
    assert s["in_band"] == pytest.approx(0.6) and s["nees_mean"] == pytest.approx((3 * 6 + 2 * 7.2) / 5)
    c = nees_check(nees, 50)
    assert c["blocks_in_band"] == [pytest.approx(0.6), 1.0]
    # over 100 runs the run-average is 6.6 at those steps, inside [5.34, 6.70]
    assert c["band"] == pytest.approx([5.34, 6.70], abs=0.005) and c["in_band"] == 1.0


def test_reproduce_refuses_fewer_nees_runs_than_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["reproduce", "--runs", "3", "--nees-runs", "2", "--out", str(tmp_path)]) == 2
    assert "--nees-runs: expected an integer >= the runs per case (3), found 2" in capsys.readouterr().err


def test_nees_runs_default_is_eight_blocks_and_none_extra_with_quick() -> None:
    from windahrs.cli import UsageError, reproduce_nees_runs

    assert reproduce_nees_runs(50, False, None) == 400
    assert reproduce_nees_runs(5, True, None) == 5
    assert reproduce_nees_runs(5, True, 40) == 40
    with pytest.raises(UsageError, match=r"runs per case \(5\), found 3"):
        reproduce_nees_runs(5, True, 3)


def test_progress_total_counts_every_progress_call() -> None:
    from windahrs.experiments.reproduce import Case, progress_total, run_reproduction

    cases = [Case(5.0, "ins-wind", "estimated", "", "ins"), Case(5.0, "madgwick", "none")]
    calls: list[tuple[str, int, int]] = []
    run_reproduction(1, duration=1.0, cases=cases, nees_runs=3, progress=lambda *a: calls.append(a), bound_fn=None)
    assert len(calls) == progress_total(cases, 1, 3) == 4
    assert [c[0] for c in calls[-2:]] == ["5 m/s | ins-wind (NEES check)"] * 2 and calls[-1][1:] == (3, 3)


def test_python_caller_gets_the_pcrb_ratios_by_default() -> None:
    """run_reproduction bounds the physically tuned cases with the PCRB of ``windahrs
    reproduce`` unless told not to (``bound_fn=None``); other cases have no ratio."""
    from windahrs.experiments.reproduce import Case, run_reproduction

    cases = [Case(5.0, "mekf", "none", "", "gravity"), Case(5.0, "paper", "oracle", "fig4")]
    res = run_reproduction(1, duration=1.0, cases=cases)
    ratio = res.cases[0]["pcrb_ratio"]
    assert ratio is not None and len(ratio) == 3 and all(np.isfinite(ratio)) and min(ratio) > 0.1
    assert res.cases[1]["pcrb_ratio"] is None
    assert "5 m/s | gravity" in res.bounds
    none = run_reproduction(1, duration=1.0, cases=cases[:1], bound_fn=None)
    assert none.cases[0]["pcrb_ratio"] is None and none.bounds == {}


def test_a_cluster_is_warmed_once_per_compiled_family_before_the_work() -> None:
    """With a ``submit`` (a cluster), each family of estimators sharing a compiled loop runs
    once on a short flight first, and only then is the real work submitted: the additive
    filters (paper, paper-nowind, ekf) once, the error-state ones (mekf, ins-wind) once."""
    from windahrs.experiments.cluster import serial_submit
    from windahrs.experiments.reproduce import Case, _flight_task, _warm_task, run_reproduction

    cases = [Case(5.0, f, "oracle" if f == "paper" else "none") for f in ("paper", "mekf", "paper-nowind", "ekf")]
    cases.append(Case(5.0, "ins-wind", "estimated"))
    calls: list[tuple[object, ...]] = []

    def put(fn: object, *args: object) -> object:
        calls.append((fn, *args))
        return serial_submit(fn, *args)  # type: ignore[arg-type]

    run_reproduction(1, duration=1.0, cases=cases, bound_fn=None, submit=put)
    warm = [c for c in calls if c[0] is _warm_task]
    assert [c[1].filter for c in warm] == ["paper", "mekf"]  # type: ignore[union-attr]
    assert calls[: len(warm)] == warm and any(c[0] is _flight_task for c in calls[len(warm):])
