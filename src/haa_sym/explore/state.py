"""The explorer's view state, framework-free: what the page shows, as plain data.

A :class:`ViewState` holds every input of the page as the text the user typed (so that a
refusal quotes it exactly as the CLI would, and a URL carries it unchanged): the actuator
(``params``, a bundled name or a file), its configuration or a position between two
configurations, every ``--set`` key (beta, alpha, the velocity filter and its N_av or f_c, Ts,
every numeric key of the actuator), every ``--option`` (the delay, ...), the gain grid, the
clicked point and the overlays. :func:`resolve` validates it through the CLI's own code paths
(:func:`haa_sym.model.params.parse_set` / ``apply_sets``, :func:`haa_sym.loop.options.parse_options`,
:mod:`haa_sym.io.gridspec`, the memory budget of :func:`haa_sym.analysis.regions.check_map_budget`):
the same messages. :func:`compute_view` and :func:`point_detail` call the library and return
plain data; the page (:mod:`haa_sym.explore.app`) only draws it. :func:`to_query` /
:func:`from_query` encode the state in a URL's query string (a round trip).

Example
-------
>>> s = ViewState().with_set("beta", "2")
>>> from_query(to_query(s)) == s
True
>>> to_query(s)
'set.beta=2'
"""
from __future__ import annotations

import csv
import functools
import io
import json
import math
from dataclasses import asdict, dataclass, field, fields, replace
from urllib.parse import parse_qsl, urlencode

import numpy as np

from haa_sym.analysis.boundaries.combined import boundaries
from haa_sym.analysis.boundaries.stability import stability_boundary
from haa_sym.analysis.margins import margins
from haa_sym.analysis.passivity import corrected_phase
from haa_sym.analysis.regions import check_map_budget, region_map
from haa_sym.analysis.robust import robust_region
from haa_sym.analysis.sweep import BLAS_THREADS, blas_limits
from haa_sym.analysis.torque import impedance_step, step_response
from haa_sym.errors import ParameterError
from haa_sym.io.gridspec import gain_axis
from haa_sym.io.inputs import read_text
from haa_sym.loop import ClosedLoop
from haa_sym.loop.options import parse_options
from haa_sym.loop.statespace import closed_loop_eigenvalues
from haa_sym.model.drive import DRIVE_KEYS
from haa_sym.model.params import (CONTROLLER_KEYS, actuator_path, apply_sets, gain_array, load_params,
                                  parse_set)

__all__ = ["ViewState", "Resolved", "View", "Detail", "resolve", "compute_view", "point_detail", "to_query",
           "from_query", "MAX_POINTS", "CURVE_LINES", "CURVE_XTOL", "STEP_DURATION_S", "CATEGORIES", "categories",
           "view_summary", "dumps", "parse_point", "state_dict", "plain", "blend_position", "clear_caches",
           "CURVE_FAMILIES", "PASSIVITY_FAMILIES", "MAX_CSV_BYTES", "CACHE_BYTES"]

# The page's own limit on a map's points, on top of the memory budget: a map within the budget
# can still take minutes (1e8 points), and the page answers every change; 1,000,000 points
# (1000 x 1000) decide in about 1-3 s.
MAX_POINTS = 1_000_000
# Lines of each family on which the drawn passivity curve is located (boundaries' n_lines; the
# CLI's `boundary` uses 101): the passivity curve is most of a change's computation and its cost
# grows with the lines; the map's decisions do not depend on it (they use the exact crossings of
# every D_gain row), only the drawn polyline's density (about 40 points per branch).
CURVE_LINES = 41
# How closely the drawn passivity curve's tangencies are located, in log omega (the library's
# default, 1e-10, is exact to rounding): each drawn point is still a root of its frequency's
# quadratic and passes the same on-boundary check; it moves along the curve by ~1e-9 relative
# (measured: the same points, 3.7e-10 apart in log P_gain), invisible on a 640-pixel map, and the
# refinement takes 27 instead of 46 frequency evaluations (about 15 ms of a change). The map's
# decisions do not use it.
CURVE_XTOL = 1e-6
# The window of the torque and impedance step responses, s (Fig. 7's).
STEP_DURATION_S = 0.3
# The map's categories, one per point (the page's colours; io.plots.plot_region's classes plus
# passivity): 0 stable, PM >= 30 deg, passive; 1 stable, PM >= 30 deg, not passive;
# 2 stable, PM < 30 deg, passive; 3 stable, PM < 30 deg, not passive; 4 unstable.
CATEGORIES = ("stable, PM >= 30 deg, passive", "stable, PM >= 30 deg, not passive",
              "stable, PM < 30 deg, passive", "stable, PM < 30 deg, not passive", "unstable")

