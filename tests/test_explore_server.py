"""The explorer's server is safe to leave open (issue 26, item 1): it answers only its own page
(Host, Origin and Sec-Fetch-Site checked on every HTTP request and the websocket), a GET builds
and computes nothing and reads no file (the page is built as its session's first work), the page
reads only files where the command line allows (the directory it was started in, --params,
--allow, the bundled actuators), and the work of closed pages stops and its memory is returned.

The fast tests check the rules in-process; the slow ones start ``haa-sym explore`` on a free
port and speak raw HTTP to it (http.client) or drive pages in headless Chromium."""
import http.client
import os
import time

import pytest

from haa_sym.errors import ParameterError
from haa_sym.explore import app
from haa_sym.explore.state import ViewState, _memo, compute_view, resolve, view_summary
from haa_sym.io.inputs import restrict_reads
from haa_sym.model.resources import data_dir

PORT = 5006


@pytest.mark.parametrize("headers, refused", [
    ({"Host": f"127.0.0.1:{PORT}"}, None),
    ({"Host": f"localhost:{PORT}", "Origin": f"http://localhost:{PORT}", "Sec-Fetch-Site": "same-origin"}, None),
    ({"Host": f"127.0.0.1:{PORT}", "Sec-Fetch-Site": "none"}, None),
    # DNS rebinding: a foreign name resolved to 127.0.0.1 sends its own name
    ({"Host": f"evil.example:{PORT}"}, "Host 'evil.example:5006'"),
    ({"Host": "127.0.0.1"}, "Host '127.0.0.1'"),
    ({}, "Host ''"),
    ({"Host": f"127.0.0.1:{PORT}", "Origin": "http://evil.example"}, "Origin 'http://evil.example'"),
    ({"Host": f"127.0.0.1:{PORT}", "Origin": "null"}, "Origin 'null'"),
    ({"Host": f"127.0.0.1:{PORT}", "Origin": f"http://127.0.0.1:{PORT + 1}"}, "Origin"),
    # a page of another site (or of another port here) linking, framing or fetching the page
    ({"Host": f"127.0.0.1:{PORT}", "Sec-Fetch-Site": "cross-site"}, "Sec-Fetch-Site 'cross-site'"),
    ({"Host": f"127.0.0.1:{PORT}", "Sec-Fetch-Site": "same-site"}, "Sec-Fetch-Site 'same-site'"),
])
def test_request_refusal(headers, refused):
    why = app.request_refusal(headers, PORT)
    if refused is None:
        assert why is None
    else:
        assert why is not None and why.startswith(refused) and "allowed:" in why


@pytest.mark.parametrize("blend, blend_to", [("2", ""), ("nan", ""), ("-0.1", ""), ("inf", ""), ("2", "retracted"),
                                             ("nan", "retracted")])
def test_blend_outside_zero_one_is_refused(blend, blend_to):
    """Item 8: a position outside [0, 1] is refused with the CLI's message style, not clamped."""
    with pytest.raises(ParameterError, match=rf"blend = '{blend}'.*allowed: a number from 0 to 1"):
        resolve(ViewState(blend=blend, blend_to=blend_to, P_gain="log:1:20000:5", D_gain="lin:1:50:5"))


def test_page_keeps_the_typed_blend_and_refuses_it():
    """The page took the URL's blend=2 as 1 (the slider's end) and nan as 0; it keeps the text
    and shows the refusal."""
    pytest.importorskip("panel")
    import bokeh
    import panel
    for text in ("2", "nan"):
        p = app._Page(ViewState(blend=text, blend_to="retracted", P_gain="log:1:20000:5", D_gain="lin:1:50:5"),
                      panel, bokeh)
        p.start()
        assert p.state().blend == text
        assert f"blend = &#x27;{text}&#x27;" in p.message.object and p.view is None


