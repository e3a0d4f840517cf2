"""An actuator defined in code: a linear sympy model with named signals and a parameter domain.

:class:`LinearActuatorModel` is what the code generator compiles (as acados compiles an
``AcadosModel`` and PyDy's ``System`` takes the equations of a ``KanesMethod``): the state space
``dx/dt = A x + B u``, ``y = C x`` with entries that are rational expressions of named,
domain-checked parameters, and the velocity-compensation constant ``VC0`` (Eq. 6 at
alpha = 1). A chain :class:`~haa_sym.model.actuator.Topology` is one producer of it
(:meth:`Topology.model`, derived by :mod:`haa_sym.symbolic.chain`); an engineer writes one by
hand, either as matrices or as equations of motion linearised at a point
(:meth:`LinearActuatorModel.from_equations`). Either way the model is compiled on first use into
the content-hash cache (:mod:`haa_sym.compiled.plant_code`) and evaluated by the same
:class:`~haa_sym.loop.plant.ContinuousPlant` path, so every analysis (``ClosedLoop``, ``region_map``,
``passivity``, margins, steps) works on it; :meth:`haa_sym.Params.from_model` gives it values and
a controller.

The closed loop reads the model through fixed signal roles:

* inputs, in this order: ``V_m`` (motor voltage, V; the loop's one actuated input), ``T_fr``
  (torque on the rotor, Nm: friction) and ``T_dist`` (external torque at the port, Nm);
* outputs (any order, more allowed): ``T_sensor`` (the measured torque, Nm, with the sensor's
  damping term), ``T_sensor_spring`` (the same without it, Nm), ``theta_encoder`` (the angle
  the encoder reads, rad) and at least one velocity ``dtheta_<name>`` (rad/s): the candidate port
  velocities; ``dtheta_<port>`` is the velocity conjugate to ``T_dist`` (the default port).

Every check is made on construction; a bad model raises one
:class:`~haa_sym.model.params.ParameterError` naming the model, the field and what is allowed. The
expressions must be exact: integers and rationals (``sp.Rational(1, 2)``), no floats, and only
``+``, ``*`` and integer powers (what :func:`haa_sym.symbolic.symbolic_to_casadi.to_sx`
translates without rounding).

Example
-------
``docs/model.md``, "An actuator in code", builds a whole model; the parameters alone:

>>> from haa_sym.symbolic.model import Parameter
>>> Parameter("J_m", ">0", "kg m^2").symbol.is_positive, Parameter("B_m", ">=0", "Nm s/rad").symbol.is_positive
(True, None)
"""
from __future__ import annotations

import hashlib
import json
import keyword
import re
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import sympy as sp

from haa_sym.model.actuator import INPUT_NAMES, Actuator
from haa_sym.errors import ParameterError
from haa_sym.model.params import CONTROLLER_KEYS

__all__ = ["Parameter", "LinearActuatorModel", "ROLE_OUTPUTS", "INPUT_NAMES", "DOMAINS"]

# The outputs the closed loop reads by role (haa_sym.loop.closed_loop: the measured torque with or without the
# sensor's damping term, the encoder angle); port velocities are the outputs named dtheta_<name>.
ROLE_OUTPUTS = ("T_sensor", "T_sensor_spring", "theta_encoder")
DOMAINS = (">0", ">=0")
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")
# names a parameter may not take: the Plant's own attributes, the controller's keys (one flat
# namespace for --set KEY=VALUE) and the Laplace variable of the symbolic layer
_RESERVED = {"topology", "actuator", "keys", "replace", "as_dict", "as_tuple", "s"} | set(CONTROLLER_KEYS)


@dataclass(frozen=True)
class Parameter:
    """One parameter of a model: its name (the flat key of the values), domain and unit.

    Parameters
    ----------
    name : str
        The symbol's name in the expressions and the key of the values (``plant.<name>``).
    domain : {">0", ">=0"}
        ">0" for what divides or sets the dynamics' order (inertias, L, R, k_t, N, spring
        stiffnesses), ">=0" for what may vanish (frictions, dampings, k_w).
    unit : str
        SI unit of the value (e.g. ``"kg m^2"``, ``"Nm/rad"``, ``"-"``).
    description : str
        Free text, e.g. where the value comes from.
    """

    name: str
    domain: str
    unit: str
    description: str = ""

    @property
    def symbol(self) -> sp.Symbol:
        """The canonical symbol: positive for ">0", nonnegative for ">=0" (as the chain's)."""
        return sp.Symbol(self.name, positive=True) if self.domain == ">0" else \
            sp.Symbol(self.name, nonnegative=True)


