"""Open an HTML file in headless Chromium, for tests: screenshot, DOM and page errors.

How it works. Chromium is run once per page with ``--screenshot`` and ``--dump-dom`` (both
are honoured in one run) on a temporary copy of the page, written beside the original so
relative references resolve the same way. Into the copy's ``<head>`` two things are
injected (the page under test is never modified, and reports stay script-free):

* a Content-Security-Policy ``<meta>`` (``offline=True``, the default) that allows only
  ``data:`` images and fonts, inline styles and the probe script: any reference to the
  network or to another file is blocked and reported, whether or not the machine is
  online, so "opens offline" is checked by the browser itself, not by grepping;
* a small probe script that records page errors (uncaught exceptions, unhandled
  rejections, ``console.error`` calls, resources that failed to load, policy
  violations) into a hidden ``<pre id="windahrs-probe">`` and writes each image's
  ``naturalWidth`` into a ``data-natural-width`` attribute, so ``--dump-dom`` carries
  them out (see :func:`dom_images`).

Console errors are the union of the probe's records and Chromium's own log
(``--enable-logging=stderr --v=0``): every ``CONSOLE`` line whose source is the page and
whose level is ERROR, or whose text starts with "Uncaught" or reports a blocked or failed
load. (Chromium 156 logs every console message at INFO level, console.error included,
which is why the probe is needed to see console.error.) Browser noise on stderr (D-Bus,
GPU) is ignored.

The run has a hard timeout (30 s): the whole process group is killed and TimeoutError
raised, so a test never hangs. Tests call :func:`require_chromium` to skip, saying why,
where Chromium is absent (CI installs it: ``apt-get install -y chromium``).
"""

from __future__ import annotations

import html
import json
import os
import re
import secrets
import shutil
import signal
import subprocess
import tempfile
from dataclasses import dataclass
from html.parser import HTMLParser
from pathlib import Path
from typing import NamedTuple
from urllib.parse import unquote

import pytest

CHROMIUM = Path(os.environ.get("WINDAHRS_CHROMIUM", "/usr/bin/chromium"))
TIMEOUT_S = 30.0
PROBE_ID = "windahrs-probe"

# Root in a container needs --no-sandbox; the background-networking flags stop Chromium
# from phoning home, which a closed network answers with refused connections.
BASE_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--enable-logging=stderr",
    "--v=0",
)

_PROBE_JS = """
(function () {
  var errors = [];
  function publish() {
    if (!document.body) return;
    var out = document.getElementById('%(id)s');
    if (!out) {
      out = document.createElement('pre');
      out.id = '%(id)s';
      out.hidden = true;
      document.body.appendChild(out);
    }
    Array.prototype.forEach.call(document.images, function (im) {
      im.setAttribute('data-natural-width', String(im.naturalWidth));
    });
    out.textContent = JSON.stringify({errors: errors});
  }
  function record(msg) { errors.push(String(msg)); publish(); }
  window.addEventListener('error', function (e) {
    var t = e.target;
    if (t && t !== window && t.nodeType === 1) {
      record('failed to load: <' + t.tagName.toLowerCase() + '> ' + (t.currentSrc || t.src || t.href || ''));
    } else {
      record('uncaught exception: ' + e.message + ' (' + e.filename + ':' + e.lineno + ')');
    }
  }, true);
  window.addEventListener('unhandledrejection', function (e) { record('unhandled rejection: ' + e.reason); });
  document.addEventListener('securitypolicyviolation', function (e) {
    record('blocked by the offline policy (' + e.violatedDirective + '): ' + (e.blockedURI || 'inline'));
  });
  var consoleError = console.error;
  console.error = function () {
    record('console.error: ' + Array.prototype.map.call(arguments, String).join(' '));
    return consoleError.apply(console, arguments);
  };
  document.addEventListener('DOMContentLoaded', publish);
  window.addEventListener('load', publish);
})();
"""

# [pid:tid:date:LEVEL:CONSOLE:line] "message", source: url (line)   (older builds: CONSOLE(line))
_CONSOLE_RE = re.compile(
    r":(?P<level>[A-Z]+\d*):CONSOLE[:(]\d*\)?\] \"(?P<msg>.*?)\", source: (?P<src>\S*) \(\d+\)",
    re.DOTALL,
)
_ERROR_TEXT = re.compile(r"^Uncaught|Content Security Policy|Failed to load|net::ERR_|Refused to")


class BrowserRender(NamedTuple):
    """What Chromium made of a page: the screenshot's path, the DOM after load (with the
    probe's annotations) and the page's errors (empty when clean)."""

    screenshot: Path
    dom: str
    console_errors: list[str]


@dataclass(frozen=True)
class DomImage:
    src: str
    natural_width: int | None  # None: the probe did not annotate the image


def require_chromium() -> Path:
    """The Chromium executable, or skip the test saying why."""
    if not (CHROMIUM.is_file() and os.access(CHROMIUM, os.X_OK)):
        pytest.skip(
            f"headless browser test needs Chromium at {CHROMIUM} (apt-get install -y chromium, "
            "or set WINDAHRS_CHROMIUM); CI installs it"
        )
    return CHROMIUM