# The largest overlay CSV read, bytes: a schedule of the page's default 200 x 100 grid is 2 MB,
# 16 MiB about 200,000 rows (each row becomes a dict: about 100 MB of memory at this bound).
MAX_CSV_BYTES = 16 << 20
# The memoised maps (:func:`_map_and_curves`, :func:`_robust_overlay`) hold at most this many
# bytes of arrays each, besides at most 8 entries: eight 200 x 100 maps take 5 MB, one
# 1000 x 1000 map 28 MB (its decisions, margins and spectral radii), so a few large maps are
# kept, not eight (224 MB).
CACHE_BYTES = 64_000_000

# The drawn curves' families. The passivity boundary's pieces are of two natures
# (analysis.boundaries.passivity): where the corrected phase of Z touches +-90 deg inside the
# judged frequency range (kind "passivity"), and where the set of passive gains is bounded by the
# range's own end, the phase reaching +-90 deg exactly at omega_min or at Nyquist (kinds
# "passivity (omega_min)", "passivity (Nyquist)"): a limit of the analysis, drawn and named apart.
CURVE_FAMILIES = ("stability", "pm", "passivity", "passivity_omega_min", "passivity_nyquist")
PASSIVITY_FAMILIES = {"passivity": "passivity", "passivity (omega_min)": "passivity_omega_min",
                      "passivity (Nyquist)": "passivity_nyquist"}

_TEXT_FIELDS = ("params", "configuration", "blend_to", "blend", "P_gain", "D_gain", "point", "schedule",
                "measured", "robust")


@dataclass(frozen=True)
class ViewState:
    """Every input of the page, as typed (text). Defaults: the bundled HyQ HAA joint, nominal,
    the file's values and default options, the CLI's map axes, no point, no overlay.

    ``configuration``: a configuration of the file ("" = the nominal values). ``blend_to`` and
    ``blend``: a second configuration and the position between the two (0 = ``configuration``,
    1 = ``blend_to``; every plant key either sets interpolated linearly, the leg range's
    "segment"). ``sets`` / ``options``: (key, text) pairs, as ``--set`` / ``--option``.
    ``P_gain`` / ``D_gain``: the map's axes (the CLI's grid syntax). ``point``: "P,D" (Nm/rad,
    Nms/rad) or "". ``schedule``: a schedule CSV (``haa-sym schedule --out``); ``measured``: a
    CSV of ``P_gain,D_gain,outcome``; ``robust``: "" (off), "on" (the file's default leg range)
    or "FROM:TO" (two configurations).
    """

    params: str = "hyq_haa"
    configuration: str = ""
    blend_to: str = ""
    blend: str = "0"
    sets: tuple[tuple[str, str], ...] = ()
    options: tuple[tuple[str, str], ...] = ()
    P_gain: str = "log:1:20000:200"
    D_gain: str = "lin:1:50:100"
    point: str = ""
    schedule: str = ""
    measured: str = ""
    robust: str = ""

    def replace(self, **changes) -> "ViewState":
        return replace(self, **changes)

    def with_set(self, key: str, text: str) -> "ViewState":
        """This state with ``--set key=text`` (text "" removes the override: the file's value)."""
        return replace(self, sets=_put(self.sets, key, text))

    def with_option(self, key: str, text: str) -> "ViewState":
        """This state with ``--option key=text`` (text "" removes it: the default)."""
        return replace(self, options=_put(self.options, key, text))

    def model_key(self) -> tuple:
        """What the closed loop depends on (the cache key of :func:`_loop`)."""
        return (self.params, self.configuration, self.blend_to, self.blend, self.sets, self.options)