def _error(model: str, field_: str, msg: str) -> ParameterError:
    return ParameterError(f"LinearActuatorModel {model!r}: {field_}: {msg}")


def _unsupported(expr: sp.Basic):
    """The first subexpression :func:`to_sx` cannot translate exactly (None if all can)."""
    if expr.is_Symbol or expr.is_Integer or (expr.is_Rational and not expr.is_Float):
        return None
    if expr.is_Float:
        return expr
    if expr.is_Add or expr.is_Mul:
        for a in expr.args:
            bad = _unsupported(a)
            if bad is not None:
                return bad
        return None
    if expr.is_Pow and expr.args[1].is_Integer:
        return _unsupported(expr.args[0])
    return expr


@dataclass(frozen=True, eq=False)
class LinearActuatorModel(Actuator):
    """A linear actuator model in sympy: ``dx/dt = A x + B u``, ``y = C x``, and VC0.

    Parameters
    ----------
    name : str
        A name for messages (not part of the compiled code's identity).
    states : sequence of str
        State names, in the order of the columns of A and C (e.g. ``"I_m"`` in A,
        ``"theta_m"`` in rad, ``"dtheta_m"`` in rad/s).
    inputs : sequence of str
        Exactly ``("V_m", "T_fr", "T_dist")``: voltage (V), rotor friction torque (Nm), port
        torque (Nm).
    outputs : sequence of str
        Output names, the rows of C; must contain ``T_sensor`` (Nm), ``T_sensor_spring`` (Nm),
        ``theta_encoder`` (rad) and ``dtheta_<port>`` (rad/s).
    parameters : sequence of Parameter, or mapping name -> (domain, unit[, description])
        Every symbol of A, B, C and VC0, in the order of the plant function's input vector.
    A, B, C : sympy.Matrix (or nested lists)
        ``n x n``, ``n x 3`` and ``len(outputs) x n``; SI units (A in 1/s, B in 1/(V s) etc.).
    VC0 : sympy.Expr
        Velocity-compensation gain at alpha = 1 (Eq. 6), V s/rad: the loop adds
        ``alpha VC0`` times the estimated encoder velocity to V_m (for a DC motor behind a
        gearbox ``N/k_t (R B_m + k_t k_w)``).
    port : str
        The name X of the velocity output ``dtheta_X`` conjugate to T_dist (the passivity
        port's default velocity, as ``[sensors] port`` of an actuator file).
    torque_damping : bool
        Whether the torque loop measures ``T_sensor`` (True, default) or ``T_sensor_spring``.
    source : str, optional
        How messages name this actuator; default ``"<model NAME>"``.

    Raises
    ------
    ParameterError
        One message naming the field: wrong names or shapes, a role output missing, an
        undeclared or state/input symbol in an entry, a float or a non-rational function, a
        domain outside {">0", ">=0"}.

    Notes
    -----
    Symbols are matched to parameters by name and replaced by the canonical symbol of their
    domain (:attr:`Parameter.symbol`), so ``sp.Symbol("J")`` and ``sp.Symbol("J",
    positive=True)`` are the same parameter. :attr:`fingerprint` hashes the canonical ``srepr``
    of A, B, C, VC0 with the signal and parameter names and domains: it names the compiled code.
    """

    name: str
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    parameters: tuple[Parameter, ...]
    A: sp.ImmutableMatrix
    B: sp.ImmutableMatrix
    C: sp.ImmutableMatrix
    VC0: sp.Expr
    port: str
    torque_damping: bool = True
    source: str = field(default="", repr=False)

    def __post_init__(self):
        name = self.name
        if not isinstance(name, str) or not name.strip():
            raise ParameterError(f"LinearActuatorModel: name = {name!r}; allowed: a non-empty string")
        set_ = lambda k, v: object.__setattr__(self, k, v)     # noqa: E731 (frozen dataclass)
        if not self.source:
            set_("source", f"<model {name}>")
        for fld in ("states", "outputs"):
            set_(fld, _names(name, fld, getattr(self, fld)))
        set_("inputs", tuple(self.inputs) if isinstance(self.inputs, (list, tuple)) else self.inputs)
        if self.inputs != INPUT_NAMES:
            raise _error(name, "inputs", f"{self.inputs!r}; allowed: exactly {INPUT_NAMES} (the motor "
                         "voltage, the rotor friction torque and the port torque, in this order)")
        missing = [o for o in ROLE_OUTPUTS if o not in self.outputs]
        if missing:
            raise _error(name, "outputs", f"missing role output(s) {missing}; allowed: outputs that "
                         f"include {list(ROLE_OUTPUTS)} (the measured torque with and without the "
                         "sensor's damping, the encoder angle) and dtheta_<port>")
        if not isinstance(self.torque_damping, bool):
            raise _error(name, "torque_damping", f"{self.torque_damping!r}; allowed: True or False")
        if not isinstance(self.port, str) or f"dtheta_{self.port}" not in self.outputs:
            vel = [o[len("dtheta_"):] for o in self.outputs if o.startswith("dtheta_")]
            raise _error(name, "port", f"{self.port!r} has no velocity output 'dtheta_{self.port}'; "
                         f"allowed: one of {vel} (X of an output dtheta_X)" if vel else
                         f"{self.port!r}: the model has no velocity output dtheta_<name>; allowed: "
                         "outputs with the port's velocity dtheta_<port> (rad/s)")
        params = _parameters(name, self.parameters)
        set_("parameters", params)
        signals = set(self.states) | set(self.inputs)
        for p in params:
            if p.name in signals:
                raise _error(name, f"parameters[{p.name!r}]", "the name is also a state or input; "
                             "allowed: distinct names")
        n, m = len(self.states), len(self.inputs)
        shapes = {"A": (n, n), "B": (n, m), "C": (len(self.outputs), n)}
        declared = {p.name: p.symbol for p in params}
        for fld, shape in shapes.items():
            set_(fld, _matrix(name, fld, getattr(self, fld), shape))
        try:
            vc0 = sp.sympify(self.VC0, strict=True)
        except (sp.SympifyError, TypeError):
            raise _error(name, "VC0", f"{self.VC0!r}; allowed: a sympy expression of the "
                         "parameters (V s/rad)") from None
        if not isinstance(vc0, sp.Expr) or isinstance(vc0, sp.MatrixBase):
            raise _error(name, "VC0", f"{self.VC0!r}; allowed: a scalar sympy expression (V s/rad)")
        set_("VC0", vc0)
        # one symbol per parameter name: the domain's canonical one (replaced only where it differs,
        # so a model that already uses them, like the chain's, keeps its expressions untouched)
        for fld in ("A", "B", "C", "VC0"):
            value = getattr(self, fld)
            entries = [((), value)] if fld == "VC0" else \
                [((i, j), value[i, j]) for i in range(value.rows) for j in range(value.cols)]
            for idx, e in entries:
                where = fld + (f"[{idx[0]}, {idx[1]}]" if idx else "")
                syms = sorted(e.free_symbols, key=str)
                sig = [str(x) for x in syms if str(x) in signals]
                if sig:
                    raise _error(name, where, f"{e} contains the signal(s) {sig}; allowed: "
                                 "expressions of the parameters alone (a linear model; use "
                                 "from_equations to linearise)")
                undeclared = [str(x) for x in syms if str(x) not in declared]
                if undeclared:
                    raise _error(name, where, f"{e} contains undeclared symbol(s) {undeclared}; "
                                 f"allowed: the declared parameters {list(declared)}")
                bad = _unsupported(e)
                if bad is not None:
                    what = f"the float {bad}" if bad.is_Float else f"{bad} ({type(bad).__name__})"
                    raise _error(name, where, f"{e} contains {what}; allowed: exact rationals "
                                 "(sp.Rational(p, q), integers) combined by +, * and integer powers")
            swap = {x: declared[str(x)] for x in value.free_symbols if x != declared[str(x)]}
            if swap:
                set_(fld, value.xreplace(swap))

    # --- what the numeric runtime reads (haa_sym.model.actuator.Actuator) --------------------------
    @property
    def domain(self) -> dict[str, str]:
        """Parameter name -> domain (">0" or ">=0"), in :attr:`parameter_keys` order."""
        return {p.name: p.domain for p in self.parameters}

    @property
    def units(self) -> dict[str, str]:
        """Parameter name -> SI unit."""
        return {p.name: p.unit for p in self.parameters}

    @property
    def parameter_keys(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.states

    @property
    def input_names(self) -> tuple[str, ...]:
        return self.inputs

    @property
    def output_names(self) -> tuple[str, ...]:
        return self.outputs

    @property
    def symbols(self) -> dict[str, sp.Symbol]:
        """Parameter name -> its (canonical) symbol in A, B, C, VC0."""
        return {p.name: p.symbol for p in self.parameters}

    def code_identity(self) -> dict:
        """What defines the compiled code, as plain data: names, domains, ``srepr`` of A, B, C, VC0."""
        return {"states": list(self.states), "inputs": list(self.inputs), "outputs": list(self.outputs),
                "parameters": [[p.name, p.domain] for p in self.parameters],
                "A": sp.srepr(self.A), "B": sp.srepr(self.B), "C": sp.srepr(self.C),
                "VC0": sp.srepr(self.VC0)}

    @property
    def fingerprint(self) -> str:
        """SHA-256 of the canonical JSON of :meth:`code_identity` (content, not the name)."""
        fp = self.__dict__.get("_fingerprint")
        if fp is None:
            text = json.dumps(self.code_identity(), sort_keys=True, separators=(",", ":"))
            fp = hashlib.sha256(text.encode()).hexdigest()
            object.__setattr__(self, "_fingerprint", fp)
        return fp

    @property
    def function_name(self) -> str:
        """Name of the compiled plant function: ``haa_plant_<first 12 hex of the fingerprint>``."""
        return f"haa_plant_{self.fingerprint[:12]}"

    def structure(self) -> dict:
        """The model as plain data (saved next to results): signals, parameters, matrices as text."""
        return {"model": self.name, "states": list(self.states), "inputs": list(self.inputs),
                "outputs": list(self.outputs), "port": self.port, "torque_damping": self.torque_damping,
                "parameters": {p.name: {"domain": p.domain, "unit": p.unit} for p in self.parameters},
                "A": sp.sstr(self.A), "B": sp.sstr(self.B), "C": sp.sstr(self.C), "VC0": sp.sstr(self.VC0)}

    def describe(self) -> str:
        return (f"model {self.name!r}: {len(self.states)} states, outputs {list(self.outputs)}, "
                f"{len(self.parameters)} parameters, port dtheta_{self.port}")

    def _identity(self):
        return (self.fingerprint, self.port, self.torque_damping,
                tuple((p.name, p.unit) for p in self.parameters))

    def __eq__(self, other) -> bool:
        return isinstance(other, LinearActuatorModel) and self._identity() == other._identity()

    def __hash__(self) -> int:
        return hash(self._identity())

    # --- from nonlinear equations ------------------------------------------------------------
    @classmethod
    def from_equations(cls, name: str, states: Sequence[sp.Symbol], inputs: Sequence[sp.Symbol],
                       xdot: Sequence[sp.Expr], outputs: Mapping[str, sp.Expr],
                       parameters, VC0: sp.Expr, port: str, *,
                       operating_point: Mapping | None = None, torque_damping: bool = True,
                       source: str = "") -> "LinearActuatorModel":
        """Linearise ``dx/dt = f(x, u)``, ``y = h(x)`` at an operating point.

        Parameters
        ----------
        name : str
        states : sequence of sympy.Symbol
            The state variables; their names are the state names.
        inputs : sequence of sympy.Symbol
            ``V_m`` (V), ``T_fr`` (Nm), ``T_dist`` (Nm), in this order.
        xdot : sequence of sympy.Expr
            ``f(x, u)``, one expression per state (SI units per second).
        outputs : mapping str -> sympy.Expr
            Output name -> ``h(x)``; the roles of :class:`LinearActuatorModel`.
        parameters, VC0, port, torque_damping, source
            As :class:`LinearActuatorModel`.
        operating_point : mapping, optional
            State/input symbol (or name) -> exact value of the point; default every signal 0.

        Returns
        -------
        LinearActuatorModel
            ``A = df/dx``, ``B = df/du``, ``C = dh/dx`` at the point (entries not simplified).

        Raises
        ------
        ParameterError
            As the class, plus: lengths that differ, signals that are not symbols, an output
            that depends on an input (a direct feedthrough D != 0, which the loop does not model).
        """
        for fld, seq in (("states", states), ("inputs", inputs)):
            if not all(isinstance(x, sp.Symbol) for x in seq):
                raise _error(name, fld, f"{list(seq)!r}; allowed: sympy Symbols (their names name "
                             "the signals)")
        if not isinstance(outputs, Mapping):
            raise _error(name, "outputs", f"{outputs!r}; allowed: a mapping name -> expression")
        if len(xdot) != len(states):
            raise _error(name, "xdot", f"{len(xdot)} expressions for {len(states)} states; "
                         "allowed: one per state")
        x, u = sp.Matrix(list(states)), sp.Matrix(list(inputs))
        try:
            f = sp.Matrix([sp.sympify(e, strict=True) for e in xdot])
            h = sp.Matrix([sp.sympify(e, strict=True) for e in outputs.values()])
        except (sp.SympifyError, TypeError) as exc:
            raise _error(name, "xdot/outputs", f"{exc}; allowed: sympy expressions") from None
        point = {}
        for k, v in (operating_point or {}).items():
            sym = k if isinstance(k, sp.Symbol) else sp.Symbol(str(k))
            match = [s for s in list(states) + list(inputs) if s.name == sym.name]
            if not match:
                raise _error(name, "operating_point", f"{k!r} is not a state or input; allowed: "
                             f"{[s.name for s in list(states) + list(inputs)]}")
            point[match[0]] = sp.sympify(v)
        point = {s: point.get(s, sp.Integer(0)) for s in list(states) + list(inputs)}
        D = h.jacobian(u).xreplace(point)
        if any(e != 0 for e in D):
            raise _error(name, "outputs", f"output(s) {[n for n, row in zip(outputs, D.tolist()) if any(row)]} "
                         "depend on the inputs directly (D != 0); allowed: outputs of the states alone")
        A = f.jacobian(x).xreplace(point)
        B = f.jacobian(u).xreplace(point)
        C = h.jacobian(x).xreplace(point)
        return cls(name=name, states=tuple(s.name for s in states), inputs=tuple(s.name for s in inputs),
                   outputs=tuple(outputs), parameters=parameters, A=A, B=B, C=C, VC0=VC0, port=port,
                   torque_damping=torque_damping, source=source)


def _names(model: str, fld: str, value) -> tuple[str, ...]:
    if isinstance(value, str) or not isinstance(value, (list, tuple)):
        raise _error(model, fld, f"{value!r}; allowed: a sequence of names")
    names = tuple(value)
    if not names:
        raise _error(model, fld, "empty; allowed: at least one name")
    for nm in names:
        if not isinstance(nm, str) or not _NAME.match(nm) or keyword.iskeyword(nm):
            raise _error(model, fld, f"name {nm!r}; allowed: identifiers [A-Za-z][A-Za-z0-9_]*")
        if names.count(nm) > 1:
            raise _error(model, fld, f"{nm!r} appears twice; allowed: distinct names")
    return names


def _parameters(model: str, value) -> tuple[Parameter, ...]:
    if isinstance(value, Mapping):
        items = []
        for k, v in value.items():
            spec = (v,) if isinstance(v, str) else tuple(v) if isinstance(v, (list, tuple)) else None
            if spec is None or not 2 <= len(spec) <= 3:
                raise _error(model, f"parameters[{k!r}]", f"{v!r}; allowed: (domain, unit) or "
                             "(domain, unit, description)")
            items.append(Parameter(k, *spec))
        value = items
    if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
        raise _error(model, "parameters", f"{value!r}; allowed: a sequence of Parameter or a mapping "
                     "name -> (domain, unit)")
    seen: set[str] = set()
    for i, p in enumerate(value):
        if not isinstance(p, Parameter):
            raise _error(model, f"parameters[{i}]", f"{p!r}; allowed: a Parameter(name, domain, unit)")
        f = f"parameters[{p.name!r}]"
        if not isinstance(p.name, str) or not _NAME.match(p.name) or keyword.iskeyword(p.name):
            raise _error(model, f"parameters[{i}].name", f"{p.name!r}; allowed: an identifier "
                         "[A-Za-z][A-Za-z0-9_]*")
        if p.name in _RESERVED:
            raise _error(model, f, f"the name {p.name!r} is reserved; allowed: not {sorted(_RESERVED)}")
        if p.name in seen:
            raise _error(model, f, "declared twice; allowed: distinct parameter names")
        seen.add(p.name)
        if p.domain not in DOMAINS:
            raise _error(model, f + ".domain", f"{p.domain!r}; allowed: {list(DOMAINS)} (\">0\" for "
                         "divisors such as inertias, \">=0\" for what may vanish such as frictions)")
        if not isinstance(p.unit, str) or not p.unit.strip():
            raise _error(model, f + ".unit", f"{p.unit!r}; allowed: the SI unit as a string "
                         "(\"-\" for none)")
        if not isinstance(p.description, str):
            raise _error(model, f + ".description", f"{p.description!r}; allowed: a string")
    return tuple(value)


def _matrix(model: str, fld: str, value, shape: tuple[int, int]) -> sp.ImmutableMatrix:
    try:
        M = value if isinstance(value, sp.ImmutableMatrix) else sp.ImmutableMatrix(value)
    except (sp.SympifyError, TypeError, ValueError) as exc:
        raise _error(model, fld, f"not a matrix ({exc}); allowed: a sympy Matrix of shape {shape}") from None
    if M.shape != shape:
        raise _error(model, fld, f"shape {M.shape}; allowed: {shape} (states x states, states x "
                     "inputs, outputs x states)")
    return M
