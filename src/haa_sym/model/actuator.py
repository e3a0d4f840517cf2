"""The actuator's topology as data: a motor, a gearbox and a chain of compliant bodies.

An actuator file (TOML, ``docs/model.md``, "Actuator files") names the bodies after the gearbox,
the couplings (spring + damper) between them, and where the torque sensor, the encoder and the
external torque sit. :class:`Topology` is that structure (no values): it fixes the flat parameter
names (``J_L2``, ``K_hd``, ...), their domains and order, the names of the plant's states,
inputs and outputs, and a fingerprint that names the generated code. :func:`parse_actuator`
reads and validates the actuator sections of a file; every bad input is one
:class:`~haa_sym.model.params.ParameterError` naming the file, the section, the key, the value and
what is allowed. No sympy, no CasADi here: the numeric runtime imports this module.

Model (generalising Eq. 1-2 of the paper): states ``[I_m, theta_m, dtheta_m]`` then
``theta_X, dtheta_X`` per body X in file order; inputs ``[V_m, T_fr, T_dist]``; a coupling
between a and b transmits ``T = K (theta_a - theta_b) + D (dtheta_a - dtheta_b)`` (with
``theta_rotor = theta_m / N``), acting ``+T`` on b and ``-T`` on a.

Example
-------
>>> HYQ.parameter_keys[:7]
('L', 'R', 'k_t', 'k_w', 'J_m', 'B_m', 'N')
>>> HYQ.output_names
('T_sensor', 'T_sensor_spring', 'theta_encoder', 'dtheta_L1', 'dtheta_L2')
"""
from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass, field
from typing import Mapping

from haa_sym.errors import ParameterError
from haa_sym.model.units import to_si

__all__ = ["Actuator", "Body", "Coupling", "Topology", "HYQ", "MOTOR_DOMAIN", "ROTOR", "CURRENT", "ACTUATOR_SECTIONS",
           "parse_actuator", "legacy_plant"]

ROTOR = "rotor"
# Domains: inertias, L, R, k_t, N and coupling stiffnesses appear as divisors or set the state
# dimension (a zero coupling stiffness would leave a body without restoring torque, a rigid
# coupling is a merged body); frictions, dampings, k_w and stiffness to ground may vanish
# (K_L2 = 0 is the gravity-compensated leg of Sec. 3.1).
MOTOR_DOMAIN: dict[str, str] = {"L": ">0", "R": ">0", "k_t": ">0", "k_w": ">=0", "J_m": ">0",
                                "B_m": ">=0", "N": ">0"}
BODY_DOMAIN: dict[str, str] = {"J": ">0", "B": ">=0", "K": ">=0"}
COUPLING_DOMAIN: dict[str, str] = {"K": ">0", "D": ">=0"}
MOTOR_UNITS: dict[str, str] = {"L": "H", "R": "Ohm", "k_t": "Nm/A", "k_w": "V s/rad", "J_m": "kg m^2",
                               "B_m": "Nm s/rad", "N": "-"}
BODY_UNITS: dict[str, str] = {"J": "kg m^2", "B": "Nm s/rad", "K": "Nm/rad"}
COUPLING_UNITS: dict[str, str] = {"K": "Nm/rad", "D": "Nm s/rad"}
SENSOR_KEYS = ("torque", "torque_damping", "encoder", "port")
# [sensors] torque = CURRENT: the torque estimated from the motor current, k_t N I_m (no torque
# sensor; the loop closes on the estimate); encoder = ROTOR: the rotor angle referred to the
# output, theta_m / N (a motor-side encoder). Neither names a coupling or a body.
CURRENT = "current"
ACTUATOR_SECTIONS = ("about", "motor", "bodies", "couplings", "sensors")
INPUT_NAMES = ("V_m", "T_fr", "T_dist")
SOURCE_LETTERS = ("D", "I", "C", "-")          # Table 1: datasheet, identified, computed, none
# ci95: an optional 95 % confidence interval [lo, hi] in the entry's unit (haa-sym identify writes it)
_ENTRY_FIELDS = ("value", "unit", "source", "description", "ci95")
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9]*\Z")
_RESERVED = (ROTOR, "m")                        # "m" would give J_m, B_m: the rotor's names