def _put(pairs, key: str, text: str) -> tuple:
    key, text = str(key).strip(), str(text).strip()
    kept = tuple((k, v) for k, v in pairs if k != key)
    return kept + ((key, text),) if text else kept


# ----------------------------------------------------------------------------- query string

def to_query(state: ViewState) -> str:
    """The state as a URL query string: the fields that differ from the defaults, ``set.KEY`` and
    ``option.KEY`` for the overrides (in the order given)."""
    base = ViewState()
    items = [(name, getattr(state, name)) for name in _TEXT_FIELDS if getattr(state, name) != getattr(base, name)]
    items += [(f"set.{k}", v) for k, v in state.sets] + [(f"option.{k}", v) for k, v in state.options]
    return urlencode(items)


def from_query(query: str | dict) -> ViewState:
    """The state of a query string (as :func:`to_query` writes it; a leading "?" is allowed) or
    of a mapping of its items (values: text or a one-element list, as servers hand them).

    Raises
    ------
    ParameterError
        An unknown or repeated key, naming it and what is allowed.
    """
    if isinstance(query, dict):
        pairs = [(k, v[0] if isinstance(v, (list, tuple)) else v) for k, v in query.items()]
        pairs = [(k, v.decode() if isinstance(v, bytes) else str(v)) for k, v in pairs]
    else:
        pairs = parse_qsl(str(query).lstrip("?"), keep_blank_values=True)
    out, sets, options, seen = {}, (), (), set()
    for key, value in pairs:
        if key in seen:
            raise ParameterError(f"query key {key!r} given twice; allowed: once")
        seen.add(key)
        if key in _TEXT_FIELDS:
            out[key] = value
        elif key.startswith("set."):
            sets = _put(sets, key[4:], value)
        elif key.startswith("option."):
            options = _put(options, key[7:], value)
        else:
            raise ParameterError(f"query key {key!r}: unknown; allowed: {list(_TEXT_FIELDS)}, set.KEY, option.KEY")
    return ViewState(sets=sets, options=options, **out)


# ----------------------------------------------------------------------------- validation

@dataclass(frozen=True)
class Resolved:
    """A validated state: the file's parameters (``file_params``, with the configuration), the
    parameters analysed (``params``), the closed loop, the map's axes, and the point or None."""

    file_params: object
    params: object
    loop: ClosedLoop
    P_gain: np.ndarray
    D_gain: np.ndarray
    point: tuple[float, float] | None


def blend_position(text: str, a: str = "", b: str = "") -> float:
    """The slider's position ``text`` between configurations ``a`` and ``b`` as a number in
    [0, 1]; anything else (2, -0.1, nan, inf, text) is refused, never clamped.

    Raises
    ------
    ParameterError
        The position, the configurations and what is allowed.
    """
    try:
        s = float(text)
    except ValueError:
        s = math.nan
    if not 0.0 <= s <= 1.0:
        between = f"configuration {a or 'nominal'!r} and {b!r}" if b else "two configurations (blend_to)"
        raise ParameterError(f"blend = {text!r}: the position between {between}; allowed: a number from 0 to 1")
    return s


def _blend(params, file_params, a: str, b: str, text: str):
    """``params`` with every plant key configurations ``a`` or ``b`` set moved to the position
    ``text`` (0..1) between them; a key one end leaves unset keeps ``params``'s own value there."""
    s = blend_position(text, a, b)
    names = list(file_params.configurations)
    if b not in names:
        raise ParameterError(f"blend_to = {b!r}: unknown configuration; allowed: {names or 'none defined'}")
    va, vb = (dict(file_params.configurations[n]) if n else {} for n in (a, b))
    own = {k: float(getattr(params.plant, k)) for k in set(va) | set(vb)}
    return params.with_values(**{k: va.get(k, own[k]) + s * (vb.get(k, own[k]) - va.get(k, own[k]))
                                 for k in sorted(own)})