def test_page_names_the_frequency_range_edges():
    """Item 9: the pieces of the passivity boundary where the judged frequency range ends
    (omega_min) are drawn and named as that, not as the |phase Z| = 90 deg boundary."""
    pytest.importorskip("panel")
    import bokeh
    import panel
    state = ViewState(params="sea", P_gain="log:1:20000:40", D_gain="lin:1:50:20").with_set("beta", "3")
    v = compute_view(state)
    kinds = {c["kind"]: c["family"] for c in v.curves}
    assert kinds["passivity (omega_min)"] == "passivity_omega_min" and kinds["passivity"] == "passivity"
    assert view_summary(v)["curves"]["passivity_omega_min"] > 0
    p = app._Page(state, panel, bokeh)
    p.start()
    shown = [item.label.value for item, src in p.legend_items.items() if item.visible]
    assert "edge of the judged frequency range (omega_min)" in shown
    assert "passivity boundary (|phase Z| = 90 deg)" in shown
    # the legend lists only what is drawn: no schedule, measured or robust layer here
    assert not any(s.startswith(("schedule", "measured", "robust")) for s in shown)
    edge = [r for item in p.legend_items if item.label.value.endswith("(omega_min)") for r in item.renderers]
    assert edge and all(r.data_source.data["xs"] for r in edge)


def test_overlays_read_only_where_allowed(tmp_path):
    """Item 1 (c): under the server's read roots, a CSV outside them, a device or a FIFO inside
    them is refused at once with one line; a CSV inside is read."""
    inside, outside = tmp_path / "in", tmp_path / "out"
    inside.mkdir(), outside.mkdir()
    csv = "P_gain,D_gain,outcome\n200,10,stable\n"
    (inside / "m.csv").write_text(csv)
    (outside / "m.csv").write_text(csv)
    os.mkfifo(inside / "fifo.csv")
    base = ViewState(P_gain="log:1:20000:5", D_gain="lin:1:50:5")
    with restrict_reads([inside, data_dir("model")]):
        assert compute_view(base.replace(measured=str(inside / "m.csv"))).overlays["measured"]["outcome"] == ["stable"]
        with pytest.raises(ParameterError, match="outside the files this server may read"):
            compute_view(base.replace(measured=str(outside / "m.csv")))
        t0 = time.monotonic()
        with pytest.raises(ParameterError, match="FIFO"):
            compute_view(base.replace(schedule=str(inside / "fifo.csv")))
        assert time.monotonic() - t0 < 1.0
    with pytest.raises(ParameterError, match="character device"):
        compute_view(base.replace(schedule="/dev/zero"))


def test_memo_is_bounded_by_bytes():
    import numpy as np
    calls = []

    @_memo(max_entries=8, max_bytes=3_000)
    def f(n):
        calls.append(n)
        return {"a": np.zeros(n, np.uint8)}
    for n in (1000, 1000, 1500, 1000, 2500):
        f(n)
    assert calls == [1000, 1500, 2500]               # the repeated 1000 came from the memo
    assert f.cache_bytes() <= 3_000
    f(1000)
    assert calls[-1] == 1000                         # evicted by the 2500-byte entry: computed again
    f(10_000)                                        # larger than the bound alone: kept, alone
    assert f.cache_bytes() == 10_000


def test_cli_allow_must_exist(assert_refused, tmp_path):
    assert_refused(["explore", "--no-browser", "--allow", str(tmp_path / "nope")], "--allow")


# ----------------------------------------------------------------------------- a real server

def _rss_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:"))


def _cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _get(port: int, path: str, headers: dict | None = None, timeout: float = 10.0):
    """(status, body, seconds) of a raw GET with exactly these headers (http.client sends
    Host itself unless given)."""
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    t0 = time.monotonic()
    headers = dict(headers or {})
    c.putrequest("GET", path, skip_host="Host" in headers, skip_accept_encoding=True)
    for k, v in headers.items():
        c.putheader(k, v)
    c.endheaders()
    r = c.getresponse()
    body = r.read()
    c.close()
    return r.status, body, time.monotonic() - t0


def _start(cwd):
    """A server started in ``cwd``, with its port."""
    from explore_driver import DriverError, start_server
    try:
        s = start_server(cwd=cwd)
    except DriverError as exc:
        pytest.fail(str(exc))
    s.port = int(s.url.rsplit(":", 1)[1].strip("/"))
    return s


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    s = _start(tmp_path_factory.mktemp("explore_cwd"))
    yield s
    s.stop()


