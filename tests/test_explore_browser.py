"""``haa-sym explore`` in headless Chromium: the server in a subprocess on a free port, the page
driven with playwright (Debian's /usr/bin/chromium, `make browser`), and what the page reports
(the JSON it exposes in ``#explore-view`` / ``#explore-detail``) compared with the library's own
results for the same parameters, computed here in the test's process. The driving and the timing
are ``tests/explore_driver.py``'s, shared with ``benchmarks/bench_explore.py``.

Latencies (a control change to the redrawn 200 x 100 map, a click to the point's detail, by the
page's clock) are measured, printed and written to ``latency.json`` in a temporary directory
(printed), with the load average; no test asserts them: speed is judged against the issue's
targets by the benchmark (``make bench``), not by a test whose outcome would follow the machine's
load. Screenshots at three settings (and one with overlays) go to the same directory."""
import json
import signal
import tempfile
from urllib.parse import urlencode
from pathlib import Path

import numpy as np
import pytest

from explore_driver import (CHANGES, DriverError, INSTALL, Tab, drive_changes, drive_clicks, launch, load,
                            start_server, summary)
from haa_sym.analysis.margins import margins
from haa_sym.errors import ParameterError
from haa_sym.explore.app import resources_are_local
from haa_sym.explore.state import ViewState, compute_view, from_query, resolve, view_summary
from haa_sym.model.params import load_params

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def server(outdir):
    try:
        s = start_server(args=["--allow", str(outdir)])         # the overlays' CSV is written there
    except DriverError as exc:
        pytest.fail(str(exc))
    yield {"proc": s.proc, "url": s.url, "html": s.html}
    s.stop()


@pytest.fixture(scope="module")
def browser():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.fail(INSTALL)
    with sync_playwright() as p:
        try:
            b = launch(p)
        except DriverError as exc:
            pytest.fail(str(exc))
        yield b
        b.close()


@pytest.fixture(scope="module")
def outdir():
    """Where the screenshots and the measured latencies go (printed)."""
    return Path(tempfile.mkdtemp(prefix="haa_sym_explore_"))


def _record(outdir: Path, key: str, data: dict) -> Path:
    """Add ``data`` under ``key`` to ``latency.json`` in ``outdir``."""
    path = outdir / "latency.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    path.write_text(json.dumps({**old, key: data}, indent=1) + "\n")
    return path


def _library_categories(query: str) -> str:
    """The map of the same parameters, computed by the library in this process."""
    return view_summary(compute_view(from_query(query)))["category"]


def _refusal(state: ViewState) -> str:
    with pytest.raises(ParameterError) as exc:
        resolve(state)
    return f"haa-sym: error: {exc.value}"


def test_page_has_no_external_assets(server, browser):
    assert resources_are_local(server["html"]) == []
    assert "127.0.0.1" in server["url"]
    # and the browser asks nothing of any other host while the page loads and draws
    page = browser.new_page()
    asked = []
    page.on("request", lambda r: asked.append(r.url))
    page.goto(server["url"])
    page.wait_for_selector('#explore-view[data-seq="1"]', state="attached", timeout=60000)
    page.close()
    elsewhere = [u for u in asked if not u.startswith((server["url"], "ws://127.0.0.1", "data:", "blob:"))]
    assert asked and not elsewhere, elsewhere


def test_controls_redraw_the_library_map(server, browser, outdir):
    tab = Tab(browser, server["url"])
    v = tab.view()
    assert (v["n_P"], v["n_D"]) == (200, 100)
    assert v["category"] == _library_categories(v["query"])
    steps = drive_changes(tab)
    assert [s["control"] for s in steps] == [c[1] for c in CHANGES]
    betas = steps[:10]
    assert betas[-1]["view"]["query"] == "set.beta=1"
    # every beta's map, and the last, are the library's for the same parameters
    for s in betas[::3] + [betas[-1]]:
        assert s["error"] is None and s["view"]["category"] == _library_categories(s["view"]["query"])
    refused = next(s for s in steps if s["value"] == "lowpass1")
    assert "f_c" in refused["error"]
    v = steps[-1]["view"]
    assert steps[-1]["error"] is None
    state = from_query(v["query"])
    assert dict(state.sets) == {"beta": "1", "alpha": "0.5", "f_c": "60", "Ts": "0.0005",
                                "velocity_filter": "lowpass1"}
    assert state.configuration == "retracted" and dict(state.options) == {"delay": "1"}
    assert v["category"] == _library_categories(v["query"])
    # measured and reported, not asserted: benchmarks/bench_explore.py judges the targets
    lat = {**summary([s["s"] for s in steps]), "load_average": load(),
           "server_compute_ms_beta": [s["view"]["compute_ms"] for s in betas]}
    path = _record(outdir, "change_to_redrawn_map_200x100", lat)
    print(f"\ncontrol change -> redrawn 200 x 100 map: median {lat['median_ms']:.0f} ms, worst "
          f"{lat['worst_ms']:.0f} ms over {lat['n']} changes ({', '.join(f'{t:.0f}' for t in lat['all_ms'])} ms); "
          f"load average {lat['load_average']:.2f}; the server's computation of the beta changes: "
          f"{', '.join(f'{t:.0f}' for t in lat['server_compute_ms_beta'])} ms ({path})")
    tab.page.close()


