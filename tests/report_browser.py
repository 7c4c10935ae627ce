"""Open an HTML report in headless Chromium, check its layout and screenshot it.

Used by the report tests (validate, diagnose, improve): ``check_page(html, png)`` loads the
page offline at 1280 px width through the Chrome DevTools protocol over a pipe
(``--remote-debugging-pipe``: no port, no websocket, no extra Python package), waits for
every image to decode, and returns a :class:`PageCheck` listing

- images that did not load (``naturalWidth == 0``),
- elements whose bounding box reaches beyond the document's width (elements inside a
  container that clips or scrolls horizontally are judged by that container instead),

and writes a full-page PNG screenshot. ``assert_layout_ok(check)`` turns the findings into
one assertion message. ``chromium_or_skip()`` finds Debian's ``/usr/bin/chromium``; without
it the test fails unless ``LPVPC_ALLOW_NO_CHROMIUM`` is set (then it skips).

Example (in a test)::

    from report_browser import assert_layout_ok, check_page
    check = check_page(report / "report.html", tmp_path / "report.png")
    assert_layout_ok(check, n_images=5)
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

CHROMIUM = "/usr/bin/chromium"
WIDTH = 1280  # px, the page width the reports are checked at
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic",
         "--disable-dev-shm-usage", "--hide-scrollbars", "--remote-debugging-pipe"]

# Runs in the page: waits for every <img> to finish, then measures. An element "overflows"
# when its right edge passes the document width by more than half a pixel; elements inside
# an ancestor that clips or scrolls horizontally are covered by that ancestor's own box.
_PROBE = r"""
(async () => {
  const imgs = Array.from(document.images);
  await Promise.all(imgs.map(im => im.complete ? null :
      new Promise(r => { im.addEventListener('load', r); im.addEventListener('error', r); })));
  await Promise.all(imgs.map(im => im.decode ? im.decode().catch(() => null) : null));
  const docW = document.documentElement.clientWidth;
  const describe = el => {
    let s = el.tagName.toLowerCase();
    if (el.id) s += '#' + el.id;
    if (el.className && typeof el.className === 'string') s += '.' + el.className.trim().split(/\s+/).join('.');
    const t = (el.textContent || '').trim().replace(/\s+/g, ' ').slice(0, 60);
    return t ? s + ' "' + t + '"' : s;
  };
  const clipped = el => {
    for (let a = el.parentElement; a && a !== document.body; a = a.parentElement) {
      const ox = getComputedStyle(a).overflowX;
      if (ox === 'auto' || ox === 'scroll' || ox === 'hidden' || ox === 'clip') return true;
    }
    return false;
  };
  const over = [], sideways = [];
  for (const el of document.body.querySelectorAll('*')) {
    const r = el.getBoundingClientRect();
    if (r.width === 0 && r.height === 0) continue;
    if (r.right > docW + 0.5 && !clipped(el)) over.push({element: describe(el), right: Math.round(r.right)});
    // a box that scrolls or clips sideways hides part of its content (scrollbars are hidden here)
    const ox = getComputedStyle(el).overflowX;
    if (ox !== 'visible' && el.scrollWidth > el.clientWidth + 1)
      sideways.push({element: describe(el), scroll_width: el.scrollWidth, width: el.clientWidth});
  }
  return {
    images: imgs.map(im => ({src: (im.getAttribute('src') || '').slice(0, 80), alt: im.alt || '',
                             natural_width: im.naturalWidth, width: Math.round(im.getBoundingClientRect().width)})),
    overflowing: over,
    sideways: sideways,
    document_width: docW,
    scroll_width: document.documentElement.scrollWidth,
    height: Math.ceil(document.documentElement.scrollHeight),
    title: document.title,
  };
})()
"""


@dataclass
class PageCheck:
    """What Chromium saw on one page at ``width`` px (see the module docstring)."""

    url: str
    width: int
    document_width: int
    scroll_width: int
    height: int  # px, full page height
    title: str
    images: list = field(default_factory=list)  # {"src", "alt", "natural_width", "width"}
    overflowing: list = field(default_factory=list)  # {"element", "right"}
    sideways: list = field(default_factory=list)  # {"element", "scroll_width", "width"}: boxes hiding content sideways
    screenshot: Path | None = None

    @property
    def broken_images(self) -> list:
        return [im for im in self.images if im["natural_width"] <= 0]

    def problems(self, n_images: int | None = None) -> list[str]:
        out = []
        if n_images is not None and len(self.images) != n_images:
            out.append(f"{len(self.images)} <img> elements, expected {n_images}")
        for im in self.broken_images:
            out.append(f"image did not load: alt={im['alt']!r} src={im['src']!r}")
        if self.scroll_width > self.document_width:
            out.append(f"page scrolls sideways: scrollWidth {self.scroll_width} > {self.document_width} px")
        for o in self.overflowing[:20]:
            out.append(f"element overflows the page width ({o['right']} > {self.document_width} px): {o['element']}")
        for o in self.sideways[:20]:
            out.append(f"element hides content sideways (scrolls or clips: {o['scroll_width']} > {o['width']} px): "
                       f"{o['element']}")
        return out


def chromium_or_skip() -> str:
    """Path of Debian's Chromium; fails the test without it unless LPVPC_ALLOW_NO_CHROMIUM is set."""
    if os.path.exists(CHROMIUM):
        return CHROMIUM
    if os.environ.get("LPVPC_ALLOW_NO_CHROMIUM"):
        pytest.skip(f"{CHROMIUM} is not installed and LPVPC_ALLOW_NO_CHROMIUM is set (CI installs it: .ci/run)")
    pytest.fail(f"{CHROMIUM} is not installed: install Debian's chromium (make chromium), or set "
                "LPVPC_ALLOW_NO_CHROMIUM=1 to skip this check locally")