def _error(msg: str):
    return ParameterError(msg)


class Actuator:
    """What the numeric runtime reads of an actuator, whatever defines it.

    Implemented by :class:`Topology` (a chain, from a file or code) and by
    :class:`haa_sym.symbolic.model.LinearActuatorModel` (a sympy model written in code):
    ``parameter_keys`` and ``domain`` (the plant vector and its rules), ``units``,
    ``state_names``, ``input_names`` and ``output_names`` (the plant's signals), ``port`` and
    ``torque_damping`` (the loop's defaults), ``fingerprint`` and ``function_name`` (the plant
    function's identity), ``source``, :meth:`describe` and :meth:`structure`. The sympy model the
    code generator compiles is :func:`haa_sym.symbolic.chain.symbolic_model` of it (the
    symbolic layer sits above this one: only code generation imports sympy).
    """

    __slots__ = ()


@dataclass(frozen=True)
class Body:
    """A rigid body after the gearbox: inertia ``J_<name>``, friction ``B_<name>`` and, when
    ``ground``, a stiffness to ground ``K_<name>`` (e.g. linearised gravity)."""

    name: str
    ground: bool = False


@dataclass(frozen=True)
class Coupling:
    """A spring ``K_<name>`` and damper ``D_<name>`` between bodies ``a`` and ``b`` (``"rotor"``
    is the rotor angle divided by N)."""

    name: str
    a: str
    b: str


