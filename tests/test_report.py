"""Report package: PNG figures, tables (HTML and Markdown from one source), the
self-contained HTML page, atomic writes, and the page as a real browser renders it."""

from __future__ import annotations

import io
import math
import os
import re
import subprocess
import sys
from html.parser import HTMLParser

import matplotlib
import numpy as np
import pytest
from matplotlib.image import imread

from browser import dom_images, render_in_chromium, require_chromium
from windahrs.report import (
    Image,
    Section,
    Table,
    error_vs_bound_png,
    error_vs_sample_png,
    format_cell,
    grouped_bars_png,
    markdown_table,
    render_html,
    timeseries_png,
    write_html,
)
from windahrs.report.figures import MAX_POINTS, _line, _percentiles_over_runs

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MAX_PNG_BYTES = 150_000


# ---------------------------------------------------------------------------------------
# data and helpers


def _errors(rng: np.random.Generator, runs: int, n: int, sigma_deg: float) -> np.ndarray:
    """Converging attitude errors in rad, (runs, n, 3): a decaying initial error plus noise."""
    k = np.arange(n)[None, :, None]
    initial = np.radians(15.0) * rng.standard_normal((runs, 1, 3))
    return initial * np.exp(-k / (n / 6)) + np.radians(sigma_deg) * rng.standard_normal((runs, n, 3))


def _figures(rng: np.random.Generator) -> dict[str, bytes]:
    n = 600
    t = np.arange(n) * 0.02
    bound = 0.3 + 5.0 * np.exp(-t[:, None] / 2.0) * np.ones(3)
    att = np.degrees(np.c_[0.3 * np.sin(t), 0.2 * np.cos(0.7 * t), 0.05 * t])
    return {
        "error_vs_sample": error_vs_sample_png(
            {"paper EKF": _errors(rng, 20, n, 1.0), "MEKF": _errors(rng, 20, n, 0.5)},
            "Attitude error vs samples",
            max_samples=500,
        ),
        "error_vs_bound": error_vs_bound_png({"MEKF": 1.1 * bound, "EKF": 1.6 * bound}, bound, "RMSE vs PCRB", t=t),
        "timeseries": timeseries_png(
            t,
            {"estimate": att + rng.normal(0, 0.3, att.shape), "reference": (t[::2], att[::2])},
            "angle [deg]",
            "Attitude vs reference",
            panels=["roll", "pitch", "yaw"],
            reference="reference",
        ),
        "nis": timeseries_png(
            t, {"mag": rng.chisquare(3, n)}, "NIS", "NIS", hlines={"2.5 %": 0.216, "97.5 %": 9.35}, logy=True
        ),
        "bars": grouped_bars_png(
            {"EKF": [1.2, 0.9, 3.4], "MEKF": [0.5, 0.4, math.nan]}, ["roll", "pitch", "yaw"], "RMSE [deg]", "RMSE"
        ),
    }


@pytest.fixture(scope="module")
def figures() -> dict[str, bytes]:
    return _figures(np.random.default_rng(7))


def _decode(png: bytes) -> np.ndarray:
    return imread(io.BytesIO(png), format="png")


class _TableCells(HTMLParser):
    """Text of every <td> of an HTML document, row by row."""

    def __init__(self) -> None:
        super().__init__()
        self.rows: list[list[str]] = []
        self._in_td = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "tr":
            self.rows.append([])
        elif tag == "td":
            self._in_td = True
            self.rows[-1].append("")

    def handle_endtag(self, tag: str) -> None:
        if tag == "td":
            self._in_td = False

    def handle_data(self, data: str) -> None:
        if self._in_td:
            self.rows[-1][-1] += data


def _results_table() -> Table:
    return Table(
        ["filter", "roll [deg]", "pitch [deg]", "yaw [deg]", "runs"],
        [
            ["paper EKF", 1.23456, 0.0123456, 12.3456, 100],
            ["MEKF", np.float64(0.5), np.float32(1234.56), None, np.int64(100)],
            ["UKF", 9.996, 1.234e-5, math.nan, 100],
        ],
        caption="RMSE over 100 runs, from sample 50",
        highlight={(1, 1): "good", (0, 3): "bad"},
    )


# ---------------------------------------------------------------------------------------
# figures