class _Pipe:
    """Chrome DevTools protocol over --remote-debugging-pipe: Chromium reads commands from
    its fd 3 and writes replies and events to its fd 4, each message NUL-terminated JSON."""

    def __init__(self, proc, to_browser, from_browser, timeout):
        self.proc, self.w, self.r, self.timeout = proc, to_browser, from_browser, timeout
        self.next_id, self.buf, self.events = 0, b"", []

    def _read_message(self, deadline):
        while b"\0" not in self.buf:
            if time.monotonic() > deadline:
                raise TimeoutError("Chromium did not answer in time")
            chunk = os.read(self.r, 1 << 20)
            if not chunk:
                raise RuntimeError(f"Chromium closed the DevTools pipe (exit status {self.proc.poll()})")
            self.buf += chunk
        msg, self.buf = self.buf.split(b"\0", 1)
        return json.loads(msg)

    def send(self, method, params=None, session=None):
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self.w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            reply = self._read_message(deadline)
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise RuntimeError(f"DevTools {method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def wait_event(self, method, session=None):
        deadline = time.monotonic() + self.timeout
        while True:
            for i, ev in enumerate(self.events):
                if ev.get("method") == method and (session is None or ev.get("sessionId") == session):
                    return self.events.pop(i)
            self.events.append(self._read_message(deadline))


def check_page(html: str | Path, screenshot: str | Path | None = None, *, width: int = WIDTH,
               timeout: float = 120.0) -> PageCheck:
    """Load ``html`` (a file path) in headless Chromium at ``width`` px, measure it (see the
    module docstring) and, if ``screenshot`` is given, save a full-page PNG there."""
    chromium = chromium_or_skip()
    url = Path(html).resolve().as_uri()
    profile = tempfile.mkdtemp(prefix="lpvpc-chromium-")
    to_r, to_w = os.pipe()  # we write commands; Chromium reads them on its fd 3
    from_r, from_w = os.pipe()  # Chromium writes on its fd 4; we read

    def child_fds():  # in the child: our pipe ends become its fds 3 and 4 (moved above 10 first,
        a = fcntl.fcntl(to_r, fcntl.F_DUPFD, 10)  # so that neither dup2 clobbers the other end)
        b = fcntl.fcntl(from_w, fcntl.F_DUPFD, 10)
        os.dup2(a, 3)
        os.dup2(b, 4)

    # close_fds=False: subprocess would close 3 and 4 after preexec_fn; Python's own fds are
    # non-inheritable anyway, so nothing else leaks into Chromium.
    proc = subprocess.Popen([chromium, *FLAGS, f"--user-data-dir={profile}", f"--window-size={width},900"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            preexec_fn=child_fds, close_fds=False)
    os.close(to_r)
    os.close(from_w)
    cdp = _Pipe(proc, to_w, from_r, timeout)
    try:
        target = cdp.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        s = cdp.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        cdp.send("Emulation.setDeviceMetricsOverride",
                 {"width": width, "height": 900, "deviceScaleFactor": 1, "mobile": False}, s)
        cdp.send("Page.enable", session=s)
        cdp.send("Page.navigate", {"url": url}, s)
        cdp.wait_event("Page.loadEventFired", s)
        res = cdp.send("Runtime.evaluate", {"expression": _PROBE, "awaitPromise": True, "returnByValue": True}, s)
        if "exceptionDetails" in res:
            raise RuntimeError(f"layout probe failed in the page: {res['exceptionDetails']}")
        v = res["result"]["value"]
        check = PageCheck(url=url, width=width, document_width=v["document_width"], scroll_width=v["scroll_width"],
                          height=v["height"], title=v["title"], images=v["images"], overflowing=v["overflowing"],
                          sideways=v["sideways"])
        if screenshot is not None:
            shot = cdp.send("Page.captureScreenshot", {
                "format": "png", "captureBeyondViewport": True,
                "clip": {"x": 0, "y": 0, "width": width, "height": v["height"], "scale": 1}}, s)
            path = Path(screenshot)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(base64.b64decode(shot["data"]))
            check.screenshot = path
        try:
            cdp.send("Browser.close")
        except (RuntimeError, TimeoutError):
            pass
        return check
    finally:
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        os.close(to_w)
        os.close(from_r)
        shutil.rmtree(profile, ignore_errors=True)


def assert_layout_ok(check: PageCheck, n_images: int | None = None) -> None:
    """Fail with every layout problem found on the page (see :meth:`PageCheck.problems`)."""
    problems = check.problems(n_images)
    assert not problems, f"{check.url} at {check.width} px:\n  " + "\n  ".join(problems)