def test_click_shows_the_library_margins(server, browser, outdir):
    tab = Tab(browser, server["url"] + "?set.beta=2")
    loop = resolve(from_query(tab.view()["query"])).loop
    clicks = drive_clicks(tab)
    for c in clicks:
        d = c["detail"]
        P, D = d["P_gain"], d["D_gain"]
        assert P > 0 and D > 0
        for which, name in (("L_imp", "impedance"), ("L_t", "torque")):
            m = margins(loop, P, D, which=which)
            np.testing.assert_allclose(d["margins"][name]["phase_margins_deg"], m.phase_margins_deg, atol=1e-9)
            np.testing.assert_allclose(d["margins"][name]["gain_crossovers_rad_s"], m.gain_crossovers, rtol=1e-9)
        assert d["stable"] == bool(loop.stability(P, D).stable)
    assert len({(c["detail"]["P_gain"], c["detail"]["D_gain"]) for c in clicks}) == len(clicks)
    # a typed point gives the same detail as the library's for exactly that point
    tab.page.locator(".ex-point input").fill("300,12")
    tab.page.locator(".ex-point input").press("Enter")
    tab.detail_seq += 1
    tab.wait("explore-detail", tab.detail_seq)
    d = tab.detail()
    assert (d["P_gain"], d["D_gain"]) == (300.0, 12.0)
    np.testing.assert_allclose(d["margins"]["impedance"]["phase_margins_deg"],
                               margins(loop, 300.0, 12.0, which="L_imp").phase_margins_deg, atol=1e-9)
    assert "point=300%2C12" in tab.page.url
    lat = {**summary([c["s"] for c in clicks]), "load_average": load()}
    path = _record(outdir, "click_to_detail", lat)
    print(f"\nclick -> point detail: median {lat['median_ms']:.0f} ms, worst {lat['worst_ms']:.0f} ms "
          f"({', '.join(f'{t:.0f}' for t in lat['all_ms'])} ms); load average {lat['load_average']:.2f} ({path})")
    tab.page.close()


def test_screenshots_at_three_settings(server, browser, outdir):
    out = outdir
    measured = out / "measured.csv"
    measured.write_text("P_gain,D_gain,outcome\n200,10,stable\n3000,2,unstable\n50,30,stable\n")
    settings = {"hyq_nominal": "?point=200%2C10",
                "hyq_beta3_retracted": "?configuration=retracted&set.beta=3&point=1000%2C20",
                # the overlays: measured points and the robust region over the leg range
                "hyq_overlays": "?" + urlencode({"point": "200,10", "measured": str(measured), "robust": "on",
                                                 "P_gain": "log:1:20000:100", "D_gain": "lin:1:50:50"}),
                "sea": "?params=sea&point=50%2C1"}
    for name, query in settings.items():
        tab = Tab(browser, server["url"] + query)
        tab.wait("explore-detail", 1)
        assert tab.error() is None
        v = tab.view()
        assert v["category"] == _library_categories(query)
        if name == "hyq_overlays":
            lib = compute_view(from_query(query)).overlays
            assert v["overlays"]["measured"]["predicted_stable"] == lib["measured"]["predicted_stable"].tolist()
            assert v["overlays"]["robust_feasible"] == int(lib["robust"]["feasible"].sum()) > 0
        tab.page.screenshot(path=str(out / f"{name}.png"), full_page=True)
        assert (out / f"{name}.png").stat().st_size > 10_000
        tab.page.close()
    print(f"\nscreenshots: {out}")