@functools.lru_cache(maxsize=16)
def _loop(model_key: tuple):
    """(file parameters, parameters, closed loop) of a state's model part, memoised: a change
    of the grid, the point or an overlay does not rebuild the loop."""
    name, configuration, blend_to, blend, sets, options = model_key
    blend_position(blend, configuration, blend_to)      # refused even while no second end is chosen
    file_params = load_params(actuator_path(name or None, "--params"))
    if configuration:
        file_params = file_params.configuration(configuration)
    params = file_params
    if blend_to:
        params = _blend(params, load_params(actuator_path(name or None, "--params")), configuration, blend_to,
                        blend)
    known = tuple(params.plant.topology.parameter_keys) + CONTROLLER_KEYS + DRIVE_KEYS
    params = apply_sets(params, parse_set([f"{k}={v}" for k, v in sets], known))
    loop = ClosedLoop(params, parse_options([f"{k}={v}" for k, v in options]))
    return file_params, params, loop


def parse_point(text: str) -> tuple[float, float] | None:
    """"P,D" (Nm/rad, Nms/rad) as two gains checked by the gains' rule, or None for ""."""
    text = str(text).strip()
    if not text:
        return None
    parts = text.split(",")
    if len(parts) != 2:
        raise ParameterError(f"point = {text!r}; allowed: P_gain,D_gain (two numbers >= 0, Nm/rad and Nms/rad)")
    values = []
    for name, part in zip(("P_gain", "D_gain"), parts):
        try:
            v = float(part)
        except ValueError:
            raise ParameterError(f"point = {text!r}: {part.strip()!r} is not a number; allowed: P_gain,D_gain "
                                 "(two numbers >= 0)") from None
        values.append(float(gain_array(name, v, f"point {name}").reshape(())))
    return values[0], values[1]


def resolve(state: ViewState) -> Resolved:
    """Validate ``state`` as the CLI validates its flags (the same messages), before any work.

    Raises
    ------
    ParameterError
        One line naming the input, its value and what is allowed.
    """
    file_params, params, loop = _loop(state.model_key())
    P, D = gain_axis(state.P_gain, "--P-gain", "P_gain"), gain_axis(state.D_gain, "--D-gain", "D_gain")
    check_map_budget(loop, P.size, D.size)
    if P.size * D.size > MAX_POINTS:
        raise ParameterError(f"--P-gain {state.P_gain!r} x --D-gain {state.D_gain!r} gives {P.size} x {D.size} = "
                             f"{P.size * D.size} points; allowed: at most {MAX_POINTS} on the page (the "
                             "CLI's `haa-sym regions` takes larger maps)")
    return Resolved(file_params, params, loop, P, D, parse_point(state.point))


# ----------------------------------------------------------------------------- the view

@dataclass(frozen=True)
class View:
    """What the page's map shows: the axes (Nm/rad, Nms/rad), the decisions (n_P, n_D) of
    :func:`haa_sym.analysis.regions.region_map`, ``category`` (:data:`CATEGORIES`), the exact
    curves (``curves``: dicts of ``family`` in :data:`CURVE_FAMILIES`, ``kind``, ``P_gain``,
    ``D_gain``), the overlays (``overlays``: schedule, measured, robust; plain data or None) and
    ``meta`` (the loop's provenance)."""

    P_gain: np.ndarray
    D_gain: np.ndarray
    stable: np.ndarray
    low_pm: np.ndarray
    passive: np.ndarray
    category: np.ndarray
    curves: list
    overlays: dict
    meta: dict = field(default_factory=dict)


def categories(stable, low_pm, passive) -> np.ndarray:
    """The index into :data:`CATEGORIES` of every point."""
    stable, low_pm, passive = (np.asarray(v, bool) for v in (stable, low_pm, passive))
    return np.where(~stable, 4, 2 * low_pm + ~passive).astype(np.int8)


def compute_view(state: ViewState, resolved: Resolved | None = None) -> View:
    """The map of ``state``: :func:`region_map` on its grid (decided from the exact curves), the
    exact stability, 30 deg PM and passivity curves in the grid's box
    (:func:`haa_sym.analysis.boundaries.combined.boundaries`) and the overlays asked for."""
    r = resolve(state) if resolved is None else resolved
    loop, P, D = r.loop, r.P_gain, r.D_gain
    m, curves = _map_and_curves(state.model_key(), state.P_gain, state.D_gain)
    overlays = {"schedule": _schedule_overlay(state.schedule) if state.schedule else None,
                "measured": _measured_overlay(state.measured, loop) if state.measured else None,
                "robust": _robust_overlay(state.model_key(), state.P_gain, state.D_gain, state.robust)
                if state.robust else None}
    return View(P, D, m.stable, m.low_pm, m.passive, categories(m.stable, m.low_pm, m.passive), curves, overlays,
                m.meta)