@pytest.mark.slow
def test_foreign_host_or_origin_gets_403(server):
    port = server.port
    own = f"127.0.0.1:{port}"
    assert _get(port, "/", {"Host": own})[0] == 200
    assert _get(port, "/", {"Host": f"localhost:{port}", "Origin": f"http://localhost:{port}"})[0] == 200
    for path in ("/", "/?P_gain=log:1:20000:1000&D_gain=lin:1:50:1000", "/static/js/bokeh.min.js", "/ws"):
        for headers in ({"Host": f"evil.example:{port}"}, {"Host": own, "Origin": "http://evil.example"},
                        {"Host": own, "Sec-Fetch-Site": "cross-site"}):
            status, body, _ = _get(port, path, headers)
            assert status == 403 and b"refused" in body, (path, headers, status)
    # the websocket's upgrade from a foreign page: refused before Bokeh's handler
    status, body, _ = _get(port, "/ws", {"Host": own, "Origin": "http://evil.example", "Upgrade": "websocket",
                                         "Connection": "Upgrade", "Sec-WebSocket-Version": "13",
                                         "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ=="})
    assert status == 403 and b"Origin" in body
    assert server.proc.poll() is None


@pytest.mark.slow
def test_a_get_computes_and_reads_nothing(server, tmp_path):
    """Item 1 (b): the GET that creates a page builds a placeholder; the URL's files and map are
    the page's session's first work. ``/dev/zero`` as the schedule grew the server to 5.2 GB;
    a FIFO blocked it; a 1000 x 1000 map was computed on a GET from anyone."""
    port = server.port
    _get(port, "/")                                  # warm: the first page imports what pages need
    fifo = tmp_path / "fifo.toml"                    # outside the server's directory
    os.mkfifo(fifo)
    pid = server.proc.pid
    rss0, cpu0 = _rss_kb(pid), _cpu_s(pid)
    for query in ("schedule=/dev/zero", f"params={fifo}", "params=/etc/passwd",
                  "P_gain=log:1:20000:1000&D_gain=lin:1:50:1000&robust=on"):
        status, body, seconds = _get(port, "/?" + query)
        assert status == 200, query
        assert seconds < 1.0, (query, seconds)
    rss1, cpu1 = _rss_kb(pid), _cpu_s(pid)
    print(f"\nfour GETs: RSS {rss0 / 1e3:.1f} -> {rss1 / 1e3:.1f} MB, server CPU {cpu1 - cpu0:.2f} s")
    assert rss1 - rss0 < 8_000, (rss0, rss1)         # a 1000 x 1000 map alone is 28 MB of arrays
    assert cpu1 - cpu0 < 1.0
    assert _get(port, "/")[0] == 200 and server.proc.poll() is None


@pytest.fixture
def own_server(tmp_path):
    """A server of the test's own (its sessions and memory are the test's alone)."""
    s = _start(tmp_path)
    yield s
    s.stop()


@pytest.mark.slow
def test_at_most_max_sessions_pages(own_server):
    """Beyond MAX_SESSIONS live pages, a page says so and computes nothing (each GET above is a
    session until it expires; a page is the websocket's document, read here with bokeh.client)."""
    pytest.importorskip("panel")
    import panel.models  # noqa: F401  (the page's models, for the client to read the document)
    from bokeh.client import pull_session
    pid = own_server.proc.pid
    for _ in range(app.MAX_SESSIONS - 1):        # start_server's own GET was the first
        assert _get(own_server.port, "/?P_gain=log:1:20000:1000&D_gain=lin:1:50:1000")[0] == 200
    cpu0 = _cpu_s(pid)
    with pull_session(url=own_server.url) as session:
        text = " ".join(str(getattr(m, "text", "")) for m in session.document.roots)
    assert f"{app.MAX_SESSIONS} pages are open" in text and "close one" in text
    assert _cpu_s(pid) - cpu0 < 1.0
    assert own_server.proc.poll() is None


