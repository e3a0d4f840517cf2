"""Drive ``haa-sym explore`` in headless Chromium and time it by the page's own clock.

Shared by ``tests/test_explore_browser.py`` (which checks what the page shows and prints the
latencies, asserting none of them) and ``benchmarks/bench_explore.py`` (which judges the
latencies against the issue's targets and writes them to ``$HAA_SYM_BENCH_DIR``): one way of
starting the server, of acting on the page and of timing it, so that the test and the benchmark
measure the same thing.

A latency runs from the user's event (the Enter key, a select's input, the pointer going down;
marked in the page) to the second animation frame after the page's JSON (``#explore-view`` /
``#explore-detail``, ``data-seq``) reached the expected update: the browser has painted it.
The driver's own round trips to the browser are not counted.
"""
from __future__ import annotations

import json
import os
import socket
import statistics
import subprocess
import sys
import time
import urllib.request
from dataclasses import dataclass

CHROMIUM = "/usr/bin/chromium"
INSTALL = ("the browser test needs playwright (pip install -e '.[test]') and Debian's chromium at "
           f"{CHROMIUM} (`make browser`, or apt-get update && apt-get install -y chromium)")
# the targets, seconds: a control change to the redrawn 200 x 100 map, a click to the
# point's detail (median, worst)
MAP_MEDIAN_S, MAP_WORST_S, CLICK_MEDIAN_S, CLICK_WORST_S = 0.25, 1.0, 0.30, 1.0
# the control changes timed on the default 200 x 100 map: ten beta values, then one change of
# each other control kind (a select, a typed key, a refused filter without its f_c, ...)
BETAS = ("2", "3", "1.5", "2.5", "0.8", "4", "1.2", "3.5", "1.8", "1")
CHANGES = tuple(("type", ".ex-set-beta", b) for b in BETAS) + (
    ("select", ".ex-configuration", "retracted"),
    ("type", ".ex-set-alpha", "0.5"),
    ("select", ".ex-set-velocity_filter", "lowpass1"),       # refused: f_c is missing
    ("type", ".ex-set-f_c", "60"),
    ("type", ".ex-set-Ts", "0.0005"),
    ("select", ".ex-option-delay", "1"))
# where the map is clicked, fractions of its frame (the plotted area, from its left and top)
CLICKS = ((0.5, 0.5), (0.62, 0.3), (0.7, 0.6), (0.4, 0.75), (0.8, 0.2))


