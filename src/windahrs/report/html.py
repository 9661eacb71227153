"""Self-contained HTML reports and Markdown tables from the same records.

A report is a title and a list of :class:`Section`; each section holds paragraphs,
tables and PNG images. :func:`render_html` turns them into one HTML document with inline
CSS and images embedded as base64 ``data:`` URIs: no scripts, no external references, so
the file opens offline and can be mailed or archived as is. All text is escaped.

One source of numbers: a :class:`Table` formats its cells once (:meth:`Table.cells`) and
both :meth:`Table.to_html` and :meth:`Table.to_markdown` render those strings, so a
``results.md`` and the HTML report can never disagree.
"""

from __future__ import annotations

import base64
import html
import math
import numbers
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeAlias

import numpy as np

__all__ = [
    "Cell",
    "Highlight",
    "Image",
    "Section",
    "Table",
    "format_cell",
    "markdown_table",
    "render_html",
    "write_html",
    "write_text",
]

Cell: TypeAlias = str | float | int | np.floating[Any] | np.integer[Any] | None
Highlight: TypeAlias = Literal["good", "bad"]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MISSING = "–"  # en dash, for None cells
_SIGNIFICANT = 3


def format_cell(value: object) -> str:
    """The text of one table cell: None -> "–"; int -> as is; float -> 3 significant digits,
    fixed point for 1e-3 <= |x| < 1e6 (trailing zeros kept so columns align, "12.3",
    "0.0123", "1235"), otherwise scientific ("1.23e-05"); nan/inf -> "nan"/"inf"/"-inf";
    str -> unchanged. numpy scalars are accepted."""
    if value is None:
        return MISSING
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return _format_float(float(value))
    raise TypeError(f"table cell: expected str, float, int or None, found {type(value).__name__}")


def _format_float(x: float) -> str:
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    if x == 0.0:
        return "0"
    rounded = float(f"{x:.{_SIGNIFICANT}g}")  # round first: 9.996 -> 10.0, not "10.00"
    magnitude = math.floor(math.log10(abs(rounded)))
    if -3 <= magnitude < 6:
        # Integer parts are never rounded away (1234.5 -> "1235", not "1.23e+03").
        decimals = max(0, _SIGNIFICANT - 1 - magnitude)
        return f"{x:.{decimals}f}"
    return f"{x:.{_SIGNIFICANT - 1}e}"


