"""Reports: tables, PNG figures and self-contained HTML.

The only package that imports matplotlib (lazily, inside :mod:`.figures`, on the first
figure) and writes HTML. Used by the CLI (``windahrs reproduce``, ``windahrs report``);
nothing else in windahrs imports it.

    from windahrs.report import Image, Section, Table, render_html, write_html
    from windahrs.report import error_vs_sample_png

    table = Table(["filter", "roll [deg]"], [["MEKF", 0.4213]], caption="RMSE")
    html = render_html("Run 1", [Section("Results", tables=[table],
                                         images=[Image(png, "errors", "error plot")])])
    write_html("report.html", html)          # atomic
    write_text("results.md", table.to_markdown())   # the same numbers, atomic too
"""

from windahrs.report.figures import (
    error_vs_bound_png,
    error_vs_sample_png,
    grouped_bars_png,
    timeseries_png,
    versus_wind_png,
)
from windahrs.report.html import (
    Image,
    Section,
    Table,
    format_cell,
    markdown_table,
    render_html,
    write_html,
    write_text,
)

__all__ = [
    "Image",
    "Section",
    "Table",
    "error_vs_bound_png",
    "error_vs_sample_png",
    "format_cell",
    "grouped_bars_png",
    "markdown_table",
    "render_html",
    "timeseries_png",
    "versus_wind_png",
    "write_html",
    "write_text",
]