def test_bad_input_shows_the_clis_message_and_the_server_keeps_running(server, browser):
    tab = Tab(browser, server["url"])
    good = tab.view()
    tab.page.locator(".card-header").first.click()              # the actuator panel
    cases = [(".ex-set-J_L2", "nan", ViewState().with_set("J_L2", "nan")),
             (".ex-set-J_L2", "-0.1", ViewState().with_set("J_L2", "-0.1")),
             (".ex-set-Ts", "0", ViewState().with_set("Ts", "0")),
             (".ex-P_gain", "log:1:20000:100000", ViewState(P_gain="log:1:20000:100000"))]
    for css, text, state in cases:
        tab.type(css, text)
        assert tab.error() == _refusal(state), text
        assert tab.view()["error"] == _refusal(state)[len("haa-sym: error: "):]
        tab.type(css, "" if css.startswith(".ex-set") else "log:1:20000:200")
    # 1e10 points: beyond the memory budget (the message of region_map's own gate)
    tab.type(".ex-P_gain", "log:1:20000:100000")
    tab.type(".ex-D_gain", "lin:1:50:100000")
    huge = ViewState(P_gain="log:1:20000:100000", D_gain="lin:1:50:100000")
    assert "memory budget" in tab.error() and tab.error() == _refusal(huge)
    tab.type(".ex-P_gain", "log:1:20000:200")
    tab.type(".ex-D_gain", "lin:1:50:100")
    assert tab.error() is None and tab.view()["category"] == good["category"]
    assert server["proc"].poll() is None
    tab.page.close()


def test_a_bad_url_is_refused_not_dropped(server, browser):
    tab = Tab(browser, server["url"])
    for query in ("set.bogus=1", "configuration=sitting", "option.delay=2", "set.velocity_filter=kalman",
                  "set.P_t0=-1"):
        tab.page.goto(server["url"] + "?" + query)
        tab.wait("explore-view", 1)
        tab.seq = 1
        assert tab.error() == _refusal(from_query(query)), query
    tab.page.close()


def test_two_tabs_at_once(server, browser):
    a = Tab(browser, server["url"] + "?set.beta=2")
    b = Tab(browser, server["url"] + "?params=harmonic_drive&P_gain=log:1:20000:60&D_gain=lin:1:50:30")
    va, vb = a.view(), b.view()
    a.type(".ex-set-beta", "3")
    assert b.view() == vb                                      # the other tab is untouched
    b.type(".ex-set-beta", "0.5")
    for tab in (a, b):
        v = tab.view()
        assert v["category"] == _library_categories(v["query"])
    assert a.view()["query"] == "set.beta=3" and va["query"] == "set.beta=2"
    assert "params=harmonic_drive" in b.view()["query"] and "set.beta=0.5" in b.view()["query"]
    a.page.close()
    b.page.close()


def test_the_url_reproduces_the_view(server, browser):
    a = Tab(browser, server["url"])
    a.select(".ex-configuration", "retracted")
    a.type(".ex-set-beta", "2.5")
    a.type(".ex-P_gain", "log:10:5000:120")
    url = a.page.url
    assert "configuration=retracted" in url and "set.beta=2.5" in url
    b = Tab(browser, url)
    assert b.view()["category"] == a.view()["category"] and b.view()["query"] == a.view()["query"]
    a.page.close()
    b.page.close()


def test_export_writes_the_setting(server, browser, tmp_path):
    tab = Tab(browser, server["url"] + "?set.beta=2.5&configuration=retracted&point=200%2C10")
    tab.page.locator(".card-header").nth(2).click()             # the export panel
    tab.page.locator(".ex-export-dir input").fill(str(tmp_path / "out"))
    tab.page.locator(".ex-export-dir input").press("Enter")
    tab.page.locator(".ex-export button").click()
    tab.page.wait_for_selector("#explore-exported", state="attached", timeout=30000)
    files = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert files == ["actuator.toml", "view.json", "view.png"]
    exported = load_params(tmp_path / "out" / "actuator.toml")
    analysed = resolve(from_query(tab.view()["query"])).params
    assert exported.plant == analysed.plant and exported.controller == analysed.controller
    assert json.loads((tmp_path / "out" / "view.json").read_text())["query"] == tab.view()["query"]
    tab.page.close()


def test_ctrl_c_stops_the_server(server):
    proc = server["proc"]
    assert proc.poll() is None
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err[-2000:]
    assert "stopped" in err and "Traceback" not in err