def _is_number(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


@dataclass(frozen=True)
class Table:
    """A table of results.

    columns: header texts; rows: one list per row, as long as ``columns``, of str, float,
    int (numpy scalars accepted) or None (shown as "–"); caption: shown above the table;
    highlight: ``{(row, col): "good" | "bad"}`` with 0-based indices into ``rows`` (the
    header is not a row), rendered as green / red cells in HTML and as **bold** / *italic*
    in Markdown. Inputs are copied, never modified.
    """

    columns: Sequence[str]
    rows: Sequence[Sequence[Cell]]
    caption: str = ""
    highlight: Mapping[tuple[int, int], Highlight] = field(default_factory=dict)

    def __post_init__(self) -> None:
        columns = tuple(str(c) for c in self.columns)
        if not columns:
            raise ValueError("Table.columns: expected at least one column, found none")
        rows = tuple(tuple(r) for r in self.rows)
        for i, row in enumerate(rows):
            if len(row) != len(columns):
                raise ValueError(f"Table.rows[{i}]: expected {len(columns)} cells (one per column), found {len(row)}")
            for j, value in enumerate(row):
                if value is not None and not isinstance(value, str | numbers.Real):
                    raise TypeError(
                        f"Table.rows[{i}][{j}]: expected str, float, int or None, found {type(value).__name__}"
                    )
        highlight = dict(self.highlight)
        for key, kind in highlight.items():
            if (
                not isinstance(key, tuple)
                or len(key) != 2
                or not (0 <= key[0] < len(rows) and 0 <= key[1] < len(columns))
            ):
                raise ValueError(
                    f"Table.highlight: expected (row, col) keys with 0 <= row < {len(rows)} and "
                    f"0 <= col < {len(columns)}, found {key!r}"
                )
            if kind not in ("good", "bad"):
                raise ValueError(f"Table.highlight[{key!r}]: expected 'good' or 'bad', found {kind!r}")
        object.__setattr__(self, "columns", columns)
        object.__setattr__(self, "rows", rows)
        object.__setattr__(self, "highlight", highlight)

    def cells(self) -> list[list[str]]:
        """The formatted text of every body cell (see :func:`format_cell`)."""
        return [[format_cell(v) for v in row] for row in self.rows]

    def numeric_columns(self) -> list[bool]:
        """Per column: True when every non-None cell is a number (right-aligned)."""
        flags = []
        for j in range(len(self.columns)):
            values = [row[j] for row in self.rows if row[j] is not None]
            flags.append(bool(values) and all(_is_number(v) for v in values))
        return flags

    def to_markdown(self) -> str:
        """GitHub-flavoured Markdown: the caption as an italic line, then the table;
        numeric columns right-aligned; "|" escaped, newlines folded into spaces."""
        numeric = self.numeric_columns()
        body = self.cells()
        for (i, j), kind in self.highlight.items():
            if body[i][j]:
                body[i][j] = f"**{body[i][j]}**" if kind == "good" else f"*{body[i][j]}*"
        lines = []
        if self.caption:
            lines += [f"*{_md_escape(self.caption)}*", ""]
        lines.append("| " + " | ".join(_md_escape(c) for c in self.columns) + " |")
        lines.append("|" + "|".join("---:" if n else "---" for n in numeric) + "|")
        for row in body:
            lines.append("| " + " | ".join(_md_escape(c) for c in row) + " |")
        return "\n".join(lines) + "\n"

    def to_html(self) -> str:
        """An HTML ``<table>`` (escaped text; classes ``num``, ``good``, ``bad``)."""
        numeric = self.numeric_columns()
        out = ["<table>"]
        if self.caption:
            out.append(f"<caption>{_esc(self.caption)}</caption>")
        head = "".join(
            f'<th scope="col"{_cls("num" if n else "")}>{_esc(c)}</th>'
            for c, n in zip(self.columns, numeric, strict=True)
        )
        out.append(f"<thead><tr>{head}</tr></thead>")
        out.append("<tbody>")
        for i, row in enumerate(self.cells()):
            tds = []
            for j, text in enumerate(row):
                classes = ("num" if numeric[j] else "", self.highlight.get((i, j), ""))
                tds.append(f"<td{_cls(*classes)}>{_esc(text)}</td>")
            out.append("<tr>" + "".join(tds) + "</tr>")
        out.append("</tbody></table>")
        return "\n".join(out)


def markdown_table(columns: Sequence[str], rows: Sequence[Sequence[Cell]]) -> str:
    """Shorthand for ``Table(columns, rows).to_markdown()``."""
    return Table(columns, rows).to_markdown()


@dataclass(frozen=True)
class Image:
    """A PNG figure: png the file's bytes (e.g. from :mod:`windahrs.report.figures`);
    caption shown below it; alt the text alternative (the caption when empty)."""

    png: bytes
    caption: str
    alt: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.png, bytes | bytearray) or not bytes(self.png).startswith(PNG_SIGNATURE):
            head = bytes(self.png[:8]) if isinstance(self.png, bytes | bytearray) else type(self.png).__name__
            raise ValueError(f"Image.png: expected PNG bytes (signature {PNG_SIGNATURE!r}), found {head!r}")
        object.__setattr__(self, "png", bytes(self.png))

    def data_uri(self) -> str:
        return "data:image/png;base64," + base64.b64encode(self.png).decode("ascii")

    def to_html(self) -> str:
        alt = self.alt or self.caption
        caption = f"<figcaption>{_esc(self.caption)}</figcaption>" if self.caption else ""
        return f'<figure><img src="{self.data_uri()}" alt="{_esc(alt)}">{caption}</figure>'


@dataclass(frozen=True)
class Section:
    """A report section: a heading, then its paragraphs (plain text, escaped), its tables
    and its images, in that order."""

    heading: str
    paragraphs: Sequence[str] = ()
    tables: Sequence[Table] = ()
    images: Sequence[Image] = ()

    def __post_init__(self) -> None:
        for name, kind in (("paragraphs", str), ("tables", Table), ("images", Image)):
            items = tuple(getattr(self, name))
            for i, item in enumerate(items):
                if not isinstance(item, kind):
                    raise TypeError(f"Section.{name}[{i}]: expected {kind.__name__}, found {type(item).__name__}")
            object.__setattr__(self, name, items)