@pytest.mark.parametrize("name", ["error_vs_sample", "error_vs_bound", "timeseries", "nis", "bars"])
def test_figure_is_a_small_non_blank_png(figures: dict[str, bytes], name: str) -> None:
    png = figures[name]
    assert png.startswith(PNG_SIGNATURE)
    assert 1_000 < len(png) < MAX_PNG_BYTES
    pixels = _decode(png)
    assert pixels.shape[:2] == (600, 900)  # 9 x 6 in at 100 dpi
    assert float(np.var(pixels[..., :3])) > 0.0
    assert np.all(pixels[2, 2, :3] == 1.0)  # pure white background, as the HTML page


def test_figures_leave_matplotlib_global_state_alone() -> None:
    rc_before = dict(matplotlib.rcParams)
    pyplot_before = "matplotlib.pyplot" in sys.modules
    _figures(np.random.default_rng(1))
    assert dict(matplotlib.rcParams) == rc_before
    assert ("matplotlib.pyplot" in sys.modules) == pyplot_before


def test_importing_report_does_not_import_matplotlib() -> None:
    code = "import sys, windahrs.report; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_long_series_are_reduced_but_keep_their_spikes() -> None:
    n = 250_000
    x = np.arange(n, dtype=np.float64)
    y = np.zeros(n)
    y[123_457] = 5.0
    y[200_001] = -3.0
    xl, yl = _line(x, y, MAX_POINTS)
    assert len(xl) == len(yl) <= MAX_POINTS
    assert yl.max() == 5.0 and yl.min() == -3.0
    assert np.all(np.diff(xl) >= 0)


def test_long_monte_carlo_figure_stays_small() -> None:
    rng = np.random.default_rng(3)
    png = error_vs_sample_png({"MEKF": _errors(rng, 3, 100_000, 0.5)}, "long")
    assert png.startswith(PNG_SIGNATURE) and len(png) < MAX_PNG_BYTES


def test_errors_in_degrees_draw_the_same_figure_as_in_radians() -> None:
    """The axes are in degrees whichever unit the errors come in (the reproduction's are
    in degrees, and were once labelled rad)."""
    rng = np.random.default_rng(4)
    err = _errors(rng, 3, 200, 0.5)
    rad = error_vs_sample_png({"MEKF": err}, "t")
    deg = error_vs_sample_png({"MEKF": np.degrees(err)}, "t", unit="deg")
    assert rad == deg


def test_percentiles_over_runs_match_numpy_nanpercentile() -> None:
    rng = np.random.default_rng(5)
    err = rng.standard_normal((9, 40, 3))
    err[rng.random(err.shape) < 0.3] = np.nan
    err[:, 3, 1] = np.nan  # an all-NaN column stays NaN
    q = (10.0, 50.0, 90.0)
    ours = _percentiles_over_runs(err, q)
    ok = ~np.isnan(err).all(axis=0)
    ref = np.nanpercentile(err[:, ok], q, axis=0)
    for o, r in zip(ours, ref, strict=True):
        np.testing.assert_allclose(o[ok], r, rtol=0, atol=1e-12)
        assert np.isnan(o[~ok]).all()


def test_figure_bad_input_names_the_field() -> None:
    with pytest.raises(ValueError, match=r"series\['MEKF'\]: expected shape \(runs, N, 3\)"):
        error_vs_sample_png({"MEKF": np.zeros((10, 3))}, "t")
    with pytest.raises(ValueError, match=r"max_samples"):
        error_vs_sample_png({"MEKF": np.zeros((2, 10, 3))}, "t", max_samples=0)
    with pytest.raises(ValueError, match=r"unit: expected 'rad' or 'deg', found 'grad'"):
        error_vs_sample_png({"MEKF": np.zeros((2, 10, 3))}, "t", unit="grad")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"rmse_deg\['EKF'\]: expected shape \(5, 3\)"):
        error_vs_bound_png({"EKF": np.ones((4, 3))}, np.ones((5, 3)), "t")
    with pytest.raises(ValueError, match=r"curves\['a'\]: expected 3 column\(s\)"):
        timeseries_png(np.arange(4.0), {"a": np.ones(4)}, "y", "t", panels=["x", "y", "z"])
    with pytest.raises(ValueError, match=r"reference"):
        timeseries_png(np.arange(4.0), {"a": np.ones(4)}, "y", "t", reference="truth")


