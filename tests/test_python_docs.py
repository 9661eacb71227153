"""Every ```python block of docs/python.md runs, in order, in one namespace per page.

A block whose first line is ``# needs real data: RELATIVE/PATH`` reads that recording from
:func:`conftest.data_dir` (exported as ``$WINDAHRS_DATA``, where the page looks) and is
skipped, saying why, where it is absent; so is every later block that needs it. Blocks run
in a temporary working directory (the plot is written there).
"""

from __future__ import annotations

import contextlib
import io
import os
import re
from pathlib import Path
from typing import Any

import pytest

from conftest import REPO, data_dir

PAGES = ("docs/python.md",)
_BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)
_NEEDS = re.compile(r"^# needs real data: (\S+)")


def blocks(page: str) -> list[tuple[int, str]]:
    """(line number, code) of every python block of a page."""
    text = (REPO / page).read_text(encoding="utf-8")
    return [(text[: m.start()].count("\n") + 1, m.group(1)) for m in _BLOCK.finditer(text)]


def test_the_page_has_blocks_and_marks_its_data() -> None:
    found = blocks("docs/python.md")
    assert len(found) >= 6
    assert any(_NEEDS.match(code) for _, code in found)


@pytest.mark.parametrize("page", PAGES)
def test_page_examples_run(page: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("WINDAHRS_DATA", str(data_dir()))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, Any] = {"__name__": "__docs__"}
    skipped: list[str] = []
    ran = 0
    for line, code in blocks(page):
        need = _NEEDS.match(code)
        if need and not (data_dir() / need.group(1)).exists():
            skipped.append(f"{page}:{line} needs {data_dir() / need.group(1)}")
            continue
        out = io.StringIO()
        try:
            with contextlib.redirect_stdout(out):
                exec(compile(code, f"{page}:{line}", "exec"), namespace)
        except Exception as exc:
            raise AssertionError(f"{page}, block at line {line} failed: {type(exc).__name__}: {exc}\n"
                                 f"its output:\n{out.getvalue()}") from exc
        ran += 1
    if skipped:
        pytest.skip(f"ran {ran} blocks; real data not available for: {'; '.join(skipped)} "
                    "(set WINDAHRS_DATA to the shared data folder)")
    if page == "docs/python.md":
        assert (tmp_path / "px4_sample_attitude.png").stat().st_size > 10_000
        assert os.path.basename(str(namespace["log"].meta["source"])) == "sample.ulg"