@pytest.mark.slow
def test_closed_pages_stop_working_and_give_memory_back(own_server):
    """Item 1 (d): pages each asking a 1000 x 1000 map, closed while the work queue holds
    them: the server stops computing within a second of the queue's current map, and its memory
    returns near where it was once the sessions are destroyed (UNUSED_SESSION_LIFETIME_MS)."""
    from explore_driver import DriverError, launch
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        from explore_driver import INSTALL
        pytest.fail(INSTALL)
    pid = own_server.proc.pid
    with sync_playwright() as p:
        try:
            browser = launch(p)
        except DriverError as exc:
            pytest.fail(str(exc))
        # one small page first: the baseline holds what any page costs (the imports of the
        # page's models, the actuator's compiled loop)
        page = browser.new_page()
        page.goto(own_server.url)
        page.wait_for_selector('#explore-view[data-seq="1"]', state="attached", timeout=60000)
        page.close()
        rss0 = _rss_kb(pid)
        n = 5
        pages = []
        for i in range(n):
            pg = browser.new_page()
            pg.goto(own_server.url + f"?P_gain=log:1:20000:1000&D_gain=lin:1:50:1000&set.beta={2 + i / 10}",
                    wait_until="commit")
            pages.append(pg)
        # until the first map is drawn: the queue holds the others
        pages[0].wait_for_selector('#explore-view[data-seq="1"]', state="attached", timeout=60000)
        rss_peak = _rss_kb(pid)
        for pg in pages:
            pg.close()
        t_closed, cpu_closed = time.monotonic(), _cpu_s(pid)
        time.sleep(1.0)                              # the websockets' closing handshakes
        browser.close()
    # the map being computed when the tabs closed finishes (1-3 s, more on a loaded machine);
    # the others are dropped unrun: the server goes idle (a 2 s window with next to no CPU)
    cpu_a, t_a = _cpu_s(pid), time.monotonic()
    while True:
        time.sleep(0.5)
        cpu_b, t_b = _cpu_s(pid), time.monotonic()
        if t_b - t_a >= 2.0:
            if cpu_b - cpu_a < 0.2 or t_b - t_closed > 20.0:
                break
            cpu_a, t_a = cpu_b, t_b
    idle_after, idle_cpu, work_after = t_a - t_closed, cpu_b - cpu_a, cpu_a - cpu_closed
    # the sessions end UNUSED_SESSION_LIFETIME_MS after their websockets closed; their memory is
    # handed back then
    rss_peak = max(rss_peak, _rss_kb(pid))
    deadline = t_closed + (app.UNUSED_SESSION_LIFETIME_MS + 30 * app.CHECK_UNUSED_SESSIONS_MS) / 1e3
    while (rss1 := _rss_kb(pid)) - rss0 >= 40_000 and time.monotonic() < deadline:
        time.sleep(0.5)
    print(f"\n{n} pages of 1000 x 1000: RSS baseline {rss0 / 1e3:.0f} MB, peak {rss_peak / 1e3:.0f} MB, "
          f"{time.monotonic() - t_closed:.1f} s after closing {rss1 / 1e3:.0f} MB; after closing the server "
          f"worked {work_after:.2f} s of CPU and was idle from {idle_after:.1f} s ({idle_cpu:.2f} s CPU in 2 s)")
    assert idle_cpu < 0.2
    assert rss1 - rss0 < 40_000, (rss0, rss_peak, rss1)
    assert _get(own_server.port, "/")[0] == 200


@pytest.mark.slow                                   # two maps of the default 200 x 100 grid: 1-3 s
def test_page_says_what_is_in_force_and_switching_the_actuator_resets_it():
    """Item 15: the drop-downs name their empty choice (the file's filter, nominal, the
    default delay); the detail panels say what to do before a point; another actuator brings its
    own keys, configurations and the default map, not the last file's overrides, axes or point."""
    pytest.importorskip("panel")
    import bokeh
    import panel
    state = ViewState(configuration="retracted", P_gain="log:1:20000:12", D_gain="lin:1:50:6",
                      point="200,10").with_set("beta", "3").with_set("J_L2", "0.2")
    p = app._Page(state, panel, bokeh)
    p.start()
    assert p.detail is not None and p.w_keys["beta"].value == "3"
    assert p.w_filter.options["the file's (average)"] == "" and p.w_config.options[app.NOMINAL] == ""
    assert p.w_delay.options["default (0)"] == ""
    p.w_params.value = "sea"
    assert p.w_keys["beta"].value == "" and p.plant_inputs["J_m"].value == ""
    assert (p.w_P.value, p.w_D.value, p.w_point.value) == (ViewState().P_gain, ViewState().D_gain, "")
    assert p.w_config.value == "" and set(p.w_config.options.values()) == {""} | set(
        resolve(ViewState(params="sea", P_gain="1", D_gain="1")).file_params.configurations)
    assert p.detail is None and "Click the map" in p.margins_html.object and not p.phase_src.data["x"]
    assert p.good == ViewState(params="sea") and p.view.P_gain.size == 200