@dataclass(frozen=True)
class Topology(Actuator):
    """The structure of an actuator (no values): bodies, couplings and sensors.

    Parameters
    ----------
    bodies : tuple of Body
        In file order (the order of the states).
    couplings : tuple of Coupling
        In file order; exactly one touches ``"rotor"`` (the gearbox).
    sensor : str
        The coupling whose transmitted torque the torque sensor measures, or ``"current"``: no
        torque sensor, the torque k_t N I_m (Nm at the output) estimated from the motor current.
    torque_damping : bool
        Whether the sensor sees the coupling's damping term (Eq. 2) or the spring deflection alone.
        Does not apply to ``sensor = "current"`` (stored as False there: both torque outputs are
        the same estimate, so the loop option ``torque_damping`` changes nothing).
    encoder : str
        The body whose angle the encoder reads, or ``"rotor"``: a motor-side encoder, theta_m / N
        (rad at the output).
    port : str
        The body the external torque T_dist acts on (passivity port, contact); ``"rotor"`` in a
        rotor-only actuator (no bodies: a direct drive or a one-axis haptic device, where the
        current estimate and the rotor's encoder are the only sensors), whose port velocity
        ``dtheta_rotor`` is dtheta_m / N (N = 1 for a direct drive).
    source : str
        Where it was read from, for messages (not part of the structure).
    """

    bodies: tuple[Body, ...]
    couplings: tuple[Coupling, ...]
    sensor: str
    torque_damping: bool
    encoder: str
    port: str
    source: str = field(default="<memory>", compare=False, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "bodies", tuple(self.bodies))
        object.__setattr__(self, "couplings", tuple(self.couplings))
        _check_structure(self)
        object.__setattr__(self, "couplings", _oriented(self.couplings))
        if self.sensor == CURRENT:            # no coupling term to include or leave out
            object.__setattr__(self, "torque_damping", False)

    # --- names -----------------------------------------------------------------------------
    @property
    def body_names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.bodies)

    @property
    def gearbox(self) -> Coupling | None:
        """The coupling touching the rotor; None for a rotor-only actuator (no [bodies])."""
        return next((c for c in self.couplings if ROTOR in (c.a, c.b)), None)

    @property
    def sensor_coupling(self) -> Coupling | None:
        """The coupling the torque sensor is on; None for the current estimate."""
        return next((c for c in self.couplings if c.name == self.sensor), None)

    @property
    def domain(self) -> dict[str, str]:
        """Flat parameter name -> domain (">0" or ">=0"), in :attr:`parameter_keys` order."""
        d = dict(MOTOR_DOMAIN)
        for b in self.bodies:
            d[f"J_{b.name}"], d[f"B_{b.name}"] = BODY_DOMAIN["J"], BODY_DOMAIN["B"]
            if b.ground:
                d[f"K_{b.name}"] = BODY_DOMAIN["K"]
        for c in self.couplings:
            d[f"K_{c.name}"], d[f"D_{c.name}"] = COUPLING_DOMAIN["K"], COUPLING_DOMAIN["D"]
        return d

    @property
    def units(self) -> dict[str, str]:
        """Flat parameter name -> SI unit (the file's ``unit`` fields say the same)."""
        u = dict(MOTOR_UNITS)
        for k in self.domain:
            if k not in u:
                kind, _, name = k.partition("_")
                sec = self.section_of(k)[0]
                u[k] = (BODY_UNITS if sec.startswith("bodies.") else COUPLING_UNITS)[kind]
        return u

    @property
    def parameter_keys(self) -> tuple[str, ...]:
        """Flat parameter names: motor, then bodies, then couplings in file order (the order of
        the generated plant function's input vector)."""
        return tuple(self.domain)

    def section_of(self, key: str) -> tuple[str, str]:
        """(file section, key in it) of flat parameter ``key``, e.g. ``("couplings.hd", "K")``."""
        if key in MOTOR_DOMAIN:
            return "motor", key
        kind, _, name = key.partition("_")
        if kind in ("J", "B") or (kind == "K" and name in self.body_names
                                  and any(b.ground for b in self.bodies if b.name == name)):
            return f"bodies.{name}", kind
        return f"couplings.{name}", kind

    @property
    def state_names(self) -> tuple[str, ...]:
        return ("I_m", "theta_m", "dtheta_m") + tuple(
            n for b in self.bodies for n in (f"theta_{b.name}", f"dtheta_{b.name}"))

    @property
    def input_names(self) -> tuple[str, ...]:
        return INPUT_NAMES

    @property
    def output_names(self) -> tuple[str, ...]:
        """The torque sensor with and without its damping term, the encoder angle, then every
        body's velocity (the candidate port velocities). The names are the roles the loop reads
        whatever the sensors are: with ``torque = "current"`` both torque outputs are the
        estimate k_t N I_m, with ``encoder = "rotor"`` ``theta_encoder`` is theta_m / N."""
        return ("T_sensor", "T_sensor_spring", "theta_encoder") + tuple(
            f"dtheta_{b.name}" for b in self.bodies) + ((f"dtheta_{ROTOR}",) if self.port == ROTOR else ())

    # --- identity ----------------------------------------------------------------------------
    def structure(self) -> dict:
        """The structure as plain data (what the fingerprint hashes; no values, no source)."""
        return {
            "bodies": [[b.name, b.ground] for b in self.bodies],
            "couplings": [[c.name, c.a, c.b] for c in self.couplings],
            "sensors": {"torque": self.sensor, "torque_damping": self.torque_damping,
                        "encoder": self.encoder, "port": self.port},
        }

    @property
    def fingerprint(self) -> str:
        """SHA-256 of the canonical JSON of :meth:`structure`."""
        text = json.dumps(self.structure(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()

    @property
    def function_name(self) -> str:
        """Name of the generated plant function of this topology."""
        return f"haa_plant_{self.fingerprint[:12]}"

    def describe(self) -> str:
        chain = ", ".join(f"{c.name}: {c.a}-{c.b}" for c in self.couplings)
        torque = "torque from the motor current (k_t N I_m)" if self.sensor == CURRENT else \
            f"torque sensor on {self.sensor}"
        return (f"bodies {list(self.body_names)}, couplings ({chain}), {torque}, encoder on "
                f"{self.encoder}, port on {self.port}")


# The HyQ HAA joint of the paper (Fig. 5): rotor, harmonic drive hd, J_L1, leg spring p, J_L2.
def _hyq() -> Topology:
    return Topology(bodies=(Body("L1"), Body("L2", ground=True)),
                    couplings=(Coupling("hd", ROTOR, "L1"), Coupling("p", "L1", "L2")),
                    sensor="hd", torque_damping=True, encoder="L1", port="L2",
                    source="the HyQ topology")


def _oriented(couplings) -> tuple:
    """Each coupling written from the motor side to the load side: ``a`` is the end nearer the
    rotor (fewer couplings away). The transmitted torque K (theta_a - theta_b) + D (...), which
    the torque sensor measures, is then positive when the motor drives the load, whichever order
    a file writes ``between`` in (the other order made the torque loop positive feedback). Ends
    equally far from the rotor (a coupling closing a loop) keep the file's order."""
    dist, frontier = {ROTOR: 0}, [ROTOR]
    while frontier:
        nxt = []
        for x in frontier:
            for c in couplings:
                for u, v in ((c.a, c.b), (c.b, c.a)):
                    if u == x and v not in dist:
                        dist[v] = dist[x] + 1
                        nxt.append(v)
        frontier = nxt
    return tuple(Coupling(c.name, c.b, c.a) if dist[c.a] > dist[c.b] else c for c in couplings)


def _check_structure(t: Topology) -> None:
    src = t.source
    if not t.bodies:
        # the rotor the only body (a direct drive, a one-axis haptic device): nothing after a
        # gearbox to couple, to sense or to load; the current estimate, the rotor's angle and
        # its port are the only sensors there are
        if t.couplings:
            raise _error(f"{src} [couplings.{t.couplings[0].name}]: a file without [bodies] has no couplings "
                         "(the rotor is the only body); allowed: [bodies.<name>] tables for the load, or no "
                         "[couplings]")
        for key, value in (("torque", t.sensor), ("encoder", t.encoder), ("port", t.port)):
            want = CURRENT if key == "torque" else ROTOR
            if value != want:
                raise _error(f"{src} [sensors]: {key} = {value!r} in a file without [bodies] (the rotor "
                             f"is the only body); allowed: {key} = {want!r}")
        if not isinstance(t.torque_damping, bool):
            raise _error(f"{src} [sensors]: torque_damping = {t.torque_damping!r}; allowed: true or false")
        return
    for kind, items in (("bodies", t.bodies), ("couplings", t.couplings)):
        for it in items:
            if not isinstance(it.name, str) or not _NAME.match(it.name) or it.name in _RESERVED:
                raise _error(f"{src} [{kind}.{it.name}]: name {it.name!r} is not allowed; allowed: "
                             f"an identifier [A-Za-z][A-Za-z0-9]*, not {list(_RESERVED)}")
    names = [b.name for b in t.bodies]
    for b in t.bodies:
        if names.count(b.name) > 1:
            raise _error(f"{src} [bodies.{b.name}]: body {b.name!r} is defined twice; allowed: "
                         "distinct body names")
    cnames = [c.name for c in t.couplings]
    for c in t.couplings:
        if cnames.count(c.name) > 1:
            raise _error(f"{src} [couplings.{c.name}]: coupling {c.name!r} is defined twice; "
                         "allowed: distinct coupling names")
    allowed_ends = [ROTOR] + names
    for c in t.couplings:
        for end in (c.a, c.b):
            if end not in allowed_ends:
                raise _error(f"{src} [couplings.{c.name}]: between = {[c.a, c.b]!r} names unknown "
                             f"body {end!r}; allowed: {allowed_ends}")
        if c.a == c.b:
            raise _error(f"{src} [couplings.{c.name}]: between = {[c.a, c.b]!r} couples a body to "
                         f"itself; allowed: two different bodies of {allowed_ends}")
    gear = [c.name for c in t.couplings if ROTOR in (c.a, c.b)]
    if len(gear) != 1:
        raise _error(f"{src} [couplings]: {len(gear)} couplings touch 'rotor' "
                     f"({gear or 'none'}); allowed: exactly one (the gearbox)")
    # every body must be reached from the rotor through couplings
    reached, frontier = {ROTOR}, [ROTOR]
    while frontier:
        x = frontier.pop()
        for c in t.couplings:
            for u, v in ((c.a, c.b), (c.b, c.a)):
                if u == x and v not in reached:
                    reached.add(v)
                    frontier.append(v)
    for b in t.bodies:
        if b.name not in reached:
            raise _error(f"{src} [bodies.{b.name}]: body {b.name!r} is not connected to the rotor "
                         "through couplings (disconnected chain); allowed: a chain where every "
                         "body is reached from 'rotor' through [couplings.*] between = [a, b]")
    # flat parameter names must not collide (body "p" with K_p and coupling "p")
    owner: dict[str, str] = {k: "motor" for k in MOTOR_DOMAIN}
    for sec, keys in ([(f"bodies.{b.name}", [f"J_{b.name}", f"B_{b.name}"]
                        + ([f"K_{b.name}"] if b.ground else [])) for b in t.bodies]
                      + [(f"couplings.{c.name}", [f"K_{c.name}", f"D_{c.name}"])
                         for c in t.couplings]):
        for k in keys:
            if k in owner:
                raise _error(f"{src} [{sec}]: parameter name {k} collides with [{owner[k]}]'s "
                             f"{k}; allowed: body and coupling names whose parameter names are "
                             "distinct")
            owner[k] = sec
    if CURRENT in cnames:
        raise _error(f"{src} [couplings.{CURRENT}]: name {CURRENT!r} is not allowed for a coupling; "
                     f"allowed: another name ([sensors] torque = {CURRENT!r} is the current estimate)")
    if not isinstance(t.torque_damping, bool):
        raise _error(f"{src} [sensors]: torque_damping = {t.torque_damping!r}; allowed: true or false")
    if t.sensor not in cnames and t.sensor != CURRENT:
        raise _error(f"{src} [sensors]: torque = {t.sensor!r} is not a coupling; allowed: {cnames} "
                     f"or {CURRENT!r} (the estimate k_t N I_m from the motor current)")
    if t.encoder not in names and t.encoder != ROTOR:
        raise _error(f"{src} [sensors]: encoder = {t.encoder!r} is not a body; allowed: {names} "
                     f"or {ROTOR!r} (a motor-side encoder: theta_m / N)")
    if t.port not in names:
        raise _error(f"{src} [sensors]: port = {t.port!r} is not a body; allowed: {names}")


HYQ = _hyq()


# --- reading a file ------------------------------------------------------------------------
def _sources_allowed(references: Mapping[str, str]) -> list[str]:
    return list(SOURCE_LETTERS) + sorted(references)


def _entry(value: object, where: str, key: str, references: Mapping[str, str],
           units: Mapping[str, str | None] | None = None) -> object:
    """Unwrap a ``{value, unit, source, description}`` entry (a bare number is accepted too), its
    value converted from ``unit`` to the key's SI unit ``units[key]`` (:func:`haa_sym.model.units.to_si`;
    a bare number or no ``unit`` is SI; a key not in ``units`` is left for the key check)."""
    if not isinstance(value, Mapping):
        return value
    extra = sorted(set(value) - set(_ENTRY_FIELDS))
    if extra:
        raise _error(f"{where}: {key}: unknown field(s) {extra}; allowed: {sorted(_ENTRY_FIELDS)}")
    if "value" not in value:
        raise _error(f"{where}: {key}: missing field 'value'; allowed: "
                     "{ value, unit, source, description } with value required")
    src = value.get("source", "-")
    if src not in SOURCE_LETTERS and src not in references:
        raise _error(f"{where}: {key}: source = {src!r}; allowed: {_sources_allowed(references)} "
                     "(Table 1 letters or a key of [about.references])")
    for f in ("unit", "description"):
        if f in value and not isinstance(value[f], str):
            raise _error(f"{where}: {key}: {f} = {value[f]!r}; allowed: a string")
    if "ci95" in value:
        _check_ci95(value["ci95"], value["value"], where, key)
    if units is not None and key in units:
        return to_si(value["value"], value.get("unit"), units[key], where, key)
    return value["value"]


def _check_ci95(ci, value, where: str, key: str) -> None:
    """A confidence interval must bracket its value: two finite numbers lo <= value <= hi (the
    entry's unit), so that a file never claims an interval that excludes its own value."""
    def number(x):
        return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
    if not (isinstance(ci, list) and len(ci) == 2 and all(number(x) for x in ci)):
        raise _error(f"{where}: {key}: ci95 = {ci!r}; allowed: two finite numbers [lo, hi] in the entry's unit")
    if number(value) and not ci[0] <= value <= ci[1]:
        raise _error(f"{where}: {key}: ci95 = {ci!r} does not contain value = {value!r}; allowed: "
                     "lo <= value <= hi")


def entry_values(table: Mapping[str, object], where: str,
                 references: Mapping[str, str] | None = None,
                 units: Mapping[str, str | None] | None = None) -> dict[str, object]:
    """The values of a table of entries (``where`` names file and section for messages), in SI:
    ``units`` maps a key to its SI unit (None: a name, no unit), see :func:`_entry`."""
    refs = references or {}
    return {k: _entry(v, where, k, refs, units) for k, v in table.items()}


def _table(data: Mapping, key: str, where: str) -> Mapping:
    value = data.get(key)
    if not isinstance(value, Mapping):
        raise _error(f"{where}: missing table [{key}]" if value is None else
                     f"{where}: [{key}] = {value!r}; allowed: a table")
    return value


def check_keys(table, allowed, required, where: str | None = None) -> None:
    """The one rule for the keys of a table (a file section, a Plant, a Controller): unknown keys
    and missing required keys are each one error naming ``where``, the keys and what is allowed."""
    prefix = f"{where}: " if where else ""
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise _error(f"{prefix}unknown key(s) {unknown}; allowed: {list(allowed)}")
    missing = [k for k in required if k not in table]
    if missing:
        raise _error(f"{prefix}missing key(s) {missing}; every key of {list(required)} is required")


def _named_tables(data: Mapping, section: str, source: str, holds: str):
    """``(name, table, where)`` of every ``[section.<name>]``, each checked to be a table."""
    tables = data.get(section, {})
    if not isinstance(tables, Mapping):
        raise _error(f"{source} [{section}]: {tables!r}; allowed: tables [{section}.<name>]")
    for name, tab in tables.items():
        where = f"{source} [{section}.{name}]"
        if not isinstance(tab, Mapping):
            raise _error(f"{where}: {tab!r}; allowed: a table with {holds}")
        yield name, tab, where


def parse_about(data: Mapping, source: str) -> dict:
    """``[about]``: name, description and references (key -> citation)."""
    about = data.get("about", {})
    where = f"{source} [about]"
    if not isinstance(about, Mapping):
        raise _error(f"{where}: [about] = {about!r}; allowed: a table")
    check_keys(about, ("name", "description", "references"), (), where)
    for k in ("name", "description"):
        if k in about and not isinstance(about[k], str):
            raise _error(f"{where}: {k} = {about[k]!r}; allowed: a string")
    refs = about.get("references", {})
    if not isinstance(refs, Mapping):
        raise _error(f"{source} [about.references]: {refs!r}; allowed: a table of key = \"citation\"")
    for k, v in refs.items():
        if not isinstance(v, str) or not v.strip():
            raise _error(f"{source} [about.references]: {k} = {v!r}; allowed: a citation string")
        if k in SOURCE_LETTERS:
            raise _error(f"{source} [about.references]: key {k!r} is a Table 1 letter; allowed: "
                         f"another key (not {list(SOURCE_LETTERS)})")
    return {"name": about.get("name", ""), "description": about.get("description", ""),
            "references": dict(refs)}


def parse_actuator(data: Mapping, source: str = "<memory>") -> tuple[Topology, dict, dict]:
    """The actuator sections of a file: ``(topology, raw values by flat name, about)``.

    Values are unwrapped but not yet checked against their domains (:class:`haa_sym.model.params.Plant`
    does that, naming the section). A file with the legacy flat ``[plant]`` table is read as the
    HyQ topology (:func:`legacy_plant`).
    """
    about = parse_about(data, source)
    refs = about["references"]
    if "plant" in data:
        return legacy_plant(data, source, refs) + (about,)
    motor = _table(data, "motor", source)
    where = f"{source} [motor]"
    check_keys(motor, tuple(MOTOR_DOMAIN), tuple(MOTOR_DOMAIN), where)
    values = {k: v for k, v in entry_values(motor, where, refs, MOTOR_UNITS).items()}
    bodies = []
    for name, tab, w in _named_tables(data, "bodies", source, "J, B and optional K"):
        check_keys(tab, tuple(BODY_DOMAIN), ("J", "B"), w)
        vals = entry_values(tab, w, refs, BODY_UNITS)
        bodies.append(Body(name, ground="K" in tab))
        values.update({f"{k}_{name}": v for k, v in vals.items()})
    couplings = []
    for name, tab, w in _named_tables(data, "couplings", source, "between, K and D"):
        check_keys(tab, ("between", "K", "D"), ("between", "K", "D"), w)
        ends = tab["between"]
        if not (isinstance(ends, list) and len(ends) == 2 and all(isinstance(e, str) for e in ends)):
            raise _error(f"{w}: between = {ends!r}; allowed: two body names [a, b] ('rotor' for "
                         "the gearbox's input)")
        vals = entry_values({k: tab[k] for k in ("K", "D")}, w, refs, COUPLING_UNITS)
        couplings.append(Coupling(name, ends[0], ends[1]))
        values.update({f"{k}_{name}": v for k, v in vals.items()})
    sensors = _table(data, "sensors", source)
    # torque_damping is required with a torque sensor and optional (ignored) with the current
    # estimate, which has no coupling damping term to include or leave out
    current = sensors.get("torque") == CURRENT
    required = tuple(k for k in SENSOR_KEYS if not (current and k == "torque_damping"))
    check_keys(sensors, SENSOR_KEYS, required, f"{source} [sensors]")
    for k in ("torque", "encoder", "port"):
        if not isinstance(sensors[k], str):
            raise _error(f"{source} [sensors]: {k} = {sensors[k]!r}; allowed: a name (string)")
    top = Topology(tuple(bodies), tuple(couplings), sensors["torque"], sensors.get("torque_damping", False),
                   sensors["encoder"], sensors["port"], source=source)
    return top, values, about


def legacy_plant(data: Mapping, source: str, references: Mapping[str, str] | None = None):
    """The old flat ``[plant]`` table (every HyQ key), read as the HyQ topology."""
    plant = _table(data, "plant", source)
    where = f"{source} [plant]"
    values = entry_values(plant, where, references, HYQ.units)
    top = Topology(HYQ.bodies, HYQ.couplings, HYQ.sensor, HYQ.torque_damping, HYQ.encoder,
                   HYQ.port, source=source)
    check_keys(values, top.parameter_keys, top.parameter_keys, where)
    return top, values
