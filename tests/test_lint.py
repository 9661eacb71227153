"""Static checks are part of the suite: ruff and mypy must be clean."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest

from conftest import REPO


@pytest.mark.parametrize(
    "cmd",
    [
        [sys.executable, "-m", "ruff", "check", "src", "tests", "benchmarks"],
        [sys.executable, "-m", "mypy", "--no-error-summary"],
    ],
    ids=["ruff", "mypy"],
)
def test_static_checks(cmd: list[str]) -> None:
    if shutil.which("ruff") is None and cmd[2] == "ruff":
        pytest.fail("ruff is not installed: install the test extra, pip install -e '.[test]'")
    res = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr
