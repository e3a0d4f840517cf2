"""The explorer's page (Panel + Bokeh): controls, the gain map with the exact curves, the detail
of a clicked point, overlays and export. It computes nothing itself: every number comes from
:mod:`haa_sym.explore.state` (which calls the library); a refusal shows the CLI's message and the
page stays as it was.

Every number the page shows is also in the DOM as JSON, for tests and scripts:
``<pre id="explore-view" data-seq="N">`` (the state, the map's decisions, or the refusal) and
``<pre id="explore-detail" data-seq="N">`` (the clicked point). ``data-seq`` counts the page's
updates.

The server answers only its own page (:func:`request_refusal`, checked on every HTTP request and
the websocket: Host, Origin, Sec-Fetch-Site), builds a page without computing anything or
reading any file (the work starts when the page's own session reports it is loaded), runs all
work through one queue (:class:`WorkQueue`: one computation at a time, a session's pending work
superseded by its newer request and dropped when the session closes), serves at most
:data:`MAX_SESSIONS` pages at once and reads files only where the command line allows
(:func:`haa_sym.io.inputs.restrict_reads`). docs/explore.md, "Who may ask, and what it costs".

Panel and Bokeh are imported lazily (the optional extra ``haa_sym[explore]``): importing this
module costs nothing; :func:`serve` and :func:`page` import them.
"""
from __future__ import annotations

import asyncio
import ctypes
import ctypes.util
import gc
import html
import logging
import math
import re
import time
from pathlib import Path

import numpy as np

from haa_sym.errors import ParameterError
from haa_sym.explore.state import (CATEGORIES, ViewState, clear_caches, compute_view, dumps, from_query,
                                   point_detail, resolve, to_query, view_summary)
from haa_sym.explore.export import export_view
from haa_sym.io.inputs import command_scope, restrict_reads
from haa_sym.model import filters
from haa_sym.model.params import CONTROLLER_KEYS, CONTROLLER_UNITS, STRING_KEYS, actuator_path, load_params

NOMINAL = "nominal (no configuration)"
# what the detail panels say before a point is chosen
_NO_POINT = ("<div id='explore-margins'><b>Click the map</b> (or type a point, left) to see that gain point's "
             "margins, the corrected phase of Z, the torque and impedance steps and the closed-loop poles below.</div>")

__all__ = ["page", "serve", "EXTRA_MISSING", "CATEGORY_COLORS", "available", "request_refusal", "WorkQueue",
           "MAX_SESSIONS", "UNUSED_SESSION_LIFETIME_MS", "CHECK_UNUSED_SESSIONS_MS", "KEEP_ALIVE_MS", "live_sessions"]

log = logging.getLogger(__name__)

# At most this many pages (browser tabs) at once; one more gets a page saying so and computes
# nothing. A page holds its map (up to MAX_POINTS points: the categories, the decisions and the
# Bokeh document's copy, 10-50 MB at the limit), so the bound is also the server's memory bound.
MAX_SESSIONS = 8
# A page whose websocket has closed (or never opened) is destroyed after this long, its memory
# released (Bokeh's default: 15 s, checked every 17 s). The page's scripts come from this server
# and connect within a second or two; 10 s leaves room on a loaded machine.
UNUSED_SESSION_LIFETIME_MS = 10_000
CHECK_UNUSED_SESSIONS_MS = 1_000
# Bokeh pings every websocket this often (its default: 37 s): a connection whose browser vanished
# without closing it is noticed, and its page destroyed, within seconds
KEEP_ALIVE_MS = 5_000

# the package is on no index: the extra installs from a checkout
EXTRA_MISSING = ("the explorer needs Panel and Bokeh, the optional extra: pip install -e '.[explore]' in a checkout "
                 "(or pip install 'panel>=1.9' 'bokeh>=3.4')")
# one colour per state.CATEGORIES entry: io.plots' region colours (white stable, grey PM < 30 deg,
# dark unstable), tinted blue where the port is not passive
CATEGORY_COLORS = ("#ffffff", "#cfe0f3", "#c8c8c8", "#9fb4cc", "#3a3a3a")
_EDGE_DASH = "6 2 2 2 2 2"                 # dash-dot-dot, as io.plots' range edge (Bokeh: whole pixels)
# each family of state.CURVE_FAMILIES: colour, dash, legend (the frequency-range edges of the
# passivity boundary in the boundary's colour, dash-dotted, and named as what they are: the
# figures' style and words, haa_sym.io.plots' "range edge")
CURVE_STYLES = {"stability": ("#d62728", "solid", "stability boundary"),
                "pm": ("#2ca02c", "dashed", "PM = 30 deg"),
                "passivity": ("#17becf", "solid", "passivity boundary (|phase Z| = 90 deg)"),
                "passivity_omega_min": ("#17becf", _EDGE_DASH, "edge of the judged frequency range (omega_min)"),
                "passivity_nyquist": ("#17becf", _EDGE_DASH, "edge of the judged frequency range (Nyquist)")}
# controller keys with their own control (the rest of the file's keys are in the actuator panel)
_CONTROL_KEYS = ("beta", "alpha", "Ts") + tuple(filters.PARAMETERS)


def available() -> bool:
    """Whether Panel and Bokeh can be imported."""
    import importlib.util
    return all(importlib.util.find_spec(m) is not None for m in ("panel", "bokeh"))


def _edges(v: np.ndarray, log: bool) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper cell edges of the grid values ``v`` (midpoints; in log space on a log axis)."""
    x = np.log(v) if log else np.asarray(v, float)
    if x.size == 1:
        half = 0.05 * abs(x[0]) if x[0] else 0.5
        e = np.array([x[0] - half, x[0] + half])
    else:
        mid = (x[1:] + x[:-1]) / 2
        e = np.concatenate([[2 * x[0] - mid[0]], mid, [2 * x[-1] - mid[-1]]])
    e = np.exp(e) if log else e
    return e[:-1], e[1:]


def _uniform(v: np.ndarray, log: bool) -> bool:
    """Whether the grid values are evenly spaced (in log space on a log axis): then the map is one
    image whose pixels fall on the cells."""
    x = np.log(v) if log else np.asarray(v, float)
    if x.size < 2:
        return True
    d = np.diff(x)
    return bool(np.all(d > 0) and np.ptp(d) <= 1e-9 * max(abs(x).max(), 1.0))


def _pre(pid: str, seq: int, data) -> str:
    # the numbers as JSON for tests and scripts: in the DOM, not shown
    return f'<pre id="{pid}" data-seq="{seq}" style="display:none">' \
           f"{html.escape(dumps(data))}</pre>"


class _Page:
    """One browser tab: its widgets, figures and the last good state."""

    def __init__(self, initial: ViewState, pn, bk, error: Exception | None = None):
        self.pn, self.bk = pn, bk
        self.seq = 0
        self.detail_seq = 0
        self.good: ViewState | None = None
        self.view = None
        self.detail = None
        self._building = False
        self.built = False
        self._state0, self._error0 = initial, error
        self.pending: dict[str, None] = {}
        self.queue: WorkQueue | None = None
        self.doc = None
        self.closed = False
        # what the GET that creates the document sends: this column, empty but for a line; the
        # page's widgets and figures are built as the session's first work (:meth:`run`), so a
        # GET costs a few milliseconds whatever its URL says
        self.root = pn.Column(pn.pane.HTML('<div id="explore-loading">loading the explorer ...</div>'),
                              sizing_mode="stretch_width")

    def _build(self):
        """The widgets and figures of the page, for the state of its URL."""
        pn = self.pn
        self._building = True
        W = pn.widgets
        s = self._state0
        self.w_params = W.TextInput(label="actuator (bundled name or TOML file)", value=s.params,
                                    css_classes=["ex-params"])
        self.w_config = W.Select(label="configuration", options=_with([""], "", NOMINAL), value="",
                                 css_classes=["ex-configuration"])
        self.w_blend_to = W.Select(label="slide towards configuration", options=_with([""], "", "none"), value="",
                                   css_classes=["ex-blend-to"])
        self.w_blend = W.FloatSlider(label="position between them", start=0.0, end=1.0, step=0.05,
                                     value=_slider_value(s.blend), css_classes=["ex-blend"])
        sets = dict(s.sets)
        self.w_keys = {}
        for key in _CONTROL_KEYS:
            self.w_keys[key] = W.TextInput(label=key, value=sets.get(key, ""), css_classes=[f"ex-set-{key}"])
        # a value from the URL that is not a choice stays selectable, so that the page refuses it
        # with the CLI's message rather than dropping it
        vf = sets.get("velocity_filter", "")
        self.w_filter = W.Select(label="velocity_filter", options=_with([""] + list(filters.names()), vf, "the file's"),
                                 value=vf,
                                 css_classes=["ex-set-velocity_filter"])
        opts = dict(s.options)
        delay = opts.get("delay", "")
        self.w_delay = W.Select(label="delay (samples)", options=_with(["", "0", "1"], delay, "default (0)"),
                                value=delay,
                                css_classes=["ex-option-delay"])
        self.extra_options = {k: v for k, v in opts.items() if k != "delay"}
        self.w_P = W.TextInput(label="P_gain axis (Nm/rad)", value=s.P_gain, css_classes=["ex-P_gain"])
        self.w_D = W.TextInput(label="D_gain axis (Nms/rad)", value=s.D_gain, css_classes=["ex-D_gain"])
        self.w_point = W.TextInput(label="point P_gain,D_gain (or click the map)", value=s.point,
                                   css_classes=["ex-point"])
        self.w_schedule = W.TextInput(label="schedule CSV (haa-sym schedule --out)", value=s.schedule,
                                      css_classes=["ex-schedule"])
        self.w_measured = W.TextInput(label="measured points CSV (P_gain,D_gain,outcome)", value=s.measured,
                                      css_classes=["ex-measured"])
        self.w_robust = W.TextInput(label="robust region: on or FROM:TO", value=s.robust, css_classes=["ex-robust"])
        self.w_export_dir = W.TextInput(label="export directory", value="explore-export", css_classes=["ex-export-dir"])
        self.w_export = W.Button(label="export actuator file + PNG + JSON", css_classes=["ex-export"])
        self.actuator_box = pn.Column()
        self.plant_inputs: dict = {}
        self.extra_sets: dict = {}
        self.message = pn.pane.HTML("", css_classes=["ex-message"], sizing_mode="stretch_width")
        self.view_pre = pn.pane.HTML(_pre("explore-view", 0, {}), sizing_mode="stretch_width")
        self.detail_pre = pn.pane.HTML(_pre("explore-detail", 0, {}), sizing_mode="stretch_width")
        self.margins_html = pn.pane.HTML(_NO_POINT, sizing_mode="stretch_width")
        self.link = pn.pane.HTML("", sizing_mode="stretch_width")
        self._figures()
        # the actuator's panel reads the file: after the widgets, in the same first job
        self._initial = (s.params, sets, s.configuration, s.blend_to)
        # the slider's position as typed in the URL, until the slider moves: a position outside
        # [0, 1] is refused with the CLI's message, not clamped to the slider's range
        self.blend_text = s.blend
        for w in [self.w_params]:
            w.param.watch(self._on_params, "value")
        for w in [self.w_config, self.w_blend_to, self.w_filter, self.w_delay, self.w_P, self.w_D,
                  self.w_schedule, self.w_measured, self.w_robust, *self.w_keys.values()]:
            w.param.watch(self._on_change, "value")
        self.w_blend.param.watch(self._on_blend, "value")
        self.w_point.param.watch(self._on_point, "value")
        self.w_export.on_click(self._on_export)
        self._building = False

    # ------------------------------------------------------------------ layout
    def _figures(self):
        from bokeh.models import ColumnDataSource, LinearColorMapper, Span
        from bokeh.plotting import figure
        # a uniform grid (log or linear, as the axis) is one image, drawn fast; any other grid quads
        self.image_src = ColumnDataSource({"image": [], "x": [], "y": [], "dw": [], "dh": []})
        self.map_src = ColumnDataSource({"left": [], "right": [], "bottom": [], "top": [], "cat": []})
        self.robust_src = ColumnDataSource({"left": [], "right": [], "bottom": [], "top": []})
        self.curve_src = {f: ColumnDataSource({"xs": [], "ys": []}) for f in CURVE_STYLES}
        self.sched_src = ColumnDataSource({"x": [], "y": [], "beta": []})
        self.meas_src = ColumnDataSource({"x": [], "y": [], "outcome": [], "color": []})
        self.point_src = ColumnDataSource({"x": [], "y": []})
        self.mapper = LinearColorMapper(palette=list(CATEGORY_COLORS), low=-0.5, high=len(CATEGORY_COLORS) - 0.5)
        self.figs = {}
        self.legend_items = {}                  # legend item -> the source whose data it names
        self.map_log = True
        self.map_pane = self.pn.pane.Bokeh(self._map_figure(True), sizing_mode="stretch_width")
        self.phase_src = ColumnDataSource({"x": [], "y": []})
        self.tstep_src = ColumnDataSource({"x": [], "y": []})
        self.zstep_src = ColumnDataSource({"x": [], "y": []})
        self.poles_src = ColumnDataSource({"x": [], "y": []})
        small = dict(width=320, height=240, toolbar_location=None)
        fp = figure(title="corrected phase of Z (deg)", x_axis_type="log", x_axis_label="omega (rad/s)", **small)
        fp.line("x", "y", source=self.phase_src)
        for y in (90, -90):
            fp.add_layout(Span(location=y, dimension="width", line_color="black", line_dash="dotted"))
        ft = figure(title="torque step, impedance loop open (Nm)", x_axis_label="t (s)", **small)
        ft.line("x", "y", source=self.tstep_src)
        fz = figure(title="impedance step: theta per Nm at the port", x_axis_label="t (s)", **small)
        fz.line("x", "y", source=self.zstep_src)
        fo = figure(title="closed-loop poles (z-plane)", match_aspect=True, **small)
        th = np.linspace(0, 2 * np.pi, 200)
        fo.line(np.cos(th), np.sin(th), line_color="gray")
        fo.scatter("x", "y", source=self.poles_src, marker="x", size=8, color="#d62728")
        self.detail_figs = (fp, ft, fz, fo)

    def _map_figure(self, log: bool):
        """The map's figure with a log (or linear) P_gain axis, built when first shown (a page
        starts with the log one: building a figure is most of a page's cost)."""
        if log in self.figs:
            return self.figs[log]
        from bokeh.events import Tap
        from bokeh.models import Legend, LegendItem
        from bokeh.plotting import figure
        # as wide as the window leaves it (the legend takes about 260 px of it)
        f = figure(sizing_mode="stretch_width", min_width=600, height=460, x_axis_type="log" if log else "linear",
                   tools="pan,wheel_zoom,reset,save", x_axis_label="P_gain (Nm/rad)", y_axis_label="D_gain (Nms/rad)",
                   toolbar_location="above")
        f.image(image="image", x="x", y="y", dw="dw", dh="dh", source=self.image_src, color_mapper=self.mapper)
        f.quad(left="left", right="right", bottom="bottom", top="top", source=self.map_src, line_width=0,
               fill_color={"field": "cat", "transform": self.mapper})
        named = [(f.quad(left="left", right="right", bottom="bottom", top="top", source=self.robust_src,
                         line_width=0, fill_color="#2ca02c", fill_alpha=0.25), "robust over the leg range",
                  self.robust_src)]
        for fam, (color, dash, label) in CURVE_STYLES.items():
            named.append((f.multi_line(xs="xs", ys="ys", source=self.curve_src[fam], line_color=color,
                                       line_dash=dash, line_width=2), label, self.curve_src[fam]))
        named.append((f.scatter("x", "y", source=self.sched_src, marker="triangle", size=6, color="#9467bd"),
                      "schedule: robust beta exists", self.sched_src))
        named.append((f.scatter("x", "y", source=self.meas_src, marker="circle", size=8, fill_color="color",
                                line_color="black"), "measured (green stable, red otherwise)", self.meas_src))
        named.append((f.scatter("x", "y", source=self.point_src, marker="x", size=16, line_width=3,
                                color="#ff7f0e"), "the point", self.point_src))
        # the legend beside the map, never over it; an entry only while its layer holds data
        items = [LegendItem(label=label, renderers=[rend], visible=False) for rend, label, _ in named]
        self.legend_items.update({item: src for item, (_, _, src) in zip(items, named)})
        f.add_layout(Legend(items=items, label_text_font_size="8pt", spacing=0, padding=4,
                            location="top_left"), "right")
        f.on_event(Tap, self._on_tap)
        self.figs[log] = f
        return f

    def layout(self):
        pn = self.pn
        # the categories' colours in one line above the map (the curves' legend is beside it)
        legend = "<div id='explore-categories' style='font-size:12px'>" + " ".join(
            f'<span style="white-space:nowrap"><span style="background:{c};border:1px solid #888;padding:0 8px;'
            f'margin:0 4px"></span>{html.escape(t)}</span>' for c, t in zip(CATEGORY_COLORS, CATEGORIES)) + "</div>"
        controls = pn.Column(
            "### Actuator and controller", self.w_params, self.w_config, self.w_blend_to, self.w_blend,
            self.w_keys["beta"], self.w_keys["alpha"], self.w_filter,
            *[self.w_keys[k] for k in filters.PARAMETERS], self.w_keys["Ts"], self.w_delay,
            pn.Card(self.actuator_box, title="actuator (every numeric key; empty = the file's value)",
                    collapsed=True, width=300),
            "### Map", self.w_P, self.w_D, self.w_point,
            pn.Card(self.w_schedule, self.w_measured, self.w_robust, title="overlays", collapsed=True, width=300),
            pn.Card(self.w_export_dir, self.w_export, title="export", collapsed=True, width=300),
            width=320)
        main = pn.Column(self.message, pn.pane.HTML(legend, sizing_mode="stretch_width"), self.map_pane,
                         self.margins_html, pn.Row(*self.detail_figs[:2]), pn.Row(*self.detail_figs[2:]), self.link,
                         self.view_pre, self.detail_pre, sizing_mode="stretch_width")
        return pn.Row(controls, main, sizing_mode="stretch_width")

    def _actuator_panel(self, name: str, sets: dict, configuration: str, blend_to: str):
        """The file's configurations and one input per plant key (placeholder: the file's value)."""
        try:
            p = load_params(actuator_path(name or None, "--params"))
        except ParameterError:
            return
        names = [""] + list(p.configurations)
        self.w_config.options = _with(names, configuration, NOMINAL)
        self.w_config.value = configuration
        self.w_blend_to.options = _with(names, blend_to, "none")
        self.w_blend_to.value = blend_to
        for w in self.plant_inputs.values():
            w.param.unwatch(w._ex_watcher)
        self.plant_inputs = {}
        top = p.plant.topology
        units = {**top.units, **CONTROLLER_UNITS}
        # every plant key, and the controller's keys without a control of their own (P_t0, I_t0)
        keys = list(top.parameter_keys) + [k for k in CONTROLLER_KEYS if k not in _CONTROL_KEYS + STRING_KEYS]
        for key in keys:
            v = getattr(p.plant, key) if key in top.parameter_keys else getattr(p.controller, key)
            w = self.pn.widgets.TextInput(label=f"{key} ({units.get(key, '')})", value=str(sets.get(key, "")),
                                          placeholder=f"{v:g}", css_classes=[f"ex-set-{key}"], width=260)
            w._ex_watcher = w.param.watch(self._on_change, "value")
            self.plant_inputs[key] = w
        self.actuator_box.objects = list(self.plant_inputs.values())
        # overrides of keys with no field (a URL's unknown key) stay in the state: refused, not dropped
        self.extra_sets = {k: v for k, v in sets.items() if k not in keys and k not in _CONTROL_KEYS + STRING_KEYS}
        for key in ("beta", "alpha", "Ts") + tuple(filters.PARAMETERS):
            v = getattr(p.controller, key, None)
            self.w_keys[key].placeholder = "" if v is None else f"{v:g}"
        self.w_filter.options = _with([""] + list(filters.names()), self.w_filter.value,
                                      f"the file's ({p.controller.velocity_filter})")

    # ------------------------------------------------------------------ state
    def state(self) -> ViewState:
        sets = [(k, w.value) for k, w in self.plant_inputs.items()] + list(self.extra_sets.items())
        sets += [(k, self.w_keys[k].value) for k in _CONTROL_KEYS] + [("velocity_filter", self.w_filter.value)]
        s = ViewState(params=self.w_params.value.strip(), configuration=self.w_config.value or "",
                      blend_to=self.w_blend_to.value or "", blend=self.blend_text,
                      P_gain=self.w_P.value, D_gain=self.w_D.value, point=self.w_point.value,
                      schedule=self.w_schedule.value.strip(), measured=self.w_measured.value.strip(),
                      robust=self.w_robust.value.strip())
        for k, v in sets:
            s = s.with_set(k, v)
        for k, v in {**self.extra_options, "delay": self.w_delay.value}.items():
            s = s.with_option(k, v)
        return s

    def _refused(self, exc: Exception, state: ViewState, pre_seq: bool = True):
        self.message.object = (f'<div id="explore-error" style="color:#b00020;font-weight:bold">'
                               f"haa-sym: error: {html.escape(str(exc))}</div>")
        if pre_seq:
            self.seq += 1
            self.view_pre.object = _pre("explore-view", self.seq, {"seq": self.seq, "error": str(exc),
                                                                   "query": to_query(state)})

    def refresh(self):
        """Recompute the map (and the point's detail) for the widgets' state."""
        s = self.state()
        t0 = time.perf_counter()
        try:
            r = resolve(s)
            v = compute_view(s, r)
        except ParameterError as exc:
            self._refused(exc, s)
            return
        self.good, self.view = s, v
        log = bool(np.all(v.P_gain > 0))
        xl, xr = _edges(v.P_gain, log)
        yb, yt = _edges(v.D_gain, False)
        L, R_ = np.repeat(xl, v.D_gain.size), np.repeat(xr, v.D_gain.size)
        B, T = np.tile(yb, v.P_gain.size), np.tile(yt, v.P_gain.size)
        with self.pn.io.hold():
            if log != self.map_log:
                self.map_log = log
                self.map_pane.object = self._map_figure(log)
            if _uniform(v.P_gain, log) and _uniform(v.D_gain, False):
                # the categories as bytes: a quarter of float32's payload, mapped to colours alike
                self.image_src.data = {"image": [np.ascontiguousarray(v.category.T, dtype=np.uint8)],
                                       "x": [xl[0]], "y": [yb[0]],
                                       "dw": [xr[-1] - xl[0]], "dh": [yt[-1] - yb[0]]}
                if len(self.map_src.data["cat"]):
                    self.map_src.data = {"left": [], "right": [], "bottom": [], "top": [], "cat": []}
            else:
                self.map_src.data = {"left": L, "right": R_, "bottom": B, "top": T, "cat": v.category.ravel()}
                self.image_src.data = {"image": [], "x": [], "y": [], "dw": [], "dh": []}
            for fam in CURVE_STYLES:
                cs = [c for c in v.curves if c["family"] == fam]
                self.curve_src[fam].data = {"xs": [c["P_gain"] for c in cs], "ys": [c["D_gain"] for c in cs]}
            ov = v.overlays
            rb = ov["robust"]
            keep = rb["feasible"].ravel() if rb else np.zeros(0, bool)
            self.robust_src.data = {"left": L[keep], "right": R_[keep], "bottom": B[keep], "top": T[keep]} if rb else \
                {"left": [], "right": [], "bottom": [], "top": []}
            sc = ov["schedule"]
            self.sched_src.data = ({"x": sc["P_gain"][sc["feasible"]], "y": sc["D_gain"][sc["feasible"]],
                                    "beta": sc["beta"][sc["feasible"]]} if sc else {"x": [], "y": [], "beta": []})
            me = ov["measured"]
            self.meas_src.data = ({"x": me["P_gain"], "y": me["D_gain"], "outcome": me["outcome"],
                                   "color": ["#2ca02c" if o.lower().startswith("stable") else "#d62728"
                                             for o in me["outcome"]]} if me else
                                  {"x": [], "y": [], "outcome": [], "color": []})
            f = self.figs[log]
            f.title.text = _title(r)
            self.message.object = ""
            self.seq += 1
            summary = view_summary(v)
            # the server's share of a change's latency (the browser test reports the rest)
            summary.update(seq=self.seq, query=to_query(s), overlays=_overlay_summary(ov),
                           compute_ms=round(1e3 * (time.perf_counter() - t0), 1))
            summary["legend"] = self._update_legend()
            self.view_pre.object = _pre("explore-view", self.seq, summary)
            q = to_query(s)
            self.link.object = f'<a id="explore-link" href="?{html.escape(q)}">link to this view</a>'
            if self.pn.state.location is not None:
                self.pn.state.location.search = f"?{q}" if q else ""
            if r.point is not None:
                self._detail(s, r, *r.point)

    def _clear_detail(self):
        """No point: the detail panels empty, saying what to do."""
        self.detail = None
        for src in (self.point_src, self.phase_src, self.tstep_src, self.zstep_src, self.poles_src):
            src.data = {"x": [], "y": []}
        self.margins_html.object = _NO_POINT

    def _update_legend(self) -> list[str]:
        """Show the legend entries of the layers that hold data, hide the others; returns the
        labels shown (each once)."""
        shown = []
        for item, src in self.legend_items.items():
            data = next(iter(src.data.values()), [])
            item.visible = len(data) > 0
            if item.visible and item.label.value not in shown:
                shown.append(item.label.value)
        return shown

    def _detail(self, s: ViewState, r, P: float, D: float):
        try:
            d = point_detail(s, P, D, r)
        except ParameterError as exc:
            self._refused(exc, s, pre_seq=False)
            return
        self.detail = d
        self.point_src.data = {"x": [P], "y": [D]}
        self.phase_src.data = {"x": d.phase["omega_rad_s"], "y": d.phase["phase_deg"]}
        self.tstep_src.data = {"x": d.torque_step["t_s"], "y": d.torque_step["T_Nm"]}
        self.zstep_src.data = {"x": d.impedance_step["t_s"], "y": d.impedance_step["theta_rad"]}
        self.poles_src.data = {"x": d.poles.real, "y": d.poles.imag}
        self._update_legend()
        self.margins_html.object = _margins_html(d)
        self.detail_seq += 1
        js = d.to_dict()
        small = {k: js[k] for k in ("P_gain", "D_gain", "stable", "spectral_radius", "margins")}
        small.update(seq=self.detail_seq, impedance_final_rad_per_Nm=js["impedance_step"]["final_value_rad_per_Nm"],
                     n_poles=len(js["poles"]))
        self.detail_pre.object = _pre("explore-detail", self.detail_seq, small)

    # ------------------------------------------------------------------ work
    def start(self):
        """The page's first work, once its session has loaded: its widgets and figures, the
        actuator's panel, then the map (unless the URL was refused)."""
        self._request("initial")

    def _request(self, job: str):
        """Ask for ``job`` (initial, actuator, refresh, point, export). A job
        already pending stays once (the work reads the widgets when it runs: the newest request
        supersedes the older); a refresh covers a pending point (it draws the point too)."""
        if self._building or self.closed:
            return
        self.pending[job] = None
        if self.queue is None:
            self.run()                          # no server (tests): at once
        else:
            self.queue.request(self)

    def alive(self) -> bool:
        """Whether the page is still open: not destroyed and its websocket connected."""
        if self.closed:
            return False
        ctx = self.doc.session_context if self.doc is not None else None
        # Bokeh's ServerSession (the session context exposes no connection count of its own)
        session = getattr(ctx, "_session", None)
        return session is None or (not session.destroyed and session.connection_count > 0)

    async def run_locked(self):
        """Run the pending work with the page's document locked and current (as Bokeh runs a
        browser event's callbacks)."""
        ctx = self.doc.session_context if self.doc is not None else None
        if ctx is None:
            self.run()
            return

        def locked(doc):
            from panel.io.state import set_curdoc
            with set_curdoc(doc):
                self.run()
        await ctx.with_locked_document(locked)

    def run(self):
        """Do the pending work, in the order: the actuator's panel, the map, the point, the export."""
        jobs, self.pending = self.pending, {}
        if not self.built:
            if "initial" not in jobs:
                return
            self._build()
            self.built = True
            self.root.objects = [self.layout()]
            self._building = True
            try:
                self._actuator_panel(*self._initial)
            finally:
                self._building = False
            if self._error0 is not None:
                self._refused(self._error0, self._state0)
                jobs.pop("initial")
        if "actuator" in jobs:
            # another actuator: its own values and the default map, not the last file's
            # overrides, configuration, axes or point
            self._building = True
            try:
                base = ViewState()
                for w in self.w_keys.values():
                    w.value = ""
                self.w_filter.value = self.w_delay.value = ""
                self.w_P.value, self.w_D.value, self.w_point.value = base.P_gain, base.D_gain, base.point
                self.w_blend.value, self.blend_text = 0.0, base.blend
                self._clear_detail()
                self._actuator_panel(self.w_params.value.strip(), {}, "", "")
            finally:
                self._building = False
        if jobs.keys() & {"initial", "actuator", "refresh"}:
            self.refresh()
        elif "point" in jobs:
            self._show_point()
        if "export" in jobs:
            self._export()

    def release(self):
        """Drop what the page holds (its map, its point): the session is gone."""
        self.closed = True
        self.pending = {}
        self.good = self.view = self.detail = None

    # ------------------------------------------------------------------ events
    def _on_change(self, event):
        self._request("refresh")

    def _on_blend(self, event):
        self.blend_text = f"{event.new:g}"
        self._request("refresh")

    def _on_params(self, event):
        self._request("actuator")

    def _on_point(self, event):
        self._request("point")

    def _show_point(self):
        s = self.state() if self.good is None else self.good.replace(point=self.w_point.value)
        try:
            r = resolve(s)
        except ParameterError as exc:
            self._refused(exc, s)
            return
        self.message.object = ""
        self.good = s
        if r.point is None:
            self._clear_detail()
            return
        with self.pn.io.hold():
            self._detail(s, r, *r.point)
            q = to_query(s)
            if self.pn.state.location is not None:
                self.pn.state.location.search = f"?{q}" if q else ""

    def _on_tap(self, event):
        if event.x is None or event.y is None or not (math.isfinite(event.x) and math.isfinite(event.y)):
            return
        # a click outside the quadrant snaps to the nearest allowed gain (>= 0)
        self.w_point.value = f"{max(event.x, 0.0):.6g},{max(event.y, 0.0):.6g}"

    def _on_export(self, event):
        self._request("export")

    def _export(self):
        if self.good is None or self.view is None:
            return
        try:
            written = export_view(self.good, self.w_export_dir.value.strip(), view=self.view)
        except (ParameterError, OSError) as exc:
            self._refused(exc, self.good, pre_seq=False)
            return
        self.message.object = ('<div id="explore-exported">wrote ' + ", ".join(html.escape(str(p)) for p in written)
                               + "</div>")


class WorkQueue:
    """The server's one queue of work: every page's computation runs here, one at a time, on the
    server's thread, in the order the pages asked. A page waits in it once, however many changes
    it asked for meanwhile (its work reads the widgets when it runs: the newest request wins); a
    page whose session closed is dropped unrun. Between two pages' work the event loop reads its
    sockets (a closed tab, a newer request, another page's GET are seen before the next
    computation starts). A computation that has started runs to its end (at most
    :data:`haa_sym.explore.state.MAX_POINTS` points, 1-3 s)."""

    def __init__(self):
        self._waiting: dict = {}
        self._task = None
        self.ran = 0                            # pages whose work ran, and dropped unrun
        self.dropped = 0

    def request(self, page) -> None:
        self._waiting.setdefault(page, None)
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._pump())

    def forget(self, page) -> None:
        if self._waiting.pop(page, 0) is None:
            self.dropped += 1

    async def _pump(self):
        try:
            while self._waiting:
                page = next(iter(self._waiting))
                del self._waiting[page]
                if page.alive():
                    self.ran += 1
                    try:
                        await page.run_locked()
                    except Exception:           # a bug in one page's work must not stop the others'
                        log.exception("haa-sym explore: a page's work failed")
                else:
                    page.pending = {}
                    self.dropped += 1
                await asyncio.sleep(0)
        finally:
            self._task = None


def _with(options: list, value: str, empty: str) -> dict:
    """A drop-down's choices, label -> value: ``options`` and ``value`` when it is none of them
    (a URL's value stays selectable, so that the page refuses it with the CLI's message rather
    than dropping it); the empty value (the file's own, or none) labelled ``empty``, so that the
    drop-down always says what is in force."""
    values = options if value in options else options + [value]
    return {(empty if v == "" else v): v for v in values}


def _slider_value(text: str) -> float:
    """Where the slider stands for the typed position ``text``: the number when it is one in
    [0, 1], else 0 (the state keeps the text, and the page refuses it with the CLI's message)."""
    try:
        v = float(text)
    except ValueError:
        return 0.0
    return v if 0.0 <= v <= 1.0 else 0.0


def _title(r) -> str:
    p = r.params
    name = str(p.about.get("name") or Path(p.source).stem)
    c = p.controller
    return f"{name}: beta = {c.beta:g}, alpha = {c.alpha:g}, Ts = {c.Ts:g} s, filter {c.velocity_filter}"


def _overlay_summary(ov: dict) -> dict:
    out = {}
    if ov["schedule"]:
        out["schedule_feasible"] = int(ov["schedule"]["feasible"].sum())
    if ov["measured"]:
        m = ov["measured"]
        out["measured"] = {"n": len(m["outcome"]), "predicted_stable": [bool(v) for v in m["predicted_stable"]]}
    if ov["robust"]:
        out["robust_feasible"] = int(ov["robust"]["feasible"].sum())
    return out


def _margins_html(d) -> str:
    rows = []
    for loop, label in (("impedance", "impedance loop (opened at T_lref)"),
                        ("torque", "torque loop (opened at the PI output)")):
        m = d.margins[loop]
        if m is None:                       # a structure without a torque loop
            rows.append(f"<b>{label}</b>: none (no torque loop)")
            continue
        pms = ", ".join(f"{pm:+.2f} deg @ {w:.4g} rad/s" for pm, w in zip(m["phase_margins_deg"],
                                                                         m["gain_crossovers_rad_s"])) or "none"
        gms = ", ".join(f"{g:+.2f} dB @ {w:.4g} rad/s" for g, w in zip(m["gain_margins_db"],
                                                                      m["phase_crossovers_rad_s"])) or "none"
        rows.append(f"<b>{label}</b>: PM {pms}; GM {gms}")
    head = (f"<b>P_gain {d.P_gain:g} Nm/rad, D_gain {d.D_gain:g} Nms/rad</b>: "
            f"{'stable' if d.stable else 'UNSTABLE'}, spectral radius {d.spectral_radius:.6f}; "
            f"impedance step settles at {d.impedance_step['final_value_rad_per_Nm']:.4g} rad/Nm")
    return "<div id='explore-margins'>" + "<br>".join([head] + rows) + "</div>"


_QUEUE = WorkQueue()
_LIVE: dict = {}                # session id -> its _Page, while the session lives


def live_sessions() -> int:
    """The number of pages the server holds."""
    return len(_LIVE)


def page(initial: ViewState | None = None):
    """A new page (one per browser tab): its state from the URL's query string when it has one,
    else ``initial``. Builds the widgets only: nothing is computed and no file is read until the
    page's own session reports it has loaded (``pn.state.onload``); beyond :data:`MAX_SESSIONS`
    pages, a page saying so."""
    import bokeh
    import panel as pn
    state = initial or ViewState()
    doc = pn.state.curdoc
    ctx = doc.session_context if doc is not None else None
    if ctx is not None and len(_LIVE) >= MAX_SESSIONS:
        return pn.pane.HTML(f'<div id="explore-error" style="color:#b00020;font-weight:bold">haa-sym explore: '
                            f"{len(_LIVE)} pages are open, the most this server serves at once "
                            f"(MAX_SESSIONS = {MAX_SESSIONS}); close one and reload this page</div>")
    args = dict(pn.state.session_args or {}) if doc is not None else {}
    error = None
    if args:
        try:
            state = from_query(args)
        except ParameterError as exc:
            error = exc
    p = _Page(state, pn, bokeh, error)
    if ctx is None:                             # no server (tests): the work at once
        p.start()
        return p.root
    p.doc, p.queue = doc, _QUEUE
    _LIVE[ctx.id] = p
    doc.on_session_destroyed(_destroyed)
    pn.state.onload(p.start)
    return p.root