_CSS = """
:root { color-scheme: light; }
body { font: 15px/1.5 system-ui, -apple-system, "Segoe UI", Roboto, "DejaVu Sans", sans-serif;
       color: #1d1d1f; background: #fff; margin: 0; }
main { max-width: 980px; margin: 0 auto; padding: 24px 20px 48px; }
h1 { font-size: 26px; margin: 0 0 12px; }
h2 { font-size: 20px; margin: 32px 0 8px; padding-bottom: 4px; border-bottom: 1px solid #ddd; }
nav ol { margin: 4px 0 16px; padding-left: 22px; }
a { color: #0b57d0; }
p { margin: 8px 0; }
table { border-collapse: collapse; margin: 12px 0 20px; font-size: 14px;
        font-variant-numeric: tabular-nums; }
caption { caption-side: top; text-align: left; font-weight: 600; padding: 4px 0; }
th, td { border: 1px solid #d0d0d0; padding: 4px 10px; text-align: left; vertical-align: top; }
thead th { background: #f3f4f6; }
tbody tr:nth-child(even) td { background: #fafafa; }
.num { text-align: right; }
td.good, tbody tr:nth-child(even) td.good { background: #dcf5e3; color: #0f5132; font-weight: 600; }
td.bad, tbody tr:nth-child(even) td.bad { background: #fbe0e0; color: #842029; }
figure { margin: 16px 0 24px; }
figure img { display: block; max-width: 100%; height: auto; border: 1px solid #eee; }
figcaption { font-size: 13px; color: #555; margin-top: 4px; }
@media print { h2 { break-after: avoid; } figure, table { break-inside: avoid; } }
""".strip()


def render_html(title: str, sections: Sequence[Section]) -> str:
    """One self-contained HTML document (str): inline CSS, images as base64 data: URIs,
    no scripts, no external references. A table of contents is added when there are
    more than two sections. Deterministic: the same input gives the same text."""
    sections = list(sections)
    for i, s in enumerate(sections):
        if not isinstance(s, Section):
            raise TypeError(f"sections[{i}]: expected Section, found {type(s).__name__}")
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en">',
        "<head>",
        '<meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{_esc(title)}</title>",
        f"<style>\n{_CSS}\n</style>",
        "</head>",
        "<body>",
        "<main>",
        f"<h1>{_esc(title)}</h1>",
    ]
    if len(sections) > 2:
        items = "".join(f'<li><a href="#section-{i + 1}">{_esc(s.heading)}</a></li>' for i, s in enumerate(sections))
        parts.append(f'<nav aria-label="Contents"><ol>{items}</ol></nav>')
    for i, s in enumerate(sections):
        parts.append(f'<section id="section-{i + 1}">')
        parts.append(f"<h2>{_esc(s.heading)}</h2>")
        parts.extend(f"<p>{_esc(p)}</p>" for p in s.paragraphs)
        parts.extend(t.to_html() for t in s.tables)
        parts.extend(im.to_html() for im in s.images)
        parts.append("</section>")
    parts += ["</main>", "</body>", "</html>", ""]
    return "\n".join(parts)


def write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`windahrs.store.write_bytes`: a
    temporary file in the same directory with the user's umask, then ``os.replace``). On
    any error the temporary file is removed and an existing file at ``path`` is left
    untouched; OutputError names ``path``. The directory must exist. Returns the path."""
    from windahrs.store import write_bytes

    return write_bytes(path, text.encode("utf-8"))


def write_html(path: str | os.PathLike[str], html_text: str) -> Path:
    """Write a rendered report atomically (see :func:`write_text`). Returns the path."""
    return write_text(path, html_text)


def _esc(text: str) -> str:
    return html.escape(str(text), quote=True)


def _cls(*names: str) -> str:
    names_ = [n for n in names if n]
    return f' class="{" ".join(names_)}"' if names_ else ""


def _md_escape(text: str) -> str:
    return " ".join(str(text).replace("\\", "\\\\").replace("|", "\\|").split())