def _nbytes(value, depth: int = 0) -> int:
    """The bytes of the numpy arrays in ``value`` (a result of the memoised functions: arrays,
    dicts, lists, tuples, dataclasses)."""
    if isinstance(value, np.ndarray):
        return value.nbytes
    if depth > 4:
        return 0
    if isinstance(value, dict):
        return sum(_nbytes(v, depth + 1) for v in value.values())
    if isinstance(value, (list, tuple)):
        return sum(_nbytes(v, depth + 1) for v in value)
    if hasattr(value, "__dict__"):
        return _nbytes(vars(value), depth + 1)
    return 0


def _memo(max_entries: int = 8, max_bytes: int = CACHE_BYTES):
    """functools.lru_cache bounded also by the bytes of the arrays it holds (:func:`_nbytes`):
    the least recently used entries go until the rest fit (the newest is always kept).
    ``f.cache_clear()`` empties it."""
    def wrap(fn):
        import collections
        entries: collections.OrderedDict = collections.OrderedDict()

        @functools.wraps(fn)
        def memoised(*args):
            if args in entries:
                entries.move_to_end(args)
                return entries[args][0]
            value = fn(*args)
            entries[args] = (value, _nbytes(value))
            while len(entries) > 1 and (len(entries) > max_entries or
                                        sum(n for _, n in entries.values()) > max_bytes):
                entries.popitem(last=False)
            return value
        memoised.cache_clear = entries.clear
        memoised.cache_bytes = lambda: sum(n for _, n in entries.values())
        return memoised
    return wrap


def clear_caches() -> None:
    """Forget the memoised loops, maps and robust regions (the explorer's last page closed)."""
    for f in (_loop, _map_and_curves, _robust_overlay):
        f.cache_clear()


@_memo()
def _map_and_curves(model_key: tuple, P_text: str, D_text: str):
    """The map and the exact curves of a state's model and grid, memoised: going back to a
    setting seen before (an undo, a toggled overlay, a second tab) redraws at once. The loop is
    :func:`_loop`'s for the same key, so the key captures every input."""
    loop = _loop(model_key)[2]
    P, D = gain_axis(P_text, "--P-gain", "P_gain"), gain_axis(D_text, "--D-gain", "D_gain")
    box = {"P_range": (float(P.min()), float(P.max())), "D_range": (float(D.min()), float(D.max()))}
    curves = []
    # one BLAS thread for the whole view, as region_map's sweeps: the curves' small products gain
    # nothing from a second thread and lose to it on a busy two-core machine (toolchain note)
    with blas_limits(BLAS_THREADS):
        if loop.options.conventions.pm_loop != "impedance":      # the map on the grid, no curves
            return region_map(loop, P, D, progress=False), curves
        # the stability boundary in the grid's box, once: the map splits its rows with it and
        # the page draws it
        st = stability_boundary(loop, **box)
        m = region_map(loop, P, D, progress=False, boundary=st)
        b = boundaries(loop, **box, n_lines=CURVE_LINES, stability=st, passivity_xtol=CURVE_XTOL)
        for family, cs in (("stability", b.stability.curves), ("pm", b.phase_margin), ("passivity", b.passivity)):
            curves += [{"family": PASSIVITY_FAMILIES.get(c.kind, family) if family == "passivity" else family,
                        "kind": c.kind, "P_gain": np.asarray(c.P_gain, float),
                        "D_gain": np.asarray(c.D_gain, float)} for c in cs]
    return m, curves


