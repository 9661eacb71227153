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
        if c["nees_check"] is not None:
            cell = format_cell(c["nees_check"]["nees_mean"])
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
    """The NEES check on more flights keeps the reproduction's runs as its first block and
    adds the next seeds: its block 0 is the reproduction's own figure, and the runs beyond
    it are exactly what a longer reproduction would have run."""
    from windahrs.experiments.reproduce import Case, case_key, nees_summary, run_reproduction

    case = Case(5.0, "ins-wind", "estimated", "", "ins")
    short = run_reproduction(2, duration=1.0, cases=[case], nees_runs=4)
    longer = run_reproduction(4, duration=1.0, cases=[case])
    row = short.cases[0]
    chk = row["nees_check"]
    assert chk["runs"] == 4 and chk["block_runs"] == 2 and len(chk["blocks_in_band"]) == 2
    assert chk["blocks_in_band"][0] == row["nees_in_band"]
    key = case_key(case)
    np.testing.assert_array_equal(short.nees[key], longer.nees[key])
    assert chk["nees_mean"] == pytest.approx(longer.cases[0]["nees_mean"])
    assert chk["band"] == pytest.approx(nees_summary(longer.nees[key])["band"])
    assert longer.cases[0]["nees_check"] is None
    # Everything but the NEES comes from the reproduction's runs alone.
    assert row["rmse_steady_deg"] == run_reproduction(2, duration=1.0, cases=[case]).cases[0]["rmse_steady_deg"]
    with pytest.raises(ValueError, match="nees_runs"):
        run_reproduction(2, duration=1.0, cases=[case], nees_runs=1)


def test_reproduce_refuses_fewer_nees_runs_than_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["reproduce", "--runs", "3", "--nees-runs", "2", "--out", str(tmp_path)]) == 2
    assert "--nees-runs: expected an integer >= --runs (3), found 2" in capsys.readouterr().err