class DriverError(RuntimeError):
    """The server did not start, or the page did not show an update in time."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class Server:
    proc: subprocess.Popen
    url: str
    html: str

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


def start_server(timeout_s: float = 60.0, env: dict | None = None, args=(), cwd=None) -> Server:
    """``haa-sym explore`` on a free port (this interpreter, ``--no-browser``, then ``args``,
    e.g. ``--allow DIR``; started in ``cwd``), once it answers."""
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "haa_sym.cli", "explore", "--port", str(port), "--no-browser",
                             *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=cwd)
    url = f"http://127.0.0.1:{port}/"
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with urllib.request.urlopen(url, timeout=5) as r:
                return Server(proc, url, r.read().decode())
        except OSError:
            if proc.poll() is not None or time.monotonic() > deadline:
                proc.kill()
                raise DriverError(f"the server did not start: {proc.communicate()[1][-2000:]}") from None
            time.sleep(0.2)


def launch(playwright):
    """Headless Debian chromium (raises :class:`DriverError` with what to install when missing)."""
    if not os.path.exists(CHROMIUM):
        raise DriverError(INSTALL)
    return playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"], headless=True)


# waits in the page, frame by frame, for an element (inside Bokeh's shadow roots) to reach a seq
WAIT_JS = """async ([pid, seq, ms]) => {
  function find(root) {
    const h = root.querySelector('#' + pid);
    if (h) return h;
    for (const n of root.querySelectorAll('*')) if (n.shadowRoot) { const f = find(n.shadowRoot); if (f) return f; }
    return null;
  }
  const frame = () => new Promise(r => requestAnimationFrame(r));
  const t0 = performance.now();
  let e = find(document), root = e ? e.getRootNode() : document;
  while (performance.now() - t0 < ms) {
    e = root.querySelector('#' + pid);
    if (!e || !e.isConnected) { e = find(document); if (e) root = e.getRootNode(); }
    if (e && Number(e.dataset.seq) >= seq) {
      // two frames: Bokeh paints its canvases in an animation frame of their own
      await frame(); await frame();
      return window.__exT0 == null ? -1 : performance.now() - window.__exT0;
    }
    await frame();
  }
  return null;
}"""
# the moment of the user's action, in the page's own clock: the first keydown, input (a select) or
# pointerdown after mark() (UI events cross the shadow roots to the document)
MARK_JS = """() => { window.__exT0 = null;
  for (const ev of ['keydown', 'input', 'pointerdown'])
    document.addEventListener(ev, () => { if (window.__exT0 == null) window.__exT0 = performance.now(); },
                              {capture: true, once: true}); }"""


# the map's frame (its plotted area; the legend stands beside it) in page pixels: left, top,
# width, height, from Bokeh's views (the figure whose x axis is P_gain)
FRAME_JS = """() => {
  const roots = Bokeh.index.roots ? [...Bokeh.index.roots] : Object.values(Bokeh.index);
  function walk(v, d) {
    if (v == null || d > 40) return null;
    if (v.frame && v.canvas_view && (v.model.below ?? []).some(a => (a.axis_label ?? '').startsWith('P_gain'))) {
      const r = v.canvas_view.el.getBoundingClientRect(), b = v.frame.bbox;
      return [r.left + b.left, r.top + b.top, b.width, b.height];
    }
    for (const c of (v.child_views ?? [])) { const f = walk(c, d + 1); if (f) return f; }
    return null;
  }
  for (const r of roots) { const f = walk(r, 0); if (f) return f; }
  return null;
}"""


class Tab:
    """One browser tab on the page; reads the JSON the page exposes."""

    def __init__(self, browser, url):
        self.page = browser.new_page(viewport={"width": 1300, "height": 1400})
        self.page.goto(url)
        self.wait("explore-view", 1)
        self.seq, self.detail_seq = 1, 0

    def wait(self, pid, seq, timeout=60.0):
        """Until the page's ``#pid`` has ``data-seq`` >= ``seq`` and two frames have been painted.
        Checked in the page on every animation frame (playwright's own selector polling backs off
        to 500 ms between tries, which would swamp the latencies). Returns the seconds from the
        action marked by :meth:`mark` to then, by the page's clock, or None when nothing was
        marked."""
        t_end = time.monotonic() + timeout
        while (ms := self.page.evaluate(WAIT_JS, [pid, seq, 5000])) is None:
            if time.monotonic() > t_end:
                raise DriverError(f"the page did not show #{pid} data-seq {seq} within {timeout:g} s")
        return None if ms < 0 else ms / 1e3

    def mark(self):
        self.page.evaluate(MARK_JS)

    def view(self):
        return json.loads(self.page.locator("#explore-view").text_content())

    def detail(self):
        return json.loads(self.page.locator("#explore-detail").text_content())

    def type(self, css, text):
        """Type ``text`` into the input of the widget ``css`` and press Enter; returns the seconds
        from the Enter key to the redrawn page."""
        box = self.page.locator(f"{css} input")
        box.fill(text)
        self.mark()
        box.press("Enter")
        self.seq += 1
        return self.wait("explore-view", self.seq)

    def select(self, css, value):
        self.mark()
        self.page.locator(f"{css} select").select_option(value)
        self.seq += 1
        return self.wait("explore-view", self.seq)

    def act(self, action: str, css: str, value: str):
        """One entry of :data:`CHANGES`; returns its latency, s."""
        return getattr(self, action)(css, value)

    def click_map(self, fx, fy):
        """Click the map at fractions (fx, fy) of its frame (:data:`FRAME_JS`); returns the
        seconds from the pointer going down to the painted detail."""
        x, y, w, h = self.page.evaluate(FRAME_JS)
        self.page.wait_for_timeout(600)        # two clicks in quick succession are a double tap
        self.page.mouse.move(x + w * fx, y + h * fy)
        self.mark()
        self.page.mouse.down()
        self.page.mouse.up()
        self.detail_seq += 1
        return self.wait("explore-detail", self.detail_seq)

    def error(self):
        loc = self.page.locator("#explore-error")
        return loc.text_content() if loc.count() else None


def drive_changes(tab: Tab, changes=CHANGES) -> list[dict]:
    """Apply ``changes`` one after the other; per change: the action, its latency ``s``, the
    page's view JSON after it and the refusal shown (or None)."""
    out = []
    for action, css, value in changes:
        s = tab.act(action, css, value)
        out.append({"action": action, "control": css, "value": value, "s": s, "view": tab.view(),
                    "error": tab.error()})
    return out


def drive_clicks(tab: Tab, clicks=CLICKS) -> list[dict]:
    """Click the map at ``clicks``; per click its latency ``s`` and the page's detail JSON."""
    return [{"at": list(c), "s": tab.click_map(*c), "detail": tab.detail()} for c in clicks]


def summary(seconds) -> dict:
    """Median, worst and every latency, ms."""
    ms = [1e3 * s for s in seconds]
    return {"median_ms": round(statistics.median(ms), 1), "worst_ms": round(max(ms), 1),
            "all_ms": [round(v, 1) for v in ms], "n": len(ms)}


def load() -> float:
    return round(os.getloadavg()[0], 2)