def _destroyed(session_context) -> None:
    """A page's session is gone: drop its pending work and what it holds; when it was the last,
    the library's memoised maps too; then hand the memory back (:func:`_release_memory`)."""
    p = _LIVE.pop(session_context.id, None)
    if p is not None:
        _QUEUE.forget(p)
        p.release()
    if not _LIVE:
        clear_caches()
    try:
        asyncio.get_running_loop().call_later(0.5, _release_memory)
    except RuntimeError:
        _release_memory()


def _release_memory() -> None:
    """Collect the pages' reference cycles (widgets and their watchers) and return the freed
    heap to the system: glibc keeps freed arrays of a few MB in its heap (its mmap threshold grows
    after the first large frees), so without ``malloc_trim`` the server's size stays at its
    peak."""
    gc.collect()
    try:
        ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):           # not glibc: the allocator keeps what it keeps
        pass


def request_refusal(headers, port: int) -> str | None:
    """Why the server refuses a request with these ``headers`` (a mapping), or None.

    Every HTTP request and the websocket's are checked (:func:`serve`):

    - ``Host`` must be ``127.0.0.1:PORT`` or ``localhost:PORT``: a page of another site that
      rebinds its own name to 127.0.0.1 (DNS rebinding) sends its own name;
    - ``Origin``, when sent, must be ``http://127.0.0.1:PORT`` or ``http://localhost:PORT``;
    - ``Sec-Fetch-Site``, when sent (every current browser does), must be ``same-origin`` (the
      page's own requests) or ``none`` (an address typed, a bookmark, a link from outside the
      browser): a page of another site or of another port of this machine that links, frames or
      fetches the explorer sends ``cross-site`` or ``same-site``.
    """
    hosts = (f"127.0.0.1:{port}", f"localhost:{port}")
    host = (headers.get("Host") or "").strip().lower()
    if host not in hosts:
        return f"Host {host!r}; allowed: {' or '.join(hosts)}"
    origin = headers.get("Origin")
    if origin is not None and origin.strip().lower() not in tuple(f"http://{h}" for h in hosts):
        return f"Origin {origin!r}; allowed: none, or {' or '.join('http://' + h for h in hosts)}"
    site = headers.get("Sec-Fetch-Site")
    if site is not None and site.strip().lower() not in ("same-origin", "none"):
        return f"Sec-Fetch-Site {site!r}; allowed: same-origin or none (this page's own requests, or an address typed)"
    return None