def render_in_chromium(
    html_path: str | os.PathLike[str],
    *,
    screenshot: str | os.PathLike[str] | None = None,
    window: tuple[int, int] = (1200, 2000),
    offline: bool = True,
    timeout: float = TIMEOUT_S,
) -> BrowserRender:
    """Open ``html_path`` in headless Chromium (see the module docstring).

    screenshot: where to write the PNG (default: ``<page>.screenshot.png`` beside it);
    window: viewport (width, height) in px; offline: block everything but data: URIs and
    report the attempts; timeout: seconds before the browser is killed (TimeoutError).
    Raises RuntimeError when Chromium fails or produces no screenshot or DOM.
    Returns ``(screenshot_png_path, dom_text, console_errors)``.
    """
    page = Path(html_path).resolve()
    shot = Path(screenshot) if screenshot is not None else page.with_name(page.stem + ".screenshot.png")
    shot.unlink(missing_ok=True)
    probe_copy = page.with_name(f".{page.stem}.probe-{secrets.token_hex(4)}.html")
    profile = Path(tempfile.mkdtemp(prefix="windahrs-chromium-"))
    try:
        probe_copy.write_text(_instrument(page.read_text(encoding="utf-8"), offline=offline), encoding="utf-8")
        url = probe_copy.as_uri()
        cmd = [
            str(CHROMIUM),
            *BASE_FLAGS,
            f"--user-data-dir={profile}",
            f"--window-size={window[0]},{window[1]}",
            f"--screenshot={shot}",
            "--dump-dom",
            url,
        ]
        stdout, stderr = _run(cmd, timeout)
    finally:
        probe_copy.unlink(missing_ok=True)
        shutil.rmtree(profile, ignore_errors=True)
    if not stdout.strip():
        raise RuntimeError(f"chromium dumped no DOM for {page}; stderr tail:\n{stderr[-2000:]}")
    if not shot.is_file() or shot.stat().st_size == 0:
        raise RuntimeError(f"chromium wrote no screenshot {shot}; stderr tail:\n{stderr[-2000:]}")
    errors = _console_errors(stderr, url) + _probe_errors(stdout)
    return BrowserRender(shot, stdout, errors)


def dom_images(dom: str) -> list[DomImage]:
    """Every ``<img>`` of a dumped DOM, with the naturalWidth the probe recorded."""
    parser = _ImgParser()
    parser.feed(dom)
    return parser.images


def _instrument(text: str, *, offline: bool) -> str:
    nonce = secrets.token_hex(8)
    head = ""
    if offline:
        policy = (
            f"default-src 'none'; img-src data:; font-src data:; style-src 'unsafe-inline'; script-src 'nonce-{nonce}'"
        )
        head += f'<meta http-equiv="Content-Security-Policy" content="{policy}">'
    head += f'<script nonce="{nonce}">{_PROBE_JS % {"id": PROBE_ID}}</script>'
    for pattern in (r"<head\b[^>]*>", r"<html\b[^>]*>", r"<!doctype[^>]*>"):
        m = re.search(pattern, text, re.IGNORECASE)
        if m:
            return text[: m.end()] + head + text[m.end() :]
    return head + text


def _run(cmd: list[str], timeout: float) -> tuple[str, str]:
    # A session of its own, so a hung browser and all its helpers die together by group id.
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        _kill_group(proc.pid)
        out, err = proc.communicate()
        raise TimeoutError(
            f"chromium did not finish within {timeout} s; killed. stderr tail:\n"
            f"{err.decode('utf-8', 'replace')[-2000:]}"
        ) from None
    finally:
        _kill_group(proc.pid)  # helpers (zygote, crashpad) that outlived the browser
    stderr = err.decode("utf-8", "replace")
    if proc.returncode != 0:
        raise RuntimeError(f"chromium exited with status {proc.returncode}; stderr tail:\n{stderr[-2000:]}")
    return out.decode("utf-8", "replace"), stderr


def _kill_group(pgid: int) -> None:
    try:
        os.killpg(pgid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def _console_errors(stderr: str, url: str) -> list[str]:
    errors = []
    for m in _CONSOLE_RE.finditer(stderr):
        if unquote(m["src"]).split("#")[0] != unquote(url):
            continue  # not from the page (e.g. an extension or an internal page)
        if m["level"] in ("ERROR", "FATAL") or _ERROR_TEXT.search(m["msg"]):
            errors.append(f"console {m['level']}: {m['msg']}")
    return errors


def _probe_errors(dom: str) -> list[str]:
    m = re.search(rf'<pre id="{PROBE_ID}"[^>]*>(.*?)</pre>', dom, re.DOTALL)
    if m is None:
        return ["page probe did not run (scripts blocked or the page failed to load): errors unknown"]
    return [f"page: {e}" for e in json.loads(html.unescape(m.group(1)))["errors"]]


class _ImgParser(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.images: list[DomImage] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag != "img":
            return
        a = dict(attrs)
        width = a.get("data-natural-width")
        self.images.append(DomImage(a.get("src") or "", int(width) if width is not None else None))