def _read_csv(path: str, field: str, required: tuple[str, ...]) -> list[dict]:
    """The rows of the CSV ``path`` (a regular file of at most :data:`MAX_CSV_BYTES`, read through
    :func:`haa_sym.io.inputs.read_text`: on the explorer's server only where it may read)."""
    text = read_text(path, field, limit=MAX_CSV_BYTES, encoding="utf-8-sig")
    try:
        rows = list(csv.DictReader(io.StringIO(text, newline="")))
        header = rows[0].keys() if rows else []
    except csv.Error as exc:
        raise ParameterError(f"{field} {path!r}: not a CSV file ({exc}); allowed: a CSV file") from None
    missing = [c for c in required if c not in header]
    if not rows or missing:
        raise ParameterError(f"{field} {path!r}: " + (f"missing column(s) {missing}" if rows else "no rows")
                             + f"; allowed: a CSV with a header row naming {list(required)}")
    return rows


def _numbers(rows, column: str, field: str, path: str, blank_nan: bool = False) -> np.ndarray:
    out = np.empty(len(rows))
    for i, row in enumerate(rows):
        text = (row.get(column) or "").strip()
        try:
            out[i] = math.nan if blank_nan and not text else float(text)
        except ValueError:
            raise ParameterError(f"{field} {path!r}, row {i + 2}: {column} = {text!r} is not a number; "
                                 "allowed: a finite number") from None
        if not blank_nan and not math.isfinite(out[i]):
            raise ParameterError(f"{field} {path!r}, row {i + 2}: {column} = {text!r}; allowed: a finite number")
    return out


def _schedule_overlay(path: str) -> dict:
    """The schedule's grid points (``haa-sym schedule --out``): where a robust beta exists, and it."""
    rows = _read_csv(path, "schedule", ("P_gain", "D_gain", "beta", "feasible"))
    feasible = np.array([(r.get("feasible") or "").strip().lower() == "true" for r in rows])
    return {"P_gain": _numbers(rows, "P_gain", "schedule", path), "D_gain": _numbers(rows, "D_gain", "schedule", path),
            "beta": _numbers(rows, "beta", "schedule", path, blank_nan=True), "feasible": feasible}


def _measured_overlay(path: str, loop) -> dict:
    """Measured points (``P_gain,D_gain,outcome``, outcome as written, e.g. stable / unstable)
    and what the model predicts there (certified stability at each point)."""
    rows = _read_csv(path, "measured", ("P_gain", "D_gain", "outcome"))
    P, D = _numbers(rows, "P_gain", "measured", path), _numbers(rows, "D_gain", "measured", path)
    for name, v in (("P_gain", P), ("D_gain", D)):
        gain_array(name, v, f"measured {path!r} {name}")
    return {"P_gain": P, "D_gain": D, "outcome": [(r.get("outcome") or "").strip() for r in rows],
            "predicted_stable": np.asarray(loop.stability(P, D).stable, bool)}


@_memo()
def _robust_overlay(model_key: tuple, P_text: str, D_text: str, text: str) -> dict:
    """The gains stable with PM >= 30 deg for every configuration of the leg range ("on": the
    file's default range; "FROM:TO": two configurations), :func:`robust_region`; memoised as
    :func:`_map_and_curves` (it maps every configuration of the range: seconds)."""
    loop = _loop(model_key)[2]
    P, D = gain_axis(P_text, "--P-gain", "P_gain"), gain_axis(D_text, "--D-gain", "D_gain")
    leg = None
    if text.strip().lower() != "on":
        a, sep, b = text.partition(":")
        if not sep:
            raise ParameterError(f"robust = {text!r}; allowed: on (the file's leg range) or FROM:TO (two "
                                 f"configurations of the file, or 'nominal')")
        leg = (a.strip(), b.strip())
    r = robust_region(loop, P, D, leg=leg)
    return {"feasible": np.asarray(r.feasible, bool), "leg": list(r.meta.get("leg", leg or ())),
            "requirements": list(r.meta.get("requirements", ()))}


# ----------------------------------------------------------------------------- one point