def _guard(tornado_app, port: int) -> None:
    """Route every request that :func:`request_refusal` refuses to a 403 (before any of Bokeh's
    or Panel's handlers sees it: no document is built, nothing read or computed). Tornado looks
    every request's handler up through ``find_handler``, the websocket's upgrade included."""
    from tornado.web import RequestHandler

    class Refused(RequestHandler):
        def initialize(self, reason: str):
            self.reason = reason

        def prepare(self):
            self.set_status(403)
            self.set_header("Content-Type", "text/plain; charset=utf-8")
            self.finish(f"haa-sym explore: refused: {self.reason}\n")

    find = tornado_app.find_handler

    def find_handler(request, **kwargs):
        reason = request_refusal(request.headers, port)
        if reason is not None:
            log.warning("haa-sym explore: refused %s %s: %s", request.method, request.uri[:200], reason)
            return tornado_app.get_handler_delegate(request, Refused, {"reason": reason})
        return find(request, **kwargs)

    tornado_app.find_handler = find_handler


def serve(initial: ViewState, port: int = 5006, show: bool = True, allowed=()) -> None:
    """Serve the page on http://127.0.0.1:``port``/ until Ctrl-C (KeyboardInterrupt propagates).

    The server listens on 127.0.0.1 only, answers only requests for its own address from its own
    page (:func:`request_refusal`), loads Bokeh's and Panel's scripts from itself (no CDN) and
    reads files only within ``allowed`` (files, or directories and what is below them) and the
    bundled model directory (:func:`haa_sym.io.inputs.restrict_reads`, entered before the server
    exists so that every callback runs under it); every file read is an input the export must not
    replace (:func:`haa_sym.io.inputs.command_scope`)."""
    import panel as pn
    origins = [f"127.0.0.1:{port}", f"localhost:{port}"]
    with command_scope(), restrict_reads(list(allowed)):
        server = pn.serve({"/": lambda: page(initial)}, port=port, address="127.0.0.1", websocket_origin=origins,
                          show=False, title="haa-sym explore", start=False, threaded=False, verbose=False,
                          unused_session_lifetime_milliseconds=UNUSED_SESSION_LIFETIME_MS,
                          check_unused_sessions_milliseconds=CHECK_UNUSED_SESSIONS_MS,
                          keep_alive_milliseconds=KEEP_ALIVE_MS)
        _guard(server._tornado, port)           # Bokeh's Server keeps its tornado Application there
        server.start()
        if show:
            server.io_loop.add_callback(server.show, "/")
        server.io_loop.start()


def resources_are_local(text: str) -> list[str]:
    """The external (http, https or protocol-relative) script or stylesheet addresses of a page's
    HTML ``text`` (empty: everything is served locally)."""
    return re.findall(r"""<(?:script|link)[^>]+(?:src|href)=["']((?:https?:)?//[^"']+)""", text, re.I)