# ---------------------------------------------------------------------------------------
# tables


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (1.23456, "1.23"),
        (0.0123456, "0.0123"),
        (12.3456, "12.3"),
        (1234.56, "1235"),
        (9.996, "10.0"),
        (0.5, "0.500"),
        (-0.5, "-0.500"),
        (1.234e-5, "1.23e-05"),
        (2.5e7, "2.50e+07"),
        (0.0, "0"),
        (math.nan, "nan"),
        (-math.inf, "-inf"),
        (np.float32(0.25), "0.250"),
        (100, "100"),
        (np.int64(7), "7"),
        (None, "–"),
        ("MEKF", "MEKF"),
    ],
)
def test_format_cell(value: object, text: str) -> None:
    assert format_cell(value) == text


def test_markdown_and_html_tables_show_the_same_numbers() -> None:
    table = _results_table()
    html_rows = _TableCells()
    html_rows.feed(table.to_html())
    html_cells = [r for r in html_rows.rows if r]
    md_lines = [ln for ln in table.to_markdown().splitlines() if ln.startswith("|")][2:]
    md_cells = [[c.strip().strip("*") for c in ln.strip("|").split(" | ")] for ln in md_lines]
    assert html_cells == md_cells == table.cells()
    assert table.cells()[1] == ["MEKF", "0.500", "1235", "–", "100"]
    # numeric columns right-aligned in Markdown; highlights as bold / italic
    assert table.to_markdown().splitlines()[3] == "|---|---:|---:|---:|---:|"
    assert "**0.500**" in table.to_markdown() and "*12.3*" in table.to_markdown()
    assert '<td class="num good">0.500</td>' in table.to_html()
    assert markdown_table(["a", "b"], [["x", 1.0]]) == "| a | b |\n|---|---:|\n| x | 1.00 |\n"


def test_tables_escape_html_and_markdown() -> None:
    evil = '<script>alert("x")</script> & |'
    table = Table([evil, "v"], [[evil, 1.0]], caption=evil)
    out = table.to_html()
    assert "<script>" not in out
    assert "&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt; &amp; |" in out
    md = table.to_markdown()
    assert md.count("\\|") == 3  # caption, header and cell: the pipe cannot break the table
    assert all(line.count(" | ") == 1 for line in md.splitlines() if line.startswith("| "))


def test_table_bad_input_names_the_field() -> None:
    with pytest.raises(ValueError, match=r"Table.rows\[1\]: expected 2 cells"):
        Table(["a", "b"], [[1, 2], [3]])
    with pytest.raises(ValueError, match=r"Table.highlight"):
        Table(["a"], [[1]], highlight={(1, 0): "good"})
    with pytest.raises(ValueError, match=r"'good' or 'bad'"):
        Table(["a"], [[1]], highlight={(0, 0): "best"})  # type: ignore[dict-item]
    with pytest.raises(TypeError, match=r"Table.rows\[0\]\[0\]"):
        Table(["a"], [[[1, 2]]])  # type: ignore[list-item]
    with pytest.raises(ValueError, match=r"Image.png: expected PNG bytes"):
        Image(b"GIF89a....", "caption")


def test_table_does_not_keep_or_modify_the_callers_lists() -> None:
    rows: list[list[str | float]] = [["a", 1.0]]
    table = Table(["k", "v"], rows)
    rows[0][1] = 99.0
    assert table.cells() == [["a", "1.00"]]


# ---------------------------------------------------------------------------------------
# HTML page


def _page(figures: dict[str, bytes]) -> str:
    return render_html(
        "Reproduction <of> the paper & more",
        [
            Section(
                "Accuracy",
                paragraphs=['Errors are estimate minus truth; "RMSE" over 100 runs <b>not bold</b>.'],
                tables=[_results_table()],
                images=[
                    Image(figures["error_vs_sample"], "Fig. 4: error vs samples", "error vs samples"),
                    Image(figures["error_vs_bound"], "RMSE against the PCRB", 'RMSE "vs" bound'),
                ],
            ),
            Section("Notes", paragraphs=["Nothing here."]),
        ],
    )