@dataclass(frozen=True)
class Detail:
    """What the page shows for one gain point: the decisions, the margins of both loops
    (:func:`haa_sym.analysis.margins.margins`: crossovers in rad/s, PM in deg, GM in dB), the
    corrected phase of Z (``omega`` rad/s, ``phase_deg``), the torque step (impedance loop open:
    ``t`` s, ``T`` Nm) and the impedance step (a unit torque on the port: ``t`` s, ``theta``
    rad), and the closed-loop poles in the z-plane (``poles``, complex)."""

    P_gain: float
    D_gain: float
    stable: bool
    spectral_radius: float
    margins: dict
    phase: dict
    torque_step: dict
    impedance_step: dict
    poles: np.ndarray

    def to_dict(self) -> dict:
        """Plain JSON-able data (poles as [re, im] pairs)."""
        d = asdict(self)
        d["poles"] = [[float(z.real), float(z.imag)] for z in self.poles]
        return plain(d)


def plain(v):
    if isinstance(v, dict):
        return {k: plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return plain(v.tolist())
    if isinstance(v, (np.floating, float)):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, (np.integer, np.bool_)):
        return v.item()
    return v


def _margins_dict(m) -> dict:
    return {"gain_crossovers_rad_s": m.gain_crossovers, "phase_margins_deg": m.phase_margins_deg,
            "phase_crossovers_rad_s": m.phase_crossovers, "gain_margins_db": m.gain_margins_db,
            "pm_deg": m.pm_deg, "distance_deg": m.distance_deg}


def point_detail(state: ViewState, P_gain: float, D_gain: float, resolved: Resolved | None = None) -> Detail:
    """Everything the page shows for the gain point (``P_gain`` Nm/rad, ``D_gain`` Nms/rad)."""
    r = resolve(state) if resolved is None else resolved
    with blas_limits(BLAS_THREADS):
        return _point_detail(r.loop, P_gain, D_gain)


def _point_detail(loop, P_gain, D_gain) -> Detail:
    P = float(gain_array("P_gain", P_gain, "point P_gain").reshape(()))
    D = float(gain_array("D_gain", D_gain, "point D_gain").reshape(()))
    st = loop.stability(P, D, radius=True)
    ctrl = loop.params.controller
    poles = closed_loop_eigenvalues(loop, np.array([[P], [D], [ctrl.beta], [ctrl.alpha]]))[0]
    w, ph = corrected_phase(loop, P, D)
    # a structure without a torque loop (haa_sym.model.structures): no torque step, no margins
    torque = loop.structure.torque_loop
    s = step_response(loop, duration=STEP_DURATION_S) if torque else None
    z = impedance_step(loop, P, D, duration=STEP_DURATION_S)
    return Detail(P, D, bool(st.stable), float(st.spectral_radius),
                  {"impedance": _margins_dict(margins(loop, P, D, which="L_imp")),
                   "torque": _margins_dict(margins(loop, P, D, which="L_t")) if torque else None},
                  {"omega_rad_s": w, "phase_deg": ph},
                  {"t_s": s.t, "T_Nm": s.T, "final_value": s.final_value} if torque else
                  {"t_s": np.zeros(0), "T_Nm": np.zeros(0), "final_value": float("nan")},
                  {"t_s": z.t, "theta_rad": z.theta, "final_value_rad_per_Nm": z.final_value},
                  poles)


def view_summary(view: View) -> dict:
    """The JSON the page exposes for a map (and tests read): the axes, the category of every
    point (:data:`CATEGORIES`) as one string of digits, [i_P, i_D] flattened in C order, the
    counts, and the number of curves of each family."""
    return {"n_P": int(view.P_gain.size), "n_D": int(view.D_gain.size),
            "P_gain": [float(v) for v in view.P_gain], "D_gain": [float(v) for v in view.D_gain],
            "category": "".join(map(str, view.category.ravel().tolist())),
            "counts": {"stable": int(view.stable.sum()), "low_pm": int(view.low_pm.sum()),
                       "passive": int(view.passive.sum())},
            "curves": {f: sum(1 for c in view.curves if c["family"] == f) for f in CURVE_FAMILIES}}


def dumps(data) -> str:
    """JSON of plain data (NaN and inf as null)."""
    return json.dumps(plain(data), separators=(",", ":"))


def state_dict(state: ViewState) -> dict:
    return {f.name: getattr(state, f.name) for f in fields(state)}
