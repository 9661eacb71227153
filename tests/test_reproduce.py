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
    assert main(["reproduce", "--runs", "1", "--duration", "2", "--out", str(out)]) == 0
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