def test_html_is_self_contained(figures: dict[str, bytes]) -> None:
    page = _page(figures)
    assert page.startswith("<!DOCTYPE html>")
    for ref in ("http://", "https://", 'src="/', "<script", "<link", "url("):
        assert ref not in page, ref
    srcs = re.findall(r'\bsrc="([^"]*)"', page)
    assert len(srcs) == 2 and all(s.startswith("data:image/png;base64,") for s in srcs)
    hrefs = re.findall(r'\bhref="([^"]*)"', page)
    assert all(h.startswith("#") for h in hrefs)


def test_html_escapes_all_text(figures: dict[str, bytes]) -> None:
    page = _page(figures)
    assert "<of>" not in page and "<b>not bold</b>" not in page
    assert "<title>Reproduction &lt;of&gt; the paper &amp; more</title>" in page
    assert "&lt;b&gt;not bold&lt;/b&gt;" in page
    assert 'alt="RMSE &quot;vs&quot; bound"' in page


def test_html_is_deterministic(figures: dict[str, bytes]) -> None:
    assert _page(figures) == _page(figures)


def test_write_html_replaces_atomically(tmp_path, figures: dict[str, bytes]) -> None:
    path = tmp_path / "report.html"
    assert write_html(path, "old") == path
    write_html(path, _page(figures))
    assert path.read_text(encoding="utf-8") == _page(figures)
    assert [p.name for p in tmp_path.iterdir()] == ["report.html"]


def test_write_html_leaves_nothing_on_error(tmp_path, monkeypatch) -> None:
    def failing_replace(src: object, dst: object) -> None:
        raise OSError("disk full (simulated)")

    fresh = tmp_path / "fresh.html"
    existing = tmp_path / "existing.html"
    existing.write_text("previous report", encoding="utf-8")
    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="simulated"):
        write_html(fresh, "<!DOCTYPE html>")
    with pytest.raises(OSError, match="simulated"):
        write_html(existing, "<!DOCTYPE html>")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing.html"]
    assert existing.read_text(encoding="utf-8") == "previous report"


# ---------------------------------------------------------------------------------------
# in a real browser


def test_report_renders_in_headless_chromium(tmp_path, figures: dict[str, bytes]) -> None:
    require_chromium()
    page = tmp_path / "report.html"
    write_html(page, _page(figures))

    shot, dom, console_errors = render_in_chromium(page, screenshot=tmp_path / "shot.png")

    assert console_errors == []
    pixels = imread(shot)
    assert pixels.shape[:2] == (2000, 1200)
    assert float(np.var(pixels[..., :3])) > 1e-3
    assert "RMSE over 100 runs, from sample 50" in dom
    images = dom_images(dom)
    assert len(images) == 2
    assert all(im.src.startswith("data:image/png;base64,") for im in images)
    assert [im.natural_width for im in images] == [900, 900]


def test_browser_helper_reports_page_errors(tmp_path) -> None:
    """The detector itself: a page with external references and a failing script must
    not pass as clean, with or without the offline policy."""
    require_chromium()
    page = tmp_path / "bad.html"
    page.write_text(
        "<!DOCTYPE html><html><head><title>bad</title>"
        '<link rel="stylesheet" href="https://example.invalid/x.css"></head><body>'
        '<img src="https://example.invalid/a.png"><img src="missing.png">'
        '<script>console.error("boom"); undefinedFunction();</script></body></html>',
        encoding="utf-8",
    )
    _, _, offline_errors = render_in_chromium(page)
    assert any("example.invalid/a.png" in e for e in offline_errors)
    assert any("x.css" in e for e in offline_errors)
    assert any("missing.png" in e for e in offline_errors)
    assert any("script-src" in e for e in offline_errors)  # scripts are not allowed in reports

    # Without the policy, on a page with no network references (nothing leaves the machine).
    page.write_text(
        '<!DOCTYPE html><html><head><title>bad</title></head><body><img src="missing.png">'
        '<img src="also-missing.png"><script>console.error("boom"); undefinedFunction();</script>'
        "</body></html>",
        encoding="utf-8",
    )
    _, dom, online_errors = render_in_chromium(page, offline=False)
    assert any("Uncaught ReferenceError" in e for e in online_errors)
    assert any("console.error: boom" in e for e in online_errors)
    assert [im.natural_width for im in dom_images(dom)] == [0, 0]
