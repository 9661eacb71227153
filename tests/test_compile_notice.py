"""A user at a terminal is told once when numba compiles (a fresh install's first run waits
10-60 s per filter family); nothing is said off a terminal (logs, pipes, the tests' own
captured output) or on a load from numba's cache."""

from __future__ import annotations

import io

from numba import njit

from windahrs.cli import COMPILE_NOTICE, compile_notice


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _fresh_function() -> object:
    @njit(cache=False)
    def add(a, b):  # type: ignore[no-untyped-def]
        return a + b

    return add


def test_said_once_at_a_terminal_when_numba_compiles() -> None:
    out = _Terminal()
    f = _fresh_function()
    with compile_notice(out):
        assert f(1, 2) == 3  # compiled: said
        assert f(1.5, 2.0) == 3.5  # compiled again: not said again
        assert f(1, 2) == 3  # no compile
    assert out.getvalue().count(COMPILE_NOTICE) == 1
    g = _fresh_function()
    g(1, 2)  # after the command: the listener is gone
    assert out.getvalue().count(COMPILE_NOTICE) == 1


def test_silent_off_a_terminal() -> None:
    out = io.StringIO()
    with compile_notice(out):
        _fresh_function()(1, 2)  # type: ignore[operator]
    assert out.getvalue() == ""
